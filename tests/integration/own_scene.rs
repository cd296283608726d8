//! Issue 13: "stylize your own scene" through the real binaries: the sample DAG run on a
//! shared `.splat` scene (copied under a path with spaces, apostrophes, `$`, backticks
//! and non-ASCII letters, issue 22) with an `orbit:` camera spec, a style from the
//! current directory and a prompt that tries shell injection, every output under
//! `--workdir`, nothing run but the stages, `data-sample/` untouched, and one `--set`
//! change rerunning exactly its downstream.
//!
//! Sizes are kept small through the params keys `render.width`, `render.height`,
//! `distill.chunks` and `distill.chunk`.

use crate::harness;
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

/// The tracked files of data-sample/ and whether the runner's own files exist there.
fn sample_state(ds: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut m = BTreeMap::new();
    for e in std::fs::read_dir(ds).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_file() && !name.ends_with(".lock") {
            m.insert(name, std::fs::read(&p).unwrap());
        }
    }
    for f in ["runs", ".pipeline", "stylize.lock"] {
        m.insert(format!("exists:{f}"), vec![ds.join(f).exists() as u8]);
    }
    m
}

/// Every file and directory name under `dir`, recursively.
fn names(dir: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        v.push(e.file_name().to_string_lossy().into_owned());
        if e.path().is_dir() {
            v.extend(names(&e.path()));
        }
    }
    v
}

fn done(stdout: &str) -> Vec<String> {
    let mut v: Vec<String> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("done"))
        .map(|l| l.split_whitespace().next().unwrap().to_string())
        .collect();
    v.sort();
    v
}

#[test]
fn own_splat_scene_with_orbit_cameras_into_a_workdir() {
    let Some(splat) = harness::shared_scene("bob_10k.splat") else {
        return;
    };
    let root = harness::repo_root();
    let ds = root.join("data-sample");
    let dag = ds.join("stylize.toml");
    let before = sample_state(&ds);
    let t = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(t.path().join("art")).unwrap();
    std::fs::copy(ds.join("style.png"), t.path().join("art/wave.png")).unwrap();
    // The scene under a name a shell would mangle: spaces, apostrophes, `$`, backticks,
    // `$(...)`, non-ASCII letters; and a prompt that tries to close a quote and run a
    // command. Both must reach the stages as they are, and nothing else may run.
    let captures = "my captures/it's $HOME `touch pwned` ünïcødé";
    let scene = format!("{captures}/bob's $(touch pwned) scene.splat");
    std::fs::create_dir_all(t.path().join(captures)).unwrap();
    std::fs::copy(&splat, t.path().join(&scene)).unwrap();
    let bin = harness::pipeline_bin();
    let mut args: Vec<String> = [
        "--dag",
        dag.to_str().unwrap(),
        "--workdir",
        "out/bob",
        "--set",
        &format!("scene={scene}"),
        "--set",
        "prompt=it's; touch pwned; echo '",
        "--set",
        "style=art/wave.png",
        "--set",
        "cameras=orbit:6",
        "--set",
        "render.width=48",
        "--set",
        "render.height=48",
        "--set",
        "distill.chunks=1",
        "--set",
        "distill.chunk=2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let pipeline = |cmd: &str, args: &[String]| {
        let o = Command::new(&bin)
            .arg(cmd)
            .args(args)
            .current_dir(t.path())
            .output()
            .unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let run_args = |a: &[String]| a.to_vec();

    let (rc, out, err) = pipeline("run", &run_args(&args));
    assert_eq!(rc, Some(0), "{out}\n{err}");
    let w = t.path().join("out/bob");
    let views = fantasystyle_schemas::Artifact::open_any(&w.join("runs/source/views")).unwrap();
    assert_eq!(
        views.manifest.file("rgb.npy").unwrap().shape.as_deref(),
        Some(&[6usize, 48, 48, 3][..])
    );
    assert!(w.join("runs/c1/manifest.json").is_file());
    assert!(w.join("stylize.lock").is_file() && w.join(".pipeline/logs").is_dir());
    assert!(
        out.contains("result  scene    out/bob/runs/final/"),
        "{out}"
    );
    assert!(
        out.contains("result  report   out/bob/runs/eval/report.html"),
        "{out}"
    );
    // The stylized splat also as .spz, and the report's 3D viewer embeds it as written
    // (or says how to install the viewer).
    let spz = w.join("runs/final/scene.spz");
    let s = fantasystyle::artifacts::load_scene(&spz).unwrap();
    let ply = fantasystyle::artifacts::load_scene(&w.join("runs/final/scene.ply")).unwrap();
    assert_eq!(s.len(), 10_000);
    let cams = fantasystyle::camera::load_cameras("orbit:4", &ply.bounds(), 64, 64).unwrap();
    let (mut worst, mut sum) = (0.0f32, 0.0f64);
    let opts = fantasystyle::render::RenderOptions::default();
    for c in &cams {
        let a = fantasystyle::render::render(&ply, c, &opts).unwrap();
        let b = fantasystyle::render::render(&s, c, &opts).unwrap();
        for (x, y) in a.rgb.iter().zip(&b.rgb) {
            let d = (x.clamp(0.0, 1.0) - y.clamp(0.0, 1.0)).abs();
            worst = worst.max(d);
            sum += d as f64;
        }
    }
    let mean = sum / (4 * 64 * 64 * 3) as f64;
    eprintln!("final scene.spz vs scene.ply renders: max {worst:.4}, mean {mean:.2e}");
    use fantasystyle::scene::spz::{SPZ_RENDER_MAX, SPZ_RENDER_MEAN};
    assert!(
        worst < SPZ_RENDER_MAX && mean < SPZ_RENDER_MEAN,
        "{worst} {mean}"
    );
    let html = std::fs::read_to_string(w.join("runs/eval/report.html")).unwrap();
    assert!(html.contains("fs-viewer-0") || html.contains("fs-viewer-missing"));
    assert!(
        html.contains("runs/final/scene.spz"),
        "the stylized pane's source"
    );
    // Outputs only under the work directory: the temp dir holds art/, the captures and
    // out/ only; no value ran as a command (no `pwned` anywhere).
    let mut top: Vec<String> = std::fs::read_dir(t.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    top.sort();
    assert_eq!(top, ["art", "my captures", "out"]);
    let all = names(t.path());
    assert!(
        !all.iter().any(|n| n == "pwned"),
        "a value ran as a command: {all:?}"
    );
    // The scene reached render-views as one argument: its log's command line names it.
    let log = std::fs::read_to_string(w.join(".pipeline/logs/source-views.log")).unwrap();
    let cmd = log.lines().find_map(|l| l.strip_prefix("# cmd: ")).unwrap();
    let argv = shlex::split(cmd).unwrap();
    let i = argv.iter().position(|a| a == "--scene").unwrap();
    assert!(
        argv[i + 1].ends_with("bob's $(touch pwned) scene.splat"),
        "{argv:?}"
    );
    assert!(sample_state(&ds) == before, "data-sample/ changed");

    // Nothing to do the second time.
    let (rc, out, _) = pipeline("run", &run_args(&args));
    assert_eq!(rc, Some(0));
    assert!(out.contains("nothing to run"), "{out}");

    // One --set change reruns exactly its downstream: the cameras feed source-views
    // (and, whole DAG, every render and the colour fit).
    let i = args.iter().position(|a| a == "cameras=orbit:6").unwrap();
    args[i] = "cameras=orbit:5".into();
    let (rc, st, _) = pipeline("status", &args);
    assert_eq!(rc, Some(0));
    assert!(
        st.contains("stale       source-views: changed cmd, changed dep orbit:5"),
        "{st}"
    );
    let (rc, out, err) = pipeline("run", &run_args(&args));
    assert_eq!(rc, Some(0), "{out}\n{err}");
    let ran = done(&out);
    // The cameras feed source-views and everything downstream of it, and eval-style (the
    // style crops' count): every stage (source-views, split, init, one distill chunk,
    // final-scene, final-views, eval-source, eval-style, evaluate).
    assert_eq!(ran.len(), 9, "{out}");
    for stage in ["source-views", "eval-source", "eval-style"] {
        assert!(ran.contains(&stage.to_string()), "{stage}: {out}");
    }
    assert!(sample_state(&ds) == before, "data-sample/ changed");
}

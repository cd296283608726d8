//! A preset names the prior its loop calls (issue 53): `distill` with no `--model` (or an
//! empty one, what the sample DAG passes by default) opens the configuration's `prior`,
//! the `arf` preset's the installed stylizer, the default's the repository's patch
//! prior; an unknown name is a missing-resource error that names it, with nothing written.

use crate::harness::{bin, ok, repo_root};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The `model` input recorded in the manifest of the artifact at `dir`.
fn model_input(dir: &Path) -> String {
    let m: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    let inputs = m["inputs"].as_array().unwrap();
    let model = inputs.iter().find(|i| i["role"] == "model").unwrap();
    model["path"].as_str().unwrap().to_string()
}

/// Two 48 px views of the sample scene, rendered into `dir/views`.
fn sample_views(dir: &Path) -> PathBuf {
    let views = dir.join("views");
    ok(bin("render-views")
        .arg("--scene")
        .arg(repo_root().join("data-sample/scene.ply"))
        .args([
            "--cameras",
            "orbit:2",
            "--width",
            "48",
            "--height",
            "48",
            "--out",
        ])
        .arg(&views));
    views
}

/// `distill` on the sample scene with its style, `views` as the source views, one thread,
/// writing `out`.
fn distill_sample(views: &Path, out: &Path) -> Command {
    let root = repo_root();
    let mut c = bin("distill");
    c.arg("--scene")
        .arg(root.join("data-sample/scene.ply"))
        .arg("--source-views")
        .arg(views)
        .arg("--style")
        .arg(root.join("data-sample/style.png"))
        .args(["--threads", "1", "--out"])
        .arg(out);
    c
}

#[test]
fn a_preset_names_the_prior_its_loop_calls() {
    let Some(_) = crate::harness::model("stylizer") else {
        return;
    };
    let (root, d) = (repo_root(), tempfile::tempdir().unwrap());
    let views = sample_views(d.path());
    let distill = |out: &str, model: Option<&str>, sets: &[&str]| {
        let mut c = distill_sample(&views, &d.path().join(out));
        c.args(["--iters", "1", "--set", "views=2"]);
        if let Some(m) = model {
            c.args(["--model", m]);
        }
        for s in sets {
            c.args(["--set", s]);
        }
        c
    };
    ok(distill("arf", None, &[]).args(["--preset", "arf"]));
    let arf = model_input(&d.path().join("arf"));
    assert!(arf.ends_with("stylizer/model.json"), "{arf}");
    // The DAG's empty `model`: the same as none.
    ok(&mut distill("default", Some(""), &["finish=none"]));
    let default = model_input(&d.path().join("default"));
    assert!(default.ends_with("priors/patch/model.json"), "{default}");
    // An explicit --model wins over the preset's.
    let patch = root.join("priors/patch");
    ok(distill("given", Some(patch.to_str().unwrap()), &[]).args(["--preset", "arf"]));
    assert_eq!(
        model_input(&d.path().join("given")),
        patch.join("model.json").to_str().unwrap()
    );
    // An unknown prior: exit 3 (a missing resource), its name in the message, no output.
    let out = distill("nope", None, &["prior=nope", "finish=none"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{err}");
    assert!(
        err.contains("prior `nope`") && err.contains("--model"),
        "{err}"
    );
    assert!(!d.path().join("nope").exists());
}

#[test]
fn the_motifs_preset_lays_cells_under_the_default_end() {
    let d = tempfile::tempdir().unwrap();
    let views = sample_views(d.path());
    let run = |preset: &str| {
        let out = d.path().join(preset);
        let o = ok(distill_sample(&views, &out).args(["--preset", preset, "--iters", "0"]));
        let scene = fantasystyle::artifacts::load_scene(&out.join("scene.ply")).unwrap();
        (scene, String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let (motifs, log) = run("motifs");
    let (default, _) = run("default");
    // The layout start ran (6 cells across the object), and the result is not the
    // default's: the geometry is, the colours are not.
    assert!(
        log.contains("layout: cells of") && log.contains("(6 across"),
        "{log}"
    );
    assert_eq!(motifs.positions, default.positions);
    assert_ne!(motifs.sh_dc, default.sh_dc);
}

//! `--workdir`, `--set`, value deps (`orbit:N`), `[result]` and output integrity, end
//! to end through the `pipeline` binary on small DAGs of fake stages.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;

const BIN: &str = env!("CARGO_BIN_EXE_pipeline");

const PARAMS: &str = "seed = 7\n[a]\nvalue = 1.0\nsteps = 2\n[b]\nvalue = 2.0\n";

/// copy (reads a file var) and gen (params) -> mid -> last; cam only reads a value dep.
const DAG: &str = r#"params = "params.toml"
[vars]
input = "in.txt"
cameras = "orbit:4"
[stages.copy]
cmd = '''sh -c 'mkdir -p runs/copy && cp "$1" runs/copy/in.txt && echo "$2" > runs/copy/cams.txt' sh ${input} ${cameras}'''
deps = ["${input}", "${cameras}"]
outs = ["runs/copy"]
[stages.gen]
cmd = "pipeline test-stage --out runs/gen --seed ${seed} --value ${a.value} --steps ${a.steps}"
outs = ["runs/gen"]
[stages.mid]
cmd = "pipeline test-stage --input runs/gen --out runs/mid --seed 2 --value ${b.value}"
deps = ["runs/gen", "runs/copy"]
outs = ["runs/mid"]
[stages.lit]
cmd = '''sh -c 'mkdir -p runs/lit && cp "$1" runs/lit/notes.txt' sh notes.txt'''
deps = ["notes.txt"]
outs = ["runs/lit"]
[stages.last]
cmd = "pipeline test-stage --input runs/mid --out runs/last --seed 3"
deps = ["runs/mid"]
outs = ["runs/last"]
[result]
final = "runs/last"
"#;

/// A temp root with `proj/` (the DAG, its params, in.txt, notes.txt).
fn project() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("proj");
    std::fs::create_dir_all(&p).unwrap();
    std::fs::write(p.join("dag.toml"), DAG).unwrap();
    std::fs::write(p.join("params.toml"), PARAMS).unwrap();
    std::fs::write(p.join("in.txt"), "from the dag dir\n").unwrap();
    std::fs::write(p.join("notes.txt"), "notes\n").unwrap();
    d
}

fn pipeline(cwd: &Path, args: &[&str]) -> (i32, String, String) {
    let o = Command::new(BIN)
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn ran(stdout: &str) -> Vec<String> {
    let mut v: Vec<String> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("done"))
        .map(|l| l.split_whitespace().next().unwrap().to_string())
        .collect();
    v.sort();
    v
}

/// Every file under `dir` (relative path -> bytes).
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, p: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        let Ok(rd) = std::fs::read_dir(p) else {
            return;
        };
        for e in rd {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

#[test]
fn workdir_holds_every_output_and_set_reruns_exactly_downstream() {
    let d = project();
    let root = d.path();
    let before = tree(&root.join("proj"));
    std::fs::write(root.join("mine.txt"), "from the current dir\n").unwrap();
    let base = [
        "run",
        "--dag",
        "proj/dag.toml",
        "--workdir",
        "out/w",
        "--set",
        "input=mine.txt",
    ];
    let (rc, out, err) = pipeline(root, &base);
    assert_eq!(rc, 0, "{out}\n{err}");
    assert_eq!(ran(&out), ["copy", "gen", "last", "lit", "mid"]);
    // Outputs, lock, logs and pid file only under the work directory; the DAG's
    // directory is untouched.
    assert_eq!(
        tree(&root.join("proj")),
        before,
        "the DAG's directory changed"
    );
    let w = root.join("out/w");
    for p in [
        "dag.lock",
        ".pipeline/logs/mid.log",
        "runs/last/manifest.json",
    ] {
        assert!(w.join(p).exists(), "{p} missing under the workdir");
    }
    assert!(!w.join(".pipeline/run.pid").exists());
    // --set path from the current directory; the DAG's literal dep from the DAG's dir;
    // the value dep passed through as text.
    assert_eq!(
        std::fs::read_to_string(w.join("runs/copy/in.txt")).unwrap(),
        "from the current dir\n"
    );
    assert_eq!(
        std::fs::read_to_string(w.join("runs/lit/notes.txt")).unwrap(),
        "notes\n"
    );
    assert_eq!(
        std::fs::read_to_string(w.join("runs/copy/cams.txt")).unwrap(),
        "orbit:4\n"
    );
    let log = std::fs::read_to_string(w.join(".pipeline/logs/copy.log")).unwrap();
    assert!(log.contains(" sh ../../mine.txt orbit:4\n"), "{log}");
    // The end of the run names the [result] paths as seen from the current directory.
    assert!(out.contains("result  final    out/w/runs/last"), "{out}");

    // Same command: nothing to run.
    let (rc, out, _) = pipeline(root, &base);
    assert_eq!(rc, 0);
    assert!(out.contains("nothing to run"), "{out}");

    // One params value: exactly its stage and downstream.
    let mut a: Vec<&str> = base.to_vec();
    a.extend(["--set", "b.value=2.5"]);
    let (rc, st, _) = pipeline(root, &[&["status"], &a[1..]].concat());
    assert_eq!(rc, 0);
    assert!(
        st.contains("stale       mid: changed cmd, changed params b.value"),
        "{st}"
    );
    assert!(
        st.contains("stale       last: upstream mid is stale"),
        "{st}"
    );
    assert!(st.contains("2 of 5 stages stale"), "{st}");
    let (rc, out, _) = pipeline(root, &a);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["last", "mid"]);

    // One [vars] value (a value dep): its stage and downstream. `mid` reruns (its dep
    // runs/copy changed) but does not read runs/copy, so it writes the same bytes and
    // `last` stays up to date.
    a.extend(["--set", "cameras=orbit:16"]);
    let (rc, st, _) = pipeline(root, &[&["status"], &a[1..]].concat());
    assert_eq!(rc, 0);
    assert!(
        st.contains("stale       copy: changed cmd, changed dep orbit:16"),
        "{st}"
    );
    assert!(st.contains("3 of 5 stages stale"), "{st}");
    let (rc, out, _) = pipeline(root, &a);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["copy", "mid"]);
    assert_eq!(
        std::fs::read_to_string(w.join("runs/copy/cams.txt")).unwrap(),
        "orbit:16\n"
    );
    // An integer param whose change alters a test-stage output.
    a.extend(["--set", "a.steps=3"]);
    let (rc, out, _) = pipeline(root, &a);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["gen", "last", "mid"]);
    // status, dag and report take the same --workdir/--set.
    let (rc, st, _) = pipeline(root, &[&["status"], &a[1..]].concat());
    assert_eq!(rc, 0);
    assert!(st.contains("0 of 5 stages stale"), "{st}");
    let (rc, rep, _) = pipeline(root, &[&["report"], &a[1..]].concat());
    assert!(rc == 0 && rep.contains("last run:"), "{rep}");
    let (rc, txt, _) = pipeline(root, &[&["dag"], &a[1..]].concat());
    assert!(
        rc == 0 && txt.contains("reads: ../../mine.txt, orbit:16"),
        "{txt}"
    );
    let (rc, txt, _) = pipeline(root, &["inspect", "--workdir", "out/w", "runs/last"]);
    assert!(rc == 0 && txt.contains("kind      latents"), "{txt}");
    // Without --workdir, the DAG's directory is the work directory, as before.
    let (rc, out, err) = pipeline(root, &["run", "--dag", "proj/dag.toml"]);
    assert_eq!(rc, 0, "{err}");
    assert_eq!(ran(&out).len(), 5);
    assert!(root.join("proj/runs/last").is_dir() && root.join("proj/dag.lock").is_file());
}

#[test]
fn bad_set_is_a_clear_usage_error_and_nothing_runs() {
    let d = project();
    let root = d.path();
    for (set, want) in [
        ("input", "--set `input`: expected NAME=VALUE"),
        ("=x", "--set `=x`: expected NAME=VALUE"),
        (
            "nope=1",
            "--set nope=1: `nope` is neither a [vars] name nor a params key of proj/dag.toml (vars: cameras, input; params keys: a.steps, a.value, b.value, seed)",
        ),
        (
            "a=1",
            "--set a=1: params key `a` is a table; set one of its values by its dotted key",
        ),
        (
            "a.steps=two",
            "--set a.steps=two: params key `a.steps` is an integer, and `two` is not one",
        ),
        (
            "input=missing/x.txt",
            "dep `missing/x.txt` of stage `copy` (from --set input=missing/x.txt) does not exist",
        ),
    ] {
        for cmd in ["run", "status", "dag"] {
            let (rc, _, err) = pipeline(
                root,
                &[
                    cmd,
                    "--dag",
                    "proj/dag.toml",
                    "--workdir",
                    "out",
                    "--set",
                    set,
                ],
            );
            assert_eq!(rc, 2, "{cmd} {set}: {err}");
            assert!(
                err.contains(want),
                "{cmd} {set}: want {want:?}, got {err:?}"
            );
        }
        assert!(!root.join("out").exists(), "{set}: something was written");
    }
}

/// A changed, truncated or deleted file inside an artifact output makes its stage
/// (and what depends on it) stale, naming the file; a rerun restores the bytes.
#[test]
fn broken_output_files_make_their_stage_stale_naming_the_file() {
    let d = project();
    let root = d.path();
    let base = ["--dag", "proj/dag.toml", "--workdir", "out"];
    let run = |extra: &[&str]| pipeline(root, &[&["run"], &base[..], extra].concat());
    let status = || pipeline(root, &[&["status"], &base[..]].concat()).1;
    assert_eq!(run(&[]).0, 0);
    let good = tree(&root.join("out/runs"));
    let mid = root.join("out/runs/mid");
    let part = mid.join("part1.npy");
    let bytes = std::fs::read(&part).unwrap();

    // Touched but unchanged: still up to date (hashed once, found equal).
    let f = std::fs::File::options().append(true).open(&part).unwrap();
    f.set_modified(std::time::SystemTime::now() + std::time::Duration::from_secs(5))
        .unwrap();
    drop(f);
    assert!(status().contains("0 of 5 stages stale"), "{}", status());
    // A run that finds it up to date records the new mtime (hashed once, not at every
    // check); a lock without stamps gets them, after a full verification.
    let stamp = || -> serde_json::Value {
        let l: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(root.join("out/dag.lock")).unwrap())
                .unwrap();
        l["stages"]["mid"]["files"]["runs/mid"]["part1.npy"].clone()
    };
    let before = stamp();
    assert!(run(&[]).1.contains("nothing to run"));
    let mtime = std::fs::metadata(&part)
        .unwrap()
        .modified()
        .unwrap()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64;
    assert_eq!(stamp()["mtime_ns"], mtime);
    assert_ne!(stamp(), before);
    let lock_path = root.join("out/dag.lock");
    let mut l: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&lock_path).unwrap()).unwrap();
    l["stages"]["mid"].as_object_mut().unwrap().remove("files");
    std::fs::write(&lock_path, l.to_string()).unwrap();
    assert!(stamp().is_null());
    assert!(run(&[]).1.contains("nothing to run"));
    assert_eq!(stamp()["mtime_ns"], mtime);

    type Case<'a> = (&'a str, Box<dyn Fn() + 'a>, String);
    let cases: [Case; 4] = [
        (
            "changed",
            Box::new(|| {
                let mut b = bytes.clone();
                let n = b.len();
                b[n - 1] ^= 0xff;
                std::fs::write(&part, b).unwrap();
            }),
            "stale       mid: output runs/mid: file part1.npy changed (its blake3 differs from the manifest's)".into(),
        ),
        (
            "truncated",
            Box::new(|| std::fs::write(&part, &bytes[..bytes.len() - 4]).unwrap()),
            format!(
                "stale       mid: output runs/mid: file part1.npy truncated ({} of {} bytes)",
                bytes.len() - 4,
                bytes.len()
            ),
        ),
        (
            "appended",
            Box::new(|| std::fs::write(&part, [&bytes[..], b"x"].concat()).unwrap()),
            format!(
                "stale       mid: output runs/mid: file part1.npy changed size ({} bytes, manifest says {})",
                bytes.len() + 1,
                bytes.len()
            ),
        ),
        (
            "deleted",
            Box::new(|| std::fs::remove_file(&part).unwrap()),
            "stale       mid: output runs/mid: file part1.npy missing".into(),
        ),
    ];
    for (what, break_it, want) in &cases {
        break_it();
        let st = status();
        assert!(st.contains(want.as_str()), "{what}: {st}");
        assert!(
            st.contains("stale       last: upstream mid is stale"),
            "{what}: {st}"
        );
        assert!(st.contains("2 of 5 stages stale"), "{what}: {st}");
        let (rc, out, _) = run(&["--dry-run"]);
        assert!(
            rc == 0 && out.contains("would run   mid: output runs/mid: file part1.npy"),
            "{what}: {out}"
        );
        // The rerun rewrites the same bytes, so downstream stays up to date.
        let (rc, out, _) = run(&[]);
        assert_eq!(rc, 0, "{what}");
        assert_eq!(ran(&out), ["mid"], "{what}: {out}");
        assert_eq!(tree(&root.join("out/runs")), good, "{what}");
        assert!(status().contains("0 of 5 stages stale"), "{what}");
    }
}

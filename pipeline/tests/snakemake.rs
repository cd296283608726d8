//! `pipeline export --snakemake` run by a real Snakemake (the pinned one set-up installs
//! into vendor/venv, or `$SNAKEMAKE`), on a 2 scenes x 2 styles matrix DAG of fake
//! stages (`pipeline test-stage`): byte-identical outputs to `pipeline run`, a no-op
//! second run, one `--set` change rerunning exactly its downstream, a killed Snakemake
//! rerun to the same bytes, and the refusal of a DAG Snakemake cannot express.
//! Without Snakemake the tests say SKIPPED, except under CI=true, where they fail.

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_pipeline");

const PARAMS: &str = "seed = 7\n[final]\nvalue = 0.5\n";

/// Every scene in every style: source per scene, stylize and evaluate per (scene, style).
const MATRIX: &str = r#"params = "params.toml"
[vars]
sleep = 20
[stages.source]
foreach = [1, 2]
cmd = "pipeline test-stage --out runs/scene${item}/source --seed ${item} --steps 2 --sleep-ms ${sleep}"
outs = ["runs/scene${item}/source"]
[stages.stylize]
foreach = { matrix = { scene = [1, 2], style = [3, 5] } }
cmd = "pipeline test-stage --input runs/scene${item.scene}/source --out runs/scene${item.scene}/style${item.style}/stylized --seed ${seed} --value ${item.style} --steps 3 --sleep-ms ${sleep}"
deps = ["runs/scene${item.scene}/source"]
outs = ["runs/scene${item.scene}/style${item.style}/stylized"]
[stages.evaluate]
foreach = { matrix = { scene = [1, 2], style = [3, 5] } }
cmd = "pipeline test-stage --input runs/scene${item.scene}/source --input runs/scene${item.scene}/style${item.style}/stylized --out runs/scene${item.scene}/style${item.style}/eval --seed 9 --value ${final.value} --steps 2 --sleep-ms ${sleep}"
deps = ["runs/scene${item.scene}/source", "runs/scene${item.scene}/style${item.style}/stylized"]
outs = ["runs/scene${item.scene}/style${item.style}/eval"]
"#;

/// The Snakemake to use, or None (SKIPPED) outside CI.
fn snakemake() -> Option<PathBuf> {
    let p = match std::env::var_os("SNAKEMAKE") {
        Some(s) => PathBuf::from(s),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../vendor/venv/bin/snakemake"),
    };
    if p.is_file() {
        return Some(p);
    }
    // The integration harness's rule (tests/integration/harness.rs `ci`).
    if std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false")) {
        panic!(
            "{} is missing: scripts/setup.sh installs it (scripts/setup/40_snakemake.sh)",
            p.display()
        );
    }
    eprintln!(
        "SKIPPED: no Snakemake at {} (run scripts/setup.sh or set SNAKEMAKE)",
        p.display()
    );
    None
}

fn project(sleep_ms: u32) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("proj");
    std::fs::create_dir_all(&p).unwrap();
    std::fs::write(
        p.join("dag.toml"),
        MATRIX.replace("sleep = 20", &format!("sleep = {sleep_ms}")),
    )
    .unwrap();
    std::fs::write(p.join("params.toml"), PARAMS).unwrap();
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

/// Export to `Snakefile` in `cwd` with workdir `wd` and `sets`.
fn export(cwd: &Path, wd: &str, sets: &[&str]) {
    let mut a = vec![
        "export",
        "--snakemake",
        "--dag",
        "proj/dag.toml",
        "--workdir",
        wd,
        "--out",
        "Snakefile",
    ];
    for s in sets {
        a.extend(["--set", s]);
    }
    let (rc, out, err) = pipeline(cwd, &a);
    assert_eq!(rc, 0, "{out}\n{err}");
}

/// Run Snakemake on `cwd/Snakefile`; (success, rules run other than `all`, log).
fn smk(bin: &Path, cwd: &Path, extra: &[&str]) -> (bool, Vec<String>, String) {
    let o = Command::new(bin)
        .args(["-s", "Snakefile", "--cores", "2"])
        .args(extra)
        .current_dir(cwd)
        .output()
        .unwrap();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let mut rules: Vec<String> = log
        .lines()
        .filter_map(|l| l.trim().strip_prefix("Finished jobid: "))
        .filter_map(|l| l.split("(Rule: ").nth(1))
        .map(|r| r.trim_end_matches(')').to_string())
        .filter(|r| r != "all")
        .collect();
    rules.sort();
    (o.status.success(), rules, log)
}

/// Every file under `dir/runs` but Snakemake's `.snakemake_timestamp` markers.
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, p: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(p).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else if p.file_name().unwrap() != ".snakemake_timestamp" {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, &dir.join("runs"), &mut out);
    out
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

#[test]
fn matrix_dag_under_snakemake_matches_pipeline_run() {
    let Some(bin) = snakemake() else { return };
    let d = project(20);
    let root = d.path();
    let (rc, out, err) = pipeline(root, &["run", "--dag", "proj/dag.toml", "--workdir", "ref"]);
    assert_eq!(rc, 0, "{err}");
    assert_eq!(ran(&out).len(), 10, "{out}");
    let want = tree(&root.join("ref"));
    // test-stage writes steps + 2 files: source 2 x 4, stylize 4 x 5, evaluate 4 x 4.
    assert_eq!(want.len(), 2 * 4 + 4 * 5 + 4 * 4, "{:?}", want.keys());

    export(root, "smk", &[]);
    let text = std::fs::read_to_string(root.join("Snakefile")).unwrap();
    assert!(text.contains("rule stylize_2_5:"), "{text}");
    let (ok, rules, log) = smk(&bin, root, &[]);
    assert!(ok, "{log}");
    assert_eq!(rules.len(), 10, "{log}");
    assert!(
        tree(&root.join("smk")) == want,
        "Snakemake's outputs differ from pipeline run's"
    );

    // A second run does nothing.
    let (ok, rules, log) = smk(&bin, root, &[]);
    assert!(ok && rules.is_empty(), "{log}");
    assert!(log.contains("Nothing to be done"), "{log}");

    // One --set change reruns exactly its downstream, under both runners.
    let evals = [
        "evaluate_1_3",
        "evaluate_1_5",
        "evaluate_2_3",
        "evaluate_2_5",
    ];
    export(root, "smk", &["final.value=0.75"]);
    let (ok, rules, log) = smk(&bin, root, &[]);
    assert!(ok, "{log}");
    assert_eq!(rules, evals, "{log}");
    let (rc, out, err) = pipeline(
        root,
        &[
            "run",
            "--dag",
            "proj/dag.toml",
            "--workdir",
            "ref",
            "--set",
            "final.value=0.75",
        ],
    );
    assert_eq!(rc, 0, "{err}");
    assert_eq!(
        ran(&out),
        [
            "evaluate@1.3",
            "evaluate@1.5",
            "evaluate@2.3",
            "evaluate@2.5"
        ]
    );
    let want2 = tree(&root.join("ref"));
    assert!(want2 != want);
    assert!(
        tree(&root.join("smk")) == want2,
        "outputs differ after --set"
    );
    // A --set of the source seed reruns every stage downstream of it: Snakemake has no
    // early cut-off, so all of them.
    export(root, "smk", &["final.value=0.75", "seed=8"]);
    let (ok, rules, log) = smk(&bin, root, &[]);
    assert!(ok, "{log}");
    assert_eq!(
        rules,
        [
            "evaluate_1_3",
            "evaluate_1_5",
            "evaluate_2_3",
            "evaluate_2_5",
            "stylize_1_3",
            "stylize_1_5",
            "stylize_2_3",
            "stylize_2_5"
        ],
        "{log}"
    );
}

/// Kill Snakemake (its whole process group: Snakemake, shells, stages) at a few points
/// of a run, then rerun with --rerun-incomplete: it completes and the bytes match.
#[test]
fn killed_snakemake_rerun_incomplete_matches_pipeline_run() {
    let Some(bin) = snakemake() else { return };
    let d = project(60);
    let root = d.path();
    let (rc, _, err) = pipeline(root, &["run", "--dag", "proj/dag.toml", "--workdir", "ref"]);
    assert_eq!(rc, 0, "{err}");
    let want = tree(&root.join("ref"));
    export(root, "smk", &[]);
    // How long a whole Snakemake run takes here (startup included).
    let t = std::time::Instant::now();
    let (ok, _, log) = smk(&bin, root, &[]);
    assert!(ok, "{log}");
    let whole = t.elapsed();
    let mut interrupted = 0;
    for k in 0..3u32 {
        std::fs::remove_dir_all(root.join("smk")).unwrap();
        let mut child = Command::new(&bin)
            .args(["-s", "Snakefile", "--cores", "2"])
            .current_dir(root)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .unwrap();
        // Kill points spread over the second half of a run (the first is startup).
        std::thread::sleep(whole.mul_f64(0.45 + 0.15 * k as f64));
        let pg = format!("-{}", child.id());
        let _ = Command::new("kill").args(["-KILL", "--", &pg]).status();
        if !child.wait().unwrap().success() {
            interrupted += 1;
        }
        // A killed Snakemake leaves its directory lock; `--unlock` is its documented
        // recovery before a rerun (it does nothing when no lock is left).
        let (ok, _, log) = smk(&bin, root, &["--unlock"]);
        assert!(ok, "kill point {k}, --unlock: {log}");
        let (ok, _, log) = smk(&bin, root, &["--rerun-incomplete"]);
        assert!(ok, "kill point {k}: {log}");
        assert!(
            tree(&root.join("smk")) == want,
            "kill point {k}: outputs differ from pipeline run's"
        );
        let (ok, rules, log) = smk(&bin, root, &[]);
        assert!(ok && rules.is_empty(), "kill point {k}: {log}");
    }
    assert!(
        interrupted >= 2,
        "only {interrupted} of 3 runs were interrupted"
    );
}

#[test]
fn export_refuses_what_snakemake_cannot_express() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(d.path().join("proj")).unwrap();
    std::fs::write(
        d.path().join("proj/dag.toml"),
        "[stages.a]\ncmd = \"mkdir -p o\"\nouts = [\"o\"]\n[stages.check]\ncmd = \"test -d o\"\ndeps = [\"o\"]\n",
    )
    .unwrap();
    let (rc, _, err) = pipeline(
        d.path(),
        &[
            "export",
            "--snakemake",
            "--dag",
            "proj/dag.toml",
            "--out",
            "Snakefile",
        ],
    );
    assert_eq!(rc, 2, "{err}");
    assert!(
        err.contains("proj/dag.toml: cannot be exported to Snakemake")
            && err.contains("stage `check` (line 4) has no outputs"),
        "{err}"
    );
    assert!(!d.path().join("Snakefile").exists());
    // Usage errors are the runner's own.
    let (rc, _, err) = pipeline(
        d.path(),
        &["export", "--dag", "proj/dag.toml", "--out", "Snakefile"],
    );
    assert_eq!(rc, 2);
    assert!(err.contains("--snakemake"), "{err}");
}

/// The Snakemake export quotes every argument as `pipeline run` passes it: a scene path
/// with spaces, apostrophes, `$`, backticks, `$(...)` and non-ASCII letters, and a prompt
/// that tries to close a quote and run a command (with braces, which Snakemake formats),
/// reach the stage unchanged under Snakemake's shell, and nothing else runs. A brace in a
/// file path is refused (Snakemake would read a wildcard).
#[test]
fn snakemake_export_passes_values_as_single_arguments() {
    let Some(bin) = snakemake() else { return };
    let d = tempfile::tempdir().unwrap();
    let root = d.path();
    let p = root.join("proj");
    std::fs::create_dir_all(&p).unwrap();
    let tool = p.join("args.sh");
    std::fs::write(
        &tool,
        "#!/bin/sh\nout=\"$1\"\nshift\nmkdir -p \"$(dirname \"$out\")\"\nprintf '%s\\0' \"$@\" > \"$out\"\n",
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&tool, std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::write(
        p.join("dag.toml"),
        "[vars]\nprompt = \"\"\nscene = \"none\"\n[stages.a]\n\
         cmd = \"./args.sh runs/got.bin --prompt ${prompt} --scene ${scene}\"\n\
         deps = [\"${scene}\"]\nouts = [\"runs/got.bin\"]\n",
    )
    .unwrap();
    let dir = "my captures/it's $HOME `touch pwned` ünï";
    let scene = format!("{dir}/cat's $(touch pwned).splat");
    std::fs::create_dir_all(p.join(dir)).unwrap();
    std::fs::write(p.join(&scene), "s").unwrap();
    let prompt = "it's; touch pwned; echo '{wildcards}";
    let sets = [format!("prompt={prompt}"), format!("scene=proj/{scene}")];
    let set_refs: Vec<&str> = sets.iter().map(String::as_str).collect();
    export(root, "proj", &set_refs);
    let (ok, rules, log) = smk(&bin, root, &[]);
    assert!(ok && rules == ["a"], "{log}");
    let got = std::fs::read(p.join("runs/got.bin")).unwrap();
    let got: Vec<&str> = std::str::from_utf8(&got)
        .unwrap()
        .split_terminator('\0')
        .collect();
    assert_eq!(got, ["--prompt", prompt, "--scene", &scene]);
    // A brace in a file path: Snakemake would read a wildcard; refused, with the reason.
    std::fs::write(p.join("a{x}.splat"), "s").unwrap();
    let (rc, _, err) = pipeline(
        root,
        &[
            "export",
            "--snakemake",
            "--dag",
            "proj/dag.toml",
            "--workdir",
            "proj",
            "--out",
            "S2",
            "--set",
            "scene=proj/a{x}.splat",
        ],
    );
    assert!(
        rc == 2 && err.contains("`a{x}.splat`") && err.contains("wildcard"),
        "{err}"
    );
    let mut stack = vec![root.to_path_buf()];
    while let Some(x) = stack.pop() {
        for e in std::fs::read_dir(&x).unwrap().flatten() {
            assert_ne!(e.file_name(), "pwned", "a value ran as a command");
            if e.path().is_dir() {
                stack.push(e.path());
            }
        }
    }
}

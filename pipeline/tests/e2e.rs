//! End-to-end tests of the `pipeline` binary on small DAGs of fake stages
//! (`pipeline test-stage`, which writes a `latents` artifact slowly, in steps).

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

const BIN: &str = env!("CARGO_BIN_EXE_pipeline");

const PARAMS: &str = "seed = 7\n[a]\nvalue = 1.0\n[b]\nvalue = 2.0\n";

/// gen -> step@r1 -> step@r2 -> step@r3 -> final <- side
const DAG: &str = r#"params = "params.toml"
[vars]
rounds = 3
sleep = 15
[stages.gen]
desc = "the round-0 latents"
cmd = "pipeline test-stage --out runs/r0 --seed ${seed} --value ${a.value} --steps 3 --sleep-ms ${sleep}"
outs = ["runs/r0"]
[stages.side]
cmd = "pipeline test-stage --out runs/side --seed 1 --value ${b.value} --steps 2 --sleep-ms ${sleep}"
outs = ["runs/side"]
[stages.step]
foreach = { from = 1, to = "${rounds}", prefix = "r" }
cmd = "pipeline test-stage --input runs/r${prev} --out runs/r${item} --seed ${item} --steps 3 --sleep-ms ${sleep}"
deps = ["runs/r${prev}"]
outs = ["runs/r${item}"]
[stages.final]
cmd = "pipeline test-stage --input runs/r${rounds} --input runs/side --out runs/final --seed 9 --steps 2 --sleep-ms ${sleep}"
deps = ["runs/r${rounds}", "runs/side"]
outs = ["runs/final"]
"#;

fn project() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("dag.toml"), DAG).unwrap();
    std::fs::write(d.path().join("params.toml"), PARAMS).unwrap();
    d
}

fn pipeline(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .envs(env.iter().copied())
        .output()
        .unwrap()
}

fn run(dir: &Path, extra: &[&str]) -> (i32, String, String) {
    let mut a = vec!["run", "--dag", "dag.toml"];
    a.extend_from_slice(extra);
    let o = pipeline(dir, &a, &[]);
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// Stage names the runner reports as done.
fn ran(stdout: &str) -> Vec<String> {
    let mut v: Vec<String> = stdout
        .lines()
        .filter_map(|l| l.strip_prefix("done"))
        .map(|l| l.split_whitespace().next().unwrap().to_string())
        .collect();
    v.sort();
    v
}

/// Every file under `dir/runs`, by relative path.
fn tree(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, p: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(p).unwrap() {
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
    walk(dir, &dir.join("runs"), &mut out);
    out
}

fn reference() -> BTreeMap<String, Vec<u8>> {
    let d = project();
    let (rc, _, e) = run(d.path(), &[]);
    assert_eq!(rc, 0, "{e}");
    tree(d.path())
}

fn assert_same(got: &BTreeMap<String, Vec<u8>>, want: &BTreeMap<String, Vec<u8>>, what: &str) {
    let gk: Vec<_> = got.keys().collect();
    let wk: Vec<_> = want.keys().collect();
    assert_eq!(gk, wk, "{what}: different files");
    for (k, v) in want {
        assert!(got[k] == *v, "{what}: {k} differs");
    }
}

#[test]
fn second_run_runs_nothing_and_says_so() {
    let d = project();
    let (rc, out, err) = run(d.path(), &["--jobs", "2"]);
    assert_eq!(rc, 0, "{err}");
    assert_eq!(
        ran(&out),
        ["final", "gen", "side", "step@r1", "step@r2", "step@r3"]
    );
    let lock1 = std::fs::read_to_string(d.path().join("dag.lock")).unwrap();
    let (rc, out, _) = run(d.path(), &[]);
    assert_eq!(rc, 0);
    assert!(ran(&out).is_empty(), "{out}");
    assert!(
        out.contains("nothing to run: all 6 stages up to date"),
        "{out}"
    );
    let lock2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("dag.lock")).unwrap()).unwrap();
    let lock1: serde_json::Value = serde_json::from_str(&lock1).unwrap();
    assert_eq!(lock1["stages"], lock2["stages"]);
    // Logs are on disk, one per stage.
    let log = std::fs::read_to_string(d.path().join(".pipeline/logs/step@r2.log")).unwrap();
    assert!(
        log.contains("# cmd: pipeline test-stage --input runs/r1")
            && log.contains("step 2 written"),
        "{log}"
    );
    // --force reruns the selection; a target selects its upstream only.
    let (rc, out, _) = run(d.path(), &["--force", "step@r1"]);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["gen", "step@r1"]);
}

#[test]
fn touching_one_param_reruns_exactly_downstream() {
    let d = project();
    assert_eq!(run(d.path(), &[]).0, 0);
    let p = d.path().join("params.toml");
    std::fs::write(&p, PARAMS.replace("value = 2.0", "value = 2.5")).unwrap();
    let st = pipeline(d.path(), &["status", "--dag", "dag.toml"], &[]);
    let st = String::from_utf8_lossy(&st.stdout);
    assert!(
        st.contains("stale       side: changed cmd, changed params b.value"),
        "{st}"
    );
    assert!(
        st.contains("stale       final: upstream side is stale"),
        "{st}"
    );
    assert!(st.contains("up to date  step@r3"), "{st}");
    let (_, out, _) = run(d.path(), &["--dry-run"]);
    assert!(
        out.contains("would run   side") && out.contains("would run   final"),
        "{out}"
    );
    assert_eq!(
        run(d.path(), &["--dry-run"]).1.matches("would run").count(),
        2
    );
    let (rc, out, _) = run(d.path(), &[]);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["final", "side"]);
    std::fs::write(
        &p,
        PARAMS
            .replace("value = 1.0", "value = 1.5")
            .replace("value = 2.0", "value = 2.5"),
    )
    .unwrap();
    let (_, out, _) = run(d.path(), &[]);
    assert_eq!(ran(&out), ["final", "gen", "step@r1", "step@r2", "step@r3"]);
    // A deleted output reruns its stage only (its bytes come back identical, so the
    // downstream stages stay up to date).
    std::fs::remove_dir_all(d.path().join("runs/r2")).unwrap();
    let st = pipeline(d.path(), &["status", "--dag", "dag.toml"], &[]);
    assert!(
        String::from_utf8_lossy(&st.stdout).contains("stale       step@r2: missing output runs/r2")
    );
    let (_, out, _) = run(d.path(), &[]);
    assert_eq!(ran(&out), ["step@r2"]);
}

#[test]
fn failed_stage_blocks_downstream_keeps_no_partial_output_and_resumes() {
    let d = project();
    let dag = d.path().join("dag.toml");
    std::fs::write(
        &dag,
        DAG.replace("--seed 1 --value", "--fail --seed 1 --value"),
    )
    .unwrap();
    let (rc, out, _) = run(d.path(), &[]);
    assert_eq!(rc, 1, "{out}");
    assert!(
        out.contains("FAILED      side") && out.contains("exited with status 1"),
        "{out}"
    );
    assert!(!d.path().join("runs/final").exists());
    let leftovers: Vec<_> = std::fs::read_dir(d.path().join("runs"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    // Without --keep-going the run stops at the failure (jobs 1, file order: gen, side).
    assert!(ran(&out).len() <= 1, "{out}");
    let (rc, out, _) = run(d.path(), &["--keep-going"]);
    assert_eq!(rc, 1);
    assert!(
        out.contains("done        step@r3") && !out.contains("done        final"),
        "{out}"
    );
    let lock = std::fs::read_to_string(d.path().join("dag.lock")).unwrap();
    assert!(lock.contains("\"status\": \"failed\""), "{lock}");
    std::fs::write(&dag, DAG).unwrap();
    let (rc, out, _) = run(d.path(), &[]);
    assert_eq!(rc, 0);
    assert_eq!(ran(&out), ["final", "side"]);
    assert_same(&tree(d.path()), &reference(), "after fixing the failure");
}

/// Wall time of one uninterrupted run on this machine: kill points are spread over it
/// so that they land inside a run however fast or loaded the machine is.
fn uninterrupted_run_time() -> Duration {
    let d = project();
    let start = std::time::Instant::now();
    let (rc, _, err) = run(d.path(), &["--jobs", "1"]);
    assert_eq!(rc, 0, "{err}");
    start.elapsed()
}

/// Kill the whole runner (process group: runner, shells, stages) at many points of a
/// run, then rerun: the outputs equal an uninterrupted run's, byte for byte.
#[test]
fn kill_runner_at_many_points_then_rerun_is_byte_identical() {
    let want = reference();
    let window = uninterrupted_run_time().mul_f64(0.8);
    let mut interrupted = 0;
    for k in 0..24u64 {
        let d = project();
        let jobs = if k % 3 == 2 { "2" } else { "1" };
        let mut child = Command::new(BIN)
            .args(["run", "--dag", "dag.toml", "--jobs", jobs])
            .current_dir(d.path())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .process_group(0)
            .spawn()
            .unwrap();
        std::thread::sleep(window.mul_f64((k as f64 + 0.5) / 24.0));
        let pg = format!("-{}", child.id());
        let _ = Command::new("kill").args(["-KILL", "--", &pg]).status();
        let st = child.wait().unwrap();
        if !st.success() {
            interrupted += 1;
        }
        let (rc, _, err) = run(d.path(), &["--jobs", jobs]);
        assert_eq!(rc, 0, "kill point {k}: {err}");
        assert_same(&tree(d.path()), &want, &format!("kill point {k}"));
        let (_, out, _) = run(d.path(), &[]);
        assert!(out.contains("nothing to run"), "kill point {k}: {out}");
    }
    assert!(
        interrupted >= 15,
        "only {interrupted} of 24 runs were interrupted"
    );
}

/// Abort one stage at every step of its write (no cleanup runs in the stage, like a
/// SIGKILL), then rerun.
#[test]
fn stage_aborted_at_every_step_then_rerun_is_byte_identical() {
    let want = reference();
    for (out_dir, steps) in [("runs/r0", 3), ("runs/r2", 3), ("runs/final", 2)] {
        for step in 0..=steps {
            let d = project();
            let abort = format!("{out_dir}:{step}");
            let o = pipeline(
                d.path(),
                &["run", "--dag", "dag.toml", "--keep-going"],
                &[("PIPELINE_TEST_ABORT", &abort)],
            );
            let out = String::from_utf8_lossy(&o.stdout);
            assert_eq!(o.status.code(), Some(1), "{abort}: {out}");
            assert!(out.contains("killed by signal 6"), "{abort}: {out}");
            // The runner removed the aborted stage's staging directory.
            let parent = d.path().join(out_dir).parent().unwrap().to_path_buf();
            let left: Vec<_> = std::fs::read_dir(&parent)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with('.'))
                .collect();
            assert!(left.is_empty(), "{abort}: leftovers {left:?}");
            let (rc, _, err) = run(d.path(), &[]);
            assert_eq!(rc, 0, "{abort}: {err}");
            assert_same(&tree(d.path()), &want, &abort);
        }
    }
}

#[test]
fn malformed_dags_exit_2_naming_file_line_and_problem() {
    let cases: [(&str, &str); 6] = [
        (
            "[stages.a]\ncmd = \"a\"\ndeps = [\"b.out\"]\nouts = [\"a.out\"]\n[stages.b]\ncmd = \"b\"\ndeps = [\"a.out\"]\nouts = [\"b.out\"]\n",
            "dag.toml:5: dependency cycle: b -> a -> b",
        ),
        (
            "[stages.a]\ncmd = \"a\"\ndeps = [\"nowhere\"]\n",
            "dag.toml:3: dep `nowhere` of stage `a` does not exist and no stage produces it (missing producer)",
        ),
        (
            "[stages.a]\ncmd = \"a\"\nouts = [\"o\"]\n[stages.b]\ncmd = \"b\"\nouts = [\"o\"]\n",
            "dag.toml:6: output `o` of stage `b` is also written by stage `a` (`o`, line 3)",
        ),
        (
            "[stages.a]\ncmd = \"a\"\nout = [\"o\"]\n",
            "dag.toml:3: unknown field `out`",
        ),
        (
            "[stages.a]\ncmd = \"a ${nope}\"\n",
            "dag.toml:2: stage `a`: cmd: undefined variable `${nope}`",
        ),
        (
            "[stages.a]\nforeach = { from = 3, to = 1 }\ncmd = \"a\"\n",
            "dag.toml:2: stage `a`: bad foreach: range is empty (from = 3, to = 1)",
        ),
    ];
    for (text, want) in cases {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("dag.toml"), text).unwrap();
        for cmd in ["run", "status", "dag"] {
            let o = pipeline(d.path(), &[cmd, "--dag", "dag.toml"], &[]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{cmd} {want}: {err}");
            assert!(err.contains(want), "{cmd}: want {want:?}, got {err:?}");
        }
        assert!(
            !d.path().join(".pipeline").exists(),
            "nothing may run: {want}"
        );
    }
    let d = project();
    let o = pipeline(d.path(), &["run", "--dag", "dag.toml", "nope"], &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no stage named `nope`"));
}

#[test]
fn dag_dot_report_and_inspect() {
    let d = project();
    let o = pipeline(d.path(), &["dag", "--dag", "dag.toml", "--dot"], &[]);
    let dot = String::from_utf8_lossy(&o.stdout);
    assert!(
        dot.starts_with("digraph pipeline {") && dot.contains("\"step@r3\" -> \"final\";"),
        "{dot}"
    );
    let o = pipeline(d.path(), &["dag", "--dag", "dag.toml"], &[]);
    let txt = String::from_utf8_lossy(&o.stdout);
    assert!(
        txt.contains("final\n  after: side, step@r3\n  writes: runs/final"),
        "{txt}"
    );
    let st =
        String::from_utf8_lossy(&pipeline(d.path(), &["status", "--dag", "dag.toml"], &[]).stdout)
            .into_owned();
    assert!(
        st.contains("stale       gen: never run") && st.contains("6 of 6 stages stale"),
        "{st}"
    );
    assert_eq!(run(d.path(), &[]).0, 0);
    let rep =
        String::from_utf8_lossy(&pipeline(d.path(), &["report", "--dag", "dag.toml"], &[]).stdout)
            .into_owned();
    assert!(
        rep.contains("stages reporting timing: wall") && rep.contains("last run:"),
        "{rep}"
    );
    let png = d.path().join("final.png");
    let o = pipeline(
        d.path(),
        &[
            "inspect",
            "runs/final",
            "--png",
            png.to_str().unwrap(),
            "--mode",
            "grid",
        ],
        &[],
    );
    let txt = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        txt.contains("kind      latents") && txt.contains("latents.npy    [1, 2, 4, 4]"),
        "{txt}"
    );
    assert!(png.is_file());
    let o = pipeline(d.path(), &["inspect", "runs/final/part0.npy"], &[]);
    let txt = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success() && txt.starts_with("tensor ") && txt.contains("part0.npy      [32]"),
        "{txt}"
    );
    let o = pipeline(
        d.path(),
        &["inspect", "runs/final", "--png", "x.png", "--mode", "rgb"],
        &[],
    );
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr)
            .contains("rgb mode needs at least 3 channels, the tensor has 2")
    );
    let o = pipeline(d.path(), &["inspect", "runs/nope"], &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("runs/nope"));
}

/// The sample DAG parses and validates (with stand-ins for the sample files and model).
/// With no loop configured (params.toml's distill.chunks = 0) it is the method's walk,
/// five stages; `--set distill.chunks=2` adds the loop's stages (split, init, two chunks)
/// and the end resumes the last checkpoint.
#[test]
fn sample_dag_is_valid() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data-sample");
    let d = tempfile::tempdir().unwrap();
    let ds = d.path().join("data-sample");
    std::fs::create_dir_all(&ds).unwrap();
    std::fs::create_dir_all(d.path().join("vendor/models/stylizer")).unwrap();
    std::fs::write(d.path().join("vendor/models/stylizer/model.json"), "{}").unwrap();
    std::fs::create_dir_all(d.path().join("priors/patch")).unwrap();
    std::fs::write(d.path().join("priors/patch/model.json"), "{}").unwrap();
    for f in ["stylize.toml", "params.toml"] {
        std::fs::copy(src.join(f), ds.join(f)).unwrap();
    }
    for f in ["scene.ply", "cameras.json", "style.png"] {
        std::fs::write(ds.join(f), "x").unwrap();
    }
    let params = std::fs::read_to_string(ds.join("params.toml")).unwrap();
    assert!(
        params.lines().any(|l| l.trim() == "chunks = 0"),
        "params.toml's default runs no loop"
    );
    let stages = |sets: &[&str]| -> Vec<String> {
        let mut args = vec!["dag", "--dag", "stylize.toml"];
        for s in sets {
            args.extend(["--set", s]);
        }
        let o = pipeline(&ds, &args, &[]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| !l.starts_with(' ') && !l.is_empty())
            .map(|l| l.split("  --").next().unwrap_or(l).trim().to_string())
            .collect()
    };
    let mut end_only = stages(&[]);
    end_only.sort();
    assert_eq!(
        end_only,
        [
            "eval-source",
            "eval-style",
            "evaluate",
            "final-scene",
            "final-views",
            "source-views"
        ],
        "the default DAG"
    );
    let mut with_loop = stages(&["distill.chunks=2"]);
    with_loop.sort();
    assert_eq!(
        with_loop,
        [
            "distill@c1",
            "distill@c2",
            "eval-source",
            "eval-style",
            "evaluate",
            "final-scene-after-loop",
            "final-views",
            "init",
            "source-views",
            "split"
        ],
        "the DAG with a loop"
    );
}

#[test]
fn a_second_runner_is_refused_while_the_first_is_alive() {
    let d = project();
    std::fs::create_dir_all(d.path().join(".pipeline")).unwrap();
    // A live process (this test) holds the DAG.
    std::fs::write(
        d.path().join(".pipeline/run.pid"),
        std::process::id().to_string(),
    )
    .unwrap();
    let (rc, _, err) = run(d.path(), &[]);
    assert_eq!(rc, 2);
    assert!(err.contains("another pipeline run (pid"), "{err}");
    // A dead one (a killed runner) is taken over.
    std::fs::write(d.path().join(".pipeline/run.pid"), "4194999").unwrap();
    let (rc, _, err) = run(d.path(), &[]);
    assert_eq!(rc, 0, "{err}");
    assert!(!d.path().join(".pipeline/run.pid").exists());
}

/// Two independent stages that each wait for the other's marker file succeed only if
/// they run at the same time: `--jobs 2` runs them in parallel, `--jobs 1` does not.
/// A changed stage executable makes its stage stale.
#[test]
fn jobs_run_independent_stages_together_and_binaries_are_tracked() {
    let d = tempfile::tempdir().unwrap();
    let tool = d.path().join("tool.sh");
    std::fs::write(&tool, "#!/bin/sh\nmkdir -p \"$1\"\ntouch \"$1/mark\"\nfor i in $(seq 100); do [ -f \"$2/mark\" ] && exit 0; sleep 0.02; done\nexit 3\n").unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&tool, std::fs::Permissions::from_mode(0o755)).unwrap();
    std::fs::write(
        d.path().join("dag.toml"),
        "[stages.a]\ncmd = \"./tool.sh a b\"\nouts = [\"a\"]\n[stages.b]\ncmd = \"./tool.sh b a\"\nouts = [\"b\"]\n",
    )
    .unwrap();
    let (rc, out, _) = run(d.path(), &["--jobs", "2"]);
    assert_eq!(rc, 0, "{out}");
    assert_eq!(ran(&out), ["a", "b"]);
    let st = pipeline(d.path(), &["status", "--dag", "dag.toml"], &[]);
    assert!(String::from_utf8_lossy(&st.stdout).contains("0 of 2 stages stale"));
    std::fs::write(&tool, std::fs::read_to_string(&tool).unwrap() + "# v2\n").unwrap();
    let st = pipeline(d.path(), &["status", "--dag", "dag.toml"], &[]);
    let st = String::from_utf8_lossy(&st.stdout);
    assert!(
        st.contains("stale       a: changed binary") && st.contains("tool.sh"),
        "{st}"
    );
    std::fs::remove_dir_all(d.path().join("a")).unwrap();
    std::fs::remove_dir_all(d.path().join("b")).unwrap();
    let (rc, out, _) = run(d.path(), &["--jobs", "1"]);
    assert_eq!(rc, 1, "{out}");
    assert!(
        out.contains("FAILED      a") && out.contains("exited with status 3"),
        "{out}"
    );
}

/// Processes running `pipeline test-stage` with working directory `dir`.
fn stage_pids(dir: &Path) -> Vec<String> {
    let dir = std::fs::canonicalize(dir).unwrap();
    let mut v = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let pid = e.file_name().to_string_lossy().into_owned();
        if !pid.chars().all(|c| c.is_ascii_digit()) {
            continue;
        }
        let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        let is_stage = String::from_utf8_lossy(&cmd).contains("test-stage");
        if is_stage
            && std::fs::read_link(e.path().join("cwd")).ok().as_deref() == Some(dir.as_path())
        {
            v.push(pid);
        }
    }
    v
}

/// SIGKILL only the running stage process (the runner survives and must notice) at
/// many points of a run (a point between two stages kills the next one to start), then
/// rerun.
#[test]
fn kill_one_stage_at_many_points_then_rerun_is_byte_identical() {
    let want = reference();
    let window = uninterrupted_run_time().mul_f64(0.8);
    let mut killed = 0;
    for k in 0..12u64 {
        let d = project();
        let mut child = Command::new(BIN)
            .args(["run", "--dag", "dag.toml"])
            .current_dir(d.path())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(window.mul_f64((k as f64 + 0.5) / 12.0));
        // At the kill point, or at the next stage to start when the point fell between
        // two (a loaded machine stretches the runner's own steps), until the run ends.
        let deadline = std::time::Instant::now() + window;
        loop {
            let pids = stage_pids(d.path());
            for pid in &pids {
                if Command::new("kill")
                    .args(["-KILL", pid])
                    .status()
                    .unwrap()
                    .success()
                {
                    killed += 1;
                }
            }
            let ended = child.try_wait().unwrap().is_some();
            if !pids.is_empty() || ended || std::time::Instant::now() > deadline {
                break;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let out = child.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        if out.status.code() == Some(1) {
            assert!(
                text.contains("killed by signal 9"),
                "kill point {k}: {text}"
            );
        }
        let (rc, _, err) = run(d.path(), &[]);
        assert_eq!(rc, 0, "kill point {k}: {err}");
        assert_same(&tree(d.path()), &want, &format!("stage kill point {k}"));
    }
    assert!(
        killed >= 8,
        "only {killed} of 12 kill points hit a running stage"
    );
}

/// Every file name under `dir`, recursively.
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

/// Values are values: a scene path with spaces, an apostrophe, `$`, backticks and
/// non-ASCII letters, and a prompt that tries to close a quote and run a command, reach
/// the stage as exactly one argument each, unchanged; nothing else runs. The stage
/// (`args.sh`) records the arguments it got, NUL-separated.
#[test]
fn values_reach_the_stage_as_single_arguments_and_run_nothing() {
    let d = tempfile::tempdir().unwrap();
    let tool = d.path().join("args.sh");
    std::fs::write(
        &tool,
        "#!/bin/sh\nout=\"$1\"\nshift\nprintf '%s\\0' \"$@\" > \"$out\"\n",
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&tool, std::fs::Permissions::from_mode(0o755)).unwrap();
    let scene_dir = "my captures/it's $HOME `touch pwned2` ünïcødé";
    let scene = format!("{scene_dir}/cat's $(touch pwned3).splat");
    std::fs::create_dir_all(d.path().join(scene_dir)).unwrap();
    std::fs::write(d.path().join(&scene), "scene").unwrap();
    std::fs::write(
        d.path().join("dag.toml"),
        "[vars]\nprompt = \"\"\nscene = \"none\"\n[stages.a]\n\
         cmd = \"./args.sh got.bin --prompt ${prompt} --scene ${scene} --both=${prompt}\"\n\
         deps = [\"${scene}\"]\nouts = [\"got.bin\"]\n",
    )
    .unwrap();
    let prompt = "it's; touch pwned; echo '";
    let set_p = format!("prompt={prompt}");
    let set_s = format!("scene={scene}");
    let (rc, out, err) = run(d.path(), &["--set", &set_p, "--set", &set_s]);
    assert_eq!(rc, 0, "{out}\n{err}");
    let got = std::fs::read(d.path().join("got.bin")).unwrap();
    let got: Vec<&str> = std::str::from_utf8(&got)
        .unwrap()
        .split_terminator('\0')
        .collect();
    let both = format!("--both={prompt}");
    assert_eq!(got, ["--prompt", prompt, "--scene", &scene, &both]);
    let all = names(d.path());
    assert!(
        !all.iter().any(|n| n.starts_with("pwned")),
        "a value ran as a command: {all:?}"
    );
    // The same values again: up to date (the lock's command line is stable).
    let (rc, out, _) = run(d.path(), &["--set", &set_p, "--set", &set_s]);
    assert_eq!(rc, 0);
    assert!(out.contains("nothing to run"), "{out}");
    // The log shows the command as a shell would need it quoted.
    let log = std::fs::read_to_string(d.path().join(".pipeline/logs/a.log")).unwrap();
    let line = log.lines().find_map(|l| l.strip_prefix("# cmd: ")).unwrap();
    assert_eq!(
        shlex::split(line).unwrap(),
        [
            "./args.sh",
            "got.bin",
            "--prompt",
            prompt,
            "--scene",
            &scene,
            &both
        ]
    );
}

/// Shell syntax in a `cmd` is refused before anything runs (no shell would interpret
/// it), with the line and the way out.
#[test]
fn shell_syntax_in_cmd_is_refused() {
    let d = tempfile::tempdir().unwrap();
    for (cmd, what) in [
        ("mkdir -p o && touch o/x", "`&&`"),
        ("echo hi > o", "`>`"),
        ("A=1 prog", "env A=1"),
        ("sh -c 'echo ${v}'", "`sh -c` contains"),
    ] {
        std::fs::write(
            d.path().join("dag.toml"),
            format!(
                "[vars]\nv = \"x\"\n[stages.a]\ncmd = \"{}\"\nouts = [\"o\"]\n",
                cmd.replace('"', "\\\"")
            ),
        )
        .unwrap();
        let (rc, out, err) = run(d.path(), &[]);
        assert_eq!(rc, 2, "{cmd}: {out}\n{err}");
        assert!(
            err.contains("dag.toml:4: stage `a`: cmd:") && err.contains(what),
            "{cmd}: {err}"
        );
        assert!(!d.path().join("o").exists());
    }
}

//! Issue 14: the sample DAG exported to Snakemake and run by it through the real stage
//! binaries, at a small size, gives byte-identical outputs to `pipeline run`, and a
//! second Snakemake run does nothing. (The matrix DAG, `--set` reruns, kills and
//! refusals are tested on fake stages in pipeline/tests/snakemake.rs.)
//! The sizes are set with the params keys `render.width`, `render.height`,
//! `distill.chunks` and `distill.chunk` of data-sample/params.toml.

use crate::harness;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn snakemake() -> Option<PathBuf> {
    let p = match std::env::var_os("SNAKEMAKE") {
        Some(s) => PathBuf::from(s),
        None => harness::repo_root().join("vendor/venv/bin/snakemake"),
    };
    harness::need(
        format_args!("Snakemake at {} (or set SNAKEMAKE)", p.display()),
        p.is_file(),
    )
    .then_some(p)
}

/// blake3 of every file under `dir/runs` but Snakemake's `.snakemake_timestamp`.
fn tree(dir: &Path) -> BTreeMap<String, String> {
    fn walk(root: &Path, p: &Path, out: &mut BTreeMap<String, String>) {
        for e in std::fs::read_dir(p).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(root, &p, out);
            } else if p.file_name().unwrap() != ".snakemake_timestamp" {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, fantasystyle_schemas::hash_file(&p).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, &dir.join("runs"), &mut out);
    out
}

#[test]
fn sample_dag_under_snakemake_matches_pipeline_run() {
    let Some(smk) = snakemake() else { return };
    let pipeline = harness::pipeline_bin();
    let dag = harness::repo_root().join("data-sample/stylize.toml");
    let t = tempfile::tempdir().unwrap();
    let common: Vec<String> = [
        "--dag",
        dag.to_str().unwrap(),
        "--set",
        "render.width=40",
        "--set",
        "render.height=40",
        "--set",
        "distill.chunks=1",
        "--set",
        "distill.chunk=2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let run = |args: &[&str]| {
        let o = Command::new(&pipeline)
            .args(args)
            .args(&common)
            .current_dir(t.path())
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "pipeline {args:?}: {}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
    };
    run(&["run", "--workdir", "ref"]);
    run(&[
        "export",
        "--snakemake",
        "--workdir",
        "smk",
        "--out",
        "Snakefile",
    ]);
    let snake = || {
        let o = Command::new(&smk)
            .args(["-s", "Snakefile", "--cores", "2"])
            .current_dir(t.path())
            .output()
            .unwrap();
        let log = format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(o.status.success(), "{log}");
        log
    };
    snake();
    let want = tree(&t.path().join("ref"));
    assert!(want.len() > 40, "{:?}", want.keys());
    let got = tree(&t.path().join("smk"));
    assert_eq!(
        got.keys().collect::<Vec<_>>(),
        want.keys().collect::<Vec<_>>()
    );
    for (k, v) in &want {
        assert_eq!(&got[k], v, "{k} differs between Snakemake and pipeline run");
    }
    let log = snake();
    assert!(log.contains("Nothing to be done"), "{log}");
}

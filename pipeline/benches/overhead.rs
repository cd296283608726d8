//! Runner overhead, measured side by side in one run: a chain of K stages that do
//! nothing (`true`), K stages that write a small artifact (`pipeline test-stage`), and
//! the up-to-date check of the same DAG (a second run that runs nothing).
//! Prints a Markdown table: wall time of the run, the sum of the stages' own wall time
//! (from the lock), and the runner's share (hashing, lock writes, scheduling).
//!
//! `cargo bench -p fantasystyle-pipeline --bench overhead`

use std::path::Path;
use std::process::Command;
use std::time::Instant;

const BIN: &str = env!("CARGO_BIN_EXE_pipeline");
const K: usize = 20;

fn dag(cmd: &str) -> String {
    let mut s = String::from("[stages.s0]\n");
    s += &format!("cmd = \"{}\"\nouts = [\"o/0\"]\n", cmd.replace("{i}", "0"));
    for i in 1..K {
        s += &format!(
            "[stages.s{i}]\ncmd = \"{}\"\ndeps = [\"o/{}\"]\nouts = [\"o/{i}\"]\n",
            cmd.replace("{i}", &i.to_string()),
            i - 1
        );
    }
    s
}

fn run(dir: &Path) -> f64 {
    let t = Instant::now();
    let o = Command::new(BIN)
        .args(["run", "--dag", "dag.toml"])
        .current_dir(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    t.elapsed().as_secs_f64()
}

fn stage_sum(dir: &Path) -> f64 {
    let l: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("dag.lock")).unwrap()).unwrap();
    l["stages"]
        .as_object()
        .unwrap()
        .values()
        .map(|e| e["duration_s"].as_f64().unwrap())
        .sum()
}

fn main() {
    println!(
        "| scenario ({K} chained stages) | run wall s | stages' wall s | runner s | runner per stage ms |"
    );
    println!("|---|---:|---:|---:|---:|");
    for (name, cmd) in [
        ("no-op (`mkdir -p o/i`)", "mkdir -p o/{i}"),
        (
            "small artifact (`pipeline test-stage`)",
            "pipeline test-stage --steps 1 --out o/{i}",
        ),
    ] {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("dag.toml"), dag(cmd)).unwrap();
        let wall = run(d.path());
        let sum = stage_sum(d.path());
        println!(
            "| {name} | {wall:.3} | {sum:.3} | {:.3} | {:.1} |",
            wall - sum,
            1e3 * (wall - sum) / K as f64
        );
        let wall2 = run(d.path());
        println!(
            "| {name}, second run (all up to date) | {wall2:.3} | 0 | {wall2:.3} | {:.1} |",
            1e3 * wall2 / K as f64
        );
    }
}

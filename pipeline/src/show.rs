//! Read-only views of a DAG: `status` (what is stale and why), `dag` (the graph as
//! text or Graphviz DOT) and `report` (stage wall time against the compute time the
//! stages reported).
//!
//! Timing convention: the runner gives every stage the environment variable
//! `PIPELINE_TIMING_FILE`; a stage may write there a JSON object of seconds by phase,
//! e.g. `{"load_s": 0.8, "compute_s": 2.1, "io_s": 0.2}` (`load_s`: model and input
//! loading, `compute_s`: the numerical work, `io_s`: writing outputs). The runner stores
//! it in the lock entry beside the stage's measured wall time. Timing never goes into
//! artifact manifests, which must stay byte-identical between runs.

use crate::dag::Dag;
use crate::error::Result;
use crate::lock::Lock;
use crate::run::plan;
use crate::state::{Hasher, stage_path_env};
use std::fmt::Write;

/// `pipeline status`: one line per stage.
pub fn status(dag: &Dag) -> Result<String> {
    let lock = Lock::read(&dag.lock_path())?;
    let mut h = Hasher::new(stage_path_env());
    let all: Vec<usize> = (0..dag.stages.len()).collect();
    let mut out = String::new();
    let mut stale = 0;
    for (i, r) in plan(dag, &all, &lock, &mut h, false) {
        let name = &dag.stages[i].name;
        if r.is_empty() {
            let _ = writeln!(out, "up to date  {name}");
        } else {
            stale += 1;
            let why: Vec<String> = r.iter().map(|x| x.to_string()).collect();
            let _ = writeln!(out, "stale       {name}: {}", why.join(", "));
        }
    }
    let _ = writeln!(
        out,
        "{stale} of {} stages stale (lock: {})",
        dag.stages.len(),
        dag.lock_path().display()
    );
    Ok(out)
}

/// `pipeline dag`: stages in run order with what they wait for.
pub fn text(dag: &Dag) -> String {
    let mut out = String::new();
    for s in &dag.stages {
        let _ = write!(out, "{}", s.name);
        if let Some(d) = &s.desc {
            let _ = write!(out, "  -- {d}");
        }
        let _ = writeln!(out);
        let up: Vec<&str> = s
            .upstream
            .iter()
            .map(|&u| dag.stages[u].name.as_str())
            .collect();
        if !up.is_empty() {
            let _ = writeln!(out, "  after: {}", up.join(", "));
        }
        let ext: Vec<&str> = s
            .deps
            .iter()
            .filter(|d| {
                !dag.stages
                    .iter()
                    .any(|t| t.outs.iter().any(|o| o == *d || crate::dag::inside(d, o)))
            })
            .map(String::as_str)
            .collect();
        if !ext.is_empty() {
            let _ = writeln!(out, "  reads: {}", ext.join(", "));
        }
        if !s.outs.is_empty() {
            let _ = writeln!(out, "  writes: {}", s.outs.join(", "));
        }
    }
    out
}

/// `pipeline dag --dot`: Graphviz DOT, one node per stage, edges producer -> consumer.
pub fn dot(dag: &Dag) -> String {
    let q = |s: &str| format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""));
    let mut out = String::from("digraph pipeline {\n  rankdir=LR;\n  node [shape=box];\n");
    for s in &dag.stages {
        let label = match &s.desc {
            Some(d) => format!("{}\\n{}", s.name, d.replace('"', "'")),
            None => s.name.clone(),
        };
        let _ = writeln!(out, "  {} [label=\"{}\"];", q(&s.name), label);
    }
    for s in &dag.stages {
        for &u in &s.upstream {
            let _ = writeln!(out, "  {} -> {};", q(&dag.stages[u].name), q(&s.name));
        }
    }
    out.push_str("}\n");
    out
}

/// `pipeline report`: per stage wall time (from the lock) and reported phases; totals
/// and the share of wall time spent outside stage compute.
pub fn report(dag: &Dag) -> Result<String> {
    let lock = Lock::read(&dag.lock_path())?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<28} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "stage", "wall_s", "load_s", "compute_s", "io_s", "outside%"
    );
    let (mut wall, mut comp, mut wall_reported) = (0.0, 0.0, 0.0);
    for s in &dag.stages {
        let Some(e) = lock.stages.get(&s.name) else {
            let _ = writeln!(out, "{:<28} {:>9}", s.name, "never run");
            continue;
        };
        let g = |k: &str| e.timing.get(k).copied();
        let f = |v: Option<f64>| v.map(|x| format!("{x:.3}")).unwrap_or_else(|| "-".into());
        wall += e.duration_s;
        let share = g("compute_s").map(|c| {
            comp += c;
            wall_reported += e.duration_s;
            format!("{:.1}", 100.0 * (1.0 - c / e.duration_s.max(1e-9)))
        });
        let _ = writeln!(
            out,
            "{:<28} {:>9.3} {:>9} {:>9} {:>9} {:>9}",
            s.name,
            e.duration_s,
            f(g("load_s")),
            f(g("compute_s")),
            f(g("io_s")),
            share.unwrap_or_else(|| "-".into())
        );
    }
    let _ = writeln!(out, "total stage wall time: {wall:.3} s");
    if wall_reported > 0.0 {
        let _ = writeln!(
            out,
            "stages reporting timing: wall {wall_reported:.3} s, compute {comp:.3} s, outside compute {:.1}%",
            100.0 * (1.0 - comp / wall_reported)
        );
    } else {
        let _ = writeln!(out, "no stage reported timing (see PIPELINE_TIMING_FILE)");
    }
    if let Some(r) = &lock.last_run {
        let ran: f64 = r
            .ran
            .iter()
            .filter_map(|n| lock.stages.get(n))
            .map(|e| e.duration_s)
            .sum();
        // With parallel stages, stage times overlap and do not add up to wall time.
        let overhead = if r.jobs <= 1 {
            format!("{:.3} s", r.wall_s - ran)
        } else {
            "n/a with --jobs > 1".to_string()
        };
        let _ = writeln!(
            out,
            "last run: {:.3} s wall, {} stages run taking {ran:.3} s (jobs {}), runner overhead {overhead}",
            r.wall_s,
            r.ran.len(),
            r.jobs,
        );
    }
    Ok(out)
}

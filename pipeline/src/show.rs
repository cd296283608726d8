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
    phase_tables(dag, &lock, &mut out);
    Ok(out)
}

/// Key prefixes of a named phase's seconds, call count and process CPU seconds in a
/// stage's timing report.
const PHASE_PREFIX: &str = "phase:";
const CALLS_PREFIX: &str = "calls:";
const CPU_PREFIX: &str = "cpu:";

/// One table per stage (instances of a `foreach` stage, `NAME@ITEM`, summed under
/// `NAME`) that reported named phases (`"phase:A/B": seconds`, `"calls:A/B": n`,
/// `"cpu:A/B"`: process CPU seconds; a phase `A/B` ran inside `A`): each phase's wall
/// seconds, CPU seconds, calls, milliseconds per call and share of the stages' compute
/// time, children indented under their parent, largest first.
fn phase_tables(dag: &Dag, lock: &Lock, out: &mut String) {
    for (base, n, compute, phases) in phase_groups(dag, lock) {
        let _ = writeln!(
            out,
            "\nphases of {base}{} (wall time, nested phases included in their parent; compute {compute:.3} s):",
            if n > 1 {
                format!(" ({n} stages summed)")
            } else {
                String::new()
            }
        );
        let _ = writeln!(
            out,
            "  {:<44} {:>9} {:>9} {:>7} {:>9} {:>9}",
            "phase", "wall_s", "cpu_s", "calls", "ms/call", "%compute"
        );
        phase_rows(&phases, compute, out);
    }
}

/// A phase's totals: (seconds, calls, cpu seconds), by phase name.
type Phases = std::collections::BTreeMap<String, (f64, f64, Option<f64>)>;

/// The phases reported by the lock's stages, summed per base name (`NAME` of
/// `NAME@ITEM`), in DAG order: (base name, instances, compute s, phases).
fn phase_groups(dag: &Dag, lock: &Lock) -> Vec<(String, usize, f64, Phases)> {
    let mut groups: Vec<(String, usize, f64, Phases)> = Vec::new();
    for s in &dag.stages {
        let Some(e) = lock.stages.get(&s.name) else {
            continue;
        };
        if !e.timing.keys().any(|k| k.starts_with(PHASE_PREFIX)) {
            continue;
        }
        let base = s.name.split('@').next().unwrap_or(&s.name).to_string();
        let i = match groups.iter().position(|g| g.0 == base) {
            Some(i) => i,
            None => {
                groups.push((base, 0, 0.0, Phases::new()));
                groups.len() - 1
            }
        };
        let g = &mut groups[i];
        g.1 += 1;
        g.2 += e.timing.get("compute_s").copied().unwrap_or(0.0);
        for (k, v) in &e.timing {
            if let Some(name) = k.strip_prefix(PHASE_PREFIX) {
                let calls = e.timing.get(&format!("{CALLS_PREFIX}{name}")).copied();
                let cpu = e.timing.get(&format!("{CPU_PREFIX}{name}")).copied();
                let p = g.3.entry(name.to_string()).or_insert((0.0, 0.0, Some(0.0)));
                p.0 += v;
                p.1 += calls.unwrap_or(0.0);
                p.2 = p.2.zip(cpu).map(|(a, b)| a + b);
            }
        }
    }
    groups
}

/// A phase and its totals.
type Row<'a> = (&'a String, (f64, f64, Option<f64>));

/// The phases directly below `parent` (the roots for `None`), largest first.
fn children<'a>(phases: &'a Phases, parent: Option<&str>) -> Vec<Row<'a>> {
    let mut c: Vec<_> = phases
        .iter()
        .filter(|(k, _)| match parent {
            None => !k.contains('/'),
            Some(p) => k
                .strip_prefix(p)
                .and_then(|r| r.strip_prefix('/'))
                .is_some_and(|r| !r.contains('/')),
        })
        .map(|(k, v)| (k, *v))
        .collect();
    c.sort_by(|a, b| b.1.0.total_cmp(&a.1.0));
    c
}

/// The rows of one table: depth first from the roots, children largest first (phases
/// whose parent was never reported at the top level).
fn phase_rows(phases: &Phases, compute: f64, out: &mut String) {
    let mut stack: Vec<(Row<'_>, usize)> = children(phases, None)
        .into_iter()
        .rev()
        .map(|r| (r, 0))
        .collect();
    for (k, v) in phases {
        if let Some((parent, _)) = k.rsplit_once('/')
            && !phases.contains_key(parent)
        {
            stack.insert(0, ((k, *v), 0));
        }
    }
    while let Some(((name, (secs, calls, cpu)), depth)) = stack.pop() {
        let leaf = if depth == 0 {
            name.as_str()
        } else {
            name.rsplit('/').next().unwrap_or(name)
        };
        let label = format!("{}{leaf}", "  ".repeat(depth));
        let per_call = if calls > 0.0 {
            format!("{:.2}", 1e3 * secs / calls)
        } else {
            "-".into()
        };
        let share = if compute > 0.0 {
            format!("{:.1}", 100.0 * secs / compute)
        } else {
            "-".into()
        };
        let cpu = cpu.map_or_else(|| "-".to_string(), |c| format!("{c:.2}"));
        let _ = writeln!(
            out,
            "  {label:<44} {secs:>9.3} {cpu:>9} {calls:>7} {per_call:>9} {share:>9}"
        );
        for r in children(phases, Some(name)).into_iter().rev() {
            stack.push((r, depth + 1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lock::{Binary, Entry, Status};
    use std::collections::BTreeMap;
    use std::path::Path;

    fn entry(timing: &[(&str, f64)]) -> Entry {
        Entry {
            cmd: String::new(),
            binary: Binary {
                path: "x".into(),
                blake3: "unresolved".into(),
            },
            deps: BTreeMap::new(),
            params: BTreeMap::new(),
            outs: BTreeMap::new(),
            status: Status::Ok,
            duration_s: 10.0,
            exit_code: Some(0),
            finished_unix: 0,
            log: String::new(),
            timing: timing.iter().map(|(k, v)| (k.to_string(), *v)).collect(),
            files: BTreeMap::new(),
        }
    }

    #[test]
    fn phase_tables_sum_instances_and_nest_children_largest_first() {
        let dag = crate::dag::parse(
            r#"
[stages.d]
foreach = { from = 1, to = 2, prefix = "c" }
cmd = "d ${item}"
outs = ["o${item}"]
[stages.plain]
cmd = "p"
outs = ["p"]
"#,
            Path::new("dag.toml"),
            Path::new("."),
        )
        .unwrap();
        let mut lock = Lock::default();
        let t = [
            ("compute_s", 8.0),
            ("phase:csd", 4.0),
            ("calls:csd", 10.0),
            ("cpu:csd", 7.5),
            ("phase:csd/prior b", 1.0),
            ("calls:csd/prior b", 10.0),
            ("phase:csd/prior a", 3.0),
            ("calls:csd/prior a", 20.0),
            ("phase:render", 2.0),
            ("calls:render", 40.0),
        ];
        lock.stages.insert("d@c1".into(), entry(&t));
        lock.stages.insert("d@c2".into(), entry(&t));
        lock.stages
            .insert("plain".into(), entry(&[("compute_s", 1.0)]));
        let mut out = String::new();
        phase_tables(&dag, &lock, &mut out);
        assert!(out.contains("phases of d (2 stages summed)"), "{out}");
        assert!(!out.contains("phases of plain"), "{out}");
        let lines: Vec<&str> = out.lines().collect();
        let at = |name: &str| {
            lines
                .iter()
                .position(|l| l.trim_start().starts_with(name))
                .unwrap_or_else(|| panic!("no `{name}` in\n{out}"))
        };
        // Largest first, children under their parent, indented.
        assert!(at("csd") < at("prior a") && at("prior a") < at("prior b"));
        assert!(at("prior b") < at("render"), "{out}");
        assert!(lines[at("prior a")].starts_with("    prior a"), "{out}");
        // Summed over the two instances: 8 s of csd, 15 CPU-s, 20 calls, 400 ms per
        // call, 50%; no CPU figure where a stage reported none.
        let csd: Vec<&str> = lines[at("csd")].split_whitespace().collect();
        assert_eq!(
            csd,
            ["csd", "8.000", "15.00", "20", "400.00", "50.0"],
            "{out}"
        );
        let render: Vec<&str> = lines[at("render")].split_whitespace().collect();
        assert_eq!(render[2], "-", "{out}");
    }
}

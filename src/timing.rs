//! Phase timing for stage binaries, reported to the DAG runner.
//!
//! The runner sets `PIPELINE_TIMING_FILE` for every stage it starts. A stage marks the
//! time it spends loading models and inputs with [`load`] and writing outputs with
//! [`io`]; [`crate::stages::run_main`] then writes `{"load_s", "io_s", "compute_s",
//! "total_s"}` there, where `compute_s = total_s - load_s - io_s` is the numerical work.
//! `pipeline report` sets the stages' compute time against the run's wall time to give
//! the share spent outside compute (process start, model loading, artifact I/O).
//!
//! Named phases ([`phase`]) break the work down further (say `distill`'s render,
//! encode, prior calls, colour step): each adds `"phase:NAME"` (seconds, summed over
//! calls), `"cpu:NAME"` (the process's CPU seconds, user + system of all its threads,
//! during those calls, from `/proc/self/stat` at 10 ms resolution: on a machine shared
//! with other work this is the steadier figure) and `"calls:NAME"` (how many calls) to
//! the report, which `pipeline report` lists under the stage. A phase started while another runs on the same thread is
//! named `OUTER/INNER`, so the library can time its own parts (the prior's network
//! calls) and they show up inside whatever the stage wrapped around them. Times are
//! wall-clock on the calling thread and include nested phases; call [`phase`] from the
//! sequential part of a stage, not from inside parallel loops (their workers would
//! report concurrent time as if it were sequential).
//! Timing never goes into artifacts, which must stay byte-identical between runs.

use std::cell::RefCell;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Environment variable through which the runner asks for a timing report.
pub const TIMING_ENV: &str = "PIPELINE_TIMING_FILE";

/// Key prefix of a phase's seconds in the report.
pub const PHASE_PREFIX: &str = "phase:";
/// Key prefix of a phase's call count in the report.
pub const CALLS_PREFIX: &str = "calls:";
/// Key prefix of a phase's process CPU seconds in the report.
pub const CPU_PREFIX: &str = "cpu:";

static LOAD_NS: AtomicU64 = AtomicU64::new(0);
static IO_NS: AtomicU64 = AtomicU64::new(0);

/// One named phase's totals.
#[derive(Debug, Clone, PartialEq)]
pub struct Phase {
    /// Full name (`OUTER/INNER` when nested).
    pub name: String,
    /// Wall-clock seconds.
    pub secs: f64,
    /// Process CPU seconds (user + system, all threads); `None` where unknown.
    pub cpu_secs: Option<f64>,
    pub calls: u64,
}

/// Named phases in the order they were first seen.
static PHASES: Mutex<Vec<Phase>> = Mutex::new(Vec::new());

/// CPU seconds (user + system) this process has used, from `/proc/self/stat` (clock
/// ticks, taken as 100 per second as on every Linux); `None` elsewhere.
pub fn process_cpu_secs() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces):
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    let rest = s.rsplit_once(')')?.1;
    let mut f = rest.split_whitespace().skip(11);
    let u: f64 = f.next()?.parse().ok()?;
    let k: f64 = f.next()?.parse().ok()?;
    Some((u + k) / 100.0)
}

thread_local! {
    /// The full name of the phase running on this thread (nesting).
    static CURRENT: RefCell<Option<String>> = const { RefCell::new(None) };
}

fn timed<T>(acc: &AtomicU64, f: impl FnOnce() -> T) -> T {
    let t = Instant::now();
    let r = f();
    acc.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
    r
}

/// Run `f`, counting its time as loading (models, input artifacts).
pub fn load<T>(f: impl FnOnce() -> T) -> T {
    timed(&LOAD_NS, f)
}

/// Run `f`, counting its time as output I/O (writing artifacts).
pub fn io<T>(f: impl FnOnce() -> T) -> T {
    timed(&IO_NS, f)
}

/// Run `f` as phase `name` (module docs): its wall time and one call are added to the
/// phase `OUTER/name` when called inside phase `OUTER` on the same thread, else `name`.
pub fn phase<T>(name: &str, f: impl FnOnce() -> T) -> T {
    let s = span(name);
    let r = f();
    drop(s);
    r
}

/// Start phase `name` (as [`phase`]); it ends when the returned guard is dropped (at the
/// end of the scope, or by `drop`), so a block of code can be timed by adding one line
/// before it and one after. Guards must end in the reverse order they started.
pub fn span(name: &str) -> Span {
    let full = CURRENT.with(|c| match c.borrow().as_deref() {
        Some(outer) => format!("{outer}/{name}"),
        None => name.to_string(),
    });
    let outer = CURRENT.with(|c| c.replace(Some(full.clone())));
    Span {
        full,
        outer,
        start: Instant::now(),
        cpu: process_cpu_secs(),
    }
}

/// A running phase ([`span`]); recorded when dropped.
#[derive(Debug)]
#[must_use = "the phase ends when this guard is dropped"]
pub struct Span {
    full: String,
    outer: Option<String>,
    start: Instant,
    cpu: Option<f64>,
}

impl Drop for Span {
    fn drop(&mut self) {
        let secs = self.start.elapsed().as_secs_f64();
        let cpu = match (self.cpu, process_cpu_secs()) {
            (Some(a), Some(b)) => Some((b - a).max(0.0)),
            _ => None,
        };
        let outer = self.outer.take();
        CURRENT.with(|c| *c.borrow_mut() = outer);
        record(std::mem::take(&mut self.full), secs, cpu, 1);
    }
}

/// Add `d` (the sum of `calls` calls) to phase `name`, nested under the phase running
/// on this thread as [`phase`] does: for work done on worker threads, whose times the
/// caller sums and records from its own thread after the parallel part (such a phase
/// can take longer than its parent: it is time summed over workers; it has no CPU
/// figure).
pub fn add(name: &str, d: Duration, calls: u64) {
    let full = CURRENT.with(|c| match c.borrow().as_deref() {
        Some(outer) => format!("{outer}/{name}"),
        None => name.to_string(),
    });
    record(full, d.as_secs_f64(), None, calls);
}

fn record(name: String, secs: f64, cpu: Option<f64>, calls: u64) {
    let mut p = PHASES.lock().unwrap_or_else(|e| e.into_inner());
    match p.iter_mut().find(|e| e.name == name) {
        Some(e) => {
            e.secs += secs;
            e.cpu_secs = match (e.cpu_secs, cpu) {
                (Some(a), Some(b)) => Some(a + b),
                _ => None,
            };
            e.calls += calls;
        }
        None => p.push(Phase {
            name,
            secs,
            cpu_secs: cpu,
            calls,
        }),
    }
}

/// The phases recorded so far, in first-seen order.
pub fn phases() -> Vec<Phase> {
    PHASES.lock().unwrap_or_else(|e| e.into_inner()).clone()
}

/// The phase split of a run that took `total`.
pub fn report(total: Duration) -> serde_json::Value {
    let s = |ns: u64| ns as f64 * 1e-9;
    let load = s(LOAD_NS.load(Ordering::Relaxed));
    let io = s(IO_NS.load(Ordering::Relaxed));
    let total = total.as_secs_f64();
    let mut m = serde_json::Map::new();
    m.insert("load_s".into(), load.into());
    m.insert("io_s".into(), io.into());
    m.insert("compute_s".into(), (total - load - io).max(0.0).into());
    m.insert("total_s".into(), total.into());
    for p in phases() {
        m.insert(format!("{PHASE_PREFIX}{}", p.name), p.secs.into());
        m.insert(format!("{CALLS_PREFIX}{}", p.name), p.calls.into());
        if let Some(c) = p.cpu_secs {
            m.insert(format!("{CPU_PREFIX}{}", p.name), c.into());
        }
    }
    serde_json::Value::Object(m)
}

/// Write the report to `$PIPELINE_TIMING_FILE` when the runner asked for one.
pub(crate) fn write_if_requested(total: Duration) {
    if let Ok(path) = std::env::var(TIMING_ENV) {
        let path = std::path::PathBuf::from(path);
        if let Err(e) = fantasystyle_schemas::atomic_write_json(&path, &report(total)) {
            tracing::warn!("cannot write the timing report: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phases_add_up_to_the_total() {
        load(|| std::thread::sleep(Duration::from_millis(5)));
        io(|| std::thread::sleep(Duration::from_millis(5)));
        let r = report(Duration::from_millis(50));
        let (l, i, c) = (
            r["load_s"].as_f64().unwrap(),
            r["io_s"].as_f64().unwrap(),
            r["compute_s"].as_f64().unwrap(),
        );
        assert!(l >= 0.005 && i >= 0.005, "{r}");
        assert!((l + i + c - 0.05).abs() < 1e-9 || c == 0.0, "{r}");
    }

    #[test]
    fn named_phases_nest_count_and_sum() {
        // Names unique to this test: the registry is process-wide.
        for _ in 0..3 {
            phase("t-outer", || {
                std::thread::sleep(Duration::from_millis(2));
                phase("t-inner", || std::thread::sleep(Duration::from_millis(3)));
            });
        }
        // Not nested: another thread has no outer phase.
        std::thread::spawn(|| phase("t-inner", || ()))
            .join()
            .unwrap();
        let p = phases();
        let get = |n: &str| p.iter().find(|e| e.name == n).cloned();
        let outer = get("t-outer").expect("outer phase");
        let inner = get("t-outer/t-inner").expect("nested phase");
        assert_eq!((outer.calls, inner.calls), (3, 3));
        assert!(
            inner.secs >= 0.009 && outer.secs >= inner.secs + 0.006,
            "{p:?}"
        );
        // Process CPU time (other tests' threads included, so only its presence).
        assert!(outer.cpu_secs.is_some(), "{p:?}");
        assert_eq!(get("t-inner").map(|e| e.calls), Some(1));
        // A span guard nests the same way.
        {
            let _outer = span("t-span");
            phase("t-in-span", || ());
        }
        assert!(phases().iter().any(|e| e.name == "t-span/t-in-span"));
        phase("t-adds", || add("t-work", Duration::from_millis(7), 4));
        let w = phases()
            .into_iter()
            .find(|e| e.name == "t-adds/t-work")
            .unwrap();
        assert!((w.secs - 0.007).abs() < 1e-9 && w.calls == 4, "{w:?}");
        // After the phases the thread is outside any phase again.
        phase("t-after", || ());
        assert!(phases().iter().any(|e| e.name == "t-after"));
        let r = report(Duration::from_secs(1));
        assert_eq!(r["calls:t-outer/t-inner"].as_u64(), Some(3));
        assert!(r["phase:t-outer"].as_f64().unwrap() >= outer.secs);
        assert!(r["cpu:t-outer"].as_f64().is_some());
        assert!(process_cpu_secs().is_some_and(|c| c > 0.0));
    }
}

//! Phase timing for stage binaries, reported to the DAG runner.
//!
//! The runner sets `PIPELINE_TIMING_FILE` for every stage it starts. A stage marks the
//! time it spends loading models and inputs with [`load`] and writing outputs with
//! [`io`]; [`crate::stages::run_main`] then writes `{"load_s", "io_s", "compute_s",
//! "total_s"}` there, where `compute_s = total_s - load_s - io_s` is the numerical work.
//! `pipeline report` sets the stages' compute time against the run's wall time to give
//! the share spent outside compute (process start, model loading, artifact I/O).
//! Timing never goes into artifacts, which must stay byte-identical between runs.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Environment variable through which the runner asks for a timing report.
pub const TIMING_ENV: &str = "PIPELINE_TIMING_FILE";

static LOAD_NS: AtomicU64 = AtomicU64::new(0);
static IO_NS: AtomicU64 = AtomicU64::new(0);

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

/// The phase split of a run that took `total`.
pub fn report(total: Duration) -> serde_json::Value {
    let s = |ns: u64| ns as f64 * 1e-9;
    let load = s(LOAD_NS.load(Ordering::Relaxed));
    let io = s(IO_NS.load(Ordering::Relaxed));
    let total = total.as_secs_f64();
    serde_json::json!({
        "load_s": load,
        "io_s": io,
        "compute_s": (total - load - io).max(0.0),
        "total_s": total,
    })
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
}

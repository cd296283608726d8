//! One function per stage binary, plus the plumbing every binary shares: logging set-up,
//! error-to-exit-code mapping ([`run_main`]), phase timing for the DAG runner ([`timing`]).
//!
//! A stage binary is `fn main() -> ExitCode { run_main(Args::parse(), stage_fn) }`.

use std::process::ExitCode;

/// Initialise tracing (RUST_LOG, default `info`) to stderr.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}

/// Run a stage: set up logging, call `f`, print the error chain and map it to an exit
/// code (see [`crate::error`]).
pub fn run_main<A>(args: A, f: fn(A) -> crate::Result<()>) -> ExitCode {
    init_logging();
    let start = std::time::Instant::now();
    match f(args) {
        Ok(()) => {
            timing::write_if_requested(start.elapsed());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            let mut src = std::error::Error::source(&e);
            while let Some(s) = src {
                eprintln!("  caused by: {s}");
                src = s.source();
            }
            ExitCode::from(e.exit_code())
        }
    }
}

pub mod csd_step;
pub mod distill;
pub mod encode_latents;
pub mod evaluate;
pub mod make_sample;
pub mod mvfc_filter;
pub mod render_views;
pub mod stylize_baseline;
pub mod timing;
pub mod update_gaussians;

use crate::{Error, Result};
use std::path::Path;

/// Run `f` on a rayon pool of `threads` threads (0 = all cores).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Other(format!("cannot start {threads} threads: {e}")))?;
    Ok(pool.install(f))
}

/// Start an artifact at `out`, turning a failure (e.g. `--out` below a regular file, a
/// read-only directory) into an I/O error that names `out`. An existing artifact at
/// `out` is replaced on commit; a non-empty directory that is not an artifact is refused
/// by `ArtifactWriter::create` and reported here as a parameter error.
pub fn create_artifact(
    out: &Path,
    kind: fantasystyle_schemas::ArtifactKind,
    producer: fantasystyle_schemas::Producer,
) -> Result<fantasystyle_schemas::ArtifactWriter> {
    fantasystyle_schemas::ArtifactWriter::create(out, kind, producer).map_err(|e| {
        let kind = match &e {
            fantasystyle_schemas::SchemaError::Io { source, .. } => source.kind(),
            // A non-artifact directory that must not be replaced: a parameter error.
            fantasystyle_schemas::SchemaError::Invalid { .. } => {
                return Error::param(format!("--out {}: {e}", out.display()));
            }
            _ => std::io::ErrorKind::Other,
        };
        Error::io(
            out,
            std::io::Error::new(kind, format!("cannot create the output artifact: {e}")),
        )
    })
}

/// Record the `--cameras` spec as an input: a camera file or directory by its hash, a
/// generated `orbit:` spec by the hash of its text.
pub fn add_cameras_input(w: &mut fantasystyle_schemas::ArtifactWriter, spec: &str) -> Result<()> {
    if spec.starts_with("orbit:") {
        w.add_input_hash(
            "cameras",
            spec,
            blake3::hash(spec.as_bytes()).to_hex().to_string(),
        );
    } else {
        w.add_input("cameras", Path::new(spec))?;
    }
    Ok(())
}

/// Parse `R,G,B` (each in [0, 1]) for `--background`.
pub fn parse_rgb(s: &str) -> std::result::Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("`{s}` is not R,G,B"))?;
    match v.as_slice() {
        [r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([*r, *g, *b]),
        _ => Err(format!(
            "`{s}`: expected three values in [0, 1], e.g. 1,1,1"
        )),
    }
}

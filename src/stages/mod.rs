//! One function per stage binary, plus the plumbing every binary shares: logging set-up,
//! error-to-exit-code mapping ([`run_main`]).
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
    match f(args) {
        Ok(()) => ExitCode::SUCCESS,
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

pub mod evaluate;

//! `sweep`: thin binary over [`fantasystyle::metrics::sweep::run_sweep`].
use clap::Parser;
use fantasystyle::metrics::sweep::{SweepSpec, run_sweep};
use std::path::PathBuf;

/// The speed-accuracy sweep: run the stylization DAG at each point of a sweep spec
/// (params overrides: resolution, views per MVFC group, rounds, timestep range, ...),
/// record wall time and the evaluate metrics, and write OUT/sweep.json, sweep.md (table)
/// and sweep.html (table and wall-time-vs-metric plots).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// The sweep spec (TOML), e.g. data-sample/sweep.toml.
    #[arg(long)]
    spec: PathBuf,
    /// Output directory (one subdirectory per point).
    #[arg(long)]
    out: PathBuf,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        let spec = SweepSpec::load(&a.spec)?;
        let sweep = run_sweep(&spec, &a.out)?;
        print!("{}", sweep.markdown());
        Ok(())
    })
}

//! `sweep`: thin binary over [`fantasystyle::sweep::run_sweep`].
use clap::Parser;
use fantasystyle::sweep::{Sweep, SweepSpec, run_sweep, write_outputs};
use std::path::PathBuf;

/// The speed-accuracy sweep: run the stylization DAG at each point of a sweep spec
/// (params overrides: resolution, views per MVFC group, rounds, timestep range, ...),
/// record wall time and the evaluate metrics, and write OUT/sweep.json, sweep.md (table)
/// and sweep.html (table and wall-time-vs-metric plots).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {
    /// The sweep spec (TOML), e.g. data-sample/sweep.toml.
    #[arg(long, required_unless_present = "from_json")]
    spec: Option<PathBuf>,
    /// Only re-render sweep.md / sweep.html from an existing sweep.json (runs nothing).
    #[arg(long, conflicts_with = "spec")]
    from_json: Option<PathBuf>,
    /// Output directory (one subdirectory per point).
    #[arg(long)]
    out: PathBuf,
}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |a| {
        let sweep = match (&a.spec, &a.from_json) {
            (_, Some(j)) => {
                let s = Sweep::load(j)?;
                write_outputs(&s, &a.out)?;
                s
            }
            (Some(spec), None) => run_sweep(&SweepSpec::load(spec)?, &a.out)?,
            (None, None) => unreachable!("clap requires --spec or --from-json"),
        };
        print!("{}", sweep.markdown());
        Ok(())
    })
}

//! `sweep`: the speed-accuracy sweep ([`crate::sweep`]): run the stylization DAG at each
//! point of a sweep spec, record wall time and the evaluate metrics, write the table and
//! plots; or re-render them from an existing `sweep.json`.

use crate::sweep::{Sweep, SweepSpec, run_sweep, write_outputs};
use crate::{Error, Result};
use std::path::PathBuf;

/// The speed-accuracy sweep: run the stylization DAG at each point of a sweep spec
/// (params overrides: resolution, iterations, views per iteration, MVFC off, ...),
/// record wall time and the evaluate metrics, and write OUT/sweep.json, sweep.md (table)
/// and sweep.html (table and wall-time-vs-metric plots).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "sweep", version)]
pub struct Args {
    /// The sweep spec (TOML), e.g. data-sample/sweep.toml.
    #[arg(long, required_unless_present = "from_json")]
    pub spec: Option<PathBuf>,
    /// Only re-render sweep.md / sweep.html from an existing sweep.json (runs nothing).
    #[arg(long, conflicts_with = "spec")]
    pub from_json: Option<PathBuf>,
    /// Output directory (one subdirectory per point).
    #[arg(long)]
    pub out: PathBuf,
}

/// The stage: run (or re-render) the sweep and print its table.
pub fn run(a: Args) -> Result<Sweep> {
    let sweep = match (&a.spec, &a.from_json) {
        (_, Some(j)) => {
            let s = Sweep::load(j)?;
            write_outputs(&s, &a.out)?;
            s
        }
        (Some(spec), None) => run_sweep(&SweepSpec::load(spec)?, &a.out)?,
        (None, None) => return Err(Error::param("give --spec or --from-json")),
    };
    print!("{}", sweep.markdown());
    Ok(sweep)
}

//! `make-sample`: write the deterministic sample of `data-sample/` (see
//! [`crate::sample`]): `scene.ply`, `cameras.json` (the orbit
//! [`crate::sample::SAMPLE_ORBIT`] at 256x256) and `style.png`.

use crate::Result;
use std::path::PathBuf;

/// Generate the sample scene (INRIA .ply, SH degree 1), its orbit cameras.json and a
/// procedurally painted style.png, deterministically.
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "make-sample", version)]
pub struct Args {
    /// Output directory (created if missing; the three files are written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the generator (the committed data-sample/ uses 0).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// The stage.
pub fn run(a: Args) -> Result<()> {
    crate::sample::write_sample(&a.out, a.seed)?;
    tracing::info!(
        "wrote scene.ply, cameras.json, style.png to {}",
        a.out.display()
    );
    Ok(())
}

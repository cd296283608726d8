//! `make-sample`: write the deterministic sample of `data-sample/` (see
//! [`crate::sample`]): `scene.ply`, `cameras.json` (the orbit
//! [`crate::sample::SAMPLE_ORBIT`] at 256x256) and `style.png`; or, with `--lettering`,
//! the lettering scene alone (a card box printed with words,
//! [`crate::sample::lettering_scene`]) as one INRIA `.ply`.

use crate::Result;
use std::path::PathBuf;

/// Generate the sample scene (INRIA .ply, SH degree 1), its orbit cameras.json and a
/// procedurally painted style.png, deterministically; or the lettering scene.
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "make-sample", version)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["out", "lettering"])))]
pub struct Args {
    /// Output directory of the sample (created if missing; the three files are written
    /// atomically).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Instead of the sample: write the lettering scene (a card box, its four sides printed
    /// with STYLE, KEEP, SPLAT, READ; 34,250 Gaussians, -y up) to this `.ply`.
    #[arg(long, value_name = "OUT.ply", conflicts_with = "out")]
    pub lettering: Option<PathBuf>,
    /// Seed of the generator (the committed data-sample/ uses 0).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// The stage.
pub fn run(a: Args) -> Result<()> {
    if let Some(path) = &a.lettering {
        crate::sample::write_lettering(path, a.seed)?;
        tracing::info!("wrote the lettering scene to {}", path.display());
    }
    if let Some(out) = &a.out {
        crate::sample::write_sample(out, a.seed)?;
        tracing::info!(
            "wrote scene.ply, cameras.json, style.png to {}",
            out.display()
        );
    }
    Ok(())
}

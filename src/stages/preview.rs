//! `preview`: the patch prior's own 2D stylization of chosen views, in seconds, before a
//! 3D run: the deterministic end of the default ([`crate::ends::patches`]) on the
//! views' images themselves instead of the Gaussians' colours
//! ([`crate::ends::patches::synthesize_images`]). Writes a `views` artifact (the
//! stylized rgb, the source views' depth and alpha, their cameras, PNG previews), which
//! `evaluate` and `pipeline inspect` read like any views; fitted by the frozen scene's
//! colours it is the 2D ceiling of what the Gaussians can hold.

use super::{ConfigArgs, Threads};
use crate::artifacts::read_views;
use crate::ends::patches::synthesize_images;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::PathBuf;

/// The prior's 2D stylization of views (patch synthesis on each image, all views matched
/// together): a quick look at a style before a 3D run. Writes a views artifact.
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "preview", version)]
pub struct Args {
    /// Views artifact of the scene (render-views): the images to stylize.
    #[arg(long)]
    pub source_views: PathBuf,
    /// Style image (PNG or JPEG, shorter side >= 64 px).
    #[arg(long)]
    pub style: PathBuf,
    /// The views to stylize, comma-separated indices (default: every view).
    #[arg(long, value_delimiter = ',')]
    pub views: Vec<usize>,
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Output views artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

/// The stage: read the views and the style, synthesise, write the views artifact.
pub fn run(a: Args) -> Result<()> {
    let config = a.config.load()?;
    let style = crate::imageio::load_style(&a.style, crate::imageio::MIN_STYLE_SIDE)?;
    let views = read_views(&a.source_views)?;
    let (n, h, w) = views.dim();
    let chosen: Vec<usize> = if a.views.is_empty() {
        (0..n).collect()
    } else {
        a.views.clone()
    };
    if let Some(&v) = chosen.iter().find(|&&v| v >= n) {
        return Err(Error::input(
            &a.source_views,
            format!("--views {v}: the artifact has {n} views"),
        ));
    }
    let src = views.source_views();
    let cams = views.cameras_per_view()?;
    let rgb: Vec<Vec<f32>> = chosen.iter().map(|&v| src.rgb[v].clone()).collect();
    let alpha: Vec<Vec<f32>> = chosen.iter().map(|&v| src.alpha[v].clone()).collect();
    let sizes = vec![(h, w); chosen.len()];
    let (bg, size, p) = (src.background, config.texture.style_size, &config.synthesis);
    let out = a
        .threads
        .install(|| synthesize_images(&rgb, &alpha, &sizes, &[(&style, 1.0)], bg, size, p))??;
    let params = serde_json::json!({"views": chosen, "synthesis": p, "style_size": size});
    let producer = Producer::new("preview", crate::VERSION, params);
    let mut art = super::create_artifact(&a.out, ArtifactKind::Views, producer)?;
    art.add_input("source-views", &a.source_views)?;
    art.add_input("style", &a.style)?;
    let m = chosen.len();
    let flat = |x: &[Vec<f32>]| x.concat();
    let depth: Vec<Vec<f32>> = chosen.iter().map(|&v| src.depth[v].clone()).collect();
    art.write_tensor("rgb.npy", &[m, h, w, 3], &flat(&out))?;
    art.write_tensor("depth.npy", &[m, h, w], &flat(&depth))?;
    art.write_tensor("alpha.npy", &[m, h, w], &flat(&alpha))?;
    let sub: Vec<crate::Camera> = chosen.iter().map(|&v| cams[v].clone()).collect();
    art.write_json("cameras.json", &crate::camera::inria::to_inria(&sub))?;
    for (i, img) in out.iter().enumerate() {
        art.write_bytes(
            &format!("view_{i:03}.png"),
            &crate::imageio::encode_png_rgb(img, w, h)?,
        )?;
    }
    crate::timing::io(|| art.commit())?;
    tracing::info!("wrote {} ({m} views)", a.out.display());
    Ok(())
}

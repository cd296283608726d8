//! `encode-latents`: VAE-encode a views artifact's renders to latents z0 (FantasyStyle
//! Sec. 4: every iteration starts from the latents of the current and the original
//! renders; the encoding is [`crate::distill::step::encode_views`], as in `distill`).
//!
//! Reads `rgb.npy` `[N, H, W, 3]` from a `views` artifact; with `--fill`, gives the
//! encoder what `distill` gives it: the object over a push-pull fill of its own colours
//! (the coverage is the views' `alpha.npy`, or with `--alpha-from` the source views',
//! as `distill` has it; [`crate::distill::step::prior_view`]).
//! Encodes with the model's VAE (posterior mean x scaling factor), `--batch` views per
//! call, and writes a `latents` artifact: `latents.npy` `[N, C, H/f, W/f]` f32 plus the
//! views' `cameras.json`, and the views' `meta.iteration` (a window of the stage chain).
//! The inputs recorded are the views artifact and the model's `model.json`.

use super::{Background, DeviceArg, Threads};
use crate::artifacts::{iteration_of, read_view_images, read_views};
use crate::distill::step;
use crate::distill::step::IterationWindow;
use crate::prior::manifest::ModelManifest;
use crate::prior::{self, PriorOptions};
use crate::runtime::Optimization;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use ndarray::{Array3, Array4, Axis};
use std::path::PathBuf;

/// VAE-encode a views artifact's renders into a latents artifact (latents.npy `[N,C,h,w]`).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "encode-latents", version)]
pub struct Args {
    /// Views artifact directory (rgb.npy `[N,H,W,3]` in `[0,1]`).
    #[arg(long)]
    pub views: PathBuf,
    /// Model directory holding model.json (e.g. vendor/models/gaussian-prior).
    #[arg(long)]
    pub model: PathBuf,
    /// Output latents artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
    #[command(flatten)]
    pub device: DeviceArg,
    /// Views per VAE call (0 = all at once; lower it to bound memory with real VAEs).
    /// distill encodes the source views a window's worth (the configuration's `views`) at a time
    /// and a window in one call.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Encode the object over a fill of its own colours (what distill's prior sees;
    /// needs the views' alpha.npy), not the render over its background.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub fill: bool,
    /// With --fill: take the coverage from this views artifact instead (its views of the
    /// window the views record in meta.iteration, else all in order). distill fills
    /// with the source views' coverage; the stage chain passes them.
    #[arg(long, requires = "fill")]
    pub alpha_from: Option<PathBuf>,
    /// The background the views were rendered over (removed by --fill).
    #[command(flatten)]
    pub background: Background,
}

/// What the encoder sees of each view ([`step::prior_view`]): the render, or with
/// `--fill` the object over a fill of its own colours with the coverage of the views
/// (or of `--alpha-from`'s views of the `window`).
fn seen(p: &Args, rgb: &Array4<f32>, window: Option<&IterationWindow>) -> Result<Vec<Array3<f32>>> {
    let (n, h, w, _) = rgb.dim();
    let alpha = match (p.fill, &p.alpha_from) {
        (false, _) => None,
        (true, None) => Some(read_views(&p.views)?.alpha),
        (true, Some(dir)) => {
            let a = read_views(dir)?.alpha;
            let rows: Vec<usize> = match window {
                Some(it) => it.window.views.clone(),
                None => (0..n).collect(),
            };
            if a.dim().1 != h || a.dim().2 != w || rows.iter().any(|&v| v >= a.dim().0) {
                return Err(Error::input(
                    dir.join("alpha.npy"),
                    format!(
                        "shape {:?} has no views {rows:?} of {h}x{w} to take the coverage from",
                        a.shape()
                    ),
                ));
            }
            Some(a.select(Axis(0), &rows))
        }
    };
    let plane = |x: ndarray::ArrayView<f32, _>| -> Vec<f32> { x.iter().copied().collect() };
    Ok((0..n)
        .map(|i| {
            let a = alpha
                .as_ref()
                .map(|a| plane(a.index_axis(Axis(0), i).into_dyn()));
            let rgb = plane(rgb.index_axis(Axis(0), i).into_dyn());
            step::prior_view(
                &rgb,
                &a.unwrap_or_default(),
                p.background.rgb,
                p.fill,
                (h, w),
            )
        })
        .collect())
}

/// The stage; returns the latents' shape.
pub fn run(p: Args) -> Result<[usize; 4]> {
    let (views, rgb) = read_view_images(&p.views)?;
    let rgb_path = views.path("rgb.npy");
    let (n, h, w, _) = rgb.dim();
    let md = ModelManifest::load(&p.model)?;
    let f = md.manifest.downsample.max(1);
    if h % f != 0 || w % f != 0 {
        return Err(Error::input(
            &rgb_path,
            format!(
                "image size {h}x{w} is not divisible by the model's downsampling factor {f} \
                 ({}); render at a multiple of {f}",
                md.manifest_path.display()
            ),
        ));
    }
    let iteration = iteration_of(&views)?;
    let images = seen(&p, &rgb, iteration.as_ref())?;
    let opts = PriorOptions {
        threads: p.threads.n,
        optimization: Optimization::All,
        device: p.device.device,
        ..Default::default()
    };
    let mut prior = crate::timing::load(|| prior::open(&md.dir, &opts))?;
    let lat = step::encode_views(prior.as_mut(), &images, p.batch)?;
    let shape = [lat.dim().0, lat.dim().1, lat.dim().2, lat.dim().3];
    let info = prior.info().clone();
    let params = serde_json::json!({
        "views": p.views, "model": p.model, "batch": p.batch, "fill": p.fill,
        "alpha_from": p.alpha_from, "background": p.background.rgb,
    });
    let mut wr = ArtifactWriter::create(
        &p.out,
        ArtifactKind::Latents,
        Producer::new("encode-latents", crate::VERSION, params),
    )?;
    wr.add_input("views", &p.views)?;
    if let Some(dir) = p.alpha_from.as_ref().filter(|_| p.fill) {
        wr.add_input("alpha-from", dir)?;
    }
    wr.add_input("model", &md.manifest_path)?;
    crate::artifacts::write_array(&mut wr, "latents.npy", &lat)?;
    let cams = views.path("cameras.json");
    let bytes = std::fs::read(&cams).map_err(|e| Error::io(&cams, e))?;
    wr.write_bytes("cameras.json", &bytes)?;
    wr.set_meta(serde_json::json!({
        "model": info.name,
        "family": md.manifest.family,
        "latent_channels": info.latent_channels,
        "downsample": info.downsample,
        "vae_scaling_factor": md.manifest.vae_scaling_factor,
        "image_size": [h, w],
        "fill": p.fill,
        "iteration": iteration,
    }));
    crate::timing::io(|| wr.commit())?;
    tracing::info!("encode-latents: {n} views -> latents {shape:?}");
    Ok(shape)
}

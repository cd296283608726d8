//! `encode-latents`: VAE-encode a views artifact's renders to latents z0 (FantasyStyle
//! Sec. 3.1: every iteration starts from the latents of the current and the original
//! renders).
//!
//! Reads `rgb.npy` `[N, H, W, 3]` in [0, 1] from a `views` artifact, encodes with the
//! model's VAE (posterior mean x scaling factor) in batches, and writes a `latents`
//! artifact: `latents.npy` `[N, C, H/f, W/f]` f32 plus the views' `cameras.json`. The
//! inputs recorded are the views artifact and the model's `model.json`.

use super::{DeviceArg, Threads};
use crate::artifacts::read_view_images;
use crate::prior::manifest::ModelManifest;
use crate::prior::{self, PriorOptions};
use crate::runtime::Optimization;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use indicatif::{ProgressBar, ProgressStyle};
use ndarray::{Axis, concatenate};
use std::path::PathBuf;

/// VAE-encode a views artifact's renders into a latents artifact (latents.npy [N,C,h,w]).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "encode-latents", version)]
pub struct Args {
    /// Views artifact directory (rgb.npy [N,H,W,3] in [0,1]).
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
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
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
    let images = rgb
        .view()
        .permuted_axes([0, 3, 1, 2])
        .as_standard_layout()
        .to_owned();
    let opts = PriorOptions {
        threads: p.threads.n,
        optimization: Optimization::All,
        device: p.device.device,
        ..Default::default()
    };
    let mut prior = crate::timing::load(|| prior::open(&md.dir, &opts))?;
    let batch = if p.batch == 0 { n } else { p.batch };
    let bar = ProgressBar::new(n as u64).with_style(
        ProgressStyle::with_template("encode-latents {bar:30} {pos}/{len} views {elapsed}")
            .expect("template"),
    );
    let mut parts = Vec::new();
    for chunk in images.axis_chunks_iter(Axis(0), batch) {
        parts.push(prior.encode(chunk)?);
        bar.inc(chunk.dim().0 as u64);
    }
    bar.finish_and_clear();
    let views_of: Vec<_> = parts.iter().map(|a| a.view()).collect();
    let lat = concatenate(Axis(0), &views_of).expect("same shapes");
    if let Some(x) = lat.iter().find(|x| !x.is_finite()) {
        return Err(Error::Onnx(format!("the VAE encoder produced {x}")));
    }
    let shape = [lat.dim().0, lat.dim().1, lat.dim().2, lat.dim().3];
    let info = prior.info().clone();
    let params = serde_json::json!({
        "views": p.views, "model": p.model, "batch": p.batch,
    });
    let mut wr = ArtifactWriter::create(
        &p.out,
        ArtifactKind::Latents,
        Producer::new("encode-latents", crate::VERSION, params),
    )?;
    wr.add_input("views", &p.views)?;
    wr.add_input("model", &md.manifest_path)?;
    let data = lat.as_standard_layout();
    wr.write_tensor(
        "latents.npy",
        &shape,
        data.as_slice().expect("standard layout"),
    )?;
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
    }));
    crate::timing::io(|| wr.commit())?;
    tracing::info!("encode-latents: {n} views -> latents {shape:?}");
    Ok(shape)
}

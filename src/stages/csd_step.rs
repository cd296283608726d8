//! `csd-step`: one controllable-stylized-distillation step (FantasyStyle Sec. 3.3; the
//! gradient is [`crate::csd`]) and the target images it implies for `update-gaussians`.
//!
//! Reads the `noised-latents` artifact of `mvfc-filter` (z_src, z_tgt, eps, t), the clean
//! target latents z0 (`latents` artifact of the current renders), the current renders
//! (`views`) and the original renders (`source-views`, for a ControlNet's control image:
//! the geometry is frozen, so depth is the original's), the model and the style image.
//! Computes z0' = z0 - lr w(t) g and writes a `targets` artifact:
//!
//! ```text
//! target = clamp(render + decode(z0') - decode(z0), 0, 1)
//! ```
//!
//! Why the difference of two decodes: decode(encode(render)) != render (an SD VAE loses
//! fine detail and shifts colours slightly), so decode(z0') alone would also ask the colour
//! fit to reproduce the VAE's reconstruction error. The difference is the change the prior
//! asks for, to first order J_dec (z0' - z0), with the reconstruction error cancelled; it is
//! exact for a linear decoder (the Gaussian prior's) and for the identity (the stylizer).
//! Clamping keeps targets in the renderer's displayable range, which the colour fit (with
//! SH DC colours passed through a clamp) can reach. Both decodes are one batched call.
//!
//! The artifact holds `rgb.npy` [N, H, W, 3], the views' `cameras.json` (copied),
//! `delta.npy` [N, H, W, 3] (target - render, for inspection) and PNG previews; `meta`
//! records t, the mode and the step's statistics.

use super::{DeviceArg, Threads};
use crate::artifacts::{read_latents, read_noised_latents, read_views};
use crate::csd::{self, CsdParams, StepInputs};
use crate::prior::cost::{CostModel, Plan};
use crate::prior::{self, PriorOptions, model_timesteps};
use crate::scheduler::Schedule;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use ndarray::{Array4, Axis};
use std::path::PathBuf;

/// One controllable stylized distillation (CSD) step: from noised latents (mvfc-filter),
/// the clean target latents and the renders, compute z0' = z0 - lr w(t) grad and write
/// target images render + decode(z0') - decode(z0) as a targets artifact
/// (rgb.npy [N,H,W,3], cameras.json, delta.npy, PNG previews).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "csd-step", version)]
pub struct Args {
    /// Noised-latents artifact from mvfc-filter (z_src, z_tgt, eps; meta.timestep).
    #[arg(long)]
    pub noised: PathBuf,
    /// Latents artifact of the current renders (the clean target latents z0).
    #[arg(long)]
    pub latents: PathBuf,
    /// Views artifact of the current renders (the targets are built on them; cameras copied).
    #[arg(long)]
    pub views: PathBuf,
    /// Views artifact of the original renders (control image for ControlNet priors).
    #[arg(long)]
    pub source_views: PathBuf,
    /// Model directory with model.json (e.g. vendor/models/stylizer, vendor/models/gaussian-prior).
    #[arg(long)]
    pub model: PathBuf,
    /// Style image (PNG or JPEG).
    #[arg(long)]
    pub style: PathBuf,
    /// The prompt P: any text for a model with a text encoder (else one of its exported
    /// prompts); default: the model's first exported prompt. Ignored by the stylizer.
    #[arg(long)]
    pub prompt: Option<String>,
    #[command(flatten)]
    pub params: CsdParams,
    /// Output targets artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
    #[command(flatten)]
    pub device: DeviceArg,
    /// Most UNet rows per call (rows = views x conditionings; 0 = automatic: all, unless
    /// the first level's attention scores would pass 2^31 floats, as SD 1.5 at 64x64
    /// latents with more than 4 rows).
    #[arg(long, default_value_t = 0)]
    pub unet_batch: usize,
}

/// Statistics of one step (also written to the artifact's meta).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StepReport {
    pub timestep: usize,
    pub grad_rms: f64,
    pub latent_step_rms: f64,
    pub image_delta_rms: f64,
    pub clamped_fraction: f64,
}

fn rms(a: impl Iterator<Item = f32>) -> f64 {
    let (mut s, mut n) = (0.0f64, 0usize);
    for v in a {
        s += (v as f64) * (v as f64);
        n += 1;
    }
    (s / n.max(1) as f64).sqrt()
}

/// The stage: read the inputs, step, write the targets artifact.
pub fn run(a: Args) -> Result<StepReport> {
    let p = a.params;
    if !(p.guidance.is_finite() && p.lr.is_finite() && p.lr >= 0.0) {
        return Err(Error::param(format!(
            "--guidance ({}) must be finite and --lr ({}) finite and >= 0",
            p.guidance, p.lr
        )));
    }
    // Inputs, checked against each other before the (slow) prior is loaded.
    let noised = read_noised_latents(&a.noised)?;
    let z0 = read_latents(&a.latents)?;
    if noised.z_src.shape() != z0.shape() {
        return Err(Error::input(
            noised.art.path("z_src.npy"),
            format!(
                "shape {:?} differs from the latents' {:?} ({})",
                noised.z_src.shape(),
                z0.shape(),
                a.latents.join("latents.npy").display()
            ),
        ));
    }
    let (z_src, z_tgt, eps, t) = (&noised.z_src, &noised.z_tgt, &noised.eps, noised.timestep);
    let views = crate::timing::load(|| read_views(&a.views))?;
    let source = crate::timing::load(|| read_views(&a.source_views))?;
    if views.rgb.shape() != source.rgb.shape() {
        return Err(Error::input(
            source.art.path("rgb.npy"),
            format!(
                "source views {:?} and views {:?} differ in shape",
                source.rgb.shape(),
                views.rgb.shape()
            ),
        ));
    }
    let (n, h, w) = (
        views.rgb.shape()[0],
        views.rgb.shape()[1],
        views.rgb.shape()[2],
    );
    if z0.shape()[0] != n {
        return Err(Error::input(
            views.art.path("rgb.npy"),
            format!("{n} views but {} latents", z0.shape()[0]),
        ));
    }
    let (_, set) = model_timesteps(&a.model)?;
    set.check(t).map_err(|e| {
        Error::input(
            noised.art.path("manifest.json"),
            format!("meta.timestep: {e}"),
        )
    })?;
    let style = crate::imageio::load_style(&a.style, crate::imageio::MIN_STYLE_SIDE)?
        .to_chw()
        .insert_axis(Axis(0));

    // The prior.
    let mut prior = crate::timing::load(|| {
        prior::open(
            &a.model,
            &PriorOptions {
                style_image: Some(style),
                prompt: a.prompt.clone(),
                threads: a.threads.n,
                device: a.device.device,
                unet_batch: a.unet_batch,
                ..Default::default()
            },
        )
    })?;
    let info = prior.info().clone();
    csd::check_mode(p.mode, &info)?;
    let f = info.downsample.max(1);
    if z0.shape()[1] != info.latent_channels || h != z0.shape()[2] * f || w != z0.shape()[3] * f {
        return Err(Error::input(
            a.latents.join("latents.npy"),
            format!(
                "latents {:?} do not fit model `{}` ({} channels, downsample {f}) and views {h}x{w}",
                z0.shape(),
                info.name,
                info.latent_channels
            ),
        ));
    }
    let schedule = Schedule::new(info.scheduler.clone())?;
    let control = match info.control {
        Some(kind) => Some(prior::control_image(
            kind,
            source.rgb.view(),
            source.depth.view(),
            source.alpha.view(),
        )?),
        None => None,
    };

    // What the step will cost (diffusion models), said before it starts.
    let (tc, sc) = csd::conds(p.mode);
    let plan = Plan {
        evaluations: 1,
        batch: n * (tc.len() + sc.len()),
        latent: (h / f, w / f),
        downsample: f,
        encodes: 0,
        decodes: 2 * n,
    };
    let mut cost = CostModel::for_model(&a.model, a.threads.n, a.device.device)?;
    if let Some(say) = cost.as_ref().and_then(|c| c.describe(&plan)) {
        tracing::info!(
            "csd-step: {n} views x {} conditionings at {}x{} latents: {say}",
            tc.len() + sc.len(),
            h / f,
            w / f
        );
    }

    // The step.
    let started = std::time::Instant::now();
    let (z1, g) = a.threads.install(|| {
        csd::step(
            prior.as_mut(),
            &schedule,
            StepInputs {
                z0: z0.view(),
                z_tgt: z_tgt.view(),
                z_src: z_src.view(),
                eps: eps.view(),
                z0_src: None,
                t,
                control: control.as_ref().map(|c| c.view()),
            },
            &p,
        )
    })??;
    let step_secs = started.elapsed().as_secs_f64();
    let started = std::time::Instant::now();
    let delta = crate::csd::image_change(prior.as_mut(), z1.view(), z0.view(), h, w)?;
    if let Some(c) = cost.as_mut() {
        c.calibrate_unet(plan.batch, plan.latent, step_secs);
        c.calibrate_vae(0, 2 * n, h * w, started.elapsed().as_secs_f64());
        tracing::info!(
            "csd-step: took {} ({:.3e} UNet and {:.3e} VAE work units/s here; see \
             prior::cost)",
            crate::prior::cost::about(c.seconds(&plan)),
            c.unet_rate,
            c.vae_rate
        );
    }
    let delta_nhwc = delta.permuted_axes([0, 2, 3, 1]);
    let raw = &views.rgb + &delta_nhwc;
    let clamped = raw.iter().filter(|v| !(0.0..=1.0).contains(*v)).count();
    let target = raw.mapv(|v| v.clamp(0.0, 1.0));
    let applied = &target - &views.rgb;
    if target.iter().any(|v| !v.is_finite()) {
        return Err(Error::Other(
            "target images are not finite (prior or decoder output NaN)".into(),
        ));
    }
    let report = StepReport {
        timestep: t,
        grad_rms: rms(g.iter().copied()),
        latent_step_rms: rms(z1.iter().zip(z0.iter()).map(|(a, b)| a - b)),
        image_delta_rms: rms(applied.iter().copied()),
        clamped_fraction: clamped as f64 / raw.len() as f64,
    };
    tracing::info!(
        "csd-step: t = {t}, mode {:?}, |grad| {:.4}, |dz0| {:.4}, |d image| {:.4}, clamped {:.2}%",
        p.mode,
        report.grad_rms,
        report.latent_step_rms,
        report.image_delta_rms,
        100.0 * report.clamped_fraction
    );

    // The artifact.
    let params = serde_json::json!({
        "mode": p.mode, "guidance": p.guidance, "weighting": p.weighting, "lr": p.lr,
        "prompt": a.prompt,
    });
    let mut wr = ArtifactWriter::create(
        &a.out,
        ArtifactKind::Targets,
        Producer::new("csd-step", crate::VERSION, params),
    )?;
    wr.add_input("noised", &a.noised)?;
    wr.add_input("latents", &a.latents)?;
    wr.add_input("views", &a.views)?;
    wr.add_input("source-views", &a.source_views)?;
    wr.add_input("style", &a.style)?;
    let mpath = if a.model.is_file() {
        a.model.clone()
    } else {
        a.model.join("model.json")
    };
    wr.add_input("model", &mpath)?;
    let flat = |x: &Array4<f32>| x.as_standard_layout().iter().copied().collect::<Vec<_>>();
    wr.write_tensor("rgb.npy", &[n, h, w, 3], &flat(&target))?;
    wr.write_tensor("delta.npy", &[n, h, w, 3], &flat(&applied))?;
    let cams = std::fs::read(views.art.path("cameras.json"))
        .map_err(|e| Error::io(views.art.path("cameras.json"), e))?;
    wr.write_bytes("cameras.json", &cams)?;
    for i in 0..n {
        let bytes: Vec<u8> = target
            .index_axis(Axis(0), i)
            .iter()
            .map(|v| (v * 255.0 + 0.5) as u8)
            .collect();
        wr.write_with(&format!("target_{i:03}.png"), |path| {
            image::save_buffer(path, &bytes, w as u32, h as u32, image::ColorType::Rgb8)
                .map_err(|e| e.to_string())
        })?;
    }
    wr.set_meta(serde_json::json!({
        "timestep": t,
        "mode": p.mode,
        "report": report,
    }));
    crate::timing::io(|| wr.commit())?;
    Ok(report)
}

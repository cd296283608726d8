//! `csd-step`: one controllable-stylized-distillation step (FantasyStyle Sec. 4, CSD; the
//! gradient is [`crate::csd`]) and the colour targets it implies for `update-gaussians`,
//! as `distill` computes them ([`crate::distill::step`]: [`control`], [`prior_change`],
//! [`targets`]).
//!
//! Reads the `noised-latents` of `mvfc-filter` (z_tgt, z_src, eps, t), the clean latents
//! z0 of the window's renders (`latents`), the window's renders (`views`, `render-views
//! --window`), the original renders (`source-views`: their alpha composites the targets,
//! their colour is kept by `preserve_color`, and a ControlNet's control image is made
//! from them, the geometry being frozen) and their latents (`source-latents`: z0_src of
//! the window's views), the model and the style image. The iteration's window is the one
//! the inputs record (`meta.iteration`; all must agree); inputs that record none are one
//! window of all their views.
//!
//! Computes z0' = z0 - lr w(t) g, the image change Delta = decode(z0') - decode(z0)
//! (the difference of two decodes, so that the VAE's reconstruction error cancels), and
//! the targets render + alpha (c' - c), c' = c + Delta (module docs of
//! [`crate::distill`]). Writes a `targets` artifact: `rgb.npy` [N, H, W, 3] (the targets;
//! not clamped to [0, 1] where the render is not), `delta.npy` [N, H, W, 3] (target -
//! render), the views' `cameras.json`, PNG previews, and `meta`: the iteration, t, the
//! mode and the step's statistics.

use super::{Background, ConfigArgs, PriorArgs, Threads};
use crate::artifacts::{
    Views, agreed_iteration, iteration_of, open_latents, read_latents, read_noised_latents,
    read_views, window_rows,
};
use crate::csd;
use crate::distill::step::{
    IterLatents, IterationWindow, TargetParams, TargetStats, control, prior_change, targets,
};
use crate::distill::{Config, SourceViews};
use crate::prior::cost::{CostModel, Plan, about, announce};
use crate::scheduler::Schedule;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use ndarray::Axis;
use std::path::PathBuf;

/// One controllable stylized distillation (CSD) step as distill makes it: from the
/// noised latents (mvfc-filter), the clean latents and the window's renders, compute
/// z0' = z0 - lr w(t) grad and write the colour targets render + alpha (c' - c),
/// c' = c + decode(z0') - decode(z0), as a targets artifact (rgb.npy `[N,H,W,3]`,
/// cameras.json, delta.npy, PNG previews).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "csd-step", version)]
pub struct Args {
    /// Noised-latents artifact from mvfc-filter (z_src, z_tgt, eps; meta.timestep).
    #[arg(long)]
    pub noised: PathBuf,
    /// Latents artifact of the window's renders (the clean target latents z0).
    #[arg(long)]
    pub latents: PathBuf,
    /// Views artifact of the window's renders (render-views --window; the targets are
    /// built on them; cameras copied).
    #[arg(long)]
    pub views: PathBuf,
    /// Views artifact of the original renders, every view (alpha, colour, control image).
    #[arg(long)]
    pub source_views: PathBuf,
    /// Latents artifact of the original renders, every view (encode-latents --fill): z0_src.
    #[arg(long)]
    pub source_latents: PathBuf,
    #[command(flatten)]
    pub prior: PriorArgs,
    /// The method's configuration (its prior term's mode, `[csd]`, `strength`,
    /// `preserve_color`, `fill`, `motif_scale`, `unet_batch`), as distill's.
    #[command(flatten)]
    pub config: ConfigArgs,
    #[command(flatten)]
    pub background: Background,
    /// Output targets artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: Threads,
}

/// Statistics of one step (also written to the artifact's meta).
#[derive(Debug, Clone, serde::Serialize)]
pub struct StepReport {
    pub timestep: usize,
    /// RMS of w(t) g.
    pub grad_rms: f64,
    /// RMS of z0' - z0.
    pub latent_step_rms: f64,
    /// What the targets asked for.
    pub stats: TargetStats,
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
    let p = a.config.load()?;
    let Inputs { views, src, win, x } = inputs(&a)?;
    let (n, h, w) = views.dim();
    let style = a.prior.load_style()?;
    let mut prior = a.prior.open(&style, &p, a.threads)?;
    let info = prior.info().clone();
    csd::check_mode(p.csd.mode, &info)?;
    let f = info.downsample.max(1);
    let z = x.z0.shape();
    if z[1] != info.latent_channels || z[2] * f != h || z[3] * f != w {
        return Err(Error::input(
            a.latents.join("latents.npy"),
            format!(
                "latents {z:?} do not fit model `{}` ({} channels, downsample {f}) and views \
                 {h}x{w}",
                info.name, info.latent_channels
            ),
        ));
    }
    let schedule = Schedule::new(info.scheduler.clone())?;
    let (bg, vs) = (a.background.rgb, &win.window.views);
    let control = control(
        info.control,
        &src,
        &|v| src.seen(&src.rgb[v], v, bg, p.fill),
        vs,
    )?;
    let plan = Plan::csd_steps(1, n, p.csd.conds(), (h, w), f, 0);
    let mut cost = CostModel::for_model(&a.prior.model(&p)?, a.threads.n, a.prior.device.device)?;
    announce(cost.as_ref(), "csd-step", &plan);

    // The step and the targets.
    let ctl = control.as_ref().map(|c| c.view());
    let change = a
        .threads
        .install(|| prior_change(prior.as_mut(), &schedule, &x, ctl, &p.csd, (h, w)))??;
    if let Some(c) = cost.as_mut() {
        c.calibrate_unet(plan.batch, plan.latent, change.unet_s);
        c.calibrate_vae(0, 2 * n, h * w, change.vae_s);
        tracing::info!(
            "csd-step: took {} (see prior::cost)",
            about(c.seconds(&plan))
        );
    }
    let rgb = views.rgb.as_slice().expect("standard layout");
    let colour: Vec<Vec<f32>> = vs.iter().map(|&v| src.colour(v, bg)).collect();
    let (target, stats) = targets(
        &rgb.chunks(h * w * 3).collect::<Vec<_>>(),
        &vs.iter()
            .map(|&v| src.alpha[v].as_slice())
            .collect::<Vec<_>>(),
        &colour.iter().map(|c| c.as_slice()).collect::<Vec<_>>(),
        change.delta.view(),
        TargetParams {
            background: bg,
            preserve_color: p.preserve_color,
        },
    )?;
    let report = StepReport {
        timestep: x.t,
        grad_rms: rms(change.grad.iter().copied()),
        latent_step_rms: rms(change.z1.iter().zip(x.z0.iter()).map(|(a, b)| a - b)),
        stats,
    };
    tracing::info!("csd-step: mode {:?}, {report:?}", p.csd.mode);
    write(&a, &p, &views, &target, &win, &report)?;
    Ok(report)
}

/// The step's inputs, read and checked against each other (before the slow prior).
struct Inputs {
    /// The window's renders.
    views: Views,
    /// The source views, every one.
    src: SourceViews,
    win: IterationWindow,
    x: IterLatents,
}

fn inputs(a: &Args) -> Result<Inputs> {
    let noised = read_noised_latents(&a.noised)?;
    let lat = open_latents(&a.latents)?;
    let views = crate::timing::load(|| read_views(&a.views))?;
    let src = crate::timing::load(|| read_views(&a.source_views))?.source_views();
    let (n, h, w) = views.dim();
    let view_it = iteration_of(&views.art)?;
    let recorded = [
        (a.noised.as_path(), noised.iteration.as_ref()),
        (a.latents.as_path(), lat.iteration.as_ref()),
        (a.views.as_path(), view_it.as_ref()),
    ];
    let win = agreed_iteration(&recorded, n)?;
    let src_file = a.source_latents.join("latents.npy");
    let z0_src = window_rows(&read_latents(&a.source_latents)?, &win, &src_file)?;
    for (file, shape) in [
        (noised.art.path("z_src.npy"), noised.z_src.shape()),
        (src_file, z0_src.shape()),
    ] {
        if shape != lat.z.shape() {
            return Err(Error::input(
                file,
                format!(
                    "shape {shape:?} (the window's) differs from the latents' {:?} ({})",
                    lat.z.shape(),
                    a.latents.display()
                ),
            ));
        }
    }
    if (src.height, src.width) != (h, w) || lat.z.shape()[0] != n {
        return Err(Error::input(
            views.art.path("rgb.npy"),
            format!(
                "{n} views of {w}x{h}, but {} latents and source views of {}x{}",
                lat.z.shape()[0],
                src.width,
                src.height
            ),
        ));
    }
    let x = IterLatents {
        z0: lat.z,
        z0_src,
        eps: noised.eps,
        z_tgt: noised.z_tgt,
        z_src: noised.z_src,
        t: noised.timestep,
    };
    Ok(Inputs { views, src, win, x })
}

/// Write the targets artifact.
fn write(
    a: &Args,
    p: &Config,
    views: &Views,
    target: &ndarray::Array4<f32>,
    win: &IterationWindow,
    report: &StepReport,
) -> Result<()> {
    let params = super::merge_params(&[
        serde_json::json!({ "config": p, "background": a.background.rgb }),
        a.prior.to_json(),
    ]);
    let mut wr = super::create_artifact(
        &a.out,
        ArtifactKind::Targets,
        Producer::new("csd-step", crate::VERSION, params),
    )?;
    for (name, p) in [
        ("noised", &a.noised),
        ("latents", &a.latents),
        ("views", &a.views),
        ("source-views", &a.source_views),
        ("source-latents", &a.source_latents),
    ] {
        wr.add_input(name, p)?;
    }
    a.prior.add_inputs(&mut wr, p, true)?;
    crate::artifacts::write_array(&mut wr, "rgb.npy", target)?;
    crate::artifacts::write_array(&mut wr, "delta.npy", &(target - &views.rgb))?;
    let cams = views.art.path("cameras.json");
    wr.write_bytes(
        "cameras.json",
        &std::fs::read(&cams).map_err(|e| Error::io(&cams, e))?,
    )?;
    let (_, h, w, _) = target.dim();
    for (i, img) in target.axis_iter(Axis(0)).enumerate() {
        let img: Vec<f32> = img.iter().copied().collect();
        wr.write_bytes(
            &format!("target_{i:03}.png"),
            &crate::imageio::encode_png_rgb(&img, w, h)?,
        )?;
    }
    wr.set_meta(serde_json::json!({
        "iteration": win,
        "timestep": report.timestep,
        "mode": p.csd.mode,
        "stats": report.stats,
        "report": report,
    }));
    crate::timing::io(|| wr.commit())?;
    Ok(())
}

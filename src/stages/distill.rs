//! `distill`: K iterations of the whole FantasyStyle loop in one process ([`crate::distill`]:
//! render N adjacent views, encode, noise, MVFC, CSD, one colour step), from a scene or
//! from a checkpoint, writing a checkpoint.
//!
//! Why in one process: an iteration of the stylizer prior on four 256x256 views takes
//! well under a second; as five stage processes with artifacts between them it would pay
//! process start, model loading and artifact hashing every iteration (the first version's
//! rounds spent about as long outside the computation as in it). The DAG runs chunks of K
//! iterations (`distill@c1`, `distill@c2`, ...) and every chunk writes a checkpoint, so a
//! run still resumes after a failure and every intermediate can be inspected.
//!
//! A checkpoint is a `scene` artifact (anything that reads a scene reads it) holding
//! `scene.ply` (and `scene.splat`, `scene.spz` with `--format ply,splat,spz`), the optimizer state
//! (`adam_dc.npy`, `adam_rest.npy`: Adam's moments; `state.json`: iteration and step
//! counts), `history.json` (every iteration's timestep, views, loss, clipped fraction, and
//! the agreement of the prior's high-frequency change across visits and neighbouring
//! views, [`crate::distill::agreement`]), `hf_prev.npy` `[V, 3, H, W]` (each view's last
//! high-pass change, which the next chunk's revisit agreement compares with) and
//! the last iteration's tensors for `pipeline inspect`: `last_z0.npy`, `last_z_tgt.npy`,
//! `last_z_src.npy` `[N, C, h, w]` and `last_targets.npy` `[N, H, W, 3]`. Every draw
//! depends only on (seed, iteration), so chunks of any size, and a resume after a kill,
//! give the same bytes as one uninterrupted run.

use crate::artifacts::{
    CHECKPOINT_ADAM_DC, CHECKPOINT_ADAM_REST, CHECKPOINT_HF_PREV, CHECKPOINT_HISTORY,
    CHECKPOINT_STATE, load_scene, read_checkpoint, read_views,
};
use crate::csd::{self, CsdParams};
use crate::distill::{DistillParams, Distiller, SourceViews};
use crate::imageio::{MIN_STYLE_SIDE, load_style};
use crate::mvfc::MvfcParams;
use crate::optim::OptimizerState;
use crate::prior::cost::{CostModel, Plan, about};
use crate::prior::{self, PriorOptions, model_timesteps};
use crate::scheduler::TimestepSet;
use crate::{Error, Result, Scene};
use fantasystyle_schemas::{ArtifactKind, Producer};
use ndarray::Axis;
use std::path::PathBuf;

/// Which scene files a checkpoint holds (`--format ply,splat,spz`; scene.ply always).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneFormat {
    /// scene.ply (INRIA layout, every SH coefficient).
    Ply,
    /// scene.splat too (32 bytes per Gaussian, SH degree 0, for web viewers).
    Splat,
    /// scene.spz too (Niantic's compressed format, version 3).
    Spz,
    /// scene.ply and scene.splat (the same as `ply,splat`).
    Both,
}

/// Distil a 2D prior into a scene's colours: K iterations of render -> encode -> MVFC ->
/// CSD -> colour step, from a scene (--scene) or a checkpoint (--resume), writing a
/// checkpoint (a scene artifact with the optimizer state).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "distill", version)]
pub struct Args {
    /// Start from this scene (an INRIA .ply, a .splat or a scene artifact) at iteration 0.
    #[arg(long, required_unless_present = "resume", conflicts_with = "resume")]
    pub scene: Option<PathBuf>,
    /// Continue from this checkpoint (written by distill).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Views artifact of the ORIGINAL scene (render-views): cameras, the source branch's
    /// images and the alpha the targets are composited with.
    #[arg(long)]
    pub source_views: PathBuf,
    /// Model directory with model.json (e.g. vendor/models/stylizer).
    #[arg(long)]
    pub model: PathBuf,
    /// Style image (PNG or JPEG, shorter side >= 64 px).
    #[arg(long)]
    pub style: PathBuf,
    /// The prompt P: any text for a model with a text encoder (else one of its exported
    /// prompts); empty or absent: the model's first exported prompt. Ignored by the
    /// stylizer.
    #[arg(long)]
    pub prompt: Option<String>,
    /// Iterations to run in this process (0: only write the checkpoint).
    #[arg(long)]
    pub iters: u64,
    /// Adjacent views per iteration (the paper's N).
    #[arg(long, default_value_t = 4)]
    pub views_per_iter: usize,
    /// Style strength in [0, 1]: 0 leaves the scene unchanged, 1 is the full style.
    #[arg(long, default_value_t = 1.0)]
    pub strength: f32,
    /// Keep the scene's own colours (chroma); change luminance (texture, contrast) only.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub preserve_color: bool,
    /// Let view-dependent colour (f_rest) change too (default: only f_dc).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub fit_rest: bool,
    #[command(flatten)]
    pub csd: CsdParams,
    /// Adam learning rate of the SH DC colours (f_rest: / 20).
    #[arg(long, default_value_t = 0.01)]
    pub lr_dc: f32,
    /// Skip MVFC (the paper's "w/o MVFC" ablation).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub no_mvfc: bool,
    /// Filter the source branch with MVFC too (false: the target only, as in the paper,
    /// which moves the scene even when the style is its own look).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub mvfc_source: bool,
    #[command(flatten)]
    pub mvfc: MvfcParams,
    /// Timestep set MIN:MAX:COUNT (default: the model's own set).
    #[arg(long)]
    pub timesteps: Option<String>,
    /// The colour step's loss: l2 passes the prior's change with its magnitude (the
    /// paper's gradient), l1 only its sign.
    #[arg(long, value_enum, default_value = "l2")]
    pub colour_loss: crate::distill::ColourLoss,
    /// Anneal the timestep from coarse to fine over this many iterations in total (the
    /// whole run, all chunks: t_max falls linearly to the set's smallest); 0 = draw
    /// uniformly from the whole set every iteration.
    #[arg(long, default_value_t = 0)]
    pub anneal_iters: u64,
    /// Motif scale of the stylizer prior: the render is enlarged this many times before
    /// the network and reduced after, so strokes and motifs come out this much smaller
    /// on the object (1 = as the network draws them at the render's size).
    #[arg(long, default_value_t = 1.0)]
    pub motif_scale: f32,
    /// Weight of the low-layer texture term in the colour step (masked VGG16 Gram loss
    /// at relu1_2 and relu2_2 of the object crop against the style image; not part of
    /// FantasyStyle, see src/distill/texture.rs); 0 = off, the paper's method alone.
    #[arg(long, default_value_t = 1.0)]
    pub texture_weight: f32,
    /// The style image is resized so its shorter side is this many pixels for the
    /// texture term (sets the motif scale against the render's pixels).
    #[arg(long, default_value_t = 256)]
    pub texture_style_size: usize,
    /// The texture term sees the object crop and the style box-averaged this many times
    /// smaller (motif scale on screen kept; D^2 times cheaper; periods under 2D pixels
    /// are left to the prior). 1 = full resolution.
    #[arg(long, default_value_t = 1)]
    pub texture_downsample: usize,
    /// VGG16 layers whose Gram matrices the texture term matches (receptive fields:
    /// relu1_2 5 px, relu2_2 14 px, relu3_3 40 px; a deeper layer sees larger motifs and
    /// costs more).
    #[arg(long, value_delimiter = ',', default_value = "relu1_2,relu2_2")]
    pub texture_layers: Vec<crate::vgg::Layer>,
    /// The texture term on this many of each iteration's views (rotating; scaled so the
    /// gradient is the same in expectation); 0 = every view. 1 looks the same as every
    /// view at about 0.7x the CPU (BENCHMARKS.md "Texture").
    #[arg(long, default_value_t = 1)]
    pub texture_views: usize,
    /// VGG16 weights for the texture term (default: lpips/vgg16 in the models directory).
    #[arg(long)]
    pub texture_vgg: Option<PathBuf>,
    /// Give the prior the raw render (object over the background) instead of the object
    /// over a fill of its own colours.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub no_fill: bool,
    /// Seed of every draw (views, timesteps, noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Scene files written into the checkpoint, comma-separated (scene.ply always).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "ply")]
    pub format: Vec<SceneFormat>,
    /// Output checkpoint directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub threads: super::Threads,
    #[command(flatten)]
    pub device: super::DeviceArg,
    /// Most UNet rows per call (rows = views x conditionings; 0 = automatic, see
    /// csd-step --unet-batch).
    #[arg(long, default_value_t = 0)]
    pub unet_batch: usize,
}

fn parse_timesteps(spec: &str, model: &crate::scheduler::SchedulerConfig) -> Result<TimestepSet> {
    let parts: Vec<&str> = spec.split(':').collect();
    let nums: Option<Vec<usize>> = parts.iter().map(|p| p.trim().parse().ok()).collect();
    match nums.as_deref() {
        Some([a, b, c]) => TimestepSet::new(model, *a, *b, *c),
        _ => Err(Error::param(format!(
            "--timesteps `{spec}`: expected MIN:MAX:COUNT, e.g. 20:300:25"
        ))),
    }
}

/// The loop's parameters from the arguments (also recorded in the checkpoint).
fn params(a: &Args) -> DistillParams {
    DistillParams {
        views_per_iter: a.views_per_iter,
        csd: a.csd,
        mvfc: (!a.no_mvfc).then_some(a.mvfc),
        mvfc_source: a.mvfc_source,
        preserve_color: a.preserve_color,
        fit_rest: a.fit_rest,
        lr_dc: a.lr_dc,
        fill_background: !a.no_fill,
        colour_loss: a.colour_loss,
        t_schedule: if a.anneal_iters > 0 {
            crate::distill::TimestepSchedule::Anneal {
                total: a.anneal_iters,
            }
        } else {
            crate::distill::TimestepSchedule::Random
        },
        seed: a.seed,
        ..DistillParams::default()
    }
}

/// Run the stage.
pub fn run(a: Args) -> Result<()> {
    if !(0.0..=1.0).contains(&a.strength) {
        return Err(Error::param(format!(
            "--strength must be in [0, 1], got {}",
            a.strength
        )));
    }
    if !(a.csd.lr.is_finite() && a.csd.lr >= 0.0 && a.lr_dc.is_finite() && a.lr_dc >= 0.0) {
        return Err(Error::param("--lr and --lr-dc must be finite and >= 0"));
    }
    if !a.csd.guidance.is_finite() {
        return Err(Error::param("--guidance must be finite"));
    }
    a.mvfc.validate()?;
    if a.views_per_iter == 0 {
        return Err(Error::param("--views-per-iter must be at least 1"));
    }
    // Inputs, all checked before the prior is loaded.
    let (scene, start, state, history, resumed_from, hf_prev) = match (&a.scene, &a.resume) {
        (_, Some(dir)) => {
            let c = crate::timing::load(|| {
                crate::timing::phase("checkpoint read", || read_checkpoint(dir))
            })?;
            (
                c.scene,
                c.iteration,
                Some(c.state),
                c.history,
                Some(dir.clone()),
                c.hf_prev,
            )
        }
        (Some(p), None) => (
            crate::timing::load(|| load_scene(p))?,
            0,
            None,
            Vec::new(),
            None,
            None,
        ),
        (None, None) => return Err(Error::param("give --scene or --resume")),
    };
    let views = crate::timing::load(|| read_views(&a.source_views))?;
    let cameras = views.cameras()?;
    let (n, h, w) = views.dim();
    if cameras.len() != n {
        return Err(Error::input(
            views.art.path("cameras.json"),
            format!("{} cameras for {n} views", cameras.len()),
        ));
    }
    if let (Some((shape, _)), Some(dir)) = (&hf_prev, &resumed_from)
        && shape[..] != [n, 3, h, w]
    {
        return Err(Error::input(
            dir.join(CHECKPOINT_HF_PREV),
            format!("shape {shape:?}, but the source views need [{n}, 3, {h}, {w}]"),
        ));
    }
    let style = load_style(&a.style, MIN_STYLE_SIDE)?;
    let (_, model_set) = model_timesteps(&a.model)?;
    let plane =
        |x: &ndarray::Array3<f32>, i: usize| x.index_axis(Axis(0), i).iter().copied().collect();
    let source = SourceViews {
        width: w,
        height: h,
        rgb: (0..n)
            .map(|i| views.rgb.index_axis(Axis(0), i).iter().copied().collect())
            .collect(),
        alpha: (0..n).map(|i| plane(&views.alpha, i)).collect(),
        depth: (0..n).map(|i| plane(&views.depth, i)).collect(),
    };
    let p = params(&a);

    let mut run_iters = a.iters;
    let (out_scene, out_state, reports, last, hf_out) = if a.strength == 0.0 || a.iters == 0 {
        // Strength 0 is "unchanged" exactly; 0 iterations only re-packages the input.
        if a.strength == 0.0 && a.iters > 0 {
            tracing::info!("strength 0: the scene is left unchanged");
        }
        run_iters = if a.strength == 0.0 { a.iters } else { 0 };
        let k = scene.rest_per_channel();
        let st = state.clone().unwrap_or_else(|| fresh_state(&scene, k));
        (scene.clone(), st, Vec::new(), None, hf_prev)
    } else {
        let mut prior = crate::timing::load(|| {
            prior::open(
                &a.model,
                &PriorOptions {
                    style_image: Some(style.to_chw().insert_axis(Axis(0))),
                    prompt: a.prompt.clone().filter(|p| !p.is_empty()),
                    threads: a.threads.n,
                    strength: Some(a.strength),
                    motif_scale: Some(a.motif_scale),
                    device: a.device.device,
                    unet_batch: a.unet_batch,
                    ..Default::default()
                },
            )
        })?;
        // A model whose style and content conditionings coincide cannot run csd.
        csd::check_mode(a.csd.mode, prior.info())?;
        let info = prior.info().clone();
        let f = info.downsample.max(1);
        let (tc, sc) = csd::conds(a.csd.mode);
        let per_iter = a.views_per_iter.min(n);
        let plan = |iters: u64| Plan {
            evaluations: iters as usize,
            batch: per_iter * (tc.len() + sc.len()),
            latent: (h / f, w / f),
            downsample: f,
            encodes: iters as usize * per_iter,
            decodes: iters as usize * 2 * per_iter,
        };
        // What the run will cost (diffusion models), said before it starts.
        let cost = CostModel::for_model(&a.model, a.threads.n, a.device.device)?;
        if let Some(say) = cost.as_ref().and_then(|c| c.describe(&plan(a.iters))) {
            tracing::info!(
                "distill: {} iterations of {per_iter} views x {} conditionings at {}x{} \
                 latents: {say}",
                a.iters,
                tc.len() + sc.len(),
                h / f,
                w / f
            );
        }
        let set = match &a.timesteps {
            Some(spec) => parse_timesteps(spec, &prior.info().scheduler)?,
            None => model_set,
        };
        super::with_threads(a.threads.n, || -> Result<_> {
            let ph = crate::timing::span("setup");
            let mut d = Distiller::new(
                &scene,
                &cameras,
                &source,
                prior.as_mut(),
                set,
                p.clone(),
                start,
            )?;
            if let Some(s) = state.clone() {
                d.set_optimizer_state(s)?;
            }
            if let Some((shape, data)) = hf_prev.clone() {
                d.set_agreement_state(&shape, data)?;
            }
            if a.texture_weight > 0.0 {
                let mut term = texture_term(&a)?;
                term.views = a.texture_views;
                d = d.with_texture(term);
            }
            drop(ph);
            tracing::info!(
                "distill: iterations {start}..{} on {n} views ({}x{}), {} per iteration, path {}",
                start + a.iters,
                w,
                h,
                a.views_per_iter.min(n),
                if d.path().closed { "closed" } else { "open" }
            );
            let bar = indicatif::ProgressBar::new(a.iters);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{msg} [{bar:30}] {pos}/{len} iterations {elapsed} (ETA {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            let mut reports = Vec::with_capacity(a.iters as usize);
            for k in 0..a.iters {
                let started = std::time::Instant::now();
                let r = crate::timing::phase("iteration", || d.iterate())?;
                let left = a.iters - 1 - k;
                if k < 2 && left > 0 {
                    // The estimate, calibrated: the first iteration timed here, and again
                    // the second (the first pays the graphs' warm-up: about a third more
                    // for SD 1.5 on a CPU, BENCHMARKS.md "Diffusion path").
                    let s = started.elapsed().as_secs_f64();
                    let model = match (k, cost.as_ref()) {
                        (0, Some(c)) => format!(
                            " (the graphs' size predicted {} for it)",
                            about(c.seconds(&plan(1)))
                        ),
                        _ => String::new(),
                    };
                    bar.suspend(|| {
                        tracing::info!(
                            "distill: iteration {} took {s:.2} s{model}; the other {left}: {} \
                             on this machine",
                            start + k,
                            about(s * left as f64)
                        )
                    });
                }
                bar.set_message(format!("distill t={:3} loss {:.4}", r.timestep, r.loss));
                bar.inc(1);
                reports.push(r);
            }
            bar.finish_and_clear();
            let hf = d.agreement_state();
            let hf = (
                hf.shape().to_vec(),
                hf.iter().copied().collect::<Vec<f32>>(),
            );
            Ok((
                d.scene().clone(),
                d.optimizer_state(),
                reports,
                d.last().cloned(),
                Some(hf),
            ))
        })??
    };
    if let Some(r) = reports.last() {
        tracing::info!(
            "distill: iteration {} t = {} loss {:.5}, clipped {:.2}% of covered target pixels",
            r.iteration,
            r.timestep,
            r.loss,
            100.0 * r.clipped
        );
    }

    // The checkpoint.
    let producer = Producer::new(
        "distill",
        crate::VERSION,
        serde_json::json!({
            "iters": a.iters, "start": start, "views_per_iter": a.views_per_iter,
            "strength": a.strength, "preserve_color": a.preserve_color, "fit_rest": a.fit_rest,
            "csd": a.csd, "lr_dc": a.lr_dc, "mvfc": !a.no_mvfc, "mvfc_source": a.mvfc_source, "gamma": a.mvfc.gamma,
            "d_s": a.mvfc.d_s, "d_t": a.mvfc.d_t, "timesteps": a.timesteps,
            "fill": !a.no_fill, "seed": a.seed,
            "colour_loss": a.colour_loss, "texture_weight": a.texture_weight,
            "texture_style_size": a.texture_style_size, "texture_downsample": a.texture_downsample, "texture_views": a.texture_views, "texture_layers": a.texture_layers.iter().map(|l| l.name()).collect::<Vec<_>>(), "anneal_iters": a.anneal_iters, "motif_scale": a.motif_scale, "prompt": a.prompt, "format": a.format,
            "device": a.device.device.to_string(), "unet_batch": a.unet_batch,
        }),
    );
    crate::distill::guard::checkpoint(&out_scene, &out_state)?;
    let ph = crate::timing::span("checkpoint write");
    let mut out = super::create_artifact(&a.out, ArtifactKind::Scene, producer)?;
    match (&resumed_from, &a.scene) {
        (Some(dir), _) => out.add_input("resume", dir)?,
        (None, Some(p)) => out.add_input("scene", p)?,
        _ => {}
    }
    out.add_input("source-views", &a.source_views)?;
    out.add_input("style", &a.style)?;
    let mpath = if a.model.is_file() {
        a.model.clone()
    } else {
        a.model.join("model.json")
    };
    out.add_input("model", &mpath)?;
    write_scene(&mut out, &out_scene, &a.format, &a.out)?;
    let st = &out_state;
    let pair = |x: &crate::optim::AdamState| [x.m.clone(), x.v.clone()].concat();
    out.write_tensor(CHECKPOINT_ADAM_DC, &[2, st.dc.m.len()], &pair(&st.dc))?;
    out.write_tensor(CHECKPOINT_ADAM_REST, &[2, st.rest.m.len()], &pair(&st.rest))?;
    let iteration = start + run_iters;
    out.write_json(
        CHECKPOINT_STATE,
        &serde_json::json!({
            "iteration": iteration,
            "adam_dc_step": st.dc.t,
            "adam_rest_step": st.rest.t,
        }),
    )?;
    let mut hist = history;
    for r in &reports {
        hist.push(serde_json::to_value(r).map_err(|e| Error::Other(e.to_string()))?);
    }
    out.write_json(CHECKPOINT_HISTORY, &hist)?;
    if let Some((shape, data)) = &hf_out {
        out.write_tensor(CHECKPOINT_HF_PREV, shape, data)?;
    }
    if let Some(l) = &last {
        let sh = |x: &ndarray::Array4<f32>| x.shape().to_vec();
        let flat =
            |x: &ndarray::Array4<f32>| x.as_standard_layout().iter().copied().collect::<Vec<_>>();
        out.write_tensor("last_z0.npy", &sh(&l.z0), &flat(&l.z0))?;
        out.write_tensor("last_z_tgt.npy", &sh(&l.z_tgt), &flat(&l.z_tgt))?;
        out.write_tensor("last_z_src.npy", &sh(&l.z_src), &flat(&l.z_src))?;
        out.write_tensor("last_targets.npy", &sh(&l.targets), &flat(&l.targets))?;
    }
    out.set_meta(serde_json::json!({
        "iteration": iteration,
        "gaussians": out_scene.len(),
        "sh_degree": out_scene.sh_degree,
        "last": last.as_ref().map(|l| &l.report),
    }));
    crate::timing::io(|| out.commit())?;
    drop(ph);
    tracing::info!("wrote {} (iteration {iteration})", a.out.display());
    Ok(())
}

/// The texture term of `--texture-weight` (VGG from `--texture-vgg` or the models
/// directory; the style image at `--texture-style-size`).
fn texture_term(a: &Args) -> Result<crate::distill::texture::TextureTerm> {
    use crate::vgg::Vgg16;
    let dir = match &a.texture_vgg {
        Some(p) => p.clone(),
        None => crate::models::model_path("lpips/vgg16")?,
    };
    let vgg = Vgg16::load(&dir)?;
    let style = crate::imageio::read_rgb(&a.style)?;
    let style = crate::baselines::prepare_style(&style, a.texture_style_size, &a.style)?;
    crate::distill::texture::TextureTerm::new(
        vgg,
        &style,
        &a.texture_layers,
        a.texture_weight,
        a.texture_downsample,
    )
}

/// Adam state of a scene that has not been optimised yet.
fn fresh_state(scene: &Scene, rest_per_channel: usize) -> OptimizerState {
    let z = |len: usize| crate::optim::AdamState {
        m: vec![0.0; len],
        v: vec![0.0; len],
        t: 0,
    };
    OptimizerState {
        dc: z(scene.len() * 3),
        rest: z(scene.len() * 3 * rest_per_channel),
    }
}

fn write_scene(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    scene: &Scene,
    format: &[SceneFormat],
    dir: &std::path::Path,
) -> Result<()> {
    let has = |f| format.contains(&f);
    let extra = crate::scene::ExtraFormats {
        splat: has(SceneFormat::Splat) || has(SceneFormat::Both),
        spz: has(SceneFormat::Spz),
    };
    for (name, bytes) in crate::scene::encode_files(dir, scene, extra)? {
        out.write_bytes(name, &bytes)?;
    }
    Ok(())
}

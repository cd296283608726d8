//! Distillation at the scale the method needs (FantasyStyle Sec. 4, the whole loop):
//! hundreds of iterations, each on a few adjacent views with a fresh timestep and fresh
//! noise, with one optimizer whose state persists across iterations and checkpoints.
//!
//! One iteration `i` (all randomness from `(seed, i)`, so a run split into chunks or
//! resumed from a checkpoint gives the same bytes as one uninterrupted run); each step is
//! a function of [`step`], which the stage chain (`render-views --window` ->
//! `encode-latents` -> `mvfc-filter` -> `csd-step` -> `update-gaussians`) calls too, so
//! the chain runs this iteration byte for byte (the integration test `chain`):
//!
//! 1. a window of N adjacent views along the camera path ([`path`]);
//! 2. render them with the current colours (frozen-geometry caches) and give the prior
//!    the object over a fill of its own colours ([`fill`]); encode: z0 (target), and
//!    the source views' z0_src (encoded once);
//! 3. t from the model's DDIM set, eps `[N, C, h, w]`, eps' `[C, h, w]`;
//!    z_src = add_noise(z0_src, eps, t), z_tgt = MVFC(add_noise(z0, eps, t), eps')
//!    along the path ([`crate::mvfc::mvfc_path`]; "without MVFC" skips it); by default
//!    z_src goes through the same filter with the same eps' (`mvfc_source`; the paper
//!    filters the target only, which biases the update: see the field's docs);
//! 4. the CSD step ([`crate::csd`]): z0' = z0 - lr w(t) (Phi_tgt - Phi_src); the image
//!    change the prior asks for is Delta = decode(z0') - decode(z0);
//! 5. targets: the object's colour c (the render un-premultiplied by its alpha) moves to
//!    c' = c + Delta (with colour preservation: c' keeps the source's chroma and takes
//!    only the new luminance, Gatys et al. 2016's luminance-only transfer), limited to
//!    [min(c, 0), max(c, 1)] (a change never pushes a colour out of range; one already
//!    out of range is left where it is), and the render moves by the alpha-weighted
//!    change, target = render + a (c' - c), so that the thin fringe of a silhouette
//!    (small a) asks for a small change only, not for a colour it can reach only by
//!    blowing up (the "glowing haze" of the first version), and Delta = 0 asks for no
//!    change at all (the target is then the render, bit for bit);
//! 6. one Adam step of the SH colours on the window's views towards the targets;
//!    geometry is frozen. With the L2 loss ([`ColourLoss::L2`], the default) the
//!    gradient at the render is -a (c' - c), the prior's change with its magnitude, and
//!    the rasterizer's vector-Jacobian product carries the paper's w(t) (Phi_tgt -
//!    Phi_src) into the colours (the MSE-to-a-detached-target form of score
//!    distillation); L1 passes only its sign. The colour step's loss is the
//!    configuration's weighted list of terms ([`terms`]): the prior's term above, and
//!    optionally VGG texture terms of the object (`nnfm`, `gram`: not part of
//!    FantasyStyle; what carries a style's motifs with the CPU stylizer prior,
//!    docs/texture-term.md).
//!
//! The whole configuration is one type, [`Config`] ([`config`]: keys, defaults, presets);
//! a run may start from the scene as it is or after a start, and end after a finish
//! ([`ends`]); splitting long Gaussians is its own stage ([`split`]).
//!
//! The timestep is drawn uniformly from the set every iteration (the paper), or annealed
//! from coarse to fine ([`TimestepSchedule::Anneal`]).
//!
//! Strength is the prior's business (`PriorOptions::strength`; for the stylizer an
//! interpolation of style vectors), except strength 0, which the stage short-circuits to
//! "unchanged". Whether f_rest (view-dependent colour) may change is `sh` (`fit`; `drop` removes the
//! bands of a fresh run after its start, [`crate::scene::colour::Bands`]).
//!
//! Not part of the iteration's arithmetic: the agreement measurement ([`agreement`],
//! between steps 4 and 5: how much the prior's high-frequency change agrees across
//! visits and neighbouring views), which only `distill` keeps (its state travels in
//! `distill`'s checkpoints as `hf_prev.npy`; the stage chain does not measure it).

pub mod checkpoint;
pub mod guard;
pub mod record;
pub mod step;

use crate::camera::path::{ViewPath, Window};
pub use crate::config::Config;
use crate::metrics::agreement;
use crate::optim::{ColourFit, OptimizerState};
use crate::prior::Prior;
use crate::prior::cost::{CostModel, Plan, about};
pub use crate::render::source::SourceViews;
pub use crate::scheduler::TimestepSchedule;
use crate::scheduler::{Schedule, TimestepSet};
pub use crate::terms::ColourLoss;
use crate::terms::{self, PriorTerm};
use crate::{Camera, Error, Result, Scene};
use ndarray::{Array3, Array4, ArrayView4, Axis};
pub use record::{IterReport, LastIteration, LastLatents, Progress};
pub use step::{ColourStep, Draws, TargetParams};

/// The distillation state: the colour fit (scene + optimizer + caches), the prior, the
/// source views and their latents.
pub struct Distiller<'a> {
    fit: ColourFit<'a>,
    prior: &'a mut dyn Prior,
    schedule: Schedule,
    timesteps: TimestepSet,
    params: Config,
    source: &'a SourceViews,
    /// Source colour per view, un-premultiplied `[H, W, 3]`.
    source_colour: Vec<Vec<f32>>,
    /// The source views as the prior sees them, `[3, H, W]` per view (the encoder's
    /// input for z0_src, and the control image of a `ControlKind::Source` prior).
    source_seen: Vec<Array3<f32>>,
    /// z0_src of every view, `[V, C, h, w]`: encoded once, by the first iteration that
    /// calls the prior (never when it asks nothing, [`Config::asks_the_prior`]: an SD
    /// VAE would encode every view for nothing).
    z0_src: Option<Array4<f32>>,
    path: ViewPath,
    iteration: u64,
    last: Option<LastIteration>,
    /// The low-layer texture term added to the colour step ([`terms::texture`]), if any.
    texture: Option<terms::texture::TextureTerm>,
    /// The configuration's view terms, made once ([`terms::ViewTerm`]).
    view_terms: Vec<(f32, Box<dyn terms::ViewTerm>)>,
    /// Each view's previous high-pass change (measurement only, [`agreement`]).
    agreement: agreement::Tracker,
}

impl<'a> Distiller<'a> {
    /// Set up: caches of every view (the source latents follow on the first iteration
    /// that calls the prior). `iteration` is the number of iterations already done (0 for
    /// a fresh start; a checkpoint's count to resume, with its optimizer state given to
    /// [`Self::set_optimizer_state`]).
    pub fn new(
        scene: &Scene,
        cameras: &'a [Camera],
        source: &'a SourceViews,
        prior: &'a mut dyn Prior,
        timesteps: TimestepSet,
        params: Config,
        iteration: u64,
    ) -> Result<Self> {
        let n = cameras.len();
        if source.rgb.len() != n || source.alpha.len() != n || source.depth.len() != n {
            return Err(Error::param(format!(
                "{n} cameras but {} source views",
                source.rgb.len()
            )));
        }
        let params = params.checked()?;
        let (h, w) = (source.height, source.width);
        for c in cameras {
            if (c.width as usize, c.height as usize) != (w, h) {
                return Err(Error::param(format!(
                    "camera {:?} is {}x{}, the source views are {w}x{h}",
                    c.name, c.width, c.height
                )));
            }
        }
        let info = prior.info().clone();
        let f = info.downsample.max(1);
        if h % f != 0 || w % f != 0 {
            return Err(Error::param(format!(
                "views of {w}x{h} do not divide by the prior's downsampling {f}"
            )));
        }
        let schedule = Schedule::new(info.scheduler.clone())?;
        let bg = source.background;
        let fit = ColourFit::without_targets(scene, cameras, &step::fit_params(&params, bg))?;
        let source_colour: Vec<Vec<f32>> = (0..n).map(|v| source.colour(v, bg)).collect();
        let source_seen: Vec<Array3<f32>> = (0..n)
            .map(|v| source.seen(&source.rgb[v], v, bg, params.fill))
            .collect();
        let view_terms = params.terms.view_terms();
        Ok(Distiller {
            fit,
            prior,
            schedule,
            timesteps,
            params,
            source,
            source_colour,
            source_seen,
            z0_src: None,
            path: ViewPath::of(cameras),
            iteration,
            last: None,
            texture: None,
            view_terms,
            agreement: agreement::Tracker::new(cameras, h, w),
        })
    }

    /// Scale every colour update by the Gaussians' weights in `sel` ([`crate::selection`]:
    /// weight 0 keeps a Gaussian's colours bit for bit); None changes nothing.
    pub fn with_selection(mut self, sel: Option<&crate::selection::Selection>) -> Result<Self> {
        self.fit.set_weights(sel)?;
        Ok(self)
    }

    /// Add the low-layer texture term to every colour step.
    pub fn with_texture(mut self, term: terms::texture::TextureTerm) -> Self {
        self.texture = Some(term);
        self
    }

    /// Iterations done so far.
    pub fn iteration(&self) -> u64 {
        self.iteration
    }

    pub fn path(&self) -> ViewPath {
        self.path
    }

    /// The scene with the current colours.
    pub fn scene(&self) -> &Scene {
        self.fit.scene()
    }

    pub fn optimizer_state(&self) -> OptimizerState {
        self.fit.optimizer_state()
    }

    pub fn set_optimizer_state(&mut self, s: OptimizerState) -> Result<()> {
        self.fit.set_optimizer_state(s)
    }

    /// The previous visits' high-pass changes `[V, 3, H, W]` (checkpointed, so a resumed
    /// run measures the same agreements as an uninterrupted one).
    pub fn agreement_state(&self) -> &Array4<f32> {
        self.agreement.state()
    }

    /// Restore [`Self::agreement_state`] from a checkpoint.
    pub fn set_agreement_state(&mut self, shape: &[usize], data: Vec<f32>) -> Result<()> {
        if self.agreement.set_state(shape, data) {
            Ok(())
        } else {
            Err(Error::param(format!(
                "agreement state of shape {shape:?}, expected {:?}",
                self.agreement.state().shape()
            )))
        }
    }

    /// The last iteration's tensors (None before the first iteration of this process).
    pub fn last(&self) -> Option<&LastIteration> {
        self.last.as_ref()
    }

    /// Render view `v` with the current colours, `[H, W, 3]`.
    pub fn render_view(&self, v: usize) -> Vec<f32> {
        self.fit.render_view(v)
    }

    /// One iteration (module docs), step by step through [`step`], unchecked:
    /// [`Self::iterate`] (in [`guard`]) names the iteration in errors and refuses a
    /// non-finite result. When the gradient is zero whatever the prior says
    /// ([`Config::asks_the_prior`]: no prior term, or csd at guidance 0) the prior is not called.
    fn iterate_unguarded(&mut self) -> Result<IterReport> {
        if !self.params.asks_the_prior() {
            self.iterate_without_prior()
        } else {
            self.iterate_with_prior()
        }
    }

    /// The iteration without the prior's calls, for a zero gradient: targets = the
    /// renders (what a zero image change gives, bit for bit, [`step::targets`]), so only
    /// the texture term moves the colours; the same timestep draw and report (no
    /// agreement: there is no change to measure), no latents.
    fn iterate_without_prior(&mut self) -> Result<IterReport> {
        let p = &self.params;
        let (h, w) = (self.source.height, self.source.width);
        let mut draws = Draws::new(p.seed, self.iteration, self.path, p.views);
        let t = draws.timestep(p.t_schedule(), &self.timesteps);
        let views = draws.window().window.views.clone();
        let ph = crate::timing::span("render");
        let renders = step::render_window(&self.fit, &views);
        drop(ph);
        let zero = Array4::zeros((views.len(), 3, h, w));
        let (targets, stats) = self.window_targets(&views, &renders, zero.view())?;
        let losses = self.colour_step(&views, &targets)?;
        let report = IterReport::new(draws.window(), t, stats, losses);
        self.last = Some(LastIteration {
            report: report.clone(),
            latents: None,
            targets,
            prior: None,
        });
        self.iteration += 1;
        Ok(report)
    }

    /// The targets of the window's `views` (`renders`: their renders) for the image
    /// change `delta` `[N, 3, H, W]` ([`step::targets`]), and what they asked for.
    fn window_targets(
        &self,
        views: &[usize],
        renders: &[Vec<f32>],
        delta: ArrayView4<'_, f32>,
    ) -> Result<(Array4<f32>, step::TargetStats)> {
        let _ph = crate::timing::span("targets");
        let alpha: Vec<&[f32]> = views.iter().map(|&v| &self.source.alpha[v][..]).collect();
        let colour: Vec<&[f32]> = views.iter().map(|&v| &self.source_colour[v][..]).collect();
        step::targets(
            &renders.iter().map(|r| r.as_slice()).collect::<Vec<_>>(),
            &alpha,
            &colour,
            delta,
            TargetParams {
                background: self.source.background,
                preserve_color: self.params.preserve_color,
            },
        )
    }

    /// One colour step on the window's `views` towards `targets` (with the texture term,
    /// if any, masked by the source coverage): `(loss, texture loss)`.
    fn colour_step(&mut self, views: &[usize], targets: &Array4<f32>) -> Result<(f64, f64)> {
        let p = &self.params;
        let _ph = crate::timing::span("colour step");
        let source = self.source;
        let alpha: Vec<&[f32]> = views.iter().map(|&v| &source.alpha[v][..]).collect();
        let cs = ColourStep {
            prior: p.terms.prior().map(|(_, weight)| PriorTerm {
                loss: p.colour_loss,
                weight,
            }),
            texture: self.texture.as_ref(),
            views: &self.view_terms,
            background: source.background,
            fill: p.fill,
            iteration: self.iteration,
        };
        step::colour_step(&mut self.fit, views, targets.view(), &alpha, &cs)
    }

    /// The whole iteration: render, encode, noise, MVFC, CSD, targets, colour step.
    fn iterate_with_prior(&mut self) -> Result<IterReport> {
        let p = &self.params;
        let size = (self.source.height, self.source.width);
        let mut draws = Draws::new(p.seed, self.iteration, self.path, p.views);
        let t = draws.timestep(p.t_schedule(), &self.timesteps);
        let Window { views, circular } = draws.window().window.clone();

        // Render the window; encode what the prior sees of it; the source latents.
        let ph = crate::timing::span("render");
        let renders = step::render_window(&self.fit, &views);
        drop(ph);
        let ph = crate::timing::span("fill");
        let (bg, fill) = (self.source.background, p.fill);
        let seen: Vec<Array3<f32>> = views
            .iter()
            .zip(&renders)
            .map(|(&v, r)| self.source.seen(r, v, bg, fill))
            .collect();
        drop(ph);
        let ph = crate::timing::span("encode");
        let z0 = step::encode_views(self.prior, &seen, views.len())?;
        if self.z0_src.is_none() {
            // The source latents, once, a window's worth of views per call.
            let per_call = p.views;
            self.z0_src = Some(step::encode_views(self.prior, &self.source_seen, per_call)?);
        }
        let z0_src = self
            .z0_src
            .as_ref()
            .expect("encoded above")
            .select(Axis(0), &views);
        drop(ph);
        let sh = z0.shape();
        let noise = draws.noise([sh[0], sh[1], sh[2], sh[3]]);
        let x = step::noise_branches(&self.schedule, z0, z0_src, &noise, t, &p.mvfc, circular)?;

        // CSD, the image change, the targets.
        let ph = crate::timing::span("control");
        let seen_src = |v: usize| self.source_seen[v].clone();
        let control = step::control(self.prior.info().control, self.source, &seen_src, &views)?;
        drop(ph);
        let change = step::prior_change(
            self.prior,
            &self.schedule,
            &x,
            control.as_ref().map(|c| c.view()),
            &p.csd,
            size,
        )?;
        let ph = crate::timing::span("agreement");
        let (a, s) = (&self.source.alpha, &self.source.depth);
        let agree = self
            .agreement
            .measure(&views, circular, change.delta.view(), a, s);
        drop(ph);
        let (targets, stats) = self.window_targets(&views, &renders, change.delta.view())?;

        // One colour step on the window (with the texture term, if any).
        let losses = self.colour_step(&views, &targets)?;
        let mut report = IterReport::new(draws.window(), t, stats, losses);
        report.hf_agree_revisit = agree.revisit;
        report.hf_agree_adjacent = agree.adjacent;
        self.last = Some(LastIteration {
            report: report.clone(),
            latents: Some(LastLatents {
                z0: x.z0,
                z_tgt: x.z_tgt,
                z_src: x.z_src,
            }),
            targets,
            prior: self.prior.describe(),
        });
        self.iteration += 1;
        Ok(report)
    }
}

impl Distiller<'_> {
    /// Run `iters` iterations with a progress bar, logging after the first (and the
    /// second: the first pays the graphs' warm-up, about a third more for SD 1.5 on a
    /// CPU, BENCHMARKS.md "Diffusion path") how long the rest will take on this machine,
    /// and what `cost` predicted for one iteration (`one`: its plan).
    pub fn run(
        &mut self,
        iters: u64,
        cost: Option<&CostModel>,
        one: &Plan,
    ) -> Result<Vec<IterReport>> {
        let start = self.iteration;
        let bar = indicatif::ProgressBar::new(iters);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{msg} [{bar:30}] {pos}/{len} iterations {elapsed} (ETA {eta})",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        let mut reports = Vec::with_capacity(iters as usize);
        for k in 0..iters {
            let started = std::time::Instant::now();
            let r = crate::timing::phase("iteration", || self.iterate())?;
            let left = iters - 1 - k;
            if k < 2 && left > 0 {
                let s = started.elapsed().as_secs_f64();
                let model = match (k, cost) {
                    (0, Some(c)) => format!(
                        " (the graphs' size predicted {} for it)",
                        about(c.seconds(one))
                    ),
                    _ => String::new(),
                };
                bar.suspend(|| {
                    tracing::info!(
                        "distill: iteration {} took {s:.2} s{model}; the other {left}: {} on \
                         this machine",
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
        Ok(reports)
    }
}

/// What a run of the loop leaves.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The scene with its colours as of the last iteration.
    pub scene: Scene,
    pub state: OptimizerState,
    /// The reports of this run's iterations.
    pub reports: Vec<IterReport>,
    /// The last iteration's tensors (None when no iteration ran).
    pub last: Option<LastIteration>,
    /// The agreement measurement's state (`[V, 3, H, W]`: shape, values), if any.
    pub hf_prev: Option<(Vec<usize>, Vec<f32>)>,
}

impl Outcome {
    /// No iteration: the start as it is.
    pub fn unchanged(start: &Progress) -> Outcome {
        Outcome {
            scene: start.scene.clone(),
            state: start.state(),
            reports: Vec::new(),
            last: None,
            hf_prev: start.hf_prev.clone(),
        }
    }
}

/// What [`distill`] runs: the loop's parameters, its timesteps, how many iterations, the
/// optional texture term and the optional selection of the Gaussians that may change.
pub struct Run<'s> {
    pub params: Config,
    pub set: TimestepSet,
    pub iters: u64,
    pub texture: Option<terms::texture::TextureTerm>,
    pub selection: Option<&'s crate::selection::Selection>,
}

/// Run `run.iters` iterations of the loop from `start` (a scene, or a checkpoint with
/// its optimizer state, iteration count and agreement state) on the views of `cameras`
/// (`source`: their original renders), with `prior`; `cost` (diffusion models) says what
/// the run will cost before it starts and is calibrated on its first iterations
/// ([`Distiller::run`]).
pub fn distill(
    start: &Progress,
    cameras: &[Camera],
    source: &SourceViews,
    prior: &mut dyn Prior,
    run: Run<'_>,
    cost: Option<&CostModel>,
) -> Result<Outcome> {
    let Run {
        params,
        set,
        iters,
        texture,
        selection,
    } = run;
    let (conds, f) = (params.csd.conds(), prior.info().downsample);
    let per_iter = params.views.min(cameras.len());
    let (h, w) = (source.height, source.width);
    let plan = |n: u64| Plan::csd_steps(n as usize, per_iter, conds, (h, w), f, 1);
    let cost = if !params.asks_the_prior() {
        tracing::info!(
            "distill: the terms {} ask nothing of the prior (no prior term, or csd at \
             guidance 0); it is not called (the other terms alone move the colours)",
            params.terms
        );
        None
    } else {
        cost
    };
    crate::prior::cost::announce(cost, "distill", &plan(iters));
    let it = start.iteration;
    let ph = crate::timing::span("setup");
    let mut d = Distiller::new(&start.scene, cameras, source, prior, set, params, it)?
        .with_selection(selection)?;
    d.set_optimizer_state(start.state())?;
    if let Some((shape, data)) = start.hf_prev.clone() {
        d.set_agreement_state(&shape, data)?;
    }
    if let Some(t) = texture {
        d = d.with_texture(t);
    }
    drop(ph);
    tracing::info!(
        "distill: iterations {it}..{} on {} views ({w}x{h}), {per_iter} per iteration, path {}",
        it + iters,
        cameras.len(),
        if d.path().closed { "closed" } else { "open" }
    );
    let reports = d.run(iters, cost, &plan(1))?;
    if let Some(r) = reports.last() {
        tracing::info!(
            "distill: iteration {} t = {} loss {:.5}, clipped {:.2}% of covered target pixels",
            r.iteration,
            r.timestep,
            r.loss,
            100.0 * r.clipped
        );
    }
    let hf = d.agreement_state();
    Ok(Outcome {
        scene: d.scene().clone(),
        state: d.optimizer_state(),
        reports,
        last: d.last().cloned(),
        hf_prev: Some((hf.shape().to_vec(), hf.iter().copied().collect())),
    })
}

/// Luminance-only transfer (Gatys et al. 2016, "Preserving color in neural artistic
/// style transfer"): the luminance of `c`, the chroma of `src` (Rec. 601 luma; chroma as
/// the offset of each channel from the luma).
pub fn keep_chroma(c: [f32; 3], src: [f32; 3]) -> [f32; 3] {
    let luma = |v: [f32; 3]| 0.299 * v[0] + 0.587 * v[1] + 0.114 * v[2];
    let (y, ys) = (luma(c), luma(src));
    src.map(|s| y + (s - ys))
}

#[cfg(test)]
mod tests;

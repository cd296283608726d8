//! Distillation at the scale the method needs (FantasyStyle Sec. 3, the whole loop):
//! hundreds of iterations, each on a few adjacent views with a fresh timestep and fresh
//! noise, with one optimizer whose state persists across iterations and checkpoints.
//!
//! One iteration `i` (all randomness from `(seed, i)`, so a run split into chunks or
//! resumed from a checkpoint gives the same bytes as one uninterrupted run):
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
//!    distillation); L1 passes only its sign. Optionally ([`texture`], on in the stage's
//!    defaults) a low-layer VGG Gram term of the object is added to the same step: it is
//!    not part of FantasyStyle, and it is what carries a style's motifs with the CPU
//!    stylizer prior (BENCHMARKS.md "Texture").
//!
//! The timestep is drawn uniformly from the set every iteration (the paper), or annealed
//! from coarse to fine ([`TimestepSchedule::Anneal`]).
//!
//! Strength is the prior's business (`PriorOptions::strength`; for the stylizer an
//! interpolation of style vectors), except strength 0, which the stage short-circuits to
//! "unchanged". Whether f_rest (view-dependent colour) may change is `fit_rest`.

pub mod agreement;
pub mod fill;
pub mod guard;
pub mod path;
pub mod texture;

use crate::csd::{self, CsdParams};
use crate::mvfc::{MvfcParams, mvfc_path};
use crate::optim::{ColourFit, FitParams, LossParams, OptimizerState, loss_and_grad};
use crate::prior::Prior;
use crate::render::CacheMode;
use crate::rng::Rng;
use crate::scheduler::{Schedule, TimestepSet};
use crate::{Camera, Error, Result, Scene};
use ndarray::{Array3, Array4, Axis, concatenate};
use path::{ViewPath, Window};

/// Parameters of the loop.
#[derive(Debug, Clone, PartialEq)]
pub struct DistillParams {
    /// Views per iteration (the paper's N adjacent views).
    pub views_per_iter: usize,
    /// The distillation gradient (mode, guidance, weighting, step on z0).
    pub csd: CsdParams,
    /// MVFC parameters; `None` = the "without MVFC" ablation.
    pub mvfc: Option<MvfcParams>,
    /// Filter the source branch's noisy latents with MVFC too (same eps'), not only the
    /// target's. MVFC scales the low band of the signal by gamma; on the target alone
    /// that is a bias the CSD difference does not cancel (the scene moves even when the
    /// style is its own look); on both branches Phi_tgt - Phi_src is 0 at the source.
    pub mvfc_source: bool,
    /// Keep the scene's own chroma, change luminance (texture, contrast) only.
    pub preserve_color: bool,
    /// Let f_rest (view-dependent colour) change.
    pub fit_rest: bool,
    /// Adam learning rate of f_dc (f_rest: lr_dc / 20 when `fit_rest`).
    pub lr_dc: f32,
    /// D-SSIM weight of the colour loss. 0 by default: the target differs from the
    /// render only by the prior's small change, and where that change is 0 the D-SSIM
    /// gradient is rounding noise, which Adam's per-parameter normalisation (eps 1e-15)
    /// turns into full-size steps: the scene then drifts with no style asking for it.
    pub ssim_weight: f32,
    /// Give the prior the object over a fill of its own colours ([`fill`]).
    pub fill_background: bool,
    /// Background colour of the renders (and of the source views).
    pub background: [f32; 3],
    /// How the prior's change reaches the colours ([`ColourLoss`]).
    pub colour_loss: ColourLoss,
    /// How the timestep of an iteration is drawn ([`TimestepSchedule`]).
    pub t_schedule: TimestepSchedule,
    /// Seed of every random draw.
    pub seed: u64,
}

/// The colour step's loss against the targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ColourLoss {
    /// L1: each pixel passes only the sign of the change the prior asks for.
    L1,
    /// Half the squared distance: dL/drender = render - target = -a (c' - c), the
    /// alpha-weighted image change itself, so the render's vector-Jacobian product
    /// carries the paper's gradient w(t) (Phi_tgt - Phi_src) with its magnitude (the
    /// MSE-to-a-detached-target form of score distillation).
    L2,
}

/// How an iteration's timestep is drawn from the model's set.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum TimestepSchedule {
    /// Uniformly from the whole set, every iteration (the paper).
    Random,
    /// Coarse to fine: at iteration i of `total` the draw is uniform over the smallest
    /// timesteps of the set up to t_max(i), which falls linearly from the set's largest
    /// to its smallest (threestudio's annealed maximum step; DreamTime's monotone
    /// schedule in its stochastic form).
    Anneal { total: u64 },
}

impl TimestepSchedule {
    /// The timestep of iteration `it`.
    pub fn draw(&self, set: &TimestepSet, it: u64, rng: &mut Rng) -> usize {
        match *self {
            TimestepSchedule::Random => set.sample(rng),
            TimestepSchedule::Anneal { total } => {
                let steps = set.steps();
                let f = (it as f64 / total.max(1) as f64).min(1.0);
                let top = ((1.0 - f) * (steps.len() - 1) as f64).round() as usize;
                let i = ((rng.uniform() * (top + 1) as f64) as usize).min(top);
                steps[i]
            }
        }
    }
}

impl Default for DistillParams {
    fn default() -> Self {
        DistillParams {
            views_per_iter: 4,
            csd: CsdParams::default(),
            mvfc: Some(MvfcParams::default()),
            mvfc_source: true,
            preserve_color: false,
            fit_rest: false,
            lr_dc: 0.01,
            ssim_weight: 0.0,
            fill_background: true,
            background: [0.0; 3],
            colour_loss: ColourLoss::L2,
            t_schedule: TimestepSchedule::Random,
            seed: 0,
        }
    }
}

/// The original renders (from the source `views` artifact), one `[H, W, ...]` per view.
#[derive(Debug, Clone)]
pub struct SourceViews {
    pub width: usize,
    pub height: usize,
    /// `[H, W, 3]` per view.
    pub rgb: Vec<Vec<f32>>,
    /// `[H, W]` per view.
    pub alpha: Vec<Vec<f32>>,
    /// `[H, W]` per view (expected depth), for ControlNet priors.
    pub depth: Vec<Vec<f32>>,
}

/// What one iteration did, for logs, checkpoints and tests.
#[derive(Debug, Clone, serde::Serialize)]
pub struct IterReport {
    pub iteration: u64,
    pub views: Vec<usize>,
    pub timestep: usize,
    /// Mean colour loss over the window before the update.
    pub loss: f64,
    /// Mean texture loss over the window before the update (0 without the term).
    pub texture_loss: f64,
    /// RMS of the image change the prior asked for, over covered pixels.
    pub delta_rms: f64,
    /// Fraction of covered target pixels clipped (<= 0.02 or >= 0.98 in every channel).
    pub clipped: f64,
    /// Cosine of the high-pass change with the same views' previous visit ([`agreement`];
    /// None when no view of the window was visited before).
    pub hf_agree_revisit: Option<f64>,
    /// Cosine of the high-pass change between the window's neighbouring views after depth
    /// reprojection ([`agreement`]; None for a one-view window or no overlap).
    pub hf_agree_adjacent: Option<f64>,
}

/// The last iteration's tensors, written into checkpoints for inspection.
#[derive(Debug, Clone)]
pub struct LastIteration {
    pub report: IterReport,
    /// `[N, C, h, w]` each.
    pub z0: Array4<f32>,
    pub z_tgt: Array4<f32>,
    pub z_src: Array4<f32>,
    /// `[N, H, W, 3]`.
    pub targets: Array4<f32>,
}

/// The distillation state: the colour fit (scene + optimizer + caches), the prior, the
/// source views and their latents.
pub struct Distiller<'a> {
    fit: ColourFit<'a>,
    prior: &'a mut dyn Prior,
    schedule: Schedule,
    timesteps: TimestepSet,
    params: DistillParams,
    source: &'a SourceViews,
    /// Source chroma/colour per view, un-premultiplied `[H, W, 3]`.
    source_colour: Vec<Vec<f32>>,
    /// The source views as the prior sees them, `[3, H, W]` per view (the encoder's
    /// input for z0_src, and the control image of a `ControlKind::Source` prior).
    source_seen: Vec<Array3<f32>>,
    /// z0_src per view, `[C, h, w]`.
    z0_src: Vec<Array3<f32>>,
    path: ViewPath,
    iteration: u64,
    last: Option<LastIteration>,
    /// The low-layer texture term added to the colour step ([`texture`]), if any.
    texture: Option<texture::TextureTerm>,
    /// Each view's previous high-pass change (measurement only, [`agreement`]).
    agreement: agreement::Tracker,
}

fn to_chw(img: &[f32], h: usize, w: usize) -> Array3<f32> {
    Array3::from_shape_fn((3, h, w), |(c, y, x)| img[(y * w + x) * 3 + c])
}

impl<'a> Distiller<'a> {
    /// Set up: caches of every view, the source latents. `iteration` is the number of
    /// iterations already done (0 for a fresh start; a checkpoint's count to resume,
    /// with its optimizer state given to [`Self::set_optimizer_state`]).
    pub fn new(
        scene: &Scene,
        cameras: &'a [Camera],
        source: &'a SourceViews,
        prior: &'a mut dyn Prior,
        timesteps: TimestepSet,
        params: DistillParams,
        iteration: u64,
    ) -> Result<Self> {
        let n = cameras.len();
        if source.rgb.len() != n || source.alpha.len() != n || source.depth.len() != n {
            return Err(Error::param(format!(
                "{n} cameras but {} source views",
                source.rgb.len()
            )));
        }
        if params.views_per_iter == 0 {
            return Err(Error::param("views per iteration must be at least 1"));
        }
        if let Some(m) = &params.mvfc {
            m.validate()?;
        }
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
        let fit_params = FitParams {
            lr_dc: params.lr_dc,
            lr_rest: if params.fit_rest {
                params.lr_dc / 20.0
            } else {
                0.0
            },
            ssim_weight: params.ssim_weight,
            mask_alpha: false,
            cache: CacheMode::On,
            background: params.background,
            progress: false,
        };
        let fit = ColourFit::without_targets(scene, cameras, &fit_params)?;
        let bg = params.background;
        let source_colour: Vec<Vec<f32>> = (0..n)
            .map(|v| fill::unpremultiply(&source.rgb[v], &source.alpha[v], bg))
            .collect();
        let source_seen: Vec<Array3<f32>> = (0..n)
            .map(|v| to_chw(&Self::prior_view(&params, source, &source.rgb[v], v), h, w))
            .collect();
        // The source latents, encoded once, a few views per call.
        let mut z0_src = Vec::with_capacity(n);
        for chunk in source_seen.chunks(params.views_per_iter.max(1)) {
            let views: Vec<_> = chunk
                .iter()
                .map(|a| a.view().insert_axis(Axis(0)))
                .collect();
            let batch = concatenate(Axis(0), &views).map_err(|e| Error::Other(e.to_string()))?;
            let z = prior.encode(batch.view())?;
            for i in 0..chunk.len() {
                z0_src.push(z.index_axis(Axis(0), i).to_owned());
            }
        }
        Ok(Distiller {
            fit,
            prior,
            schedule,
            timesteps,
            params,
            source,
            source_colour,
            source_seen,
            z0_src,
            path: ViewPath::of(cameras),
            iteration,
            last: None,
            texture: None,
            agreement: agreement::Tracker::new(cameras, h, w),
        })
    }

    /// The image of view `v` the prior sees: `rgb` as rendered, or the object over a
    /// fill of its own colours.
    fn prior_view(p: &DistillParams, source: &SourceViews, rgb: &[f32], v: usize) -> Vec<f32> {
        if p.fill_background {
            fill::fill_background(
                rgb,
                &source.alpha[v],
                p.background,
                source.height,
                source.width,
            )
        } else {
            rgb.to_vec()
        }
    }

    /// Add the low-layer texture term to every colour step.
    pub fn with_texture(mut self, term: texture::TextureTerm) -> Self {
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

    /// One iteration (module docs), unchecked: [`Self::iterate`] (in [`guard`]) names
    /// the iteration in errors and refuses a non-finite result.
    fn iterate_unguarded(&mut self) -> Result<IterReport> {
        let it = self.iteration;
        let p = self.params.clone();
        let (h, w) = (self.source.height, self.source.width);
        let mut rng = Rng::derive(p.seed, &format!("distill/{it}"));
        let Window { views, circular } = self.path.draw(&mut rng, p.views_per_iter);
        let t = p.t_schedule.draw(&self.timesteps, it, &mut rng);
        let n = views.len();

        // Renders, what the prior sees, latents.
        let ph = crate::timing::span("render");
        let renders: Vec<Vec<f32>> = views.iter().map(|&v| self.fit.render_view(v)).collect();
        drop(ph);
        let ph = crate::timing::span("fill");
        let seen: Vec<Array3<f32>> = views
            .iter()
            .zip(&renders)
            .map(|(&v, r)| to_chw(&Self::prior_view(&p, self.source, r, v), h, w))
            .collect();
        drop(ph);
        let stack = |xs: &[Array3<f32>]| -> Result<Array4<f32>> {
            let v: Vec<_> = xs.iter().map(|a| a.view().insert_axis(Axis(0))).collect();
            concatenate(Axis(0), &v).map_err(|e| Error::Other(e.to_string()))
        };
        let ph = crate::timing::span("encode");
        let z0 = self.prior.encode(stack(&seen)?.view())?;
        let z0_src = stack(
            &views
                .iter()
                .map(|&v| self.z0_src[v].clone())
                .collect::<Vec<_>>(),
        )?;
        drop(ph);
        if z0.shape() != z0_src.shape() {
            return Err(Error::Other(format!(
                "prior encoded renders to {:?} but the source to {:?}",
                z0.shape(),
                z0_src.shape()
            )));
        }
        let ph = crate::timing::span("noise");
        let sh = z0.shape().to_vec();
        let eps = Array4::from_shape_vec((sh[0], sh[1], sh[2], sh[3]), rng.normals_f32(z0.len()))
            .expect("length matches");
        let eps_shared = Array3::from_shape_vec(
            (sh[1], sh[2], sh[3]),
            rng.normals_f32(sh[1] * sh[2] * sh[3]),
        )
        .expect("length matches");
        let src_noisy = self.schedule.add_noise(z0_src.view(), eps.view(), t)?;
        let z_noisy = self.schedule.add_noise(z0.view(), eps.view(), t)?;
        drop(ph);
        let ph = crate::timing::span("mvfc");
        let (z_tgt, z_src) = match &p.mvfc {
            Some(m) => (
                mvfc_path(z_noisy.view(), eps_shared.view(), *m, circular)?,
                if p.mvfc_source {
                    mvfc_path(src_noisy.view(), eps_shared.view(), *m, circular)?
                } else {
                    src_noisy
                },
            ),
            None => (z_noisy, src_noisy),
        };
        drop(ph);
        let ph = crate::timing::span("control");
        let control = match self.prior.info().control {
            // The original render as the prior sees it (over the same fill).
            Some(crate::prior::ControlKind::Source) => {
                let imgs: Vec<Array3<f32>> =
                    views.iter().map(|&v| self.source_seen[v].clone()).collect();
                Some(stack(&imgs)?)
            }
            Some(kind) => {
                let pick = |xs: &Vec<Vec<f32>>, c: usize| -> Array4<f32> {
                    Array4::from_shape_fn((n, h, w, c), |(i, y, x, k)| {
                        xs[views[i]][(y * w + x) * c + k]
                    })
                };
                let rgb = pick(&self.source.rgb, 3);
                let depth = pick(&self.source.depth, 1).remove_axis(Axis(3));
                let alpha = pick(&self.source.alpha, 1).remove_axis(Axis(3));
                Some(crate::prior::control_image(
                    kind,
                    rgb.view(),
                    depth.view(),
                    alpha.view(),
                )?)
            }
            None => None,
        };
        drop(ph);
        let ph = crate::timing::span("csd");
        let (z1, _g) = csd::step(
            self.prior,
            &self.schedule,
            csd::StepInputs {
                z0: z0.view(),
                z_tgt: z_tgt.view(),
                z_src: z_src.view(),
                eps: eps.view(),
                z0_src: Some(z0_src.view()),
                t,
                control: control.as_ref().map(|c| c.view()),
            },
            &p.csd,
        )?;
        drop(ph);
        let ph = crate::timing::span("decode");
        let delta = csd::image_change(self.prior, z1.view(), z0.view(), h, w)?;
        drop(ph);
        let ph = crate::timing::span("agreement");
        let (a, s) = (&self.source.alpha, &self.source.depth);
        let agree = self.agreement.measure(&views, circular, delta.view(), a, s);
        drop(ph);

        let ph = crate::timing::span("targets");
        // Targets: the object's colour moves by Delta, recomposited with alpha.
        let bg = p.background;
        let mut targets = Array4::<f32>::zeros((n, h, w, 3));
        let (mut d2, mut covered, mut clipped) = (0.0f64, 0usize, 0usize);
        for (i, &v) in views.iter().enumerate() {
            let alpha = &self.source.alpha[v];
            let src = &self.source_colour[v];
            for y in 0..h {
                for x in 0..w {
                    let q = y * w + x;
                    let a = alpha[q];
                    let rgb = &renders[i][q * 3..q * 3 + 3];
                    // The object's own colour (un-premultiplied, not clamped).
                    let c0: [f32; 3] = std::array::from_fn(|k| {
                        if a >= 1e-4 {
                            (rgb[k] - (1.0 - a) * bg[k]) / a
                        } else {
                            0.0
                        }
                    });
                    let mut c = [0.0f32; 3];
                    for k in 0..3 {
                        let d = delta[[i, k, y, x]];
                        if !d.is_finite() {
                            return Err(Error::Other(format!(
                                "prior asked for a non-finite change at t = {t}"
                            )));
                        }
                        c[k] = c0[k] + d;
                        if a > 0.5 {
                            d2 += (d * d) as f64;
                        }
                    }
                    if p.preserve_color {
                        c = keep_chroma(c, [src[q * 3], src[q * 3 + 1], src[q * 3 + 2]]);
                    }
                    let c: [f32; 3] =
                        std::array::from_fn(|k| c[k].clamp(c0[k].min(0.0), c0[k].max(1.0)));
                    if a > 0.5 {
                        covered += 1;
                        if c.iter().all(|v| *v <= 0.02) || c.iter().all(|v| *v >= 0.98) {
                            clipped += 1;
                        }
                    }
                    for k in 0..3 {
                        targets[[i, y, x, k]] = rgb[k] + a * (c[k] - c0[k]);
                    }
                }
            }
        }
        drop(ph);

        let ph = crate::timing::span("colour step");
        // One colour step on the window.
        let lp = LossParams {
            ssim_weight: p.ssim_weight,
        };
        let index: std::collections::HashMap<usize, usize> =
            views.iter().enumerate().map(|(i, &v)| (v, i)).collect();
        let tg = &targets;
        let tex = self.texture.as_ref();
        let source = self.source;
        let mut tex_loss = 0.0f64;
        let mut loss = |v: usize, rgb: &[f32], _a: Option<&[f32]>| -> Result<(f64, Vec<f32>)> {
            let i = index[&v];
            let target = tg.index_axis(Axis(0), i);
            let target = target.as_slice().expect("standard layout");
            let (l, mut g) = match p.colour_loss {
                ColourLoss::L1 => {
                    let (l, g) = loss_and_grad(rgb, target, None, h, w, lp);
                    (l as f64, g)
                }
                ColourLoss::L2 => half_squared_distance(rgb, target),
            };
            // The term on some of the window's views (rotating with the iteration), scaled
            // so its gradient is the same in expectation ([`texture::TextureTerm::applies`]).
            if let Some((t, scale)) = tex.and_then(|t| t.applies(i, n, it).map(|s| (t, s))) {
                let seen = Self::prior_view(&p, source, rgb, v);
                let tg = t.view_grad(&seen, &source.alpha[v], h, w)?;
                tex_loss += tg.loss * scale as f64 / n as f64;
                for (a, b) in g.iter_mut().zip(&tg.grad) {
                    *a += scale * t.weight * b;
                }
            }
            Ok((l, g))
        };
        let loss = self.fit.step_views(&views, &mut loss)?;
        drop(ph);
        let report = IterReport {
            iteration: it,
            views: views.clone(),
            timestep: t,
            loss,
            texture_loss: tex_loss,
            delta_rms: (d2 / (3 * covered.max(1)) as f64).sqrt(),
            clipped: clipped as f64 / covered.max(1) as f64,
            hf_agree_revisit: agree.revisit,
            hf_agree_adjacent: agree.adjacent,
        };
        self.last = Some(LastIteration {
            report: report.clone(),
            z0,
            z_tgt,
            z_src,
            targets,
        });
        self.iteration += 1;
        Ok(report)
    }
}

/// `(sum 0.5 (x - y)^2 / n, (x - y) / n)` over the `n` values of a view: the gradient is
/// the difference itself, scaled like the L1 loss's (1/n per value).
pub fn half_squared_distance(render: &[f32], target: &[f32]) -> (f64, Vec<f32>) {
    let n = render.len().max(1) as f32;
    let mut loss = 0.0f64;
    let g = render
        .iter()
        .zip(target)
        .map(|(x, y)| {
            let d = x - y;
            loss += 0.5 * (d as f64) * (d as f64);
            d / n
        })
        .collect();
    (loss / n as f64, g)
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

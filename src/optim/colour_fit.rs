//! [`ColourFit`], the state of a colour fit: per-view caches (or not), Adam moments,
//! the current scene. One step renders every view, sums the per-view losses' gradients
//! (divided by the number of views) and updates once; the loss recorded per step is the
//! mean over views before the update. The update is projected: every base colour it may
//! move ends inside [0, 1] ([`crate::scene::colour`]).

use super::adam::{Adam, OptimizerState};
use super::fit::{FitParams, FitReport, check_options, check_params};
use super::loss::{LossParams, LossScratch, loss_and_grad_into};
use crate::render::backward::{ViewGrad, colour_grad_uncached, sh_backward_views};
use crate::render::{
    CacheMode, ViewCache, clamp_colours, composite, project, raw_colours, validate_camera,
    validate_scene,
};
use crate::scene::colour::bound_dc;
use crate::{Camera, Error, Result, Scene};
use rayon::prelude::*;

enum ViewState {
    Cached {
        cache: Box<ViewCache>,
        alpha: Vec<f32>,
    },
    Uncached,
}

/// A per-view loss for [`ColourFit::step_with`]: `(view, rgb, alpha) -> (loss, dL/drgb)`.
pub type ViewLoss<'a> = dyn FnMut(usize, &[f32], Option<&[f32]>) -> Result<(f64, Vec<f32>)> + 'a;

/// A view's loss inside a step: `loss(v, bufs, rgb, alpha)` reads the render from
/// `rgb`, or from `bufs.rgb` when `rgb` is `None` (cached views render into the
/// buffers), and leaves dL/drgb in `bufs.grad`.
type StepLoss<'a> =
    dyn Fn(usize, &mut ViewBufs, Option<&[f32]>, Option<&[f32]>) -> Result<f64> + Sync + 'a;
/// The same, called one view at a time.
type SeqLoss<'a> =
    dyn FnMut(usize, &mut ViewBufs, Option<&[f32]>, Option<&[f32]>) -> Result<f64> + 'a;

/// How a step calls the per-view loss: on all cores, or view after view in order (a
/// caller's hook that is not thread-safe).
enum Losses<'a, 'b> {
    Parallel(&'a StepLoss<'b>),
    InOrder(&'a mut SeqLoss<'b>),
    /// The mean squared error against these targets (one per camera), on all cores;
    /// cached views fuse it into their forward and backward ([`ViewCache::l2_backward`]).
    L2(&'a [Vec<f32>]),
}

/// Image buffers of one view's step: the render (cached views), dL/drgb, the loss planes.
#[derive(Debug, Default)]
struct ViewBufs {
    rgb: Vec<f32>,
    grad: Vec<f32>,
    loss: LossScratch,
}

/// A view's share of a step, until it is added into the SH gradients.
struct ViewGradOwned<'a> {
    loss: f64,
    ids: std::borrow::Cow<'a, [u32]>,
    centre: [f32; 3],
    raw: Vec<[f32; 3]>,
    grad_c: Vec<[f32; 3]>,
}

/// Buffers handed out to one task at a time and taken back, so that a fit reuses its
/// memory across views and steps (fresh multi-megabyte buffers fault in new pages every
/// time). Which buffer a view gets does not matter: every use overwrites it.
#[derive(Debug, Default)]
struct Pool<T>(std::sync::Mutex<Vec<T>>);

impl<T: Default> Pool<T> {
    fn take(&self) -> T {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default()
    }
    fn put(&self, t: T) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).push(t);
    }
}

/// The state of a colour fit: per-view caches (or not), Adam moments, the current
/// scene. [`fit_colours`](super::fit_colours) drives it; benchmarks time [`ColourFit::step`] alone.
pub struct ColourFit<'a> {
    cameras: &'a [Camera],
    targets: Option<&'a [Vec<f32>]>,
    params: FitParams,
    states: Vec<ViewState>,
    scene: Scene,
    dc: Vec<f32>,
    adam_dc: Adam,
    adam_rest: Adam,
    grad_dc: Vec<[f32; 3]>,
    grad_rest: Vec<f32>,
    /// Per-view image buffers, reused across views and steps.
    bufs: Pool<ViewBufs>,
    losses: Vec<f32>,
    cached_views: usize,
    cache_bytes: usize,
    /// Per-Gaussian weights of the colour updates ([`crate::selection`]); None: all 1.
    weights: Option<Vec<f32>>,
}

/// Each view's state: its cache (projection and compositing order, and alpha when the
/// fit masks by it) when the cache mode allows, in view order; and the cached bytes. An
/// error when no Gaussian is visible from any camera.
fn plan_views(scene: &Scene, cameras: &[Camera], p: &FitParams) -> Result<(Vec<ViewState>, usize)> {
    let mut states = Vec::with_capacity(cameras.len());
    let mut cache_bytes = 0usize;
    let mut any_visible = false;
    // Views are projected and composited a window at a time on all cores; which
    // caches are kept is decided in view order, as before.
    let window = crate::parallel::window_for(rayon::current_num_threads());
    for win in cameras.chunks(window) {
        let caches: Vec<ViewCache> = win
            .par_iter()
            .map(|cam| ViewCache::from_frame(&project(scene, cam)))
            .collect();
        for (cam, cache) in win.iter().zip(caches) {
            if cache.blends() == 0 {
                tracing::warn!("camera {:?}: no Gaussian is visible", cam.name);
            } else {
                any_visible = true;
            }
            let keep = match p.cache {
                CacheMode::On => true,
                CacheMode::Off => false,
                CacheMode::Budget(b) => cache_bytes + cache.bytes() <= b,
            };
            if keep {
                cache_bytes += cache.bytes();
                let alpha = if p.mask_alpha {
                    cache.alpha()
                } else {
                    Vec::new()
                };
                states.push(ViewState::Cached {
                    cache: Box::new(cache),
                    alpha,
                });
            } else {
                states.push(ViewState::Uncached);
            }
        }
    }
    if !any_visible {
        return Err(Error::param(format!(
            "no Gaussian of the scene ({} Gaussians) is visible from any of the {} cameras",
            scene.len(),
            cameras.len()
        )));
    }
    Ok((states, cache_bytes))
}

impl<'a> ColourFit<'a> {
    /// Validate the inputs and plan the views: build the caches that the mode allows.
    pub fn new(
        scene: &Scene,
        cameras: &'a [Camera],
        targets: &'a [Vec<f32>],
        p: &FitParams,
    ) -> Result<ColourFit<'a>> {
        check_params(scene, cameras, targets, 1, p)?;
        let mut fit = Self::without_targets(scene, cameras, p)?;
        fit.targets = Some(targets);
        Ok(fit)
    }

    /// A fit whose per-step losses the caller supplies ([`Self::step_views`],
    /// [`Self::step_with`]); it has no targets, so [`Self::step`] must not be called.
    pub fn without_targets(
        scene: &Scene,
        cameras: &'a [Camera],
        p: &FitParams,
    ) -> Result<ColourFit<'a>> {
        validate_scene(scene)?;
        if cameras.is_empty() {
            return Err(Error::param("no cameras to fit to"));
        }
        for c in cameras {
            validate_camera(c)?;
        }
        check_options(p)?;
        let (states, cache_bytes) = plan_views(scene, cameras, p)?;
        let cached_views = states
            .iter()
            .filter(|s| matches!(s, ViewState::Cached { .. }))
            .count();
        tracing::info!(
            "fitting colours of {} Gaussians (SH degree {}) to {} views, {} cached ({:.1} MB)",
            scene.len(),
            scene.sh_degree,
            cameras.len(),
            cached_views,
            cache_bytes as f64 / 1e6
        );
        let k = scene.rest_per_channel();
        let n = scene.len();
        Ok(ColourFit {
            cameras,
            targets: None,
            params: p.clone(),
            states,
            scene: scene.clone(),
            dc: scene.sh_dc.iter().flatten().copied().collect(),
            adam_dc: Adam::new(n * 3, p.lr_dc),
            adam_rest: Adam::new(n * k * 3, p.lr_rest),
            grad_dc: vec![[0.0; 3]; n],
            grad_rest: vec![0.0; n * k * 3],
            bufs: Pool::default(),
            losses: Vec::new(),
            cached_views,
            cache_bytes,
            weights: None,
        })
    }

    /// Scale each Gaussian's colour updates by its weight in `sel` (one per Gaussian of
    /// the scene, in [0, 1]; weight 0: the Gaussian's colours keep their bits); None:
    /// every Gaussian moves freely (the same bytes as never calling this).
    pub fn set_weights(&mut self, sel: Option<&crate::selection::Selection>) -> Result<()> {
        if let Some(s) = sel
            && s.len() != self.scene.len()
        {
            return Err(Error::param(format!(
                "selection of {} Gaussians for a scene of {}",
                s.len(),
                self.scene.len()
            )));
        }
        self.weights = sel.map(|s| s.weights.clone());
        Ok(())
    }

    /// Views whose contributions are cached, and the bytes the caches hold.
    pub fn cache_stats(&self) -> (usize, usize) {
        (self.cached_views, self.cache_bytes)
    }

    /// One Adam step over all views; returns the mean loss over views before the update.
    /// Views are processed in parallel; losses and gradients are added in view order,
    /// so the result is the same for any thread count.
    pub fn step(&mut self) -> f32 {
        let lp = LossParams {
            ssim_weight: self.params.ssim_weight,
        };
        let cameras = self.cameras;
        let targets = self
            .targets
            .expect("ColourFit::step needs the targets given to ColourFit::new");
        let loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let (h, w) = (cameras[v].height as usize, cameras[v].width as usize);
            let ViewBufs {
                loss,
                rgb: own,
                grad,
            } = b;
            let rgb = rgb.unwrap_or(own);
            grad.resize(h * w * 3, 0.0);
            Ok(loss_and_grad_into(loss, rgb, &targets[v], alpha, h, w, lp, grad) as f64)
        };
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_over(&all, Losses::Parallel(&loss))
            .expect("the L1 + D-SSIM loss cannot fail") as f32
    }

    /// The image-gradient hook (added for the VGG baselines): one Adam step over all
    /// views like [`ColourFit::step`], with the per-view loss supplied by the caller.
    /// `view_loss(v, rgb, alpha)` gets camera `v`'s render `[H, W, 3]` (and its alpha
    /// when `mask_alpha` is set) and returns the loss and dL/d(rgb); the gradient is
    /// chained through the colour backward pass. Returns the mean loss over views before
    /// the update; the targets given to [`ColourFit::new`] are not used. The hook is
    /// called view after view, in order.
    pub fn step_with(&mut self, view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_over(&all, Losses::InOrder(&mut loss))
    }

    /// One Adam step over the cameras `views` only (indices into the cameras given to
    /// [`Self::new`]): the per-view losses' gradients are summed, divided by
    /// `views.len()`, and applied once. Returns the mean loss over `views` before the
    /// update. Distillation ([`crate::distill`]) steps on a few adjacent views at a time.
    /// The hook is called view after view, in the order of `views`.
    pub fn step_views(&mut self, views: &[usize], view_loss: &mut ViewLoss<'_>) -> Result<f64> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        self.step_over(views, Losses::InOrder(&mut loss))
    }

    /// One Adam step over all views with the mean squared error against `targets` (one
    /// `[H, W, 3]` image per camera, no alpha mask) as each view's loss, the views in
    /// parallel: [`Self::step_views`] with [`super::l2`] over all views, the same step bit
    /// for bit (the returned loss may differ in its last digits: a cached view sums it
    /// tile by tile). The patch synthesis's step.
    pub fn step_l2(&mut self, targets: &[Vec<f32>]) -> Result<f64> {
        if targets.len() != self.cameras.len() {
            return Err(Error::param(format!(
                "step_l2: {} targets for {} cameras",
                targets.len(),
                self.cameras.len()
            )));
        }
        let all: Vec<usize> = (0..self.cameras.len()).collect();
        self.step_over(&all, Losses::L2(targets))
    }

    /// One step: for every view (in parallel or in order, see [`Losses`]), colours,
    /// render, the loss (which leaves dL/drgb in the buffers' `grad`), colour and SH
    /// backward; then the Adam update.
    fn step_over(&mut self, views: &[usize], losses: Losses<'_, '_>) -> Result<f64> {
        Ok(self.grad_or_step(views, losses, true)?.0)
    }

    /// The gradient of the mean loss over `views` w.r.t. the DC coefficients (`[N * 3]`,
    /// what [`Self::step_views`] hands to Adam), without changing anything: for plain
    /// gradient steps and for tests of the gradient itself.
    pub fn gradient_views(
        &mut self,
        views: &[usize],
        view_loss: &mut ViewLoss<'_>,
    ) -> Result<(f64, Vec<f32>)> {
        let mut loss = |v: usize, b: &mut ViewBufs, rgb: Option<&[f32]>, alpha: Option<&[f32]>| {
            let rgb = rgb.unwrap_or(&b.rgb);
            let (l, g) = view_loss(v, rgb, alpha)?;
            b.grad = g;
            Ok(l)
        };
        self.grad_or_step(views, Losses::InOrder(&mut loss), false)
    }

    /// The gradient over `views`, then (with `apply`) the Adam update; returns the mean
    /// loss and the DC gradient.
    fn grad_or_step(
        &mut self,
        views: &[usize],
        mut losses: Losses<'_, '_>,
        apply: bool,
    ) -> Result<(f64, Vec<f32>)> {
        if views.is_empty() || views.iter().any(|&v| v >= self.cameras.len()) {
            return Err(Error::param(format!(
                "step_views: views {views:?} for {} cameras",
                self.cameras.len()
            )));
        }
        let nv = views.len();
        let mut grad_dc = std::mem::take(&mut self.grad_dc);
        let mut grad_rest = std::mem::take(&mut self.grad_rest);
        grad_dc.par_iter_mut().for_each(|g| *g = [0.0; 3]);
        grad_rest.par_iter_mut().for_each(|g| *g = 0.0);
        let mut loss_sum = 0.0f64;
        // A window of views at a time: their colour gradients (two floats triples per
        // visible Gaussian) are held until added, so memory stays bounded.
        let window = crate::parallel::window_for(rayon::current_num_threads()).max(8);
        let mut first_err = None;
        for chunk in views.chunks(window) {
            let outs: Vec<ViewGradOwned<'_>> = match self.view_grads(chunk, &mut losses) {
                Ok(o) => o,
                Err(e) => {
                    first_err = Some(e);
                    break;
                }
            };
            for o in &outs {
                loss_sum += o.loss;
            }
            let views: Vec<ViewGrad<'_>> = outs
                .iter()
                .map(|o| ViewGrad {
                    ids: &o.ids,
                    centre: o.centre,
                    raw: &o.raw,
                    grad_c: &o.grad_c,
                })
                .collect();
            sh_backward_views(&self.scene, &views, &mut grad_dc, &mut grad_rest);
        }
        if let Some(e) = first_err {
            self.grad_dc = grad_dc;
            self.grad_rest = grad_rest;
            return Err(e);
        }
        let nvf = nv as f32;
        let gdc: Vec<f32> = grad_dc
            .par_iter()
            .flat_map_iter(|g| g.map(|x| x / nvf))
            .collect();
        grad_rest.par_iter_mut().for_each(|g| *g /= nvf);
        if !apply {
            self.grad_dc = grad_dc;
            self.grad_rest = grad_rest;
            return Ok((loss_sum / nv as f64, gdc));
        }
        let w = self.weights.as_deref();
        self.adam_dc.step_weighted(&mut self.dc, &gdc, w);
        self.adam_rest
            .step_weighted(&mut self.scene.sh_rest, &grad_rest, w);
        // Projected: every base colour a step may move stays in [0, 1] (scene::colour).
        self.scene
            .sh_dc
            .par_iter_mut()
            .zip(self.dc.par_chunks_mut(3))
            .enumerate()
            .for_each(|(i, (c, d))| {
                if w.is_none_or(|w| w[i] > 0.0) {
                    let b = bound_dc([d[0], d[1], d[2]]);
                    d.copy_from_slice(&b);
                }
                *c = [d[0], d[1], d[2]];
            });
        self.grad_dc = grad_dc;
        self.grad_rest = grad_rest;
        let loss = loss_sum / nv as f64;
        self.losses.push(loss as f32);
        Ok((loss, gdc))
    }

    /// [`Self::view_grad`] (or [`Self::view_grad_l2`]) of each view of `chunk`, in
    /// parallel unless the loss must be called in order; the first error if any.
    fn view_grads(
        &self,
        chunk: &[usize],
        losses: &mut Losses<'_, '_>,
    ) -> Result<Vec<ViewGradOwned<'_>>> {
        match losses {
            Losses::Parallel(f) => chunk
                .par_iter()
                .map(|&v| self.view_grad(v, &mut |v, b, rgb, alpha| f(v, b, rgb, alpha)))
                .collect(),
            Losses::InOrder(f) => chunk.iter().map(|&v| self.view_grad(v, &mut **f)).collect(),
            Losses::L2(targets) => chunk
                .par_iter()
                .map(|&v| self.view_grad_l2(v, &targets[v]))
                .collect(),
        }
    }

    /// Forward, loss and colour backward of view `v`.
    fn view_grad<'s>(&'s self, v: usize, loss: &mut SeqLoss<'_>) -> Result<ViewGradOwned<'s>> {
        let p = &self.params;
        let out = &self.scene;
        let cam = &self.cameras[v];
        let centre = cam.center();
        let mut b = self.bufs.take();
        let r = match &self.states[v] {
            ViewState::Cached { cache, alpha } => {
                let ids = cache.gaussians();
                let raw = raw_colours(out, ids, centre);
                b.rgb.resize(cache.width * cache.height * 3, 0.0);
                cache.forward_into(&clamp_colours(&raw), p.background, &mut b.rgb);
                let mask = p.mask_alpha.then_some(&alpha[..]);
                loss(v, &mut b, None, mask).map(|l| ViewGradOwned {
                    loss: l,
                    ids: std::borrow::Cow::Borrowed(ids),
                    centre,
                    grad_c: cache.backward(&b.grad),
                    raw,
                })
            }
            ViewState::Uncached => {
                let frame = project(out, cam);
                let raw = raw_colours(out, &frame.splats.ids, centre);
                let r = composite(&frame, &clamp_colours(&raw), p.background);
                let mask = p.mask_alpha.then_some(&r.alpha[..]);
                loss(v, &mut b, Some(&r.rgb), mask).map(|l| {
                    let grad_c = colour_grad_uncached(&frame, &b.grad);
                    ViewGradOwned {
                        loss: l,
                        ids: std::borrow::Cow::Owned(frame.splats.ids),
                        centre,
                        grad_c,
                        raw,
                    }
                })
            }
        };
        self.bufs.put(b);
        r
    }

    /// [`Self::view_grad`] with the mean squared error against `target` as the loss,
    /// fused into the forward and backward when the view is cached.
    fn view_grad_l2<'s>(&'s self, v: usize, target: &[f32]) -> Result<ViewGradOwned<'s>> {
        let (h, w) = (
            self.cameras[v].height as usize,
            self.cameras[v].width as usize,
        );
        if target.len() != h * w * 3 {
            return Err(Error::param(format!(
                "step_l2: view {v}'s target has {} values for {h}x{w}x3",
                target.len()
            )));
        }
        let ViewState::Cached { cache, .. } = &self.states[v] else {
            return self.view_grad(v, &mut |_, b, rgb, _| {
                let (l, g) = super::l2(rgb.unwrap_or(&b.rgb), target);
                b.grad = g;
                Ok(l)
            });
        };
        let centre = self.cameras[v].center();
        let ids = cache.gaussians();
        let raw = raw_colours(&self.scene, ids, centre);
        let (loss, grad_c) =
            cache.l2_backward(&clamp_colours(&raw), self.params.background, target);
        Ok(ViewGradOwned {
            loss,
            ids: std::borrow::Cow::Borrowed(ids),
            centre,
            grad_c,
            raw,
        })
    }

    /// Camera `v`'s render `[H, W, 3]` with the current colours (the cached forward
    /// pass where the view is cached, a full rasterization otherwise).
    pub fn render_view(&self, v: usize) -> Vec<f32> {
        let cam = &self.cameras[v];
        let centre = cam.center();
        match &self.states[v] {
            ViewState::Cached { cache, .. } => {
                let raw = raw_colours(&self.scene, cache.gaussians(), centre);
                cache.forward(&clamp_colours(&raw), self.params.background)
            }
            ViewState::Uncached => {
                let frame = project(&self.scene, cam);
                let raw = raw_colours(&self.scene, &frame.splats.ids, centre);
                composite(&frame, &clamp_colours(&raw), self.params.background).rgb
            }
        }
    }

    /// Camera `v`'s coverage `[H, W]` (`1 - T_final`), which colours do not change: the
    /// cache's where the view is cached (bit for bit a render's alpha), a projection and
    /// rasterization otherwise.
    pub fn alpha_view(&self, v: usize) -> Vec<f32> {
        match &self.states[v] {
            ViewState::Cached { cache, .. } => cache.alpha(),
            ViewState::Uncached => {
                let frame = project(&self.scene, &self.cameras[v]);
                let raw = raw_colours(&self.scene, &frame.splats.ids, self.cameras[v].center());
                composite(&frame, &clamp_colours(&raw), self.params.background).alpha
            }
        }
    }

    /// The optimizer's state (Adam moments and step counts), for checkpoints.
    pub fn optimizer_state(&self) -> OptimizerState {
        OptimizerState {
            dc: self.adam_dc.state(),
            rest: self.adam_rest.state(),
        }
    }

    /// Restore a state saved by [`Self::optimizer_state`] for this scene (same number
    /// of Gaussians and SH degree), so a resumed fit continues bit for bit.
    pub fn set_optimizer_state(&mut self, s: OptimizerState) -> Result<()> {
        self.adam_dc.set_state(s.dc, "f_dc")?;
        self.adam_rest.set_state(s.rest, "f_rest")
    }

    /// The scene as of the last step (geometry as given, colours updated).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The fitted scene and the report.
    pub fn finish(self) -> (Scene, FitReport) {
        (
            self.scene,
            FitReport {
                losses: self.losses,
                cached_views: self.cached_views,
                cache_bytes: self.cache_bytes,
            },
        )
    }
}

/// Fit the SH colours (`f_dc`, `f_rest`) of `scene` so that its renders from `cameras`
/// match `targets` (`[H, W, 3]` per camera), for `steps` Adam steps. Every other field
/// of the returned scene is the input's, bit for bit.
///
/// A view in which no Gaussian blends is kept (its loss counts, it gives no gradient)
/// with a warning; if no view sees any Gaussian, this is an error (nothing to fit).
pub fn fit_colours(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    steps: usize,
    p: &FitParams,
) -> Result<(Scene, FitReport)> {
    check_params(scene, cameras, targets, steps, p)?;
    let mut fit = ColourFit::new(scene, cameras, targets, p)?;
    let bar = if p.progress {
        indicatif::ProgressBar::new(steps as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("fit colours");
    for _ in 0..steps {
        let loss = fit.step();
        bar.set_message(format!("fit colours, loss {loss:.5}"));
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(fit.finish())
}

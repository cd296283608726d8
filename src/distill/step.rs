//! One iteration of the method, step by step (FantasyStyle Sec. 4, the method: MVFC on
//! the noisy latents, then CSD). Every step is one function here, called both by
//! [`super::Distiller::iterate`] (one process, everything in memory) and by the stage
//! chain (one process per step, every step's output an artifact), so the chain runs the
//! same method as `distill`, byte for byte (the integration test `chain` holds it):
//!
//! | step | here | chain stage (artifact) |
//! |---|---|---|
//! | the window and the timestep, from (seed, iteration) | [`Draws`] | `render-views --window` draws the window and records it ([`IterationWindow`]); `mvfc-filter` replays it, then draws t, eps, eps' |
//! | render the window with the current colours | [`render_window`] | `render-views --window` (views) |
//! | what the prior sees (the object over a fill) | [`prior_view`] | `encode-latents --fill` |
//! | encode: z0, and z0_src of the source views | [`encode_views`] | `encode-latents` (latents) |
//! | noise both branches with one eps; MVFC along the path | [`noise_branches`] | `mvfc-filter` (noised-latents) |
//! | the control image of a ControlNet prior | [`control`] | `csd-step` |
//! | CSD and the image change Delta | [`prior_change`] | `csd-step` |
//! | targets = render + alpha (c' - c) | [`targets`] | `csd-step` (targets) |
//! | one colour step, persistent optimizer state | [`colour_step`] | `update-gaussians` (a checkpoint) |
//!
//! What `distill` keeps in memory between steps, the chain passes as artifacts: the
//! window and the iteration's identity in every artifact's `meta.iteration`, the
//! optimizer state in the checkpoint (`crate::distill::checkpoint::read_checkpoint`).

pub use super::record::{IterationWindow, TargetStats};
use super::{TimestepSchedule, keep_chroma};
use crate::camera::path::ViewPath;
use crate::config::Config;
use crate::csd::{self, CsdParams};
use crate::mvfc::mvfc_path;
use crate::optim::{ColourFit, FitParams};
use crate::prior::{ControlKind, Prior};
use crate::render::CacheMode;
pub use crate::render::fill::{prior_image, prior_view};
use crate::render::source::SourceViews;
use crate::rng::Rng;
use crate::scheduler::{Schedule, TimestepSet};
use crate::terms::PriorTerm;
use crate::terms::texture::TextureTerm;
use crate::{Error, Result};
use ndarray::{Array3, Array4, ArrayView4, Axis, concatenate};
use std::time::Instant;

/// The random draws of one iteration, in their order: the window, the timestep, the
/// noise eps `[N, C, h, w]` shared by both branches, then MVFC's eps' `[C, h, w]`. One
/// stream per (seed, iteration), so that a run split into chunks, resumed, or run as the
/// stage chain draws the same numbers.
#[derive(Debug, Clone)]
pub struct Draws {
    rng: Rng,
    window: IterationWindow,
}

/// The noise of one iteration.
#[derive(Debug, Clone)]
pub struct Noise {
    /// Shared by the source and target branches, `[N, C, h, w]`.
    pub eps: Array4<f32>,
    /// MVFC's eps', shared by the views, `[C, h, w]`.
    pub eps_shared: Array3<f32>,
}

impl Draws {
    /// Start iteration `iteration`'s stream and draw its window of `views_per_iter`
    /// adjacent views on `path`.
    pub fn new(seed: u64, iteration: u64, path: ViewPath, views_per_iter: usize) -> Draws {
        let mut rng = Rng::derive(seed, &format!("distill/{iteration}"));
        let window = path.draw(&mut rng, views_per_iter);
        Draws {
            rng,
            window: IterationWindow {
                seed,
                iteration,
                path,
                window,
            },
        }
    }

    /// Replay the draws of a recorded iteration up to its window (checked against the
    /// record), ready for [`Self::timestep`].
    pub fn replay(w: &IterationWindow) -> Result<Draws> {
        let d = Draws::new(w.seed, w.iteration, w.path, w.window.views.len());
        if d.window != *w {
            return Err(Error::param(format!(
                "the recorded window {:?} of iteration {} (seed {}) is not the one its \
                 draws give ({:?})",
                w.window.views, w.iteration, w.seed, d.window.window.views
            )));
        }
        Ok(d)
    }

    /// The iteration and its window.
    pub fn window(&self) -> &IterationWindow {
        &self.window
    }

    /// Draw the timestep from `set` by `schedule` (after the window).
    pub fn timestep(&mut self, schedule: TimestepSchedule, set: &TimestepSet) -> usize {
        schedule.draw(set, self.window.iteration, &mut self.rng)
    }

    /// Draw eps for latents of `shape` `[N, C, h, w]`, then eps' (after the timestep).
    pub fn noise(&mut self, shape: [usize; 4]) -> Noise {
        let [n, c, h, w] = shape;
        let eps = Array4::from_shape_vec(shape, self.rng.normals_f32(n * c * h * w))
            .expect("length matches");
        let eps_shared = Array3::from_shape_vec((c, h, w), self.rng.normals_f32(c * h * w))
            .expect("length matches");
        Noise { eps, eps_shared }
    }
}

/// The colour fit's settings for the loop's configuration, rendering over `background`.
pub fn fit_params(p: &Config, background: [f32; 3]) -> FitParams {
    FitParams {
        lr_dc: p.lr_dc,
        lr_rest: if p.sh.fitted() { p.lr_dc / 20.0 } else { 0.0 },
        ssim_weight: 0.0,
        mask_alpha: false,
        cache: CacheMode::On,
        background,
        progress: false,
    }
}

/// The renders `[H, W, 3]` of cameras `views` with the fit's current colours (not
/// clamped: colours have no upper bound).
pub fn render_window(fit: &ColourFit<'_>, views: &[usize]) -> Vec<Vec<f32>> {
    views.iter().map(|&v| fit.render_view(v)).collect()
}

/// Stack `[C, H, W]` images (or latents) into `[N, C, H, W]`.
pub fn stack(xs: &[Array3<f32>]) -> Result<Array4<f32>> {
    let v: Vec<_> = xs.iter().map(|a| a.view().insert_axis(Axis(0))).collect();
    concatenate(Axis(0), &v).map_err(|e| Error::Other(e.to_string()))
}

/// Encode images `[3, H, W]` to latents `[N, C, h, w]`, `batch` images per call (0 = all
/// in one); refuses a non-finite latent.
pub fn encode_views(
    prior: &mut dyn Prior,
    images: &[Array3<f32>],
    batch: usize,
) -> Result<Array4<f32>> {
    let batch = if batch == 0 { images.len() } else { batch };
    let mut parts = Vec::with_capacity(images.len().div_ceil(batch.max(1)));
    for chunk in images.chunks(batch.max(1)) {
        parts.push(prior.encode(stack(chunk)?.view())?);
    }
    let views: Vec<_> = parts.iter().map(|a| a.view()).collect();
    let z = concatenate(Axis(0), &views).map_err(|e| Error::Other(e.to_string()))?;
    if let Some(x) = z.iter().find(|x| !x.is_finite()) {
        return Err(Error::Onnx(format!("the VAE encoder produced {x}")));
    }
    Ok(z)
}

/// The latents of one iteration's two branches, `[N, C, h, w]` each.
#[derive(Debug, Clone)]
pub struct IterLatents {
    /// Clean latents of the renders (target branch).
    pub z0: Array4<f32>,
    /// Clean latents of the source views (source branch).
    pub z0_src: Array4<f32>,
    /// The noise both branches share.
    pub eps: Array4<f32>,
    /// Noised (and MVFC-filtered) target latents.
    pub z_tgt: Array4<f32>,
    /// Noised (and, with MVFC's `source`, filtered) source latents.
    pub z_src: Array4<f32>,
    /// The timestep.
    pub t: usize,
}

/// Noise both branches with the same eps at `t`; MVFC on the target (and on the source
/// with `mvfc.source`) along the path, with the same eps' ([`mvfc_path`]; `circular`:
/// the window's ends are neighbours). `mvfc.enabled = false` is "without MVFC".
pub fn noise_branches(
    schedule: &Schedule,
    z0: Array4<f32>,
    z0_src: Array4<f32>,
    noise: &Noise,
    t: usize,
    mvfc: &crate::mvfc::MvfcParams,
    circular: bool,
) -> Result<IterLatents> {
    if z0.shape() != z0_src.shape() || z0.shape() != noise.eps.shape() {
        return Err(Error::param(format!(
            "latents of the renders {:?}, of the source views {:?} and the noise {:?} differ \
             in shape",
            z0.shape(),
            z0_src.shape(),
            noise.eps.shape()
        )));
    }
    let ph = crate::timing::span("noise");
    let src_noisy = schedule.add_noise(z0_src.view(), noise.eps.view(), t)?;
    let z_noisy = schedule.add_noise(z0.view(), noise.eps.view(), t)?;
    drop(ph);
    let ph = crate::timing::span("mvfc");
    let es = noise.eps_shared.view();
    let (z_tgt, z_src) = if mvfc.enabled {
        (
            mvfc_path(z_noisy.view(), es, *mvfc, circular)?,
            if mvfc.source {
                mvfc_path(src_noisy.view(), es, *mvfc, circular)?
            } else {
                src_noisy
            },
        )
    } else {
        (z_noisy, src_noisy)
    };
    drop(ph);
    Ok(IterLatents {
        z0,
        z0_src,
        eps: noise.eps.clone(),
        z_tgt,
        z_src,
        t,
    })
}

/// The control image `[N, 3, H, W]` a ControlNet prior wants for source views `views`
/// (geometry is frozen, so it comes from the original renders): for
/// [`ControlKind::Source`] the source view as the prior sees it (`seen(v)`) (with
/// [`ControlKind::SourceAlpha`] its coverage as a fourth channel), else
/// [`crate::prior::control_image`] of the source's RGB, depth and alpha. `None` for a
/// prior without one.
pub fn control(
    kind: Option<ControlKind>,
    source: &SourceViews,
    seen: &dyn Fn(usize) -> Array3<f32>,
    views: &[usize],
) -> Result<Option<Array4<f32>>> {
    let (h, w) = (source.height, source.width);
    let n = views.len();
    Ok(match kind {
        Some(ControlKind::Source) => {
            let imgs: Vec<Array3<f32>> = views.iter().map(|&v| seen(v)).collect();
            Some(stack(&imgs)?)
        }
        Some(ControlKind::SourceAlpha) => {
            let imgs: Vec<Array3<f32>> = views
                .iter()
                .map(|&v| {
                    let a = Array3::from_shape_vec((1, h, w), source.alpha[v].clone())
                        .map_err(|e| Error::Other(e.to_string()))?;
                    concatenate(Axis(0), &[seen(v).view(), a.view()])
                        .map_err(|e| Error::Other(e.to_string()))
                })
                .collect::<Result<_>>()?;
            Some(stack(&imgs)?)
        }
        Some(kind) => {
            let pick = |xs: &Vec<Vec<f32>>, c: usize| -> Array4<f32> {
                Array4::from_shape_fn((n, h, w, c), |(i, y, x, k)| {
                    xs[views[i]][(y * w + x) * c + k]
                })
            };
            let rgb = pick(&source.rgb, 3);
            let depth = pick(&source.depth, 1).remove_axis(Axis(3));
            let alpha = pick(&source.alpha, 1).remove_axis(Axis(3));
            Some(crate::prior::control_image(
                kind,
                rgb.view(),
                depth.view(),
                alpha.view(),
            )?)
        }
        None => None,
    })
}

/// What the prior asks for in one CSD step.
#[derive(Debug, Clone)]
pub struct PriorChange {
    /// z0' = z0 - lr w(t) g.
    pub z1: Array4<f32>,
    /// w(t) g.
    pub grad: Array4<f32>,
    /// The image change Delta = decode(z0') - decode(z0), `[N, 3, H, W]`.
    pub delta: Array4<f32>,
    /// Seconds in the CSD step (the UNet) and in the two decodes.
    pub unet_s: f64,
    pub vae_s: f64,
}

/// The CSD step on `x` ([`csd::step`], with z0_src for the source branch) and the image
/// change it asks for ([`csd::image_change`]) at views of `size` (h, w).
pub fn prior_change(
    prior: &mut dyn Prior,
    schedule: &Schedule,
    x: &IterLatents,
    control: Option<ArrayView4<'_, f32>>,
    p: &CsdParams,
    (h, w): (usize, usize),
) -> Result<PriorChange> {
    let started = Instant::now();
    let ph = crate::timing::span("csd");
    let (z1, grad) = csd::step(
        prior,
        schedule,
        csd::StepInputs {
            z0: x.z0.view(),
            z_tgt: x.z_tgt.view(),
            z_src: x.z_src.view(),
            eps: x.eps.view(),
            z0_src: Some(x.z0_src.view()),
            t: x.t,
            control,
        },
        p,
    )?;
    drop(ph);
    let unet_s = started.elapsed().as_secs_f64();
    let started = Instant::now();
    let ph = crate::timing::span("decode");
    let delta = csd::image_change(prior, z1.view(), x.z0.view(), h, w)?;
    drop(ph);
    Ok(PriorChange {
        z1,
        grad,
        delta,
        unet_s,
        vae_s: started.elapsed().as_secs_f64(),
    })
}

/// How targets are made from the image change.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetParams {
    /// The background the renders are composited over.
    pub background: [f32; 3],
    /// Keep the source's chroma, take only the new luminance.
    pub preserve_color: bool,
}

/// The colour targets `[N, H, W, 3]` of one iteration: the object's colour c (the render
/// un-premultiplied by its alpha, not clamped) moves to c' = c + Delta (with
/// `preserve_color`: the luminance of that and the chroma of the source colour,
/// [`keep_chroma`]), limited to [min(c, 0), max(c, 1)], and the render moves by the
/// alpha-weighted change: target = render + alpha (c' - c). Delta = 0 gives the render
/// bit for bit; a thin fringe (small alpha) asks for a small change only.
///
/// Per view i: `renders[i]` `[H, W, 3]`, `alpha[i]` `[H, W]` (the source's coverage),
/// `source_colour[i]` `[H, W, 3]` (the source un-premultiplied, for `preserve_color`);
/// `delta` `[N, 3, H, W]`.
pub fn targets(
    renders: &[&[f32]],
    alpha: &[&[f32]],
    source_colour: &[&[f32]],
    delta: ArrayView4<'_, f32>,
    tp: TargetParams,
) -> Result<(Array4<f32>, TargetStats)> {
    let (n, _, h, w) = delta.dim();
    if renders.len() != n || alpha.len() != n || source_colour.len() != n {
        return Err(Error::param(format!(
            "targets: {n} image changes for {} renders, {} alpha planes and {} source colours",
            renders.len(),
            alpha.len(),
            source_colour.len()
        )));
    }
    let bg = tp.background;
    let mut out = Array4::<f32>::zeros((n, h, w, 3));
    let (mut d2, mut covered, mut clipped) = (0.0f64, 0usize, 0usize);
    for i in 0..n {
        let (alpha, src) = (alpha[i], source_colour[i]);
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
                        return Err(Error::Other(
                            "the prior asked for a non-finite image change".into(),
                        ));
                    }
                    c[k] = c0[k] + d;
                    if a > 0.5 {
                        d2 += (d * d) as f64;
                    }
                }
                if tp.preserve_color {
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
                    out[[i, y, x, k]] = rgb[k] + a * (c[k] - c0[k]);
                }
            }
        }
    }
    let stats = TargetStats {
        delta_rms: (d2 / (3 * covered.max(1)) as f64).sqrt(),
        clipped: clipped as f64 / covered.max(1) as f64,
    };
    Ok((out, stats))
}

/// The colour step's terms ([`super::terms`]) and what they see.
#[derive(Debug, Clone, Copy)]
pub struct ColourStep<'t> {
    /// The prior's term: the colour loss against the targets, weighted (`None`: no
    /// prior term; the targets then ask nothing).
    pub prior: Option<PriorTerm>,
    /// The VGG texture terms ([`super::terms::texture`]), if any; they see each render
    /// as the prior does ([`prior_image`] with `background`, `fill`).
    pub texture: Option<&'t TextureTerm>,
    /// The view terms that are on, with their weights ([`crate::terms::ViewTerm`]); they
    /// see the render itself and the source coverage.
    pub views: &'t [(f32, Box<dyn crate::terms::ViewTerm>)],
    pub background: [f32; 3],
    pub fill: bool,
    /// The iteration's index: which of the window's views get the texture term
    /// ([`TextureTerm::applies`]).
    pub iteration: u64,
}

/// One Adam step of the fit's SH colours on cameras `views` towards `targets`
/// `[N, H, W, 3]` (one per view, in the order of `views`; `alpha[i]` `[H, W]` is view
/// i's source coverage, which the texture terms mask with): per view the gradient at the
/// render is the prior term's ([`PriorTerm::view`]; zero without one) plus the texture
/// terms' ([`TextureTerm::view_grad`], on the views [`TextureTerm::applies`] picks) plus
/// the view terms' (their losses added to the colour loss); the
/// optimizer state is the fit's and persists. Returns the mean colour loss and the mean
/// texture loss over the views before the step.
pub fn colour_step(
    fit: &mut ColourFit<'_>,
    views: &[usize],
    targets: ArrayView4<'_, f32>,
    alpha: &[&[f32]],
    cs: &ColourStep<'_>,
) -> Result<(f64, f64)> {
    let (n, h, w, _) = targets.dim();
    if n != views.len() || alpha.len() != n {
        return Err(Error::param(format!(
            "{n} target images and {} alpha planes for a window of {} views",
            alpha.len(),
            views.len()
        )));
    }
    let index: std::collections::HashMap<usize, usize> =
        views.iter().enumerate().map(|(i, &v)| (v, i)).collect();
    let tex = cs.texture;
    let mut tex_loss = 0.0f64;
    let mut loss = |v: usize, rgb: &[f32], _a: Option<&[f32]>| -> Result<(f64, Vec<f32>)> {
        let i = index[&v];
        let target = targets.index_axis(Axis(0), i);
        let target = target
            .as_slice()
            .ok_or_else(|| Error::Other("targets are not in standard layout".into()))?;
        let (l, mut g) = match &cs.prior {
            Some(p) => p.view(rgb, target, h, w),
            None => (0.0, vec![0.0; rgb.len()]),
        };
        // The term on some of the window's views (rotating with the iteration), scaled so
        // its gradient is the same in expectation ([`TextureTerm::applies`]).
        if let Some((t, scale)) = tex.and_then(|t| t.applies(i, n, cs.iteration).map(|s| (t, s))) {
            let ph = crate::timing::span("texture");
            let seen = prior_image(rgb, alpha[i], cs.background, cs.fill, (h, w));
            let tg = t.view_grad(&seen, alpha[i], h, w)?;
            drop(ph);
            tex_loss += tg.loss * scale as f64 / n as f64;
            for (a, b) in g.iter_mut().zip(&tg.grad) {
                *a += scale * b;
            }
        }
        let mut l = l;
        for (weight, term) in cs.views {
            let (lv, gv) = term.view(rgb, alpha[i], h, w);
            l += *weight as f64 * lv;
            for (a, b) in g.iter_mut().zip(&gv) {
                *a += weight * b;
            }
        }
        Ok((l, g))
    };
    let loss = fit.step_views(views, &mut loss)?;
    Ok((loss, tex_loss))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replay_gives_the_same_draws_and_refuses_a_foreign_window() {
        let path = ViewPath {
            len: 8,
            closed: true,
        };
        let set = TimestepSet::new(
            &crate::scheduler::SchedulerConfig::stable_diffusion(),
            20,
            980,
            50,
        )
        .unwrap();
        let mut a = Draws::new(5, 7, path, 3);
        let mut b = Draws::replay(a.window()).unwrap();
        assert_eq!(
            a.timestep(TimestepSchedule::Random, &set),
            b.timestep(TimestepSchedule::Random, &set)
        );
        let (na, nb) = (a.noise([3, 2, 3, 5]), b.noise([3, 2, 3, 5]));
        assert_eq!((na.eps, na.eps_shared), (nb.eps, nb.eps_shared));
        let mut w = a.window().clone();
        w.window.views = w.window.views.iter().map(|v| (v + 1) % 8).collect();
        let e = Draws::replay(&w).unwrap_err().to_string();
        assert!(e.contains("not the one its draws give"), "{e}");
    }

    #[test]
    fn zero_change_targets_are_the_render_bit_for_bit() {
        let (h, w) = (3, 4);
        let render: Vec<f32> = (0..h * w * 3).map(|i| (i % 7) as f32 / 5.0).collect();
        let alpha: Vec<f32> = (0..h * w).map(|i| (i % 4) as f32 / 3.0).collect();
        let delta = Array4::<f32>::zeros((1, 3, h, w));
        let tp = TargetParams {
            background: [0.2, 0.3, 0.4],
            preserve_color: false,
        };
        let (t, s) = targets(&[&render], &[&alpha], &[&render], delta.view(), tp).unwrap();
        assert_eq!(t.as_slice().unwrap(), &render[..]);
        assert_eq!(s.delta_rms, 0.0);
    }
}

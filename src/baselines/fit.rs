//! Colour-only optimisation of a scene against an image-space [`Objective`]: the loop the
//! baselines run. Geometry (positions, scales, rotations, opacities) is never written;
//! only `sh_dc` and `sh_rest` change.
//!
//! The loop is the colour fit of [`crate::optim::ColourFit`] (frozen-geometry caches, the
//! colour backward pass, Adam with separate DC / higher-order learning rates), driven
//! through its image-gradient hook [`ColourFit::step_with`]: each step renders every view,
//! evaluates the objective on it, and chains dL/d(rgb) into the SH coefficients. Without
//! an objective (the refit baseline) it is the plain target fit ([`ColourFit::step`],
//! L1 + D-SSIM).

use super::Objective;
use crate::imageio::Image;
use crate::optim::{ColourFit, FitParams};
use crate::render::{RenderOptions, render};
use crate::{Camera, Error, Result, Scene};

/// Settings of the colour fit.
#[derive(Debug, Clone, PartialEq)]
pub struct FitOptions {
    /// Most steps (a step callback may stop the fit earlier, e.g. at a time budget).
    pub steps: usize,
    /// Learning rates, background, cache mode of the underlying colour fit.
    pub fit: FitParams,
    /// Evaluate the monitor (e.g. Gram distance) every this many steps (and at the ends).
    pub monitor_every: usize,
    /// Views per step: `None` (or at least the number of views) = every view, in order,
    /// each step; `Some(k)` = `k` distinct views per step, drawn from seeded shuffles of
    /// all views (one shuffle per pass, so every view is visited equally often), as ARF
    /// and SGSST sample views.
    pub views_per_step: Option<usize>,
    /// Seed of the view draws.
    pub seed: u64,
}

impl FitOptions {
    /// All views per step, seed 0.
    pub fn new(steps: usize, fit: FitParams, monitor_every: usize) -> FitOptions {
        FitOptions {
            steps,
            fit,
            monitor_every,
            views_per_step: None,
            seed: 0,
        }
    }
}

/// The views of successive steps: all of them in order, or `k` distinct ones per step
/// from seeded per-pass shuffles (see [`FitOptions::views_per_step`]).
#[derive(Debug)]
pub struct ViewSchedule {
    n: usize,
    k: usize,
    rng: crate::rng::Rng,
    queue: std::collections::VecDeque<usize>,
}

impl ViewSchedule {
    pub fn new(n: usize, k: Option<usize>, seed: u64) -> ViewSchedule {
        ViewSchedule {
            n,
            k: k.map_or(n, |k| k.clamp(1, n.max(1))),
            rng: crate::rng::Rng::derive(seed, "baseline-view-schedule"),
            queue: Default::default(),
        }
    }

    /// The views of the next step.
    pub fn next_views(&mut self) -> Vec<usize> {
        if self.k >= self.n {
            return (0..self.n).collect();
        }
        let mut out: Vec<usize> = Vec::with_capacity(self.k);
        while out.len() < self.k {
            if self.queue.is_empty() {
                let mut perm: Vec<usize> = (0..self.n).collect();
                for i in (1..self.n).rev() {
                    let j = (self.rng.next_u64() % (i as u64 + 1)) as usize;
                    perm.swap(i, j);
                }
                self.queue.extend(perm);
            }
            // A view already drawn this step waits for the next step.
            let pos = self.queue.iter().position(|v| !out.contains(v));
            match pos {
                Some(p) => out.push(self.queue.remove(p).expect("in range")),
                None => {
                    let mut perm: Vec<usize> = (0..self.n).collect();
                    for i in (1..self.n).rev() {
                        let j = (self.rng.next_u64() % (i as u64 + 1)) as usize;
                        perm.swap(i, j);
                    }
                    self.queue.extend(perm);
                }
            }
        }
        out
    }
}

/// One line of `loss.json`: the objective before the update of step `step`, and the
/// monitor on the same scene when it was evaluated. The last entry (step = steps) is the
/// final scene, after every update.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StepLog {
    pub step: usize,
    pub total: f64,
    pub style: f64,
    pub content: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gram_distance: Option<f64>,
}

/// A measure of the current renders logged beside the loss (the Gram distance).
pub type Monitor<'a> = &'a dyn Fn(&[Image]) -> Result<f64>;

fn render_all(scene: &Scene, cameras: &[Camera], background: [f32; 3]) -> Result<Vec<Image>> {
    let opts = RenderOptions { background };
    cameras
        .iter()
        .map(|c| {
            let r = render(scene, c, &opts)?;
            Ok(Image {
                width: r.width,
                height: r.height,
                data: r.rgb,
            })
        })
        .collect()
}

/// Optimise the colours of `scene` seen from `cameras` for `obj` (or, when `obj` is
/// `None`, fit `targets` with the L1 + D-SSIM loss; with an objective `targets` only has
/// to match the cameras' sizes, e.g. the original renders). `monitor` maps the current
/// renders to a number logged as `gram_distance` (every `monitor_every` steps and at the
/// first and last entries); with a monitor the last entry is the final scene's loss over
/// every view, without one the log ends with the last step's. `on_step(steps_done,
/// scene)` is called after each step (progress bars, checkpoints, a time budget) and
/// stops the fit early by returning `false`.
pub fn fit_objective(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    obj: Option<&dyn Objective>,
    opts: &FitOptions,
    monitor: Option<Monitor<'_>>,
    on_step: &mut dyn FnMut(usize, &Scene) -> Result<bool>,
) -> Result<(Scene, Vec<StepLog>)> {
    if cameras.is_empty() {
        return Err(Error::param("the view set is empty: nothing to stylize"));
    }
    let mut fit = ColourFit::new(scene, cameras, targets, &opts.fit)?;
    let mut log = Vec::with_capacity(opts.steps + 1);
    let mut schedule = ViewSchedule::new(cameras.len(), opts.views_per_step, opts.seed);
    let mut stopped = false;
    for step in 0..=opts.steps {
        let last = step == opts.steps || stopped;
        let want_monitor =
            step == 0 || last || (opts.monitor_every > 0 && step % opts.monitor_every == 0);
        let gram_distance = match monitor {
            Some(m) if want_monitor => {
                Some(m(&render_all(fit.scene(), cameras, opts.fit.background)?)?)
            }
            _ => None,
        };
        let mut entry = StepLog {
            step,
            total: 0.0,
            style: 0.0,
            content: 0.0,
            gram_distance,
        };
        if last && monitor.is_none() {
            break;
        }
        if last {
            final_loss(&fit, cameras, targets, obj, opts, &mut entry)?;
            log.push(entry);
            break;
        }
        let views = schedule.next_views();
        one_step(
            &mut fit,
            cameras,
            targets,
            obj,
            opts,
            (step, &views),
            &mut entry,
        )?;
        log.push(entry);
        stopped = !on_step(step + 1, fit.scene())?;
    }
    Ok((fit.finish().0, log))
}

/// The final scene's loss over every view, without an update, into `entry`.
fn final_loss(
    fit: &ColourFit<'_>,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    obj: Option<&dyn Objective>,
    opts: &FitOptions,
    entry: &mut StepLog,
) -> Result<()> {
    let nv = cameras.len() as f64;
    let imgs = render_all(fit.scene(), cameras, opts.fit.background)?;
    for (v, img) in imgs.iter().enumerate() {
        let (total, style, content) = match obj {
            Some(o) => {
                let t = o.eval(v, img)?;
                (t.total, t.style, t.content)
            }
            None => {
                let lp = crate::optim::LossParams {
                    ssim_weight: opts.fit.ssim_weight,
                };
                let l = crate::optim::loss_and_grad(
                    &img.data,
                    &targets[v],
                    None,
                    img.height,
                    img.width,
                    lp,
                )
                .0 as f64;
                (l, l, 0.0)
            }
        };
        entry.total += total / nv;
        entry.style += style / nv;
        entry.content += content / nv;
    }
    Ok(())
}

/// One step of the fit on `views` (step `step`): the objective's gradient, or the target
/// fit's; its loss into `entry`.
fn one_step(
    fit: &mut ColourFit<'_>,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    obj: Option<&dyn Objective>,
    opts: &FitOptions,
    (step, views): (usize, &[usize]),
    entry: &mut StepLog,
) -> Result<()> {
    let nv = views.len() as f64;
    match obj {
        Some(o) => {
            let (mut style, mut content) = (0.0, 0.0);
            let mut hook = |v: usize, rgb: &[f32], _alpha: Option<&[f32]>| {
                let cam = &cameras[v];
                let img = Image {
                    width: cam.width as usize,
                    height: cam.height as usize,
                    data: rgb.to_vec(),
                };
                let t = o.eval(v, &img)?;
                if !t.total.is_finite() {
                    return Err(Error::Other(format!(
                        "the loss became {} at step {step}, view {v}",
                        t.total
                    )));
                }
                style += t.style / nv;
                content += t.content / nv;
                Ok((t.total, t.grad))
            };
            entry.total = fit.step_views(views, &mut hook)?;
            entry.style = style;
            entry.content = content;
        }
        None if views.len() == cameras.len() => {
            let l = fit.step() as f64;
            (entry.total, entry.style) = (l, l);
        }
        None => {
            let lp = crate::optim::LossParams {
                ssim_weight: opts.fit.ssim_weight,
            };
            let mut hook = |v: usize, rgb: &[f32], alpha: Option<&[f32]>| {
                let cam = &cameras[v];
                let (h, w) = (cam.height as usize, cam.width as usize);
                let (l, g) = crate::optim::loss_and_grad(rgb, &targets[v], alpha, h, w, lp);
                Ok((l as f64, g))
            };
            let l = fit.step_views(views, &mut hook)?;
            (entry.total, entry.style) = (l, l);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_view_set_is_an_error() {
        let scene = Scene::default();
        let opts = FitOptions::new(1, FitParams::default(), 0);
        let e =
            fit_objective(&scene, &[], &[], None, &opts, None, &mut |_, _| Ok(true)).unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
    }

    /// Subsets: k distinct views per step, every view equally often over whole passes,
    /// the same draws for the same seed; all views (in order) without a subset.
    #[test]
    fn view_schedule_visits_views_evenly() {
        let mut all = ViewSchedule::new(5, None, 1);
        assert_eq!(all.next_views(), vec![0, 1, 2, 3, 4]);
        assert_eq!(
            ViewSchedule::new(5, Some(9), 1).next_views(),
            vec![0, 1, 2, 3, 4]
        );
        for k in [1, 2, 3] {
            let mut s = ViewSchedule::new(6, Some(k), 4);
            let mut count = [0usize; 6];
            let mut draws = Vec::new();
            for _ in 0..(6 * 10 / k) {
                let v = s.next_views();
                assert_eq!(v.len(), k);
                let mut u = v.clone();
                u.sort();
                u.dedup();
                assert_eq!(u.len(), k, "{v:?}");
                v.iter().for_each(|&i| count[i] += 1);
                draws.push(v);
            }
            // Over 10 passes each view is drawn 10 times, give or take the pass boundaries.
            assert!(
                count.iter().all(|&c| (9..=11).contains(&c)),
                "k {k}: {count:?}"
            );
            let mut again = ViewSchedule::new(6, Some(k), 4);
            assert_eq!(again.next_views(), draws[0]);
        }
    }
}

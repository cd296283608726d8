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
    pub steps: usize,
    /// Learning rates, background, cache mode of the underlying colour fit.
    pub fit: FitParams,
    /// Evaluate the monitor (e.g. Gram distance) every this many steps (and at the ends).
    pub monitor_every: usize,
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
/// first and last entries). `on_step` is called after each step (progress bars).
pub fn fit_objective(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    obj: Option<&dyn Objective>,
    opts: &FitOptions,
    monitor: Option<Monitor<'_>>,
    on_step: &mut dyn FnMut(usize),
) -> Result<(Scene, Vec<StepLog>)> {
    if cameras.is_empty() {
        return Err(Error::param("the view set is empty: nothing to stylize"));
    }
    let nv = cameras.len() as f64;
    let mut fit = ColourFit::new(scene, cameras, targets, &opts.fit)?;
    let mut log = Vec::with_capacity(opts.steps + 1);
    for step in 0..=opts.steps {
        let want_monitor = step == 0
            || step == opts.steps
            || (opts.monitor_every > 0 && step % opts.monitor_every == 0);
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
        if step == opts.steps {
            // The final scene's loss, without an update.
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
            log.push(entry);
            break;
        }
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
                entry.total = fit.step_with(&mut hook)?;
                entry.style = style;
                entry.content = content;
            }
            None => {
                let l = fit.step() as f64;
                (entry.total, entry.style) = (l, l);
            }
        }
        log.push(entry);
        on_step(step + 1);
    }
    Ok((fit.finish().0, log))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn empty_view_set_is_an_error() {
        let scene = Scene::default();
        let opts = FitOptions {
            steps: 1,
            fit: FitParams::default(),
            monitor_every: 0,
        };
        let e = fit_objective(&scene, &[], &[], None, &opts, None, &mut |_| {}).unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
    }
}

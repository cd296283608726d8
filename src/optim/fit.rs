//! The parameters of a colour fit ([`super::fit_colours`], [`super::ColourFit`]), its
//! report and the checks of its inputs. 3DGS uses
//! separate learning rates for `f_dc` and `f_rest` (`f_rest = f_dc / 20`).

use crate::render::{CacheMode, validate_camera, validate_scene};
use crate::{Camera, Error, Result, Scene};

/// Parameters of [`super::fit_colours`].
#[derive(Debug, Clone, PartialEq)]
pub struct FitParams {
    /// Adam learning rate of `f_dc` (3DGS: 0.0025).
    pub lr_dc: f32,
    /// Adam learning rate of `f_rest` (3DGS: `lr_dc / 20`).
    pub lr_rest: f32,
    /// lambda of the D-SSIM term.
    pub ssim_weight: f32,
    /// Multiply render and target by the rendered alpha before the loss.
    pub mask_alpha: bool,
    pub cache: CacheMode,
    /// Background colour the renders are composited over.
    pub background: [f32; 3],
    /// Show a progress bar.
    pub progress: bool,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            lr_dc: 0.0025,
            lr_rest: 0.0025 / 20.0,
            ssim_weight: 0.2,
            mask_alpha: false,
            cache: CacheMode::On,
            background: [0.0; 3],
            progress: false,
        }
    }
}

/// What a fit did besides updating colours.
#[derive(Debug, Clone, PartialEq)]
pub struct FitReport {
    /// Mean loss over views, per step (before that step's update).
    pub losses: Vec<f32>,
    /// Views whose contributions were cached.
    pub cached_views: usize,
    /// Bytes held by the caches.
    pub cache_bytes: usize,
}

pub(super) fn check_params(
    scene: &Scene,
    cameras: &[Camera],
    targets: &[Vec<f32>],
    steps: usize,
    p: &FitParams,
) -> Result<()> {
    validate_scene(scene)?;
    if steps == 0 {
        return Err(Error::param("steps must be at least 1"));
    }
    if cameras.is_empty() {
        return Err(Error::param("no cameras to fit to"));
    }
    if targets.len() != cameras.len() {
        return Err(Error::param(format!(
            "{} target images for {} cameras",
            targets.len(),
            cameras.len()
        )));
    }
    for (i, (c, t)) in cameras.iter().zip(targets).enumerate() {
        validate_camera(c)?;
        let want = c.width as usize * c.height as usize * 3;
        if t.len() != want {
            return Err(Error::param(format!(
                "target {i} has {} values; camera {:?} is {}x{} (needs {want})",
                t.len(),
                c.name,
                c.width,
                c.height
            )));
        }
        if let Some(j) = t.iter().position(|v| !v.is_finite()) {
            return Err(Error::param(format!(
                "target {i} has a non-finite value at index {j}"
            )));
        }
    }
    check_options(p)
}

/// Learning rates, SSIM weight and background of a fit.
pub(super) fn check_options(p: &FitParams) -> Result<()> {
    let lr_ok = |v: f32| v.is_finite() && v >= 0.0;
    if !(lr_ok(p.lr_dc) && lr_ok(p.lr_rest)) {
        return Err(Error::param(format!(
            "learning rates must be finite and >= 0 (lr_dc {}, lr_rest {})",
            p.lr_dc, p.lr_rest
        )));
    }
    if !(0.0..=1.0).contains(&p.ssim_weight) {
        return Err(Error::param(format!(
            "ssim weight {} is outside [0, 1]",
            p.ssim_weight
        )));
    }
    if !p.background.iter().all(|v| v.is_finite()) {
        return Err(Error::param("background colour is not finite"));
    }
    Ok(())
}

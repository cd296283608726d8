//! Fitting SH colours to target images with geometry frozen (issue: update-gaussians).
//!
//! Loss (Kerbl et al. 2023, Eq. 7): `L = (1 - lambda) L1 + lambda (1 - SSIM)`, lambda =
//! 0.2, with SSIM as in the 3DGS code: 11x11 Gaussian window, sigma 1.5, zero "same"
//! padding, `C1 = 0.01^2`, `C2 = 0.03^2`, averaged over pixels and channels (Wang et al.
//! 2004). The optional alpha mask multiplies both the render and the target by the
//! rendered alpha (constant, geometry is frozen) before the loss, so uncovered pixels
//! carry no loss. [`loss_and_grad`] returns the loss and its exact gradient w.r.t. the
//! rendered image.
//!
//! Optimiser: Adam (Kingma & Ba 2015) with beta1 = 0.9, beta2 = 0.999 and eps = 1e-15
//! as in 3DGS, and separate learning rates for `f_dc` and `f_rest` (3DGS uses
//! `f_rest = f_dc / 20`). One step of [`fit_colours`] renders every view, sums the
//! per-view losses' gradients (divided by the number of views) and updates once; the
//! loss recorded per step is the mean over views before the update.
//!
//! One module per concern: `loss` (L1 + D-SSIM and its gradient, SSIM, PSNR), `adam`
//! (the optimiser and its saved state), `fit` ([`fit_colours`], its parameters and
//! checks) and `colour_fit` ([`ColourFit`], the state of a fit and its steps).

mod adam;
mod colour_fit;
mod fit;
mod loss;

pub use adam::{Adam, AdamState, OptimizerState};
pub use colour_fit::{ColourFit, ViewLoss, fit_colours};
pub use fit::{FitParams, FitReport};
pub use loss::{
    LossParams, LossScratch, SSIM_C1, SSIM_C2, l2, loss_and_grad, loss_and_grad_into, psnr, ssim,
};

#[cfg(test)]
mod tests;

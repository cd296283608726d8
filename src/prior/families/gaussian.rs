//! The `gaussian` family: the closed-form optimal denoiser for Gaussian-distributed
//! latents ([`crate::prior::gaussian`]), shipped as tiny ONNX graphs with the real I/O
//! contract of the diffusion families. It is validated and opened as they are
//! ([`super::diffusion`]), with no fixed VAE scaling factor (its VAE is its own).

use super::diffusion;
use crate::Result;
use crate::prior::manifest::{ModelDir, TimestepRange};
use crate::prior::{Prior, PriorOptions};

/// The diffusion contract, any positive VAE scaling factor.
pub fn validate(md: &ModelDir) -> Result<()> {
    diffusion::validate(md, None)
}

/// The scheduler's default timestep set.
pub fn timesteps(md: &ModelDir) -> Result<Option<TimestepRange>> {
    diffusion::timesteps(md)
}

/// Opened as an ONNX diffusion prior.
pub fn open(md: ModelDir, opts: &PriorOptions) -> Result<Box<dyn Prior>> {
    diffusion::open(md, opts)
}

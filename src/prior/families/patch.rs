//! The `patch` family: the weight-free patch prior ([`crate::prior::patch`]), whose
//! clean-image model is the style image's patches. Its fields live under the manifest's
//! `patch` ([`crate::prior::patch::PatchConfig`]) and are checked when it opens.

use super::section_timesteps;
use crate::Result;
use crate::prior::manifest::{ModelDir, TimestepRange};
use crate::prior::patch::PatchPrior;
use crate::prior::{Prior, PriorOptions};

/// Nothing beyond the format and the scheduler: the prior validates its own fields.
pub fn validate(_: &ModelDir) -> Result<()> {
    Ok(())
}

/// `patch.timesteps`, if given.
pub fn timesteps(md: &ModelDir) -> Result<Option<TimestepRange>> {
    section_timesteps(md, "patch", md.manifest.patch.as_ref())
}

/// The patch prior with the options' style image.
pub fn open(md: ModelDir, opts: &PriorOptions) -> Result<Box<dyn Prior>> {
    Ok(Box::new(PatchPrior::open(&md, opts)?))
}

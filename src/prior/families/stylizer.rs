//! The `stylizer` family: a feed-forward 2D style-transfer network used as an
//! x0-predictor in pixel space (the MVFC/CSD stages' 2D-stylizer prior, real weights, the
//! CPU demo; [`crate::prior::stylizer`]). Its fields live under the manifest's
//! `stylizer` and are checked by that prior when it opens.

use super::section_timesteps;
use crate::Result;
use crate::prior::manifest::{ModelDir, TimestepRange};
use crate::prior::stylizer::StylizerPrior;
use crate::prior::{Prior, PriorOptions};

/// Nothing beyond the format and the scheduler: the prior validates its own fields.
pub fn validate(_: &ModelDir) -> Result<()> {
    Ok(())
}

/// `stylizer.timesteps`, if given.
pub fn timesteps(md: &ModelDir) -> Result<Option<TimestepRange>> {
    section_timesteps(md, "stylizer", md.manifest.stylizer.as_ref())
}

/// The stylizer with the options' style image, strength and motif scale.
pub fn open(md: ModelDir, opts: &PriorOptions) -> Result<Box<dyn Prior>> {
    Ok(Box::new(
        StylizerPrior::open_with(
            &md.dir,
            opts.style_image.as_ref().map(|a| a.view()),
            opts.session_config(),
        )?
        .with_strength(opts.strength.unwrap_or(1.0))?
        .with_motif_scale(opts.motif_scale.unwrap_or(1.0))?,
    ))
}

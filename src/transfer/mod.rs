//! Putting a style image's colours or texture on a scene without a prior: the tools the
//! ends (a start or a finish) and the baselines share, below both.
//!
//! | module | what |
//! |---|---|
//! | [`colour`] | the object's colour mean and covariance moved onto the style image's (ARF's colour transfer; Reinhard et al. 2001 in a correlated colour space) |
//! | [`projection`] | the style image texture-mapped onto the object: triplanar projection along each Gaussian's normal |

pub mod colour;
pub mod projection;

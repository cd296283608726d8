//! `test-grey`, a finish for the tests only: every Gaussian's base colour set to mid
//! grey. It is here to show that a new end is one file and one line of
//! [`super::ENDS`]: the configuration, `--help` and [`super::apply`] take it from there.

use super::{EndInputs, Role};
use crate::{Result, Scene};

/// `scene` with every base colour at SH DC 0 (grey 0.5).
pub fn run(_: Role, scene: &Scene, _: &EndInputs<'_>) -> Result<Scene> {
    let mut out = scene.clone();
    out.sh_dc.iter_mut().for_each(|c| *c = [0.0; 3]);
    Ok(out)
}

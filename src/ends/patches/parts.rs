//! The parts of the patch synthesis: what it matches and how beyond the colours, each
//! switched on by its own key of `[synthesis]`. A part is one of two kinds:
//!
//! - a [`Channel`]: one more image channel of every patch, matched beside the colours
//!   (the structure guide: StyLit's and EbSynth's guide channels, Fiser et al. 2016,
//!   Jamriska et al. 2019): the frozen source views give the object's, the style image
//!   its own, and the channel's weight says how much a pixel of it counts;
//! - a [`Rematch`]: the coupling made a second time with its distances changed after
//!   the first (the negative branch of CSD at t -> 0).
//!
//! A new part is one new file of this module and one line of [`super::PARTS`].

use super::SynthesisParams;
use super::coherence::Neighbour;
use crate::imageio::Image;
use ndarray::ArrayView3;

/// One more channel of every patch (module docs).
pub trait Channel: Sync {
    /// The channel of every source view (`[H W]` each) from the frozen source views
    /// (`rgb` `[H, W, 3]`, `alpha` `[H, W]`, `sizes` (H, W) per view, composited over
    /// `background`) and the style image.
    fn source(
        &self,
        rgb: &[Vec<f32>],
        alpha: &[Vec<f32>],
        sizes: &[(usize, usize)],
        background: [f32; 3],
        style: &Image,
    ) -> Vec<Vec<f32>>;
    /// The channel of the style image at one level (`[h w]`).
    fn style(&self, sized: &Image, p: &SynthesisParams) -> Vec<f32>;
    /// A source view's channel at one level (`[h w]`, pooled from [`Channel::source`]'s),
    /// as the match sees it (the default: as it is).
    fn at_level(&self, pooled: Vec<f32>, _size: (usize, usize), _p: &SynthesisParams) -> Vec<f32> {
        pooled
    }
    /// Its weight in the search: a patch's channel distance counts `weight^2` times.
    fn weight(&self, p: &SynthesisParams) -> f32;
    /// Whether, at each level, the object's channel (over its pixels of every view) has
    /// its spread narrowed to the spread of the level's style patches' channel where it
    /// is wider ([`super::guide::Moments::toward`]; the structure guide's,
    /// [`super::guide`]).
    fn matched_at_level(&self) -> bool {
        false
    }
    /// Where a query's channel is the object's: a share per pixel in [0, 1] (`[h w]`),
    /// from the view's channel at the level (`frozen`, [`Channel::at_level`]) and its
    /// coverage `alpha`, made once per level; the rest is the channel of the query's
    /// current colours ([`Channel::of_current`], [`follow`]). For a part that asks
    /// something only where the object has something to say and leaves the current
    /// texture free elsewhere (the edge guide, [`super::edges`]). `None` (the default):
    /// the object's everywhere.
    fn imposed(&self, _frozen: &[f32], _alpha: &[f32], _size: (usize, usize)) -> Option<Vec<f32>> {
        None
    }
    /// The channel of a query's current colours (`current` `[3, h, w]`, as the match
    /// sees them), read only where [`Channel::imposed`] leaves room (the default: zero).
    fn of_current(&self, current: ArrayView3<'_, f32>) -> Vec<f32> {
        vec![0.0; current.len() / 3]
    }
}

/// A query's channel: `share` of the object's (`frozen`) and the rest of its current
/// colours' (`current`), pixel by pixel ([`Channel::imposed`]).
pub fn follow(frozen: &[f32], share: &[f32], current: &[f32]) -> Vec<f32> {
    (frozen.iter().zip(share).zip(current))
        .map(|((&f, &m), &c)| m * f + (1.0 - m) * c)
        .collect()
}

/// A second coupling with changed distances (module docs).
pub trait Rematch: Sync {
    /// Change the distances `dist` `[P x cells]` (`arg`: each entry's style patch) given
    /// each query's first-pass match `first`, its neighbours `nbrs` and the style patches'
    /// positions `pos`; `mean_min` is the mean of the queries' nearest distances.
    #[allow(clippy::too_many_arguments)]
    fn penalise(
        &self,
        dist: &mut [f32],
        arg: &[u32],
        first: &[u32],
        nbrs: &[Vec<Neighbour>],
        pos: &[[i32; 2]],
        mean_min: f64,
        p: &SynthesisParams,
    );
}

/// What a part does.
#[derive(Clone, Copy)]
pub enum Hook {
    Channel(&'static dyn Channel),
    Rematch(&'static dyn Rematch),
}

/// One part: its name, the key that switches it on, a line of help, whether the
/// settings switch it on, and what it does.
#[derive(Clone, Copy)]
pub struct PartKind {
    pub name: &'static str,
    pub key: &'static str,
    pub help: &'static str,
    pub on: fn(&SynthesisParams) -> bool,
    pub hook: Hook,
}

impl std::fmt::Debug for PartKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PartKind")
            .field("name", &self.name)
            .finish()
    }
}

//! The source views: the original scene's renders from the run's cameras (colour,
//! coverage, expected depth, and the background they are composited over). Read from a
//! `views` artifact ([`crate::artifacts::Views::source_views`]) or rendered here; the
//! loop, the ends and the baselines all take them (the source branch of CSD, the
//! structure guide, the colour fit's coverage).

use crate::{Camera, Error, Result, Scene};
use ndarray::Array3;

/// The original renders (from the source `views` artifact), one `[H, W, ...]` per view.
#[derive(Debug, Clone)]
pub struct SourceViews {
    pub width: usize,
    pub height: usize,
    /// `[H, W, 3]` per view.
    pub rgb: Vec<Vec<f32>>,
    /// `[H, W]` per view.
    pub alpha: Vec<Vec<f32>>,
    /// `[H, W]` per view (expected depth), for ControlNet priors.
    pub depth: Vec<Vec<f32>>,
    /// The colour they are composited over (the loop renders over it too).
    pub background: [f32; 3],
}

impl SourceViews {
    /// The source views of `scene` rendered from `cameras` over `background` (the
    /// original renders without a `views` artifact); the cameras must share one size.
    pub fn render(scene: &Scene, cameras: &[Camera], background: [f32; 3]) -> Result<SourceViews> {
        let Some(first) = cameras.first() else {
            return Err(Error::param("source views: no camera"));
        };
        let (w, h) = (first.width, first.height);
        if let Some(c) = cameras.iter().find(|c| (c.width, c.height) != (w, h)) {
            return Err(Error::param(format!(
                "source views: camera {:?} is {}x{}, the first is {w}x{h}",
                c.name, c.width, c.height
            )));
        }
        let mut src = SourceViews {
            width: w as usize,
            height: h as usize,
            rgb: Vec::with_capacity(cameras.len()),
            alpha: Vec::with_capacity(cameras.len()),
            depth: Vec::with_capacity(cameras.len()),
            background,
        };
        for r in super::render_all(scene, cameras, background)? {
            src.rgb.push(r.rgb);
            src.alpha.push(r.alpha);
            src.depth.push(r.depth);
        }
        Ok(src)
    }

    /// Image `rgb` `[H, W, 3]` of view `v` as the prior sees it, `[3, H, W]`
    /// ([`super::fill::prior_view`] with this view's coverage).
    pub fn seen(&self, rgb: &[f32], v: usize, background: [f32; 3], fill: bool) -> Array3<f32> {
        super::fill::prior_view(
            rgb,
            &self.alpha[v],
            background,
            fill,
            (self.height, self.width),
        )
    }

    /// The un-premultiplied colour `[H, W, 3]` of view `v` ([`super::fill::unpremultiply`]).
    pub fn colour(&self, v: usize, background: [f32; 3]) -> Vec<f32> {
        super::fill::unpremultiply(&self.rgb[v], &self.alpha[v], background)
    }
}

//! What a stylized scene's colour may be: the base colour's range and the choice of the
//! view-dependent bands.
//!
//! A Gaussian's colour seen from direction `d` is `max(0, 0.5 + SH_C0 f_dc + sum_l
//! Y_l(d) f_rest_l)` (Kerbl et al. 2023, Sec. 4, the renderer's evaluation). The *base
//! colour* `0.5 + SH_C0 f_dc` is all that `.splat` holds (one byte a channel, so [0, 1])
//! and `.spz` holds [-0.44, 1.44] of it. A fit left alone puts base colours outside [0, 1]
//! wherever overlapping Gaussians or the bands can make up for it, and the writers must
//! then clamp: what a viewer shows is no longer what the report showed. So every colour
//! fit ([`crate::optim::ColourFit`]) and every end ([`crate::ends::apply`]) projects the
//! base colours it changes into [0, 1] ([`bound_base`]): projected gradient descent,
//! the range held by construction.
//!
//! [`Bands`] is the user's choice for the degree >= 1 bands (`sh` in the configuration):
//! drop them (degree 0, every format holds the result exactly), keep the input's, or fit
//! them with the base.

use super::{SH_C0, Scene};
use crate::selection::Selection;
use rayon::prelude::*;

/// The `f_dc` range whose base colour `0.5 + SH_C0 f_dc` lies in [0, 1].
pub const DC_RANGE: (f32, f32) = (-0.5 / SH_C0, 0.5 / SH_C0);

/// `dc` (one Gaussian's three `f_dc`) moved into [`DC_RANGE`].
pub fn bound_dc(dc: [f32; 3]) -> [f32; 3] {
    dc.map(|v| v.clamp(DC_RANGE.0, DC_RANGE.1))
}

/// `scene` with every base colour moved into [0, 1] where `weights` (one per Gaussian;
/// None: all) is above 0; a Gaussian of weight 0 keeps its bits. Returns how many
/// Gaussians moved.
pub fn bound_base(scene: &mut Scene, weights: Option<&[f32]>) -> usize {
    scene
        .sh_dc
        .par_iter_mut()
        .enumerate()
        .filter(|(i, _)| weights.is_none_or(|w| w[*i] > 0.0))
        .map(|(_, dc)| {
            let b = bound_dc(*dc);
            let moved = b != *dc;
            *dc = b;
            moved as usize
        })
        .sum()
}

/// Base colours of `scene` outside [0, 1] (counted per Gaussian).
pub fn outside_base(scene: &Scene) -> usize {
    scene
        .sh_dc
        .iter()
        .filter(|dc| bound_dc(**dc) != **dc)
        .count()
}

/// What happens to the input's view-dependent bands (SH degree >= 1) when a scene is
/// stylized (`sh` in the configuration).
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    Default,
    clap::ValueEnum,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Bands {
    /// The stylized Gaussians lose their bands (without a selection the scene is written
    /// at degree 0): the colour is view-independent, fitted with no view-dependent
    /// residue, and `.ply`, `.splat` and `.spz` all hold it exactly.
    #[default]
    Drop,
    /// The input's bands are kept as they were; only the base colour is fitted, and the
    /// input's highlights and tints ride on top of the style. `.splat` cannot hold them.
    Keep,
    /// The bands are fitted with the base colour (at 1/20 of its learning rate, 3DGS's
    /// ratio). `.splat` cannot hold them.
    Fit,
}

impl Bands {
    /// Whether a colour fit moves the bands.
    pub fn fitted(self) -> bool {
        self == Bands::Fit
    }
}

/// `scene` with the bands of the stylized Gaussians dropped: with a selection, each
/// Gaussian's bands are scaled by `1 - weight` (weight 0 keeps its bits, the degree is
/// kept); without one, the scene at degree 0.
pub fn drop_bands(scene: &Scene, selection: Option<&Selection>) -> Scene {
    let mut out = scene.clone();
    match selection {
        None => {
            out.sh_degree = 0;
            out.sh_rest = Vec::new();
        }
        Some(sel) => {
            let k = 3 * scene.rest_per_channel();
            if k == 0 {
                return out;
            }
            out.sh_rest
                .par_chunks_mut(k)
                .zip(&sel.weights)
                .filter(|(_, w)| **w > 0.0)
                .for_each(|(r, &w)| r.iter_mut().for_each(|v| *v *= 1.0 - w));
        }
    }
    out
}

/// `scene` at SH `degree` (0..=3): the bands it has kept, the new ones zero, those above
/// `degree` removed (the colour seen is unchanged when raising).
pub fn with_degree(scene: &Scene, degree: usize) -> Scene {
    let mut out = scene.clone();
    let (k_old, k_new) = (
        3 * scene.rest_per_channel(),
        3 * (super::sh_coeffs(degree) - 1),
    );
    out.sh_degree = degree;
    out.sh_rest = vec![0.0; scene.len() * k_new];
    if k_new > 0 {
        let keep = k_old.min(k_new);
        out.sh_rest
            .par_chunks_mut(k_new)
            .enumerate()
            .for_each(|(i, r)| {
                r[..keep].copy_from_slice(&scene.sh_rest[i * k_old..i * k_old + keep])
            });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The bound is the base colour's [0, 1], applied only where the weight is above 0;
    /// what is inside keeps its bits.
    #[test]
    fn bound_base_holds_the_range_and_spares_weight_zero() {
        let mut s = crate::sample::sample_scene(1);
        let n = s.len();
        s.sh_dc[0] = [5.0, -5.0, 0.1];
        s.sh_dc[1] = [5.0, -5.0, 0.1];
        let before = s.clone();
        let w: Vec<f32> = (0..n).map(|i| if i == 1 { 0.0 } else { 1.0 }).collect();
        let moved = bound_base(&mut s, Some(&w));
        assert_eq!(s.sh_dc[1], before.sh_dc[1]);
        let base = |d: f32| 0.5 + SH_C0 * d;
        for c in 0..2 {
            let b = base(s.sh_dc[0][c]);
            assert!((b - [1.0, 0.0][c]).abs() < 1e-6, "{b}");
        }
        assert_eq!(s.sh_dc[0][2], 0.1);
        assert_eq!(moved, outside_base(&before) - 1);
        assert_eq!(outside_base(&s), 1);
        bound_base(&mut s, None);
        assert_eq!(outside_base(&s), 0);
    }

    /// Raising the degree keeps each Gaussian's bands and pads zeros after them (the
    /// colour seen is unchanged); lowering cuts them.
    #[test]
    fn degree_up_and_down() {
        let s = crate::sample::sample_scene(1);
        assert_eq!(s.sh_degree, 1);
        let up = with_degree(&s, 3);
        assert_eq!(up.sh_rest.len(), s.len() * 45);
        for i in 0..s.len() {
            let r = &up.sh_rest[i * 45..(i + 1) * 45];
            assert_eq!(&r[..9], &s.sh_rest[i * 9..(i + 1) * 9]);
            assert!(r[9..].iter().all(|v| *v == 0.0));
        }
        assert_eq!(with_degree(&up, 1), s);
        let d0 = with_degree(&s, 0);
        assert_eq!((d0.sh_degree, d0.sh_rest.len()), (0, 0));
    }

    /// Dropping the bands: degree 0 without a selection; scaled by 1 - weight with one.
    #[test]
    fn drop_bands_by_weight() {
        let s = crate::sample::sample_scene(1);
        assert!(s.sh_degree >= 1);
        let d = drop_bands(&s, None);
        assert_eq!((d.sh_degree, d.sh_rest.len()), (0, 0));
        assert_eq!(d.sh_dc, s.sh_dc);
        let n = s.len();
        let w: Vec<f32> = (0..n).map(|i| [0.0, 1.0, 0.25][i % 3]).collect();
        let sel = Selection::new(w, Path::new("s")).unwrap();
        let d = drop_bands(&s, Some(&sel));
        let k = 3 * s.rest_per_channel();
        for i in 0..n {
            for j in i * k..(i + 1) * k {
                let want = [s.sh_rest[j], 0.0, 0.75 * s.sh_rest[j]][i % 3];
                assert_eq!(d.sh_rest[j], want);
            }
        }
    }
}

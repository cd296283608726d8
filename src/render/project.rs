//! Projection of 3D Gaussians into screen-space splats.
//!
//! For each Gaussian (Kerbl et al. 2023, Sec. 4; Zwicker et al. 2001, EWA splatting):
//! - mean in camera space `t = W p + w` (W, w: world-to-camera rotation/translation);
//!   culled when `t.z < NEAR` (0.2, as INRIA's `in_frustum`);
//! - 3D covariance `Sigma = R S S^T R^T` from the normalised quaternion and the linear
//!   scales (Kerbl Eq. 6);
//! - 2D covariance `Sigma' = J W Sigma W^T J^T` (Kerbl Eq. 5, Zwicker Eq. 31) with the
//!   affine Jacobian of the perspective map at the mean,
//!   `J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]`, where x/z and y/z are clamped
//!   to the image frustum widened by 30% on each side (the guard band used by INRIA and
//!   gsplat, which keeps J bounded for Gaussians far outside the view), then the
//!   low-pass dilation `Sigma' + 0.3 I` (EWA's screen-space pre-filter);
//! - conic `Sigma'^-1`, radius `ceil(3 sqrt(lambda_max))` with INRIA's
//!   `lambda_max = mid + sqrt(max(0.1, mid^2 - det))`;
//! - the 16x16 tiles of the square `mean ± radius` (pixel centres at `i + 0.5`), cut
//!   down to the tiles that meet the bounding box of the ellipse where
//!   `opacity * exp(-power) >= 1/255`: pixels outside that box can never pass the 1/255
//!   test, so this cut changes no output, it only saves work. The box is widened by a
//!   margin ([`BOX_MARGIN`]) that covers the rounding of the compositor's own `power`
//!   (which grows with the ellipse's condition number); a test checks that a far wider
//!   margin gives the same bits.
//!
//! Arithmetic: f32, eight Gaussians at a time (the lane loops vectorise; `exp` and `ln`
//! are polynomials, [`exp_f32`] and [`ln_f32`]), as the CUDA rasterizers do. With
//! `Sigma' = U U^T + 0.3 I` (`U = J W R S`, 2x3) the determinant is evaluated as
//! `|u0 x u1|^2 + 0.3 (|u0|^2 + |u1|^2) + 0.09` and `mid^2 - det` as
//! `((a - c) / 2)^2 + b^2`: sums of non-negative terms, so thin Gaussians lose no
//! precision to cancellation. A Gaussian whose f32 evaluation overflows or meets a
//! non-finite value (absurd scales or positions) is projected again by the f64 code
//! (`project_one_f64`), which is also the reference the f32 path is tested against.
//!
//! Binning into tiles: [`super::bin`].
//!
//! One module per part: `fastmath` (the polynomial `exp` and `ln`), `camera` (the
//! camera constants in f64 and f32), `screen` (the screen-space tail both paths share),
//! `reference` (the f64 path) and `lanes` (the f32 lane path).

mod camera;
mod fastmath;
mod lanes;
mod reference;
mod screen;

use crate::{Camera, Scene};
use camera::{Cam, CamF};
pub(crate) use fastmath::exp_poly;
pub use fastmath::{exp_f32, ln_f32};
use lanes::project_range;
use rayon::prelude::*;

/// Tile edge in pixels.
pub const TILE: usize = 16;
/// Near-plane distance (camera-space z) below which Gaussians are culled.
pub const NEAR: f64 = 0.2;
/// Low-pass dilation added to the 2D covariance diagonal (pixels^2).
pub const DILATION: f64 = 0.3;
/// Minimum alpha that is composited.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Maximum alpha of one splat.
pub const ALPHA_MAX: f32 = 0.99;
/// Compositing stops for a pixel before a splat would take transmittance below this.
pub const T_MIN: f32 = 1e-4;

/// Margin of the opacity-aware ellipse box: the half-widths `sqrt(2 (L + 1e-3) S_xx)`
/// (`L = ln(opacity / ALPHA_MIN)`, `S` the dilated 2D covariance) are multiplied by
/// `1 + rel * cond` (`cond = S_xx S_yy / det S`, which bounds how much f32 rounding of
/// the conic and of `power` can move the ellipse's edge, relative to its size) and
/// widened by `px` pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxMargin {
    pub rel: f32,
    pub px: f32,
}

/// The margin used: f32 rounding moves the edge by about `1e-7 cond` relative, so this
/// is a hundredfold bound, plus a hundredth of a pixel for the pixel-centre offsets.
pub const BOX_MARGIN: BoxMargin = BoxMargin {
    rel: 1e-5,
    px: 0.01,
};

/// What the compositor reads of one splat, packed so that one splat is one load.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct SplatRec {
    /// Projected mean, pixels.
    pub mean: [f32; 2],
    /// Conic (inverse 2D covariance) `[[a, b], [b, c]]` as `[a, b, c]`.
    pub conic: [f32; 3],
    pub opacity: f32,
    /// `power` below which `opacity * exp(power) < 1/255` with a margin of 1e-3 (far
    /// above f32 rounding and the compositor's exp error): a pixel below it never blends.
    pub power_floor: f32,
    /// Pixel rows `[y0, y1)` (image coordinates) that can receive alpha >= 1/255.
    pub rows: [u16; 2],
    /// Pixel columns `[x0, x1)` that can receive alpha >= 1/255.
    pub cols: [u16; 2],
}

/// Screen-space splats of the Gaussians that survive culling. Index `i` here is the
/// "local" index; `ids[i]` is the index in the scene.
#[derive(Debug, Default, Clone)]
pub struct Splats {
    pub ids: Vec<u32>,
    pub recs: Vec<SplatRec>,
    /// Camera-space z.
    pub depth: Vec<f32>,
    /// Tile rectangle `[tx0, ty0, tx1, ty1)`.
    pub tiles: Vec<[u16; 4]>,
}

impl Splats {
    /// Number of splats.
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// A projected and binned view: everything the compositing needs.
#[derive(Debug, Default, Clone)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub tiles_x: usize,
    pub tiles_y: usize,
    pub splats: Splats,
    /// `tile_start[t]..tile_start[t+1]` indexes `tile_list` for tile `t` (row-major).
    pub tile_start: Vec<u32>,
    /// Local splat indices per tile, front to back.
    pub tile_list: Vec<u32>,
}

impl Frame {
    /// Local splat indices of tile `t`, front to back.
    #[inline]
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.tile_list[self.tile_start[t] as usize..self.tile_start[t + 1] as usize]
    }
}

/// One projected Gaussian (before it is stored in [`Splats`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct One {
    pub id: u32,
    pub rec: SplatRec,
    pub depth: f32,
    pub tiles: [u16; 4],
}

/// Split `s` into consecutive pieces of the given lengths (which must sum to its length).
pub(crate) fn split_lengths<T>(
    mut s: &mut [T],
    lens: impl IntoIterator<Item = usize>,
) -> Vec<&mut [T]> {
    let mut out = Vec::new();
    for n in lens {
        let (a, b) = s.split_at_mut(n);
        out.push(a);
        s = b;
    }
    out
}

/// Gaussians per projection task.
const CHUNK: usize = 4096;

/// Project every Gaussian of `scene` for `camera` (validated by the caller), in scene
/// order, without binning.
pub fn project_splats(scene: &Scene, camera: &Camera) -> Splats {
    project_splats_with(scene, camera, BOX_MARGIN)
}

/// [`project_splats`] with another ellipse-box margin (for tests).
pub(crate) fn project_splats_with(scene: &Scene, camera: &Camera, margin: BoxMargin) -> Splats {
    let cam = Cam::new(camera);
    let camf = CamF::new(&cam);
    let n = scene.len();
    // Parallel in fixed-size chunks, concatenated in order: deterministic.
    let chunks: Vec<Vec<One>> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let lo = c * CHUNK;
            project_range(scene, &cam, &camf, margin, lo, (lo + CHUNK).min(n))
        })
        .collect();
    let m: usize = chunks.iter().map(Vec::len).sum();
    let mut s = Splats {
        ids: vec![0; m],
        recs: vec![SplatRec::default(); m],
        depth: vec![0.0; m],
        tiles: vec![[0; 4]; m],
    };
    let lens = || chunks.iter().map(Vec::len);
    split_lengths(&mut s.ids, lens())
        .into_par_iter()
        .zip(split_lengths(&mut s.recs, lens()))
        .zip(split_lengths(&mut s.depth, lens()))
        .zip(split_lengths(&mut s.tiles, lens()))
        .zip(&chunks)
        .for_each(|((((ids, recs), depth), tiles), c)| {
            for (k, o) in c.iter().enumerate() {
                ids[k] = o.id;
                recs[k] = o.rec;
                depth[k] = o.depth;
                tiles[k] = o.tiles;
            }
        });
    s
}

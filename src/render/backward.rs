//! Colour backward pass with frozen geometry.
//!
//! With positions, covariances, opacities and the depth order fixed, a pixel's colour is
//! linear in the splat colours: `C_p = sum_i w_pi c_i + T_p bg` with constant weights
//! `w_pi = alpha_i T_i` (Kerbl et al. 2023, Eq. 3). Hence `dL/dc_i = sum_p w_pi dL/dC_p`
//! (the transpose product), and through the clamp `c = max(0, raw)`:
//! `dL/draw = dL/dc` where `raw >= 0`, else 0. The SH coefficients enter linearly,
//! `raw = sum_k Y_k(d) f_k + 0.5`, so `dL/df_k = Y_k(d) dL/draw` per channel.
//!
//! [`colour_grad_uncached`] recomputes the weights by compositing again (the "cache
//! off" path); [`super::ViewCache::backward`] reads them from the cache. Both sum each
//! splat's pixels in row-major order within a tile and the tiles in row-major order,
//! so they give identical results.

use super::Frame;
use super::project::TILE;
use super::raster::{HALF, Plane, Sink, TileState, composite_tile};
use super::sh;
use crate::Scene;
use rayon::prelude::*;

/// Collects, per tile, each splat's `sum_p w_p g_p` in front-to-back order.
pub(crate) struct GradSink<'a> {
    /// Tile-local gradient planes dL/dC (R, G, B).
    pub grad: [Plane; 3],
    pub out: &'a mut Vec<(u32, [f32; 3])>,
    /// The current splat's sum, pixels in row-major order.
    sum: [f32; 3],
}

impl Sink for GradSink<'_> {
    #[inline(always)]
    fn begin(&mut self, _local: u32, _slot: usize) {
        self.sum = [0.0; 3];
    }

    #[inline(always)]
    fn half(&mut self, r: usize, h: usize, w: &[f32; HALF]) {
        // Half rows that are not reported have zero weight; leaving them out of the sum
        // changes no bit (the sum starts at +0 and the gradients are finite).
        let s = &mut self.sum;
        for (c, &wp) in w.iter().enumerate() {
            let x = h * HALF + c;
            s[0] += wp * self.grad[0][r][x];
            s[1] += wp * self.grad[1][r][x];
            s[2] += wp * self.grad[2][r][x];
        }
    }

    #[inline(always)]
    fn end(&mut self, local: u32, _slot: usize, _any: bool) {
        self.out.push((local, self.sum));
    }
}

/// Load tile `(tx, ty)` of an `[H, W, 3]` image into three planes (zero outside).
pub(crate) fn load_tile(
    img: &[f32],
    width: usize,
    height: usize,
    tile: usize,
    tiles_x: usize,
) -> [Plane; 3] {
    let mut g = [[[0.0f32; TILE]; TILE]; 3];
    let x0 = (tile % tiles_x) * TILE;
    let y0 = (tile / tiles_x) * TILE;
    for r in 0..(height - y0).min(TILE) {
        for c in 0..(width - x0).min(TILE) {
            let o = ((y0 + r) * width + x0 + c) * 3;
            g[0][r][c] = img[o];
            g[1][r][c] = img[o + 1];
            g[2][r][c] = img[o + 2];
        }
    }
    g
}

/// Add per-tile lists of `(local, grad)` into one gradient per splat, tile by tile.
pub(crate) fn merge(per_tile: Vec<Vec<(u32, [f32; 3])>>, n: usize) -> Vec<[f32; 3]> {
    let mut out = vec![[0.0f32; 3]; n];
    for list in per_tile {
        for (g, v) in list {
            let o = &mut out[g as usize];
            o[0] += v[0];
            o[1] += v[1];
            o[2] += v[2];
        }
    }
    out
}

/// `dL/dc` per splat of `frame` (indexed like `frame.splats`) given `dL/dC` as an
/// `[H, W, 3]` image, recomputing the blending weights.
pub fn colour_grad_uncached(frame: &Frame, grad_rgb: &[f32]) -> Vec<[f32; 3]> {
    let nt = frame.tiles_x * frame.tiles_y;
    let per_tile: Vec<Vec<(u32, [f32; 3])>> = (0..nt)
        .into_par_iter()
        .map_init(TileState::new, |st, t| {
            let mut out = Vec::new();
            let mut sink = GradSink {
                grad: load_tile(grad_rgb, frame.width, frame.height, t, frame.tiles_x),
                out: &mut out,
                sum: [0.0; 3],
            };
            composite_tile(frame, t, st, &mut sink);
            out
        })
        .collect();
    merge(per_tile, frame.splats.ids.len())
}

/// Accumulate SH-coefficient gradients of scene Gaussians `ids` seen from `centre`,
/// given pre-clamp colours `raw` and colour gradients `grad_c` (both indexed like
/// `ids`), into `grad_dc` (`[N][3]`) and `grad_rest` (layout of `Scene::sh_rest`).
pub fn sh_backward(
    scene: &Scene,
    ids: &[u32],
    centre: [f32; 3],
    raw: &[[f32; 3]],
    grad_c: &[[f32; 3]],
    grad_dc: &mut [[f32; 3]],
    grad_rest: &mut [f32],
) {
    let k = scene.rest_per_channel();
    let deg = scene.sh_degree;
    let mut basis = [0.0f32; 16];
    for (j, &id) in ids.iter().enumerate() {
        let i = id as usize;
        let mut g = grad_c[j];
        for ch in 0..3 {
            if raw[j][ch] < 0.0 {
                g[ch] = 0.0;
            }
        }
        if g == [0.0; 3] {
            continue;
        }
        for ch in 0..3 {
            grad_dc[i][ch] += sh::C0 * g[ch];
        }
        let Some(d) = sh::unit_dir(centre, scene.positions[i]) else {
            continue;
        };
        if k == 0 {
            continue;
        }
        sh::sh_basis(deg, d, &mut basis);
        let gr = &mut grad_rest[i * k * 3..(i + 1) * k * 3];
        for kk in 0..k {
            let b = basis[kk + 1];
            for ch in 0..3 {
                gr[kk * 3 + ch] += b * g[ch];
            }
        }
    }
}

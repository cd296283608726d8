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
    for (j, &id) in ids.iter().enumerate() {
        let i = id as usize;
        sh_backward_one(
            scene,
            i,
            centre,
            raw[j],
            grad_c[j],
            &mut grad_dc[i],
            &mut grad_rest[i * k * 3..(i + 1) * k * 3],
        );
    }
}

/// One Gaussian's share of [`sh_backward`]; `gr` is its `3 K` slice of `grad_rest`.
#[inline(always)]
fn sh_backward_one(
    scene: &Scene,
    i: usize,
    centre: [f32; 3],
    raw: [f32; 3],
    mut g: [f32; 3],
    gdc: &mut [f32; 3],
    gr: &mut [f32],
) {
    let k = scene.rest_per_channel();
    for ch in 0..3 {
        if raw[ch] < 0.0 {
            g[ch] = 0.0;
        }
    }
    if g == [0.0; 3] {
        return;
    }
    for ch in 0..3 {
        gdc[ch] += sh::C0 * g[ch];
    }
    if k == 0 {
        return;
    }
    let Some(d) = sh::unit_dir(centre, scene.positions[i]) else {
        return;
    };
    let mut basis = [0.0f32; 16];
    sh::sh_basis(scene.sh_degree, d, &mut basis);
    for kk in 0..k {
        let b = basis[kk + 1];
        for ch in 0..3 {
            gr[kk * 3 + ch] += b * g[ch];
        }
    }
}

/// The colour gradients of one view for [`sh_backward_views`]: `ids` ascending (as
/// [`super::ViewCache::gaussians`] and [`super::project::Splats::ids`] are), `raw` and `grad_c`
/// indexed like `ids`.
#[derive(Debug, Clone, Copy)]
pub struct ViewGrad<'a> {
    pub ids: &'a [u32],
    pub centre: [f32; 3],
    pub raw: &'a [[f32; 3]],
    pub grad_c: &'a [[f32; 3]],
}

/// [`sh_backward`] of several views, in parallel over blocks of Gaussians: within a
/// Gaussian the views are added in the order given, so the result is bit-identical to
/// calling [`sh_backward`] view after view, for any thread count.
pub fn sh_backward_views(
    scene: &Scene,
    views: &[ViewGrad<'_>],
    grad_dc: &mut [[f32; 3]],
    grad_rest: &mut [f32],
) {
    const BLOCK: usize = 2048;
    let k3 = scene.rest_per_channel() * 3;
    let block = |b: usize, gdc: &mut [[f32; 3]], gr: &mut [f32]| {
        let lo = b * BLOCK;
        let hi = lo + gdc.len();
        for v in views {
            let a = v.ids.partition_point(|&i| (i as usize) < lo);
            let e = v.ids.partition_point(|&i| (i as usize) < hi);
            for j in a..e {
                let i = v.ids[j] as usize;
                let o = i - lo;
                sh_backward_one(
                    scene,
                    i,
                    v.centre,
                    v.raw[j],
                    v.grad_c[j],
                    &mut gdc[o],
                    &mut gr[o * k3..(o + 1) * k3],
                );
            }
        }
    };
    if k3 == 0 {
        grad_dc
            .par_chunks_mut(BLOCK)
            .enumerate()
            .for_each(|(b, gdc)| block(b, gdc, &mut []));
    } else {
        grad_dc
            .par_chunks_mut(BLOCK)
            .zip(grad_rest.par_chunks_mut(BLOCK * k3))
            .enumerate()
            .for_each(|(b, (gdc, gr))| block(b, gdc, gr));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::tests::random_scene;

    #[test]
    fn sh_backward_views_equals_view_after_view() {
        for deg in [0usize, 2] {
            let scene = random_scene(5000, deg, 70 + deg as u64);
            let mut rng = crate::rng::Rng::new(3);
            type View = (Vec<u32>, [f32; 3], Vec<[f32; 3]>, Vec<[f32; 3]>);
            let views: Vec<View> = (0..4)
                .map(|v| {
                    let ids: Vec<u32> = (0..scene.len() as u32)
                        .filter(|i| (i * 7 + v) % 3 != 0)
                        .collect();
                    let three = |r: &mut crate::rng::Rng| {
                        let x = r.normals_f32(3);
                        [x[0], x[1], x[2]]
                    };
                    let raw = ids.iter().map(|_| three(&mut rng)).collect();
                    let gc = ids.iter().map(|_| three(&mut rng)).collect();
                    (ids, [v as f32, 2.0, -3.0], raw, gc)
                })
                .collect();
            let n = scene.len();
            let k3 = scene.rest_per_channel() * 3;
            let (mut dc0, mut rest0) = (vec![[0.0f32; 3]; n], vec![0.0f32; n * k3]);
            for (ids, c, raw, gc) in &views {
                sh_backward(&scene, ids, *c, raw, gc, &mut dc0, &mut rest0);
            }
            let vg: Vec<ViewGrad> = views
                .iter()
                .map(|(ids, c, raw, gc)| ViewGrad {
                    ids,
                    centre: *c,
                    raw,
                    grad_c: gc,
                })
                .collect();
            for threads in [1, 3] {
                let (mut dc1, mut rest1) = (vec![[0.0f32; 3]; n], vec![0.0f32; n * k3]);
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| sh_backward_views(&scene, &vg, &mut dc1, &mut rest1));
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(dc1.as_flattened()), bits(dc0.as_flattened()));
                assert_eq!(bits(&rest1), bits(&rest0));
            }
        }
    }
}

//! Projection of 3D Gaussians into screen-space splats and their binning into tiles.
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
//!   `opacity * exp(-power) >= 1/255` (plus a pixel of margin): pixels outside that box
//!   can never pass the 1/255 test, so this cut changes no output, it only saves work.
//!
//! Binning: one radix sort of all splats on the key `(depth bits, index)` (depths are
//! positive floats so their bit patterns order like the values, and the index breaks
//! ties, so the order is total and deterministic), then a counting sort by tile that
//! visits splats in that order, so every tile's list comes out front to back.
//! Projection itself is computed in f64 for robustness at extreme scales, then stored
//! as f32 structure-of-arrays for the rasterizer.

use crate::{Camera, Scene};
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

/// Screen-space splats of the Gaussians that survive culling, as structure of arrays.
/// Index `i` here is the "local" index; `ids[i]` is the index in the scene.
#[derive(Debug, Default, Clone)]
pub struct Splats {
    pub ids: Vec<u32>,
    pub mean_x: Vec<f32>,
    pub mean_y: Vec<f32>,
    /// Conic (inverse 2D covariance) `[[a, b], [b, c]]`.
    pub conic_a: Vec<f32>,
    pub conic_b: Vec<f32>,
    pub conic_c: Vec<f32>,
    pub opacity: Vec<f32>,
    /// `power` below which `opacity * exp(power) < 1/255` with a margin of 1e-3 (far
    /// above f32 rounding and the compositor's exp error): a pixel below it never blends.
    pub power_floor: Vec<f32>,
    /// Camera-space z.
    pub depth: Vec<f32>,
    /// Pixel rows `[y0, y1)` (image coordinates) that can receive alpha >= 1/255.
    pub rows: Vec<[u32; 2]>,
    /// Pixel columns `[x0, x1)` that can receive alpha >= 1/255.
    pub cols: Vec<[u32; 2]>,
    /// Tile rectangle `[tx0, ty0, tx1, ty1)`.
    pub tiles: Vec<[u32; 4]>,
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

struct One {
    id: u32,
    mean: [f32; 2],
    conic: [f32; 3],
    opacity: f32,
    power_floor: f32,
    depth: f32,
    rows: [u32; 2],
    cols: [u32; 2],
    tiles: [u32; 4],
}

#[inline(always)]
fn sigmoid(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

/// Project Gaussian `i`; `None` when culled.
#[inline(always)]
fn project_one(scene: &Scene, cam: &Cam, i: usize) -> Option<One> {
    let p = scene.positions[i];
    let p = [p[0] as f64, p[1] as f64, p[2] as f64];
    let r = &cam.r;
    let t = [
        r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + cam.t[0],
        r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + cam.t[1],
        r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + cam.t[2],
    ];
    // Written so that NaN is rejected too.
    let in_front = t[2] >= NEAR && t.iter().all(|v| v.is_finite());
    if !in_front {
        return None;
    }
    let opacity = sigmoid(scene.opacity_logits[i] as f64);
    let visible = opacity >= ALPHA_MIN as f64;
    if !visible {
        return None;
    }
    // Rotation from the normalised quaternion (w, x, y, z).
    let rq = crate::geometry::rows(crate::geometry::quat_to_mat(
        scene.rotations[i].map(f64::from),
    )?);
    let ls = scene.log_scales[i];
    let s = [
        (ls[0] as f64).exp(),
        (ls[1] as f64).exp(),
        (ls[2] as f64).exp(),
    ];
    // M = R S; Sigma = M M^T.
    let mut m = [[0.0f64; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            m[a][b] = rq[a][b] * s[b];
        }
    }
    // Jacobian with the guard-band clamp.
    let z = t[2];
    let tx = z * (t[0] / z).clamp(-cam.lim_x_neg, cam.lim_x_pos);
    let ty = z * (t[1] / z).clamp(-cam.lim_y_neg, cam.lim_y_pos);
    let j = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    // T = J W (2x3), then U = T M (2x3), Sigma' = U U^T.
    let mut tw = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            tw[a][b] = j[a][0] * r[0][b] + j[a][1] * r[1][b] + j[a][2] * r[2][b];
        }
    }
    let mut u = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            u[a][b] = tw[a][0] * m[0][b] + tw[a][1] * m[1][b] + tw[a][2] * m[2][b];
        }
    }
    let ca = u[0][0] * u[0][0] + u[0][1] * u[0][1] + u[0][2] * u[0][2] + DILATION;
    let cb = u[0][0] * u[1][0] + u[0][1] * u[1][1] + u[0][2] * u[1][2];
    let cc = u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2] + DILATION;
    let det = ca * cc - cb * cb;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let conic = [cc / det, -cb / det, ca / det];
    let mx = cam.fx * t[0] / z + cam.cx;
    let my = cam.fy * t[1] / z + cam.cy;
    if !mx.is_finite() || !my.is_finite() {
        return None;
    }
    let mid = 0.5 * (ca + cc);
    let lambda = mid + (mid * mid - det).max(0.1).sqrt();
    let radius = (3.0 * lambda.sqrt()).ceil();
    // Tile square of the 3-sigma radius.
    let (w, h) = (cam.width as f64, cam.height as f64);
    if mx + radius < 0.0 || my + radius < 0.0 || mx - radius >= w || my - radius >= h {
        return None;
    }
    // Opacity-aware ellipse box: power <= ln(255 * opacity).
    let level = (opacity / ALPHA_MIN as f64).ln().max(0.0);
    let ex = (2.0 * level * ca).sqrt() + 1.0;
    let ey = (2.0 * level * cc).sqrt() + 1.0;
    // Tiles: those of the radius square that also meet the ellipse box.
    let ts = TILE as f64;
    let tile_range = |lo: f64, hi: f64, size: f64| -> Option<[u32; 2]> {
        let lo = lo.max(0.0);
        let hi = hi.min(size - 1e-3);
        (hi >= lo).then(|| [(lo / ts).floor() as u32, (hi / ts).floor() as u32 + 1])
    };
    let sq_x = tile_range(mx - radius, mx + radius, w)?;
    let sq_y = tile_range(my - radius, my + radius, h)?;
    let el_x = tile_range(mx - ex, mx + ex, w)?;
    let el_y = tile_range(my - ey, my + ey, h)?;
    let tiles = [
        sq_x[0].max(el_x[0]),
        sq_y[0].max(el_y[0]),
        sq_x[1].min(el_x[1]),
        sq_y[1].min(el_y[1]),
    ];
    if tiles[2] <= tiles[0] || tiles[3] <= tiles[1] {
        return None;
    }
    // Pixel rows whose centre (y + 0.5) lies in the ellipse box.
    let rows = [
        (my - ey - 0.5).ceil().max(0.0) as u32,
        ((my + ey - 0.5).floor() + 1.0).clamp(0.0, h) as u32,
    ];
    let cols = [
        (mx - ex - 0.5).ceil().max(0.0) as u32,
        ((mx + ex - 0.5).floor() + 1.0).clamp(0.0, w) as u32,
    ];
    if rows[1] <= rows[0] || cols[1] <= cols[0] {
        return None;
    }
    Some(One {
        id: i as u32,
        mean: [mx as f32, my as f32],
        conic: [conic[0] as f32, conic[1] as f32, conic[2] as f32],
        opacity: opacity as f32,
        power_floor: -(level as f32 + 1e-3),
        depth: z as f32,
        rows,
        cols,
        tiles,
    })
}

/// Camera in f64 with the guard-band limits precomputed.
struct Cam {
    r: [[f64; 3]; 3],
    t: [f64; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: usize,
    height: usize,
    lim_x_pos: f64,
    lim_x_neg: f64,
    lim_y_pos: f64,
    lim_y_neg: f64,
}

impl Cam {
    fn new(c: &Camera) -> Cam {
        let mut r = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                r[a][b] = c.rotation[a][b] as f64;
            }
        }
        let (fx, fy, cx, cy) = (c.fx as f64, c.fy as f64, c.cx as f64, c.cy as f64);
        let (w, h) = (c.width as f64, c.height as f64);
        let tan_x = 0.5 * w / fx;
        let tan_y = 0.5 * h / fy;
        Cam {
            r,
            t: [
                c.translation[0] as f64,
                c.translation[1] as f64,
                c.translation[2] as f64,
            ],
            fx,
            fy,
            cx,
            cy,
            width: c.width as usize,
            height: c.height as usize,
            lim_x_pos: (w - cx) / fx + 0.3 * tan_x,
            lim_x_neg: cx / fx + 0.3 * tan_x,
            lim_y_pos: (h - cy) / fy + 0.3 * tan_y,
            lim_y_neg: cy / fy + 0.3 * tan_y,
        }
    }
}

/// Project Gaussians `lo..hi`, keeping the survivors in order.
///
/// On x86-64 CPUs with AVX2 and FMA this runs a copy compiled with those features (so
/// `floor`/`ceil` become single instructions instead of libm calls). Rust never fuses
/// `a * b + c`, so both copies give identical bits.
fn project_range(scene: &Scene, cam: &Cam, lo: usize, hi: usize) -> Vec<One> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        return unsafe { project_range_avx2(scene, cam, lo, hi) };
    }
    project_range_impl(scene, cam, lo, hi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_range_avx2(scene: &Scene, cam: &Cam, lo: usize, hi: usize) -> Vec<One> {
    project_range_impl(scene, cam, lo, hi)
}

#[inline(always)]
fn project_range_impl(scene: &Scene, cam: &Cam, lo: usize, hi: usize) -> Vec<One> {
    let mut out = Vec::with_capacity(hi - lo);
    for i in lo..hi {
        if let Some(o) = project_one(scene, cam, i) {
            out.push(o);
        }
    }
    out
}

/// Project every Gaussian of `scene` for `camera` (validated by the caller) and bin the
/// survivors into tiles.
pub fn project(scene: &Scene, camera: &Camera) -> Frame {
    let cam = Cam::new(camera);
    let n = scene.len();
    // Parallel in fixed-size chunks, concatenated in order: deterministic.
    let chunks: Vec<Vec<One>> = (0..n.div_ceil(4096))
        .into_par_iter()
        .map(|c| {
            let lo = c * 4096;
            let hi = (lo + 4096).min(n);
            project_range(scene, &cam, lo, hi)
        })
        .collect();
    let m: usize = chunks.iter().map(|c| c.len()).sum();
    let mut s = Splats {
        ids: Vec::with_capacity(m),
        mean_x: Vec::with_capacity(m),
        mean_y: Vec::with_capacity(m),
        conic_a: Vec::with_capacity(m),
        conic_b: Vec::with_capacity(m),
        conic_c: Vec::with_capacity(m),
        opacity: Vec::with_capacity(m),
        power_floor: Vec::with_capacity(m),
        depth: Vec::with_capacity(m),
        rows: Vec::with_capacity(m),
        cols: Vec::with_capacity(m),
        tiles: Vec::with_capacity(m),
    };
    for o in chunks.into_iter().flatten() {
        s.ids.push(o.id);
        s.mean_x.push(o.mean[0]);
        s.mean_y.push(o.mean[1]);
        s.conic_a.push(o.conic[0]);
        s.conic_b.push(o.conic[1]);
        s.conic_c.push(o.conic[2]);
        s.opacity.push(o.opacity);
        s.power_floor.push(o.power_floor);
        s.depth.push(o.depth);
        s.rows.push(o.rows);
        s.cols.push(o.cols);
        s.tiles.push(o.tiles);
    }
    bin(s, cam.width, cam.height)
}

/// Counting sort of (tile, splat) pairs by tile, visiting splats front to back.
fn bin(splats: Splats, width: usize, height: usize) -> Frame {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let nt = tiles_x * tiles_y;
    let mut count = vec![0u32; nt + 1];
    for r in &splats.tiles {
        for ty in r[1]..r[3] {
            for tx in r[0]..r[2] {
                count[ty as usize * tiles_x + tx as usize + 1] += 1;
            }
        }
    }
    for t in 0..nt {
        count[t + 1] += count[t];
    }
    let tile_start = count.clone();
    let total = count[nt] as usize;
    let mut tile_list = vec![0u32; total];
    let mut fill = count;
    // Visiting splats front to back fills every tile's range already sorted.
    for key in depth_order(&splats.depth) {
        let i = key as u32;
        let r = splats.tiles[i as usize];
        for ty in r[1]..r[3] {
            for tx in r[0]..r[2] {
                let t = ty as usize * tiles_x + tx as usize;
                tile_list[fill[t] as usize] = i;
                fill[t] += 1;
            }
        }
    }
    Frame {
        width,
        height,
        tiles_x,
        tiles_y,
        splats,
        tile_start,
        tile_list,
    }
}

/// Keys `(depth bits) << 32 | index` of all splats, sorted: an LSD radix sort (four
/// stable 8-bit passes over the depth bits) of keys that start in index order, so ties
/// in depth keep index order and the order is total and deterministic. Depths are
/// positive floats, whose bit patterns order like the values.
fn depth_order(depth: &[f32]) -> Vec<u64> {
    let mut keys: Vec<u64> = depth
        .iter()
        .enumerate()
        .map(|(i, z)| ((z.to_bits() as u64) << 32) | i as u64)
        .collect();
    let mut tmp = vec![0u64; keys.len()];
    for pass in 0..4 {
        let shift = 32 + 8 * pass;
        let mut start = [0usize; 257];
        for k in &keys {
            start[((k >> shift) & 255) as usize + 1] += 1;
        }
        for b in 0..256 {
            start[b + 1] += start[b];
        }
        for &k in &keys {
            let b = ((k >> shift) & 255) as usize;
            tmp[start[b]] = k;
            start[b] += 1;
        }
        std::mem::swap(&mut keys, &mut tmp);
    }
    keys
}

#[cfg(test)]
mod tests {
    #[test]
    fn depth_order_sorts_keys_like_sort_unstable() {
        let depth = [3.0f32, 0.5, 3.0, 1e6, 0.2, 7.25, 0.5, 2.0];
        let mut want: Vec<u64> = depth
            .iter()
            .enumerate()
            .map(|(i, z)| ((z.to_bits() as u64) << 32) | i as u64)
            .collect();
        want.sort_unstable();
        assert_eq!(super::depth_order(&depth), want);
    }
}

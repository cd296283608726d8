//! Front-to-back alpha compositing of one 16x16 tile (Kerbl et al. 2023, Eq. 2-3):
//! `C = sum_i c_i alpha_i T_i`, `T_i = prod_{j<i} (1 - alpha_j)`, with
//! `alpha_i = min(0.99, o_i exp(-power_i))`, `power = 1/2 d^T Sigma'^-1 d`,
//! `d` = mean minus pixel centre.
//!
//! Conventions follow the INRIA/gsplat CUDA kernels exactly: a splat is skipped when
//! `power < 0` would be needed (i.e. `-power > 0`) or `alpha < 1/255`; before blending,
//! `T_next = T (1 - alpha)` is tested and when `T_next < 1e-4` the pixel is finished
//! *without* blending that splat. The final colour is `C + T_final * background`.
//!
//! The loop is splat-outer, pixel-inner: for each splat of the tile (front to back) the
//! 16 pixels of every row it can reach are updated with branch-free selects, so the
//! compiler vectorises the pixel loop. The blending weights `w = alpha T` of each splat
//! are handed to a [`Sink`], which turns them into colour (forward), contribution
//! records (the frozen-geometry cache) or colour gradients (the uncached backward).
//! Per pixel, the order of operations is the front-to-back order, independent of
//! threads, so results are bit-identical for any thread count.

use super::project::{ALPHA_MAX, ALPHA_MIN, Frame, T_MIN, TILE};

/// Pixels per tile.
pub const TP: usize = TILE * TILE;

/// Receives the blending weights of each splat of a tile, in front-to-back order.
pub trait Sink {
    /// Splat `local` (index into [`Frame::splats`]) blends with weight `w[p]` into tile
    /// pixel `p` for rows `r0..r1` (tile-local); `w` is zero where it does not blend.
    fn blend(&mut self, local: u32, r0: usize, r1: usize, w: &[f32; TP]);
}

/// `exp(x)` for `x <= 0`, a Cephes-style polynomial (relative error about 2e-7) built
/// from plain float ops so that the pixel loop vectorises; the libm call does not.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    let x = x.max(-87.0);
    // Round x / ln2 to nearest with the 1.5 * 2^23 trick.
    let magic = 12_582_912.0f32;
    let kf = x * std::f32::consts::LOG2_E + magic;
    let k = kf - magic;
    let r = x - k * 0.693_359_4 - k * -2.121_944_4e-4;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_2e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    // 2^k from the exponent bits; k is in [-126, 0] after the clamp above.
    let bits = ((kf.to_bits() as i32 - magic.to_bits() as i32 + 127) as u32) << 23;
    e * f32::from_bits(bits)
}

/// Per-tile compositing state.
pub struct TileState {
    /// Transmittance per pixel.
    pub t: [f32; TP],
    /// 1.0 while the pixel is still compositing, 0.0 once finished or outside the image.
    live: [f32; TP],
    w: [f32; TP],
}

impl TileState {
    pub fn new() -> Box<TileState> {
        Box::new(TileState {
            t: [1.0; TP],
            live: [1.0; TP],
            w: [0.0; TP],
        })
    }
}

/// Composite tile `tile` of `frame`, reporting weights to `sink`. `st` is reset here.
pub fn composite_tile<S: Sink>(frame: &Frame, tile: usize, st: &mut TileState, sink: &mut S) {
    let tx = tile % frame.tiles_x;
    let ty = tile / frame.tiles_x;
    let px0 = tx * TILE;
    let py0 = ty * TILE;
    let cols = (frame.width - px0).min(TILE);
    let rows = (frame.height - py0).min(TILE);
    st.t.fill(1.0);
    for r in 0..TILE {
        for c in 0..TILE {
            st.live[r * TILE + c] = if r < rows && c < cols { 1.0 } else { 0.0 };
        }
    }
    let s = &frame.splats;
    let list =
        &frame.tile_list[frame.tile_start[tile] as usize..frame.tile_start[tile + 1] as usize];
    let mut since_check = 0;
    for &g in list {
        let gi = g as usize;
        let rr = s.rows[gi];
        let r0 = (rr[0] as usize).max(py0) - py0;
        let r1 = (rr[1] as usize).min(py0 + rows).saturating_sub(py0);
        if r1 <= r0 {
            continue;
        }
        let (ca, cb, cc) = (s.conic_a[gi], s.conic_b[gi], s.conic_c[gi]);
        let op = s.opacity[gi];
        // Offsets from the mean to pixel centres.
        let dx0 = s.mean_x[gi] - (px0 as f32 + 0.5);
        let dy0 = s.mean_y[gi] - (py0 as f32 + 0.5);
        for r in r0..r1 {
            let dy = dy0 - r as f32;
            let row = r * TILE;
            let t = &mut st.t[row..row + TILE];
            let live = &mut st.live[row..row + TILE];
            let w = &mut st.w[row..row + TILE];
            for c in 0..TILE {
                let dx = dx0 - c as f32;
                let power = -0.5 * (ca * dx * dx + cc * dy * dy) - cb * dx * dy;
                let alpha = (op * exp_neg(power)).min(ALPHA_MAX);
                let tc = t[c];
                let next = tc * (1.0 - alpha);
                let ok = power <= 0.0 && alpha >= ALPHA_MIN && live[c] > 0.0;
                let finish = ok && next < T_MIN;
                let blend = ok && !finish;
                w[c] = if blend { alpha * tc } else { 0.0 };
                t[c] = if blend { next } else { tc };
                live[c] = if finish { 0.0 } else { live[c] };
            }
        }
        sink.blend(g, r0, r1, &st.w);
        since_check += 1;
        if since_check == 32 {
            since_check = 0;
            if st.live.iter().all(|&l| l == 0.0) {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_neg_is_accurate() {
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -(i as f32) * 1e-4;
            let a = exp_neg(x) as f64;
            let b = (x as f64).exp();
            worst = worst.max(((a - b) / b).abs());
        }
        assert!(worst < 5e-7, "relative error {worst}");
        assert_eq!(exp_neg(0.0), 1.0);
    }
}

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
//! are handed to a [`Sink`] half row by half row, which turns them into colour (forward),
//! contribution records (the frozen-geometry cache) or colour gradients (the uncached
//! backward).
//! Half rows whose 8 pixels have all finished, or where `power` stays below the level
//! at which `alpha < 1/255`, are skipped (they could only receive zero weight), and the
//! tile stops as soon as every half row has finished. The splat records of a tile's list
//! are copied into a small local buffer [`BATCH`] at a time before they are used, so
//! that the cache misses of fetching them overlap.
//! Per pixel, the order of operations is the front-to-back order, independent of
//! threads, so results are bit-identical for any thread count.

use super::project::{ALPHA_MAX, ALPHA_MIN, Frame, SplatRec, T_MIN, TILE};

/// Pixels per tile.
pub const TP: usize = TILE * TILE;

/// A per-pixel tile plane, row-major rows of [`TILE`] pixels.
pub type Plane = [[f32; TILE]; TILE];

/// Splats of a tile list gathered into a local buffer at a time.
pub const BATCH: usize = 32;

/// Receives the blending weights of each splat of a tile, in front-to-back order: for
/// every splat of the tile's list, [`Self::begin`], then [`Self::half`] for each half row
/// that was evaluated (row-major order), then [`Self::end`].
pub trait Sink {
    /// Called with the next (at most [`BATCH`]) splats of the tile's list before any of
    /// them is blended; `slot` in the other calls indexes this batch. A sink that reads
    /// per-splat data gathers it here (one tight loop of independent loads) instead of
    /// missing the cache once per splat.
    #[inline(always)]
    fn gather(&mut self, batch: &[u32]) {
        let _ = batch;
    }

    /// Splat `local` (index into [`Frame::splats`], `slot` in the current batch) starts.
    #[inline(always)]
    fn begin(&mut self, local: u32, slot: usize) {
        let _ = (local, slot);
    }

    /// The splat blends with weights `w` into half `h` (pixels `h * HALF..(h + 1) *
    /// HALF`) of tile row `r`; `w` is zero at the pixels where it does not blend. Half
    /// rows that are not reported have zero weight.
    fn half(&mut self, r: usize, h: usize, w: &[f32; HALF]);

    /// The splat ends; `any` says whether any half row was reported.
    #[inline(always)]
    fn end(&mut self, local: u32, slot: usize, any: bool) {
        let _ = (local, slot, any);
    }
}

/// `exp(x)` for `x <= 0`, a Cephes-style polynomial (relative error about 2e-7) built
/// from plain float ops so that the pixel loop vectorises; the libm call does not.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    super::project::exp_poly(x.max(-87.0))
}

#[inline(always)]
fn as_half(s: &mut [f32]) -> &mut [f32; HALF] {
    // The callers pass exactly HALF elements.
    s.try_into().expect("half row")
}

/// Per-tile compositing state (one per worker; reused across tiles).
pub struct TileState {
    /// Transmittance per pixel, stored negated once the pixel has finished (and -1
    /// outside the image), so that one array carries both; see [`Self::transmittance`].
    t: Plane,
    /// The current batch of splat records.
    recs: Vec<SplatRec>,
}

impl TileState {
    pub fn new() -> Box<TileState> {
        Box::new(TileState {
            t: [[1.0; TILE]; TILE],
            recs: Vec::with_capacity(BATCH),
        })
    }

    /// Final transmittance of tile pixel `(r, c)`.
    #[inline]
    pub fn transmittance(&self, r: usize, c: usize) -> f32 {
        self.t[r][c].abs()
    }
}

/// Pixels per half row: the unit of work along x (one AVX2 register).
pub const HALF: usize = TILE / 2;

/// `power` of a splat at the 8 pixel centres of a half row; returns whether any of
/// them reaches `floor`. Branch-free so that it vectorises.
#[inline(always)]
fn half_power(dx0: f32, dy: f32, conic: [f32; 3], floor: f32, power: &mut [f32; HALF]) -> bool {
    let [ca, cb, cc] = conic;
    let cdy = cc * dy * dy;
    let bdy = cb * dy;
    let mut any = false;
    for c in 0..HALF {
        let dx = dx0 - c as f32;
        let p = -0.5 * (ca * dx * dx + cdy) - bdy * dx;
        power[c] = p;
        any |= p >= floor;
    }
    any
}

/// One splat over half a row (8 pixels) from its `power` there: branch-free so that it
/// vectorises. Returns whether a pixel of the half is still open.
#[inline(always)]
fn blend_half(power: &[f32; HALF], op: f32, t: &mut [f32; HALF], w: &mut [f32; HALF]) -> bool {
    for c in 0..HALF {
        let power = power[c];
        let alpha = (op * exp_neg(power)).min(ALPHA_MAX);
        let tc = t[c];
        let next = tc * (1.0 - alpha);
        let ok = (power <= 0.0) & (alpha >= ALPHA_MIN) & (tc > 0.0);
        let finish = ok & (next < T_MIN);
        let blend = ok & !finish;
        w[c] = if blend { alpha * tc } else { 0.0 };
        let kept = if finish { -tc } else { tc };
        t[c] = if blend { next } else { kept };
    }
    // Whether any pixel of the half is still open (branch-free reduction).
    let mut open = false;
    for v in t.iter() {
        open |= *v > 0.0;
    }
    open
}

/// Composite tile `tile` of `frame`, reporting weights to `sink`. `st` is reset here.
///
/// On x86-64 CPUs with AVX2 and FMA the same code is compiled a second time with
/// those features enabled and chosen at run time (8 pixels per instruction instead of
/// 4). No fused multiply-add is emitted (Rust never contracts `a * b + c`), so both
/// versions produce identical bits.
pub fn composite_tile<S: Sink>(frame: &Frame, tile: usize, st: &mut TileState, sink: &mut S) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        unsafe {
            composite_tile_avx2(frame, tile, st, sink)
        };
        return;
    }
    composite_tile_impl(frame, tile, st, sink);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn composite_tile_avx2<S: Sink>(frame: &Frame, tile: usize, st: &mut TileState, sink: &mut S) {
    composite_tile_impl(frame, tile, st, sink);
}

#[inline(always)]
fn composite_tile_impl<S: Sink>(frame: &Frame, tile: usize, st: &mut TileState, sink: &mut S) {
    let tx = tile % frame.tiles_x;
    let ty = tile / frame.tiles_x;
    let px0 = tx * TILE;
    let py0 = ty * TILE;
    let cols = (frame.width - px0).min(TILE);
    let rows = (frame.height - py0).min(TILE);
    // `open[r][h]`: half `h` of row `r` still has a pixel with transmittance > 0. A
    // closed half would get zero weight from every later splat, so it is skipped; when
    // no half is open the tile is finished.
    let mut open = [[false; TILE / HALF]; TILE];
    let mut n_open = 0usize;
    for r in 0..TILE {
        for c in 0..TILE {
            st.t[r][c] = if r < rows && c < cols { 1.0 } else { -1.0 };
        }
        for (h, o) in open[r].iter_mut().enumerate() {
            *o = r < rows && h * HALF < cols;
            n_open += *o as usize;
        }
    }
    let all = &frame.splats.recs;
    let mut power = [0.0f32; HALF];
    let mut w = [0.0f32; HALF];
    for batch in frame.tile(tile).chunks(BATCH) {
        if n_open == 0 {
            break;
        }
        st.recs.clear();
        st.recs.extend(batch.iter().map(|&g| all[g as usize]));
        sink.gather(batch);
        for (slot, (&g, s)) in batch.iter().zip(&st.recs).enumerate() {
            if n_open == 0 {
                break;
            }
            let r0 = (s.rows[0] as usize).max(py0) - py0;
            let r1 = (s.rows[1] as usize).min(py0 + rows).saturating_sub(py0);
            let c0 = (s.cols[0] as usize).max(px0) - px0;
            let c1 = (s.cols[1] as usize).min(px0 + cols).saturating_sub(px0);
            if r1 <= r0 || c1 <= c0 {
                continue;
            }
            // Whole halves only, so the kernel has a fixed width.
            let h0 = c0 / HALF;
            let h1 = c1.div_ceil(HALF);
            sink.begin(g, slot);
            let mut any = false;
            // Offsets from the mean to pixel centres.
            let dx0 = s.mean[0] - (px0 as f32 + 0.5);
            let dy0 = s.mean[1] - (py0 as f32 + 0.5);
            for r in r0..r1 {
                let dy = dy0 - r as f32;
                for h in h0..h1 {
                    if !open[r][h] {
                        continue;
                    }
                    // A half row entirely below `power_floor` blends nothing.
                    let dxh = dx0 - (h * HALF) as f32;
                    if !half_power(dxh, dy, s.conic, s.power_floor, &mut power) {
                        continue;
                    }
                    any = true;
                    let still = blend_half(
                        &power,
                        s.opacity,
                        as_half(&mut st.t[r][h * HALF..(h + 1) * HALF]),
                        &mut w,
                    );
                    sink.half(r, h, &w);
                    if !still {
                        open[r][h] = false;
                        n_open -= 1;
                    }
                }
            }
            sink.end(g, slot, any);
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

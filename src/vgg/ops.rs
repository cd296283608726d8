//! The Rust engine's operators: 3x3 convolutions (stride 1, zero padding 1) as im2col +
//! SGEMM, parallel over bands of output rows (each band: its own im2col buffer and a
//! single-threaded GEMM into its column block of the output), and the 2x2 max-pool and
//! its backward. The input gradient of a convolution is the convolution of the output
//! gradient with the flipped, transposed kernel ([`Conv`]'s `w_back`), so forward and
//! backward share [`conv3x3`].

use super::Tensor3;
use ndarray::{Array2, ArrayViewMut2, Axis, linalg::general_mat_mul};
use rayon::prelude::*;

/// One 3x3 convolution: weights as the `[O, I*9]` GEMM matrix, bias, and the transposed,
/// flipped `[I, O*9]` matrix for the input gradient.
#[derive(Debug, Clone)]
pub(super) struct Conv {
    pub(super) cin: usize,
    pub(super) cout: usize,
    pub(super) w: Array2<f32>,
    pub(super) w_back: Array2<f32>,
    pub(super) b: Vec<f32>,
}

impl Conv {
    /// From OIHW weights `[O, I, 3, 3]` and a bias `[O]`.
    pub(super) fn new(cout: usize, cin: usize, oihw: &[f32], b: Vec<f32>) -> Self {
        let w = Array2::from_shape_vec((cout, cin * 9), oihw.to_vec()).expect("OIHW shape");
        let mut w_back = Array2::zeros((cin, cout * 9));
        for o in 0..cout {
            for i in 0..cin {
                for k in 0..9 {
                    w_back[[i, o * 9 + (8 - k)]] = oihw[(o * cin + i) * 9 + k];
                }
            }
        }
        Conv {
            cin,
            cout,
            w,
            w_back,
            b,
        }
    }
}

/// Pixels per im2col band: bounds the `[9 C, band]` buffer to about 4 M floats (16 MiB).
fn band_rows(k: usize, h: usize, w: usize) -> usize {
    let by_mem = (4 << 20) / (k * w).max(1);
    // At least two bands per thread when the image allows, for load balance.
    let by_par = h.div_ceil(2 * rayon::current_num_threads());
    by_mem.min(by_par).clamp(1, h)
}

/// 3x3, stride 1, zero-pad 1 convolution of `x` with the `[cout, cin*9]` matrix `wm`
/// (no bias): im2col per band of output rows, one GEMM per band, bands in parallel.
pub(super) fn conv3x3(x: &Tensor3, wm: &Array2<f32>, cout: usize) -> Tensor3 {
    let (cin, h, w) = (x.c, x.h, x.w);
    let k = cin * 9;
    debug_assert_eq!(wm.dim(), (cout, k));
    let mut out = Array2::<f32>::zeros((cout, h * w));
    let rows = band_rows(k, h, w);
    let mut bands: Vec<(usize, ArrayViewMut2<'_, f32>)> = Vec::new();
    let mut rest = out.view_mut();
    let mut y0 = 0;
    while y0 < h {
        let n = rows.min(h - y0);
        let (band, tail) = rest.split_at(Axis(1), n * w);
        bands.push((y0, band));
        rest = tail;
        y0 += n;
    }
    bands.into_par_iter().for_each(|(y0, mut band)| {
        let n = band.ncols() / w;
        let mut col = Array2::<f32>::zeros((k, n * w));
        for ci in 0..cin {
            let plane = &x.data[ci * h * w..(ci + 1) * h * w];
            for ky in 0..3 {
                for kx in 0..3 {
                    let mut row = col.row_mut(ci * 9 + ky * 3 + kx);
                    let row = row.as_slice_mut().expect("contiguous row");
                    for dy in 0..n {
                        let sy = (y0 + dy + ky) as isize - 1;
                        if sy < 0 || sy >= h as isize {
                            continue;
                        }
                        let src = &plane[sy as usize * w..(sy as usize + 1) * w];
                        let dst = &mut row[dy * w..(dy + 1) * w];
                        match kx {
                            0 => dst[1..].copy_from_slice(&src[..w - 1]),
                            1 => dst.copy_from_slice(src),
                            _ => dst[..w - 1].copy_from_slice(&src[1..]),
                        }
                    }
                }
            }
        }
        general_mat_mul(1.0, wm, &col, 0.0, &mut band);
    });
    Tensor3 {
        c: cout,
        h,
        w,
        data: out.into_raw_vec_and_offset().0,
    }
}

/// 2x2 max-pool, stride 2, floor (odd trailing rows/columns dropped).
pub(super) fn max_pool(x: &Tensor3) -> Tensor3 {
    let (h2, w2) = (x.h / 2, x.w / 2);
    let mut y = Tensor3::zeros(x.c, h2, w2);
    for c in 0..x.c {
        let src = &x.data[c * x.h * x.w..];
        for i in 0..h2 {
            for j in 0..w2 {
                let p = (2 * i) * x.w + 2 * j;
                let m = src[p]
                    .max(src[p + 1])
                    .max(src[p + x.w])
                    .max(src[p + x.w + 1]);
                y.data[(c * h2 + i) * w2 + j] = m;
            }
        }
    }
    y
}

/// Route each pooled gradient to its window's maximum (the first in row-major order on
/// ties); `x` is the pool's input.
pub(super) fn max_pool_backward(g: &Tensor3, x: &Tensor3) -> Tensor3 {
    let mut out = Tensor3::zeros(x.c, x.h, x.w);
    for c in 0..x.c {
        let base = c * x.h * x.w;
        for i in 0..g.h {
            for j in 0..g.w {
                let p = base + (2 * i) * x.w + 2 * j;
                let cand = [p, p + 1, p + x.w, p + x.w + 1];
                let mut best = cand[0];
                for &q in &cand[1..] {
                    if x.data[q] > x.data[best] {
                        best = q;
                    }
                }
                out.data[best] += g.data[(c * g.h + i) * g.w + j];
            }
        }
    }
    out
}

//! The Gram matrix of a feature map (Gatys et al. 2016, Eq. 3): `G = F F^T / (H W)` for
//! `[C, H, W]` features, in f64. The one Gram of the crate: the Gram metric
//! ([`crate::metrics::gram`]), the VGG baselines' style loss and the method's Gram
//! texture term all use it.

use crate::vgg::Tensor3;
use rayon::prelude::*;

/// The `C x C` Gram matrix `G = F F^T / (H W)` of a `[C, H, W]` feature map, row-major,
/// in f64.
///
/// Each entry is the sum over positions, in position order, of `f_a f_b` (products in
/// f64), divided by `H W` ([`gram_sums`]).
pub fn gram(t: &Tensor3) -> Vec<f64> {
    let hw = t.h * t.w;
    let mut g = gram_sums(t, None);
    g.iter_mut().for_each(|v| *v /= hw as f64);
    g
}

/// The `C x C` sums `sum_p f_a[p] f_b[p]` (row-major, symmetric; products in f64) of the
/// features `t` (`[C, H, W]`) over the positions `keep` (ascending) or over all, each
/// entry summed over the positions in order.
///
/// For speed, the upper triangle is computed in strips of rows, in parallel (a
/// strip runs from the diagonal to the last column), and mirrored. A strip takes the
/// positions in chunks: each chunk's features of the strip's columns are laid out
/// position-major in f64 in a small buffer (it stays in cache), and blocks of sums
/// advance over it one position at a time, the inner loop over contiguous channels.
/// That changes no entry's summation order (see the bitwise test below); laying out a
/// chunk at a time, rather than the whole map first, reads the features once per strip
/// from memory and writes nothing there.
pub fn gram_sums(t: &Tensor3, keep: Option<&[usize]>) -> Vec<f64> {
    let c = t.c;
    let tile = (c / 4).clamp(4, MAX_TILE);
    // A strip's work falls with its first row; taken longest, shortest, second longest,
    // ..., any run of neighbouring strips (what one thread takes) holds a fair share.
    let by_row: Vec<usize> = (0..c).step_by(tile).collect();
    let strips: Vec<usize> = (0..by_row.len())
        .map(|k| {
            by_row[if k % 2 == 0 {
                k / 2
            } else {
                by_row.len() - 1 - k / 2
            }]
        })
        .collect();
    let sums: Vec<Vec<f64>> = strips
        .par_iter()
        .map(|&a0| strip_sums(t, keep, a0, tile))
        .collect();
    let mut g = vec![0.0; c * c];
    for (&a0, acc) in strips.iter().zip(&sums) {
        let tb = c - a0;
        for (k, &s) in acc.iter().enumerate() {
            let (a, b) = (a0 + k / tb, a0 + k % tb);
            if b >= a {
                g[a * c + b] = s;
                g[b * c + a] = s;
            }
        }
    }
    g
}

/// Most rows of a strip of the Gram matrix computed as one task (a quarter of the rows,
/// at most this: more rows per strip lay out fewer chunks, at least four strips share
/// the work between threads).
const MAX_TILE: usize = 32;
/// Columns of a block of sums held in registers (two vectors of four f64).
const NJ: usize = 8;
/// Positions laid out at a time.
const CHUNK: usize = 128;

/// The sums of one strip, rows `a0..a0 + tile` (clipped to `c`) by columns `a0..c`,
/// row-major `ta x (c - a0)`.
///
/// On x86-64 CPUs with AVX2 and FMA the same loop runs with fused multiply-adds, chosen
/// at run time. That gives the same bits: a product of two f32 values is exact in f64
/// (24 + 24 significant bits), so rounding `s + x y` once (fused) or rounding the
/// product first (exact) and then the sum is the same.
fn strip_sums(t: &Tensor3, keep: Option<&[usize]>, a0: usize, tile: usize) -> Vec<f64> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        return unsafe { strip_sums_fma(t, keep, a0, tile) };
    }
    strip_sums_impl::<false>(t, keep, a0, tile)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn strip_sums_fma(t: &Tensor3, keep: Option<&[usize]>, a0: usize, tile: usize) -> Vec<f64> {
    strip_sums_impl::<true>(t, keep, a0, tile)
}

/// [`strip_sums`]; `FMA`: accumulate with fused multiply-adds (only where the CPU has
/// them: elsewhere `mul_add` is a slow library call).
#[inline(always)]
fn strip_sums_impl<const FMA: bool>(
    t: &Tensor3,
    keep: Option<&[usize]>,
    a0: usize,
    tile: usize,
) -> Vec<f64> {
    let hw = t.h * t.w;
    let n = keep.map_or(hw, <[usize]>::len);
    let (ta, tb) = (tile.min(t.c - a0), t.c - a0);
    let mut acc = vec![-0.0f64; ta * tb];
    let mut buf = vec![0.0f64; CHUNK.min(n) * tb];
    for p0 in (0..n).step_by(CHUNK) {
        let np = CHUNK.min(n - p0);
        let chunk = &mut buf[..np * tb];
        for (col, ch) in t.data[a0 * hw..].chunks_exact(hw).enumerate() {
            match keep {
                None => {
                    for (k, &v) in ch[p0..p0 + np].iter().enumerate() {
                        chunk[k * tb + col] = f64::from(v);
                    }
                }
                Some(keep) => {
                    for (k, &p) in keep[p0..p0 + np].iter().enumerate() {
                        chunk[k * tb + col] = f64::from(ch[p]);
                    }
                }
            }
        }
        chunk_sums::<FMA>(chunk, tb, ta, &mut acc);
    }
    acc
}

/// Add to `acc` (`ta x tb`, row-major) the sums over the rows of `chunk` (position-major,
/// `tb` columns: the strip's first column is 0, its rows are columns `0..ta`), in row
/// order. 4 x [`NJ`] blocks of sums are held in registers (eight independent vectors of
/// four sums: enough to keep the multiply-adds busy); the blocks wholly below the
/// diagonal are not computed.
#[inline(always)]
fn chunk_sums<const FMA: bool>(chunk: &[f64], tb: usize, ta: usize, acc: &mut [f64]) {
    for i0 in (0..ta).step_by(4) {
        for j0 in (0..tb).step_by(NJ) {
            if j0 + NJ <= i0 {
                continue; // below the diagonal: its mirror block is computed
            }
            let (ni, nj) = (4.min(ta - i0), NJ.min(tb - j0));
            let mut s = [[-0.0f64; NJ]; 4];
            for i in 0..ni {
                s[i][..nj].copy_from_slice(&acc[(i0 + i) * tb + j0..][..nj]);
            }
            if ni == 4 && nj == NJ {
                for row in chunk.chunks_exact(tb) {
                    let x: [f64; 4] = row[i0..i0 + 4].try_into().expect("4 values");
                    let y: [f64; NJ] = row[j0..j0 + NJ].try_into().expect("NJ values");
                    for i in 0..4 {
                        for j in 0..NJ {
                            s[i][j] = if FMA {
                                x[i].mul_add(y[j], s[i][j])
                            } else {
                                s[i][j] + x[i] * y[j]
                            };
                        }
                    }
                }
            } else {
                for row in chunk.chunks_exact(tb) {
                    for i in 0..ni {
                        for j in 0..nj {
                            s[i][j] += row[i0 + i] * row[j0 + j];
                        }
                    }
                }
            }
            for i in 0..ni {
                acc[(i0 + i) * tb + j0..][..nj].copy_from_slice(&s[i][..nj]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tiled, parallel loop gives, bit for bit, the plain per-entry sum in position
    /// order: C = 75 (full and partial strips and blocks, diagonal and off-diagonal),
    /// over one chunk of positions and over several (the last partial), over every
    /// position and over a subset.
    #[test]
    fn gram_equals_the_plain_sum_bitwise() {
        let mut r = crate::rng::Rng::new(5);
        for (c, h, w) in [(75, 7, 9), (75, 13, 23), (64, 3, 3)] {
            let t = Tensor3 {
                c,
                h,
                w,
                data: (0..c * h * w).map(|_| r.normal() as f32).collect(),
            };
            let hw = h * w;
            let every: Vec<usize> = (0..hw).collect();
            let some: Vec<usize> = (0..hw).filter(|p| p % 3 != 1).collect();
            let g = gram(&t);
            for (keep, got) in [(&every, None), (&some, Some(gram_sums(&t, Some(&some))))] {
                for a in 0..c {
                    for b in 0..c {
                        let s: f64 = keep
                            .iter()
                            .map(|&p| t.data[a * hw + p] as f64 * t.data[b * hw + p] as f64)
                            .sum();
                        let (got, want) = match &got {
                            None => (g[a * c + b], s / hw as f64),
                            Some(sums) => (sums[a * c + b], s),
                        };
                        assert_eq!(got.to_bits(), want.to_bits(), "{c}x{h}x{w} ({a}, {b})");
                    }
                }
            }
        }
    }
}

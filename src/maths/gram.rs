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
/// f64), divided by `H W`. For speed the features are laid out position-major
/// ([`position_major`]) and the sums ([`gram_sums`]) advance a block of entries one
/// position at a time, so the inner loop runs over contiguous channels; that changes
/// no entry's summation order (see the bitwise test below).
pub fn gram(t: &Tensor3) -> Vec<f64> {
    let (c, hw) = (t.c, t.h * t.w);
    let mut g = gram_sums(&position_major(t, None), c);
    g.iter_mut().for_each(|v| *v /= hw as f64);
    g
}

/// The features of `t` (`[C, H, W]`) position-major in f64 (`[HW', C]`), of the
/// positions `keep` (ascending) or of all; transposed in blocks of 64 positions, in
/// parallel.
pub fn position_major(t: &Tensor3, keep: Option<&[usize]>) -> Vec<f64> {
    let (c, hw) = (t.c, t.h * t.w);
    let n = keep.map_or(hw, <[usize]>::len);
    let mut xt = vec![0.0f64; n * c];
    xt.par_chunks_mut(64 * c)
        .enumerate()
        .for_each(|(blk, out)| {
            let p0 = blk * 64;
            let np = out.len() / c;
            for a in 0..c {
                let ch = &t.data[a * hw..(a + 1) * hw];
                match keep {
                    None => {
                        for (k, &v) in ch[p0..p0 + np].iter().enumerate() {
                            out[k * c + a] = f64::from(v);
                        }
                    }
                    Some(keep) => {
                        for (k, &p) in keep[p0..p0 + np].iter().enumerate() {
                            out[k * c + a] = f64::from(ch[p]);
                        }
                    }
                }
            }
        });
    xt
}

/// The `C x C` sums `sum_p x[p][a] x[p][b]` (row-major, symmetric) of position-major
/// features `xt` (`[HW, C]`, from [`position_major`]), each over the positions in order:
/// the upper triangle in strips of `TILE` rows, in parallel (a strip runs from the
/// diagonal to the last column, so the features are read once per strip rather than
/// once per square tile), mirrored.
pub fn gram_sums(xt: &[f64], c: usize) -> Vec<f64> {
    let strips: Vec<usize> = (0..c).step_by(TILE).collect();
    let sums: Vec<Vec<f64>> = strips
        .par_iter()
        .map(|&a0| gram_tile(xt, c, a0, a0))
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

/// Rows of the strips of the Gram matrix computed as one task.
const TILE: usize = 16;
/// Columns of a block of sums held in registers (two vectors of four f64).
const NJ: usize = 8;

/// The sums `sum_p x[p][a] x[p][b]` of one tile (`a0..a0 + TILE` x `b0..c`, clipped to
/// `c`) of position-major features `xt` (`hw x c`), row-major `ta x tb`. Each
/// sum runs over the positions in order; positions are taken in chunks (so the tile's
/// columns stay in cache) and 4 x [`NJ`] blocks of sums are held in registers within a
/// chunk (eight independent vectors of four sums: enough to keep the multiply-adds
/// busy). On a diagonal tile the blocks wholly below the diagonal are not computed.
///
/// On x86-64 CPUs with AVX2 and FMA the same loop runs with fused multiply-adds, chosen
/// at run time. That gives the same bits: a product of two f32 values is exact in f64
/// (24 + 24 significant bits), so rounding `s + x y` once (fused) or rounding the
/// product first (exact) and then the sum is the same.
fn gram_tile(xt: &[f64], c: usize, a0: usize, b0: usize) -> Vec<f64> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        return unsafe { gram_tile_fma(xt, c, a0, b0) };
    }
    gram_tile_impl::<false>(xt, c, a0, b0)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn gram_tile_fma(xt: &[f64], c: usize, a0: usize, b0: usize) -> Vec<f64> {
    gram_tile_impl::<true>(xt, c, a0, b0)
}

/// [`gram_tile`]; `FMA`: accumulate with fused multiply-adds (only where the CPU has
/// them: elsewhere `mul_add` is a slow library call).
#[inline(always)]
fn gram_tile_impl<const FMA: bool>(xt: &[f64], c: usize, a0: usize, b0: usize) -> Vec<f64> {
    const CHUNK: usize = 128;
    let (ta, tb) = (TILE.min(c - a0), c - b0);
    let mut acc = vec![-0.0f64; ta * tb];
    for chunk in xt.chunks(CHUNK * c) {
        for i0 in (0..ta).step_by(4) {
            for j0 in (0..tb).step_by(NJ) {
                if a0 == b0 && j0 + NJ <= i0 {
                    continue; // below the diagonal: its mirror block is computed
                }
                let (ni, nj) = (4.min(ta - i0), NJ.min(tb - j0));
                let mut s = [[-0.0f64; NJ]; 4];
                for i in 0..ni {
                    s[i][..nj].copy_from_slice(&acc[(i0 + i) * tb + j0..][..nj]);
                }
                let (a, b) = (a0 + i0, b0 + j0);
                if ni == 4 && nj == NJ {
                    for row in chunk.chunks_exact(c) {
                        let x: [f64; 4] = row[a..a + 4].try_into().expect("4 values");
                        let y: [f64; NJ] = row[b..b + NJ].try_into().expect("NJ values");
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
                    for row in chunk.chunks_exact(c) {
                        for i in 0..ni {
                            for j in 0..nj {
                                s[i][j] += row[a + i] * row[b + j];
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
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tiled, parallel loop gives, bit for bit, the plain per-entry sum in position
    /// order (C = 75: full and partial tiles, diagonal and off-diagonal).
    #[test]
    fn gram_equals_the_plain_sum_bitwise() {
        let mut r = crate::rng::Rng::new(5);
        let (c, h, w) = (75, 7, 9);
        let t = Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(|_| r.normal() as f32).collect(),
        };
        let g = gram(&t);
        let hw = h * w;
        for a in 0..c {
            for b in 0..c {
                let s: f64 = (0..hw)
                    .map(|p| t.data[a * hw + p] as f64 * t.data[b * hw + p] as f64)
                    .sum();
                assert_eq!(
                    g[a * c + b].to_bits(),
                    (s / hw as f64).to_bits(),
                    "({a}, {b})"
                );
            }
        }
    }
}

//! The exact posterior mean under a *local* patch model (Kamb & Ganguli, ICML 2025, the
//! equivariant local score machine on one image per view): the candidates of a pixel are
//! the k x k patches of its own clean image centred within a radius of it, their squared
//! distances computed per offset as box sums over summed-area tables.

use super::*;

/// The exact posterior mean `[P, C]` at `pixels` (b, y, x) of the noisy images `z`
/// `[B, C, h, w]` under a *local* model of the clean images `source` `[B, C, h, w]`:
/// the candidates of pixel (b, y, x) are the k x k patches of image b centred within
/// `radius` of (y, x) and inside the image (Kamb & Ganguli's local score machine on one
/// image per view; patches read with reflection at the borders, as [`crate::prior::patch::bank::patches`]).
///
/// Written per offset o rather than per patch: the squared distance of the patch at i to
/// the one at i + o is a k x k box sum of e_o(p) = |z(p) - sa y(p + o)|^2, so one image of
/// e_o and its summed-area table give every pixel's distance for that offset in O(1)
/// (k^2 times fewer operations than comparing patches).
pub fn denoise_local(
    source: ArrayView4<'_, f32>,
    z: ArrayView4<'_, f32>,
    pixels: &[[usize; 3]],
    k: usize,
    radius: usize,
    level: Level,
) -> Array2<f32> {
    let (nb, channels, h, w) = source.dim();
    let side = 2 * radius + 1;
    let offsets: Vec<(isize, isize)> = (0..side * side)
        .map(|i| {
            (
                (i / side) as isize - radius as isize,
                (i % side) as isize - radius as isize,
            )
        })
        .collect();
    // dist[b][o][y * w + x]: the squared patch distance of pixel (y, x) to offset o.
    let dist: Vec<Vec<Vec<f32>>> = (0..nb)
        .into_par_iter()
        .map(|b| {
            offsets
                .par_iter()
                .map(|&o| {
                    offset_distances(
                        source.index_axis(Axis(0), b),
                        z.index_axis(Axis(0), b),
                        o,
                        k,
                        level.sa,
                    )
                })
                .collect()
        })
        .collect();
    let var2 = 2.0 * level.sb * level.sb;
    let mut out = vec![0.0f32; pixels.len() * channels];
    out.par_chunks_mut(channels)
        .zip(pixels.par_iter())
        .for_each(|(o, &[b, y, x])| {
            let inside = |(dy, dx): (isize, isize)| {
                let (yy, xx) = (y as isize + dy, x as isize + dx);
                (yy >= 0 && yy < h as isize && xx >= 0 && xx < w as isize)
                    .then_some((yy as usize, xx as usize))
            };
            let cand: Vec<(f32, usize, usize)> = offsets
                .iter()
                .enumerate()
                .filter_map(|(oi, &off)| {
                    inside(off).map(|(yy, xx)| (-dist[b][oi][y * w + x] / var2, yy, xx))
                })
                .collect();
            let logits: Vec<f32> = cand.iter().map(|c| c.0).collect();
            let (wgts, zsum) = shifted_exp(&logits);
            for (&(_, yy, xx), &wgt) in cand.iter().zip(&wgts) {
                for ch in 0..channels {
                    o[ch] += wgt * source[[b, ch, yy, xx]];
                }
            }
            o.iter_mut().for_each(|v| *v /= zsum);
        });
    Array2::from_shape_vec((pixels.len(), channels), out).expect("length matches")
}

/// For one image pair and offset o = (dy, dx): every pixel's squared distance between
/// the k x k patch of `z` at it and `sa` times the patch of `y` at it + o (reflected
/// reads), as a box sum of the per-pixel squared difference (a summed-area table in f64).
fn offset_distances(
    y: ArrayView3<'_, f32>,
    z: ArrayView3<'_, f32>,
    (dy, dx): (isize, isize),
    k: usize,
    sa: f32,
) -> Vec<f32> {
    use crate::prior::patch::bank::reflect;
    let (channels, h, w) = y.dim();
    let m = (k / 2) as isize;
    let (eh, ew) = (h + 2 * m as usize, w + 2 * m as usize);
    // Summed-area table of e over the extended domain [-m, h + m) x [-m, w + m).
    let mut sat = vec![0.0f64; (eh + 1) * (ew + 1)];
    for ey in 0..eh {
        let py = ey as isize - m;
        let (zy, yy) = (reflect(py, h), reflect(py + dy, h));
        let mut row = 0.0f64;
        for ex in 0..ew {
            let px = ex as isize - m;
            let (zx, yx) = (reflect(px, w), reflect(px + dx, w));
            let mut e = 0.0f32;
            for c in 0..channels {
                let d = z[[c, zy, zx]] - sa * y[[c, yy, yx]];
                e += d * d;
            }
            row += e as f64;
            sat[(ey + 1) * (ew + 1) + ex + 1] = sat[ey * (ew + 1) + ex + 1] + row;
        }
    }
    let ks = k;
    let mut out = vec![0.0f32; h * w];
    for yi in 0..h {
        for xi in 0..w {
            // Pixel (yi, xi)'s patch covers extended rows yi..yi + k, columns xi..xi + k.
            let (y0, x0, y1, x1) = (yi, xi, yi + ks, xi + ks);
            let s = sat[y1 * (ew + 1) + x1] - sat[y0 * (ew + 1) + x1] - sat[y1 * (ew + 1) + x0]
                + sat[y0 * (ew + 1) + x0];
            out[yi * w + xi] = s.max(0.0) as f32;
        }
    }
    out
}

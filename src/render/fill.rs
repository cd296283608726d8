//! What the prior sees around the object: the render's own colours, un-premultiplied,
//! extended into the uncovered background by push-pull (Gortler et al. 1996, "The
//! Lumigraph", Sec. 3.4: a pyramid of coverage-weighted averages, each level filling
//! the holes of the finer one by bilinear upsampling).
//!
//! Why: a captured object rendered over black covers a small part of the frame. A 2D
//! prior that looks at the whole frame then works on "a small object in a black void":
//! the stylizer's style vector of such a frame is dominated by black (its self-restyling
//! is far darker than the object, which is where the brightening drift of the first
//! version came from), and its output bleeds the void's texture into the silhouette.
//! Filling the void with the object's own colours gives the prior a frame whose
//! statistics are the object's; the fill carries no new information, and the colour
//! fit only ever sees the covered part (targets are recomposited with the coverage,
//! target = render + alpha (c' - c), [`crate::distill::step::targets`]).
//!
//! [`prior_image`] and [`prior_view`] are what the prior is given of a render: the render
//! itself, or the object over the fill.
//!
//! Images are `[H, W, 3]` row-major; weights (coverage, alpha) `[H, W]` in [0, 1].

use ndarray::Array3;

/// Colour per pixel with the background removed: `(rgb - (1 - a) bg) / a`, clamped to
/// [0, 1]; 0 where `a` < 1e-4 (no colour to recover).
pub fn unpremultiply(rgb: &[f32], alpha: &[f32], bg: [f32; 3]) -> Vec<f32> {
    let mut out = vec![0.0f32; rgb.len()];
    for (p, &a) in alpha.iter().enumerate() {
        if a < 1e-4 {
            continue;
        }
        for c in 0..3 {
            out[p * 3 + c] = ((rgb[p * 3 + c] - (1.0 - a) * bg[c]) / a).clamp(0.0, 1.0);
        }
    }
    out
}

/// Push-pull: `colour` kept where `weight` is 1, blended towards the coarser levels'
/// weighted average where it is less, the average alone where it is 0. Every output
/// pixel is a convex combination of input colours with positive weight (so it stays in
/// their range); with no weight anywhere the result is 0.
pub fn push_pull(colour: &[f32], weight: &[f32], h: usize, w: usize) -> Vec<f32> {
    assert_eq!(colour.len(), h * w * 3);
    assert_eq!(weight.len(), h * w);
    let wsum: f64 = weight.iter().map(|&v| v as f64).sum();
    if h <= 1 && w <= 1 || wsum <= 0.0 {
        // The coarsest level: one weighted mean (or nothing to average).
        let mut m = [0.0f64; 3];
        if wsum > 0.0 {
            for (p, &a) in weight.iter().enumerate() {
                for c in 0..3 {
                    m[c] += a as f64 * colour[p * 3 + c] as f64;
                }
            }
            m.iter_mut().for_each(|v| *v /= wsum);
        }
        let mut out = colour.to_vec();
        for (p, &a) in weight.iter().enumerate() {
            let a = a.clamp(0.0, 1.0);
            for c in 0..3 {
                out[p * 3 + c] = a * colour[p * 3 + c] + (1.0 - a) * m[c] as f32;
            }
        }
        return out;
    }
    // Push: 2x2 sums of weight and weighted colour.
    let (h2, w2) = (h.div_ceil(2), w.div_ceil(2));
    let mut cw = vec![0.0f32; h2 * w2 * 3];
    let mut ws = vec![0.0f32; h2 * w2];
    for y in 0..h {
        for x in 0..w {
            let (p, q) = (y * w + x, (y / 2) * w2 + x / 2);
            let a = weight[p];
            ws[q] += a;
            for c in 0..3 {
                cw[q * 3 + c] += a * colour[p * 3 + c];
            }
        }
    }
    let mut small = vec![0.0f32; h2 * w2 * 3];
    let mut small_w = vec![0.0f32; h2 * w2];
    for q in 0..h2 * w2 {
        if ws[q] > 0.0 {
            for c in 0..3 {
                small[q * 3 + c] = cw[q * 3 + c] / ws[q];
            }
        }
        small_w[q] = ws[q].min(1.0);
    }
    let coarse = push_pull(&small, &small_w, h2, w2);
    // Pull: bilinear upsampling (pixel centres aligned), blended under the fine level.
    let mut out = vec![0.0f32; h * w * 3];
    let tap = |i: usize, n2: usize| -> (usize, usize, f32) {
        let s = ((i as f32 + 0.5) / 2.0 - 0.5).clamp(0.0, (n2 - 1) as f32);
        let i0 = s.floor() as usize;
        let i1 = (i0 + 1).min(n2 - 1);
        (i0, i1, s - i0 as f32)
    };
    let tx: Vec<(usize, usize, f32)> = (0..w).map(|x| tap(x, w2)).collect();
    for y in 0..h {
        let (y0, y1, fy) = tap(y, h2);
        for (x, &(x0, x1, fx)) in tx.iter().enumerate() {
            let p = y * w + x;
            let a = weight[p].clamp(0.0, 1.0);
            for c in 0..3 {
                let g = |yy: usize, xx: usize| coarse[(yy * w2 + xx) * 3 + c];
                let up = (1.0 - fy) * ((1.0 - fx) * g(y0, x0) + fx * g(y0, x1))
                    + fy * ((1.0 - fx) * g(y1, x0) + fx * g(y1, x1));
                out[p * 3 + c] = a * colour[p * 3 + c] + (1.0 - a) * up;
            }
        }
    }
    out
}

/// The frame the prior sees: the object's colours over a push-pull fill of themselves
/// (module docs). `rgb` was composited over `bg` with coverage `alpha`.
pub fn fill_background(rgb: &[f32], alpha: &[f32], bg: [f32; 3], h: usize, w: usize) -> Vec<f32> {
    let c = unpremultiply(rgb, alpha, bg);
    push_pull(&c, alpha, h, w)
}

/// The image `[H, W, 3]` the prior sees of a render `rgb` `[H, W, 3]` composited over
/// `background` with coverage `alpha` `[H, W]`: the render itself, or with `fill` the
/// object over a push-pull fill of its own colours ([`fill_background`]).
pub fn prior_image(
    rgb: &[f32],
    alpha: &[f32],
    background: [f32; 3],
    fill: bool,
    (h, w): (usize, usize),
) -> Vec<f32> {
    if fill {
        fill_background(rgb, alpha, background, h, w)
    } else {
        rgb.to_vec()
    }
}

/// [`prior_image`] as the encoder takes it, `[3, H, W]`.
pub fn prior_view(
    rgb: &[f32],
    alpha: &[f32],
    background: [f32; 3],
    fill: bool,
    (h, w): (usize, usize),
) -> Array3<f32> {
    let img = prior_image(rgb, alpha, background, fill, (h, w));
    Array3::from_shape_fn((3, h, w), |(c, y, x)| img[(y * w + x) * 3 + c])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_coverage_is_the_identity_and_holes_take_the_neighbours_colour() {
        let (h, w) = (5, 7);
        let c: Vec<f32> = (0..h * w * 3).map(|i| (i % 11) as f32 / 10.0).collect();
        assert_eq!(push_pull(&c, &vec![1.0; h * w], h, w), c);
        // A half-covered frame: left half red, right half uncovered.
        let (h, w) = (8, 8);
        let mut c = vec![0.0f32; h * w * 3];
        let mut a = vec![0.0f32; h * w];
        for y in 0..h {
            for x in 0..w / 2 {
                a[y * w + x] = 1.0;
                c[(y * w + x) * 3] = 0.9;
            }
        }
        let f = push_pull(&c, &a, h, w);
        for p in 0..h * w {
            assert!((f[p * 3] - 0.9).abs() < 1e-5, "pixel {p}: {}", f[p * 3]);
            assert!(f[p * 3 + 1].abs() < 1e-6);
        }
    }

    #[test]
    fn fill_stays_in_the_range_of_covered_colours() {
        let (h, w) = (13, 9);
        let mut rng = crate::rng::Rng::new(3);
        let c: Vec<f32> = (0..h * w * 3)
            .map(|_| 0.2 + 0.5 * rng.uniform() as f32)
            .collect();
        let a: Vec<f32> = (0..h * w)
            .map(|_| {
                if rng.uniform() < 0.2 {
                    rng.uniform() as f32
                } else {
                    0.0
                }
            })
            .collect();
        let f = push_pull(&c, &a, h, w);
        assert!(f.iter().all(|v| (0.2 - 1e-5..=0.7 + 1e-5).contains(v)));
        // No coverage at all: zeros, no NaN.
        assert!(
            push_pull(&c, &vec![0.0; h * w], h, w)
                .iter()
                .all(|v| *v == 0.0)
        );
    }

    #[test]
    fn unpremultiply_inverts_compositing() {
        let bg = [0.2, 0.4, 0.6];
        let colour = [0.9f32, 0.1, 0.5];
        let alpha = [0.0f32, 0.3, 1.0];
        let mut rgb = Vec::new();
        for a in alpha {
            for c in 0..3 {
                rgb.push(a * colour[c] + (1.0 - a) * bg[c]);
            }
        }
        let u = unpremultiply(&rgb, &alpha, bg);
        assert_eq!(&u[..3], &[0.0, 0.0, 0.0]);
        for p in 1..3 {
            for c in 0..3 {
                assert!((u[p * 3 + c] - colour[c]).abs() < 1e-5);
            }
        }
    }
}

//! Gram-matrix style distance (Gatys et al. 2016) on VGG16 features — an extra style
//! measure beside FID_style, the loss the VGG baselines (SGSST-like) optimise.
//!
//! For each LPIPS-VGG tap (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3) with features
//! `F` (`C x HW`), `G = F F^T / (H W)`, so images of different sizes are comparable; the
//! distance is `sum_k mean_{c,c'} (G_k(x) - G_k(s))^2`.

use super::nets::Features;
use crate::vgg::Tensor3;
use rayon::prelude::*;

/// The `C x C` Gram matrix `G = F F^T / (H W)` of a `[C, H, W]` feature map, row-major,
/// in f64. The one Gram of the crate: the metric below and the VGG baselines' style loss
/// ([`crate::baselines::gram_loss_grad`]) both use it.
///
/// Each entry is the sum over positions, in position order, of `f_a f_b` (products in
/// f64), divided by `H W`; rows run in parallel and four entries of a row accumulate
/// side by side, which changes no entry's summation order.
pub fn gram(t: &Tensor3) -> Vec<f64> {
    let (c, hw) = (t.c, t.h * t.w);
    let ch = |a: usize| &t.data[a * hw..(a + 1) * hw];
    // Upper triangle: row a holds entries b = a..c.
    let upper: Vec<Vec<f64>> = (0..c)
        .into_par_iter()
        .map(|a| {
            let fa = ch(a);
            let mut row = Vec::with_capacity(c - a);
            let mut b = a;
            while b + 4 <= c {
                let (f0, f1, f2, f3) = (ch(b), ch(b + 1), ch(b + 2), ch(b + 3));
                let mut s = [-0.0f64; 4];
                for p in 0..hw {
                    let x = fa[p] as f64;
                    s[0] += x * f0[p] as f64;
                    s[1] += x * f1[p] as f64;
                    s[2] += x * f2[p] as f64;
                    s[3] += x * f3[p] as f64;
                }
                row.extend(s);
                b += 4;
            }
            for b in b..c {
                let fb = ch(b);
                row.push(fa.iter().zip(fb).map(|(x, y)| *x as f64 * *y as f64).sum());
            }
            row
        })
        .collect();
    let mut g = vec![0.0; c * c];
    for (a, row) in upper.iter().enumerate() {
        for (k, s) in row.iter().enumerate() {
            let b = a + k;
            g[a * c + b] = s / hw as f64;
            g[b * c + a] = s / hw as f64;
        }
    }
    g
}

/// Gram matrices of every tap.
pub fn grams(f: &Features) -> Vec<Vec<f64>> {
    f.iter().map(gram).collect()
}

/// `sum_k mean (G_k(a) - G_k(b))^2`.
pub fn gram_distance(a: &[Vec<f64>], b: &[Vec<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(ga, gb)| {
            ga.iter()
                .zip(gb)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f64>()
                / ga.len() as f64
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocked, parallel loop gives, bit for bit, the plain per-entry sum in position
    /// order (C = 11: blocks of four and a remainder).
    #[test]
    fn gram_equals_the_plain_sum_bitwise() {
        let mut r = crate::rng::Rng::new(5);
        let (c, h, w) = (11, 7, 9);
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

    #[test]
    fn gram_by_hand_and_size_invariance() {
        // c = 2, positions: (1, 2), (3, 4) -> G = [[10, 14], [14, 20]] / 2
        let t = Tensor3 {
            c: 2,
            h: 1,
            w: 2,
            data: vec![1.0, 3.0, 2.0, 4.0],
        };
        assert_eq!(gram(&t), vec![5.0, 7.0, 7.0, 10.0]);
        // the same statistics over twice the positions give the same Gram matrix
        let t2 = Tensor3 {
            c: 2,
            h: 2,
            w: 2,
            data: vec![1.0, 3.0, 1.0, 3.0, 2.0, 4.0, 2.0, 4.0],
        };
        assert_eq!(gram(&t2), gram(&t));
        let g = grams(&vec![t.clone()]);
        assert_eq!(gram_distance(&g, &g), 0.0);
        let other = grams(&vec![Tensor3 {
            c: 2,
            h: 1,
            w: 2,
            data: vec![0.0; 4],
        }]);
        assert!((gram_distance(&g, &other) - (25.0 + 49.0 + 49.0 + 100.0) / 4.0).abs() < 1e-12);
    }
}

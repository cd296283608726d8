//! Gram-matrix style distance (Gatys et al. 2016) on VGG16 features — an extra style
//! measure beside FID_style, the loss the VGG baselines (SGSST-like) optimise.
//!
//! For each LPIPS-VGG tap (relu1_2, relu2_2, relu3_3, relu4_3, relu5_3) with features
//! `F` (`C x HW`), `G = F F^T / (H W)`, so images of different sizes are comparable; the
//! distance is `sum_k mean_{c,c'} (G_k(x) - G_k(s))^2`.

use super::nets::Features;
use crate::maths::gram::gram;

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
    use crate::vgg::Tensor3;

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

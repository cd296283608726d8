//! `tv`: total variation of the object's colours, a smoothness term on each view's render
//! (Johnson et al. 2016, "Perceptual losses for real-time style transfer", Sec. 3.3: the
//! total-variation regulariser; here its squared form). Over the pairs of horizontally
//! and vertically neighbouring pixels (p, q) of a view, each weighted by the object's
//! coverage at both, min(a_p, a_q):
//!
//! ```text
//! L = 1/n sum_(p,q) min(a_p, a_q) 1/2 |x_p - x_q|^2,   dL/dx_p = 1/n sum_q min(a_p, a_q) (x_p - x_q)
//! ```
//!
//! with `n` the view's values (H W 3), as the prior term scales its loss. Not part of
//! FantasyStyle: it damps the speckle a high-variance gradient leaves, at the cost of fine
//! strokes. It is the smallest example of a term: one file and one line of
//! [`super::TERMS`].

use super::ViewTerm;

/// The total-variation term (no settings).
#[derive(Debug, Clone, Copy, Default)]
pub struct TotalVariation;

/// Make the term ([`super::Role::View`]).
pub fn make() -> Box<dyn ViewTerm> {
    Box::new(TotalVariation)
}

impl ViewTerm for TotalVariation {
    fn view(&self, rgb: &[f32], alpha: &[f32], h: usize, w: usize) -> (f64, Vec<f32>) {
        let n = rgb.len().max(1) as f32;
        let mut g = vec![0.0f32; rgb.len()];
        let mut loss = 0.0f64;
        let mut pair = |p: usize, q: usize, g: &mut [f32]| {
            let m = alpha[p].min(alpha[q]);
            if m <= 0.0 {
                return;
            }
            for c in 0..3 {
                let d = rgb[p * 3 + c] - rgb[q * 3 + c];
                loss += 0.5 * (m * d * d) as f64;
                g[p * 3 + c] += m * d / n;
                g[q * 3 + c] -= m * d / n;
            }
        };
        for y in 0..h {
            for x in 0..w {
                let p = y * w + x;
                if x + 1 < w {
                    pair(p, p + 1, &mut g);
                }
                if y + 1 < h {
                    pair(p, p + w, &mut g);
                }
            }
        }
        (loss / n as f64, g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The gradient is the loss's: central differences on a random view with partial
    /// coverage, in f64 of the f32 loss (step 1e-3, tolerance 2e-4 relative to the
    /// largest gradient); a flat view costs nothing.
    #[test]
    fn the_gradient_matches_finite_differences() {
        let (h, w) = (5, 6);
        let mut rng = crate::rng::Rng::new(3);
        let rgb: Vec<f32> = (0..h * w * 3).map(|_| rng.uniform() as f32).collect();
        let alpha: Vec<f32> = (0..h * w)
            .map(|i| if i % 7 == 0 { 0.0 } else { 0.8 })
            .collect();
        let (_, g) = TotalVariation.view(&rgb, &alpha, h, w);
        let big = g.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(big > 0.0);
        let eps = 1e-3f32;
        for i in (0..rgb.len()).step_by(5) {
            let (mut up, mut down) = (rgb.clone(), rgb.clone());
            up[i] += eps;
            down[i] -= eps;
            let fd = (TotalVariation.view(&up, &alpha, h, w).0
                - TotalVariation.view(&down, &alpha, h, w).0)
                / (2.0 * eps as f64);
            assert!(
                (fd - g[i] as f64).abs() <= 2e-4 * big as f64,
                "value {i}: finite difference {fd}, gradient {}",
                g[i]
            );
        }
        let flat = vec![0.3f32; h * w * 3];
        assert_eq!(TotalVariation.view(&flat, &alpha, h, w).0, 0.0);
    }
}

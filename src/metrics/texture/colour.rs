//! Object colour: over covered pixels (alpha > 0.5) of the original views' alpha,
//! colours un-premultiplied (divided by alpha; the views are rendered over black): the
//! share of *clipped* pixels (all channels <= 0.02 or all >= 0.98), and the distance of
//! the colour statistics to the style image's, `|mu - mu_s| + ||C - C_s||_F` (unbiased
//! covariances of the colours clipped to [0, 1]); over the silhouette fringe
//! (0.02 < alpha < 0.5), the mean brightening stylized - original over channels (the
//! "glowing haze" of issue 11).

use crate::imageio::Image;
use crate::metrics::views::ViewSet;
use serde::Serialize;

/// Colour measures over the object (see module docs).
#[derive(Debug, Clone, Serialize)]
pub struct ObjectColour {
    pub clipped_original: Option<f64>,
    pub clipped_stylized: Option<f64>,
    /// Mean (stylized - original) over the fringe pixels and channels.
    pub fringe_brightening: Option<f64>,
    pub fringe_pixels: usize,
    pub stats_distance_original: Option<f64>,
    pub stats_distance_stylized: Option<f64>,
}

/// `|mu_a - mu_b| + ||C_a - C_b||_F` of two RGB sets (unbiased covariances).
pub fn stats_distance(a: &[[f64; 3]], b: &[[f64; 3]]) -> Option<f64> {
    if a.len() < 2 || b.len() < 2 {
        return None;
    }
    let stats = |v: &[[f64; 3]]| {
        let n = v.len() as f64;
        let mut mu = [0.0; 3];
        for p in v {
            (0..3).for_each(|c| mu[c] += p[c] / n);
        }
        let mut cov = [0.0; 9];
        for p in v {
            for i in 0..3 {
                for j in 0..3 {
                    cov[i * 3 + j] += (p[i] - mu[i]) * (p[j] - mu[j]) / (n - 1.0);
                }
            }
        }
        (mu, cov)
    };
    let ((ma, ca), (mb, cb)) = (stats(a), stats(b));
    let dm = (0..3).map(|c| (ma[c] - mb[c]).powi(2)).sum::<f64>().sqrt();
    let dc = (0..9).map(|k| (ca[k] - cb[k]).powi(2)).sum::<f64>().sqrt();
    Some(dm + dc)
}

/// Clipped share, colour-statistics distance and fringe brightening (see module docs).
pub fn object_colour(orig: &ViewSet, styl: &ViewSet, style: &Image) -> ObjectColour {
    let sty: Vec<[f64; 3]> = style
        .data
        .chunks_exact(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let (mut uo, mut us) = (Vec::new(), Vec::new());
    let (mut fringe, mut nf) = (0.0, 0usize);
    for i in 0..orig.n {
        let (_, alpha) = orig.geometry(i);
        let (o, s) = (&orig.images[i].data, &styl.images[i].data);
        for (p, &a) in alpha.iter().enumerate() {
            if a > 0.5 {
                let un = |d: &[f32]| {
                    let q = &d[p * 3..p * 3 + 3];
                    [
                        q[0] as f64 / a as f64,
                        q[1] as f64 / a as f64,
                        q[2] as f64 / a as f64,
                    ]
                };
                uo.push(un(o));
                us.push(un(s));
            } else if a > 0.02 {
                for c in 0..3 {
                    fringe += (s[p * 3 + c] - o[p * 3 + c]) as f64;
                }
                nf += 1;
            }
        }
    }
    let clipped = |v: &[[f64; 3]]| {
        (!v.is_empty()).then(|| {
            v.iter()
                .filter(|p| p.iter().all(|&x| x <= 0.02) || p.iter().all(|&x| x >= 0.98))
                .count() as f64
                / v.len() as f64
        })
    };
    let clip01 = |v: &[[f64; 3]]| -> Vec<[f64; 3]> {
        v.iter().map(|p| p.map(|x| x.clamp(0.0, 1.0))).collect()
    };
    ObjectColour {
        clipped_original: clipped(&uo),
        clipped_stylized: clipped(&us),
        fringe_brightening: (nf > 0).then(|| fringe / (3 * nf) as f64),
        fringe_pixels: nf,
        stats_distance_original: stats_distance(&clip01(&uo), &sty),
        stats_distance_stylized: stats_distance(&clip01(&us), &sty),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_distance_by_hand() {
        // a: two points, mean (0.5, 0, 0), cov only in R: var = 0.5
        let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let b = [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        // |mu diff| = sqrt(0.25 + 1) ; ||cov diff|| = 0.5
        let d = stats_distance(&a, &b).unwrap();
        assert!((d - (1.25f64.sqrt() + 0.5)).abs() < 1e-12, "{d}");
        assert_eq!(stats_distance(&a, &a), Some(0.0));
    }
}

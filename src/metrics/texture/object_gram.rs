//! The per-layer Gram distance over the object: for each LPIPS-VGG16 tap in
//! [`GRAM_LAYERS`], the mean squared difference `mean_{c,c'} (G(x) - G(s))^2` between a
//! view's Gram matrix and the style image's, with the view's Gram alpha-weighted,
//! `G = sum_p w_p f_p f_p^T / sum_p w_p` (the rendered alpha box-averaged to the tap's
//! resolution as `w`), so that the black background does not dominate the statistics.

use super::ratio;
use crate::maths::gram::{gram, gram_sums};
use crate::metrics::nets::Features;
use crate::vgg::Tensor3;
use serde::Serialize;

/// The LPIPS-VGG16 taps the per-layer Gram distance reports (taps 0..4 of the five).
pub const GRAM_LAYERS: [&str; 4] = ["relu1_2", "relu2_2", "relu3_3", "relu4_3"];

/// Views whose object covers less than this many pixels (sum of alpha) are skipped by the
/// object measures.
const MIN_COVERAGE: f64 = 16.0;

/// The per-layer Gram distance over the object.
#[derive(Debug, Clone, Serialize)]
pub struct LayerGram {
    pub layer: &'static str,
    /// Mean over views of the stylized view's distance to the style.
    pub stylized: Option<f64>,
    /// The same for the original views.
    pub original: Option<f64>,
    /// `stylized / original`.
    pub ratio: Option<f64>,
    /// Per view (`None`: no object in the view).
    pub stylized_per_view: Vec<Option<f64>>,
    pub original_per_view: Vec<Option<f64>>,
}

/// Box-average `alpha` (`h x w`) to `th x tw` with the integer factors `h / th`,
/// `w / tw` (VGG's floor poolings: position `y` of a tap `2^k` times smaller covers input
/// rows `y 2^k .. (y+1) 2^k`).
pub fn pool_alpha(alpha: &[f32], w: usize, h: usize, tw: usize, th: usize) -> Vec<f32> {
    let (fy, fx) = ((h / th.max(1)).max(1), (w / tw.max(1)).max(1));
    let inv = 1.0 / (fx * fy) as f32;
    let mut out = vec![0.0; tw * th];
    for y in 0..th {
        for x in 0..tw {
            let mut s = 0.0;
            for dy in 0..fy {
                let row = (y * fy + dy).min(h - 1) * w;
                for dx in 0..fx {
                    s += alpha[row + (x * fx + dx).min(w - 1)];
                }
            }
            out[y * tw + x] = s * inv;
        }
    }
    out
}

/// The Gram matrix of `t` weighted by `weights` (one per position):
/// `sum_p w_p f_p f_p^T / sum_p w_p`; `None` when the weights sum to less than 1e-6.
///
/// Computed as the Gram of the features scaled by `sqrt(w_p)` (in f32), times
/// `HW / sum_p w_p`. The positions of weight 0 (the background, most of a view of an
/// object) add products of zeros, which change no sum that is not itself zero: the sums
/// run over the other positions alone (their scaled features gathered first, so the
/// work follows the object's size, not the view's). An entry that comes out zero is zero
/// over every position too, and only its sign can differ: a sum in order from -0 stays
/// -0 only while every product is -0. So it is +0 unless a channel of the two has a sign
/// bit set (a negative value or a -0; ReLU features have none), and then summed again
/// over every position; every bit is that of the sum over all of them (see the test).
pub fn weighted_gram(t: &Tensor3, weights: &[f32]) -> Option<Vec<f64>> {
    let hw = t.h * t.w;
    assert_eq!(weights.len(), hw, "weighted_gram: weights size");
    let sw: f64 = weights.iter().map(|&v| v as f64).sum();
    if sw < 1e-6 {
        return None;
    }
    let root: Vec<f32> = weights.iter().map(|&v| v.max(0.0).sqrt()).collect();
    let k = hw as f64 / sw;
    let keep: Vec<usize> = (0..hw).filter(|&p| root[p] != 0.0).collect();
    // A skipped position's products must be zeros: finite features (`f * 0` is then a
    // zero of `f`'s sign).
    let finite = t.data.iter().all(|v| v.is_finite());
    let mut g = if keep.len() < hw && finite {
        let c = t.c;
        let kept = Tensor3 {
            c,
            h: 1,
            w: keep.len(),
            data: t
                .data
                .chunks_exact(hw)
                .flat_map(|ch| keep.iter().map(|&p| ch[p] * root[p]))
                .collect(),
        };
        let signed: Vec<bool> = t
            .data
            .chunks_exact(hw)
            .map(|ch| ch.iter().any(|v| v.is_sign_negative()))
            .collect();
        let mut g = gram_sums(&kept, None);
        for a in 0..c {
            for b in a..c {
                if g[a * c + b] == 0.0 {
                    let s = if signed[a] || signed[b] {
                        let (fa, fb) =
                            (&t.data[a * hw..(a + 1) * hw], &t.data[b * hw..(b + 1) * hw]);
                        (0..hw)
                            .map(|p| f64::from(fa[p] * root[p]) * f64::from(fb[p] * root[p]))
                            .sum()
                    } else {
                        0.0
                    };
                    g[a * c + b] = s;
                    g[b * c + a] = s;
                }
            }
        }
        g.iter_mut().for_each(|v| *v /= hw as f64);
        g
    } else {
        let mut scaled = t.clone();
        for ch in scaled.data.chunks_exact_mut(hw) {
            ch.iter_mut().zip(&root).for_each(|(f, r)| *f *= r);
        }
        gram(&scaled)
    };
    g.iter_mut().for_each(|v| *v *= k);
    Some(g)
}

/// One view's alpha-weighted Gram matrix per layer of [`GRAM_LAYERS`] (`None` where the
/// view covers less than `MIN_COVERAGE`), from its features and its alpha (`h x w`, the
/// image's): what [`ObjectGram::distances`] compares with the style's.
pub fn view_grams(f: &Features, alpha: &[f32], w: usize, h: usize) -> Vec<Option<Vec<f64>>> {
    let covered = alpha.iter().map(|&a| a as f64).sum::<f64>() >= MIN_COVERAGE;
    (0..GRAM_LAYERS.len())
        .map(|k| {
            let f = &f[k];
            covered
                .then(|| weighted_gram(f, &pool_alpha(alpha, w, h, f.w, f.h)))
                .flatten()
        })
        .collect()
}

fn mean_sq_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64
}

fn mean_some(v: &[Option<f64>]) -> Option<f64> {
    let s: Vec<f64> = v.iter().flatten().copied().collect();
    (!s.is_empty()).then(|| s.iter().sum::<f64>() / s.len() as f64)
}

/// Accumulates the per-layer object Gram distances view by view (the evaluation's VGG
/// loop feeds it the features it computes anyway).
#[derive(Debug, Clone)]
pub struct ObjectGram {
    style: Vec<Vec<f64>>,
    stylized: Vec<Vec<Option<f64>>>,
    original: Vec<Vec<Option<f64>>>,
}

impl ObjectGram {
    /// `style_grams`: the style image's Gram matrices per tap (at least the four of
    /// [`GRAM_LAYERS`], in tap order).
    pub fn new(style_grams: &[Vec<f64>]) -> ObjectGram {
        assert!(style_grams.len() >= GRAM_LAYERS.len(), "ObjectGram: taps");
        ObjectGram {
            style: style_grams[..GRAM_LAYERS.len()].to_vec(),
            stylized: vec![Vec::new(); GRAM_LAYERS.len()],
            original: vec![Vec::new(); GRAM_LAYERS.len()],
        }
    }

    /// One view's distance to the style per layer of [`GRAM_LAYERS`] (`None` where the
    /// view covers less than `MIN_COVERAGE`), from its features and its alpha (`h x w`,
    /// the image's): [`Self::distances`] of [`view_grams`].
    pub fn view_distances(
        &self,
        f: &Features,
        alpha: &[f32],
        w: usize,
        h: usize,
    ) -> Vec<Option<f64>> {
        self.distances(&view_grams(f, alpha, w, h))
    }

    /// The distance to the style per layer of one view's object Grams ([`view_grams`]).
    pub fn distances(&self, grams: &[Option<Vec<f64>>]) -> Vec<Option<f64>> {
        grams
            .iter()
            .zip(&self.style)
            .map(|(g, s)| g.as_ref().map(|g| mean_sq_diff(g, s)))
            .collect()
    }

    /// One view: the [`Self::view_distances`] of its stylized and of its original render.
    pub fn push(&mut self, stylized: &[Option<f64>], original: &[Option<f64>]) {
        for k in 0..GRAM_LAYERS.len() {
            self.stylized[k].push(stylized[k]);
            self.original[k].push(original[k]);
        }
    }

    /// The per-layer summary.
    pub fn finish(self) -> Vec<LayerGram> {
        GRAM_LAYERS
            .iter()
            .enumerate()
            .map(|(k, &layer)| {
                let (s, o) = (mean_some(&self.stylized[k]), mean_some(&self.original[k]));
                LayerGram {
                    layer,
                    stylized: s,
                    original: o,
                    ratio: ratio(s, o),
                    stylized_per_view: self.stylized[k].clone(),
                    original_per_view: self.original[k].clone(),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn rand_tensor(c: usize, h: usize, w: usize, seed: u64) -> Tensor3 {
        let mut r = Rng::new(seed);
        Tensor3 {
            c,
            h,
            w,
            data: (0..c * h * w).map(|_| r.normal().abs() as f32).collect(),
        }
    }

    /// Weighted Gram against the plain weighted sum; 0/1 weights equal the Gram of the
    /// kept positions alone.
    #[test]
    fn weighted_gram_by_definition() {
        let (c, h, w) = (5, 4, 6);
        let t = rand_tensor(c, h, w, 1);
        let mut r = Rng::new(2);
        let wts: Vec<f32> = (0..h * w).map(|_| r.uniform() as f32).collect();
        let g = weighted_gram(&t, &wts).unwrap();
        let sw: f64 = wts.iter().map(|&v| v as f64).sum();
        for a in 0..c {
            for b in 0..c {
                let s: f64 = (0..h * w)
                    .map(|p| {
                        wts[p] as f64 * t.data[a * h * w + p] as f64 * t.data[b * h * w + p] as f64
                    })
                    .sum();
                assert!(
                    (g[a * c + b] - s / sw).abs() < 1e-6 * (1.0 + s.abs()),
                    "{a},{b}"
                );
            }
        }
        // Positions with weight 0 do not count; with weight 1 it is their Gram.
        let keep: Vec<f32> = (0..h * w)
            .map(|p| if p % 3 == 0 { 1.0 } else { 0.0 })
            .collect();
        let kept: Vec<usize> = (0..h * w).filter(|p| p % 3 == 0).collect();
        let sub = Tensor3 {
            c,
            h: 1,
            w: kept.len(),
            data: (0..c)
                .flat_map(|a| kept.iter().map(move |&p| (a, p)))
                .map(|(a, p)| t.data[a * h * w + p])
                .collect(),
        };
        let (g1, g2) = (weighted_gram(&t, &keep).unwrap(), gram(&sub));
        for (x, y) in g1.iter().zip(&g2) {
            assert!((x - y).abs() < 1e-6 * (1.0 + y.abs()));
        }
        assert!(weighted_gram(&t, &vec![0.0; h * w]).is_none());
    }

    /// With positions of weight 0 (skipped) the bits are those of the Gram over every
    /// position: ordinary entries, entries that are exactly zero (a channel that is zero
    /// wherever the weight is not: +0, or -0 from -0 or negative features), a channel of
    /// -0s and one of +0s.
    #[test]
    fn skipping_zero_weights_changes_no_bit() {
        let (c, h, w) = (21, 9, 13);
        let mut t = rand_tensor(c, h, w, 3);
        let hw = h * w;
        let wts: Vec<f32> = (0..hw)
            .map(|p| {
                if p % 5 < 2 {
                    0.0
                } else {
                    0.3 + (p % 7) as f32 * 0.1
                }
            })
            .collect();
        for p in 0..hw {
            // Channel 3: nonzero only where the weight is 0; channel 4: -0 everywhere;
            // channel 5: -0 where the weight is 0, +0 elsewhere; channel 6: +0
            // everywhere; channel 7: negative only where the weight is 0.
            t.data[3 * hw + p] = if wts[p] == 0.0 { 1.5 } else { 0.0 };
            t.data[4 * hw + p] = -0.0;
            t.data[5 * hw + p] = if wts[p] == 0.0 { -0.0 } else { 0.0 };
            t.data[6 * hw + p] = 0.0;
            t.data[7 * hw + p] = if wts[p] == 0.0 { -2.0 } else { 0.0 };
        }
        let got = weighted_gram(&t, &wts).unwrap();
        // By definition, every position summed in order.
        let sw: f64 = wts.iter().map(|&v| v as f64).sum();
        let root: Vec<f32> = wts.iter().map(|&v| v.max(0.0).sqrt()).collect();
        let f = |a: usize, p: usize| f64::from(t.data[a * hw + p] * root[p]);
        for a in 0..c {
            for b in 0..c {
                let s: f64 = (0..hw).map(|p| f(a, p) * f(b, p)).sum();
                let want = s / hw as f64 * (hw as f64 / sw);
                assert_eq!(got[a * c + b].to_bits(), want.to_bits(), "({a}, {b})");
            }
        }
    }

    #[test]
    fn pool_alpha_matches_floor_pooling() {
        // 5 wide x 4 high pooled by 2 (floor): 2 x 2 output, the last column dropped.
        let a: Vec<f32> = (0..20).map(|v| v as f32).collect();
        let p = pool_alpha(&a, 5, 4, 2, 2);
        assert_eq!(p, vec![3.0, 5.0, 13.0, 15.0]);
    }
}

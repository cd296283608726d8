//! KID with its interval: the unbiased KID of [`crate::metrics::fid::kid`] with a
//! jackknife standard error (Arvesen's two-sample jackknife: leave one image out of each
//! set in turn, `var = (n-1)/n sum (theta_-i - mean)^2` per set, summed), and
//! `value +- 1.96 se`. Reliable when both sets have at least [`KID_MIN_IMAGES`] images.

use crate::maths::kid::{kernel_matrix, mmd2};
use crate::metrics::fid::FeatureSet;
use serde::Serialize;

/// Fewest images per set for a KID the benchmark calls reliable (issue 21: 16 views).
pub const KID_MIN_IMAGES: usize = 16;

/// KID_style with its jackknife interval.
#[derive(Debug, Clone, Serialize)]
pub struct KidInterval {
    pub value: Option<f64>,
    /// Jackknife standard error.
    pub se: Option<f64>,
    /// `value -+ 1.96 se`.
    pub ci95: Option<[f64; 2]>,
    pub n_a: usize,
    pub n_b: usize,
    pub reliable: bool,
    pub note: String,
}

impl KidInterval {
    /// A KID not computed because the Inception measures are off.
    pub fn off() -> KidInterval {
        KidInterval {
            value: None,
            se: None,
            ci95: None,
            n_a: 0,
            n_b: 0,
            reliable: false,
            note: crate::metrics::fid::OFF_NOTE.into(),
        }
    }
}

/// KID (the value of [`crate::metrics::fid::kid`]) and its two-sample jackknife standard error;
/// `None` for the error when a set has fewer than 3 images.
pub fn kid_jackknife(a: &FeatureSet, b: &FeatureSet) -> Option<(f64, Option<f64>)> {
    if a.n < 2 || b.n < 2 || a.d != b.d {
        return None;
    }
    let kaa = kernel_matrix(&a.data, a.n, &a.data, a.n, a.d);
    let kbb = kernel_matrix(&b.data, b.n, &b.data, b.n, b.d);
    let kab = kernel_matrix(&a.data, a.n, &b.data, b.n, a.d);
    let (mut ka, mut kb) = (vec![true; a.n], vec![true; b.n]);
    let full = mmd2(&kaa, &kbb, &kab, a.n, b.n, &ka, &kb);
    if a.n < 3 || b.n < 3 {
        return Some((full, None));
    }
    let mut var = 0.0;
    for side in 0..2 {
        let n = if side == 0 { a.n } else { b.n };
        let mut th = Vec::with_capacity(n);
        for i in 0..n {
            let keep = if side == 0 { &mut ka } else { &mut kb };
            keep[i] = false;
            th.push(mmd2(&kaa, &kbb, &kab, a.n, b.n, &ka, &kb));
            let keep = if side == 0 { &mut ka } else { &mut kb };
            keep[i] = true;
        }
        let m = th.iter().sum::<f64>() / n as f64;
        var += (n - 1) as f64 / n as f64 * th.iter().map(|t| (t - m) * (t - m)).sum::<f64>();
    }
    Some((full, Some(var.sqrt())))
}

/// KID_style with its interval from the Inception features of the stylized views and of
/// the style crops.
pub fn kid_interval(styl: &[Vec<f32>], crops: &[Vec<f32>], sets: [&str; 2]) -> KidInterval {
    let (na, nb) = (styl.len(), crops.len());
    let r = (na >= 2 && nb >= 2)
        .then(|| kid_jackknife(&FeatureSet::from_rows(styl), &FeatureSet::from_rows(crops)))
        .flatten();
    let (value, se) = match r {
        Some((v, se)) => (Some(v), se),
        None => (None, None),
    };
    let reliable = na.min(nb) >= KID_MIN_IMAGES;
    KidInterval {
        value,
        se,
        ci95: value.zip(se).map(|(v, s)| [v - 1.96 * s, v + 1.96 * s]),
        n_a: na,
        n_b: nb,
        reliable,
        note: format!(
            "{na} {} vs {nb} {}; {}",
            sets[0],
            sets[1],
            if reliable {
                "interval from the two-sample jackknife".to_string()
            } else {
                format!(
                    "fewer than {KID_MIN_IMAGES} images per set: high variance, compare with care"
                )
            }
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn set(rows: &[Vec<f64>]) -> FeatureSet {
        FeatureSet {
            n: rows.len(),
            d: rows[0].len(),
            data: rows.iter().flatten().copied().collect(),
        }
    }

    /// The jackknife KID equals fid::kid, and its standard error equals a direct
    /// leave-one-out recomputation with fid::kid on the reduced sets.
    #[test]
    fn kid_jackknife_against_fid_kid() {
        let mut r = Rng::new(7);
        let rows = |n: usize, shift: f64, r: &mut Rng| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| (0..6).map(|_| shift + r.normal()).collect())
                .collect()
        };
        let (ra, rb) = (rows(7, 0.0, &mut r), rows(5, 0.4, &mut r));
        let (a, b) = (set(&ra), set(&rb));
        let (v, se) = kid_jackknife(&a, &b).unwrap();
        let want = crate::metrics::fid::kid(&a, &b).unwrap();
        assert!(
            (v - want).abs() < 1e-9 * want.abs().max(1.0),
            "{v} vs {want}"
        );
        let mut var = 0.0;
        for (rows_, other, first) in [(&ra, &rb, true), (&rb, &ra, false)] {
            let n = rows_.len();
            let th: Vec<f64> = (0..n)
                .map(|i| {
                    let less: Vec<Vec<f64>> = rows_
                        .iter()
                        .enumerate()
                        .filter(|(j, _)| *j != i)
                        .map(|(_, x)| x.clone())
                        .collect();
                    let (x, y) = if first {
                        (set(&less), set(other))
                    } else {
                        (set(other), set(&less))
                    };
                    crate::metrics::fid::kid(&x, &y).unwrap()
                })
                .collect();
            let m = th.iter().sum::<f64>() / n as f64;
            var += (n - 1) as f64 / n as f64 * th.iter().map(|t| (t - m).powi(2)).sum::<f64>();
        }
        let se = se.unwrap();
        assert!(
            (se - var.sqrt()).abs() < 1e-9 * se.max(1e-12),
            "{se} vs {}",
            var.sqrt()
        );
        assert!(se > 0.0);
        // Two images per set: a value but no error.
        let (v2, se2) = kid_jackknife(&set(&ra[..2]), &set(&rb[..2])).unwrap();
        assert!(v2.is_finite() && se2.is_none());
    }
}

//! Selection algebra on weights in [0, 1] (the fuzzy-set operators of Zadeh, 1965):
//! union `max(a, b)`, intersection `min(a, b)`, complement `1 - a`. On hard selections
//! (weights 0 and 1) they are the set operations; on soft ones they keep weights in
//! [0, 1].

use super::Selection;
use crate::{Error, Result};
use std::path::Path;

/// The two selections' weights side by side, or an error naming `other_path` when they
/// belong to scenes of different sizes.
fn pair<'a>(
    a: &'a Selection,
    b: &'a Selection,
    other_path: &Path,
) -> Result<impl Iterator<Item = (f32, f32)> + 'a> {
    if a.len() != b.len() {
        return Err(Error::input(
            other_path,
            format!(
                "selection of {} Gaussians, combined with one of {} (both must be of the same \
                 scene)",
                b.len(),
                a.len()
            ),
        ));
    }
    Ok(a.weights.iter().zip(&b.weights).map(|(&x, &y)| (x, y)))
}

/// `max(a, b)` per Gaussian (`b` read from `b_path`, for errors).
pub fn union(a: &Selection, b: &Selection, b_path: &Path) -> Result<Selection> {
    Ok(Selection {
        weights: pair(a, b, b_path)?.map(|(x, y)| x.max(y)).collect(),
    })
}

/// `min(a, b)` per Gaussian (`b` read from `b_path`, for errors).
pub fn intersection(a: &Selection, b: &Selection, b_path: &Path) -> Result<Selection> {
    Ok(Selection {
        weights: pair(a, b, b_path)?.map(|(x, y)| x.min(y)).collect(),
    })
}

/// `1 - a` per Gaussian.
pub fn complement(a: &Selection) -> Selection {
    Selection {
        weights: a.weights.iter().map(|w| 1.0 - w).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_intersection_complement() {
        let p = Path::new("b");
        let a = Selection::new(vec![0.0, 1.0, 0.25, 1.0], p).unwrap();
        let b = Selection::new(vec![1.0, 0.0, 0.5, 1.0], p).unwrap();
        assert_eq!(union(&a, &b, p).unwrap().weights, [1.0, 1.0, 0.5, 1.0]);
        assert_eq!(
            intersection(&a, &b, p).unwrap().weights,
            [0.0, 0.0, 0.25, 1.0]
        );
        assert_eq!(complement(&a).weights, [1.0, 0.0, 0.75, 0.0]);
        let short = Selection::all(3);
        let e = union(&a, &short, Path::new("other/sel"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("other/sel") && e.contains("3"), "{e}");
    }
}

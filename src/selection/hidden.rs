//! Labels for the Gaussians that masked views show only behind other surfaces: each
//! takes the weight of the Gaussians it overlaps, spreading inward from the Gaussians the
//! views do show (a breadth-first form of label propagation on a neighbourhood graph:
//! Zhu and Ghahramani, "Learning from Labeled and Unlabeled Data with Label
//! Propagation", CMU-CALD-02-107, 2002).
//!
//! Two Gaussians overlap when each one's centre lies within [`OVERLAP`] standard
//! deviations of the other (the Mahalanobis distance `|S^-1 R^T (x - p)|` under the
//! other's covariance `R S^2 R^T`). For the flat, surface-aligned Gaussians of a trained
//! scene this links neighbours along a surface and not across a thin gap: the sample's
//! sphere, 0.01 above the ground, is 4 to 6 of its or the ground's normal-direction
//! deviations away from it, and its own neighbours about 1.3 apart.
//!
//! In rounds: every unlabelled Gaussian with a labelled neighbour takes their mean
//! weight (with hard weights, 1 when the mean is above 1/2, else 0), and is labelled from
//! the next round on; the rounds end when none changes. One left unreached (it overlaps
//! nothing labelled, through any chain) keeps weight 0. Neighbour lists are sorted and a
//! round reads only earlier rounds' labels, so the result does not depend on threads.

use crate::Scene;
use rayon::prelude::*;
use std::collections::HashMap;

/// Standard deviations within which two Gaussians overlap (each centre within this
/// Mahalanobis distance of the other).
pub const OVERLAP: f64 = 3.0;

/// What [`fill`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Fill {
    /// Gaussians to label.
    pub hidden: usize,
    /// Of those, labelled through their neighbours (the rest keep weight 0).
    pub reached: usize,
    /// Of those, with a weight above 0.
    pub selected: usize,
}

/// One Gaussian's centre and its whitening map `S^-1 R^T` (rows).
struct Frame {
    p: [f64; 3],
    m: [[f64; 3]; 3],
    /// `OVERLAP` times its largest scale: no overlapping centre lies farther.
    reach: f64,
}

impl Frame {
    fn of(scene: &Scene, i: usize) -> Frame {
        let q = scene.rotations[i].map(f64::from);
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let r = crate::geometry::unit_quat_rows(q[0] / n, q[1] / n, q[2] / n, q[3] / n);
        let s = scene.scale(i).map(f64::from);
        // Row k of S^-1 R^T is column k of R over s_k.
        let m = [0, 1, 2].map(|k| [r[0][k] / s[k], r[1][k] / s[k], r[2][k] / s[k]]);
        Frame {
            p: scene.positions[i].map(f64::from),
            m,
            reach: OVERLAP * s[0].max(s[1]).max(s[2]),
        }
    }

    /// Mahalanobis distance of `x` from this Gaussian.
    fn distance(&self, x: [f64; 3]) -> f64 {
        let d = [x[0] - self.p[0], x[1] - self.p[1], x[2] - self.p[2]];
        self.m
            .iter()
            .map(|r| {
                let v = r[0] * d[0] + r[1] * d[1] + r[2] * d[2];
                v * v
            })
            .sum::<f64>()
            .sqrt()
    }
}

/// Whether Gaussians `a` and `b` overlap (module docs).
fn overlap(a: &Frame, b: &Frame) -> bool {
    let d2: f64 = (0..3).map(|k| (a.p[k] - b.p[k]).powi(2)).sum();
    let r = a.reach.min(b.reach);
    d2 <= r * r && a.distance(b.p) <= OVERLAP && b.distance(a.p) <= OVERLAP
}

/// For each of `hidden`, the Gaussians among `member` it overlaps, sorted (a uniform grid
/// over the members' centres, its cell the median reach of the hidden ones).
fn neighbours(scene: &Scene, member: &[bool], hidden: &[usize]) -> Vec<Vec<u32>> {
    let frames: Vec<Option<Frame>> = (0..scene.len())
        .into_par_iter()
        .map(|i| member[i].then(|| Frame::of(scene, i)))
        .collect();
    let frame = |i: usize| frames[i].as_ref().expect("a member");
    let mut reach: Vec<f64> = hidden.iter().map(|&i| frame(i).reach).collect();
    reach.sort_by(f64::total_cmp);
    let cell = reach[reach.len() / 2].max(1e-12);
    let key = |p: [f64; 3]| p.map(|v| (v / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, f) in frames.iter().enumerate() {
        if let Some(f) = f {
            grid.entry(key(f.p)).or_default().push(i as u32);
        }
    }
    hidden
        .par_iter()
        .map(|&i| {
            let a = frame(i);
            let (lo, hi) = (key(a.p.map(|v| v - a.reach)), key(a.p.map(|v| v + a.reach)));
            let span = |k: usize| (hi[k] - lo[k] + 1).max(1) as u128;
            let mut out = Vec::new();
            let mut visit = |list: &Vec<u32>| {
                out.extend(
                    list.iter()
                        .filter(|&&j| j as usize != i && overlap(a, frame(j as usize))),
                );
            };
            if span(0) * span(1) * span(2) > grid.len() as u128 {
                grid.values().for_each(&mut visit);
            } else {
                for x in lo[0]..=hi[0] {
                    for y in lo[1]..=hi[1] {
                        for z in lo[2]..=hi[2] {
                            if let Some(list) = grid.get(&[x, y, z]) {
                                visit(list);
                            }
                        }
                    }
                }
            }
            out.sort_unstable();
            out
        })
        .collect()
}

/// Label `hidden` (indices into `weights`) from the Gaussians they overlap (module
/// docs). `member[i]` says whether Gaussian `i` takes part: labelled (its weight in
/// `weights`) unless it is one of `hidden`; the others (neither) are not links.
/// `soft` keeps the neighbours' mean instead of rounding it.
pub fn fill(
    scene: &Scene,
    weights: &mut [f32],
    member: &[bool],
    hidden: &[usize],
    soft: bool,
) -> Fill {
    let mut report = Fill {
        hidden: hidden.len(),
        ..Fill::default()
    };
    if hidden.is_empty() {
        return report;
    }
    let mut part = member.to_vec();
    for &i in hidden {
        part[i] = true;
    }
    let nb = neighbours(scene, &part, hidden);
    let mut known = member.to_vec();
    for &i in hidden {
        known[i] = false;
    }
    let mut left: Vec<usize> = (0..hidden.len()).collect();
    loop {
        let next: Vec<(usize, f32)> = left
            .iter()
            .filter_map(|&k| {
                let (sum, n) = nb[k]
                    .iter()
                    .filter(|&&j| known[j as usize])
                    .fold((0.0f64, 0usize), |(s, n), &j| {
                        (s + f64::from(weights[j as usize]), n + 1)
                    });
                let mean = (n > 0).then(|| (sum / n as f64) as f32)?;
                Some((
                    k,
                    if soft {
                        mean
                    } else {
                        f32::from(u8::from(mean > 0.5))
                    },
                ))
            })
            .collect();
        if next.is_empty() {
            break;
        }
        for &(k, w) in &next {
            weights[hidden[k]] = w;
            known[hidden[k]] = true;
            report.reached += 1;
            report.selected += usize::from(w > 0.0);
        }
        left.retain(|&k| !known[hidden[k]]);
    }
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Flat Gaussians (scales 0.01, 0.01, 0.001, axis-aligned) at `points`.
    fn flat(points: &[[f32; 3]]) -> Scene {
        let n = points.len();
        Scene {
            positions: points.to_vec(),
            log_scales: vec![[0.01f32.ln(), 0.01f32.ln(), 0.001f32.ln()]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![2.0; n],
            sh_dc: vec![[0.0; 3]; n],
            sh_rest: Vec::new(),
            sh_degree: 0,
        }
    }

    #[test]
    fn labels_spread_along_a_surface_and_not_across_a_gap() {
        // Plane z = 0: a selected Gaussian at x = 0, then hidden ones every 0.015 along x.
        // Plane z = 0.006 (6 normal deviations above): an unselected one at x = 0 and
        // hidden ones above the first chain. Each chain takes its own label.
        let mut pts: Vec<[f32; 3]> = (0..6).map(|k| [0.015 * k as f32, 0.0, 0.0]).collect();
        pts.extend((0..6).map(|k| [0.015 * k as f32, 0.2, 0.006]));
        pts.extend((0..6).map(|k| [0.015 * k as f32, 0.0, 0.006]));
        let scene = flat(&pts);
        let mut w = vec![0.0f32; scene.len()];
        w[0] = 1.0;
        let member = vec![true; scene.len()];
        // Row 1 (y = 0.2) has no seed at all; row 2 starts from an unselected seed.
        let hidden: Vec<usize> = (1..6).chain(6..12).chain(13..18).collect();
        let report = fill(&scene, &mut w, &member, &hidden, false);
        assert_eq!(&w[..6], &[1.0; 6]);
        assert_eq!(&w[6..], &[0.0; 12]);
        assert_eq!(report.hidden, 16);
        assert_eq!(report.reached, 10, "{report:?}");
        assert_eq!(report.selected, 5);
    }

    #[test]
    fn soft_fill_takes_the_mean_and_hard_fill_rounds_it() {
        // Two seeds (1 and 0.25) overlap the hidden one in the middle.
        let scene = flat(&[[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.01, 0.0, 0.0]]);
        let member = vec![true; 3];
        let mut w = vec![1.0, 0.25, 0.0];
        fill(&scene, &mut w, &member, &[2], true);
        assert_eq!(w[2], 0.625);
        let mut w = vec![1.0, 0.0, 0.0];
        fill(&scene, &mut w, &member, &[2], false);
        assert_eq!(w[2], 0.0, "a tie is not a majority");
        // A non-member neither labels nor links.
        let mut w = vec![1.0, 0.0, 0.0];
        fill(&scene, &mut w, &[true, false, true], &[2], false);
        assert_eq!(w[2], 1.0);
    }

    #[test]
    fn overlap_is_measured_in_each_gaussians_own_deviations() {
        let scene = flat(&[[0.0, 0.0, 0.0], [0.029, 0.0, 0.0], [0.0, 0.0, 0.0029]]);
        let f: Vec<Frame> = (0..3).map(|i| Frame::of(&scene, i)).collect();
        assert!((f[0].distance(f[1].p) - 2.9).abs() < 1e-5);
        assert!((f[0].distance(f[2].p) - 2.9).abs() < 1e-5);
        assert!(overlap(&f[0], &f[1]) && overlap(&f[0], &f[2]));
        // 0.0031 along the normal is 3.1 deviations: apart, though 10x nearer than f[1].
        let g = Frame::of(&flat(&[[0.0, 0.0, 0.0031]]), 0);
        assert!(!overlap(&f[0], &g));
    }
}

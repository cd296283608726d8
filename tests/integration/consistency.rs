//! The consistency measures' excess over the warp's own loss
//! (`fantasystyle::metrics::consistency`): against an independent float64 numpy reference
//! of the warp, its round trip and the RMSE excess, computed here on this machine
//! (`scripts/reference/consistency_ref.py`, written from the definitions), on real
//! rasterizer renders of the sample scene; and what the excess is for, on the analytic
//! textured plane of the evaluate tests: a consistent but sharply textured recolouring
//! raises the pair scores and leaves the excess near zero, a per-view flicker raises both.
//!
//! Tolerances: valid pixel counts equal (the masks decide on f64 depths in both); RMSE
//! and excess 1e-5 (Rust samples the f32 images in f64 and sums in f64; numpy in f64).

use crate::evaluate::{cameras, ready, restyle, write_views};
use crate::harness::{self, repo_root};
use fantasystyle::artifacts::read_view_set;
use fantasystyle::imageio::Image;
use fantasystyle::metrics::consistency::{self, PairScore};
use fantasystyle::metrics::nets::{LpipsModel, LpipsNet};
use fantasystyle::metrics::views::ViewSet;
use fantasystyle::models::models_dir;

fn lpips() -> LpipsModel {
    LpipsModel::load(&models_dir().unwrap(), LpipsNet::Alex, 2).unwrap()
}

/// Views of `src`'s cameras and depth whose odd views are recoloured (a seam every other
/// view).
fn flickered(src: &ViewSet, dir: &std::path::Path) -> ViewSet {
    let rgb: Vec<f32> = src
        .images
        .iter()
        .enumerate()
        .flat_map(|(v, img)| {
            let img = if v % 2 == 1 {
                Image::from_fn(img.width, img.height, |x, y| {
                    let p = img.px(x, y);
                    [0.9 * p[1], 0.2 + 0.7 * p[0], p[2]]
                })
            } else {
                img.clone()
            };
            img.data
        })
        .collect();
    let cams = std::fs::read(src.dir.join("cameras.json")).unwrap();
    let shape = [src.n, src.height, src.width];
    harness::write_views(dir, shape, &rgb, &src.depth, &src.alpha, &cams);
    read_view_set(dir).unwrap()
}

#[test]
fn pair_round_trip_and_excess_match_an_independent_numpy_reference() {
    let Some(py) = harness::python() else { return };
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let rendered = d.path().join("rendered");
    harness::render_sample(&rendered, 8, 96);
    let src = read_view_set(&rendered).unwrap();
    let styl = flickered(&src, &d.path().join("flickered"));
    let mut lp = lpips();
    let out = d.path().join("ref.json");
    let mut excesses = 0;
    for offset in [1, 2] {
        let pairs = consistency::pairs(src.n, offset);
        let (got, _) = consistency::score_pairs(&mut lp, &src, &styl.images, &pairs).unwrap();
        let st = std::process::Command::new(&py)
            .arg(repo_root().join("scripts/reference/consistency_ref.py"))
            .args([&rendered, &d.path().join("flickered")])
            .args(["--offset", &offset.to_string(), "--out"])
            .arg(&out)
            .status()
            .unwrap();
        assert!(st.success(), "consistency_ref.py --offset {offset} failed");
        let want: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        let want = want["pairs"].as_array().unwrap();
        assert_eq!(want.len(), got.len());
        for (g, w) in got.iter().zip(want) {
            let valid = (g.valid_fraction * (src.width * src.height) as f64).round() as u64;
            eprintln!(
                "pair ({}, {}): {valid} valid, rmse {:?} excess {:?}; numpy {w}",
                g.i, g.j, g.rmse, g.excess_rmse
            );
            assert_eq!(valid, w["pair_valid"].as_u64().unwrap());
            let same = |a: Option<f64>, b: &serde_json::Value| match (a, b.as_f64()) {
                (Some(a), Some(b)) => (a - b).abs() < 1e-5,
                (None, None) => true,
                _ => false,
            };
            assert!(same(g.rmse, &w["rmse"]), "pair ({}, {}) rmse", g.i, g.j);
            assert!(
                same(g.excess_rmse, &w["excess_rmse"]),
                "pair ({}, {}) excess",
                g.i,
                g.j
            );
            assert_eq!(g.excess_lpips.is_some(), g.excess_rmse.is_some());
            excesses += usize::from(g.excess_rmse.is_some());
        }
    }
    assert!(excesses >= 6, "only {excesses} pairs had an excess");
}

/// Means of the pair RMSE / LPIPS and of their excesses.
fn means(v: &[PairScore]) -> [f64; 4] {
    let m = |f: fn(&PairScore) -> Option<f64>| consistency::mean_of(v.iter().map(f)).unwrap();
    [
        m(|p| p.rmse),
        m(|p| p.lpips),
        m(|p| p.excess_rmse),
        m(|p| p.excess_lpips),
    ]
}

#[test]
fn the_excess_reads_seams_not_texture() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let cams = cameras(6);
    let views = |name: &str, f: &dyn Fn(usize, [f32; 3]) -> [f32; 3]| {
        let dir = d.path().join(name);
        read_view_set(&write_views(&dir, &cams, &|v, i| {
            Image::from_fn(i.width, i.height, |x, y| f(v, i.px(x, y)))
        }))
        .unwrap()
    };
    // Consistent: a smooth remap, and fine stripes along the texture's iso-lines (every
    // view sees the same stripes on the plane; the warp's resampling blurs them).
    let smooth = views("smooth", &|_, p| restyle(p));
    let stripes = views("stripes", &|_, p| {
        let s = |c: f32| 0.5 + 0.4 * (std::f32::consts::TAU * 6.0 * c).sin();
        [s(p[0]), s(p[1]), s(0.5 * (p[0] + p[2]))]
    });
    // A seam: every other view's colours moved.
    let flicker = views("flicker", &|v, p| {
        let q = restyle(p);
        if v % 2 == 1 { [q[1], q[2], q[0]] } else { q }
    });
    let mut lp = lpips();
    let pairs = consistency::pairs(cams.len(), 1);
    let mut score = |s: &ViewSet| {
        let (scores, _) = consistency::score_pairs(&mut lp, &smooth, &s.images, &pairs).unwrap();
        means(&scores)
    };
    let [sm, st, fl] = [&smooth, &stripes, &flicker].map(&mut score);
    eprintln!(
        "rmse, lpips, excess rmse, excess lpips: smooth {sm:?} stripes {st:?} flicker {fl:?}"
    );
    // Texture raises the pair scores of a consistent set many times ...
    assert!(st[0] > 10.0 * sm[0] && st[1] > 10.0 * sm[1]);
    // ... and its excess stays a tenth of a seam's, which raises both. (The round trip
    // resamples twice: on these stripes its LPIPS is above the pair's, the excess negative.)
    for k in [2, 3] {
        assert!(fl[k] > 10.0 * st[k].abs().max(sm[k].abs()), "excess {k}");
        assert!(
            fl[k] > 0.5 * fl[k - 2],
            "a seam's excess is most of its pair score"
        );
    }
}

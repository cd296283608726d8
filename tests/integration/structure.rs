//! Structure kept (`fantasystyle::metrics::structure`, issue 47) against an independent
//! float64 numpy reference computed here, on this machine
//! (`scripts/reference/structure_ref.py`, written from the definition), on renders of
//! the sample scene and perturbed copies of them: unchanged, blurred, a colour change,
//! noise, inverted, a blurred colour change with noise.
//!
//! Tolerance 1e-4 per view (both compute in f64 from the same f32 rgb; measured
//! differences are about 1e-15).

use crate::harness::{self, repo_root};
use fantasystyle::artifacts::read_view_set;
use fantasystyle::imageio::Image;
use fantasystyle::metrics::structure;
use fantasystyle::metrics::views::ViewSet;
use std::path::Path;

/// The perturbations, one per view.
const PERTURBATIONS: [&str; 6] = [
    "unchanged",
    "blur sigma 2",
    "colour change",
    "noise 0.05",
    "inverted",
    "colour, blur, noise",
];

fn perturb(k: usize, img: &Image, seed: u64) -> Image {
    let map = |img: &Image, f: &dyn Fn([f32; 3]) -> [f32; 3]| {
        Image::from_fn(img.width, img.height, |x, y| f(img.px(x, y)))
    };
    let colour = |p: [f32; 3]| [0.2 + 0.7 * p[2], 0.9 * p[0], 0.1 + 0.5 * p[1]];
    match k {
        0 => img.clone(),
        1 => img.blurred(2.0),
        2 => map(img, &colour),
        3 => img.noisy(0.05, seed),
        4 => map(img, &|p| p.map(|v| 1.0 - v)),
        _ => map(img, &colour).blurred(1.0).noisy(0.03, seed),
    }
}

/// The views `src` with view `i` perturbed by perturbation `i`, written as a views
/// artifact at `dir` (the source's depth, alpha and cameras).
fn write_perturbed(src: &ViewSet, dir: &Path) -> ViewSet {
    let rgb: Vec<f32> = (0..src.n)
        .flat_map(|i| perturb(i % PERTURBATIONS.len(), &src.images[i], i as u64).data)
        .collect();
    let cams = std::fs::read(src.dir.join("cameras.json")).unwrap();
    let (n, h, w) = (src.n, src.height, src.width);
    harness::write_views(dir, [n, h, w], &rgb, &src.depth, &src.alpha, &cams);
    read_view_set(dir).unwrap()
}

#[test]
fn structure_kept_matches_an_independent_numpy_reference() {
    let Some(py) = harness::python() else { return };
    let d = tempfile::tempdir().unwrap();
    let views = d.path().join("source");
    harness::render_sample(&views, 6, 96);
    let src = read_view_set(&views).unwrap();
    let styl = write_perturbed(&src, &d.path().join("stylized"));
    let (mean, per_view) = structure::structure_kept(&src, &styl);

    let out = d.path().join("ref.json");
    let st = std::process::Command::new(&py)
        .arg(repo_root().join("scripts/reference/structure_ref.py"))
        .arg(&views)
        .arg(d.path().join("stylized"))
        .arg("--out")
        .arg(&out)
        .status()
        .unwrap();
    assert!(st.success(), "structure_ref.py failed");
    let want: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let want_views = want["per_view"].as_array().unwrap();
    assert_eq!(want_views.len(), per_view.len());
    let mut worst = 0.0f64;
    for (i, (got, want)) in per_view.iter().zip(want_views).enumerate() {
        let objects = src.geometry(i).1.iter().filter(|a| **a > 0.5).count();
        eprintln!(
            "view {i} ({}; {objects} object pixels): rust {got:?} numpy {want}",
            PERTURBATIONS[i]
        );
        let (g, w) = (got.expect("a value"), want.as_f64().expect("a value"));
        worst = worst.max((g - w).abs());
        assert!((g - w).abs() < 1e-4, "view {i}: {g} vs {w}");
    }
    eprintln!("largest difference {worst:.2e}");
    let (m, wm) = (mean.unwrap(), want["mean"].as_f64().unwrap());
    assert!((m - wm).abs() < 1e-4, "mean {m} vs {wm}");
    // What each perturbation keeps, as the definition says: all of it unchanged, minus
    // all of it inverted, most of it under noise, less under a blur.
    let v: Vec<f64> = per_view.iter().map(|r| r.unwrap()).collect();
    assert!(
        (v[0] - 1.0).abs() < 1e-12 && (v[4] + 1.0).abs() < 1e-9,
        "{v:?}"
    );
    assert!(v[1] < v[3] && v[3] < 1.0 && v[2] < 1.0, "{v:?}");
}

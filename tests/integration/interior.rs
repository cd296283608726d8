//! Interior structure, edge recall, motif contrast and style texture
//! (`fantasystyle::metrics::interior`, issue 53) against an independent float64 numpy reference computed here, on this
//! machine (`scripts/reference/interior_ref.py`, written from the definitions: its own
//! erosion, band pass, percentiles and style resize), on renders of the sample scene
//! perturbed one way per view, with a style image that needs resizing (600 x 840 -> 256 x
//! 358: one box halving, then bilinear) and one view whose interior is too small.
//!
//! Tolerances: the interior pixel counts equal; interior structure 1e-9 (both in f64 from
//! the same f32 rgb); edge recall within one strong pixel (a pixel exactly at a
//! percentile could fall either way by a rounding difference); motif contrast, style
//! texture and the style's spread 1e-5 relative (the Rust resize interpolates in f32),
//! style texture with an absolute floor of 1e-9 (the unchanged view's is 0 up to rounding:
//! numpy fits beta by least squares, Rust by the ratio of sums).

use crate::harness::{self, repo_root};
use fantasystyle::artifacts::read_view_set;
use fantasystyle::imageio::Image;
use fantasystyle::metrics::interior::{self, CHANCE_RECALL};
use fantasystyle::metrics::views::ViewSet;
use std::path::Path;

/// The perturbations, one per view; the last view's source alpha is cut to a 20 px
/// square (an interior of 4 x 4 pixels: no value).
const PERTURBATIONS: [&str; 7] = [
    "unchanged",
    "blur sigma 2",
    "colour change",
    "noise 0.05",
    "the style pasted over the object",
    "a flat wash over the object",
    "unchanged, interior too small",
];

fn perturb(k: usize, img: &Image, alpha: &[f32], style: &Image, seed: u64) -> Image {
    let map = |f: &dyn Fn(usize, usize, [f32; 3]) -> [f32; 3]| {
        Image::from_fn(img.width, img.height, |x, y| f(x, y, img.px(x, y)))
    };
    let w = img.width;
    let on_object = |x: usize, y: usize, p: [f32; 3], q: [f32; 3]| {
        if alpha[y * w + x] > 0.5 { q } else { p }
    };
    match k {
        1 => img.blurred(2.0),
        2 => map(&|_, _, p| [0.2 + 0.7 * p[2], 0.9 * p[0], 0.1 + 0.5 * p[1]]),
        3 => img.noisy(0.05, seed),
        4 => map(&|x, y, p| on_object(x, y, p, style.px(x + 40, y + 40))),
        5 => map(&|x, y, p| on_object(x, y, p, [0.6, 0.4, 0.3])),
        _ => img.clone(),
    }
}

/// A views artifact at `dir` of `src`'s cameras and depth with `rgb` and `alpha`.
fn write(src: &ViewSet, dir: &Path, rgb: &[f32], alpha: &[f32]) -> ViewSet {
    let cams = std::fs::read(src.dir.join("cameras.json")).unwrap();
    let (n, h, w) = (src.n, src.height, src.width);
    harness::write_views(dir, [n, h, w], rgb, &src.depth, alpha, &cams);
    read_view_set(dir).unwrap()
}

/// A 600 x 840 style from the sample's (256 x 256, mirrored tiles).
fn style() -> Image {
    let s = Image::load(&repo_root().join("data-sample/style.png")).unwrap();
    let fold = |i: usize| {
        let j = i % 512;
        if j < 256 { j } else { 511 - j }
    };
    Image::from_fn(600, 840, |x, y| s.px(fold(x), fold(y)))
}

#[test]
fn interior_measures_match_an_independent_numpy_reference() {
    let Some(py) = harness::python() else { return };
    let d = tempfile::tempdir().unwrap();
    let rendered = d.path().join("rendered");
    harness::render_sample(&rendered, 7, 128);
    let r = read_view_set(&rendered).unwrap();
    let (w, h) = (r.width, r.height);
    // The source: the last view's alpha cut to a 20 px square at the object's centre row.
    let mut alpha = r.alpha.clone();
    let last = &mut alpha[6 * w * h..];
    for (p, a) in last.iter_mut().enumerate() {
        let (x, y) = (p % w, p / w);
        if !((54..74).contains(&x) && (54..74).contains(&y)) {
            *a = 0.0;
        }
    }
    let rgb: Vec<f32> = r.images.iter().flat_map(|i| i.data.clone()).collect();
    let src = write(&r, &d.path().join("source"), &rgb, &alpha);
    let style = style();
    let styl_rgb: Vec<f32> = (0..src.n)
        .flat_map(|i| perturb(i, &src.images[i], src.geometry(i).1, &style, i as u64).data)
        .collect();
    let styl = write(&r, &d.path().join("stylized"), &styl_rgb, &alpha);
    let got = interior::interior(&src, &styl, &style, interior::STYLE_SHORTER_SIDE);

    let style_npy = d.path().join("style.npy");
    fantasystyle_schemas::npy::write_npy(&style_npy, &[840, 600, 3], &style.data).unwrap();
    let out = d.path().join("ref.json");
    // The numpy reference's JSON, the style taken at shorter side `side` px.
    let reference = |side: usize| -> serde_json::Value {
        let st = std::process::Command::new(&py)
            .arg(repo_root().join("scripts/reference/interior_ref.py"))
            .arg(d.path().join("source"))
            .arg(d.path().join("stylized"))
            .arg(&style_npy)
            .args(["--style-side", &side.to_string(), "--out"])
            .arg(&out)
            .status()
            .unwrap();
        assert!(st.success(), "interior_ref.py --style-side {side} failed");
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap()
    };
    let want = reference(interior::STYLE_SHORTER_SIDE);

    let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1e-12);
    let spread = want["style_spread"].as_f64().unwrap();
    assert!(rel(got.style_band_spread.unwrap(), spread) < 1e-5);
    let wv = want["per_view"].as_array().unwrap();
    assert_eq!(wv.len(), got.interior_per_view.len());
    for (i, (g, w)) in got.interior_per_view.iter().zip(wv).enumerate() {
        eprintln!(
            "view {i} ({}): {} interior px; rust IS {:?} ER {:?} MC {:?} ST {:?}; numpy {w}",
            PERTURBATIONS[i],
            g.pixels,
            g.interior_structure,
            g.edge_recall,
            g.motif_contrast,
            g.style_texture
        );
        assert_eq!(g.pixels as u64, w["pixels"].as_u64().unwrap(), "view {i}");
        let same = |name: &str, got: Option<f64>, tol: &dyn Fn(f64, f64) -> bool| match (
            got,
            w[name].as_f64(),
        ) {
            (Some(a), Some(b)) => assert!(tol(a, b), "view {i} {name}: {a} vs {b}"),
            (None, None) => {}
            (a, _) => panic!("view {i} {name}: {a:?} vs {}", w[name]),
        };
        let strong = w["strong"].as_u64().unwrap().max(1) as f64;
        same("interior_structure", g.interior_structure, &|a, b| {
            (a - b).abs() < 1e-9
        });
        same("edge_recall", g.edge_recall, &|a, b| {
            (a - b).abs() <= 1.0 / strong + 1e-12
        });
        same("motif_contrast", g.motif_contrast, &|a, b| rel(a, b) < 1e-5);
        same("style_texture", g.style_texture, &|a, b| {
            (a - b).abs() <= 1e-5 * b.abs() + 1e-9
        });
    }
    let wm = &want["mean"];
    assert!(
        (got.interior_structure.unwrap() - wm["interior_structure"].as_f64().unwrap()).abs() < 1e-9
    );
    assert!((got.edge_recall.unwrap() - wm["edge_recall"].as_f64().unwrap()).abs() < 0.01);
    assert!(
        rel(
            got.motif_contrast.unwrap(),
            wm["motif_contrast"].as_f64().unwrap()
        ) < 1e-5
    );
    assert!(
        rel(
            got.style_texture.unwrap(),
            wm["style_texture"].as_f64().unwrap()
        ) < 1e-5
    );

    // What the definitions say of each perturbation: all of it unchanged; the pasted
    // style near chance and with the style's contrast, the flat wash with less; style
    // texture 0 on the unchanged view (the source's own detail is no style texture) and
    // most of the pasted style's motif contrast; the small interior has no value and
    // says why.
    let v = &got.interior_per_view;
    assert!((v[0].interior_structure.unwrap() - 1.0).abs() < 1e-12);
    assert_eq!(v[0].edge_recall, Some(1.0));
    assert!(
        v[4].edge_recall.unwrap() < 2.0 * CHANCE_RECALL,
        "{:?}",
        v[4]
    );
    assert!(v[4].motif_contrast.unwrap() > v[5].motif_contrast.unwrap());
    assert!(v[0].motif_contrast.unwrap() > 0.1, "{:?}", v[0]);
    assert!(v[0].style_texture.unwrap() < 1e-9, "{:?}", v[0]);
    assert!(
        v[4].style_texture.unwrap() > 0.5 * v[4].motif_contrast.unwrap(),
        "{:?}",
        v[4]
    );
    assert!(v[4].style_texture.unwrap() > v[5].style_texture.unwrap());
    assert!(v[1].edge_recall.unwrap() < v[3].edge_recall.unwrap());
    assert!(
        v[6].pixels < interior::MIN_INTERIOR_PIXELS && v[6].reasons[0].contains("fewer than 64")
    );
    assert_eq!((v[6].motif_contrast, v[6].style_texture), (None, None));

    // The style taken at the scale an end laid it at (`evaluate --style-size`): 96 px.
    let at96 = interior::interior(&src, &styl, &style, 96);
    let want = reference(96);
    let spread96 = want["style_spread"].as_f64().unwrap();
    assert!(rel(at96.style_band_spread.unwrap(), spread96) < 1e-5);
    assert!(rel(spread96, spread) > 0.01, "{spread96} vs {spread}");
    assert_eq!(at96.style_size, 96);
    for (g, w) in at96
        .interior_per_view
        .iter()
        .zip(want["per_view"].as_array().unwrap())
    {
        if let (Some(a), Some(b)) = (g.motif_contrast, w["motif_contrast"].as_f64()) {
            assert!(rel(a, b) < 1e-5, "motif contrast at 96 px: {a} vs {b}");
        }
    }
}

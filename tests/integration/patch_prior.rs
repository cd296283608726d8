//! The weight-free patch prior (`fantasystyle::prior::patch`): its exact denoiser against
//! an independent float64 numpy brute force computed here, on this machine
//! (`scripts/reference/patch_ref.py`), with and without the structure guide.
//!
//! Tolerance 1e-5 absolute on clean estimates in [-1, 1] for the exact denoiser: it
//! accumulates in f64 and rounds once to f32 (error ~6e-8). The fast path (the search
//! with the whole bank as its shortlist) computes its logits in f32: 1e-4 (why, beside
//! the assertion).

use crate::harness::{self, repo_root};
use fantasystyle::prior::patch::bank::{Bank, patches, patches_at};
use fantasystyle::prior::patch::denoise::{self, Guide, Level, Search};
use fantasystyle::rng::Rng;
use fantasystyle_schemas::{read_npy_f32, write_npy};
use ndarray::{Array2, Array4};
use std::path::{Path, PathBuf};

fn random(seed: u64, shape: (usize, usize, usize, usize), scale: f32) -> Array4<f32> {
    let mut r = Rng::new(seed);
    let n = shape.0 * shape.1 * shape.2 * shape.3;
    Array4::from_shape_vec(shape, r.normals_f32(n)).unwrap() * scale
}

/// Every pixel (b, y, x) of a batch, in order.
fn all_pixels(b: usize, h: usize, w: usize) -> Vec<[usize; 3]> {
    (0..b * h * w)
        .map(|i| [i / (h * w), (i / w) % h, i % w])
        .collect()
}

fn max_abs(a: &Array2<f32>, b: &Array2<f32>) -> f32 {
    (a - b).iter().fold(0.0f32, |m, v| m.max(v.abs()))
}

#[test]
fn patch_denoiser_matches_an_independent_numpy_brute_force() {
    let Some(py) = harness::python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let style = random(1, (1, 3, 10, 9), 0.6).mapv(f32::tanh);
    let style = style.index_axis(ndarray::Axis(0), 0).to_owned();
    let z = random(2, (2, 3, 6, 7), 1.0);
    let (gs, gz) = (random(3, (1, 1, 10, 9), 1.0), random(4, (2, 1, 6, 7), 1.0));
    write_npy(&d.join("style.npy"), &[3, 10, 9], style.as_slice().unwrap()).unwrap();
    write_npy(&d.join("z.npy"), &[2, 3, 6, 7], z.as_slice().unwrap()).unwrap();
    write_npy(&d.join("guide_style.npy"), &[10, 9], gs.as_slice().unwrap()).unwrap();
    write_npy(&d.join("guide_z.npy"), &[2, 6, 7], gz.as_slice().unwrap()).unwrap();
    let pixels = all_pixels(2, 6, 7);
    for (k, sa, sb, g) in [
        (3, 0.98, 0.2, 0.0),
        (5, 0.7, 0.71, 0.0),
        (3, 0.3, 0.95, 0.0),
        (3, 0.9, 0.44, 0.3),
    ] {
        let params = serde_json::json!({"k": k, "sa": sa, "sb": sb, "guide_weight": g});
        std::fs::write(d.join("params.json"), params.to_string()).unwrap();
        let st = std::process::Command::new(&py)
            .arg(repo_root().join("scripts/reference/patch_ref.py"))
            .arg(d)
            .status()
            .unwrap();
        assert!(st.success(), "patch_ref.py failed");
        let want = read_npy_f32(&d.join("x0.npy")).unwrap();
        let want = Array2::from_shape_fn((pixels.len(), 3), |(i, c)| {
            let [b, y, x] = pixels[i];
            want.data[((b * 3 + c) * 6 + y) * 7 + x]
        });
        let bank = Bank::new(patches(style.view(), k, 1), k, 3, None, 0).unwrap();
        let q = patches_at(z.view(), k, &pixels);
        let (gq, gb) = (
            patches_at(gz.view(), k, &pixels),
            patches(gs.index_axis(ndarray::Axis(0), 0), k, 1),
        );
        let guide = (g > 0.0).then(|| Guide {
            query: gq.view(),
            bank: gb.view(),
            weight: g,
        });
        let level = Level { sa, sb };
        let exact = denoise::denoise_exact(&bank, q.view(), level, guide);
        let search = Search {
            shortlist: 0,
            probe: 0,
            balance: 0,
        };
        let fast = denoise::denoise(&bank, q.view(), level, search, guide);
        let (e1, e2) = (max_abs(&exact, &want), max_abs(&fast, &want));
        assert!(e1 < 1e-5, "k {k} sa {sa} guide {g}: exact {e1:e}");
        // The fast path computes its logits in f32: a logit of size |d| / (2 sb^2) (~500 at
        // sb = 0.2 over 27-75 terms) carries ~6e-8 x 500 = 3e-5 of rounding, which moves
        // the softmax weights, and the estimate, by about as much.
        assert!(e2 < 1e-4, "k {k} sa {sa} guide {g}: fast {e2:e}");
    }
}

/// The committed default prior, `priors/patch`.
pub(crate) fn patch_dir() -> PathBuf {
    repo_root().join("priors/patch")
}

/// A copy of `priors/patch` in `dir` with keys of its `patch` section replaced.
pub(crate) fn patch_model(dir: &Path, keys: &[(&str, serde_json::Value)]) -> PathBuf {
    let text = std::fs::read_to_string(patch_dir().join("model.json")).unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    for (k, v) in keys {
        m["patch"][*k] = v.clone();
    }
    let out = dir.join("patch-model");
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("model.json"), m.to_string()).unwrap();
    out
}

/// Chunks, resume and a killed chunk give the same bytes with the patch prior (its banks
/// are rebuilt from the style and the source views in each process).
#[test]
fn chunks_resume_and_kill_give_the_same_bytes_with_the_patch_prior() {
    crate::distill::resume_case(&patch_dir());
}

/// The sample DAG as it ships (the default), at a small size: its stylized splat has
/// exactly the input's Gaussians, with bit-identical positions, scales, rotations and
/// opacities; only colours changed (issues 38 and 40).
#[test]
fn the_default_dag_keeps_the_geometry_bit_for_bit() {
    let t = tempfile::tempdir().unwrap();
    let dag = repo_root().join("data-sample/stylize.toml");
    let o = std::process::Command::new(harness::pipeline_bin())
        .arg("run")
        .arg("--dag")
        .arg(&dag)
        .args(["--workdir", "run"])
        .args(["--set", "render.width=48", "--set", "render.height=48"])
        .args(["--set", "distill.chunks=1", "--set", "distill.chunk=3"])
        .current_dir(t.path())
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let load = |p: &Path| fantasystyle::artifacts::load_scene(p).unwrap();
    let input = load(&repo_root().join("data-sample/scene.ply"));
    let out = load(&t.path().join("run/runs/final/scene.ply"));
    assert_eq!(out.len(), input.len(), "Gaussians added or removed");
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(&out.positions) == bits(&input.positions),
        "positions changed"
    );
    assert!(
        bits(&out.log_scales) == bits(&input.log_scales),
        "scales changed"
    );
    let rot = |s: &fantasystyle::Scene| {
        s.rotations
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert!(rot(&out) == rot(&input), "rotations changed");
    let op = |s: &fantasystyle::Scene| {
        s.opacity_logits
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert!(op(&out) == op(&input), "opacities changed");
    let dc = |s: &fantasystyle::Scene| {
        s.sh_dc
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert!(dc(&out) != dc(&input), "the colours did not change");
}

/// `preview`: the prior's 2D stylization of chosen views is a views artifact of those
/// views (their cameras, depth and alpha as the source's), changed on the object only,
/// the same bytes on a second run; a view index past the artifact is refused naming it.
#[test]
fn preview_is_a_views_artifact_and_deterministic() {
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_preview"))
            .args(args)
            .output()
            .unwrap()
    };
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_render-views"))
        .arg("--scene")
        .arg(repo_root().join("data-sample/scene.ply"))
        .args([
            "--cameras",
            "orbit:4",
            "--width",
            "64",
            "--height",
            "64",
            "--out",
        ])
        .arg(d.join("views"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let style = repo_root().join("data-sample/style.png");
    let (views, style) = (d.join("views"), style.to_str().unwrap().to_string());
    let args = |out: &str| {
        let v = views.to_str().unwrap().to_string();
        let o = d.join(out).to_str().unwrap().to_string();
        vec![
            "--source-views".to_string(),
            v,
            "--style".into(),
            style.clone(),
        ]
        .into_iter()
        .chain(["--preset", "default", "--views", "1,3", "--set"].map(String::from))
        .chain(["synthesis.levels=2,1".into(), "--out".into(), o])
        .collect::<Vec<String>>()
    };
    for out in ["p1", "p2"] {
        let a = args(out);
        let o = run(&a.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let src = fantasystyle::artifacts::read_views(&views).unwrap();
    let p = fantasystyle::artifacts::read_views(&d.join("p1")).unwrap();
    assert_eq!(p.dim(), (2, 64, 64));
    let again = std::fs::read(d.join("p2/rgb.npy")).unwrap();
    assert_eq!(std::fs::read(d.join("p1/rgb.npy")).unwrap(), again);
    for (i, v) in [1usize, 3].into_iter().enumerate() {
        assert_eq!(
            p.alpha.index_axis(ndarray::Axis(0), i),
            src.alpha.index_axis(ndarray::Axis(0), v)
        );
        let (mut on, mut off) = (0.0f64, 0.0f64);
        for y in 0..64 {
            for x in 0..64 {
                let a = src.alpha[[v, y, x]];
                let diff: f64 = (0..3)
                    .map(|c| (p.rgb[[i, y, x, c]] - src.rgb[[v, y, x, c]]).abs() as f64)
                    .sum();
                if a > 0.5 {
                    on += diff;
                } else if a < 1e-4 {
                    off += diff;
                }
            }
        }
        assert!(
            on > 1.0 && off == 0.0,
            "view {v}: change {on} on the object, {off} off it"
        );
    }
    let mut bad = args("p3");
    let i = bad.iter().position(|s| s == "1,3").unwrap();
    bad[i] = "9".into();
    let o = run(&bad.iter().map(String::as_str).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--views 9") && err.contains("views"),
        "{err}"
    );
    assert!(!d.join("p3").exists());
}

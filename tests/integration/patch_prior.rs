//! The weight-free patch prior (`fantasystyle::prior::patch`): its exact denoiser against
//! an independent float64 numpy brute force computed here, on this machine
//! (`scripts/reference/patch_ref.py`), with and without the structure guide.
//!
//! Tolerance 1e-5 absolute on clean estimates in [-1, 1]: the Rust brute force
//! accumulates in f64 and rounds once to f32 (error ~6e-8); the fast path with the whole
//! bank as its shortlist sums f32 distances of at most 75 terms and a softmax over at
//! most 100 patches, each term's relative error ~1e-7, so its logits are off by
//! ~1e-5 x |logit| at the extremes and its weights by less (the softmax is
//! shift-invariant and the far patches carry ~0 weight).

use crate::harness::{self, repo_root};
use fantasystyle::prior::patch::bank::{Bank, patches, patches_at};
use fantasystyle::prior::patch::denoise::{self, Guide, Level, Search};
use fantasystyle::rng::Rng;
use fantasystyle_schemas::{read_npy_f32, write_npy};
use ndarray::{Array2, Array3, Array4};

fn random(seed: u64, shape: (usize, usize, usize, usize), scale: f32) -> Array4<f32> {
    let mut r = Rng::new(seed);
    let n = shape.0 * shape.1 * shape.2 * shape.3;
    Array4::from_shape_vec(shape, r.normals_f32(n)).unwrap() * scale
}

/// Every pixel (b, y, x) of a batch, in order.
fn all_pixels(b: usize, h: usize, w: usize) -> Vec<[usize; 3]> {
    (0..b * h * w).map(|i| [i / (h * w), (i / w) % h, i % w]).collect()
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
    for (k, sa, sb, g) in [(3, 0.98, 0.2, 0.0), (5, 0.7, 0.71, 0.0), (3, 0.3, 0.95, 0.0), (3, 0.9, 0.44, 0.3)] {
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
        let (gq, gb) = (patches_at(gz.view(), k, &pixels), patches(gs.index_axis(ndarray::Axis(0), 0), k, 1));
        let guide = (g > 0.0).then(|| Guide { query: gq.view(), bank: gb.view(), weight: g });
        let level = Level { sa, sb };
        let exact = denoise::denoise_exact(&bank, q.view(), level, guide);
        let search = Search { shortlist: 0, probe: 0, balance: 0 };
        let fast = denoise::denoise(&bank, q.view(), level, search, guide);
        let (e1, e2) = (max_abs(&exact, &want), max_abs(&fast, &want));
        assert!(e1 < 1e-5 && e2 < 1e-5, "k {k} sa {sa} guide {g}: exact {e1:e}, fast {e2:e}");
    }
    let _ = Array3::<f32>::zeros((1, 1, 1));
}

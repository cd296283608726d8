//! Baselines: VGG16 against the numpy reference, and the baseline stage end to end.

use crate::harness::repo_root;
use fantasystyle::vgg::{Layer, Vgg16};
use std::path::Path;

/// Compare our VGG16 forward with `scripts/reference/vgg_ref.py`'s output in `golden`
/// (float64 direct convolution). Tolerance: max |ours - ref| <= 1e-4 * max |ref| per tap.
fn check_golden(weights: &Path, golden: &Path) {
    let vgg = Vgg16::load(weights).unwrap();
    let input = fantasystyle_schemas::read_npy_f32(&golden.join("input.npy")).unwrap();
    let (h, w) = (input.shape[0], input.shape[1]);
    let f = vgg.forward(&input.data, h, w, Layer::Relu4_3).unwrap();
    for l in [
        Layer::Relu1_2,
        Layer::Relu2_2,
        Layer::Relu3_3,
        Layer::Relu4_3,
    ] {
        let r =
            fantasystyle_schemas::read_npy_f32(&golden.join(format!("{}.npy", l.name()))).unwrap();
        let a = f.get(l);
        assert_eq!(r.shape, vec![a.c, a.h, a.w], "{}", l.name());
        let scale = r.data.iter().fold(0f32, |m, v| m.max(v.abs()));
        let err = a
            .data
            .iter()
            .zip(&r.data)
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            err <= 1e-4 * scale,
            "{}: max err {err}, scale {scale}",
            l.name()
        );
    }
}

#[test]
fn vgg_forward_matches_numpy_golden() {
    let g = repo_root().join("tests/golden/vgg");
    check_golden(&g, &g);
}

#[test]
fn vgg_real_weights_match_numpy_if_present() {
    let w = repo_root().join("vendor/models/lpips/vgg16");
    let g = repo_root().join("vendor/models/lpips/vgg16-golden");
    if !g.join("relu4_3.npy").is_file() {
        eprintln!("SKIPPED: {} is absent (run scripts/setup.sh)", g.display());
        return;
    }
    check_golden(&w, &g);
}

#[test]
fn vgg_missing_or_malformed_weights_are_clear_errors() {
    let d = tempfile::tempdir().unwrap();
    let e = Vgg16::load(&d.path().join("nope")).unwrap_err();
    assert_eq!(e.exit_code(), 3, "{e}");
    // conv0 with the wrong input channels.
    let g = repo_root().join("tests/golden/vgg");
    for i in 0..10 {
        for k in ["weight", "bias"] {
            let n = format!("conv{i}_{k}.npy");
            std::fs::copy(g.join(&n), d.path().join(&n)).unwrap();
        }
    }
    fantasystyle_schemas::write_npy::<f32>(
        &d.path().join("conv0_weight.npy"),
        &[4, 2, 3, 3],
        &[0.0; 72],
    )
    .unwrap();
    let e = Vgg16::load(d.path()).unwrap_err().to_string();
    assert!(
        e.contains("conv0_weight.npy") && e.contains("[O, 3, 3, 3]"),
        "{e}"
    );
}

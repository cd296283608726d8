//! MVFC and CSD stages (issue 5): agreement with the numpy reference, the stages'
//! artifacts and their bad-input errors.

use crate::harness::repo_root;
use fantasystyle::mvfc::{MvfcParams, mvfc};
use fantasystyle_schemas::read_npy_f32;
use ndarray::{Array3, Array4};

fn golden(name: &str) -> (Array4<f32>, Array3<f32>, Array4<f32>) {
    let dir = repo_root().join("tests/golden/mvfc");
    let z = read_npy_f32(&dir.join(format!("{name}_z.npy"))).unwrap();
    let e = read_npy_f32(&dir.join(format!("{name}_eps.npy"))).unwrap();
    let o = read_npy_f32(&dir.join(format!("{name}_out.npy"))).unwrap();
    let s4 = |s: &[usize]| [s[0], s[1], s[2], s[3]];
    (
        Array4::from_shape_vec(s4(&z.shape), z.data).unwrap(),
        Array3::from_shape_vec([e.shape[0], e.shape[1], e.shape[2]], e.data).unwrap(),
        Array4::from_shape_vec(s4(&o.shape), o.data).unwrap(),
    )
}

/// `scripts/reference/mvfc_ref.py` (numpy.fft, float64, fftshift-ed spectra, both arrays
/// transformed) against our f32 single-transform implementation. Tolerance 2e-5 absolute
/// on unit-variance data (f32 FFT round-off is ~1e-6 at these sizes).
#[test]
fn mvfc_agrees_with_numpy_reference() {
    let cases: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(repo_root().join("tests/golden/mvfc/cases.json")).unwrap(),
    )
    .unwrap();
    let cases = cases.as_object().unwrap();
    assert!(cases.len() >= 4);
    for (name, p) in cases {
        let (z, e, want) = golden(name);
        let params = MvfcParams {
            gamma: p["gamma"].as_f64().unwrap() as f32,
            d_s: p["d_s"].as_f64().unwrap() as f32,
            d_t: p["d_t"].as_f64().unwrap() as f32,
        };
        let got = mvfc(z.view(), e.view(), params).unwrap();
        let err = got
            .iter()
            .zip(want.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // The filter must actually change something (else the comparison proves little).
        let change = got
            .iter()
            .zip(z.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(err < 2e-5, "{name}: max error {err}");
        assert!(change > 1e-2, "{name}: filter changed nothing ({change})");
    }
}

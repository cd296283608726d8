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

// ---------------------------------------------------------------------------------
// The stylizer prior (real Magenta weights from scripts/setup/20_stylizer.py).

use fantasystyle::csd::{self, CsdParams, StepInputs};
use fantasystyle::prior::Prior;
use fantasystyle::prior::stylizer::StylizerPrior;
use fantasystyle::rng::Rng;

/// The style image: the sample's `data-sample/style.png` when present (scene engineer's
/// generator), else a synthetic colourful swirl of the same kind.
fn style_image(size: usize) -> Array4<f32> {
    let p = repo_root().join("data-sample/style.png");
    if let Ok(img) = image::open(&p) {
        let img = img
            .resize_exact(
                size as u32,
                size as u32,
                image::imageops::FilterType::Triangle,
            )
            .to_rgb32f();
        return Array4::from_shape_fn((1, 3, size, size), |(_, c, y, x)| {
            img.get_pixel(x as u32, y as u32)[c]
        });
    }
    Array4::from_shape_fn((1, 3, size, size), |(_, c, y, x)| {
        let (u, v) = (x as f32 / size as f32, y as f32 / size as f32);
        let a = (12.0 * u + 5.0 * (6.0 * v).sin()).sin();
        let b = (9.0 * v + 4.0 * (7.0 * u).cos()).cos();
        let col = [[0.95, 0.55, 0.1], [0.1, 0.3, 0.85], [0.1, 0.7, 0.6]];
        let k = if a > 0.3 {
            0
        } else if b > 0.0 {
            1
        } else {
            2
        };
        col[k][c]
    })
}

/// Synthetic "views": a shaded grey-brown ball on a pale gradient, shifting per view.
fn content_views(n: usize, size: usize) -> Array4<f32> {
    Array4::from_shape_fn((n, 3, size, size), |(v, c, y, x)| {
        let (u, w) = (x as f32 / size as f32, y as f32 / size as f32);
        let cx = 0.4 + 0.05 * v as f32;
        let r2 = (u - cx).powi(2) + (w - 0.55).powi(2);
        if r2 < 0.09 {
            let shade = 1.0 - r2 / 0.09 * 0.6;
            [0.55, 0.45, 0.4][c] * shade
        } else {
            0.75 + 0.15 * w - 0.05 * c as f32
        }
    })
}

/// Distance of an image batch's colour statistics to the style's: per-channel mean and
/// standard deviation (colour moments) plus the 3x3 RGB Gram matrix (mean of x x^T).
fn style_distance(imgs: &Array4<f32>, style: &Array4<f32>) -> (f64, f64) {
    let stats = |a: &Array4<f32>| {
        let n = (a.len() / 3) as f64;
        let ch = |c: usize| a.slice(ndarray::s![.., c, .., ..]).mapv(|v| v as f64);
        let chans: Vec<_> = (0..3).map(ch).collect();
        let mean: Vec<f64> = chans.iter().map(|x| x.sum() / n).collect();
        let sd: Vec<f64> = chans
            .iter()
            .zip(&mean)
            .map(|(x, m)| (x.mapv(|v| (v - m).powi(2)).sum() / n).sqrt())
            .collect();
        let mut gram = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                gram[i][j] = (&chans[i] * &chans[j]).sum() / n;
            }
        }
        (mean, sd, gram)
    };
    let (m1, s1, g1) = stats(imgs);
    let (m2, s2, g2) = stats(style);
    let moments: f64 = (0..3)
        .map(|c| (m1[c] - m2[c]).abs() + (s1[c] - s2[c]).abs())
        .sum();
    let gram: f64 = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (g1[i][j] - g2[i][j]).powi(2))
        .sum::<f64>()
        .sqrt();
    (moments, gram)
}

fn stylizer(style: &Array4<f32>) -> Option<StylizerPrior> {
    let dir = repo_root().join("vendor/models/stylizer");
    if !dir.join("model.json").is_file() {
        eprintln!("SKIPPED: vendor/models/stylizer missing (run scripts/setup.sh)");
        return None;
    }
    Some(StylizerPrior::open(&dir, Some(style.view()), 2).unwrap())
}

/// A few CSD rounds with the stylizer prior move the views' colour statistics toward
/// the style image: colour-moment and RGB-Gram distances both fall by at least 20%, and
/// the images stay finite in [0, 1].
#[test]
fn stylizer_csd_moves_views_toward_the_style() {
    let style = style_image(256);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let views = content_views(2, 128);
    let (m0, g0) = style_distance(&views, &style);
    let mut z0 = prior.encode(views.view()).unwrap();
    let params = CsdParams::default();
    for round in 0..3u64 {
        let t = [300, 200, 100][round as usize];
        let eps = Array4::from_shape_vec(
            z0.raw_dim(),
            Rng::derive(5, &format!("eps/{round}")).normals_f32(z0.len()),
        )
        .unwrap();
        let z_tgt = sched.add_noise(z0.view(), eps.view(), t).unwrap();
        let z_src = sched.add_noise(views.view(), eps.view(), t).unwrap();
        let (z1, _) = csd::step(
            &mut prior,
            &sched,
            StepInputs {
                z0: z0.view(),
                z_tgt: z_tgt.view(),
                z_src: z_src.view(),
                eps: eps.view(),
                t,
                control: None,
            },
            &params,
        )
        .unwrap();
        z0 = z1.mapv(|v| v.clamp(0.0, 1.0));
    }
    let (m1, g1) = style_distance(&z0, &style);
    eprintln!("colour moments {m0:.4} -> {m1:.4}, RGB Gram {g0:.4} -> {g1:.4}");
    assert!(z0.iter().all(|v| v.is_finite()));
    assert!(m1 < 0.8 * m0, "colour-moment distance {m0} -> {m1}");
    assert!(g1 < 0.8 * g0, "Gram distance {g0} -> {g1}");
}

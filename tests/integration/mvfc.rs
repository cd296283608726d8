//! MVFC and CSD stages (issue 5): agreement with the numpy reference, the stages'
//! artifacts and their bad-input errors.

use crate::harness::repo_root;
use fantasystyle::mvfc::{MvfcParams, mvfc};
use fantasystyle_schemas::read_npy_f32;
use ndarray::{Array3, Array4};

/// A case of `tests/golden/mvfc/`. Committed bytes, on purpose: float64 numpy of the
/// formulas (no network), which differ between CPUs by float64 rounding (1e-16
/// relative), far below the tolerances (2e-5 and up).
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
            ..MvfcParams::default()
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
    let dir = crate::harness::model("stylizer")?;
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
                z0_src: None,
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

// ---------------------------------------------------------------------------------
// The stages: mvfc-filter and csd-step, through their library functions.

use fantasystyle::artifacts::{read_latents, read_noised_latents, read_targets};
use fantasystyle::camera::path::ViewPath;
use fantasystyle::csd::Mode;
use fantasystyle::distill::TimestepSchedule;
use fantasystyle::distill::step::Draws;
use fantasystyle::mvfc::mvfc_path;
use fantasystyle::stages::{Background, ConfigArgs, PriorArgs, Threads};
use fantasystyle::stages::{csd_step, encode_latents, mvfc_filter};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use std::path::{Path, PathBuf};

/// An installed model ([`crate::harness::model`]; these all need onnxruntime too).
fn model_dir(name: &str) -> Option<PathBuf> {
    if !crate::harness::onnxruntime() {
        return None;
    }
    crate::harness::model(name)
}

fn write_latents(dir: &Path, z: &Array4<f32>, meta: serde_json::Value) {
    let mut w = ArtifactWriter::create(
        dir,
        ArtifactKind::Latents,
        Producer::new("test", "0", serde_json::json!({})),
    )
    .unwrap();
    w.write_tensor("latents.npy", z.shape(), z.as_slice().unwrap())
        .unwrap();
    w.set_meta(meta);
    w.commit().unwrap();
}

/// A views artifact from images [N, 3, H, W].
fn write_views(dir: &Path, imgs: &Array4<f32>) {
    let (n, h, w) = (imgs.shape()[0], imgs.shape()[2], imgs.shape()[3]);
    let rgb: Vec<f32> = imgs
        .view()
        .permuted_axes([0, 2, 3, 1])
        .iter()
        .copied()
        .collect();
    crate::harness::write_views(
        dir,
        [n, h, w],
        &rgb,
        &vec![2.0f32; n * h * w],
        &vec![1.0f32; n * h * w],
        b"[{\"id\": 0, \"note\": \"test\"}]\n",
    );
}

fn filter_args(d: &Path, model: &Path) -> mvfc_filter::Args {
    mvfc_filter::Args {
        latents: d.join("lat_tgt"),
        source_latents: d.join("lat_src"),
        model: model.to_path_buf(),
        config: ConfigArgs {
            sets: vec!["seed=3".into()],
            ..Default::default()
        },
        iteration: Some(1),
        out: d.join("noised"),
        threads: Threads::new(1),
    }
}

/// Golden alphas_cumprod of the scaled-linear schedule (numpy, float64:
/// scripts/reference/csd_ref.py).
fn numpy_alphas() -> Vec<f64> {
    fantasystyle_schemas::read_npy::<f64>(&repo_root().join("tests/golden/csd/alphas_cumprod.npy"))
        .unwrap()
        .data
}

fn max_abs_diff(a: &Array4<f32>, b: &Array4<f32>) -> f32 {
    assert_eq!(a.shape(), b.shape());
    a.iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max)
}

/// mvfc-filter against independent references, not its own library calls:
/// * z_src = sqrt(ab) z0_src + sqrt(1-ab) eps with ab from numpy's schedule (1e-5);
/// * MVFC is linear, so two runs of the same (seed, iteration) -- hence the same t, eps
///   and eps' -- whose target latents differ by Z / sqrt(ab) differ in z_tgt by
///   (H + gamma L) Z on the mirror-extended view axis (latents without a recorded
///   iteration are one window of an open path), the noise-free golden case
///   `stage_4v_path` of scripts/reference/mvfc_ref.py (2e-5);
/// * eps' enters through the low band: the mean over the mirror-extended views
///   (v0 .. v_{N-1}, v_{N-2} .. v1) and pixels of z_tgt (the DC term, where L = 1 and
///   H = 0) is gamma * mean(noisy) + (1 - gamma) * mean(eps') per channel (1e-5);
/// * `--mvfc-source false`: the source only noised; `--no-mvfc`: the noisy latents
///   themselves; the draws are distill's stream for (seed, iteration), another
///   iteration draws other noise, and a recorded window picks its rows of the source
///   latents and wins over flags, which may not contradict it.
#[test]
fn mvfc_filter_stage_noises_and_filters() {
    let Some(model) = model_dir("gaussian-prior") else {
        return;
    };
    let (zg, eg, _) = golden("stage_4v");
    assert!(eg.iter().all(|v| *v == 0.0));
    let outg = read_npy_f32(&repo_root().join("tests/golden/mvfc/stage_4v_path_out.npy")).unwrap();
    let outg = Array4::from_shape_vec(zg.raw_dim(), outg.data).unwrap();
    let p = MvfcParams::default();
    let d = tempfile::tempdir().unwrap();
    let shape = zg.raw_dim();
    let z_s = Array4::from_shape_vec(shape, Rng::new(11).normals_f32(zg.len())).unwrap();
    write_latents(&d.path().join("lat_src"), &z_s, serde_json::json!({}));
    write_latents(
        &d.path().join("lat_b"),
        &Array4::zeros(shape),
        serde_json::json!({}),
    );
    let run = |tgt: &str, out: &str, edit: &dyn Fn(&mut mvfc_filter::Args)| {
        let mut a = filter_args(d.path(), &model);
        a.latents = d.path().join(tgt);
        a.out = d.path().join(out);
        edit(&mut a);
        let used = mvfc_filter::run(a).unwrap();
        (used, read_noised_latents(&d.path().join(out)).unwrap())
    };
    // The iteration's t comes from its draws; the golden case is scaled by its ab.
    let (t, nb) = run("lat_b", "b", &|_| {});
    let (_, set) = fantasystyle::prior::model_timesteps(&model).unwrap();
    assert!(set.contains(t) && nb.timestep == t);
    let ab = numpy_alphas()[t];
    let (sa, sb) = (ab.sqrt() as f32, (1.0 - ab).sqrt() as f32);
    write_latents(
        &d.path().join("lat_a"),
        &zg.mapv(|v| v / sa),
        serde_json::json!({}),
    );
    let (ta, na) = run("lat_a", "a", &|_| {});
    assert_eq!(ta, t);
    assert_eq!((&na.eps, &na.eps_shared), (&nb.eps, &nb.eps_shared));
    let eps = &na.eps;
    let want_src = ndarray::Zip::from(&z_s)
        .and(eps)
        .map_collect(|&z, &e| sa * z + sb * e);
    // The source is filtered too (same eps'): compare with its own filter off.
    let (_, ns) = run("lat_a", "src-only-noised", &|a| {
        a.config.sets.push("mvfc.source=false".into())
    });
    let e_src = max_abs_diff(&ns.z_src, &want_src);
    assert!(e_src < 1e-5, "z_src vs numpy's schedule: {e_src}");
    assert_eq!(ns.z_tgt, na.z_tgt);
    assert!(na.z_src != ns.z_src);
    let e_lin = max_abs_diff(&(&na.z_tgt - &nb.z_tgt), &outg);
    assert!(e_lin < 2e-5, "filter vs the numpy reference: {e_lin}");
    // The low band takes (1 - gamma) of eps', whose per-channel means are far from 0
    // only by chance: the DC identity pins how eps' is used.
    let noisy_b = eps.mapv(|e| sb * e);
    let (n, c, h, w) = nb.z_tgt.dim();
    for ch in 0..c {
        // Over the mirror-extended views: the ends once, the inner views twice.
        let mean = |a: ndarray::ArrayView3<'_, f32>| {
            let wt = |v: usize| if v == 0 || v == n - 1 { 1.0 } else { 2.0 };
            let s: f64 = (0..n)
                .map(|v| {
                    wt(v)
                        * a.index_axis(ndarray::Axis(0), v)
                            .iter()
                            .map(|x| *x as f64)
                            .sum::<f64>()
                })
                .sum();
            s / ((2 * n - 2) * h * w) as f64
        };
        let got = mean(nb.z_tgt.index_axis(ndarray::Axis(1), ch));
        let want = p.gamma as f64 * mean(noisy_b.index_axis(ndarray::Axis(1), ch))
            + (1.0 - p.gamma as f64)
                * nb.eps_shared
                    .index_axis(ndarray::Axis(0), ch)
                    .mean()
                    .unwrap() as f64;
        assert!(
            (got - want).abs() < 1e-5,
            "channel {ch}: DC {got} vs {want} ({n}x{h}x{w})"
        );
    }
    // --no-mvfc: the noisy latents, nothing else.
    let (_, nf) = run("lat_a", "nofilter", &|a| {
        a.config.sets.push("mvfc.enabled=false".into())
    });
    let want_noisy = ndarray::Zip::from(&zg)
        .and(eps)
        .map_collect(|&z, &e| sa * (z / sa) + sb * e);
    assert!(max_abs_diff(&nf.z_tgt, &want_noisy) < 1e-5);
    assert!(max_abs_diff(&nf.z_src, &want_src) < 1e-5);
    assert_eq!(nf.eps, na.eps);
    // The draws: distill's stream for (seed 3, iteration 1) on an open path of 4 views.
    let path = ViewPath {
        len: shape[0],
        closed: false,
    };
    let mut draws = Draws::new(3, 1, path, shape[0]);
    assert_eq!(
        draws.window().window.views,
        (0..shape[0]).collect::<Vec<_>>()
    );
    assert_eq!(draws.timestep(TimestepSchedule::Random, &set), t);
    assert_eq!(
        &draws.noise([shape[0], shape[1], shape[2], shape[3]]).eps,
        eps
    );
    // Another iteration draws other noise; an annealed schedule at its end the smallest t.
    let (_, n2) = run("lat_b", "it2", &|a| a.iteration = Some(2));
    assert!(n2.eps != nb.eps);
    let (t_end, _) = run("lat_b", "annealed", &|a| {
        a.config.sets.push("anneal_iters=1".into())
    });
    assert_eq!(t_end, set.steps()[0]);

    // A recorded window: views 3, 4, 0 of a closed path of 5; the source rows are those.
    let mut rng = Rng::new(12);
    let (c, lh, lw) = (shape[1], shape[2], shape[3]);
    let z_all = Array4::from_shape_vec((5, c, lh, lw), rng.normals_f32(5 * c * lh * lw)).unwrap();
    let z_t = Array4::from_shape_vec((3, c, lh, lw), rng.normals_f32(3 * c * lh * lw)).unwrap();
    let closed = ViewPath {
        len: 5,
        closed: true,
    };
    let win = (0..200)
        .map(|i| Draws::new(9, i, closed, 3).window().clone())
        .find(|w| w.window.views == [3, 4, 0])
        .unwrap();
    write_latents(&d.path().join("lat_src5"), &z_all, serde_json::json!({}));
    write_latents(
        &d.path().join("lat_w"),
        &z_t,
        serde_json::json!({ "iteration": win }),
    );
    let mut b = filter_args(d.path(), &model);
    (b.latents, b.source_latents) = (d.path().join("lat_w"), d.path().join("lat_src5"));
    (b.iteration, b.out) = (None, d.path().join("win"));
    let tw = mvfc_filter::run(b.clone()).unwrap();
    let nw = read_noised_latents(&b.out).unwrap();
    assert_eq!(nw.iteration.as_ref(), Some(&win));
    let ab = numpy_alphas()[tw];
    let (sa, sb) = (ab.sqrt() as f32, (1.0 - ab).sqrt() as f32);
    let src_rows = z_all.select(ndarray::Axis(0), &[3, 4, 0]);
    let noisy = ndarray::Zip::from(&src_rows)
        .and(&nw.eps)
        .map_collect(|&z, &e| sa * z + sb * e);
    // The window is not the whole closed path: mirror-extended, as mvfc_path says.
    let want = mvfc_path(noisy.view(), nw.eps_shared.view(), p, false).unwrap();
    assert!(max_abs_diff(&nw.z_src, &want) < 1e-5);
    // The recorded iteration wins over --iteration, which may not contradict it.
    b.iteration = Some(1);
    b.out = d.path().join("conflict");
    let e = mvfc_filter::run(b.clone()).unwrap_err().to_string();
    assert!(
        e.contains("records its iteration") && !b.out.exists(),
        "{e}"
    );
}

/// Bad input to mvfc-filter: clear errors naming the problem, nothing written.
#[test]
fn mvfc_filter_stage_rejects_bad_input() {
    let Some(model) = model_dir("gaussian-prior") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let z = Array4::<f32>::zeros((2, 4, 8, 8));
    let none = || serde_json::json!({});
    write_latents(&d.path().join("lat_tgt"), &z, none());
    write_latents(
        &d.path().join("lat_src"),
        &Array4::<f32>::zeros((2, 4, 8, 6)),
        none(),
    );
    let err = |a: &mvfc_filter::Args| {
        let e = mvfc_filter::run(a.clone()).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(!a.out.exists());
        e.to_string()
    };
    let a = filter_args(d.path(), &model);
    let e = err(&a);
    assert!(e.contains("lat_src") && e.contains("shape"), "{e}");

    let mut nan = z.clone();
    nan[[1, 2, 3, 4]] = f32::NAN;
    write_latents(&d.path().join("lat_src"), &nan, none());
    let e = err(&a);
    assert!(e.contains("lat_src") && e.contains("NaN"), "{e}");

    // Source latents of another number of views than the path.
    write_latents(
        &d.path().join("lat_src"),
        &Array4::zeros((3, 4, 8, 8)),
        none(),
    );
    let e = err(&a);
    assert!(e.contains("lat_src") && e.contains("3 views"), "{e}");

    write_latents(&d.path().join("lat_src"), &z, none());
    let mut b = filter_args(d.path(), &model);
    b.config.sets.push("timesteps=3:2:1".into());
    let e = err(&b);
    assert!(e.contains("t_min 3"), "{e}");
    b.config.sets.push("timesteps=soon".into());
    let e = err(&b);
    assert!(e.contains("MIN:MAX:COUNT"), "{e}");

    let mut c = filter_args(d.path(), &model);
    c.config.sets.push("mvfc.gamma=1.5".into());
    let e = err(&c);
    assert!(e.contains("gamma"), "{e}");
    let mut m = filter_args(d.path(), &model);
    m.model = d.path().join("no-such-model");
    let e = err(&m);
    assert!(e.contains("no-such-model"), "{e}");
}

/// Build views, latents and noised latents for a csd-step run in `d`.
pub(crate) fn csd_inputs(
    d: &Path,
    model: &Path,
    views: &Array4<f32>,
    style: &Array4<f32>,
) -> PathBuf {
    write_views(&d.join("views"), views);
    encode_latents::run(encode_latents::Args {
        views: d.join("views"),
        model: model.to_path_buf(),
        out: d.join("lat"),
        threads: Threads::new(1),
        device: Default::default(),
        batch: 0,
        fill: false,
        alpha_from: None,
        background: Background { rgb: [0.0; 3] },
    })
    .unwrap();
    let mut a = filter_args(d, model);
    a.latents = d.join("lat");
    a.source_latents = d.join("lat");
    mvfc_filter::run(a.clone()).unwrap();
    let sp = d.join("style.png");
    let s = style.index_axis(ndarray::Axis(0), 0);
    let (h, w) = (s.shape()[1], s.shape()[2]);
    let bytes: Vec<u8> = s
        .permuted_axes([1, 2, 0])
        .iter()
        .map(|v| (v * 255.0).round() as u8)
        .collect();
    image::save_buffer(&sp, &bytes, w as u32, h as u32, image::ColorType::Rgb8).unwrap();
    sp
}

/// A distillation mode's name as a term of the configuration (`csd-no-neg`, ...).
pub(crate) fn mode_name(mode: Mode) -> String {
    clap::ValueEnum::to_possible_value(&mode)
        .unwrap()
        .get_name()
        .to_string()
}

pub(crate) fn step_args(d: &Path, model: &Path, style: &Path, mode: Mode) -> csd_step::Args {
    csd_step::Args {
        noised: d.join("noised"),
        latents: d.join("lat"),
        views: d.join("views"),
        source_views: d.join("views"),
        source_latents: d.join("lat"),
        prior: PriorArgs {
            model: Some(model.to_path_buf()),
            style: style.to_path_buf(),
            prompt: None,
            device: Default::default(),
        },
        config: ConfigArgs {
            sets: vec![format!("terms={}=1", mode_name(mode)), "csd.lr=0.05".into()],
            ..Default::default()
        },
        background: Background { rgb: [0.0; 3] },
        out: d.join("targets"),
        threads: Threads::new(1),
    }
}

// csd-step against numpy's targets: csd_golden::csd_step_stage_matches_numpy_targets.

/// csd-step with the stylizer model through `prior::open`: the targets move toward the
/// style's colour statistics.
#[test]
fn csd_step_stage_with_stylizer() {
    let Some(model) = model_dir("stylizer") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let views = content_views(2, 64);
    let style = style_image(128);
    let sp = csd_inputs(d.path(), &model, &views, &style);
    let mut a = step_args(d.path(), &model, &sp, Mode::Csd);
    a.config.sets.push("csd.lr=0.1".into());
    csd_step::run(a.clone()).unwrap();
    let rgb = read_targets(&d.path().join("targets")).unwrap().rgb;
    let tgt = rgb.permuted_axes([0, 3, 1, 2]).to_owned();
    let (m0, _) = style_distance(&views, &style);
    let (m1, _) = style_distance(&tgt, &style);
    assert!(m1 < m0, "colour moments {m0} -> {m1}");
}

/// Bad input to csd-step: missing style image, mismatched latents, inputs of another
/// iteration; clear errors and no output.
#[test]
fn csd_step_stage_rejects_bad_input() {
    let Some(model) = model_dir("gaussian-prior") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let views = content_views(2, 32);
    let sp = csd_inputs(d.path(), &model, &views, &style_image(32));
    let err = |a: &csd_step::Args| {
        let e = csd_step::run(a.clone()).unwrap_err();
        assert!(!a.out.exists());
        (e.exit_code(), e.to_string())
    };
    let mut a = step_args(d.path(), &model, &sp, Mode::Csd);
    a.prior.style = d.path().join("nope.png");
    let (code, e) = err(&a);
    assert!(
        code == 2 && e.contains("nope.png") && e.contains("not found"),
        "{e}"
    );

    std::fs::write(d.path().join("bad.png"), b"not a png").unwrap();
    a.prior.style = d.path().join("bad.png");
    let (code, e) = err(&a);
    assert!(code == 2 && e.contains("bad.png"), "{e}");

    // Latents of another shape than the noised ones.
    write_latents(
        &d.path().join("lat2"),
        &Array4::zeros((2, 4, 4, 2)),
        serde_json::json!({}),
    );
    let mut b = step_args(d.path(), &model, &sp, Mode::Csd);
    b.latents = d.path().join("lat2");
    let (code, e) = err(&b);
    assert!(code == 2 && e.contains("shape"), "{e}");

    // Noised latents of a recorded iteration, latents of none.
    let z = read_latents(&d.path().join("lat")).unwrap();
    let w = Draws::new(
        0,
        4,
        ViewPath {
            len: 2,
            closed: false,
        },
        2,
    )
    .window()
    .clone();
    let mut c = filter_args(d.path(), &model);
    write_latents(
        &d.path().join("lat_it"),
        &z,
        serde_json::json!({ "iteration": w }),
    );
    (c.latents, c.source_latents) = (d.path().join("lat_it"), d.path().join("lat"));
    (c.iteration, c.out) = (None, d.path().join("noised_it"));
    mvfc_filter::run(c).unwrap();
    let mut e2 = step_args(d.path(), &model, &sp, Mode::Csd);
    e2.noised = d.path().join("noised_it");
    let (code, e) = err(&e2);
    assert!(
        code == 2 && e.contains("another iteration") && e.contains("lat"),
        "{e}"
    );
}

/// The binaries: every contract flag is documented in -h; bad input exits 2 with a
/// message naming the file, without a panic.
#[test]
fn stage_binaries_document_flags_and_exit_cleanly() {
    use std::process::Command;
    let help = |bin: &str| {
        let o = Command::new(bin).arg("-h").output().unwrap();
        assert!(o.status.success());
        String::from_utf8(o.stdout).unwrap()
    };
    let mf = env!("CARGO_BIN_EXE_mvfc-filter");
    let cs = env!("CARGO_BIN_EXE_csd-step");
    let h = help(mf);
    for f in [
        "--latents",
        "--source-latents",
        "--model",
        "--preset",
        "--config",
        "--set",
        "--iteration",
        "--out",
        "--threads",
    ] {
        assert!(h.contains(f), "mvfc-filter -h lacks {f}");
    }
    let h = help(cs);
    for f in [
        "--noised",
        "--latents",
        "--views",
        "--source-views",
        "--source-latents",
        "--model",
        "--style",
        "--prompt",
        "--device",
        "--preset",
        "--config",
        "--set",
        "--background",
        "--out",
        "--threads",
    ] {
        assert!(h.contains(f), "csd-step -h lacks {f}");
    }
    let d = tempfile::tempdir().unwrap();
    let o = Command::new(mf)
        .args([
            "--latents",
            "missing-lat",
            "--source-latents",
            "missing-lat",
        ])
        .args(["--model", "vendor/models/stylizer", "--out"])
        .arg(d.path().join("o"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("missing-lat") && !err.contains("panicked"),
        "{err}"
    );
    let o = Command::new(mf)
        .args(["--latents", "a", "--source-latents", "b", "--model", "m"])
        .args(["--iteration", "soon", "--out", "x"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("soon"));
}

/// The stylizer's eps under Null inverts to its clean estimate (eps = (z - sqrt(ab) x0) /
/// sqrt(1-ab)); Content equals Null (both the identity: unstyled); Prompt (the image
/// redrawn with its own style) and PromptStyle (with the style image's) differ from it
/// and from each other.
#[test]
fn stylizer_eps_is_the_x0_parameterisation() {
    let style = style_image(64);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let x = content_views(1, 48);
    let eps = Array4::from_shape_vec(x.raw_dim(), Rng::new(4).normals_f32(x.len())).unwrap();
    let t = 200;
    let z = sched.add_noise(x.view(), eps.view(), t).unwrap();
    let conds = [
        fantasystyle::prior::Cond::Null,
        fantasystyle::prior::Cond::Prompt,
        fantasystyle::prior::Cond::PromptStyle,
        fantasystyle::prior::Cond::Content,
    ];
    let e = prior.predict_eps(z.view(), t, &conds, None).unwrap();
    let x0 = sched.x0_from_eps(z.view(), e[0].view(), t).unwrap();
    let xh = prior
        .clean_estimate(z.index_axis(ndarray::Axis(0), 0), t)
        .unwrap();
    let err = x0
        .index_axis(ndarray::Axis(0), 0)
        .iter()
        .zip(xh.iter())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(err < 1e-4, "{err}");
    assert_eq!(e[0], e[3]);
    let diff = |a: &Array4<f32>, b: &Array4<f32>| {
        a.iter()
            .zip(b.iter())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0f32, f32::max)
    };
    assert!(diff(&e[1], &e[0]) > 1e-2 && diff(&e[2], &e[0]) > 1e-2);
    assert!(diff(&e[2], &e[1]) > 1e-2);
    // The clean estimate is closer to the clean image than z / sqrt(ab) is.
    let ab = sched.alpha_bar(t).unwrap() as f32;
    let naive: f32 = z
        .iter()
        .zip(x.iter())
        .map(|(a, b)| (a / ab.sqrt() - b).powi(2))
        .sum();
    let est: f32 = xh.iter().zip(x.iter()).map(|(a, b)| (a - b).powi(2)).sum();
    assert!(est < 0.2 * naive, "{est} vs {naive}");
}

/// `predict_eps` stylizes the views of a call side by side (one transfer session per
/// worker, intra-op threads split between them): the same bits on pools of 1, 2 and 3
/// threads, and the same as stylizing view after view with one session of the default
/// thread count (eps from the clean estimate redrawn by `stylize`).
#[test]
fn lanes_give_the_same_bits_as_one_session() {
    use fantasystyle::prior::Cond;
    let style = style_image(64);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let x = content_views(3, 48);
    let eps = Array4::from_shape_vec(x.raw_dim(), Rng::new(9).normals_f32(x.len())).unwrap();
    let t = 150;
    let z = sched.add_noise(x.view(), eps.view(), t).unwrap();
    let conds = [Cond::PromptStyle, Cond::Prompt];
    let on = |threads: usize, prior: &mut StylizerPrior| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| prior.predict_eps(z.view(), t, &conds, Some(x.view())))
            .unwrap()
    };
    let one = on(1, &mut prior);
    assert_eq!(on(2, &mut prior), one);
    assert_eq!(on(3, &mut prior), one);
    // View after view on the prior's own session (2 intra-op threads).
    let s_style = prior
        .style_vector(style.index_axis(ndarray::Axis(0), 0))
        .unwrap();
    for b in 0..3 {
        let zb = z.index_axis(ndarray::Axis(0), b);
        let xh = prior.clean_estimate(zb, t).unwrap();
        let s_own = prior
            .style_vector(x.index_axis(ndarray::Axis(0), b))
            .unwrap();
        for (k, s) in [(0, &s_style), (1, &s_own)] {
            let x0 = prior.stylize(xh.view(), s).unwrap();
            let e = sched.eps_from_x0(zb, x0.view(), t).unwrap();
            assert_eq!(
                one[k].index_axis(ndarray::Axis(0), b),
                e,
                "view {b}, cond {k}"
            );
        }
    }
}

//! MVFC and the stages (issue 5): agreement with the numpy reference, the mvfc-filter
//! stage's artifacts and bad-input errors, the stage binaries' flags and exits, and the
//! helpers that build csd-step inputs. (CSD with the stylizer prior and the csd-step
//! stage's tests are in `mvfc_csd`.)

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
// The stages: mvfc-filter and csd-step, through their library functions.

use fantasystyle::artifacts::read_noised_latents;
use fantasystyle::camera::path::ViewPath;
use fantasystyle::csd::Mode;
use fantasystyle::distill::TimestepSchedule;
use fantasystyle::distill::step::Draws;
use fantasystyle::mvfc::mvfc_path;
use fantasystyle::rng::Rng;
use fantasystyle::stages::{Background, ConfigArgs, PriorArgs, Threads};
use fantasystyle::stages::{csd_step, encode_latents, mvfc_filter};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use std::path::{Path, PathBuf};

/// An installed model ([`crate::harness::model`]; these all need onnxruntime too).
pub(crate) fn model_dir(name: &str) -> Option<PathBuf> {
    if !crate::harness::onnxruntime() {
        return None;
    }
    crate::harness::model(name)
}

pub(crate) fn write_latents(dir: &Path, z: &Array4<f32>, meta: serde_json::Value) {
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

pub(crate) fn filter_args(d: &Path, model: &Path) -> mvfc_filter::Args {
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

//! CSD against the independent numpy reference `scripts/reference/csd_ref.py` (issue
//! 22): the golden files in `tests/golden/csd/` hold inputs and the expected gradients,
//! steps and targets, computed in float64 from the formulas, never by the Rust code.
//! They are committed bytes, and may be: float64 numpy of closed formulas differs between
//! CPUs by a few units in the 16th digit, far below the float32 tolerances here.
//!
//! * The default prior (the 2D stylizer) through `csd::step`, with its exact ("oracle")
//!   unconditional branches and the source's clean latents z0_src: once with a test
//!   double that returns two fixed images as the network's outputs (no model needed, so
//!   CSD's algebra is always tested), once with the installed stylizer itself, against
//!   its outputs computed *on this machine* by onnx's reference evaluator in float64
//!   (`scripts/reference/stylizer_ref.py`, run by set-up; issue 40: a network's numbers
//!   recorded on one CPU are not a reference on another).
//! * The `csd-step` stage on the Gaussian prior's ONNX graphs, every mode.
//!
//! Tolerances: gradients and steps 1e-4 relative to their largest entry (f32 against
//! float64; the oracle divides by sqrt(1 - ab) ~ 0.4 at t = 160), plus, with the real
//! network, its outputs' tolerance carried through CSD's closed form; clean estimates
//! 1e-5 (a blur in f32), targets 1e-4 absolute. The network's outputs: ten times the
//! float32 evaluation's own distance from the float64 one ([`net_tolerance`]).

use crate::harness::{self, repo_root};
use fantasystyle::csd::{self, CsdParams, Mode, StepInputs, Weighting};
use fantasystyle::prior::{Cond, ControlKind, Prior, PriorInfo};
use fantasystyle::scheduler::{Schedule, SchedulerConfig};
use fantasystyle_schemas::{read_npy, read_npy_f32};
use ndarray::{Array3, Array4, ArrayView4, Axis};
use std::path::{Path, PathBuf};

fn dir() -> PathBuf {
    repo_root().join("tests/golden/csd")
}

fn g4(name: &str) -> Array4<f32> {
    let a = read_npy_f32(&dir().join(name)).unwrap();
    let s = &a.shape;
    Array4::from_shape_vec((s[0], s[1], s[2], s[3]), a.data).unwrap()
}

/// A `[64, 64, 3]` u8 image as `[1, 3, 64, 64]` in [0, 1].
fn style(name: &str) -> (Vec<u8>, Array4<f32>) {
    let a = read_npy::<u8>(&dir().join(name)).unwrap();
    assert_eq!(a.shape, [64, 64, 3]);
    let img = Array4::from_shape_fn((1, 3, 64, 64), |(_, c, y, x)| {
        a.data[(y * 64 + x) * 3 + c] as f32 / 255.0
    });
    (a.data, img)
}

fn cases() -> serde_json::Map<String, serde_json::Value> {
    cases_in(&dir())
}

fn cases_in(dir: &Path) -> serde_json::Map<String, serde_json::Value> {
    let text = std::fs::read_to_string(dir.join("cases.json")).unwrap();
    serde_json::from_str::<serde_json::Value>(&text)
        .unwrap()
        .as_object()
        .unwrap()
        .clone()
}

fn params(c: &serde_json::Value) -> CsdParams {
    let weighting: Weighting = serde_json::from_value(c["weighting"].clone()).unwrap();
    let mode: Mode = serde_json::from_value(c["mode"].clone()).unwrap();
    CsdParams {
        mode,
        guidance: c["guidance"].as_f64().unwrap() as f32,
        weighting,
        lr: c["lr"].as_f64().unwrap() as f32,
    }
}

/// [`params`] as csd-step's configuration.
fn config_args(c: &serde_json::Value) -> fantasystyle::stages::ConfigArgs {
    let p = params(c);
    fantasystyle::stages::ConfigArgs {
        sets: vec![
            format!("terms={}=1", crate::mvfc::mode_name(p.mode)),
            format!("csd.guidance={}", p.guidance),
            format!("csd.lr={}", p.lr),
            format!(
                "csd.weighting={}",
                clap::ValueEnum::to_possible_value(&p.weighting)
                    .unwrap()
                    .get_name()
            ),
        ],
        ..Default::default()
    }
}

/// Largest |a - b| and largest |b|.
fn err(a: ArrayView4<'_, f32>, b: ArrayView4<'_, f32>) -> (f32, f32) {
    assert_eq!(a.shape(), b.shape());
    let e = a
        .iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    (e, b.iter().map(|v| v.abs()).fold(0.0f32, f32::max))
}

/// The stylizer case's inputs.
struct StylizerCase {
    z0: Array4<f32>,
    z0_src: Array4<f32>,
    eps: Array4<f32>,
    z_src: Array4<f32>,
    z_tgt: Array4<f32>,
    style: Array4<f32>,
}

fn stylizer_case() -> StylizerCase {
    StylizerCase {
        z0: g4("stylizer_z0.npy"),
        z0_src: g4("stylizer_z0_src.npy"),
        eps: g4("stylizer_eps.npy"),
        z_src: g4("stylizer_z_src.npy"),
        z_tgt: g4("stylizer_z_tgt.npy"),
        style: style("stylizer_style.npy").1,
    }
}

/// Run every stylizer case of `expected`'s cases.json through `csd::step` with `prior`
/// and compare gradient and step with the reference's there. `t_err` bounds
/// max |T - T_ref| + max |T' - T'_ref| of the prior's two network outputs (0 for a double
/// that returns the reference's own): CSD's gradient is, for every mode here,
/// w beta sqrt(ab / (1 - ab)) times a difference of the two (the module docs of
/// `prior::stylizer`), so their error reaches the gradient times that factor.
fn check_stylizer_cases(prior: &mut dyn Prior, expected: &Path, t_err: f32) {
    let x = stylizer_case();
    let sched = Schedule::new(prior.info().scheduler.clone()).unwrap();
    let mut n = 0;
    for (name, c) in cases_in(expected) {
        if c["prior"] != "stylizer" {
            continue;
        }
        let p = params(&c);
        let with_src = c["z0_src"].as_bool().unwrap();
        let (z1, g) = csd::step(
            prior,
            &sched,
            StepInputs {
                z0: x.z0.view(),
                z_tgt: x.z_tgt.view(),
                z_src: x.z_src.view(),
                eps: x.eps.view(),
                z0_src: with_src.then_some(x.z0_src.view()),
                t: c["timestep"].as_u64().unwrap() as usize,
                control: Some(x.z0_src.view()),
            },
            &p,
        )
        .unwrap();
        let load = |f: String| {
            let a = read_npy_f32(&expected.join(f)).unwrap();
            let s = &a.shape;
            Array4::from_shape_vec((s[0], s[1], s[2], s[3]), a.data).unwrap()
        };
        let (eg, sg) = err(g.view(), load(format!("{name}_grad.npy")).view());
        let (ez, sz) = err(z1.view(), load(format!("{name}_z1.npy")).view());
        let ab = c["alpha_bar"].as_f64().unwrap();
        let w = p.weighting.weight(ab);
        let net = (w * p.guidance as f64 * (ab / (1.0 - ab)).sqrt()) as f32 * t_err;
        let (tg, tz) = (1e-4 * sg + net, 1e-4 * sz.max(1.0) + p.lr * net);
        eprintln!(
            "{name}: |grad - ref| {eg:.2e} (max |grad| {sg:.3}, tolerance {tg:.2e}), \
             |z1 - ref| {ez:.2e} (tolerance {tz:.2e})"
        );
        assert!(
            sg > 0.1,
            "{name}: a vanishing reference gradient tests little ({sg})"
        );
        assert!(
            eg <= tg,
            "{name}: gradient off by {eg} (max {sg}, tolerance {tg})"
        );
        assert!(ez <= tz, "{name}: step off by {ez} (tolerance {tz})");
        n += 1;
    }
    assert_eq!(n, 5, "stylizer cases in cases.json");
}

/// A test double for the stylizer: its network outputs are two fixed images (inputs of
/// the reference, `stylizer_T_*.npy`), and its eps is the x0-parameterisation written out here, (z - sqrt(ab) x0) / sqrt(1 - ab),
/// with ab from the reference's own alphas_cumprod.npy. The unconditional branches
/// (Null, Content) must never be asked of it: CSD gives them exactly.
struct RecordedStylizer {
    info: PriorInfo,
    alphas: Vec<f64>,
    /// T(x^_tgt, s_style), T(x^_src, s_own): `[N, 3, H, W]`.
    t_ps: Array4<f32>,
    t_p: Array4<f32>,
}

impl Prior for RecordedStylizer {
    fn info(&self) -> &PriorInfo {
        &self.info
    }
    fn unconditional_is_identity(&self) -> bool {
        true
    }
    fn encode(&mut self, images: ArrayView4<'_, f32>) -> fantasystyle::Result<Array4<f32>> {
        Ok(images.to_owned())
    }
    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> fantasystyle::Result<Array4<f32>> {
        Ok(latents.to_owned())
    }
    fn predict_eps(
        &mut self,
        z: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        _control: Option<ArrayView4<'_, f32>>,
    ) -> fantasystyle::Result<Vec<Array4<f32>>> {
        let ab = self.alphas[t];
        let (sa, sb) = (ab.sqrt(), (1.0 - ab).sqrt());
        Ok(conds
            .iter()
            .map(|c| {
                let x0 = match c {
                    Cond::PromptStyle => &self.t_ps,
                    Cond::Prompt => &self.t_p,
                    other => panic!("CSD asked the prior for {other:?}, which it gives exactly"),
                };
                ndarray::Zip::from(z)
                    .and(x0)
                    .map_collect(|&z, &x| ((z as f64 - sa * x as f64) / sb) as f32)
            })
            .collect())
    }
}

/// CSD's algebra for the default prior, with no model: two fixed images as the
/// network's outputs through a test double, the oracle Null/Content branches (with and
/// without z0_src), the weightings and the step, against numpy.
#[test]
fn csd_oracle_branches_match_numpy_reference() {
    // Fixed inputs, not a network recording under test: the network's outputs on the day
    // they were made; any images would do, the expected values are numpy's from them.
    let (t_ps, t_p) = (g4("stylizer_T_ps_tgt.npy"), g4("stylizer_T_p_src.npy"));
    let alphas = read_npy::<f64>(&dir().join("alphas_cumprod.npy"))
        .unwrap()
        .data;
    let mut prior = RecordedStylizer {
        info: PriorInfo {
            name: "recorded-stylizer".into(),
            latent_channels: 3,
            downsample: 1,
            scheduler: SchedulerConfig::stable_diffusion(),
            control: Some(ControlKind::Source),
            coinciding_style_content: None,
        },
        alphas,
        t_ps,
        t_p,
    };
    check_stylizer_cases(&mut prior, &dir(), 0.0);
}

/// The reference's outputs for the installed stylizer (`vendor/models/stylizer/ref`, made
/// by set-up on this machine: `scripts/reference/stylizer_ref.py`), checked to belong to
/// the installed graphs; with its `ref.json`.
fn stylizer_reference(model: &Path) -> Option<(PathBuf, serde_json::Value)> {
    let stamp = harness::model_file("stylizer", "ref/ref.json")?;
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stamp).unwrap()).unwrap();
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(model.join("model.json")).unwrap()).unwrap();
    for g in ["style_predict", "transform"] {
        assert_eq!(
            r["sha256"]["graphs"][g],
            m["stylizer"][g]["sha256"],
            "{}: made for another {g} graph than the installed one; run scripts/setup.sh",
            stamp.display()
        );
    }
    Some((stamp.parent().unwrap().to_path_buf(), r))
}

/// The tolerance for the network output `key` of the reference against a float32
/// evaluation: ten times the reference's own float32 evaluation's largest distance from
/// its float64 one (`f32_error`). Both are float32 evaluations of the same graph; they
/// differ in kernels and summation order, not in the size of their rounding error
/// (measured on this case: onnxruntime's error 0.6-1.02x the reference evaluator's, on
/// AVX-512, AVX2 and SSE4.2). At least 4 float32 ulps of the largest value.
fn net_tolerance(r: &serde_json::Value, key: &str) -> f32 {
    let e = r["f32_error"][key].as_f64().unwrap();
    let m = r["max_abs"][key].as_f64().unwrap();
    (10.0 * e).max(4.0 * f32::EPSILON as f64 * m) as f32
}

/// Largest |a - b| of a float32 result against a float64 reference.
fn err64(a: &[f32], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x as f64 - y).abs())
        .fold(0.0, f64::max)
}

/// The installed stylizer: its clean estimate x^ equals numpy's (blur and clamp), its
/// style vectors and transfer outputs equal the float64 reference evaluator's on this
/// machine within float32 rounding, and `csd::step` with it gives the reference's
/// gradient and step.
#[test]
fn stylizer_csd_matches_numpy_reference() {
    let Some(model) = harness::model("stylizer") else {
        return;
    };
    let Some((refdir, r)) = stylizer_reference(&model) else {
        return;
    };
    let f64s = |name: &str| read_npy::<f64>(&refdir.join(name)).unwrap().data;
    let x = stylizer_case();
    let mut prior =
        fantasystyle::prior::stylizer::StylizerPrior::open(&model, Some(x.style.view()), 2)
            .unwrap();
    let t = 160;
    for (z, name) in [(&x.z_tgt, "tgt"), (&x.z_src, "src")] {
        let want = g4(&format!("stylizer_xhat_{name}.npy"));
        for b in 0..z.shape()[0] {
            let got = prior.clean_estimate(z.index_axis(Axis(0), b), t).unwrap();
            let w = want.index_axis(Axis(0), b);
            let e = got
                .iter()
                .zip(w.iter())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(e < 1e-5, "x^ of z_{name}[{b}]: off by {e}");
        }
    }
    // The style vectors: the style image's and the control images' (centre crop, resize,
    // style-prediction graph).
    let s_style = prior.style_vector(x.style.index_axis(Axis(0), 0)).unwrap();
    let mut s_own = Vec::new();
    for b in 0..x.z0_src.shape()[0] {
        s_own.extend(prior.style_vector(x.z0_src.index_axis(Axis(0), b)).unwrap());
    }
    // The transfer outputs, T(x^_tgt, s_style) and T(x^_src, s_own).
    let (ps, p) = transfer(&mut prior, &x, t);
    let mut t_err = 0.0;
    for (key, got) in [
        ("s_style", s_style.as_slice()),
        ("s_own", s_own.as_slice()),
        ("stylizer_T_ps_tgt", ps.as_slice().unwrap()),
        ("stylizer_T_p_src", p.as_slice().unwrap()),
    ] {
        let e = err64(got, &f64s(&format!("{key}.npy")));
        let tol = net_tolerance(&r, key);
        eprintln!(
            "{key}: max |ours - float64 reference| {e:.2e} (the reference's float32 \
             evaluation: {:.2e}; tolerance {tol:.2e}; largest value {:.3})",
            r["f32_error"][key].as_f64().unwrap(),
            r["max_abs"][key].as_f64().unwrap()
        );
        assert!(
            e <= tol as f64,
            "{key}: the stylizer's output is {e} from the reference evaluator's (tolerance \
             {tol}): not float rounding; see {}",
            refdir.display()
        );
        if key.starts_with("stylizer_T") {
            t_err += tol;
        }
    }
    check_stylizer_cases(&mut prior, &refdir, t_err);
}

/// The default stylizer's two graphs are the set-up's float rewrites of the shipped int8
/// ones (`scripts/setup/20_stylizer.py`, `dequantize`): the same networks without the
/// activations' 8-bit rounding. Checked against the shipped graphs
/// (`vendor/models/stylizer-int8`), those run as the ONNX standard defines them
/// (onnxruntime's basic optimisation level: each QuantizeLinear / DequantizeLinear as an
/// operator of its own, in float), not fused into the int8 kernels onnxruntime picks by
/// instruction set, whose outputs differ between CPUs (issue 40: style vectors 0.54 apart,
/// of 3.0, between AVX2 and AVX-512 VNNI).
///
/// Style prediction, on the style image and a 96x128 image with edges, gradients and
/// flat areas: the two style vectors differ by 2-10% (relative L2: the 8-bit rounding of
/// every activation); with one weight scale for all output channels instead of
/// per-channel scales (a wrong rewrite) they differ by 140-260%. So: above 0 (the rewrite
/// ran) and below 30%.
///
/// Transfer, both graphs given the same (float) style vector: the int8 graph's rounding
/// compounds through its five residual blocks (its instance norms' squared differences
/// are quantized with up to 19% relative error), and the outputs in [0, 1] differ by
/// 0.10-0.14 in the mean, depending on the style vector given (0.139 with the float
/// graph's, 0.127 and 0.100 with the int8 graph's on AVX-512 VNNI and on AVX2; mostly a
/// flat tint of the background, the strokes look alike, BENCHMARKS.md). The wrong rewrite
/// gives 0.34. So: above 0 and below 0.2.
#[test]
fn float_graphs_are_the_int8_network() {
    let (Some(float), Some(int8)) = (harness::model("stylizer"), harness::model("stylizer-int8"))
    else {
        return;
    };
    let (_, style) = style("stylizer_style.npy");
    let content = Array3::from_shape_fn((3, 96, 128), |(c, y, x)| {
        let (u, v) = (x as f32 / 127.0, y as f32 / 95.0);
        let check = if (x / 16 + y / 16) % 2 == 0 { 0.8 } else { 0.2 };
        match c {
            0 => 0.5 * u + 0.5 * check,
            1 => v,
            _ => {
                if (x as f32 - 64.0).hypot(y as f32 - 48.0) < 30.0 {
                    0.9
                } else {
                    0.1
                }
            }
        }
    });
    let open = |dir: &Path, optimization| {
        let cfg = fantasystyle::runtime::SessionConfig {
            threads: 2,
            optimization,
            ..Default::default()
        };
        fantasystyle::prior::stylizer::StylizerPrior::open_with(dir, None, cfg).unwrap()
    };
    let mut pf = open(&float, fantasystyle::runtime::Optimization::All);
    let mut pq = open(&int8, fantasystyle::runtime::Optimization::Basic);
    for (name, img) in [
        ("style image", style.index_axis(Axis(0), 0)),
        ("96x128 test image", content.view()),
    ] {
        let (a, b) = (pf.style_vector(img).unwrap(), pq.style_vector(img).unwrap());
        let norm = |v: &mut dyn Iterator<Item = f32>| v.map(|x| x * x).sum::<f32>().sqrt();
        let rel = norm(&mut a.iter().zip(&b).map(|(x, y)| x - y)) / norm(&mut b.iter().copied());
        eprintln!("float vs int8 style-prediction graph, {name}: relative difference {rel:.4}");
        assert!(
            rel > 0.0,
            "the default stylizer's style-prediction graph is the int8 one"
        );
        assert!(
            rel < 0.3,
            "float and int8 style-prediction graphs disagree on the {name}: {rel}"
        );
    }
    let s = pf.style_vector(style.index_axis(Axis(0), 0)).unwrap();
    let (a, b) = (
        pf.stylize(content.view(), &s).unwrap(),
        pq.stylize(content.view(), &s).unwrap(),
    );
    assert_eq!(a.shape(), b.shape());
    let mean = a
        .iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .sum::<f32>()
        / a.len() as f32;
    eprintln!("float vs int8 transfer graph: mean |difference| {mean:.4}");
    assert!(
        mean > 0.0,
        "the default stylizer's transfer graph is the int8 one"
    );
    assert!(
        mean < 0.2,
        "float and int8 transfer graphs disagree: mean |difference| {mean}"
    );
}

/// T(x^_tgt, s_style) and T(x^_src, s_own(control)) with the installed network.
fn transfer(
    prior: &mut fantasystyle::prior::stylizer::StylizerPrior,
    x: &StylizerCase,
    t: usize,
) -> (Array4<f32>, Array4<f32>) {
    let s_style = prior.style_vector(x.style.index_axis(Axis(0), 0)).unwrap();
    let mut ps = Array4::zeros(x.z0.raw_dim());
    let mut p = Array4::zeros(x.z0.raw_dim());
    for b in 0..x.z0.shape()[0] {
        let xh = prior
            .clean_estimate(x.z_tgt.index_axis(Axis(0), b), t)
            .unwrap();
        let out: Array3<f32> = prior.stylize(xh.view(), &s_style).unwrap();
        ps.index_axis_mut(Axis(0), b).assign(&out);
        let s_own = prior.style_vector(x.z0_src.index_axis(Axis(0), b)).unwrap();
        let xh = prior
            .clean_estimate(x.z_src.index_axis(Axis(0), b), t)
            .unwrap();
        p.index_axis_mut(Axis(0), b)
            .assign(&prior.stylize(xh.view(), &s_own).unwrap());
    }
    (ps, p)
}

// ---------------------------------------------------------------------------------
// The csd-step stage on the Gaussian prior's ONNX graphs.

use fantasystyle::stages::{Threads, csd_step, encode_latents};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};

fn write_tensors(
    dir: &Path,
    kind: ArtifactKind,
    t: &[(&str, &Array4<f32>)],
    meta: serde_json::Value,
) {
    let mut w =
        ArtifactWriter::create(dir, kind, Producer::new("test", "0", serde_json::json!({})))
            .unwrap();
    for (name, a) in t {
        w.write_tensor(name, a.shape(), a.as_standard_layout().as_slice().unwrap())
            .unwrap();
    }
    if kind == ArtifactKind::NoisedLatents {
        let s = t[0].1.shape();
        w.write_tensor(
            "eps_shared.npy",
            &[s[1], s[2], s[3]],
            &vec![0.0f32; s[1] * s[2] * s[3]],
        )
        .unwrap();
    }
    w.set_meta(meta);
    w.commit().unwrap();
}

/// `csd-step` with the Gaussian prior's ONNX graphs, every case of the reference (csd
/// with two weightings, sds, dds, csd-no-neg): the targets equal numpy's
/// clamp(render + decode(z0') - decode(z0), 0, 1) within 1e-4, the reported gradient
/// RMS equals the reference gradient's within 1e-4 relative, cameras are copied; and
/// `encode-latents` of the views gives numpy's latents.
#[test]
fn csd_step_stage_matches_numpy_targets() {
    if !harness::onnxruntime() {
        return;
    }
    let Some(model) = harness::model("gaussian-prior") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let dp = d.path();
    let views = g4("gaussian_views.npy"); // [N, H, W, 3]
    let (n, h, w) = (views.shape()[0], views.shape()[1], views.shape()[2]);
    let cams = b"[{\"id\": 0, \"note\": \"golden\"}]\n";
    harness::write_views(
        &dp.join("views"),
        [n, h, w],
        views.as_slice().unwrap(),
        &vec![2.0f32; n * h * w],
        &vec![1.0f32; n * h * w],
        cams,
    );
    // encode-latents: numpy's 8x8-pool + ENC encoder.
    encode_latents::run(encode_latents::Args {
        views: dp.join("views"),
        model: model.clone(),
        out: dp.join("lat-enc"),
        threads: Threads::new(1),
        device: Default::default(),
        batch: 0,
        fill: false,
        alpha_from: None,
        background: fantasystyle::stages::Background { rgb: [0.0; 3] },
    })
    .unwrap();
    let z0 = g4("gaussian_z0.npy");
    let enc = fantasystyle::artifacts::read_latents(&dp.join("lat-enc")).unwrap();
    let (e, _) = err(enc.view(), z0.view());
    assert!(e < 1e-5, "encode-latents vs numpy: {e}");

    let (style_u8, _) = style("gaussian_style.npy");
    let sp = dp.join("style.png");
    image::save_buffer(&sp, &style_u8, 64, 64, image::ColorType::Rgb8).unwrap();
    write_tensors(
        &dp.join("lat"),
        ArtifactKind::Latents,
        &[("latents.npy", &z0)],
        serde_json::json!({}),
    );
    let mut checked = 0;
    for (name, c) in cases() {
        if c["prior"] != "gaussian" {
            continue;
        }
        let t = c["timestep"].as_u64().unwrap();
        let nd = dp.join(format!("noised-{name}"));
        write_tensors(
            &nd,
            ArtifactKind::NoisedLatents,
            &[
                ("z_src.npy", &g4("gaussian_z_src.npy")),
                ("z_tgt.npy", &g4("gaussian_z_tgt.npy")),
                ("eps.npy", &g4("gaussian_eps.npy")),
            ],
            serde_json::json!({ "timestep": t }),
        );
        let out = dp.join(format!("targets-{name}"));
        let report = csd_step::run(csd_step::Args {
            noised: nd,
            latents: dp.join("lat"),
            views: dp.join("views"),
            source_views: dp.join("views"),
            // z0_src = z0: numpy's z_src is add_noise(z0, eps).
            source_latents: dp.join("lat"),
            prior: fantasystyle::stages::PriorArgs {
                model: Some(model.clone()),
                style: sp.clone(),
                prompt: None,
                device: Default::default(),
            },
            config: config_args(&c),
            background: fantasystyle::stages::Background { rgb: [0.0; 3] },
            out: out.clone(),
            threads: Threads::new(1),
        })
        .unwrap();
        assert_eq!(report.timestep as u64, t);
        let got = fantasystyle::artifacts::read_targets(&out).unwrap().rgb;
        let want = g4(&format!("{name}_raw.npy")).mapv(|v| v.clamp(0.0, 1.0));
        let (e, _) = err(got.view(), want.view());
        // How much the step changes the images: the comparison is not of two renders.
        let moved = want
            .iter()
            .zip(views.iter())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        let g = g4(&format!("{name}_grad.npy"));
        let rms = (g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / g.len() as f64).sqrt();
        eprintln!(
            "{name}: targets off by {e:.2e} (they move the views by up to {moved:.3}); \
             grad RMS {:.5} vs numpy {rms:.5}",
            report.grad_rms
        );
        assert!(
            moved > 0.01,
            "{name}: the step barely changes the views ({moved})"
        );
        assert!(e < 1e-4, "{name}: targets off by {e}");
        assert!(
            (report.grad_rms - rms).abs() <= 1e-4 * rms,
            "{name}: grad RMS {} vs {rms}",
            report.grad_rms
        );
        assert_eq!(std::fs::read(out.join("cameras.json")).unwrap(), cams);
        checked += 1;
    }
    assert_eq!(checked, 5, "gaussian cases in cases.json");
}

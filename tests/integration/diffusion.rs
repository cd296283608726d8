//! The exported-diffusion-model path, on the committed random-weight SD-1.5-shaped export
//! `tests/fixtures/tiny-sd15` (made by `scripts/export_models.py --tiny`, see its README):
//! agreement with eager diffusers, run-time prompts through the model's own tokenizer and
//! text encoder, InstantStyle routing of the image tokens, CSD's refusal of coinciding
//! style and content conditionings, ONNX external data, and `--device` errors.
//!
//! References: `reference/*.npy` were computed by eager diffusers (the pipeline's own
//! encode_prompt, prepare_ip_adapter_image_embeds, set_ip_adapter_scale, ControlNet and
//! UNet calls) before the export rewired anything; token ids by the independent
//! plain-Python BPE `scripts/reference/clip_bpe_ref.py`. Committed bytes, and why: eager
//! diffusers (PyTorch) is not part of set-up, so its float32 outputs are recorded with the
//! fixture. Both sides are float32 graphs without quantized operators, whose results
//! differ between CPUs by float rounding only (measured <= 1.3e-6 relative on AVX-512 and
//! under qemu's AVX2 and SSE4.2, issue 40), against a tolerance of 1e-4 (fp32).

use crate::harness::repo_root;
use fantasystyle::csd::{self, CsdParams, Mode, StepInputs};
use fantasystyle::prior::manifest::{ModelManifest, Precision};
use fantasystyle::prior::text::TextEncoder;
use fantasystyle::prior::{Cond, OnnxPrior, Prior, PriorOptions};
use fantasystyle::runtime::{Device, SessionConfig};
use ndarray::{Array3, Array4, ArrayD, IxDyn};
use std::path::{Path, PathBuf};

/// The committed fixture, or `None` without onnxruntime ([`crate::harness::need`]: a
/// failure under CI).
pub fn tiny_sd15() -> Option<PathBuf> {
    if !crate::harness::onnxruntime() {
        return None;
    }
    Some(repo_root().join("tests/fixtures/tiny-sd15"))
}

fn npy(dir: &Path, name: &str) -> ArrayD<f32> {
    let a = fantasystyle_schemas::read_npy_f32(&dir.join("reference").join(name)).unwrap();
    ArrayD::from_shape_vec(IxDyn(&a.shape), a.data).unwrap()
}

fn npy4(dir: &Path, name: &str) -> Array4<f32> {
    npy(dir, name).into_dimensionality().unwrap()
}

fn reference_json(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("reference/reference.json")).unwrap())
        .unwrap()
}

/// max |a - b| / max |b|.
fn rel<D: ndarray::Dimension>(a: &ndarray::Array<f32, D>, b: &ndarray::Array<f32, D>) -> f32 {
    assert_eq!(a.shape(), b.shape());
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    d / b.iter().fold(0f32, |m, x| m.max(x.abs())).max(1e-12)
}

fn open(dir: &Path, prompt: Option<String>) -> OnnxPrior {
    let style = npy4(dir, "style.npy");
    OnnxPrior::open(
        dir,
        &PriorOptions {
            style_image: Some(style),
            prompt,
            threads: 1,
            ..Default::default()
        },
    )
    .unwrap()
}

/// Copy a model directory (with its subdirectories) and edit its model.json.
fn edited(src: &Path, f: impl FnOnce(&mut serde_json::Value)) -> tempfile::TempDir {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let t = to.join(p.file_name().unwrap());
            if p.is_dir() {
                copy(&p, &t);
            } else {
                std::fs::copy(&p, &t).unwrap();
            }
        }
    }
    let d = tempfile::tempdir().unwrap();
    copy(src, d.path());
    let mp = d.path().join("model.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mp).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&mp, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    d
}

/// The model with plain IP-Adapter conditioning: the content conditioning routed like
/// the style one (what `export_models.py --ip-routing shared` writes, up to the scales).
fn shared_copy(dir: &Path) -> tempfile::TempDir {
    edited(dir, |v| {
        let ic = &mut v["image_conditioning"];
        ic["scheme"] = "shared".into();
        ic["content"] = ic["style"].clone();
    })
}

/// Relative max errors of every reference the export wrote, with the run-time prompt
/// (not pre-embedded) going through the tokenizer and the text encoder.
fn agreement(dir: &Path) -> Vec<(&'static str, f32)> {
    let r = reference_json(dir);
    let t = r["t"].as_u64().unwrap() as usize;
    let prompt = r["prompt"].as_str().unwrap().to_string();
    let md = ModelManifest::load(dir).unwrap();
    let text = md.manifest.text.as_ref().unwrap();
    assert!(
        text.prompts.iter().all(|p| p.text != prompt),
        "the reference prompt must not be pre-embedded"
    );
    let mut errs = Vec::new();

    // Tokenizer(s): ids equal to the independent BPE's, for every reference prompt.
    let enc_cfg = text.encoder.as_ref().expect("a text encoder");
    let mut te = TextEncoder::load(&md, enc_cfg, &SessionConfig::default()).unwrap();
    for p in r["prompts"].as_array().unwrap() {
        let ids = te.tokenize(p["text"].as_str().unwrap()).unwrap();
        for (k, key) in ["input_ids", "input_ids_2"]
            .iter()
            .enumerate()
            .take(ids.len())
        {
            let want: Vec<u32> = p[key]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap() as u32)
                .collect();
            assert_eq!(ids[k], want, "{key} of {:?}", p["text"]);
        }
    }
    let enc = te.encode(&prompt).unwrap();
    let hidden: Array3<f32> = npy(dir, "text_hidden.npy").into_dimensionality().unwrap();
    errs.push(("text hidden states", rel(&enc.hidden, &hidden)));
    if let Some(p) = &enc.pooled {
        let want = npy(dir, "text_pooled.npy").into_dimensionality().unwrap();
        errs.push(("text pooled", rel(p, &want)));
    }

    let mut p = open(dir, Some(prompt));
    let lat = p.encode(npy4(dir, "images.npy").view()).unwrap();
    errs.push(("vae encode", rel(&lat, &npy4(dir, "latents.npy"))));
    let z = npy4(dir, "z.npy");
    let dec = p
        .decode(z.slice(ndarray::s![..1, .., .., ..]).view())
        .unwrap();
    errs.push(("vae decode", rel(&dec, &npy4(dir, "decoded.npy"))));
    let ctrl = npy4(dir, "control.npy");
    let conds = [Cond::Null, Cond::Prompt, Cond::PromptStyle, Cond::Content];
    let names = ["eps null", "eps prompt", "eps prompt+style", "eps content"];
    let files = [
        "eps_null.npy",
        "eps_prompt.npy",
        "eps_prompt_style.npy",
        "eps_content.npy",
    ];
    let control = p.info().control.is_some().then(|| ctrl.view());
    // One batched call carrying all four conditionings (rows routed differently).
    let eps = p.predict_eps(z.view(), t, &conds, control).unwrap();
    for ((e, name), file) in eps.iter().zip(names).zip(files) {
        errs.push((name, rel(e, &npy4(dir, file))));
    }
    errs
}

fn tolerances(dir: &Path) -> (f32, f32) {
    // fp32: both sides compute in float32 with different kernels and summation orders;
    // measured <= 4e-6 (tiny and full-size SD 1.5 shapes). fp16 weights: both sides
    // round to float16 (unit roundoff 4.9e-4) in different orders; measured <= 2.4e-3.
    let m = ModelManifest::load(dir).unwrap().manifest;
    let tol = |p: Precision| if p == Precision::Fp16 { 1e-2 } else { 1e-4 };
    (
        tol(m.precision),
        tol(m.vae_precision.unwrap_or(m.precision)),
    )
}

fn check_agreement(dir: &Path) {
    let (tol, vae_tol) = tolerances(dir);
    let errs = agreement(dir);
    eprintln!(
        "{}: relative max errors vs eager diffusers {errs:?} (tolerance {tol}, VAE {vae_tol})",
        dir.display()
    );
    for (name, e) in errs {
        let t = if name.starts_with("vae") {
            vae_tol
        } else {
            tol
        };
        assert!(e < t, "{name}: {e} >= {t}");
    }
}

#[test]
fn tiny_sd15_export_agrees_with_eager_diffusers() {
    let Some(dir) = tiny_sd15() else { return };
    check_agreement(&dir);
}

/// Opt-in: `FANTASYSTYLE_EXPORTED_MODEL=DIR` for any `scripts/export_models.py --random`
/// export (e.g. the tiny SDXL one, which is not committed): the same checks.
#[test]
fn exported_model_agrees_with_eager_diffusers() {
    let Ok(dir) = std::env::var("FANTASYSTYLE_EXPORTED_MODEL") else {
        // Opt-in (a user's own export, not installed by set-up): a skip, also under CI.
        eprintln!(
            "SKIPPED (opt-in, not a set-up item): set FANTASYSTYLE_EXPORTED_MODEL to an \
             export_models.py --tiny export"
        );
        return;
    };
    check_agreement(Path::new(&dir));
}

#[test]
fn style_and_content_conditionings_differ_on_one_latent() {
    let Some(dir) = tiny_sd15() else { return };
    let r = reference_json(&dir);
    let t = r["t"].as_u64().unwrap() as usize;
    let z = npy4(&dir, "z.npy");
    let z = z.slice(ndarray::s![..1, .., .., ..]).to_owned();
    let ctrl = npy4(&dir, "control.npy");
    let ctrl = ctrl.slice(ndarray::s![..1, .., .., ..]).to_owned();
    let conds = [Cond::Null, Cond::Prompt, Cond::PromptStyle, Cond::Content];

    let mut p = open(&dir, None);
    assert_eq!(p.info().coinciding_style_content, None);
    let e = p
        .predict_eps(z.view(), t, &conds, Some(ctrl.view()))
        .unwrap();
    // The image enters both branches (each differs from its no-image counterpart) ...
    let content_vs_null = rel(&e[3], &e[0]);
    let style_vs_prompt = rel(&e[2], &e[1]);
    // ... and through different layers: routing the content tokens like the style ones
    // (plain IP-Adapter) changes the content branch.
    let shared = shared_copy(&dir);
    let mut q = open(shared.path(), None);
    let why = q.info().coinciding_style_content.clone();
    let f = q
        .predict_eps(z.view(), t, &conds, Some(ctrl.view()))
        .unwrap();
    let routed_vs_shared = rel(&e[3], &f[3]);
    eprintln!(
        "eps(content) vs eps(null) {content_vs_null:.3e}, eps(prompt+style) vs eps(prompt) \
         {style_vs_prompt:.3e}, eps(content) InstantStyle vs shared routing \
         {routed_vs_shared:.3e}"
    );
    assert!(content_vs_null > 1e-3 && style_vs_prompt > 1e-3 && routed_vs_shared > 1e-3);
    // Rows split over several UNet calls give the same numbers.
    let mut one = OnnxPrior::open(
        &dir,
        &PriorOptions {
            style_image: Some(npy4(&dir, "style.npy")),
            threads: 1,
            unet_batch: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let split = one
        .predict_eps(z.view(), t, &conds, Some(ctrl.view()))
        .unwrap();
    for (a, b) in split.iter().zip(&e) {
        assert!(rel(a, b) < 1e-6, "{}", rel(a, b));
    }
    // The unrouted conditionings do not depend on the routing.
    assert!(rel(&e[0], &f[0]) < 1e-6 && rel(&e[2], &f[2]) < 1e-6);
    assert!(why.is_some_and(|w| w.contains("shared")));
}

#[test]
fn csd_refuses_coinciding_style_and_content() {
    let Some(dir) = tiny_sd15() else { return };
    let shared = shared_copy(&dir);
    let mut q = open(shared.path(), None);
    let z = npy4(&dir, "z.npy");
    let ctrl = npy4(&dir, "control.npy");
    let x = StepInputs {
        z0: z.view(),
        z_tgt: z.view(),
        z_src: z.view(),
        eps: z.view(),
        z0_src: None,
        t: 321,
        control: Some(ctrl.view()),
    };
    let schedule = q.schedule().clone();
    let step = |mode| CsdParams {
        mode,
        ..Default::default()
    };
    let e = csd::gradient(&mut q, &schedule, x, &step(Mode::Csd))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("csd-no-neg") && e.contains("sds") && e.contains("shared"),
        "{e}"
    );
    for mode in [Mode::CsdNoNeg, Mode::Sds] {
        let g = csd::gradient(&mut q, &schedule, x, &step(mode)).unwrap();
        assert!(g.iter().all(|v| v.is_finite()));
    }
    // The routed model runs csd, and its negative content branch is really there:
    // csd - csd-no-neg = w(t) beta (e(Null) - e(Content)) (src/csd.rs), not 0.
    let mut p = open(&dir, None);
    let g = csd::gradient(&mut p, &schedule, x, &step(Mode::Csd)).unwrap();
    let g_nn = csd::gradient(&mut p, &schedule, x, &step(Mode::CsdNoNeg)).unwrap();
    let e = p
        .predict_eps(
            z.view(),
            321,
            &[Cond::Null, Cond::Content],
            Some(ctrl.view()),
        )
        .unwrap();
    let p0 = CsdParams::default();
    let wb = (p0.weighting.weight(schedule.alpha_bar(321).unwrap()) as f32) * p0.guidance;
    let want = (&e[0] - &e[1]).mapv(|v| wb * v);
    let scale = want.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
    let off = (&(&g - &g_nn) - &want)
        .iter()
        .map(|v| v.abs())
        .fold(0.0f32, f32::max);
    assert!(scale > 1e-3, "routed content guidance vanishes: {scale}");
    assert!(
        off <= 1e-4 * scale,
        "csd - csd-no-neg off by {off} (scale {scale})"
    );
}

#[test]
fn unknown_prompt_without_text_encoder_names_the_exported_ones() {
    let Some(dir) = tiny_sd15() else { return };
    let m = edited(&dir, |v| {
        v["text"].as_object_mut().unwrap().remove("encoder");
    });
    let e = OnnxPrior::open(
        m.path(),
        &PriorOptions {
            prompt: Some("a pencil drawing".into()),
            threads: 1,
            ..Default::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("no text encoder") && e.contains("a painting in the style"),
        "{e}"
    );
    // The exported prompt still works without the encoder: naming it selects its
    // stored embedding, the same one the model uses by default.
    let mut named = OnnxPrior::open(
        m.path(),
        &PriorOptions {
            prompt: Some("a painting in the style of the reference image".into()),
            threads: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let mut default = OnnxPrior::open(
        m.path(),
        &PriorOptions {
            threads: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let z = npy4(&dir, "z.npy");
    let ctrl = npy4(&dir, "control.npy");
    let a = named
        .predict_eps(
            z.view(),
            321,
            &[Cond::Prompt, Cond::Null],
            Some(ctrl.view()),
        )
        .unwrap();
    let b = default
        .predict_eps(z.view(), 321, &[Cond::Prompt], Some(ctrl.view()))
        .unwrap();
    assert_eq!(
        a[0], b[0],
        "the named exported prompt is not the stored one"
    );
    assert!(
        a[0] != a[1],
        "the prompt makes no difference to the prediction"
    );
}

#[test]
fn external_data_is_read_and_its_absence_named() {
    let Some(dir) = tiny_sd15() else { return };
    // The fixture keeps the UNet's and ControlNet's weights in ONNX external data.
    assert!(dir.join("unet.onnx.data").is_file() && dir.join("controlnet.onnx.data").is_file());
    let m = edited(&dir, |_| {});
    std::fs::remove_file(m.path().join("unet.onnx.data")).unwrap();
    let e = OnnxPrior::open(m.path(), &PriorOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("unet.onnx") && e.contains("graph `unet`"), "{e}");
}

#[test]
fn device_without_gpu_library_is_a_clear_error() {
    let Some(dir) = tiny_sd15() else { return };
    for (device, name) in [
        (Device::Cuda(0), "CUDAExecutionProvider"),
        (Device::TensorRt(0), "TensorrtExecutionProvider"),
    ] {
        let e = OnnxPrior::open(
            &dir,
            &PriorOptions {
                device,
                ..Default::default()
            },
        )
        .unwrap_err();
        let msg = e.to_string();
        eprintln!("--device {device}: {msg}");
        // This machine's onnxruntime is the CPU build: the provider is missing from it.
        assert_eq!(e.exit_code(), 3, "{msg}");
        assert!(
            msg.contains(name)
                && msg.contains("FANTASYSTYLE_ORT_LIB")
                && msg.contains("--device cpu"),
            "{msg}"
        );
    }
    assert_eq!("cuda:1".parse::<Device>(), Ok(Device::Cuda(1)));
    assert_eq!("tensorrt".parse::<Device>(), Ok(Device::TensorRt(0)));
    assert!(
        "gpu"
            .parse::<Device>()
            .unwrap_err()
            .contains("cpu, cuda[:N]")
    );
    // The stage flag: exit code 3, the message, nothing written.
    let t = tempfile::tempdir().unwrap();
    let views = t.path().join("views");
    let n = 64 * 64;
    crate::harness::write_views(
        &views,
        [1, 64, 64],
        &vec![0.5; 3 * n],
        &vec![1.0; n],
        &vec![1.0; n],
        b"[]",
    );
    let out = t.path().join("lat");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_encode-latents"))
        .arg("--views")
        .arg(&views)
        .arg("--model")
        .arg(&dir)
        .args(["--device", "cuda", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("CUDAExecutionProvider"), "{err}");
    assert!(!out.exists());
}

#[test]
fn csd_step_stage_runs_the_fixture_and_refuses_shared_conditioning() {
    let Some(dir) = tiny_sd15() else { return };
    let d = tempfile::tempdir().unwrap();
    // Two 64x64 views and a 64x64 style image (the smallest csd-step accepts).
    let views = Array4::from_shape_fn((2, 3, 64, 64), |(v, c, y, x)| {
        0.5 + 0.4 * (((x + 2 * y + 7 * c) as f32) * 0.1 + v as f32).sin()
    });
    let style = Array4::from_shape_fn((1, 3, 64, 64), |(_, c, y, x)| {
        ((x * 3 + y * (c + 1)) % 17) as f32 / 16.0
    });
    let sp = crate::mvfc::csd_inputs(d.path(), &dir, &views, &style);
    // The routed model, a run-time prompt, the term csd: targets written.
    let mut a = crate::mvfc::step_args(d.path(), &dir, &sp, Mode::Csd);
    a.prior.prompt = Some("an ink drawing of a stone bridge".into());
    let lr = 0.05; // step_args' csd.lr
    let rep = fantasystyle::stages::csd_step::run(a).unwrap();
    // z0' - z0 = -lr w g exactly: the two reported RMS agree, and the step is not nil.
    assert!(rep.grad_rms > 1e-4, "{rep:?}");
    assert!(
        (rep.latent_step_rms - lr * rep.grad_rms).abs() <= 1e-3 * lr * rep.grad_rms,
        "{rep:?}"
    );
    // The run-time prompt reaches the gradient: another prompt, other targets.
    let mut b = crate::mvfc::step_args(d.path(), &dir, &sp, Mode::Csd);
    b.prior.prompt = Some("a watercolour of a lighthouse".into());
    b.out = d.path().join("targets-other-prompt");
    let rep_b = fantasystyle::stages::csd_step::run(b).unwrap();
    assert!(
        (rep_b.grad_rms - rep.grad_rms).abs() > 1e-6 * rep.grad_rms,
        "the prompt changed nothing: {rep:?} {rep_b:?}"
    );
    // Plain IP-Adapter routing: the term csd refused (exit code 2 from the binary),
    // csd-no-neg accepted.
    let shared = shared_copy(&dir);
    let mut a = crate::mvfc::step_args(d.path(), shared.path(), &sp, Mode::Csd);
    a.out = d.path().join("refused");
    let e = fantasystyle::stages::csd_step::run(a.clone()).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("term csd-no-neg"), "{e}");
    assert!(!a.out.exists());
    a.config.sets.push("terms=csd-no-neg=1".into());
    fantasystyle::stages::csd_step::run(a).unwrap();
}

/// Run a stage binary, returning (exit code, stderr).
fn run_bin(exe: &str, args: &[&std::ffi::OsStr]) -> (Option<i32>, String) {
    let o = std::process::Command::new(exe).args(args).output().unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The whole loop (`distill`) on the sample scene with the fixture: its depth ControlNet
/// (the fixture's UNet takes the ControlNet's residuals as required inputs, so a run is a
/// run through the ControlNet), a run-time prompt through the tokenizer and the text
/// encoder, the term csd; the prompt changes the result; a copy with plain IP-Adapter
/// conditioning is refused under csd before anything is written and accepted under
/// csd-no-neg. Two iterations on two 64x64 views (8x8 latents): a few
/// seconds.
#[test]
fn distill_runs_the_fixture_end_to_end_with_a_runtime_prompt() {
    let Some(dir) = tiny_sd15() else { return };
    let t = tempfile::tempdir().unwrap();
    let d = t.path();
    let scene = repo_root().join("data-sample/scene.ply");
    let style = repo_root().join("data-sample/style.png");
    let views = d.join("views");
    let (rc, err) = run_bin(
        env!("CARGO_BIN_EXE_render-views"),
        &[
            "--scene".as_ref(),
            scene.as_os_str(),
            "--cameras".as_ref(),
            "orbit:4,elev=30,radius=2.4".as_ref(),
            "--width".as_ref(),
            "64".as_ref(),
            "--height".as_ref(),
            "64".as_ref(),
            "--out".as_ref(),
            views.as_os_str(),
        ],
    );
    assert_eq!(rc, Some(0), "{err}");
    let distill = |model: &Path, out: &Path, extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "--scene".as_ref(),
            scene.as_os_str(),
            "--source-views".as_ref(),
            views.as_os_str(),
            "--model".as_ref(),
            model.as_os_str(),
            "--style".as_ref(),
            style.as_os_str(),
            "--iters".as_ref(),
            "2".as_ref(),
            "--set".as_ref(),
            "views=2".as_ref(),
            "--threads".as_ref(),
            "2".as_ref(),
            "--out".as_ref(),
            out.as_os_str(),
        ];
        args.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
        run_bin(env!("CARGO_BIN_EXE_distill"), &args)
    };
    let prompt = "an ink drawing of a stone bridge";
    let started = std::time::Instant::now();
    let (rc, err) = distill(&dir, &d.join("a"), &["--prompt", prompt, "--terms", "csd"]);
    eprintln!(
        "distill, 2 iterations on the fixture: {:.2} s\n{err}",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(rc, Some(0), "{err}");
    // The cost estimate was said before the run and calibrated after its first iteration.
    assert!(
        err.contains("on this machine (from the graphs' size") && err.contains("iteration 0 took"),
        "{err}"
    );
    let a = d.join("a");
    let hist: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(a.join("history.json")).unwrap()).unwrap();
    assert_eq!(hist.len(), 2);
    assert!(hist.iter().all(|r| r["loss"].as_f64().unwrap().is_finite()));
    let z0 = fantasystyle_schemas::read_npy_f32(&a.join("last_z0.npy")).unwrap();
    assert_eq!(z0.shape, [2, 4, 8, 8]);
    let targets = fantasystyle_schemas::read_npy_f32(&a.join("last_targets.npy")).unwrap();
    assert!(targets.data.iter().all(|v| v.is_finite()));
    // The colours moved, and the prompt is part of what moved them.
    let input = fantasystyle::artifacts::load_scene(&scene).unwrap();
    let out = fantasystyle::artifacts::load_scene(&a).unwrap();
    let moved = input
        .sh_dc
        .iter()
        .flatten()
        .zip(out.sh_dc.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    // Two Adam steps of lr_dc = 0.05 (the default): each moves a colour by at most
    // lr (1 + 1.3e-3) (|m^ / sqrt(v^)| <= 1.0013 at t <= 2), and a colour with a
    // gradient moves by lr at the first step.
    let lr = 0.05f32;
    assert!(
        (0.5 * lr..=2.0 * 1.0014 * lr).contains(&moved),
        "largest colour change {moved}, Adam with lr {lr} over 2 steps"
    );
    let (rc, err) = distill(&dir, &d.join("b"), &["--terms", "csd"]);
    assert_eq!(rc, Some(0), "{err}");
    assert_ne!(
        std::fs::read(a.join("scene.ply")).unwrap(),
        std::fs::read(d.join("b/scene.ply")).unwrap(),
        "the run-time prompt changed nothing"
    );
    // Plain IP-Adapter conditioning: csd refused (exit code 2, nothing written),
    // csd-no-neg runs.
    let shared = shared_copy(&dir);
    let refused = d.join("refused");
    let (rc, err) = distill(shared.path(), &refused, &["--terms", "csd"]);
    assert_eq!(rc, Some(2), "{err}");
    assert!(
        err.contains("term csd-no-neg") && err.contains("sds") && err.contains("shared"),
        "{err}"
    );
    assert!(!refused.exists());
    let (rc, err) = distill(shared.path(), &refused, &["--terms", "csd-no-neg"]);
    assert_eq!(rc, Some(0), "{err}");
}

/// The sample DAG (`data-sample/stylize.toml`) with the fixture as its model
/// (`--set model=...`) and a run-time prompt (`--set prompt=...`), end to end: source
/// views, one distill chunk of two iterations through the ControlNet, the final splat,
/// its renders and the evaluation (64x64, four views: seconds).
#[test]
fn sample_dag_runs_with_the_fixture_as_its_model() {
    let Some(dir) = tiny_sd15() else { return };
    let pipeline = crate::harness::pipeline_bin();
    let t = tempfile::tempdir().unwrap();
    let dag = repo_root().join("data-sample/stylize.toml");
    let prompt = "an ink drawing of a stone bridge";
    let o = std::process::Command::new(&pipeline)
        .arg("run")
        .arg("--dag")
        .arg(&dag)
        .args(["--workdir", "w", "--set"])
        .arg(format!("model={}", dir.display()))
        .args(["--set", &format!("prompt={prompt}")])
        .args(["--set", "render.width=64", "--set", "render.height=64"])
        .args(["--set", "cameras=orbit:4", "--set", "distill.chunks=1"])
        .args(["--set", "distill.chunk=2", "--set", "distill.loop.views=2"])
        .current_dir(t.path())
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        out.contains("result  scene    w/runs/final/scene.ply"),
        "{out}"
    );
    let w = t.path().join("w");
    let log = std::fs::read_to_string(w.join(".pipeline/logs/distill@c1.log")).unwrap();
    assert!(log.contains(&format!("--prompt '{prompt}'")), "{log}");
    let c1 = std::fs::read_to_string(w.join("runs/c1/manifest.json")).unwrap();
    assert!(c1.contains(prompt) && c1.contains("tiny-sd15"), "{c1}");
    let h: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(w.join("runs/c1/history.json")).unwrap()).unwrap();
    assert_eq!(h.len(), 2);
    // The second window of two views on a 4-view orbit: neighbours always overlap.
    assert!(h[1]["hf_agree_adjacent"].is_number(), "{:?}", h[1]);
    let report = std::fs::read_to_string(w.join("runs/eval/report.html")).unwrap();
    assert!(report.contains("high-frequency change agreement"));
}

//! Baselines: VGG16 against the numpy reference, and the baseline stage end to end.

use crate::harness::repo_root;
use fantasystyle::vgg::{Layer, Vgg16};
use std::path::Path;

/// `vgg` on the Rust engine, and on onnxruntime when the library is there
/// ([`crate::harness::onnxruntime`]: required under CI).
fn engines(vgg: Vgg16) -> Vec<Vgg16> {
    let mut v = vec![vgg.clone()];
    if crate::harness::onnxruntime() {
        v.push(vgg.on_onnxruntime(0).unwrap());
    }
    v
}

/// max |a - b| and max |b|.
fn max_err(a: &[f32], b: &[f32]) -> (f32, f32) {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
    let err = a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
    (err, scale)
}

/// Compare our VGG16 forward, on both engines, with `scripts/reference/vgg_ref.py`'s
/// output in `golden` (float64 direct convolution). Tolerance: max |ours - ref| <= 1e-4 *
/// max |ref| per tap. `tests/golden/vgg` is committed bytes, on purpose: a network, but
/// evaluated in float64 numpy (narrow weights), so the same on every CPU to float64
/// rounding, far below 1e-4 relative; the real weights' golden is made by set-up on the
/// machine that runs the test (`scripts/setup/35_vgg_golden.sh`).
fn check_golden(weights: &Path, golden: &Path) {
    for vgg in engines(Vgg16::load(weights).unwrap()) {
        check_golden_with(&vgg, golden);
    }
}

fn check_golden_with(vgg: &Vgg16, golden: &Path) {
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
            "{} (onnxruntime: {}): max err {err}, scale {scale}",
            l.name(),
            vgg.onnxruntime_threads().is_some()
        );
    }
}

/// The onnxruntime engine's forward activations and input gradient against the Rust
/// engine's (itself checked against finite differences and the f64 golden), on an odd-sized
/// image (floor pooling drops a row and a column) with gradients at five layers, one of
/// them given twice; and with one tap. Tolerance: 1e-4 x the largest magnitude.
#[test]
fn vgg_on_onnxruntime_matches_the_rust_engine() {
    if !crate::harness::onnxruntime() {
        return;
    }
    let rust = Vgg16::random(3, 8);
    let ort = rust.clone().on_onnxruntime(0).unwrap();
    let (h, w) = (37, 29);
    let mut r = fantasystyle::rng::Rng::new(9);
    let img: Vec<f32> = (0..h * w * 3).map(|_| r.uniform() as f32).collect();
    let fr = rust.forward(&img, h, w, Layer::Relu4_3).unwrap();
    let fo = ort.forward(&img, h, w, Layer::Relu4_3).unwrap();
    for (i, (a, b)) in fo.acts.iter().zip(&fr.acts).enumerate() {
        assert_eq!((a.c, a.h, a.w), (b.c, b.h, b.w), "layer {i}");
        let (err, scale) = max_err(&a.data, &b.data);
        assert!(
            err <= 1e-4 * scale,
            "layer {i}: forward err {err}, scale {scale}"
        );
    }
    let grad = |l: Layer, r: &mut fantasystyle::rng::Rng| {
        let a = fr.get(l);
        let mut g = fantasystyle::vgg::Tensor3::zeros(a.c, a.h, a.w);
        g.data.iter_mut().for_each(|v| *v = r.normal() as f32);
        g
    };
    let taps = [
        Layer::Relu1_2,
        Layer::Relu2_2,
        Layer::Relu2_2,
        Layer::Relu3_1,
        Layer::Relu3_3,
        Layer::Relu4_3,
    ];
    let gs: Vec<_> = taps.iter().map(|&l| (l, grad(l, &mut r))).collect();
    let refs: Vec<_> = gs.iter().map(|(l, g)| (*l, g)).collect();
    for refs in [&refs[..], &refs[1..2]] {
        let gr = rust.backward(&fr, refs).unwrap();
        // The onnxruntime engine's own forward, as a caller would pass it.
        let go = ort.backward(&fo, refs).unwrap();
        let (err, scale) = max_err(&go, &gr);
        assert!(
            err <= 1e-4 * scale && scale > 0.0,
            "{} taps: backward err {err}, scale {scale}",
            refs.len()
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
    let Some(g) = crate::harness::model_file("lpips/vgg16-golden", "relu4_3.npy") else {
        return;
    };
    let g = g.parent().unwrap();
    let w = g.parent().unwrap().join("vgg16");
    check_golden(&w, g);
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

mod stage {
    use crate::harness::repo_root;
    use fantasystyle::stages::stylize_baseline::{Args, Method, run};
    use fantasystyle::stages::{Background, SceneInput, Threads};
    use std::path::{Path, PathBuf};

    /// Real VGG16 weights when set-up has made them, else the golden test's narrow
    /// random-weight network (same topology), so the test always runs.
    fn vgg_dir() -> PathBuf {
        let real = repo_root().join("vendor/models/lpips/vgg16");
        if real.join("conv9_weight.npy").is_file() {
            real
        } else {
            eprintln!("NOTE: real VGG16 weights absent; using tests/golden/vgg");
            repo_root().join("tests/golden/vgg")
        }
    }

    fn args(method: Method, out: &Path, style: &Path, steps: usize) -> Args {
        Args {
            method,
            input: SceneInput {
                scene: repo_root().join("data-sample/scene.ply"),
                cameras: "orbit:2".into(),
            },
            style: style.to_path_buf(),
            steps,
            views_per_step: 0,
            seed: 0,
            budget_s: None,
            budget_from: None,
            save_at: Vec::new(),
            record_time: false,
            out: out.to_path_buf(),
            width: 48,
            height: 48,
            background: Background { rgb: [0.0; 3] },
            lr_dc: 0.03,
            lr_rest: 0.001,
            style_size: 128,
            style_weight: 1.0,
            content_weight: None,
            monitor_every: steps,
            no_monitor: false,
            vgg: Some(vgg_dir()),
            stylizer: Some(repo_root().join("vendor/models/stylizer")),
            threads: Threads::new(2),
        }
    }

    fn sample_style() -> PathBuf {
        repo_root().join("data-sample/style.png")
    }

    /// Each baseline lowers the Gram distance to the style on the sample scene (48x48,
    /// two orbit views, a few steps), and geometry stays bit-identical.
    fn check_method(method: Method, steps: usize) {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("out");
        run(args(method, &out, &sample_style(), steps)).unwrap();
        let log: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("loss.json")).unwrap()).unwrap();
        let steps_log = log["steps"].as_array().unwrap();
        assert_eq!(steps_log.len(), steps + 1);
        let first = steps_log[0]["gram_distance"].as_f64().unwrap();
        let last = steps_log[steps]["gram_distance"].as_f64().unwrap();
        eprintln!(
            "{method:?}: Gram distance {first} -> {last} (targets: {}, agreement {})",
            log["targets_gram_distance"], log["hf_agree_adjacent"]
        );
        if method != Method::Refit {
            assert!(
                log.get("hf_agree_adjacent").is_none(),
                "only refit has targets"
            );
        }
        eprintln!(
            "totals: {:?}",
            steps_log
                .iter()
                .map(|s| s["total"].as_f64().unwrap())
                .collect::<Vec<_>>()
        );
        assert!(last < first, "{method:?}: Gram distance {first} -> {last}");
        let before =
            fantasystyle::artifacts::load_scene(&repo_root().join("data-sample/scene.ply"))
                .unwrap();
        let after = fantasystyle::artifacts::load_scene(&out.join("scene.ply")).unwrap();
        let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&before.positions), bits(&after.positions));
        assert_eq!(bits(&before.log_scales), bits(&after.log_scales));
        let q = |s: &fantasystyle::Scene| {
            s.rotations
                .iter()
                .flatten()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(q(&before), q(&after));
        let o = |s: &fantasystyle::Scene| {
            s.opacity_logits
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(o(&before), o(&after));
        assert_ne!(before.sh_dc, after.sh_dc, "colours did not change");
    }

    #[test]
    fn gram_lowers_gram_distance_geometry_frozen() {
        check_method(Method::Gram, 6);
    }

    #[test]
    fn nnfm_lowers_gram_distance_geometry_frozen() {
        check_method(Method::Nnfm, 6);
    }

    #[test]
    fn refit_lowers_gram_distance_geometry_frozen() {
        if crate::harness::model("stylizer").is_none() {
            return;
        }
        check_method(Method::Refit, 150);
    }

    /// A baseline on the `split` stage's output: it optimises the split scene's colours
    /// (more Gaussians in the result, the Gram distance still falls); the split stage
    /// records what it did in its meta.
    #[test]
    fn a_baseline_stylizes_the_split_scene() {
        use clap::Parser;
        use fantasystyle::stages::{render_views, split};
        let d = tempfile::tempdir().unwrap();
        let scene = repo_root().join("data-sample/scene.ply");
        let views = d.path().join("views");
        let (s, v) = (scene.display(), views.display());
        let cmd = format!("rv --scene {s} --cameras orbit:2 --width 48 --height 48 --out {v}");
        render_views::run(render_views::Args::parse_from(cmd.split(' '))).unwrap();
        let split_dir = d.path().join("split");
        let cmd = format!(
            "split --scene {s} --source-views {v} --set split=0.25 --out {}",
            split_dir.display()
        );
        let report = split::run(split::Args::parse_from(cmd.split(' '))).unwrap();
        let report = report.expect("a split was asked for");
        let out = d.path().join("out");
        let mut a = args(Method::Gram, &out, &sample_style(), 3);
        a.input.scene = split_dir.clone();
        run(a).unwrap();
        let before = fantasystyle::artifacts::load_scene(&scene).unwrap();
        let after = fantasystyle::artifacts::load_scene(&out.join("scene.ply")).unwrap();
        assert!(
            after.len() > before.len() && after.len() == report.after,
            "{} -> {} ({report})",
            before.len(),
            after.len()
        );
        let log: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("loss.json")).unwrap()).unwrap();
        let steps = log["steps"].as_array().unwrap();
        let gram = |i: usize| steps[i]["gram_distance"].as_f64().unwrap();
        assert!(
            gram(3) < gram(0),
            "Gram distance {} -> {}",
            gram(0),
            gram(3)
        );
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(split_dir.join("manifest.json")).unwrap())
                .unwrap();
        assert_eq!(m["meta"]["after"], serde_json::json!(report.after));
        // split = 0 (the default): the scene as it is.
        let plain = d.path().join("plain");
        let cmd = format!(
            "split --scene {s} --source-views {v} --out {}",
            plain.display()
        );
        assert!(
            split::run(split::Args::parse_from(cmd.split(' ')))
                .unwrap()
                .is_none()
        );
        assert_eq!(
            fantasystyle::artifacts::load_scene(&plain).unwrap(),
            before,
            "split = 0 changed the scene"
        );
    }

    fn write_png(path: &Path, w: u32, h: u32, channels: u8) {
        let n = (w * h) as usize;
        let px = |i: usize| ((i * 37) % 251) as u8;
        match channels {
            1 => image::GrayImage::from_raw(w, h, (0..n).map(px).collect())
                .unwrap()
                .save(path),
            4 => image::RgbaImage::from_raw(w, h, (0..n * 4).map(px).collect())
                .unwrap()
                .save(path),
            _ => image::RgbImage::from_raw(w, h, (0..n * 3).map(px).collect())
                .unwrap()
                .save(path),
        }
        .unwrap();
    }

    /// Without the onnxruntime library the VGG baselines run on the Rust engine (the same
    /// passes, slower) with a warning saying why, instead of failing. A subprocess: the
    /// onnxruntime environment is per process.
    #[test]
    fn gram_baseline_falls_back_to_the_rust_vgg_without_onnxruntime() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("out");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_stylize-baseline"))
            .env("FANTASYSTYLE_ORT_LIB", d.path().join("no-such-library.so"))
            .arg("--method=gram")
            .arg("--scene")
            .arg(repo_root().join("data-sample/scene.ply"))
            .args([
                "--cameras=orbit:2",
                "--steps=1",
                "--width=48",
                "--height=48",
            ])
            .args(["--style-size=128", "--threads=2"])
            .arg("--style")
            .arg(sample_style())
            .arg("--vgg")
            .arg(vgg_dir())
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{err}");
        assert!(
            err.contains("Rust engine") && err.contains("no-such-library.so"),
            "{err}"
        );
        assert!(out.join("scene.ply").is_file());
    }

    /// A style image below relu4_3's receptive field (92 px) is refused with exit code 2,
    /// naming the file; nothing is written.
    #[test]
    fn tiny_style_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let style = d.path().join("tiny.png");
        write_png(&style, 91, 200, 3);
        let out = d.path().join("out");
        let e = run(args(Method::Gram, &out, &style, 1)).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        let msg = e.to_string();
        assert!(msg.contains("tiny.png") && msg.contains("92"), "{msg}");
        assert!(!out.exists());
    }

    /// Grayscale (expanded to RGB) and RGBA (alpha dropped) style images are accepted.
    #[test]
    fn grayscale_and_rgba_styles_are_accepted() {
        let d = tempfile::tempdir().unwrap();
        for ch in [1u8, 4] {
            let style = d.path().join(format!("s{ch}.png"));
            write_png(&style, 100, 96, ch);
            let out = d.path().join(format!("out{ch}"));
            run(args(Method::Gram, &out, &style, 1)).unwrap();
            assert!(out.join("scene.ply").is_file());
        }
    }

    /// An empty camera set is a clear error (exit code 2), nothing written.
    #[test]
    fn empty_view_set_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let cams = d.path().join("cameras.json");
        std::fs::write(&cams, "[]").unwrap();
        let out = d.path().join("out");
        let mut a = args(Method::Nnfm, &out, &sample_style(), 1);
        a.input.cameras = cams.to_string_lossy().into_owned();
        let e = run(a).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(e.to_string().contains("cameras.json"), "{e}");
        assert!(!out.exists());
    }

    /// One rule for the models (`fantasystyle::models`): started from another directory,
    /// the binary finds `vendor/models` above itself (the `--vgg` default no longer
    /// depends on the current directory); `FANTASYSTYLE_MODELS` overrides the search.
    #[test]
    fn models_are_found_from_any_directory_and_the_env_var_wins() {
        if crate::harness::model_file("lpips/vgg16", "conv9_weight.npy").is_none() {
            return;
        }
        let bin = env!("CARGO_BIN_EXE_stylize-baseline");
        let d = tempfile::tempdir().unwrap();
        let run = |models: Option<&Path>, out: &str| {
            let mut c = std::process::Command::new(bin);
            c.current_dir(d.path())
                .env_remove("FANTASYSTYLE_MODELS")
                .args(["--method", "gram", "--cameras", "orbit:1", "--steps", "1"])
                .args(["--width", "16", "--height", "16", "--style-size", "92"])
                .arg("--scene")
                .arg(repo_root().join("data-sample/scene.ply"))
                .arg("--style")
                .arg(sample_style())
                .args(["--out", out, "--threads", "1"]);
            if let Some(m) = models {
                c.env("FANTASYSTYLE_MODELS", m);
            }
            c.output().unwrap()
        };
        let ok = run(None, "o1");
        assert!(
            ok.status.success(),
            "{}",
            String::from_utf8_lossy(&ok.stderr)
        );
        assert!(d.path().join("o1/scene.ply").is_file());
        let elsewhere = d.path().join("no-models-here");
        let bad = run(Some(&elsewhere), "o2");
        assert_eq!(bad.status.code(), Some(3));
        let err = String::from_utf8_lossy(&bad.stderr);
        assert!(err.contains("no-models-here/lpips/vgg16"), "{err}");
        assert!(!d.path().join("o2").exists());
    }

    /// Through the binary: `-h` documents every flag; a bad style exits 2 naming the file.
    #[test]
    fn binary_help_and_exit_code() {
        let bin = env!("CARGO_BIN_EXE_stylize-baseline");
        let out = std::process::Command::new(bin).arg("-h").output().unwrap();
        let help = String::from_utf8_lossy(&out.stdout);
        for f in [
            "--method",
            "--scene",
            "--cameras",
            "--style",
            "--steps",
            "--out",
            "--width",
            "--height",
            "--background",
            "--lr-dc",
            "--lr-rest",
            "--style-size",
            "--style-weight",
            "--content-weight",
            "--monitor-every",
            "--no-monitor",
            "--views-per-step",
            "--budget-s",
            "--budget-from",
            "--save-at",
            "--record-time",
            "--vgg",
            "--stylizer",
            "--threads",
        ] {
            assert!(help.contains(f), "help lacks {f}:\n{help}");
        }
        let d = tempfile::tempdir().unwrap();
        let style = d.path().join("gray.png");
        write_png(&style, 50, 50, 1);
        let scene = repo_root().join("data-sample/scene.ply");
        let out = std::process::Command::new(bin)
            .args(["--method", "gram", "--cameras", "orbit:1", "--steps", "1"])
            .arg("--scene")
            .arg(&scene)
            .arg("--style")
            .arg(&style)
            .arg("--out")
            .arg(d.path().join("o"))
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("gray.png") && err.contains("92 px"), "{err}");
    }

    fn ply_bytes(p: &Path) -> Vec<u8> {
        std::fs::read(p).unwrap()
    }

    /// A time budget stops after the step during which it runs out and records the
    /// steps done; that many steps without a budget give the same scene, bit for bit,
    /// and so does a checkpoint saved at an earlier step (one view per step, seeded).
    #[test]
    fn budget_and_checkpoints_reproduce_fixed_step_runs() {
        let d = tempfile::tempdir().unwrap();
        let sub = |name: &str, steps: usize| {
            let mut a = args(Method::Gram, &d.path().join(name), &sample_style(), steps);
            a.views_per_step = 1;
            a.seed = 3;
            a.no_monitor = true;
            a
        };
        // A budget far below one step's time: exactly one step.
        let mut a = sub("budget", 50);
        a.budget_s = Some(1e-3);
        run(a).unwrap();
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.path().join("budget/timing.json")).unwrap())
                .unwrap();
        assert_eq!(t["steps_done"], 1, "{t}");
        assert!(t["wall_s"].as_f64().unwrap() >= t["setup_s"].as_f64().unwrap());
        let log: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.path().join("budget/loss.json")).unwrap())
                .unwrap();
        assert_eq!(log["steps"].as_array().unwrap().len(), 1, "{log}");
        // The same one step without a budget; three steps saving after 1 and 2; two steps.
        run(sub("one", 1)).unwrap();
        let mut a = sub("three", 3);
        a.save_at = vec![1, 2];
        a.record_time = true;
        run(a).unwrap();
        run(sub("two", 2)).unwrap();
        let one = ply_bytes(&d.path().join("one/scene.ply"));
        assert_eq!(ply_bytes(&d.path().join("budget/scene.ply")), one);
        assert_eq!(ply_bytes(&d.path().join("three/scene_step1.ply")), one);
        let two = ply_bytes(&d.path().join("two/scene.ply"));
        assert_eq!(ply_bytes(&d.path().join("three/scene_step2.ply")), two);
        assert_ne!(one, two);
        assert_ne!(ply_bytes(&d.path().join("three/scene.ply")), two);
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(d.path().join("three/timing.json")).unwrap())
                .unwrap();
        let cps = t["checkpoints"].as_array().unwrap();
        assert_eq!(cps.len(), 2);
        assert!(cps[1]["elapsed_s"].as_f64() >= cps[0]["elapsed_s"].as_f64());
        // No timing without a budget or --record-time (the bytes stay machine-independent).
        assert!(!d.path().join("two/timing.json").exists());
        // A budget file without `budget_s` is a clear error naming it.
        let bad = d.path().join("budget.json");
        std::fs::write(&bad, "{\"seconds\": 3}").unwrap();
        let mut a = sub("bad", 2);
        a.budget_from = Some(bad);
        let e = run(a).unwrap_err();
        assert_eq!(e.exit_code(), 2, "{e}");
        assert!(e.to_string().contains("budget.json"), "{e}");
    }

    /// Un-premultiplied colour statistics of the object over covered pixels (alpha > 0.5),
    /// computed here directly from the renders.
    fn object_stats(
        scene: &fantasystyle::Scene,
        cams: &[fantasystyle::Camera],
    ) -> ([f64; 3], [f64; 9]) {
        let mut px = Vec::new();
        for c in cams {
            let r = fantasystyle::render::render(scene, c, &Default::default()).unwrap();
            for (p, &a) in r.alpha.iter().enumerate() {
                if a > 0.5 {
                    px.push([0, 1, 2].map(|k| r.rgb[p * 3 + k] as f64 / a as f64));
                }
            }
        }
        let n = px.len() as f64;
        let mut mu = [0.0; 3];
        px.iter()
            .for_each(|p| (0..3).for_each(|k| mu[k] += p[k] / n));
        let mut cov = [0.0; 9];
        for p in &px {
            for i in 0..3 {
                for j in 0..3 {
                    cov[i * 3 + j] += (p[i] - mu[i]) * (p[j] - mu[j]) / n;
                }
            }
        }
        (mu, cov)
    }

    /// colour-transfer: seconds, geometry untouched, and the object's colour statistics
    /// in fresh renders move onto the style image's (the sample's style: mean 0.075 -> 0.005
    /// away, covariance 86% -> 3% of the style's norm when written; tested at 0.015 and
    /// 10%: the residue is the renderer's clamp of negative colours and the alpha > 0.5 cut).
    #[test]
    fn colour_transfer_moves_object_statistics_onto_the_style() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("ct");
        let mut a = args(Method::ColourTransfer, &out, &sample_style(), 0);
        a.input.cameras = "orbit:6".into();
        a.vgg = Some(d.path().join("no-vgg-needed"));
        run(a).unwrap();
        let before =
            fantasystyle::artifacts::load_scene(&repo_root().join("data-sample/scene.ply"))
                .unwrap();
        let after = fantasystyle::artifacts::load_scene(&out.join("scene.ply")).unwrap();
        assert_eq!(before.positions, after.positions);
        assert_eq!(before.opacity_logits, after.opacity_logits);
        let cams = fantasystyle::camera::load_cameras("orbit:6", &before.bounds(), 48, 48).unwrap();
        let style = fantasystyle::imageio::read_rgb(&sample_style()).unwrap();
        let n = (style.width * style.height) as f64;
        let mut smu = [0.0; 3];
        style
            .data
            .chunks(3)
            .for_each(|p| (0..3).for_each(|k| smu[k] += p[k] as f64 / n));
        let mut scov = [0.0; 9];
        for p in style.data.chunks(3) {
            for i in 0..3 {
                for j in 0..3 {
                    scov[i * 3 + j] += (p[i] as f64 - smu[i]) * (p[j] as f64 - smu[j]) / n;
                }
            }
        }
        let dist = |(mu, cov): ([f64; 3], [f64; 9])| {
            let dm = (0..3).map(|k| (mu[k] - smu[k]).powi(2)).sum::<f64>().sqrt();
            let dc = (0..9)
                .map(|k| (cov[k] - scov[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            (dm, dc)
        };
        let norm = scov.iter().map(|v| v * v).sum::<f64>().sqrt();
        let (m0, c0) = dist(object_stats(&before, &cams));
        let (m1, c1) = dist(object_stats(&after, &cams));
        eprintln!(
            "colour transfer: mean distance {m0:.4} -> {m1:.4}, covariance {c0:.5} -> {c1:.5} (style cov norm {norm:.5})"
        );
        assert!(m1 < 0.015 && m0 > 3.0 * m1, "mean {m0} -> {m1}");
        assert!(
            c1 < 0.1 * norm && c0 > 3.0 * c1,
            "cov {c0} -> {c1} (norm {norm})"
        );
        let log: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("loss.json")).unwrap()).unwrap();
        assert_eq!(log["method"], "colour-transfer");
        assert_eq!(log["colour_map"]["t"].as_array().unwrap().len(), 9);
    }

    /// The surface normals on real splats: on a mesh-derived one (fish_10k, discs with
    /// scales 4:4:1 laid on the mesh's surface, so each Gaussian's thin axis is the mesh's
    /// normal) the normals from the renders' depth agree with the Gaussians' own axes
    /// (mean |cos| over the seen Gaussians above 0.9; 0.96 at the benchmark's 16 views at
    /// 256 px); on a trained capture (plant) they do not (below 0.75; 0.63 measured, 0.5
    /// for unrelated directions): there the own axis is a poor normal, which is why the
    /// projection takes the surface's.
    #[test]
    fn surface_normals_agree_with_a_mesh_derived_splats_axes() {
        use fantasystyle::transfer::projection::rendered_normals;
        let mut agreement = Vec::new();
        for name in ["fish_10k.splat", "plant.splat"] {
            let Some(path) = crate::harness::shared_scene(name) else {
                return;
            };
            let scene = fantasystyle::artifacts::load_scene(&path).unwrap();
            let cams =
                fantasystyle::camera::load_cameras("orbit:8", &scene.bounds(), 128, 128).unwrap();
            let n = rendered_normals(&scene, &cams).unwrap();
            eprintln!("{name}: {n}");
            assert!(n.seen * 2 > scene.len(), "{name}: {n}");
            agreement.push(n.axis_agreement);
        }
        assert!(agreement[0] > 0.9 && agreement[1] < 0.75, "{agreement:?}");
    }

    /// project: no network, geometry untouched, and the colours written are the style at
    /// `--style-size` projected from the cameras' placement along the normals of the
    /// scene's renders from them (the library's map; its own tests check the map), so the
    /// stage passes the resized style and the cameras on;
    /// a different `--style-size` gives different colours.
    #[test]
    fn project_writes_the_projected_style() {
        use fantasystyle::transfer::projection::{Placement, project_style, rendered_normals};
        let d = tempfile::tempdir().unwrap();
        let before =
            fantasystyle::artifacts::load_scene(&repo_root().join("data-sample/scene.ply"))
                .unwrap();
        let cams = fantasystyle::camera::load_cameras("orbit:2", &before.bounds(), 48, 48).unwrap();
        let raw = fantasystyle::imageio::read_rgb(&sample_style()).unwrap();
        let mut written = Vec::new();
        for size in [128, 256] {
            let out = d.path().join(format!("p{size}"));
            let mut a = args(Method::Project, &out, &sample_style(), 0);
            a.style_size = size;
            a.vgg = Some(d.path().join("no-vgg-needed"));
            run(a).unwrap();
            let after = fantasystyle::artifacts::load_scene(&out.join("scene.ply")).unwrap();
            assert_eq!(before.positions, after.positions);
            assert_eq!(before.log_scales, after.log_scales);
            assert_eq!(before.opacity_logits, after.opacity_logits);
            let want = project_style(
                &before,
                &raw.with_shorter_side(size),
                &Placement::of(&before, &cams).unwrap(),
                &rendered_normals(&before, &cams).unwrap().normals,
            );
            let err = want
                .sh_dc
                .iter()
                .zip(&after.sh_dc)
                .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
                .fold(0.0f32, f32::max);
            // The PLY stores f32: the same values.
            assert!(err < 1e-6, "style size {size}: max |dc - want| {err}");
            let log: serde_json::Value =
                serde_json::from_slice(&std::fs::read(out.join("loss.json")).unwrap()).unwrap();
            assert_eq!(log["method"], "project");
            written.push(after.sh_dc);
        }
        assert_ne!(written[0], written[1]);
    }
}

/// The NNFM search on onnxruntime (MatMul + ArgMax) against the Rust search: the same
/// loss and gradient on random features (with a coverage mask that leaves some positions
/// unsearched), where no two style columns are within float error of a tie.
/// Tolerance: loss 1e-5 relative, gradient 1e-4 x its largest magnitude.
#[test]
fn nnfm_search_on_onnxruntime_matches_the_rust_search() {
    use fantasystyle::terms::nnfm::{StyleColumns, nnfm_loss_grad};
    use ndarray::Array2;
    if !crate::harness::onnxruntime() {
        return;
    }
    let mut r = fantasystyle::rng::Rng::new(4);
    let (c, n, ns) = (48, 700, 530);
    let f = Array2::from_shape_fn((c, n), |_| r.normal().max(0.0) as f32);
    let mut s = Array2::from_shape_fn((c, ns), |_| r.normal().max(0.0) as f32 + 1e-3);
    for mut col in s.columns_mut() {
        let norm = col.iter().map(|v| v * v).sum::<f32>().sqrt();
        col.mapv_inplace(|v| v / norm);
    }
    let mask: Vec<f32> = (0..n).map(|i| [0.0, 0.5, 1.0][i % 3]).collect();
    let ort = StyleColumns::new(s.clone(), Some(0)).unwrap();
    for weights in [None, Some(&mask[..])] {
        let (lr, gr) = nnfm_loss_grad(f.view(), s.view(), weights, 0.7);
        let (lo, go) = ort.loss_grad(f.view(), weights, 0.7).unwrap();
        assert!((lr - lo).abs() <= 1e-5 * lr.abs(), "loss {lr} vs {lo}");
        let (err, scale) = max_err(go.as_slice().unwrap(), gr.as_slice().unwrap());
        assert!(
            err <= 1e-4 * scale && scale > 0.0,
            "gradient err {err}, scale {scale}"
        );
    }
}

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
        if !repo_root()
            .join("vendor/models/stylizer/model.json")
            .is_file()
        {
            eprintln!("SKIPPED: vendor/models/stylizer is absent (run scripts/setup.sh)");
            return;
        }
        check_method(Method::Refit, 150);
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
        if !repo_root()
            .join("vendor/models/lpips/vgg16/conv9_weight.npy")
            .is_file()
        {
            eprintln!("SKIPPED: vendor/models/lpips/vgg16 is absent (run scripts/setup.sh)");
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
}

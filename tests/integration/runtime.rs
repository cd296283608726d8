//! Diffusion runtime: the Gaussian prior's ONNX graphs against the Rust closed form,
//! manifest validation against real sessions, `encode-latents`.

use fantasystyle::prior::gaussian::{self, GaussianPrior};
use fantasystyle::prior::{Cond, OnnxPrior, Prior, PriorOptions};
use fantasystyle::rng::Rng;
use fantasystyle_schemas::{Artifact, ArtifactKind};
use ndarray::Array4;
use std::path::{Path, PathBuf};

/// The installed `gaussian-prior` model (made by scripts/setup.sh) and onnxruntime, or
/// `None` ([`crate::harness::need`]: a failure under CI).
fn gaussian_dir() -> Option<PathBuf> {
    if !crate::harness::onnxruntime() {
        return None;
    }
    crate::harness::model("gaussian-prior")
}

fn rand(shape: (usize, usize, usize, usize), seed: u64, scale: f32, offset: f32) -> Array4<f32> {
    let mut r = Rng::new(seed);
    Array4::from_shape_fn(shape, |_| offset + scale * r.uniform() as f32)
}

fn max_diff(a: &Array4<f32>, b: &Array4<f32>) -> f32 {
    assert_eq!(a.shape(), b.shape());
    a.iter()
        .zip(b.iter())
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max)
}

fn opts(style: Option<Array4<f32>>) -> PriorOptions {
    PriorOptions {
        style_image: style,
        threads: 1,
        ..Default::default()
    }
}

/// Copy the model directory to a temp dir, edit model.json with `f`.
fn edited(src: &Path, f: impl FnOnce(&mut serde_json::Value)) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, d.path().join(p.file_name().unwrap())).unwrap();
    }
    let mp = d.path().join("model.json");
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&mp).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&mp, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    d
}

#[test]
fn gaussian_onnx_graphs_agree_with_rust_closed_form() {
    let Some(dir) = gaussian_dir() else { return };
    let style = rand((1, 3, 48, 80), 1, 1.0, 0.0);
    let mut onnx = OnnxPrior::open(&dir, &opts(Some(style.clone()))).unwrap();
    let mut rust = GaussianPrior::with_default_text(Some(style.view())).unwrap();
    assert_eq!(onnx.info().latent_channels, 4);

    // VAE, batched.
    let img = rand((3, 3, 32, 48), 2, 1.0, 0.0);
    let (zo, zr) = (
        onnx.encode(img.view()).unwrap(),
        rust.encode(img.view()).unwrap(),
    );
    let e_enc = max_diff(&zo, &zr);
    let (xo, xr) = (
        onnx.decode(zo.view()).unwrap(),
        rust.decode(zo.view()).unwrap(),
    );
    let e_dec = max_diff(&xo, &xr);

    // eps under every conditioning, one batched call, across t.
    let z = rand((2, 4, 4, 6), 3, 4.0, -2.0);
    let conds = [Cond::Null, Cond::Prompt, Cond::PromptStyle, Cond::Content];
    let mut e_eps = 0f32;
    for t in [0usize, 1, 20, 500, 980, 999] {
        let eo = onnx.predict_eps(z.view(), t, &conds, None).unwrap();
        let er = rust.predict_eps(z.view(), t, &conds, None).unwrap();
        for (a, b) in eo.iter().zip(&er) {
            e_eps = e_eps.max(max_diff(a, b));
        }
        // The four conditionings really differ (the test would catch a mix-up).
        assert!(max_diff(&er[0], &er[2]) > 1e-3 && max_diff(&er[1], &er[2]) > 1e-3);
        assert!(max_diff(&er[0], &er[3]) > 1e-3);
    }
    eprintln!(
        "gaussian ONNX vs Rust max abs error: encode {e_enc:e}, decode {e_dec:e}, eps {e_eps:e}"
    );
    assert!(e_enc < 1e-5 && e_dec < 1e-5 && e_eps < 1e-5);
}

#[test]
fn batched_cfg_equals_separate_calls_and_v_prediction_converts() {
    let Some(dir) = gaussian_dir() else { return };
    let style = rand((1, 3, 64, 64), 4, 1.0, 0.0);
    let mut p = OnnxPrior::open(&dir, &opts(Some(style.clone()))).unwrap();
    let z = rand((3, 4, 5, 3), 5, 3.0, -1.5);
    let both = p
        .predict_eps(z.view(), 300, &[Cond::PromptStyle, Cond::Content], None)
        .unwrap();
    let a = p
        .predict_eps(z.view(), 300, &[Cond::PromptStyle], None)
        .unwrap();
    let b = p
        .predict_eps(z.view(), 300, &[Cond::Content], None)
        .unwrap();
    assert!(max_diff(&both[0], &a[0]) < 1e-6 && max_diff(&both[1], &b[0]) < 1e-6);

    // The same graph declared as v-prediction: eps = sqrt(1-ab) z + sqrt(ab) v.
    let vd = edited(&dir, |v| {
        v["scheduler"]["prediction_type"] = "v_prediction".into();
    });
    let mut pv = OnnxPrior::open(vd.path(), &opts(Some(style))).unwrap();
    let got = pv
        .predict_eps(z.view(), 300, &[Cond::PromptStyle], None)
        .unwrap();
    let want = p.schedule().eps_from_v(z.view(), a[0].view(), 300).unwrap();
    assert!(max_diff(&got[0], &want) < 1e-6);

    // Without a style image: Null/Prompt work, the image conditionings are clear errors.
    let mut q = OnnxPrior::open(&dir, &opts(None)).unwrap();
    let n = q.predict_eps(z.view(), 10, &[Cond::Null], None).unwrap();
    let n2 = p.predict_eps(z.view(), 10, &[Cond::Null], None).unwrap();
    assert!(max_diff(&n[0], &n2[0]) < 1e-6);
    let e = q
        .predict_eps(z.view(), 10, &[Cond::Content], None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("style image"), "{e}");
    let e = q
        .predict_eps(z.view(), 1000, &[Cond::Null], None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("timestep 1000"), "{e}");
    let bad = Array4::<f32>::zeros((1, 3, 4, 4));
    assert!(q.predict_eps(bad.view(), 10, &[Cond::Null], None).is_err());
}

#[test]
fn manifest_mismatches_name_the_graph_and_input() {
    let Some(dir) = gaussian_dir() else { return };
    let expect = |d: &Path, needles: &[&str]| {
        let e = OnnxPrior::open(d, &opts(None)).unwrap_err().to_string();
        for n in needles {
            assert!(e.contains(n), "`{n}` not in: {e}");
        }
    };
    // Wrong input name.
    let d = edited(&dir, |v| v["unet"]["timestep"] = "t".into());
    expect(
        d.path(),
        &["unet.onnx", "graph `unet`", "input `t`", "no such input"],
    );
    // Wrong shape: the manifest says 3 latent channels, the graphs have 4.
    let d = edited(&dir, |v| {
        v["family"] = "custom".into();
        v["latent_channels"] = 3.into();
    });
    expect(
        d.path(),
        &[
            "vae_encoder.onnx",
            "graph `vae_encoder`",
            "output `latent`",
            "4 channels",
            "expected 3",
        ],
    );
    // Wrong static size of the image encoder's input.
    let d = edited(&dir, |v| v["image_encoder"]["size"] = 32.into());
    expect(
        d.path(),
        &["graph `image_encoder`", "input `image`", "dimension 2 = 64"],
    );
    // Wrong output name.
    let d = edited(&dir, |v| v["vae_encoder"]["output"] = "mean".into());
    expect(d.path(), &["graph `vae_encoder`", "output `mean`"]);
    // A graph input the manifest does not name.
    let d = edited(&dir, |v| {
        v["unet"].as_object_mut().unwrap().remove("image_tokens");
        v.as_object_mut().unwrap().remove("image_encoder");
    });
    expect(
        d.path(),
        &[
            "graph `unet`",
            "input `image_tokens`",
            "not named in the manifest",
        ],
    );
    // Missing graph: absent from the manifest, or its file absent.
    let d = edited(&dir, |v| {
        v.as_object_mut().unwrap().remove("vae_encoder");
    });
    expect(d.path(), &["model.json", "graph `vae_encoder` is missing"]);
    let d = edited(&dir, |_| {});
    std::fs::remove_file(d.path().join("unet.onnx")).unwrap();
    expect(
        d.path(),
        &["model.json", "unet", "unet.onnx does not exist"],
    );
    // Corrupt graph.
    let d = edited(&dir, |_| {});
    std::fs::write(
        d.path().join("unet.onnx"),
        b"\x08\x07garbage that is not protobuf",
    )
    .unwrap();
    expect(
        d.path(),
        &["unet.onnx", "graph `unet`", "cannot load ONNX graph"],
    );
    // Corrupt text embedding.
    let d = edited(&dir, |_| {});
    std::fs::write(d.path().join("null.npy"), b"not npy").unwrap();
    expect(d.path(), &["null.npy"]);
    // Unknown prompt.
    let e = OnnxPrior::open(
        &dir,
        &PriorOptions {
            prompt: Some("a cat".into()),
            ..opts(None)
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("a cat") && e.contains("a gaussian"), "{e}");
    // The stylizer family is dispatched (to an error until that prior is linked in).
    let d = edited(&dir, |v| v["family"] = "stylizer".into());
    let e = fantasystyle::prior::open(d.path(), &opts(None))
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("stylizer"), "{e}");
}

fn write_views(dir: &Path, n: usize, h: usize, w: usize) {
    let mut r = Rng::new(11);
    let rgb: Vec<f32> = (0..n * h * w * 3).map(|_| r.uniform() as f32).collect();
    let ones = vec![1f32; n * h * w];
    crate::harness::write_views(dir, [n, h, w], &rgb, &ones, &ones, b"[]");
}

#[test]
fn encode_latents_stage_writes_latents_and_rejects_bad_input() {
    use fantasystyle::stages::{Threads, encode_latents};
    let Some(dir) = gaussian_dir() else { return };
    let t = tempfile::tempdir().unwrap();
    let views = t.path().join("views");
    write_views(&views, 3, 16, 24);
    let out = t.path().join("lat");
    let p = encode_latents::Args {
        views: views.clone(),
        model: dir.clone(),
        out: out.clone(),
        threads: Threads::new(1),
        device: Default::default(),
        batch: 2,
        fill: false,
        alpha_from: None,
        background: fantasystyle::stages::Background { rgb: [0.0; 3] },
    };
    assert_eq!(encode_latents::run(p.clone()).unwrap(), [3, 4, 2, 3]);
    let a = Artifact::open(&out, ArtifactKind::Latents).unwrap();
    let got = fantasystyle::artifacts::read_latents(&out).unwrap();
    assert_eq!(got.shape(), [3, 4, 2, 3]);
    assert!(a.manifest.inputs.iter().any(|i| i.role == "model"));
    // Same numbers as the Rust closed form's encoder on the same images.
    let img = fantasystyle::artifacts::read_views(&views)
        .unwrap()
        .rgb
        .permuted_axes([0, 3, 1, 2])
        .to_owned();
    let want = gaussian::vae_encode(img.view()).unwrap();
    assert!(max_diff(&got, &want) < 1e-5);

    // Image size not divisible by 8: error names rgb.npy, nothing written.
    let bad = t.path().join("bad_views");
    write_views(&bad, 1, 12, 16);
    let out2 = t.path().join("lat2");
    let e = encode_latents::run(encode_latents::Args {
        views: bad,
        out: out2.clone(),
        ..p.clone()
    })
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("rgb.npy") && msg.contains("divisible"),
        "{msg}"
    );
    assert_eq!(e.exit_code(), 2);
    assert!(!out2.exists());
    // Not a views artifact; missing model.
    let e = encode_latents::run(encode_latents::Args {
        views: out.clone(),
        out: out2.clone(),
        ..p.clone()
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("views"), "{e}");
    let e = encode_latents::run(encode_latents::Args {
        model: t.path().join("nomodel"),
        out: out2.clone(),
        ..p
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("nomodel"), "{e}");
    assert!(!out2.exists());
}

#[test]
fn controlnet_residuals_and_sdxl_inputs_reach_the_unet() {
    // vendor/models/gaussian-prior-controlnet (setup step 10): the test ControlNet emits
    // down_0 = raw latents of the control image and mid = time_ids[0]/1000 +
    // text_embeds[0]; the UNet adds down_res_0 + mid_res + text_embeds[1] to the
    // closed-form eps. So the expected output is known exactly.
    let Some(base) = gaussian_dir() else { return };
    let dir = base.with_file_name("gaussian-prior-controlnet");
    let style = rand((1, 3, 64, 64), 6, 1.0, 0.0);
    let mut p = OnnxPrior::open(&dir, &opts(Some(style.clone()))).unwrap();
    assert_eq!(
        p.info().control,
        Some(fantasystyle::prior::ControlKind::Depth)
    );
    let mut rust = GaussianPrior::with_default_text(Some(style.view())).unwrap();
    let z = rand((2, 4, 3, 4), 7, 2.0, -1.0);
    let ctrl = rand((2, 3, 24, 32), 8, 1.0, 0.0);
    let t = 321;
    let conds = [Cond::Null, Cond::Prompt, Cond::PromptStyle];
    let got = p
        .predict_eps(z.view(), t, &conds, Some(ctrl.view()))
        .unwrap();
    let eps = rust.predict_eps(z.view(), t, &conds, None).unwrap();
    let raw = gaussian::vae_encode(ctrl.view()).unwrap() / gaussian::SCALING_FACTOR;
    let scale = 0.5f32;
    // pooled text embeddings: null [0, 0], prompt [0.1, 0.2]; image height 24.
    for (i, te) in [[0.0f32, 0.0], [0.1, 0.2], [0.1, 0.2]].iter().enumerate() {
        let want = &eps[i] + &(&raw * scale) + scale * (24.0 / 1000.0 + te[0]) + te[1];
        let d = max_diff(&got[i], &want);
        assert!(d < 1e-5, "cond {i}: {d}");
    }
    let e = p
        .predict_eps(z.view(), t, &conds, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("ControlNet") && e.contains("Depth"), "{e}");
    // This model's VAE encoder outputs [mean, logvar] (8 channels): the mean is used.
    let img = rand((2, 3, 16, 24), 10, 1.0, 0.0);
    let lat = p.encode(img.view()).unwrap();
    assert_eq!(lat.dim(), (2, 4, 2, 3));
    assert!(max_diff(&lat, &gaussian::vae_encode(img.view()).unwrap()) < 1e-5);
    let small = rand((2, 3, 16, 16), 9, 1.0, 0.0);
    let e = p
        .predict_eps(z.view(), t, &conds, Some(small.view()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("control image"), "{e}");
}

#[test]
fn control_images_from_renders() {
    use fantasystyle::prior::{ControlKind, control_image};
    use ndarray::{Array3, Array4};
    let depth = Array3::from_shape_fn((1, 4, 4), |(_, y, _)| 1.0 + y as f32);
    let mut alpha = Array3::<f32>::ones((1, 4, 4));
    alpha[[0, 3, 3]] = 0.0;
    let rgb = Array4::from_shape_fn((1, 4, 4, 3), |(_, _, x, _)| (x >= 2) as u8 as f32);
    let d = control_image(ControlKind::Depth, rgb.view(), depth.view(), alpha.view()).unwrap();
    assert_eq!(d.dim(), (1, 3, 4, 4));
    assert!((d[[0, 0, 0, 0]] - 1.0).abs() < 1e-6, "nearest row is 1");
    assert!(d[[0, 2, 3, 0]].abs() < 1e-6, "farthest row is 0");
    assert_eq!(d[[0, 1, 3, 3]], 0.0, "background is 0");
    let e = control_image(ControlKind::Edges, rgb.view(), depth.view(), alpha.view()).unwrap();
    // The vertical edge between columns 1 and 2 is the strongest response.
    assert!((e[[0, 0, 1, 1]] - 1.0).abs() < 1e-6 && e[[0, 0, 1, 3]] < 1e-6);
    let bad = Array3::<f32>::ones((1, 3, 4));
    assert!(control_image(ControlKind::Depth, rgb.view(), bad.view(), alpha.view()).is_err());
}

#[test]
fn encode_latents_binary_exit_codes() {
    let Some(dir) = gaussian_dir() else { return };
    let t = tempfile::tempdir().unwrap();
    let views = t.path().join("views");
    write_views(&views, 2, 16, 16);
    let bin = env!("CARGO_BIN_EXE_encode-latents");
    let run = |views: &Path, model: &Path, out: &Path| {
        std::process::Command::new(bin)
            .args(["--views", views.to_str().unwrap()])
            .args(["--model", model.to_str().unwrap()])
            .args(["--out", out.to_str().unwrap(), "--threads", "1"])
            .output()
            .unwrap()
    };
    let out = t.path().join("lat");
    let o = run(&views, &dir, &out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("latents.npy").is_file());
    let o = run(&t.path().join("missing"), &dir, &t.path().join("x"));
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing"));
    // A corrupt graph in a copied model: non-zero exit, the file named, nothing written.
    let m = edited(&dir, |_| {});
    std::fs::write(m.path().join("vae_encoder.onnx"), b"junk").unwrap();
    let o = run(&views, m.path(), &t.path().join("y"));
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("vae_encoder.onnx"));
    assert!(!t.path().join("y").exists());
}

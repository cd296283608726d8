//! `evaluate` end to end on synthetic views artifacts (an analytically ray-cast textured
//! ground plane with a square occluder, seen by an arc of cameras), bad input through the
//! binary, and the report opened in headless Chromium.

use fantasystyle::Camera;
use fantasystyle::artifacts::read_view_set;
use fantasystyle::camera::inria::to_inria;
use fantasystyle::imageio::Image;
use fantasystyle::maths::warp::{look_at, synthetic};
use fantasystyle::metrics::consistency;
use fantasystyle::metrics::nets::{LpipsModel, LpipsNet};
use fantasystyle::models::models_dir;
use fantasystyle::stages::evaluate::{Args, run};

use std::path::{Path, PathBuf};
use std::process::Command;

pub(crate) const W: u32 = 64;
pub(crate) const H: u32 = 48;

pub(crate) fn cameras(n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let a = -0.5 + 0.12 * i as f64;
            look_at(
                &format!("v{i}"),
                [3.2 * a.sin(), -3.2 * a.cos(), 2.6],
                [0.0, 0.0, 0.2],
                W,
                H,
                52.0,
            )
        })
        .collect()
}

/// A consistent "stylization": a fixed colour remap of every rendered pixel.
pub(crate) fn restyle(p: [f32; 3]) -> [f32; 3] {
    [1.0 - p[1], 0.3 + 0.6 * p[0] * p[2], (p[0] + p[1]) * 0.5]
}

/// Write a views artifact; `colour` maps each rendered image.
pub(crate) fn write_views(
    dir: &Path,
    cams: &[Camera],
    colour: &dyn Fn(usize, Image) -> Image,
) -> PathBuf {
    let (mut rgb, mut depth, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    for (i, c) in cams.iter().enumerate() {
        let (img, d, a) = synthetic::render(c, Some((0.7, 0.35)));
        rgb.extend(colour(i, img).data);
        depth.extend(d);
        alpha.extend(a);
    }
    let n = cams.len();
    let (h, w) = (cams[0].height as usize, cams[0].width as usize);
    let mut json = serde_json::to_vec_pretty(&to_inria(cams)).unwrap();
    json.push(b'\n');
    crate::harness::write_views(dir, [n, h, w], &rgb, &depth, &alpha, &json);
    dir.to_path_buf()
}

pub(crate) fn style_png(dir: &Path) -> PathBuf {
    let img = Image::from_fn(96, 80, |x, y| {
        let s = ((x / 8 + y / 8) % 2) as f32;
        [
            0.2 + 0.6 * s,
            0.5 + 0.4 * ((x as f32) * 0.3).sin(),
            0.8 - 0.5 * (y as f32 / 80.0),
        ]
    });
    let p = dir.join("style.png");
    std::fs::write(&p, img.to_png()).unwrap();
    p
}

/// onnxruntime and the metric networks ([`crate::harness::need`]: a failure under CI).
pub(crate) fn ready() -> bool {
    crate::harness::onnxruntime()
        && match models_dir() {
            Ok(m) => crate::harness::need(
                format_args!("the metric networks {}", m.join("metrics").display()),
                m.join("metrics").is_dir(),
            ),
            Err(e) => crate::harness::need(format_args!("the models directory ({e})"), false),
        }
}

pub(crate) fn opts(o: &Path, s: &Path, style: &Path, out: &Path) -> Args {
    Args {
        original: Some(o.into()),
        stylized: Some(s.into()),
        style: Some(style.into()),
        out: out.into(),
        reference_only: None,
        reference: Vec::new(),
        cameras: None,
        width: None,
        height: None,
        lpips_net: LpipsNet::Alex,
        short_range: 1,
        long_range: 5,
        seed: 0,
        object_squares: fantasystyle::metrics::texture::PATCHES_PER_VIEW,
        inception: true,
        style_size: fantasystyle::metrics::interior::STYLE_SHORTER_SIDE,
        threads: fantasystyle::stages::Threads::new(2),
        sweep: None,
        original_scene: None,
        stylized_scene: None,
        history: None,
        refit_baseline: None,
        preview: None,
    }
}

/// Runs `evaluate` once on 7 synthetic views; checks metrics.json and the report, then
/// opens the report in headless Chromium.
#[test]
fn evaluate_writes_metrics_and_a_report_that_renders() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let cams = cameras(7);
    let orig = write_views(&d.path().join("orig"), &cams, &|_, i| i);
    let styl = write_views(&d.path().join("styl"), &cams, &|_, i| {
        Image::from_fn(i.width, i.height, |x, y| restyle(i.px(x, y)))
    });
    let style = style_png(d.path());
    let out = d.path().join("eval");
    let m = run(opts(&orig, &styl, &style, &out))
        .unwrap()
        .expect("an evaluation");

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(json["views"], 7);
    let lp = json["lpips_content"].as_f64().unwrap();
    assert!(lp > 0.05, "restyled views differ from the originals: {lp}");
    let fs = json["fid_style"]["value"].as_f64().unwrap();
    let fc = json["fid_content"]["value"].as_f64().unwrap();
    // A colour remap of the same renders is far nearer its originals than the style
    // image's crops are (measured: FID_content 144, FID_style 609).
    assert!(
        fc > 1.0 && fc < 0.5 * fs,
        "FID_content {fc} should be well below FID_style {fs}"
    );
    assert_eq!(
        json["fid_style"]["reliable"], false,
        "7 images cannot give an unbiased FID"
    );
    let art = json["artfid"].as_f64().unwrap();
    assert!((art - (1.0 + lp) * (1.0 + fs)).abs() < 1e-9 * art);
    assert!(json["kid_style"]["value"].is_number());
    // A consistent (world-space) restyle is as consistent as the original renders: its
    // short-range warp error is of the same size as the original's floor.
    let sr = &m.short_range;
    assert_eq!(sr.stylized.len(), 6);
    assert_eq!(m.long_range.stylized.len(), 2);
    let (rs, ro) = (sr.rmse_mean.unwrap(), sr.original_rmse_mean.unwrap());
    eprintln!(
        "short-range RMSE stylized {rs:.4} original {ro:.4}; LPIPS {:?} {:?}",
        sr.lpips_mean, sr.original_lpips_mean
    );
    assert!(
        rs < 0.03 && ro < 0.03,
        "warp of a consistent scene: {rs} {ro}"
    );
    // The reported Gram distance is the mean of the per-view ones, each positive.
    let per_view = &m.gram_style_per_view;
    assert!(per_view.len() == 7 && per_view.iter().all(|g| *g > 0.0 && g.is_finite()));
    let mean = per_view.iter().sum::<f64>() / 7.0;
    assert!((m.gram_style.unwrap() - mean).abs() <= 1e-9 * mean);
    assert!(m.warnings.iter().any(|w| w.contains("biased")));
    // The texture measures: four layers with a value per view, KID's interval around
    // the same KID as kid_style, the spectra, the object measures; and their section.
    let t = &m.texture;
    assert_eq!(t.gram_object.len(), 4);
    for l in &t.gram_object {
        assert_eq!(l.stylized_per_view.len(), 7, "{}", l.layer);
        assert!(
            l.stylized.unwrap() > 0.0 && l.original.unwrap() > 0.0,
            "{}",
            l.layer
        );
    }
    let kid = json["kid_style"]["value"].as_f64().unwrap();
    assert!((t.kid_style.value.unwrap() - kid).abs() <= 1e-9 * kid.abs().max(1.0));
    let [lo, hi] = t.kid_style.ci95.unwrap();
    assert!(lo < kid && kid < hi && !t.kid_style.reliable);
    assert!(t.spectrum.distance_original.is_some() && t.spectrum.peak_style.is_some());
    // The object KID: squares inside the rendered plane, the same ones in the originals,
    // the style's 64 squares; the restyle changes the value.
    let (ko, kor) = (&t.kid_object, &t.kid_object_original);
    eprintln!(
        "object squares: {} per set, KID {:?} (original {:?})",
        ko.n_a, ko.value, kor.value
    );
    assert!(
        ko.n_a >= 7 && ko.n_a == kor.n_a,
        "{} vs {}",
        ko.n_a,
        kor.n_a
    );
    assert_eq!((ko.n_b, kor.n_b), (64, 64));
    let (v, vo) = (ko.value.unwrap(), kor.value.unwrap());
    assert!(v.is_finite() && vo.is_finite() && v != vo, "{v} {vo}");
    assert!(t.object.clipped_stylized.is_some() && t.object.stats_distance_stylized.is_some());
    assert_eq!(
        json["texture"]["spectrum"]["style"]
            .as_array()
            .unwrap()
            .len(),
        24
    );

    // Content leakage: a colour map of the original leaves little large-scale structure.
    let leak = json["leakage"]["value"].as_f64().unwrap();
    assert!(
        (0.0..0.1).contains(&leak),
        "leakage of a colour map: {leak}"
    );

    // Structure kept: a value per view, their mean, the note; a colour remap that is not
    // monotonic in luminance keeps some of the structure, not all.
    let sv: Vec<f64> = json["structure_kept_per_view"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().expect("every view has a value"))
        .collect();
    assert_eq!(sv.len(), 7);
    assert!(sv.iter().all(|r| (-1.0..1.0).contains(r)), "{sv:?}");
    let sm = json["structure_kept"].as_f64().unwrap();
    assert!((sm - sv.iter().sum::<f64>() / 7.0).abs() < 1e-12, "{sm}");
    assert!(
        json["structure_kept_note"]
            .as_str()
            .unwrap()
            .contains("band-passed luminance")
    );
    eprintln!("structure kept {sm:.4}, per view {sv:.3?}");
    // Interior structure, edge recall, motif contrast, style texture beside it: a value or
    // a reason per view, the means, the notes.
    let iv = json["interior_per_view"].as_array().unwrap();
    assert_eq!(iv.len(), 7);
    for (k, note) in [
        ("interior_structure", "interior_structure_note"),
        ("edge_recall", "edge_recall_note"),
        ("motif_contrast", "motif_contrast_note"),
        ("style_texture", "style_texture_note"),
    ] {
        assert!(json[note].as_str().unwrap().contains("8 px"), "{note}");
        let have = iv.iter().filter(|v| v[k].is_f64()).count();
        assert_eq!(json[k].is_f64(), have > 0, "{k}");
        assert!(
            iv.iter()
                .all(|v| v[k].is_f64() || !v["reasons"].as_array().unwrap().is_empty()),
            "{k}"
        );
    }
    assert!(json["style_band_spread"].as_f64().unwrap() > 0.0);
    eprintln!(
        "interior structure {}, edge recall {}, motif contrast {}, style texture {}",
        json["interior_structure"],
        json["edge_recall"],
        json["motif_contrast"],
        json["style_texture"]
    );

    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    // It opens with pictures: the style, original and stylized views before the numbers.
    let at = |s: &str| {
        html.find(s)
            .unwrap_or_else(|| panic!("no {s} in the report"))
    };
    assert!(at("id=\"pictures\"") < at("<h2>Metrics</h2>"));
    assert!(html.contains(
        "<th>view 0 of 7</th><th>view 1 of 7</th><th>view 3 of 7</th><th>view 5 of 7</th>"
    ));
    assert!(at("<h2>Metrics</h2>") < at("structure kept ↑"));
    assert!(at("structure kept ↑") < at("interior structure ↑"));
    assert!(at("edge recall ↑") < at("motif contrast (→ 1)"));
    assert!(at("motif contrast (→ 1)") < at("style texture (→ 1)"));
    assert!(at("style texture (→ 1)") < at("<h2>Structure kept: the worst view</h2>"));
    assert!(html.contains("<th>edge recall</th><th>motif contrast</th><th>style texture</th>"));
    assert!(html.contains("band-pass, stylized"));
    assert!(html.contains("<h2>Content leakage</h2>"));
    assert!(html.contains("<h2>Texture</h2>") && html.contains("Radially averaged luminance"));
    assert!(html.contains("KID of object squares vs style squares"));
    assert!(html.contains("ArtFID") && html.contains("standard FID Inception"));
    assert!(html.contains("<svg") && html.contains("short range: LPIPS per view pair"));
    // opening: style + 4 originals + 4 stylized; worst structure: 4; style + 7 originals +
    // 7 stylized + 2 x 4 consistency examples + 7 crops
    assert!(html.matches("data:image/png;base64,").count() >= 9 + 4 + 1 + 14 + 8 + 7);
    if let Ok(keep) = std::env::var("FANTASYSTYLE_KEEP_REPORT") {
        std::fs::copy(out.join("report.html"), keep).unwrap();
    }
    chromium_check(&out.join("report.html"));
}

/// A `preview` views artifact of `views` of `cams` (a colour remap of their renders) whose
/// producer params name `named` as the views.
fn write_preview(dir: &Path, cams: &[Camera], views: &[usize], named: &[usize]) -> PathBuf {
    use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
    let (mut rgb, mut depth, mut alpha) = (Vec::new(), Vec::new(), Vec::new());
    let sub: Vec<Camera> = views.iter().map(|&v| cams[v].clone()).collect();
    for c in &sub {
        let (img, d, a) = synthetic::render(c, Some((0.7, 0.35)));
        rgb.extend(img.data.iter().map(|v| 1.0 - v));
        depth.extend(d);
        alpha.extend(a);
    }
    let (n, h, w) = (sub.len(), H as usize, W as usize);
    let params = serde_json::json!({ "views": named });
    let mut wr = ArtifactWriter::create(
        dir,
        ArtifactKind::Views,
        Producer::new("preview", "0", params),
    )
    .unwrap();
    wr.write_tensor("rgb.npy", &[n, h, w, 3], &rgb).unwrap();
    wr.write_tensor("depth.npy", &[n, h, w], &depth).unwrap();
    wr.write_tensor("alpha.npy", &[n, h, w], &alpha).unwrap();
    wr.write_json("cameras.json", &to_inria(&sub)).unwrap();
    wr.commit().unwrap();
    dir.to_path_buf()
}

/// `--preview`: the report opens with the preview's views beside the original and
/// stylized ones (the views it has), labelled, before the numbers; it is recorded as an
/// input. A preview of views the evaluation does not have, or from other cameras, is
/// refused (exit 2, naming it, nothing written).
#[test]
fn a_preview_opens_the_report_beside_the_views() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let cams = cameras(5);
    let orig = write_views(&p.join("orig"), &cams, &|_, i| i);
    let styl = write_views(&p.join("styl"), &cams, &|_, i| {
        Image::from_fn(i.width, i.height, |x, y| restyle(i.px(x, y)))
    });
    let style = style_png(p);
    let preview = write_preview(&p.join("preview"), &cams, &[1, 3], &[1, 3]);
    let out = p.join("eval");
    run(Args {
        preview: Some(preview.clone()),
        object_squares: 0,
        ..opts(&orig, &styl, &style, &out)
    })
    .unwrap()
    .unwrap();
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let at = |s: &str| {
        html.find(s)
            .unwrap_or_else(|| panic!("no {s} in the report"))
    };
    let label = fantasystyle::metrics::report::PREVIEW_LABEL;
    assert!(at("id=\"pictures\"") < at(label) && at(label) < at("<h2>Metrics</h2>"));
    // The columns are the preview's views; each row has its pictures.
    assert!(html.contains("<th>view 1 of 5</th><th>view 3 of 5</th></tr>"));
    for row in ["original", "stylized", label] {
        for v in [1, 3] {
            assert!(html.contains(&format!("alt=\"{row} {v}\"")), "{row} {v}");
        }
    }
    let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap();
    assert!(manifest.contains("\"preview\""), "recorded as an input");

    let bad = [
        (write_preview(&p.join("p7"), &cams, &[1], &[7]), "view 7"),
        (
            write_preview(&p.join("p2"), &cams, &[1], &[2]),
            "camera 0 differs from view 2",
        ),
    ];
    let out2 = p.join("eval2");
    for (dir, want) in bad {
        let o = Command::new(env!("CARGO_BIN_EXE_evaluate"))
            .args(["--original", orig.to_str().unwrap()])
            .args(["--stylized", styl.to_str().unwrap()])
            .args(["--style", style.to_str().unwrap()])
            .args(["--preview", dir.to_str().unwrap()])
            .args(["--out", out2.to_str().unwrap()])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{want}: {err}");
        assert!(
            err.contains(want) && err.contains(dir.to_str().unwrap()),
            "expected `{want}` naming {}: {err}",
            dir.display()
        );
        assert!(!out2.exists(), "nothing written on a bad preview");
    }
}

/// Opens the report in headless Chromium with a script that counts decoded images.
fn chromium_check(report: &Path) {
    let Some(chrome) = ["chromium", "chromium-browser", "google-chrome"]
        .iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
    else {
        // CI installs it (scripts/setup/05_chromium.sh): there, its absence is a failure.
        crate::harness::need(
            "chromium (scripts/setup/05_chromium.sh, or apt-get install -y chromium)",
            false,
        );
        return;
    };
    let html = std::fs::read_to_string(report).unwrap();
    let probe = r#"<script>window.addEventListener('load', () => {
  const imgs = Array.from(document.images);
  const ok = imgs.filter(i => i.complete && i.naturalWidth > 0).length;
  const pre = document.createElement('pre'); pre.id = 'imgcheck';
  pre.textContent = 'IMG' + 'CHECK total=' + imgs.length + ' decoded=' + ok + ' svgs=' + document.querySelectorAll('svg').length;
  document.body.appendChild(pre);
});</script></body>"#;
    let dir = report.parent().unwrap();
    let probe_path = dir.join("probe.html");
    std::fs::write(&probe_path, html.replace("</body>", probe)).unwrap();
    let out = Command::new(chrome)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--virtual-time-budget=10000",
            "--dump-dom",
        ])
        .arg(format!(
            "--user-data-dir={}",
            dir.join("chrome-profile").display()
        ))
        .arg(format!("file://{}", probe_path.display()))
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&out.stdout);
    let line = dom
        .lines()
        .find(|l| l.contains("IMGCHECK"))
        .unwrap_or_else(|| {
            panic!(
                "no probe output; stderr: {}",
                String::from_utf8_lossy(&out.stderr)
            )
        });
    eprintln!("chromium: {line}");
    let num = |k: &str| -> usize {
        let s = &line[line.find(k).unwrap() + k.len()..];
        s.split(|c: char| !c.is_ascii_digit())
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let (total, decoded, svgs) = (num("total="), num("decoded="), num("svgs="));
    assert!(total >= 30, "{line}");
    assert_eq!(total, decoded, "every image decodes: {line}");
    assert!(svgs >= 4, "{line}");
}

/// Consistency separates a consistent stylization from a per-view flickering one.
#[test]
fn consistency_penalises_per_view_flicker() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let cams = cameras(4);
    let good = read_view_set(&write_views(&d.path().join("good"), &cams, &|_, i| {
        Image::from_fn(i.width, i.height, |x, y| restyle(i.px(x, y)))
    }))
    .unwrap();
    let flicker = read_view_set(&write_views(&d.path().join("flicker"), &cams, &|v, i| {
        let shift = [0.15, -0.1, 0.2][v % 3];
        Image::from_fn(i.width, i.height, |x, y| {
            restyle(i.px(x, y)).map(|c| (c + shift).clamp(0.0, 1.0))
        })
    }))
    .unwrap();
    let mut lp = LpipsModel::load(&models_dir().unwrap(), LpipsNet::Alex, 2).unwrap();
    let pairs = consistency::pairs(4, 1);
    let (g, _) = consistency::score_pairs(&mut lp, &good, &good.images, &pairs).unwrap();
    let (f, _) = consistency::score_pairs(&mut lp, &good, &flicker.images, &pairs).unwrap();
    for (a, b) in g.iter().zip(&f) {
        eprintln!(
            "pair ({},{}): consistent {:?}/{:?} flicker {:?}/{:?}",
            a.i, a.j, a.lpips, a.rmse, b.lpips, b.rmse
        );
        assert!(a.valid_fraction > 0.3);
        assert!(b.rmse.unwrap() > 3.0 * a.rmse.unwrap());
        assert!(b.lpips.unwrap() > a.lpips.unwrap());
    }
}

fn evaluate_bin(args: &[&Path]) -> (i32, String) {
    let names = ["--original", "--stylized", "--style", "--out"];
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_evaluate"));
    for (n, a) in names.iter().zip(args) {
        cmd.arg(n).arg(a);
    }
    let o = cmd.output().unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn bad_input_is_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let cams = cameras(3);
    let orig = write_views(&p.join("orig"), &cams, &|_, i| i);
    let two = write_views(&p.join("two"), &cams[..2], &|_, i| i);
    let mut moved = cams.clone();
    moved[1].translation[0] += 0.5;
    let moved = write_views(&p.join("moved"), &moved, &|_, i| i);
    let small: Vec<Camera> = cams
        .iter()
        .map(|c| {
            look_at(
                &c.name,
                c.center().map(|v| v as f64),
                [0.0, 0.0, 0.2],
                32,
                24,
                26.0,
            )
        })
        .collect();
    let small = write_views(&p.join("small"), &small, &|_, i| i);
    let style = style_png(p);
    let out = p.join("eval");
    let cases: [(&Path, &Path, &Path, &str); 5] = [
        (&orig, &two, &style, "2 views, but"),
        (&orig, &moved, &style, "camera 1 differs"),
        (&orig, &small, &style, "images are 32x24"),
        (
            &orig,
            &orig,
            &p.join("missing.png"),
            "missing.png: image file not found",
        ),
        (
            &orig,
            &p.join("nope"),
            &style,
            "nope: views artifact directory not found",
        ),
    ];
    for (a, b, s, want) in cases {
        let (code, err) = evaluate_bin(&[a, b, s, &out]);
        assert_eq!(code, 2, "{want}: {err}");
        assert!(err.contains(want), "expected `{want}` in: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "nothing written on bad input");
    }
    // A stylized set with NaN colours is refused by the artifact reader.
    let nan = write_views(&p.join("nan"), &cams, &|_, mut i| {
        i.data[5] = f32::NAN;
        i
    });
    let (code, err) = evaluate_bin(&[&orig, &nan, &style, &out]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("rgb.npy"), "{err}");
}

/// One view: FID/KID cannot be computed; the run still succeeds, marks them unavailable
/// and says why in metrics.json and in the report.
#[test]
fn too_few_images_for_fid_is_a_documented_warning() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let cams = cameras(1);
    let orig = write_views(&d.path().join("orig"), &cams, &|_, i| i);
    let style = style_png(d.path());
    let out = d.path().join("eval");
    let (code, err) = evaluate_bin(&[&orig, &orig, &style, &out]);
    assert_eq!(code, 0, "{err}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert!(json["fid_content"]["value"].is_null() && json["kid_style"]["value"].is_null());
    assert!(json["artfid"].is_null());
    assert_eq!(json["lpips_content"].as_f64().unwrap(), 0.0);
    // The same views keep all their structure.
    let sk = json["structure_kept"].as_f64().unwrap();
    assert!((sk - 1.0).abs() < 1e-12, "structure kept {sk}");
    assert_eq!(json["structure_kept_per_view"].as_array().unwrap().len(), 1);
    // Inside the object too, or no value with the reason (a small interior).
    let iv = &json["interior_per_view"][0];
    match json["edge_recall"].as_f64() {
        Some(e) => {
            assert_eq!(e, 1.0);
            assert!((json["interior_structure"].as_f64().unwrap() - 1.0).abs() < 1e-12);
        }
        None => assert!(!iv["reasons"].as_array().unwrap().is_empty(), "{iv}"),
    }
    eprintln!("one view: {iv}");
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(
        html.contains("id=\"warnings\"") && html.contains("need at least 2 images per set"),
        "warning shown"
    );
    assert!(html.contains("No short range pairs"));
}

//! The distillation loop as a whole (issue 11): render -> prior -> targets -> colour step
//! on renders of objects over a background, with the real 2D stylizer prior.
//!
//! Properties: the update is ~0 when the style image is the content itself; no drift of
//! brightness beyond what the style's statistics justify; at most 2% more clipped
//! covered pixels than the original; finite at t = 1, t = T-1, strength 0 and 1; chunks
//! and resume (also after a kill) give the same bytes as one run.
//!
//! (The starts, the finish and the `split` stage are in `distill_starts`.)

use crate::harness::{bin, repo_root};
use fantasystyle::camera::load_cameras;
use fantasystyle::distill::{Config, Distiller, SourceViews};
use fantasystyle::prior::{self, PriorOptions};
use fantasystyle::render::fill;
use fantasystyle::scheduler::TimestepSet;
use fantasystyle::{Camera, Scene};
use ndarray::Array4;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The installed stylizer model ([`crate::harness::model`]: a failure under CI, else a
/// skip).
pub(crate) fn stylizer_dir() -> Option<PathBuf> {
    crate::harness::model("stylizer")
}

pub(crate) fn sample_scene() -> Scene {
    fantasystyle::artifacts::load_scene(&repo_root().join("data-sample/scene.ply")).unwrap()
}

/// Source views of `scene` from an `n`-view orbit at `size` x `size`.
pub(crate) fn source(scene: &Scene, n: usize, size: u32) -> (Vec<Camera>, SourceViews) {
    let cams = load_cameras(
        &format!("orbit:{n},elev=30,radius=2.4"),
        &scene.bounds(),
        size,
        size,
    )
    .unwrap();
    let src = SourceViews::render(scene, &cams, [0.0; 3]).unwrap();
    (cams, src)
}

/// A high-contrast procedural style: diagonal stripes of saturated colours.
pub(crate) fn stripes() -> Array4<f32> {
    let cols = [
        [0.95, 0.85, 0.1],
        [0.1, 0.2, 0.8],
        [0.85, 0.1, 0.15],
        [0.05, 0.05, 0.1],
    ];
    Array4::from_shape_fn((1, 3, 128, 128), |(_, c, y, x)| cols[((x + y) / 12) % 4][c])
}

/// The loop on `scene` with the prior at `dir` for the largest of `checkpoints`
/// iterations: the scene and the renders of every view after each checkpoint's number of
/// iterations.
pub(crate) fn run_loop(
    dir: &Path,
    scene: &Scene,
    cams: &[Camera],
    src: &SourceViews,
    style: Array4<f32>,
    strength: f32,
    set: Option<TimestepSet>,
    checkpoints: &[usize],
) -> Vec<(Scene, Vec<Vec<f32>>)> {
    let mut p = prior::open(
        dir,
        &PriorOptions {
            style_image: Some(style),
            strength: Some(strength),
            ..Default::default()
        },
    )
    .unwrap();
    let set = set.unwrap_or_else(|| prior::model_timesteps(dir).unwrap().1);
    let params = Config {
        views: 3,
        lr_dc: 0.05,
        ..Config::default()
    };
    let mut d = Distiller::new(scene, cams, src, p.as_mut(), set, params, 0).unwrap();
    let mut out = Vec::new();
    let mut done = 0;
    for &iters in checkpoints {
        for _ in done..iters {
            d.iterate().unwrap();
        }
        done = done.max(iters);
        let renders = (0..cams.len()).map(|v| d.render_view(v)).collect();
        out.push((d.scene().clone(), renders));
    }
    out
}

fn luma(c: &[f32]) -> f32 {
    0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]
}

/// Over covered pixels (alpha > 0.5) of every view: (RMS change of the un-premultiplied
/// colour from the source, mean luma, fraction clipped in every channel).
pub(crate) fn stats(src: &SourceViews, renders: &[Vec<f32>]) -> (f64, f64, f64) {
    let (mut d2, mut l, mut clip, mut n) = (0.0f64, 0.0f64, 0usize, 0usize);
    for (v, r) in renders.iter().enumerate() {
        let a = &src.alpha[v];
        let c0 = fill::unpremultiply(&src.rgb[v], a, [0.0; 3]);
        let c1 = fill::unpremultiply(r, a, [0.0; 3]);
        for p in 0..a.len() {
            if a[p] > 0.5 {
                let (x, y) = (&c0[p * 3..p * 3 + 3], &c1[p * 3..p * 3 + 3]);
                d2 += x
                    .iter()
                    .zip(y)
                    .map(|(a, b)| ((a - b) * (a - b)) as f64)
                    .sum::<f64>()
                    / 3.0;
                l += luma(y) as f64;
                if y.iter().all(|v| *v <= 0.02) || y.iter().all(|v| *v >= 0.98) {
                    clip += 1;
                }
                n += 1;
            }
        }
    }
    let n = n.max(1) as f64;
    ((d2 / n).sqrt(), l / n, clip as f64 / n)
}

/// With the style image equal to the content, the loop barely moves the scene; a real
/// style moves it several times as far. One camera seen three times, so that the "content"
/// is the same image in every view (over several views the style of view 0 is a real
/// restyle for its neighbours, and the shared Gaussians carry that back into view 0).
#[test]
fn self_style_is_nearly_a_fixed_point() {
    let Some(dir) = stylizer_dir() else {
        return;
    };
    let (d_own, d_style) = self_style_changes(&dir);
    assert!(
        d_style > 0.05,
        "the stripes style barely moved the scene: {d_style}"
    );
    // Exactly 0 in exact arithmetic (both branches see the same latents, and a target
    // equal to the render asks for no step); the bound leaves room for rounding only.
    assert!(
        d_own < 0.02 * d_style,
        "own style moved {d_own} vs stripes {d_style}"
    );
}

/// RMS colour change of the covered pixels after 20 iterations with the prior at `dir`,
/// with the style image equal to the content and with the stripes.
fn self_style_changes(dir: &Path) -> (f64, f64) {
    let scene = sample_scene();
    let (cams, src) = source(&scene, 6, 96);
    let cams = vec![cams[0].clone(); 3];
    let src = SourceViews {
        rgb: vec![src.rgb[0].clone(); 3],
        alpha: vec![src.alpha[0].clone(); 3],
        depth: vec![src.depth[0].clone(); 3],
        ..src
    };
    let seen = fill::fill_background(&src.rgb[0], &src.alpha[0], [0.0; 3], 96, 96);
    let own = Array4::from_shape_fn((1, 3, 96, 96), |(_, c, y, x)| seen[(y * 96 + x) * 3 + c]);
    let (_, r_own) = run_loop(dir, &scene, &cams, &src, own, 1.0, None, &[20]).remove(0);
    let (_, r_style) = run_loop(dir, &scene, &cams, &src, stripes(), 1.0, None, &[20]).remove(0);
    let (d_own, ..) = stats(&src, &r_own);
    let (d_style, ..) = stats(&src, &r_style);
    eprintln!("RMS colour change: own style {d_own:.4}, stripes {d_style:.4}");
    (d_own, d_style)
}

/// The mean luma of covered pixels in the stylizer's output T(view, s_style) on the
/// source views (as the prior sees them: over a fill of their own colours).
fn stylized_luma(src: &SourceViews, style: &Array4<f32>) -> f64 {
    let dir = stylizer_dir().unwrap();
    let mut p =
        fantasystyle::prior::stylizer::StylizerPrior::open(&dir, Some(style.view()), 2).unwrap();
    let s = p
        .style_vector(style.index_axis(ndarray::Axis(0), 0))
        .unwrap();
    let (h, w) = (src.height, src.width);
    let (mut l, mut n) = (0.0f64, 0usize);
    for v in 0..src.rgb.len() {
        let seen = fill::fill_background(&src.rgb[v], &src.alpha[v], [0.0; 3], h, w);
        let img = ndarray::Array3::from_shape_fn((3, h, w), |(c, y, x)| seen[(y * w + x) * 3 + c]);
        let t = p.stylize(img.view(), &s).unwrap();
        for q in 0..h * w {
            if src.alpha[v][q] > 0.5 {
                let (y, x) = (q / w, q % w);
                l += luma(&[t[[0, y, x]], t[[1, y, x]], t[[2, y, x]]]) as f64;
                n += 1;
            }
        }
    }
    l / n.max(1) as f64
}

/// Brightness settles, within what the pictures involved span: the mean luma of covered
/// pixels stops moving (after 45 and after 90 iterations within 0.02: a drift that
/// brightened or darkened every iteration by 0.0005 or more would fail), it stays within
/// 0.02 of the range spanned by the source, the style image and the 2D stylizer's own
/// output on the source views, and no more than 2% of covered pixels become clipped.
///
/// Why these bounds and not "the 2D stylization's luma": CSD's gradient for this prior
/// vanishes where the render differs from its stylization T(x^, s_style) as the source
/// differs from its own restyling T(x^_src, s_own) (`prior::stylizer` module docs), with
/// x^ a blurred clean estimate: the fixed point is the 2D stylization's luma minus the
/// own restyling's shift, plus what the blur changes, not the 2D luma itself. How far the
/// two are apart depends on the style vector: 3D minus 2D was -0.071 with the float
/// style-prediction graph (0.413 against 0.483; the own restyling brightens the source
/// by 0.035), and with the shipped int8 graph, whose vector depends on the CPU, -0.040 on
/// AVX2 (0.378 against 0.418) and -0.065 on AVX-512 VNNI (0.384 against 0.449; issue 40):
/// the former bound, 0.05 around the 2D luma, held on the CPUs it was written on.
///
/// Why they hold on any CPU: the networks are float graphs (`scripts/setup/20_stylizer.py`),
/// whose outputs differ between instruction sets by float rounding (style vectors 1e-6
/// of 3.6, BENCHMARKS.md "Reproducibility across instruction sets"), and the loop converges
/// to its fixed point (the luma after 45 and 90 iterations agrees to 4e-4) instead of
/// amplifying such differences; measured between AVX-512, AVX2 and SSE4.2 (qemu), the
/// lumas here agree to 1e-4 or better, against margins of 0.02 or more.
#[test]
fn no_brightness_drift_and_no_extra_clipping() {
    if stylizer_dir().is_none() {
        return;
    }
    let scene = sample_scene();
    let (cams, src) = source(&scene, 6, 96);
    let (_, l0, clip0) = stats(&src, &src.rgb);
    let style = stripes();
    let ls = {
        let n = 128 * 128;
        (0..n)
            .map(|p| {
                let (y, x) = (p / 128, p % 128);
                luma(&[
                    style[[0, 0, y, x]],
                    style[[0, 1, y, x]],
                    style[[0, 2, y, x]],
                ]) as f64
            })
            .sum::<f64>()
            / n as f64
    };
    let l2d = stylized_luma(&src, &style);
    let at = run_loop(
        &stylizer_dir().unwrap(),
        &scene,
        &cams,
        &src,
        style,
        1.0,
        None,
        &[45, 90],
    );
    let (l45, (_, l90, clip)) = (stats(&src, &at[0].1).1, stats(&src, &at[1].1));
    eprintln!(
        "luma: source {l0:.4}, style {ls:.4}, the 2D stylizer's output on the source views \
         {l2d:.4}, after 45 / 90 iterations {l45:.4} / {l90:.4}; clipped {clip0:.4} -> {clip:.4}"
    );
    assert!(
        (l90 - l45).abs() < 0.02,
        "still drifting: luma {l45} after 45 iterations, {l90} after 90"
    );
    let (lo, hi) = (l0.min(ls).min(l2d), l0.max(ls).max(l2d));
    assert!(
        (lo - 0.02..=hi + 0.02).contains(&l90),
        "luma after 90 iterations {l90} leaves the range of the source ({l0}), the style \
         ({ls}) and the 2D stylization ({l2d}) by more than 0.02"
    );
    assert!(clip - clip0 <= 0.02, "clipped {clip0} -> {clip}");
}

/// Finite at the ends of the schedule (t = 1, t = T-1) and at strength 0 and 1.
#[test]
fn extremes_are_finite() {
    let Some(dir) = stylizer_dir() else {
        return;
    };
    let scene = sample_scene();
    let (cams, src) = source(&scene, 4, 48);
    let cfg = prior::model_timesteps(&dir).unwrap().0.config.clone();
    let t_last = cfg.num_train_timesteps - 1;
    for (t, strength) in [(1, 1.0), (t_last, 1.0), (1, 0.0), (t_last, 0.0)] {
        let set = TimestepSet::new(&cfg, t, t, 1).unwrap();
        let (s, r) = run_loop(
            &stylizer_dir().unwrap(),
            &scene,
            &cams,
            &src,
            stripes(),
            strength,
            Some(set),
            &[3],
        )
        .remove(0);
        assert!(
            s.sh_dc.iter().flatten().all(|v| v.is_finite()),
            "t {t} strength {strength}"
        );
        assert!(r.iter().flatten().all(|v| v.is_finite()));
    }
}

/// `render-views` of `scene` from `cameras` at `size` x `size` into `out`.
pub(crate) fn render_source(scene: &Path, cameras: &str, size: u32, out: &Path) {
    let size = size.to_string();
    ok(bin("render-views")
        .arg("--scene")
        .arg(scene)
        .args([
            "--cameras",
            cameras,
            "--width",
            &size,
            "--height",
            &size,
            "--out",
        ])
        .arg(out));
}

pub(crate) fn ok(c: &mut Command) {
    let out = c.output().unwrap();
    assert!(
        out.status.success(),
        "{c:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

pub(crate) fn distill_args(dir: &Path, stylizer: &Path) -> Vec<String> {
    [
        "--source-views",
        &dir.join("views").to_string_lossy(),
        "--model",
        &stylizer.to_string_lossy(),
        "--style",
        &repo_root().join("data-sample/style.png").to_string_lossy(),
        "--set",
        "views=2",
        "--threads",
        "2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// A checkpoint's state: scene, optimizer state, iteration count, history.
pub(crate) const STATE_FILES: [&str; 5] = [
    "scene.ply",
    "adam_dc.npy",
    "adam_rest.npy",
    "state.json",
    "history.json",
];

/// Files `STATE_FILES` of checkpoints `a` and `b` are the same bytes.
pub(crate) fn same_files(a: &Path, b: &Path) {
    same_bytes(a, b, &STATE_FILES);
}

/// Files `files` of artifacts `a` and `b` are the same bytes.
pub(crate) fn same_bytes(a: &Path, b: &Path, files: &[&str]) {
    for f in files {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        let first = x.iter().zip(&y).position(|(p, q)| p != q);
        assert!(
            x == y,
            "{f} differs between {} and {} ({} vs {} bytes, first difference at {first:?})",
            a.display(),
            b.display(),
            x.len(),
            y.len()
        );
    }
}

/// Six iterations in one process, as two chunks of three, and as a chunk killed part-way
/// and run again: the same bytes (scene, optimizer state, history).
#[test]
fn chunks_resume_and_kill_give_the_same_bytes() {
    let Some(stylizer) = stylizer_dir() else {
        return;
    };
    resume_case(&stylizer);
}

/// Six iterations with the prior at `model` in one process, as two chunks of three, and
/// as a chunk killed part-way and run again: the same bytes; strength 0 leaves the colours.
pub(crate) fn resume_case(stylizer: &Path) {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo_root().join("data-sample/scene.ply");
    render_source(&scene, "orbit:5,elev=30,radius=2.4", 64, &d.join("views"));
    let base = distill_args(d, stylizer);
    let start = std::time::Instant::now();
    ok(bin("distill")
        .args(&base)
        .args(["--scene", &scene.to_string_lossy(), "--iters", "6", "--out"])
        .arg(d.join("one")));
    let one_s = start.elapsed();
    ok(bin("distill")
        .args(&base)
        .args(["--scene", &scene.to_string_lossy(), "--iters", "3", "--out"])
        .arg(d.join("a")));
    ok(bin("distill")
        .args(&base)
        .arg("--resume")
        .arg(d.join("a"))
        .args(["--iters", "3", "--out"])
        .arg(d.join("b")));
    same_files(&d.join("one"), &d.join("b"));
    // The history holds all six iterations, in order.
    let h: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(d.join("b/history.json")).unwrap()).unwrap();
    let its: Vec<u64> = h.iter().map(|r| r["iteration"].as_u64().unwrap()).collect();
    assert_eq!(its, [0, 1, 2, 3, 4, 5]);
    // Kill the second chunk part-way: nothing is left at --out; the rerun matches.
    let mut child = bin("distill")
        .args(&base)
        .arg("--resume")
        .arg(d.join("a"))
        .args(["--iters", "3", "--out"])
        .arg(d.join("k"))
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(one_s / 4);
    let killed = child.try_wait().unwrap().is_none();
    let _ = child.kill();
    let _ = child.wait();
    if killed {
        assert!(
            !d.join("k/manifest.json").exists(),
            "a killed chunk left an artifact"
        );
    }
    ok(bin("distill")
        .args(&base)
        .arg("--resume")
        .arg(d.join("a"))
        .args(["--iters", "3", "--out"])
        .arg(d.join("k")));
    same_files(&d.join("b"), &d.join("k"));
    // Strength 0: the colours are the input's, bit for bit.
    ok(bin("distill")
        .args(&base)
        .args(["--scene", &scene.to_string_lossy(), "--iters", "0", "--out"])
        .arg(d.join("z0")));
    ok(bin("distill")
        .args(&base)
        .arg("--resume")
        .arg(d.join("z0"))
        .args(["--iters", "4", "--set", "strength=0", "--out"])
        .arg(d.join("z")));
    assert_eq!(
        std::fs::read(d.join("z0/scene.ply")).unwrap(),
        std::fs::read(d.join("z/scene.ply")).unwrap()
    );
}

/// Bad input: a style too small to carry a style is refused with its size; a checkpoint
/// that is a plain scene artifact is refused by name; nothing is written.
#[test]
fn distill_bad_input_is_refused() {
    let Some(stylizer) = stylizer_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo_root().join("data-sample/scene.ply");
    render_source(&scene, "orbit:3", 32, &d.join("views"));
    image::save_buffer(
        d.join("tiny.png"),
        &[200, 10, 10],
        1,
        1,
        image::ColorType::Rgb8,
    )
    .unwrap();
    let mut base = distill_args(d, &stylizer);
    let si = base.iter().position(|a| a == "--style").unwrap();
    base[si + 1] = d.join("tiny.png").to_string_lossy().into_owned();
    let out = bin("distill")
        .args(&base)
        .args(["--scene", &scene.to_string_lossy(), "--iters", "1", "--out"])
        .arg(d.join("x"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("tiny.png") && err.contains("1x1"), "{err}");
    assert!(!d.join("x").exists());
    let out = bin("distill")
        .args(distill_args(d, &stylizer))
        .arg("--resume")
        .arg(d.join("views"))
        .args(["--iters", "1", "--out"])
        .arg(d.join("x"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(!d.join("x").exists());
    // Each term's weight finite and >= 0; one prior term; known keys and values only.
    for (config, says) in [
        (["--terms", "csd=1,nnfm=1,gram=-0.5"], "-0.5"),
        (["--terms", "csd,sds"], "choose one"),
        (["--terms", "csd,vgg"], "unknown term `vgg`"),
        (["--set", "csd.guidanse=1"], "csd.guidanse"),
        (["--config", "{ finihs = \"none\" }"], "finihs"),
        (["--set", "start=paint"], "start=paint"),
    ] {
        let out = bin("distill")
            .args(distill_args(d, &stylizer))
            .args(["--scene", &scene.to_string_lossy(), "--iters", "1"])
            .args(config)
            .arg("--out")
            .arg(d.join("x"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{config:?}: {err}");
        assert!(err.contains(says), "{config:?}: {err}");
        assert!(!d.join("x").exists());
    }
}

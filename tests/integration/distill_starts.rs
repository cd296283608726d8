//! The `distill` binary's starts and finish (`--start colour`, `--start projection`,
//! `--finish colour`): the object takes the style's colours or its stripes, a resumed
//! checkpoint is not started again, and each is refused beside `preserve_color`; and the
//! `split` stage: the long Gaussians split, the renders kept.

use crate::distill::{distill_args, ok, render_source, same_bytes, stylizer_dir};
use crate::harness::{bin, repo_root};
use std::path::Path;

/// `--start colour`: the start scene's object takes the style image's colour mean (checked
/// on fresh renders of the written scene, `--iters 0`); a resumed run has been through its
/// start (the start changes nothing there), and `preserve_color` is refused beside it
/// (exit 2, nothing written). `--finish colour` does the same to the result of the
/// iterations (two, from the scene's own colours), and is refused with `preserve_color`.
#[test]
fn colour_init_and_finish_move_the_object_to_the_style_colours() {
    use fantasystyle::transfer::colour::{image_stats, object_stats};
    let Some(stylizer) = stylizer_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo_root().join("data-sample/scene.ply");
    render_source(&scene, "orbit:4,elev=30,radius=2.4", 48, &d.join("views"));
    let stats_of = |dir: &Path| {
        let v = fantasystyle::artifacts::read_views(dir).unwrap();
        let src = v.source_views();
        let views: Vec<(&[f32], &[f32])> = src
            .rgb
            .iter()
            .zip(&src.alpha)
            .map(|(r, a)| (&r[..], &a[..]))
            .collect();
        object_stats(&views, [0.0; 3]).unwrap()
    };
    // A red style with some spread in every channel (the sample's own style has about
    // the sample scene's mean colour).
    let style_path = d.join("red.png");
    let px: Vec<u8> = (0..128 * 128 * 3)
        .map(|i| {
            let (p, c) = (i / 3, i % 3);
            let v = [200usize, 30, 40][c] + (p * 7 + p / 128 * 13 + c * 5) % 40;
            v as u8
        })
        .collect();
    image::save_buffer(&style_path, &px, 128, 128, image::ColorType::Rgb8).unwrap();
    let style_img = fantasystyle::imageio::read_rgb(&style_path).unwrap();
    let style = image_stats(&style_img);
    let gap = |m: [f64; 3]| {
        (0..3)
            .map(|k| (m[k] - style.mean[k]).abs())
            .fold(0.0, f64::max)
    };
    let before = stats_of(&d.join("views"));
    assert!(
        gap(before.mean) > 0.1,
        "the test needs an object far from the style's colours"
    );
    let mut base = distill_args(d, &stylizer);
    let si = base.iter().position(|a| a == "--style").unwrap();
    base[si + 1] = style_path.to_string_lossy().into_owned();
    ok(bin("distill")
        .args(&base)
        .args(["--scene", &scene.to_string_lossy(), "--iters", "0"])
        .args(["--start", "colour", "--out"])
        .arg(d.join("init")));
    let cams = d.join("views");
    // The scene in `dir`, rendered from the source cameras into `views`, has the
    // style's object colour mean (within 0.03) after `flag`.
    let on_style_mean = |dir: &std::path::Path, views: &std::path::Path, flag: &str| {
        render_source(dir, &cams.to_string_lossy(), 48, views);
        let got = stats_of(views);
        assert!(
            gap(got.mean) < 0.03,
            "object mean {:?} after {flag}, style mean {:?}",
            got.mean,
            style.mean
        );
    };
    on_style_mean(&d.join("init"), &d.join("after"), "--start colour");
    start_on_resume_and_beside_preserve_color(
        &base,
        ["--start", "colour"],
        &d.join("init"),
        &scene,
        d,
    );

    // --colour-finish: two iterations from the scene's own colours, then the move.
    let scene_arg = ["--scene".to_string(), scene.to_string_lossy().into_owned()];
    ok(bin("distill")
        .args(&base)
        .args(&scene_arg)
        .args(["--iters", "2", "--finish", "colour", "--out"])
        .arg(d.join("fin")));
    on_style_mean(&d.join("fin"), &d.join("fin-views"), "--finish colour");
    let mut cmd = bin("distill");
    cmd.args(&base)
        .args(&scene_arg)
        .args(["--iters", "1", "--finish", "colour"])
        .args(["--set", "preserve_color=true"]);
    refused_with(cmd, "preserve_color", &d.join("y"));
}

/// `--start projection`: the style texture-mapped onto the object shows the style's
/// stripes in every view (red/blue alternations along image rows or columns inside the
/// object, at least twice as many as after `--start colour`, which moves the same colours
/// onto the object without their arrangement); the view-dependent SH coefficients are
/// zeroed; a resumed run is not projected again, and `preserve_color` is refused beside
/// it (exit 2, nothing written).
#[test]
fn project_style_paints_the_stripes_in_every_view() {
    let Some(stylizer) = stylizer_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo_root().join("data-sample/scene.ply");
    let cams = "orbit:4,elev=30,radius=2.4";
    render_source(&scene, cams, 96, &d.join("views"));
    // Vertical stripes, 4 px red, 4 px blue, at the texture term's size (256).
    let style_path = d.join("stripes.png");
    let px: Vec<u8> = (0..256 * 256 * 3)
        .map(|i| {
            let (x, c) = ((i / 3) % 256, i % 3);
            let red = (x / 4) % 2 == 0;
            [[220u8, 30, 30], [30, 40, 220]][usize::from(!red)][c]
        })
        .collect();
    image::save_buffer(&style_path, &px, 256, 256, image::ColorType::Rgb8).unwrap();
    let mut base = distill_args(d, &stylizer);
    let si = base.iter().position(|a| a == "--style").unwrap();
    base[si + 1] = style_path.to_string_lossy().into_owned();
    let scene_arg = ["--scene".to_string(), scene.to_string_lossy().into_owned()];
    for (start, out) in [("projection", "proj"), ("colour", "init")] {
        ok(bin("distill")
            .args(&base)
            .args(&scene_arg)
            .args(["--iters", "0", "--start", start, "--out"])
            .arg(d.join(out)));
        render_source(
            &d.join(out),
            &d.join("views").to_string_lossy(),
            96,
            &d.join(format!("{out}-views")),
        );
    }
    // Red/blue alternations per object pixel along the rows and along the columns of each
    // view, the larger of the two (stripes on a face seen edge-on run along the rows).
    let alternations = |dir: &Path| -> Vec<f64> {
        let v = fantasystyle::artifacts::read_views(dir).unwrap();
        let src = v.source_views();
        let (w, h) = (src.width, src.height);
        let count =
            |rgb: &[f32], alpha: &[f32], at: &dyn Fn(usize, usize) -> usize, n: usize, m: usize| {
                let (mut flips, mut pixels) = (0usize, 0usize);
                for i in 0..n {
                    let mut last = 0i8;
                    for j in 0..m {
                        let p = at(i, j);
                        if alpha[p] < 0.9 {
                            last = 0;
                            continue;
                        }
                        pixels += 1;
                        let rb = rgb[p * 3] - rgb[p * 3 + 2];
                        let now = if rb > 0.1 {
                            1
                        } else if rb < -0.1 {
                            -1
                        } else {
                            0
                        };
                        if now != 0 {
                            flips += usize::from(last != 0 && now != last);
                            last = now;
                        }
                    }
                }
                flips as f64 / pixels.max(1) as f64
            };
        (0..src.rgb.len())
            .map(|i| {
                let (rgb, alpha) = (&src.rgb[i], &src.alpha[i]);
                let rows = count(rgb, alpha, &|y, x| y * w + x, h, w);
                let cols = count(rgb, alpha, &|x, y| y * w + x, w, h);
                rows.max(cols)
            })
            .collect()
    };
    let (proj, init) = (
        alternations(&d.join("proj-views")),
        alternations(&d.join("init-views")),
    );
    // (The sample's checkerboard floor alternates too.)
    for (i, (p, c)) in proj.iter().zip(&init).enumerate() {
        assert!(
            *p > 0.15 && *p > 2.0 * c,
            "view {i}: {p:.3} alternations per object pixel after --start projection, \
             {c:.3} after --start colour"
        );
    }
    let projected = fantasystyle::scene::read_scene_file(&d.join("proj/scene.ply")).unwrap();
    assert!(projected.sh_rest.iter().all(|&v| v == 0.0));
    start_on_resume_and_beside_preserve_color(
        &base,
        ["--start", "projection"],
        &d.join("init"),
        &scene,
        d,
    );
}

/// The `split` stage: the sample scene's long Gaussians split in two until none is longer
/// than the configuration's `split` (or 8 rounds), with the renders kept (each pair has
/// its parent's mean and covariance); a negative or NaN length is refused (exit 2,
/// nothing written).
#[test]
fn split_px_splits_the_long_gaussians_and_keeps_the_renders() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let scene = repo_root().join("data-sample/scene.ply");
    render_source(&scene, "orbit:4,elev=30,radius=2.4", 96, &d.join("views"));
    let base = |px: &str| {
        let mut c = bin("split");
        c.arg("--scene")
            .arg(&scene)
            .arg("--source-views")
            .arg(d.join("views"))
            .args(["--set", &format!("split={px}")]);
        c
    };
    ok(base("1").arg("--out").arg(d.join("split")));
    let original = fantasystyle::scene::read_scene_file(&scene).unwrap();
    let split = fantasystyle::scene::read_scene_file(&d.join("split/scene.ply")).unwrap();
    let views = d.join("views").to_string_lossy().into_owned();
    render_source(&d.join("split"), &views, 96, &d.join("split-views"));
    let [a, b] = [d.join("views"), d.join("split-views")]
        .map(|p| fantasystyle::artifacts::read_views(&p).unwrap());
    let (a, b) = (a.source_views(), b.source_views());
    let worst = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .map(|(x, y)| fantasystyle::optim::psnr(x, y))
        .fold(f64::INFINITY, f64::min);
    assert!(
        split.len() > 2 * original.len() && worst > 33.0,
        "{} -> {} Gaussians, worst PSNR {worst:.1} dB",
        original.len(),
        split.len()
    );
    for bad in ["-1", "NaN"] {
        refused_with(base(bad), "split", &d.join("x"));
    }
}

/// A start (`start`: the flag and its value) changes nothing on a resumed checkpoint,
/// which has been through its start (`--resume resumed --iters 0` writes its scene as it
/// is), and is refused on `--scene scene` beside `preserve_color` ([`refused_with`]: exit
/// 2 naming `preserve_color`, nothing written); outputs under `d`.
fn start_on_resume_and_beside_preserve_color(
    base: &[String],
    start: [&str; 2],
    resumed: &Path,
    scene: &Path,
    d: &Path,
) {
    let again = d.join("resumed-again");
    ok(bin("distill")
        .args(base)
        .arg("--resume")
        .arg(resumed)
        .args(["--iters", "0"])
        .args(start)
        .arg("--out")
        .arg(&again));
    same_bytes(resumed, &again, &["scene.ply"]);
    let mut cmd = bin("distill");
    cmd.args(base)
        .arg("--scene")
        .arg(scene)
        .args(["--iters", "1", "--set", "preserve_color=true"])
        .args(start);
    refused_with(cmd, "preserve_color", &d.join("x"));
}

/// `cmd` with `--out out` exits 2 naming `flag` in its message and writes nothing.
fn refused_with(mut cmd: std::process::Command, flag: &str, out: &std::path::Path) {
    let run = cmd.arg("--out").arg(out).output().unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{cmd:?}: {err}");
    assert!(err.contains(flag), "{err}");
    assert!(!out.exists());
}

//! Issue 19: `.spz` scenes. A written `.spz` read back renders like the `.ply` it came
//! from within the bounds `fantasystyle::scene::spz` states, and bad files are refused by
//! the stages with the file named and exit code 2, nothing written.

use crate::harness;
use fantasystyle::artifacts::load_scene;
use fantasystyle::render::{RenderOptions, render};
use fantasystyle::scene::spz::{SPZ_RENDER_MAX, SPZ_RENDER_MEAN, write_spz};
use std::path::Path;
use std::process::Command;

/// Max and mean absolute RGB difference of the renders of two scenes from `cams`.
fn render_diff(
    a: &fantasystyle::Scene,
    b: &fantasystyle::Scene,
    cams: &[fantasystyle::Camera],
) -> (f32, f64) {
    let (mut worst, mut sum, mut cnt) = (0.0f32, 0.0f64, 0usize);
    for c in cams {
        let x = render(a, c, &RenderOptions::default()).unwrap();
        let y = render(b, c, &RenderOptions::default()).unwrap();
        for (p, q) in x.rgb.iter().zip(&y.rgb) {
            let d = (p.clamp(0.0, 1.0) - q.clamp(0.0, 1.0)).abs();
            worst = worst.max(d);
            sum += d as f64;
            cnt += 1;
        }
    }
    (worst, sum / cnt as f64)
}

/// The sample scene (SH degree 1) written as `.spz`, read back through the scene loader
/// and rendered from four orbit views at 128x128: against the `.ply`'s renders, within
/// `SPZ_RENDER_MAX` / `SPZ_RENDER_MEAN` (the measured values are printed).
#[test]
fn written_spz_renders_like_the_ply() {
    let root = harness::repo_root();
    let ply = root.join("data-sample/scene.ply");
    let s = load_scene(&ply).unwrap();
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("scene.spz");
    write_spz(&p, &s).unwrap();
    let r = load_scene(&p).unwrap();
    assert_eq!((r.len(), r.sh_degree), (s.len(), s.sh_degree));
    let cams = fantasystyle::camera::load_cameras("orbit:4", &s.bounds(), 128, 128).unwrap();
    let (worst, mean) = render_diff(&s, &r, &cams);
    let (ply_len, spz_len) = (
        std::fs::metadata(&ply).unwrap().len(),
        std::fs::metadata(&p).unwrap().len(),
    );
    eprintln!(
        "spz vs ply renders: max {worst:.4}, mean {mean:.2e}; sizes: .ply {ply_len} B, \
         .spz {spz_len} B ({:.1}x smaller)",
        ply_len as f64 / spz_len as f64
    );
    assert!(
        worst < SPZ_RENDER_MAX && mean < SPZ_RENDER_MEAN,
        "max {worst}, mean {mean}"
    );
    // A real capture (SH degree 0), when the shared scenes are there.
    if let Some(bob) = harness::shared_scene("bob_10k.splat") {
        let s = load_scene(&bob).unwrap();
        let q = d.path().join("bob.spz");
        write_spz(&q, &s).unwrap();
        let r = load_scene(&q).unwrap();
        let cams = fantasystyle::camera::load_cameras("orbit:4", &s.bounds(), 128, 128).unwrap();
        let (worst, mean) = render_diff(&s, &r, &cams);
        eprintln!("bob_10k: spz vs splat renders: max {worst:.4}, mean {mean:.2e}");
        assert!(
            worst < SPZ_RENDER_MAX && mean < SPZ_RENDER_MEAN,
            "max {worst}, mean {mean}"
        );
    }
    // Written again, a read .spz loses nothing more.
    let p2 = d.path().join("again.spz");
    write_spz(&p2, &r).unwrap();
    let r2 = load_scene(&p2).unwrap();
    let (w2, m2) = render_diff(&r, &r2, &cams[..1]);
    assert!(
        w2 < 1e-3 && m2 < 1e-5,
        "second generation: max {w2}, mean {m2}"
    );
}

/// Run `render-views` on `scene`; (exit code, stderr).
fn render_views(scene: &Path, out: &Path) -> (i32, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_render-views"))
        .arg("--scene")
        .arg(scene)
        .args(["--cameras", "orbit:2", "--width", "16", "--height", "16"])
        .arg("--out")
        .arg(out)
        .env("RUST_LOG", "error")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!err.contains("panicked"), "render-views panicked: {err}");
    (o.status.code().unwrap_or(-1), err)
}

/// A `.spz` renders through the stages like any scene file; broken ones (not gzip,
/// truncated, a count the data does not hold) are refused with exit code 2, the file
/// named, and no output.
#[test]
fn stages_read_spz_and_refuse_broken_ones() {
    let d = tempfile::tempdir().unwrap();
    let s = load_scene(&harness::repo_root().join("data-sample/scene.ply")).unwrap();
    let good = d.path().join("good.spz");
    write_spz(&good, &s).unwrap();
    let (code, err) = render_views(&good, &d.path().join("ok"));
    assert_eq!(code, 0, "{err}");
    assert!(d.path().join("ok/rgb.npy").is_file());

    let bytes = std::fs::read(&good).unwrap();
    let mut raw = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::GzDecoder::new(&bytes[..]), &mut raw).unwrap();
    let gzip = |raw: &[u8]| {
        let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        std::io::Write::write_all(&mut e, raw).unwrap();
        e.finish().unwrap()
    };
    let mut lying = raw.clone();
    lying[8..12].copy_from_slice(&2_000_000_000u32.to_le_bytes());
    let cases: [(&str, Vec<u8>, &str); 5] = [
        ("text.spz", b"not a splat".to_vec(), "not a gzip stream"),
        ("plain.spz", raw.clone(), "uncompressed .spz stream"),
        ("cut.spz", bytes[..bytes.len() / 3].to_vec(), "corrupt gzip"),
        ("short.spz", gzip(&raw[..raw.len() - 100]), "truncated"),
        ("lying.spz", gzip(&lying), "2000000000 Gaussians"),
    ];
    for (name, b, msg) in cases {
        let p = d.path().join(name);
        std::fs::write(&p, b).unwrap();
        let out = d.path().join(format!("out-{name}"));
        let (code, err) = render_views(&p, &out);
        assert_eq!(code, 2, "{name}: {err}");
        assert!(err.contains(name) && err.contains(msg), "{name}: {err}");
        assert!(!out.exists(), "{name}: nothing written on failure");
    }
}

//! Bad input to scene and camera I/O, every case of the foundation issue: each asserts
//! the library's message and `render-views`' exit code + message (PLY and `.splat`
//! files, cameras, image size, output path; a failed run keeps the previous output),
//! and `render-views --help` documents every flag.

use crate::scene::{render_views, scene};
use fantasystyle::artifacts::load_scene;
use fantasystyle::camera::{self, load_cameras};
use fantasystyle::scene::ply;
use std::path::{Path, PathBuf};
use std::process::Command;

/// A valid 3-Gaussian PLY as bytes.
fn good_ply() -> Vec<u8> {
    ply::encode_ply(&scene(3, 1, 1))
}

fn replace(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let pos = bytes
        .windows(from.len())
        .position(|w| w == from.as_bytes())
        .unwrap();
    let mut v = bytes[..pos].to_vec();
    v.extend_from_slice(to.as_bytes());
    v.extend_from_slice(&bytes[pos + from.len()..]);
    v
}

/// The library refuses `bytes` (written as `name`) with `msg`; so does `render-views`,
/// with exit code 2, naming the file.
fn refused_scene(name: &str, bytes: &[u8], msg: &str) {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join(name);
    std::fs::write(&p, bytes).unwrap();
    let e = load_scene(&p).unwrap_err();
    let s = e.to_string();
    assert!(s.contains(name) && s.contains(msg), "library: {s}");
    assert_eq!(e.exit_code(), 2);
    let out = d.path().join("out");
    let (code, err) = render_views(&[
        "--scene",
        p.to_str().unwrap(),
        "--cameras",
        "orbit:2",
        "--width",
        "16",
        "--height",
        "16",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains(name) && err.contains(msg), "binary: {err}");
    assert!(!out.exists(), "nothing written on failure");
}

#[test]
fn bad_ply_truncated() {
    let b = good_ply();
    refused_scene("trunc.ply", &b[..b.len() - 7], "truncated");
}

#[test]
fn bad_ply_header_count_lies_too_many() {
    let b = replace(&good_ply(), "element vertex 3", "element vertex 4");
    refused_scene("more.ply", &b, "the count lies");
}

#[test]
fn bad_ply_header_count_lies_too_few() {
    let b = replace(&good_ply(), "element vertex 3", "element vertex 2");
    refused_scene("fewer.ply", &b, "trailing data");
}

#[test]
fn bad_ply_unknown_property_type() {
    let b = replace(
        &good_ply(),
        "property float opacity",
        "property half opacity",
    );
    refused_scene("type.ply", &b, "unknown property type `half`");
}

#[test]
fn bad_ply_missing_required_property() {
    let b = replace(&good_ply(), "property float rot_3", "property float rot_9");
    refused_scene(
        "missing.ply",
        &b,
        "missing required vertex property `rot_3`",
    );
}

#[test]
fn bad_ply_no_end_header() {
    let b = replace(&good_ply(), "end_header", "end_headex");
    refused_scene("noend.ply", &b, "no `end_header`");
}

#[test]
fn bad_ply_big_endian_refused() {
    let b = replace(&good_ply(), "binary_little_endian", "binary_big_endian");
    refused_scene("be.ply", &b, "big-endian");
}

#[test]
fn bad_ply_nan_position() {
    let mut s = scene(3, 1, 1);
    s.positions[1][2] = f32::NAN;
    refused_scene("nan.ply", &ply::encode_ply(&s), "Gaussian 1: position");
}

#[test]
fn bad_ply_infinite_position() {
    let mut s = scene(3, 0, 1);
    s.positions[2][0] = f32::INFINITY;
    refused_scene("inf.ply", &ply::encode_ply(&s), "not finite");
}

#[test]
fn bad_ply_zero_quaternion() {
    let mut s = scene(3, 1, 1);
    s.rotations[0] = [0.0; 4];
    refused_scene(
        "zeroq.ply",
        &ply::encode_ply(&s),
        "quaternion [0.0, 0.0, 0.0, 0.0] is zero",
    );
}

#[test]
fn bad_ply_huge_scale() {
    let mut s = scene(3, 1, 1);
    s.log_scales[2][1] = 40.0;
    refused_scene("huge.ply", &ply::encode_ply(&s), "absurdly large");
}

#[test]
fn bad_ply_nan_scale() {
    let mut s = scene(3, 1, 1);
    s.log_scales[0][0] = f32::NAN;
    refused_scene("nanscale.ply", &ply::encode_ply(&s), "log-scale");
}

fn splat_record(p: [f32; 3], s: [f32; 3]) -> Vec<u8> {
    let mut b = Vec::new();
    for v in p.iter().chain(&s) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&[200, 100, 50, 255, 255, 128, 128, 128]);
    b
}

#[test]
fn bad_splat_negative_scale() {
    let mut b = splat_record([0.0; 3], [0.1; 3]);
    b.extend(splat_record([1.0; 3], [0.1, -0.2, 0.1]));
    refused_scene("neg.splat", &b, "Gaussian 1: scale");
}

#[test]
fn bad_splat_huge_scale() {
    let b = splat_record([0.0; 3], [1e12, 0.1, 0.1]);
    refused_scene("huge.splat", &b, "absurdly large");
}

#[test]
fn bad_splat_truncated() {
    let b = splat_record([0.0; 3], [0.1; 3]);
    refused_scene("short.splat", &b[..20], "multiple of the 32-byte");
}

#[test]
fn bad_splat_nan_position() {
    let b = splat_record([0.0, f32::NAN, 0.0], [0.1; 3]);
    refused_scene("nan.splat", &b, "position");
}

/// A scene file and an INRIA cameras.json in `d`.
fn good_inputs(d: &Path) -> (PathBuf, PathBuf) {
    let sp = d.join("s.ply");
    ply::write_ply(&sp, &scene(20, 0, 3)).unwrap();
    let cams = load_cameras("orbit:2", &scene(20, 0, 3).bounds(), 32, 24).unwrap();
    let cp = d.join("cameras.json");
    camera::inria::write_inria(&cp, &cams).unwrap();
    (sp, cp)
}

#[test]
fn bad_camera_rotation_not_orthonormal() {
    let d = tempfile::tempdir().unwrap();
    let (sp, cp) = good_inputs(d.path());
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cp).unwrap()).unwrap();
    v[1]["rotation"][0][0] = serde_json::json!(1.5);
    std::fs::write(&cp, serde_json::to_string(&v).unwrap()).unwrap();
    let e = load_cameras(cp.to_str().unwrap(), &scene(1, 0, 0).bounds(), 32, 24)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("cameras.json") && e.contains("orbit_001") && e.contains("not orthonormal"),
        "{e}"
    );
    let out = d.path().join("out");
    let (code, err) = render_views(&[
        "--scene",
        sp.to_str().unwrap(),
        "--cameras",
        cp.to_str().unwrap(),
        "--width",
        "32",
        "--height",
        "24",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(
        err.contains("cameras.json") && err.contains("not orthonormal"),
        "{err}"
    );
}

#[test]
fn bad_camera_reflection_refused() {
    let d = tempfile::tempdir().unwrap();
    let (_, cp) = good_inputs(d.path());
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&cp).unwrap()).unwrap();
    for k in 0..3 {
        let x = v[0]["rotation"][k][2].as_f64().unwrap();
        v[0]["rotation"][k][2] = serde_json::json!(-x);
    }
    std::fs::write(&cp, serde_json::to_string(&v).unwrap()).unwrap();
    let e = load_cameras(cp.to_str().unwrap(), &scene(1, 0, 0).bounds(), 32, 24)
        .unwrap_err()
        .to_string();
    assert!(e.contains("determinant"), "{e}");
}

#[test]
fn bad_zero_image_size() {
    let d = tempfile::tempdir().unwrap();
    let (sp, _) = good_inputs(d.path());
    let e = load_cameras("orbit:2", &scene(2, 0, 0).bounds(), 0, 24)
        .unwrap_err()
        .to_string();
    assert!(e.contains("image size 0x24"), "{e}");
    for (w, h) in [("0", "24"), ("32", "0")] {
        let (code, err) = render_views(&[
            "--scene",
            sp.to_str().unwrap(),
            "--cameras",
            "orbit:2",
            "--width",
            w,
            "--height",
            h,
            "--out",
            d.path().join("out").to_str().unwrap(),
        ]);
        assert_eq!(code, 2, "{err}");
        assert!(err.contains("must be positive"), "{err}");
    }
}

#[test]
fn bad_unwritable_output_path() {
    let d = tempfile::tempdir().unwrap();
    let (sp, _) = good_inputs(d.path());
    // --out below a regular file.
    let file = d.path().join("a_file");
    std::fs::write(&file, b"x").unwrap();
    let out = file.join("views");
    let (code, err) = render_views(&[
        "--scene",
        sp.to_str().unwrap(),
        "--cameras",
        "orbit:2",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 4, "{err}");
    assert!(
        err.contains("a_file/views") && err.contains("cannot create the output artifact"),
        "{err}"
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
    // A read-only directory (not enforceable when the tests run as root).
    use std::os::unix::fs::PermissionsExt;
    let ro = d.path().join("ro");
    std::fs::create_dir(&ro).unwrap();
    std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
    if std::fs::write(ro.join("probe"), b"").is_ok() {
        eprintln!(
            "SKIPPED (cannot run as root, also under CI): read-only directory case, permissions not enforced"
        );
        return;
    }
    let (code, err) = render_views(&[
        "--scene",
        sp.to_str().unwrap(),
        "--cameras",
        "orbit:2",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        ro.join("views").to_str().unwrap(),
    ]);
    assert_eq!(code, 4, "{err}");
    assert!(err.contains("ro/views"), "{err}");
}

#[test]
fn out_must_not_be_a_non_artifact_directory() {
    let d = tempfile::tempdir().unwrap();
    let (sp, _) = good_inputs(d.path());
    // d itself holds the user's files: render-views must not replace it.
    let (code, err) = render_views(&[
        "--scene",
        sp.to_str().unwrap(),
        "--cameras",
        "orbit:1",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        d.path().to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("refusing to replace"), "{err}");
    assert!(sp.is_file());
}

#[test]
fn failed_run_keeps_the_previous_output() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    std::fs::create_dir(&out).unwrap();
    std::fs::write(out.join("keep.txt"), b"old").unwrap();
    let bad = d.path().join("bad.ply");
    std::fs::write(&bad, b"ply\nformat ascii 1.0\n").unwrap();
    let (code, err) = render_views(&[
        "--scene",
        bad.to_str().unwrap(),
        "--cameras",
        "orbit:1",
        "--width",
        "8",
        "--height",
        "8",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 2, "{err}");
    assert_eq!(std::fs::read(out.join("keep.txt")).unwrap(), b"old");
    assert_eq!(std::fs::read_dir(d.path()).unwrap().count(), 2);
}

#[test]
fn render_views_help_documents_every_flag() {
    let out = Command::new(env!("CARGO_BIN_EXE_render-views"))
        .arg("--help")
        .output()
        .unwrap();
    let h = String::from_utf8_lossy(&out.stdout);
    for f in [
        "--scene",
        "--cameras",
        "--width",
        "--height",
        "--out",
        "--background",
        "--threads",
    ] {
        let line = h
            .lines()
            .find(|l| l.trim_start().starts_with(f))
            .unwrap_or("");
        assert!(
            line.split(f).nth(1).is_some_and(|r| r.len() > 12),
            "{f}: {h}"
        );
    }
}

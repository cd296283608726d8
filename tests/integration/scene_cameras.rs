//! Camera readers on hand-made fixtures: COLMAP (text and binary models, and the text
//! writer's round trip), nerfstudio `transforms.json`, and INRIA `cameras.json` in an
//! artifact directory.

use crate::scene::scene;
use fantasystyle::camera::load_cameras;
use fantasystyle::camera::{self, Camera};
use std::path::Path;

// Camera readers on hand-made fixtures. Expected values are derived by hand:
// camera 1: identity rotation, t = (0, 0, 5): the world origin is 5 in front of it and
// projects to the principal point (50, 40); (1, 0, 0) lands fx/5 = 20 px to the right.
// camera 2: q = (cos 45, 0, sin 45, 0) is +90 degrees about y, R = [[0,0,1],[0,1,0],[-1,0,0]],
// t = (0, 0, 4): its centre is -R^T t = (4, 0, 0) and it sees (-4, 0, 0) at depth 8 at its
// principal point (32, 24); (-4, 1, 0) lands f/8 = 11.25 px below.

const CAMERAS_TXT: &str = "\
# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
1 PINHOLE 100 80 100 120 50 40
2 SIMPLE_RADIAL 64 48 90 32 24 0.01
";

const IMAGES_TXT: &str = "\
# Image list with two lines of data per image:
#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME
#   POINTS2D[] as (X, Y, POINT3D_ID)
7 0.7071067811865476 0 0.7071067811865476 0 0 0 4 2 b.png
1.0 2.0 -1
3 1 0 0 0 0 0 5 1 a.png

";

fn colmap_bin(dir: &Path) {
    let mut c = 2u64.to_le_bytes().to_vec();
    let cam = |c: &mut Vec<u8>, id: i32, model: i32, w: u64, h: u64, p: &[f64]| {
        c.extend_from_slice(&id.to_le_bytes());
        c.extend_from_slice(&model.to_le_bytes());
        c.extend_from_slice(&w.to_le_bytes());
        c.extend_from_slice(&h.to_le_bytes());
        for v in p {
            c.extend_from_slice(&v.to_le_bytes());
        }
    };
    cam(&mut c, 1, 1, 100, 80, &[100.0, 120.0, 50.0, 40.0]);
    cam(&mut c, 2, 2, 64, 48, &[90.0, 32.0, 24.0, 0.01]);
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    let mut b = 2u64.to_le_bytes().to_vec();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let img =
        |b: &mut Vec<u8>, id: i32, q: [f64; 4], t: [f64; 3], cid: i32, name: &str, pts: u64| {
            b.extend_from_slice(&id.to_le_bytes());
            for v in q.iter().chain(&t) {
                b.extend_from_slice(&v.to_le_bytes());
            }
            b.extend_from_slice(&cid.to_le_bytes());
            b.extend_from_slice(name.as_bytes());
            b.push(0);
            b.extend_from_slice(&pts.to_le_bytes());
            for _ in 0..pts {
                b.extend_from_slice(&[0u8; 24]);
            }
        };
    img(&mut b, 7, [h, 0.0, h, 0.0], [0.0, 0.0, 4.0], 2, "b.png", 2);
    img(
        &mut b,
        3,
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 5.0],
        1,
        "a.png",
        0,
    );
    std::fs::write(dir.join("images.bin"), b).unwrap();
}

fn check_colmap_cameras(c: &[Camera]) {
    assert_eq!(c.len(), 2);
    assert_eq!((c[0].name.as_str(), c[1].name.as_str()), ("a.png", "b.png"));
    let (uv, z) = c[0].project([0.0, 0.0, 0.0]);
    assert!((uv[0] - 50.0).abs() < 1e-4 && (uv[1] - 40.0).abs() < 1e-4 && (z - 5.0).abs() < 1e-6);
    assert!((c[0].project([1.0, 0.0, 0.0]).0[0] - 70.0).abs() < 1e-4);
    assert_eq!(
        (c[0].fx, c[0].fy, c[0].width, c[0].height),
        (100.0, 120.0, 100, 80)
    );
    let ce = c[1].center();
    assert!((ce[0] - 4.0).abs() < 1e-5 && ce[1].abs() < 1e-6 && ce[2].abs() < 1e-5);
    let (uv, z) = c[1].project([-4.0, 0.0, 0.0]);
    assert!((uv[0] - 32.0).abs() < 1e-4 && (uv[1] - 24.0).abs() < 1e-4 && (z - 8.0).abs() < 1e-5);
    assert!((c[1].project([-4.0, 1.0, 0.0]).0[1] - 35.25).abs() < 1e-4);
    assert_eq!((c[1].fx, c[1].fy), (90.0, 90.0));
}

#[test]
fn colmap_text_model() {
    let d = tempfile::tempdir().unwrap();
    let sp = d.path().join("sparse/0");
    std::fs::create_dir_all(&sp).unwrap();
    std::fs::write(sp.join("cameras.txt"), CAMERAS_TXT).unwrap();
    std::fs::write(sp.join("images.txt"), IMAGES_TXT).unwrap();
    check_colmap_cameras(&camera::colmap::read_colmap(&sp).unwrap());
    // Through the dispatcher: the sparse/0 dir, or the dataset dir holding it; intrinsics
    // rescaled to the requested size.
    let s = scene(2, 0, 0);
    let c = load_cameras(d.path().to_str().unwrap(), &s.bounds(), 200, 160).unwrap();
    assert_eq!((c[0].fx, c[0].cx, c[0].width), (200.0, 100.0, 200));
    // A bad line names the file and the line.
    std::fs::write(sp.join("images.txt"), "1 1 0 0 0 0 0 5 9 a.png\n\n").unwrap();
    let e = camera::colmap::read_colmap(&sp).unwrap_err().to_string();
    assert!(e.contains("images.txt") && e.contains("camera 9"), "{e}");
}

#[test]
fn colmap_binary_model() {
    let d = tempfile::tempdir().unwrap();
    colmap_bin(d.path());
    check_colmap_cameras(&camera::colmap::read_colmap(d.path()).unwrap());
    // Truncated images.bin: named, no panic.
    let p = d.path().join("images.bin");
    let b = std::fs::read(&p).unwrap();
    std::fs::write(&p, &b[..b.len() - 5]).unwrap();
    let e = camera::colmap::read_colmap(d.path())
        .unwrap_err()
        .to_string();
    assert!(e.contains("images.bin") && e.contains("truncated"), "{e}");
}

#[test]
fn colmap_text_writer_round_trips() {
    let d = tempfile::tempdir().unwrap();
    let s = scene(30, 0, 4);
    let cams = load_cameras("orbit:5,elev=40", &s.bounds(), 40, 30).unwrap();
    camera::colmap::write_colmap_txt(d.path(), &cams).unwrap();
    let back = camera::colmap::read_colmap(d.path()).unwrap();
    for (a, b) in cams.iter().zip(&back) {
        assert_eq!(a.name, b.name);
        for i in 0..3 {
            assert!((a.translation[i] - b.translation[i]).abs() < 1e-5);
            for j in 0..3 {
                assert!((a.rotation[i][j] - b.rotation[i][j]).abs() < 1e-6);
            }
        }
    }
}

#[test]
fn nerfstudio_transforms() {
    // Frame a: OpenGL identity pose at (0, 0, 4): looks along -z at the origin, y up.
    // Frame b: +90 degrees about y at (4, 0, 0): its -z axis is world -x, so it also looks
    // at the origin; it overrides fl_x and the size.
    let j = serde_json::json!({
    "camera_model": "OPENCV", "fl_x": 60.0, "fl_y": 60.0, "cx": 31.5, "cy": 23.5,
    "w": 64, "h": 48, "k1": 0.0,
    "frames": [
        {"file_path": "images/a.png", "transform_matrix":
            [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]},
        {"file_path": "images/b.png", "fl_x": 30.0, "fl_y": 30.0, "cx": 16.0, "cy": 12.0,
         "w": 32, "h": 24, "transform_matrix":
            [[0,0,1,4],[0,1,0,0],[-1,0,0,0],[0,0,0,1]]}
    ]});
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("transforms.json");
    std::fs::write(&p, j.to_string()).unwrap();
    let (c, _) = camera::load_camera_file(&p).unwrap();
    let (uv, z) = c[0].project([0.0, 0.0, 0.0]);
    assert_eq!((uv, z), ([31.5, 23.5], 4.0));
    // World +y is up for a GL camera: (0, 1, 0) appears above the centre (smaller v).
    assert!((c[0].project([0.0, 1.0, 0.0]).0[1] - (23.5 - 15.0)).abs() < 1e-5);
    // World +x appears to the right.
    assert!(c[0].project([1.0, 0.0, 0.0]).0[0] > 31.5);
    let (uv, z) = c[1].project([0.0, 0.0, 0.0]);
    assert!((uv[0] - 16.0).abs() < 1e-5 && (uv[1] - 12.0).abs() < 1e-5 && (z - 4.0).abs() < 1e-6);
    assert_eq!((c[1].width, c[1].fx), (32, 30.0));
    // Through the dispatcher (directory holding transforms.json), rescaled to 128x96.
    let s = scene(2, 0, 0);
    let c = load_cameras(d.path().to_str().unwrap(), &s.bounds(), 128, 96).unwrap();
    assert_eq!((c[0].fx, c[1].fx), (120.0, 120.0));
}

#[test]
fn inria_cameras_from_artifact_dir() {
    use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
    let d = tempfile::tempdir().unwrap();
    let s = scene(10, 0, 5);
    let cams = load_cameras("orbit:3", &s.bounds(), 16, 16).unwrap();
    let a = d.path().join("views");
    let mut w = ArtifactWriter::create(
        &a,
        ArtifactKind::Views,
        Producer::new("test", "0", serde_json::json!({})),
    )
    .unwrap();
    for n in ["rgb.npy", "depth.npy", "alpha.npy"] {
        w.write_tensor(n, &[1], &[0f32]).unwrap();
    }
    w.write_json("cameras.json", &camera::inria::to_inria(&cams))
        .unwrap();
    w.commit().unwrap();
    let back = load_cameras(a.to_str().unwrap(), &s.bounds(), 16, 16).unwrap();
    assert_eq!(back.len(), 3);
    for (x, y) in cams.iter().zip(&back) {
        assert_eq!(
            (x.name.as_str(), x.rotation, x.fx),
            (y.name.as_str(), y.rotation, y.fx)
        );
        for k in 0..3 {
            assert!((x.translation[k] - y.translation[k]).abs() < 1e-5);
        }
    }
}

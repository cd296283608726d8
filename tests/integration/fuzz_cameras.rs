//! Fuzzing the camera readers (the machinery is in `fuzz`): INRIA `cameras.json`,
//! nerfstudio `transforms.json`, COLMAP text and binary models; a returned camera set
//! is valid.

use crate::fuzz::{apply, apply_lines, edit, fuzz, guarded, json_case, line_edit, names_file, tmp};
use crate::fuzz_scenes::scene;
use fantasystyle::camera::{Camera, colmap, inria, load_cameras};
use proptest::prelude::*;
use std::path::{Path, PathBuf};

fn orbit_cams(n: usize) -> Vec<Camera> {
    let b = scene(4, 0, 1).bounds();
    load_cameras(&format!("orbit:{n}"), &b, 64, 48).unwrap()
}

/// Load `path` as `load_cameras` does for a stage (and resize to 32x24); a returned
/// camera set must be valid.
fn check_cameras(path: PathBuf, name: &str, len: usize) -> Result<(), String> {
    let r = guarded(len, move || {
        let b = scene(4, 0, 1).bounds();
        load_cameras(path.to_str().unwrap(), &b, 32, 24)
    })?;
    names_file(&r, name)?;
    if let Ok(cams) = r {
        if cams.is_empty() {
            return Err("an empty camera list was accepted".into());
        }
        for c in &cams {
            c.validate(Path::new(name))
                .map_err(|e| format!("returned an invalid camera: {e}"))?;
        }
    }
    Ok(())
}

#[test]
fn fuzz_inria_cameras_json() {
    let seeds: Vec<serde_json::Value> = [1, 3, 6]
        .iter()
        .map(|&n| serde_json::to_value(inria::to_inria(&orbit_cams(n))).unwrap())
        .collect();
    let d = tmp();
    let p = d.path().join("cameras.json");
    fuzz("cameras.json", 2000, json_case(seeds), |(b, _)| {
        std::fs::write(&p, &b).unwrap();
        check_cameras(p.clone(), "cameras.json", b.len())
    });
}

#[test]
fn fuzz_transforms_json() {
    let frame = |i: usize| {
        serde_json::json!({
            "file_path": format!("images/{i:03}.png"),
            "transform_matrix": [[1.0, 0.0, 0.0, 0.1 * i as f64], [0.0, 1.0, 0.0, 0.0],
                                 [0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, 1.0]],
        })
    };
    let seeds = vec![
        serde_json::json!({"fl_x": 50.0, "fl_y": 52.0, "cx": 32.0, "cy": 24.0, "w": 64, "h": 48,
                           "k1": 0.01, "camera_model": "OPENCV",
                           "frames": [frame(0), frame(1), frame(2)]}),
        serde_json::json!({"camera_angle_x": 0.69, "frames": [frame(0), frame(1)]}),
    ];
    let d = tmp();
    let p = d.path().join("transforms.json");
    fuzz("transforms.json", 2000, json_case(seeds), |(b, _)| {
        std::fs::write(&p, &b).unwrap();
        check_cameras(p.clone(), "transforms.json", b.len())
    });
}

#[test]
fn fuzz_colmap_text() {
    let d = tmp();
    let mut seeds = Vec::new();
    for n in [1, 3] {
        colmap::write_colmap_txt(d.path(), &orbit_cams(n)).unwrap();
        seeds.push((
            std::fs::read(d.path().join("cameras.txt")).unwrap(),
            std::fs::read(d.path().join("images.txt")).unwrap(),
        ));
    }
    let strategy = (
        prop::sample::select(seeds),
        any::<bool>(),
        prop::collection::vec(line_edit(), 0..3),
        prop::collection::vec(edit(), 0..3),
    );
    fuzz(
        "colmap-text",
        1500,
        strategy,
        |((mut c, mut i), which, lines, edits)| {
            let t = if which { &mut c } else { &mut i };
            apply_lines(t, &lines, None);
            apply(t, &edits);
            std::fs::write(d.path().join("cameras.txt"), &c).unwrap();
            std::fs::write(d.path().join("images.txt"), &i).unwrap();
            // The error names the model directory or one of its files.
            let r = {
                let dir = d.path().to_path_buf();
                guarded(c.len() + i.len(), move || colmap::read_colmap(&dir))?
            };
            names_file(&r, &d.path().display().to_string())?;
            if let Ok(cams) = &r {
                for cam in cams {
                    cam.validate(d.path())
                        .map_err(|e| format!("returned an invalid camera: {e}"))?;
                }
            }
            let shown = d.path().display().to_string();
            check_cameras(d.path().to_path_buf(), &shown, c.len() + i.len())
        },
    );
}

/// `cameras.bin` and `images.bin` for `cams` (COLMAP's binary layout, PINHOLE).
fn colmap_bin(cams: &[Camera]) -> (Vec<u8>, Vec<u8>) {
    let mut c = Vec::new();
    c.extend((cams.len() as u64).to_le_bytes());
    for (k, cam) in cams.iter().enumerate() {
        c.extend((k as i32 + 1).to_le_bytes());
        c.extend(1i32.to_le_bytes());
        c.extend((cam.width as u64).to_le_bytes());
        c.extend((cam.height as u64).to_le_bytes());
        for v in [cam.fx, cam.fy, cam.cx, cam.cy] {
            c.extend((v as f64).to_le_bytes());
        }
    }
    let mut i = Vec::new();
    i.extend((cams.len() as u64).to_le_bytes());
    for (k, cam) in cams.iter().enumerate() {
        i.extend((k as i32 + 1).to_le_bytes());
        let q = fantasystyle::geometry::mat_to_quat(fantasystyle::geometry::mat3(
            cam.rotation.map(|r| r.map(|v| v as f64)),
        ));
        for v in q {
            i.extend(v.to_le_bytes());
        }
        for v in cam.translation {
            i.extend((v as f64).to_le_bytes());
        }
        i.extend((k as i32 + 1).to_le_bytes());
        i.extend(format!("view_{k:03}.png\0").as_bytes());
        i.extend(2u64.to_le_bytes());
        i.extend([0u8; 48]);
    }
    (c, i)
}

#[test]
fn fuzz_colmap_binary() {
    let seeds: Vec<(Vec<u8>, Vec<u8>)> = [1, 2, 4]
        .iter()
        .map(|&n| colmap_bin(&orbit_cams(n)))
        .collect();
    let d = tmp();
    let (c0, i0) = &seeds[1];
    std::fs::write(d.path().join("cameras.bin"), c0).unwrap();
    std::fs::write(d.path().join("images.bin"), i0).unwrap();
    assert_eq!(
        colmap::read_colmap(d.path()).unwrap().len(),
        2,
        "the seed is valid"
    );
    let strategy = (
        prop::sample::select(seeds),
        any::<bool>(),
        prop::collection::vec(edit(), 0..4),
    );
    fuzz(
        "colmap-binary",
        2000,
        strategy,
        |((mut c, mut i), which, edits)| {
            apply(if which { &mut c } else { &mut i }, &edits);
            std::fs::write(d.path().join("cameras.bin"), &c).unwrap();
            std::fs::write(d.path().join("images.bin"), &i).unwrap();
            let dir = d.path().to_path_buf();
            let r = guarded(c.len() + i.len(), move || colmap::read_colmap(&dir))?;
            let shown = d.path().display().to_string();
            names_file(&r, &shown)?;
            check_cameras(d.path().to_path_buf(), &shown, c.len() + i.len())
        },
    );
}

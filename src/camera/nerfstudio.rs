//! nerfstudio / instant-ngp `transforms.json` (docs.nerf.studio, "Data conventions").
//!
//! An object with shared intrinsics (`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`, or the
//! Blender-style `camera_angle_x` / `camera_angle_y` field of view in radians) and
//! `frames`, each with `file_path` and a 4x4 `transform_matrix`; a frame may override any
//! intrinsic. `transform_matrix` is **camera-to-world in the OpenGL convention** (x right,
//! y up, z backward). We convert to OpenCV by negating the camera's y and z axes (the
//! second and third columns of the rotation): `C_cv = C_gl diag(1, -1, -1)`, the camera
//! centre being the fourth column. Defaults: `fl_y = fl_x`, `cx = w/2`, `cy = h/2`. When
//! neither file nor frame gives `w`/`h` (Blender synthetic scenes), a square 800x800
//! image is assumed (the Blender datasets' size); `load_cameras` rescales to the
//! requested size anyway. Distortion coefficients are ignored with a warning; fisheye and
//! equirectangular camera models are refused. Poses are used as given (nerfstudio's
//! dataparser re-centring and `applied_transform` are not applied).

use super::Camera;
use crate::{Error, Result};
use serde_json::Value;
use std::path::Path;

fn get_f64(v: &Value, k: &str) -> Option<f64> {
    v.get(k).and_then(Value::as_f64)
}

/// Parse a `transforms.json` object; `path` names the file in errors.
pub fn parse_transforms(path: &Path, v: &Value) -> Result<Vec<Camera>> {
    let frames = v
        .get("frames")
        .and_then(Value::as_array)
        .ok_or_else(|| Error::input(path, "transforms.json has no `frames` array"))?;
    if let Some(m) = v.get("camera_model").and_then(Value::as_str)
        && m != "OPENCV"
        && m != "PINHOLE"
        && m != "SIMPLE_PINHOLE"
    {
        return Err(Error::input(
            path,
            format!("camera_model {m} is not supported (pinhole/OPENCV only)"),
        ));
    }
    if ["k1", "k2", "k3", "k4", "p1", "p2"]
        .iter()
        .any(|k| get_f64(v, k).is_some_and(|x| x != 0.0))
    {
        tracing::warn!("{}: distortion coefficients ignored", path.display());
    }
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let name = f
            .get("file_path")
            .and_then(Value::as_str)
            .map(str::to_string)
            .unwrap_or_else(|| format!("frame_{i:03}"));
        let bad = |r: String| Error::input(path, format!("frame {i} (`{name}`): {r}"));
        // A frame value overrides the shared one.
        let k = |key: &str| get_f64(f, key).or_else(|| get_f64(v, key));
        let size = |key: &str| -> Result<u32> {
            match k(key) {
                None => Ok(800),
                Some(x) if x >= 1.0 && x <= u32::MAX as f64 && x.fract() == 0.0 => Ok(x as u32),
                Some(x) => Err(bad(format!("`{key}` = {x} is not a positive integer"))),
            }
        };
        let (w, h) = (size("w")?, size("h")?);
        let fx = match (k("fl_x"), k("camera_angle_x")) {
            (Some(f), _) => f,
            (None, Some(a)) => 0.5 * w as f64 / (0.5 * a).tan(),
            (None, None) => {
                return Err(bad("no focal length (`fl_x` or `camera_angle_x`)".into()));
            }
        };
        let fy = match (k("fl_y"), k("camera_angle_y")) {
            (Some(f), _) => f,
            (None, Some(a)) => 0.5 * h as f64 / (0.5 * a).tan(),
            (None, None) => fx,
        };
        let cx = k("cx").unwrap_or(0.5 * w as f64);
        let cy = k("cy").unwrap_or(0.5 * h as f64);
        let m: [[f64; 4]; 4] = f
            .get("transform_matrix")
            .ok_or_else(|| bad("no `transform_matrix`".into()))
            .and_then(|m| {
                serde_json::from_value(m.clone())
                    .map_err(|e| bad(format!("`transform_matrix` is not 4x4 numbers: {e}")))
            })?;
        let mut c2w = [[0.0; 3]; 3];
        for r in 0..3 {
            c2w[r] = [m[r][0], -m[r][1], -m[r][2]];
        }
        let center = [m[0][3], m[1][3], m[2][3]];
        let cam = Camera::from_c2w(name, w, h, [fx, fy, cx, cy], c2w, center);
        cam.validate(path)?;
        out.push(cam);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gl_camera_looking_down_minus_z_sees_a_point_in_front() {
        // Identity GL pose at (0, 0, 5): looks toward -z, y up. The origin is in front of
        // it (depth 5) at the image centre; a point at +y appears above the centre.
        let v = serde_json::json!({"fl_x": 100.0, "w": 64, "h": 32, "frames": [
            {"file_path": "a.png", "transform_matrix":
                [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]}]});
        let c = parse_transforms(Path::new("transforms.json"), &v).unwrap();
        let (uv, z) = c[0].project([0.0, 0.0, 0.0]);
        assert_eq!((uv, z), ([32.0, 16.0], 5.0));
        assert!(c[0].project([0.0, 1.0, 0.0]).0[1] < 16.0);
        assert_eq!(c[0].fy, 100.0);
    }

    #[test]
    fn camera_angle_and_overrides() {
        let a = 2.0 * (0.5f64).atan(); // fx = (w/2) / 0.5 = w
        let v = serde_json::json!({"camera_angle_x": a, "frames": [
            {"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]},
            {"w": 100, "h": 50, "cx": 40.0, "transform_matrix":
                [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]}]});
        let c = parse_transforms(Path::new("t.json"), &v).unwrap();
        assert!((c[0].fx - 800.0).abs() < 1e-3 && c[0].width == 800);
        assert!((c[1].fx - 100.0).abs() < 1e-3 && c[1].cx == 40.0 && c[1].cy == 25.0);
        let bad = serde_json::json!({"frames": [{"transform_matrix": [[1,0,0,0]]}]});
        let e = parse_transforms(Path::new("t.json"), &bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.json") && e.contains("frame 0"), "{e}");
    }
}

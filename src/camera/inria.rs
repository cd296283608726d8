//! The INRIA 3DGS `cameras.json` (`utils/camera_utils.py: camera_to_JSON`).
//!
//! A JSON array of objects `{id, img_name, width, height, position, rotation, fy, fx}`.
//! INRIA builds `Rt` = the world-to-camera matrix `[R_w2c | t]`, inverts it, and stores
//! the inverse's translation as `position` (the camera centre in world coordinates) and
//! its 3x3 block as `rotation`, row by row: **`rotation` is camera-to-world**
//! (its columns are the camera's x right, y down, z forward axes in world coordinates).
//! Hence `R_w2c = rotation^T` and `t = -R_w2c position`. The principal point is the image
//! centre in INRIA's code; we also write (and read, when present) `cx`, `cy`, which other
//! readers ignore.

use super::Camera;
use crate::geometry::{mat3, rows};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// One entry of an INRIA `cameras.json` (extra keys in files are ignored on read).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InriaCamera {
    pub id: serde_json::Value,
    #[serde(default)]
    pub img_name: Option<String>,
    pub width: u32,
    pub height: u32,
    /// Camera centre, world coordinates.
    pub position: [f64; 3],
    /// Camera-to-world rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    pub fy: f64,
    pub fx: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
}

/// Read an INRIA `cameras.json` (cameras at the file's image sizes, validated).
pub fn read_inria(path: &Path) -> Result<Vec<Camera>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::input(path, format!("invalid JSON: {e}")))?;
    parse_inria(path, v)
}

/// Parse an INRIA camera array; `path` names the file in errors.
pub fn parse_inria(path: &Path, v: serde_json::Value) -> Result<Vec<Camera>> {
    let arr = match v {
        serde_json::Value::Array(a) => a,
        _ => {
            return Err(Error::input(
                path,
                "INRIA cameras.json must be a JSON array",
            ));
        }
    };
    let mut out = Vec::with_capacity(arr.len());
    for (i, e) in arr.into_iter().enumerate() {
        let c: InriaCamera = serde_json::from_value(e)
            .map_err(|err| Error::input(path, format!("camera {i}: {err}")))?;
        let name = c.img_name.clone().unwrap_or_else(|| match &c.id {
            serde_json::Value::String(s) => s.clone(),
            other => format!("{other}"),
        });
        let cx = c.cx.unwrap_or(0.5 * c.width as f64);
        let cy = c.cy.unwrap_or(0.5 * c.height as f64);
        let cam = Camera::from_c2w(
            name,
            c.width,
            c.height,
            [c.fx, c.fy, cx, cy],
            c.rotation,
            c.position,
        );
        cam.validate(path)?;
        out.push(cam);
    }
    Ok(out)
}

/// Cameras as INRIA `cameras.json` entries (ids 0.., `cx`/`cy` added).
pub fn to_inria(cams: &[Camera]) -> Vec<InriaCamera> {
    cams.iter()
        .enumerate()
        .map(|(i, c)| {
            let r = c.rotation.map(|row| row.map(|v| v as f64));
            let t = c.translation.map(|v| v as f64);
            let position = [0, 1, 2].map(|j| -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]));
            InriaCamera {
                id: serde_json::json!(i),
                img_name: Some(c.name.clone()),
                width: c.width,
                height: c.height,
                position,
                rotation: rows(mat3(r).transpose()),
                fy: c.fy as f64,
                fx: c.fx as f64,
                cx: Some(c.cx as f64),
                cy: Some(c.cy as f64),
            }
        })
        .collect()
}

/// Write `cams` as an INRIA `cameras.json`, atomically.
pub fn write_inria(path: &Path, cams: &[Camera]) -> Result<()> {
    fantasystyle_schemas::atomic_write_json(path, &to_inria(cams))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inria_convention_and_round_trip() {
        // Hand-written INRIA entry: a camera at (0, 0, -4) with identity camera-to-world
        // rotation looks down +z; the world origin projects to the image centre, and the
        // point (1, 0, 0) lands fx / 4 pixels to the right.
        let j = serde_json::json!([{"id": 0, "img_name": "a", "width": 100, "height": 50,
            "position": [0.0, 0.0, -4.0], "rotation": [[1,0,0],[0,1,0],[0,0,1]],
            "fy": 80.0, "fx": 80.0}]);
        let cams = parse_inria(Path::new("c.json"), j).unwrap();
        let (uv, z) = cams[0].project([0.0, 0.0, 0.0]);
        assert_eq!((uv, z), ([50.0, 25.0], 4.0));
        assert_eq!(cams[0].project([1.0, 0.0, 0.0]).0, [70.0, 25.0]);
        // A rotated camera: rotation = c2w; camera x axis = first column.
        let c = super::super::tests::look_at([2.0, -1.0, -3.0], [0.0, 0.0, 0.0]);
        let back = parse_inria(
            Path::new("c.json"),
            serde_json::to_value(to_inria(std::slice::from_ref(&c))).unwrap(),
        )
        .unwrap();
        assert_eq!(back[0].rotation, c.rotation);
        for k in 0..3 {
            assert!((back[0].translation[k] - c.translation[k]).abs() < 1e-5);
        }
        assert_eq!(
            (back[0].fx, back[0].cx, back[0].name.as_str()),
            (c.fx, c.cx, "t")
        );
    }

    #[test]
    fn bad_rotation_is_refused_with_camera_name() {
        let j = serde_json::json!([{"id": 3, "img_name": "img3", "width": 10, "height": 10,
            "position": [0, 0, 0], "rotation": [[1,0,0],[0,2,0],[0,0,1]], "fy": 8, "fx": 8}]);
        let e = parse_inria(Path::new("c.json"), j).unwrap_err().to_string();
        assert!(
            e.contains("c.json") && e.contains("img3") && e.contains("orthonormal"),
            "{e}"
        );
        let j = serde_json::json!([{"id": 3, "width": 10}]);
        let e = parse_inria(Path::new("c.json"), j).unwrap_err().to_string();
        assert!(e.contains("camera 0") && e.contains("missing field"), "{e}");
    }
}

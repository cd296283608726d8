//! Loading `views` artifacts (`rgb.npy` [N,H,W,3], `depth.npy` [N,H,W], `alpha.npy`
//! [N,H,W], `cameras.json`) for evaluation, and checking that an original and a stylized
//! set show the same views: same count, same image size, same cameras.

use super::image::Image;
use crate::{Camera, Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use std::path::{Path, PathBuf};

/// One views artifact in memory.
#[derive(Debug, Clone)]
pub struct ViewSet {
    pub dir: PathBuf,
    pub n: usize,
    pub width: usize,
    pub height: usize,
    pub images: Vec<Image>,
    /// Expected depth `sum_i w_i z_i` (NOT divided by alpha), `N*H*W`.
    pub depth: Vec<f32>,
    /// Accumulated opacity, `N*H*W`.
    pub alpha: Vec<f32>,
    pub cameras: Vec<Camera>,
}

/// Read the INRIA-format `cameras.json` of a views artifact: `rotation` is
/// camera-to-world (row-major), `position` the camera centre; optional `cx`, `cy`
/// (default: image centre). So `R_w2c = rotation^T`, `t = -R_w2c position`.
// TODO(merge): use the camera module's INRIA reader once the scene branch is merged.
fn read_cameras(path: &Path) -> Result<Vec<Camera>> {
    #[derive(serde::Deserialize)]
    struct Inria {
        #[serde(default)]
        img_name: Option<String>,
        width: u32,
        height: u32,
        position: [f64; 3],
        rotation: [[f64; 3]; 3],
        fx: f64,
        fy: f64,
        #[serde(default)]
        cx: Option<f64>,
        #[serde(default)]
        cy: Option<f64>,
    }
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let cams: Vec<Inria> = serde_json::from_str(&text)
        .map_err(|e| Error::input(path, format!("invalid INRIA cameras.json: {e}")))?;
    Ok(cams
        .into_iter()
        .enumerate()
        .map(|(i, c)| {
            let mut r = [[0f32; 3]; 3];
            for a in 0..3 {
                for b in 0..3 {
                    r[a][b] = c.rotation[b][a] as f32;
                }
            }
            let t: [f32; 3] = std::array::from_fn(|a| {
                -(0..3)
                    .map(|b| c.rotation[b][a] * c.position[b])
                    .sum::<f64>() as f32
            });
            Camera {
                name: c.img_name.unwrap_or_else(|| format!("view_{i:03}")),
                width: c.width,
                height: c.height,
                fx: c.fx as f32,
                fy: c.fy as f32,
                cx: c.cx.unwrap_or(0.5 * c.width as f64) as f32,
                cy: c.cy.unwrap_or(0.5 * c.height as f64) as f32,
                rotation: r,
                translation: t,
            }
        })
        .collect())
}

/// Write cameras as INRIA `cameras.json` entries (for test fixtures and tools).
pub fn inria_json(cams: &[Camera]) -> serde_json::Value {
    let arr: Vec<serde_json::Value> = cams
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let rot: Vec<Vec<f32>> = (0..3).map(|a| (0..3).map(|b| c.rotation[b][a]).collect()).collect();
            serde_json::json!({
                "id": i, "img_name": c.name, "width": c.width, "height": c.height,
                "position": c.center(), "rotation": rot, "fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy,
            })
        })
        .collect();
    serde_json::Value::Array(arr)
}

impl ViewSet {
    /// Open and validate a views artifact.
    pub fn load(dir: &Path) -> Result<ViewSet> {
        if !dir.is_dir() {
            return Err(Error::input(dir, "views artifact directory not found"));
        }
        let art = Artifact::open(dir, ArtifactKind::Views)?;
        let rgb = art.read_f32("rgb.npy")?;
        let depth = art.read_f32("depth.npy")?;
        let alpha = art.read_f32("alpha.npy")?;
        let bad = |f: &str, r: String| Err(Error::input(dir.join(f), r));
        if rgb.shape.len() != 4 || rgb.shape[3] != 3 {
            return bad(
                "rgb.npy",
                format!("expected shape [N,H,W,3], got {:?}", rgb.shape),
            );
        }
        let (n, h, w) = (rgb.shape[0], rgb.shape[1], rgb.shape[2]);
        if n == 0 || h == 0 || w == 0 {
            return bad("rgb.npy", format!("empty view set, shape {:?}", rgb.shape));
        }
        for (f, a) in [("depth.npy", &depth), ("alpha.npy", &alpha)] {
            if a.shape != [n, h, w] {
                return bad(
                    f,
                    format!(
                        "expected shape [{n},{h},{w}] to match rgb.npy, got {:?}",
                        a.shape
                    ),
                );
            }
        }
        if alpha.data.iter().any(|a| !(-1e-4..=1.0 + 1e-4).contains(a)) {
            return bad("alpha.npy", "values outside [0, 1]".into());
        }
        let cameras = read_cameras(&dir.join("cameras.json"))?;
        if cameras.len() != n {
            return bad(
                "cameras.json",
                format!("{} cameras for {n} views in rgb.npy", cameras.len()),
            );
        }
        for (i, c) in cameras.iter().enumerate() {
            if (c.width as usize, c.height as usize) != (w, h) {
                return bad(
                    "cameras.json",
                    format!(
                        "camera {i} is {}x{}, the views are {w}x{h}",
                        c.width, c.height
                    ),
                );
            }
        }
        let images = (0..n)
            .map(|i| Image {
                width: w,
                height: h,
                data: rgb.data[i * h * w * 3..(i + 1) * h * w * 3].to_vec(),
            })
            .collect();
        Ok(ViewSet {
            dir: dir.to_path_buf(),
            n,
            width: w,
            height: h,
            images,
            depth: depth.data,
            alpha: alpha.data,
            cameras,
        })
    }

    /// Depth and alpha of view `i`.
    pub fn geometry(&self, i: usize) -> (&[f32], &[f32]) {
        let p = self.width * self.height;
        (
            &self.depth[i * p..(i + 1) * p],
            &self.alpha[i * p..(i + 1) * p],
        )
    }

    /// Check that `other` shows the same views as `self` (count, size, cameras).
    pub fn check_same_views(&self, other: &ViewSet) -> Result<()> {
        if self.n != other.n {
            return Err(Error::input(
                &other.dir,
                format!(
                    "{} views, but {} has {}",
                    other.n,
                    self.dir.display(),
                    self.n
                ),
            ));
        }
        if (self.width, self.height) != (other.width, other.height) {
            return Err(Error::input(
                other.dir.join("rgb.npy"),
                format!(
                    "images are {}x{}, but those of {} are {}x{}",
                    other.width,
                    other.height,
                    self.dir.display(),
                    self.width,
                    self.height
                ),
            ));
        }
        for (i, (a, b)) in self.cameras.iter().zip(&other.cameras).enumerate() {
            if let Some(why) = camera_difference(a, b) {
                return Err(Error::input(
                    other.dir.join("cameras.json"),
                    format!(
                        "camera {i} differs from {}: {why}",
                        self.dir.join("cameras.json").display()
                    ),
                ));
            }
        }
        Ok(())
    }
}

/// `None` if two cameras agree (intrinsics to 1e-3 px, rotation to 1e-5, translation to
/// 1e-4 (1 + |t|)), else what differs.
pub fn camera_difference(a: &Camera, b: &Camera) -> Option<String> {
    let intr = [(a.fx, b.fx), (a.fy, b.fy), (a.cx, b.cx), (a.cy, b.cy)];
    if intr
        .iter()
        .any(|(x, y)| (x - y).abs() > 1e-3 * (1.0 + x.abs()))
    {
        return Some(format!(
            "intrinsics (fx,fy,cx,cy) ({},{},{},{}) vs ({},{},{},{})",
            a.fx, a.fy, a.cx, a.cy, b.fx, b.fy, b.cx, b.cy
        ));
    }
    let rot = (0..9).any(|k| (a.rotation[k / 3][k % 3] - b.rotation[k / 3][k % 3]).abs() > 1e-5);
    if rot {
        return Some("rotation differs".into());
    }
    let tn = a.translation.iter().map(|x| x * x).sum::<f32>().sqrt();
    if (0..3).any(|k| (a.translation[k] - b.translation[k]).abs() > 1e-4 * (1.0 + tn)) {
        return Some(format!(
            "translation {:?} vs {:?}",
            a.translation, b.translation
        ));
    }
    None
}

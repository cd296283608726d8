//! `views` artifacts as the evaluation holds them ([`crate::artifacts::read_view_set`]
//! reads one), and checking that an original and a stylized set show the same views:
//! same count, same image size, same cameras.

use crate::imageio::Image;
use crate::{Camera, Error, Result};
use ndarray::{Array3, Array4, Axis};
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

impl ViewSet {
    /// The views of the artifact at `dir` (named in errors), validated: `rgb` `[N, H, W,
    /// 3]`, `depth` and `alpha` `[N, H, W]`, one camera per view at the images' size.
    pub fn new(
        dir: &Path,
        rgb: Array4<f32>,
        depth: Array3<f32>,
        alpha: Array3<f32>,
        cameras: Vec<Camera>,
    ) -> Result<ViewSet> {
        let (n, h, w) = (rgb.shape()[0], rgb.shape()[1], rgb.shape()[2]);
        let bad = |f: &str, r: String| Err(Error::input(dir.join(f), r));
        if n == 0 || h == 0 || w == 0 {
            return bad(
                "rgb.npy",
                format!("empty view set, shape {:?}", rgb.shape()),
            );
        }
        if alpha.iter().any(|a| !(-1e-4..=1.0 + 1e-4).contains(a)) {
            return bad("alpha.npy", "values outside [0, 1]".into());
        }
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
                data: rgb.index_axis(Axis(0), i).iter().copied().collect(),
            })
            .collect();
        Ok(ViewSet {
            dir: dir.to_path_buf(),
            n,
            width: w,
            height: h,
            images,
            depth: depth.into_raw_vec_and_offset().0,
            alpha: alpha.into_raw_vec_and_offset().0,
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

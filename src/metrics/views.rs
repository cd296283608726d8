//! `views` artifacts as the evaluation holds them ([`crate::artifacts::read_view_set`]
//! reads one), and checking that an original and a stylized set show the same views:
//! same count, same image size, same cameras; and a [`Preview`]: a views artifact of
//! some of the evaluation's views (the `preview` stage's), checked against them.

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

/// A preview's views (the prior's 2D stylization of some of the evaluation's views, the
/// `preview` stage's artifact) and which evaluation views they are.
#[derive(Debug, Clone)]
pub struct Preview {
    pub views: ViewSet,
    /// The evaluation view of each preview view.
    pub indices: Vec<usize>,
}

impl Preview {
    /// `views`, showing the evaluation views `indices` of `orig` (`None`: every view, in
    /// order), checked: one index per view, each an evaluation view, at the same image
    /// size and from the same camera.
    pub fn new(views: ViewSet, indices: Option<Vec<usize>>, orig: &ViewSet) -> Result<Preview> {
        let dir = views.dir.clone();
        let indices = match indices {
            Some(ix) => ix,
            None if views.n == orig.n => (0..orig.n).collect(),
            None => {
                return Err(Error::input(
                    dir.join("manifest.json"),
                    format!(
                        "{} views, but {} has {}, and its producer params name no \"views\"",
                        views.n,
                        orig.dir.display(),
                        orig.n
                    ),
                ));
            }
        };
        let bad = |f: &str, why: String| Err(Error::input(dir.join(f), why));
        if indices.len() != views.n {
            return bad(
                "manifest.json",
                format!(
                    "params name {} views, rgb.npy holds {}",
                    indices.len(),
                    views.n
                ),
            );
        }
        if let Some(v) = indices.iter().find(|&&v| v >= orig.n) {
            return bad(
                "manifest.json",
                format!("view {v}: {} has {} views", orig.dir.display(), orig.n),
            );
        }
        if (views.width, views.height) != (orig.width, orig.height) {
            return bad(
                "rgb.npy",
                format!(
                    "images are {}x{}, but those of {} are {}x{}",
                    views.width,
                    views.height,
                    orig.dir.display(),
                    orig.width,
                    orig.height
                ),
            );
        }
        for (k, &v) in indices.iter().enumerate() {
            if let Some(why) = camera_difference(&orig.cameras[v], &views.cameras[k]) {
                return bad(
                    "cameras.json",
                    format!(
                        "camera {k} differs from view {v} of {}: {why}",
                        orig.dir.display()
                    ),
                );
            }
        }
        Ok(Preview { views, indices })
    }

    /// The preview's image of evaluation view `i`, if it has one.
    pub fn image_of(&self, i: usize) -> Option<&Image> {
        let k = self.indices.iter().position(|&v| v == i)?;
        Some(&self.views.images[k])
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maths::warp::look_at;

    /// `n` views of `w x h` from cameras `eyes[i]`, every pixel `value + i`.
    fn set(dir: &str, eyes: &[f64], (w, h): (usize, usize), value: f32) -> ViewSet {
        let n = eyes.len();
        let cams = eyes
            .iter()
            .enumerate()
            .map(|(i, e)| {
                look_at(
                    &format!("v{i}"),
                    [*e, -3.0, 1.0],
                    [0.0; 3],
                    w as u32,
                    h as u32,
                    40.0,
                )
            })
            .collect();
        let rgb = Array4::from_shape_fn((n, h, w, 3), |(i, ..)| (value + i as f32) / 10.0);
        let zeros = Array3::zeros((n, h, w));
        ViewSet::new(Path::new(dir), rgb, zeros.clone(), zeros, cams).unwrap()
    }

    #[test]
    fn a_preview_of_some_views_is_matched_to_them() {
        let orig = set("o", &[0.0, 0.5, 1.0, 1.5], (8, 6), 0.0);
        let p = Preview::new(set("p", &[0.5, 1.5], (8, 6), 5.0), Some(vec![1, 3]), &orig).unwrap();
        assert_eq!(p.image_of(3).unwrap().data[0], 0.6);
        assert!(p.image_of(0).is_none());
        // Without "views", a preview of every view is in order.
        let all = Preview::new(set("a", &[0.0, 0.5, 1.0, 1.5], (8, 6), 1.0), None, &orig).unwrap();
        assert_eq!(all.indices, vec![0, 1, 2, 3]);
    }

    #[test]
    fn a_preview_that_is_not_of_these_views_is_refused() {
        let orig = set("o", &[0.0, 0.5, 1.0], (8, 6), 0.0);
        let err = |eyes: &[f64], size, ix: Option<Vec<usize>>| {
            Preview::new(set("p", eyes, size, 0.0), ix, &orig)
                .unwrap_err()
                .to_string()
        };
        assert!(err(&[0.5], (8, 6), None).contains("name no \"views\""));
        assert!(err(&[0.5], (8, 6), Some(vec![1, 2])).contains("params name 2 views"));
        assert!(err(&[0.5], (8, 6), Some(vec![3])).contains("view 3"));
        assert!(err(&[0.5], (4, 3), Some(vec![1])).contains("images are 4x3"));
        assert!(err(&[0.5], (8, 6), Some(vec![2])).contains("camera 0 differs from view 2"));
    }
}

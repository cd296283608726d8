//! Masks drawn on views, lifted to the Gaussians in closed form (FlashSplat: Shen, Yang
//! and Wang, "FlashSplat: 2D to 3D Gaussian Splatting Segmentation Solved Optimally",
//! ECCV 2024).
//!
//! A pixel `p` of a view blends the Gaussians that cover it with weights
//! `w_ip = alpha_ip T_ip` (alpha-compositing, front to back). With a mask `m_p` in
//! [0, 1] per pixel (white = in; grey counts fractionally), every Gaussian gets
//!
//! ```text
//! in_i  = sum over views v, pixels p of  w_ip m_p
//! out_i = sum over views v, pixels p of  w_ip (1 - m_p)
//! ```
//!
//! and is selected (weight 1) iff `in_i > (1 + bias) out_i` (FlashSplat's optimal
//! label assignment, its background bias `bias >= 0` leaning toward "out"), or, with
//! `soft`, weighted `in_i / (in_i + (1 + bias) out_i)`. A Gaussian that blends into no
//! pixel of any masked view (`in_i + out_i = 0`) is never selected.
//!
//! Both sums are one transposed colour composite each: the frozen-geometry cache's
//! backward ([`crate::render::cache::ViewCache::backward`]) of the image whose first
//! channel is `m` and second `1 - m` gives `(in, out)` per contributing Gaussian.
//!
//! Masks are PNGs in one directory, one per view, each named after its camera
//! (`orbit_003.png` for camera `orbit_003`; the file's stem is the camera's name or the
//! name's stem) and of that camera's image size (cameras from `orbit:` specs are made
//! at the masks' size, so all masks must share one). The cameras come from `--cameras`
//! (a camera file or directory, a views artifact, or an `orbit:` spec around the
//! scene). A mask's value is the mean of its RGB channels (alpha dropped).

use super::{Context, Make, Selection};
use crate::render::cache::ViewCache;
use crate::{Camera, Error, Result, Scene};
use std::path::{Path, PathBuf};

/// How masks become weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiftOptions {
    /// Background bias: selected iff `in > (1 + bias) out` (>= 0).
    pub bias: f32,
    /// Weights `in / (in + (1 + bias) out)` instead of 0 or 1.
    pub soft: bool,
}

impl Default for LiftOptions {
    fn default() -> Self {
        LiftOptions {
            bias: 0.0,
            soft: false,
        }
    }
}

/// One mask: values in [0, 1], row-major `[H, W]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

impl Mask {
    /// Read a PNG (or JPEG) mask: the mean of its channels.
    pub fn read(path: &Path) -> Result<Mask> {
        let img = crate::imageio::Image::load(path)?;
        Ok(Mask {
            path: path.to_path_buf(),
            width: img.width,
            height: img.height,
            values: img
                .data
                .chunks_exact(3)
                .map(|c| (c[0] + c[1] + c[2]) / 3.0)
                .collect(),
        })
    }
}

/// The `*.png` masks of `dir`, by file name; an error naming `dir` when it has none.
pub fn read_masks(dir: &Path) -> Result<Vec<Mask>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(Error::input(dir, "no mask (*.png) in the directory"));
    }
    paths.iter().map(|p| Mask::read(p)).collect()
}

/// The cameras of `spec` at their own sizes (an `orbit:` spec at `width` x `height`).
fn native_cameras(spec: &str, scene: &Scene, width: usize, height: usize) -> Result<Vec<Camera>> {
    if spec.starts_with("orbit:") {
        return crate::camera::load_cameras(spec, &scene.bounds(), width as u32, height as u32);
    }
    let path = Path::new(spec);
    let (cams, _) = if crate::artifacts::is_artifact(path) {
        crate::artifacts::read_cameras(path)?
    } else {
        crate::camera::load_camera_file(path)?
    };
    Ok(cams)
}

/// Each mask with its camera (by name, see the module docs): errors name the mask file
/// whose name matches no camera, or whose size is not its camera's.
pub fn match_cameras(masks: Vec<Mask>, spec: &str, scene: &Scene) -> Result<Vec<(Camera, Mask)>> {
    let (w, h) = (masks[0].width, masks[0].height);
    let cams = native_cameras(spec, scene, w, h)?;
    let stem = |s: &str| {
        Path::new(s)
            .file_stem()
            .map(|x| x.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let mut out = Vec::with_capacity(masks.len());
    for m in masks {
        let name = stem(&m.path.to_string_lossy());
        let Some(cam) = cams
            .iter()
            .find(|c| c.name == name || stem(&c.name) == name)
        else {
            let names: Vec<&str> = cams.iter().take(8).map(|c| c.name.as_str()).collect();
            return Err(Error::input(
                &m.path,
                format!(
                    "no camera named `{name}` among the {} cameras of {spec} ({}{}): a mask is \
                     named after its camera",
                    cams.len(),
                    names.join(", "),
                    if cams.len() > 8 { ", ..." } else { "" }
                ),
            ));
        };
        if (cam.width as usize, cam.height as usize) != (m.width, m.height) {
            return Err(Error::input(
                &m.path,
                format!(
                    "mask is {}x{}, but camera `{}` is {}x{} (a mask has its camera's size)",
                    m.width, m.height, cam.name, cam.width, cam.height
                ),
            ));
        }
        out.push((cam.clone(), m));
    }
    Ok(out)
}

/// `(in, out)` per Gaussian of `scene`, summed over the masked views (module docs).
pub fn contributions(scene: &Scene, views: &[(Camera, Mask)]) -> Result<Vec<[f64; 2]>> {
    let mut acc = vec![[0.0f64; 2]; scene.len()];
    let mut grad = Vec::new();
    for (cam, mask) in views {
        let cache = ViewCache::build(scene, cam)?;
        grad.clear();
        grad.extend(mask.values.iter().flat_map(|&m| [m, 1.0 - m, 0.0]));
        for (&g, s) in cache.gaussians().iter().zip(cache.backward(&grad)) {
            let a = &mut acc[g as usize];
            a[0] += s[0] as f64;
            a[1] += s[1] as f64;
        }
    }
    Ok(acc)
}

/// The weights of `(in, out)` sums under `opts` (module docs).
pub fn weights(sums: &[[f64; 2]], opts: LiftOptions) -> Vec<f32> {
    let k = 1.0 + opts.bias.max(0.0) as f64;
    sums.iter()
        .map(|&[i, o]| {
            if i <= 0.0 {
                0.0
            } else if opts.soft {
                (i / (i + k * o)).clamp(0.0, 1.0) as f32
            } else if i > k * o {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

/// Lift masks to a selection of `scene`.
pub fn lift(scene: &Scene, views: &[(Camera, Mask)], opts: LiftOptions) -> Result<Selection> {
    Ok(Selection {
        weights: weights(&contributions(scene, views)?, opts),
    })
}

/// The `masks:DIR` source.
#[derive(Debug, Clone, PartialEq)]
pub struct MaskSource {
    pub dir: PathBuf,
}

impl MaskSource {
    /// `masks:DIR` (the part after `masks:`).
    pub fn parse(spec: &str) -> Result<Box<dyn Make>> {
        if spec.is_empty() {
            return Err(Error::param("masks: expected masks:DIR"));
        }
        Ok(Box::new(MaskSource {
            dir: PathBuf::from(spec),
        }))
    }
}

impl Make for MaskSource {
    fn make(&self, scene: &Scene, ctx: &Context) -> Result<Selection> {
        let Some(spec) = &ctx.cameras else {
            return Err(Error::param(
                "masks: the cameras the masks were drawn on are needed (--cameras)",
            ));
        };
        let views = match_cameras(read_masks(&self.dir)?, spec, scene)?;
        let t = std::time::Instant::now();
        let sel = lift(scene, &views, ctx.lift)?;
        tracing::info!(
            "masks: {} views lifted onto {} Gaussians in {:.2} s",
            views.len(),
            scene.len(),
            t.elapsed().as_secs_f64()
        );
        Ok(sel)
    }

    fn describe(&self, ctx: &Context) -> serde_json::Value {
        serde_json::json!({"masks": {
            "dir": self.dir.display().to_string(), "cameras": ctx.cameras,
            "bias": ctx.lift.bias, "soft": ctx.lift.soft,
        }})
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_follow_the_rule() {
        let sums = [[0.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 3.0]];
        let hard = weights(&sums, LiftOptions::default());
        assert_eq!(hard, [0.0, 1.0, 0.0, 1.0, 0.0]);
        let biased = weights(
            &sums,
            LiftOptions {
                bias: 1.5,
                soft: false,
            },
        );
        assert_eq!(biased, [0.0, 0.0, 0.0, 1.0, 0.0]);
        let soft = weights(
            &sums,
            LiftOptions {
                bias: 0.0,
                soft: true,
            },
        );
        assert_eq!(soft, [0.0, 2.0 / 3.0, 0.5, 1.0, 0.0]);
    }

    #[test]
    fn a_full_mask_selects_exactly_the_visible_gaussians() {
        let scene = crate::sample::sample_scene(0);
        let cams = crate::camera::load_cameras("orbit:2", &scene.bounds(), 48, 48).unwrap();
        let views: Vec<(Camera, Mask)> = cams
            .into_iter()
            .map(|c| {
                let m = Mask {
                    path: PathBuf::from(format!("{}.png", c.name)),
                    width: 48,
                    height: 48,
                    values: vec![1.0; 48 * 48],
                };
                (c, m)
            })
            .collect();
        let sums = contributions(&scene, &views).unwrap();
        let sel = lift(&scene, &views, LiftOptions::default()).unwrap();
        let visible = sums.iter().filter(|s| s[0] > 0.0).count();
        assert!(visible > 1000 && visible < scene.len(), "{visible}");
        assert_eq!(sel.selected(), visible);
        assert!(sums.iter().all(|s| s[1] == 0.0));
    }
}

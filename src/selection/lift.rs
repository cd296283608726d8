//! Masks drawn on views, lifted to the Gaussians in closed form (FlashSplat: Shen, Yang
//! and Wang, "FlashSplat: 2D to 3D Gaussian Splatting Segmentation Solved Optimally",
//! ECCV 2024), leaving out the Gaussians the views show only behind other surfaces.
//!
//! A pixel `p` of a view blends the Gaussians that cover it with weights
//! `w_ip = alpha_ip T_ip` (alpha-compositing, front to back; `T_ip` is the transmittance
//! in front of Gaussian `i`, `1 - sum` of the weights before it). With a mask `m_p` in
//! [0, 1] per pixel (white = in; grey counts fractionally), every Gaussian gets
//!
//! ```text
//! in_i   = sum over views v, pixels p of  w_ip m_p
//! out_i  = sum over views v, pixels p of  w_ip (1 - m_p)
//! seen_i = max over views v, pixels p with w_ip > 0 of  T_ip
//! ```
//!
//! A Gaussian with `seen_i >= occlusion` (some pixel of a masked view gets at least that
//! share of its light to it) is *seen*, and is selected (weight 1) iff
//! `in_i > (1 + bias) out_i` (FlashSplat's optimal label assignment, its background bias
//! `bias >= 0` leaning toward "out"), or, with `soft`, weighted
//! `in_i / (in_i + (1 + bias) out_i)`.
//!
//! A Gaussian that blends into masked pixels but is never seen (`seen_i < occlusion`,
//! `in_i > 0`) is *hidden*: every view shows it only behind other surfaces (the ground
//! under the sample's sphere, also the sphere's own underside). Its sums say nothing
//! about it (any `in_i > 0` with `out_i = 0` would select it), so it does not vote:
//! it takes the weight of the Gaussians it overlaps in 3D ([`super::hidden`]). A
//! Gaussian that blends into no masked pixel (`in_i = 0`) keeps weight 0, as does a
//! hidden one linked to nothing labelled. `occlusion = 0` makes every blending Gaussian
//! seen: the sums alone, as FlashSplat.
//!
//! The sums are one composite per view: the tile rasteriser's weights go to a sink that
//! accumulates `w m`, `w (1 - m)` and the transmittance `1 - sum w` of the weights before
//! each one, per pixel, front to back (the same weights and order as the frozen-geometry
//! cache's transposed composite, [`crate::render::cache::ViewCache::backward`]).
//!
//! Masks are PNGs in one directory, one per view, each named after its camera
//! (`orbit_003.png` for camera `orbit_003`; the file's stem is the camera's name or the
//! name's stem) and of that camera's image size (cameras from `orbit:` specs are made
//! at the masks' size, so all masks must share one). The cameras come from `--cameras`
//! (a camera file or directory, a views artifact, or an `orbit:` spec around the
//! scene). A mask's value is the mean of its RGB channels (alpha dropped).

use super::hidden::Fill;
use super::{Context, Make, Selection};
use crate::render::project::TILE;
use crate::render::raster::{HALF, Plane, Sink, TileState, composite_tile};
use crate::{Camera, Error, Result, Scene};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// The default [`LiftOptions::occlusion`]: a Gaussian is seen where at least half of a
/// pixel's light reaches it, as a mask pixel is in where the region makes more than
/// half of it (measured on the sample: docs/selection.md).
pub const DEFAULT_OCCLUSION: f32 = 0.5;

/// How masks become weights.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiftOptions {
    /// Background bias: selected iff `in > (1 + bias) out` (>= 0).
    pub bias: f32,
    /// Weights `in / (in + (1 + bias) out)` instead of 0 or 1.
    pub soft: bool,
    /// The transmittance in [0, 1] a Gaussian needs at some masked pixel to vote (module
    /// docs); 0: every Gaussian that blends votes.
    pub occlusion: f32,
}

impl Default for LiftOptions {
    fn default() -> Self {
        LiftOptions {
            bias: 0.0,
            soft: false,
            occlusion: DEFAULT_OCCLUSION,
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
    Ok(crate::camera::load_camera_file(Path::new(spec))?.0)
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

/// What the masked views say about one Gaussian (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Votes {
    /// `in`: its blending weights times the mask, summed.
    pub inside: f64,
    /// `out`: its blending weights times one minus the mask, summed.
    pub outside: f64,
    /// `seen`: the largest transmittance in front of it at a pixel it blends into
    /// (0 when it blends into none).
    pub seen: f32,
}

/// Per tile: the mask, the weight blended so far per pixel, and each splat's
/// `(local index, [w m, w (1 - m), max T])`.
struct VoteSink {
    mask: Plane,
    cover: Plane,
    run: [f32; 3],
    out: Vec<(u32, [f32; 3])>,
}

impl Sink for VoteSink {
    #[inline(always)]
    fn begin(&mut self, _local: u32, _slot: usize) {
        self.run = [0.0; 3];
    }

    #[inline(always)]
    fn half(&mut self, r: usize, h: usize, w: &[f32; HALF]) {
        for (c, &wp) in w.iter().enumerate() {
            let x = h * HALF + c;
            if wp > 0.0 {
                let m = self.mask[r][x];
                self.run[0] += wp * m;
                self.run[1] += wp * (1.0 - m);
                self.run[2] = self.run[2].max((1.0 - self.cover[r][x]).max(0.0));
                self.cover[r][x] += wp;
            }
        }
    }

    #[inline(always)]
    fn end(&mut self, local: u32, _slot: usize, _any: bool) {
        if self.run[0] + self.run[1] > 0.0 {
            self.out.push((local, self.run));
        }
    }
}

/// Tile `t` of an `[H, W]` mask (zero outside the image).
fn mask_tile(mask: &Mask, tiles_x: usize, t: usize) -> Plane {
    let mut p = [[0.0f32; TILE]; TILE];
    let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
    for (r, row) in p
        .iter_mut()
        .enumerate()
        .take(mask.height.saturating_sub(y0))
    {
        for (c, v) in row
            .iter_mut()
            .enumerate()
            .take(mask.width.saturating_sub(x0))
        {
            *v = mask.values[(y0 + r) * mask.width + x0 + c];
        }
    }
    p
}

/// [`Votes`] per Gaussian of `scene`, over the masked views (module docs).
pub fn contributions(scene: &Scene, views: &[(Camera, Mask)]) -> Result<Vec<Votes>> {
    crate::render::validate_scene(scene)?;
    let mut acc = vec![Votes::default(); scene.len()];
    for (cam, mask) in views {
        crate::render::validate_camera(cam)?;
        if (mask.width, mask.height) != (cam.width as usize, cam.height as usize)
            || mask.values.len() != mask.width * mask.height
        {
            return Err(Error::input(
                &mask.path,
                format!(
                    "mask is {}x{} ({} values), camera `{}` is {}x{}",
                    mask.width,
                    mask.height,
                    mask.values.len(),
                    cam.name,
                    cam.width,
                    cam.height
                ),
            ));
        }
        let frame = crate::render::project(scene, cam);
        let tiles: Vec<Vec<(u32, [f32; 3])>> = (0..frame.tiles_x * frame.tiles_y)
            .into_par_iter()
            .map_init(TileState::new, |st, t| {
                let mut sink = VoteSink {
                    mask: mask_tile(mask, frame.tiles_x, t),
                    cover: [[0.0; TILE]; TILE],
                    run: [0.0; 3],
                    out: Vec::new(),
                };
                composite_tile(&frame, t, st, &mut sink);
                sink.out
            })
            .collect();
        for (local, [i, o, t]) in tiles.into_iter().flatten() {
            let v = &mut acc[frame.splats.ids[local as usize] as usize];
            v.inside += f64::from(i);
            v.outside += f64::from(o);
            v.seen = v.seen.max(t);
        }
    }
    Ok(acc)
}

/// The weight of a seen Gaussian's sums under `opts` (module docs).
pub fn vote(v: &Votes, opts: LiftOptions) -> f32 {
    let k = 1.0 + f64::from(opts.bias.max(0.0));
    let (i, o) = (v.inside, v.outside);
    if i <= 0.0 {
        0.0
    } else if opts.soft {
        (i / (i + k * o)).clamp(0.0, 1.0) as f32
    } else if i > k * o {
        1.0
    } else {
        0.0
    }
}

/// The weights of `votes` under `opts`: seen Gaussians by [`vote`], hidden ones through
/// [`super::hidden::fill`] (module docs); with what the fill did.
pub fn weights(scene: &Scene, votes: &[Votes], opts: LiftOptions) -> (Vec<f32>, Fill) {
    let mut w = vec![0.0f32; votes.len()];
    let mut member = vec![false; votes.len()];
    let mut hidden = Vec::new();
    for (i, v) in votes.iter().enumerate() {
        if v.inside + v.outside <= 0.0 {
            continue;
        }
        if v.seen >= opts.occlusion {
            w[i] = vote(v, opts);
            member[i] = true;
        } else if v.inside > 0.0 {
            hidden.push(i);
        }
    }
    let fill = super::hidden::fill(scene, &mut w, &member, &hidden, opts.soft);
    (w, fill)
}

/// Lift masks to a selection of `scene`, with what the fill of hidden Gaussians did.
pub fn lift_with(
    scene: &Scene,
    views: &[(Camera, Mask)],
    opts: LiftOptions,
) -> Result<(Selection, Fill)> {
    let (weights, fill) = weights(scene, &contributions(scene, views)?, opts);
    Ok((Selection { weights }, fill))
}

/// Lift masks to a selection of `scene`.
pub fn lift(scene: &Scene, views: &[(Camera, Mask)], opts: LiftOptions) -> Result<Selection> {
    Ok(lift_with(scene, views, opts)?.0)
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
        let (sel, fill) = lift_with(scene, &views, ctx.lift)?;
        tracing::info!(
            "masks: {} views lifted onto {} Gaussians in {:.2} s; {} hidden (seen only \
             behind other surfaces, transmittance < {}), {} of them overlapping labelled \
             ones, {} selected",
            views.len(),
            scene.len(),
            t.elapsed().as_secs_f64(),
            fill.hidden,
            ctx.lift.occlusion,
            fill.reached,
            fill.selected
        );
        Ok(sel)
    }

    fn describe(&self, ctx: &Context) -> serde_json::Value {
        serde_json::json!({"masks": {
            "dir": self.dir.display().to_string(), "cameras": ctx.cameras,
            "bias": ctx.lift.bias, "soft": ctx.lift.soft, "occlusion": ctx.lift.occlusion,
        }})
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::ViewCache;

    fn opts(bias: f32, soft: bool, occlusion: f32) -> LiftOptions {
        LiftOptions {
            bias,
            soft,
            occlusion,
        }
    }

    #[test]
    fn vote_follows_the_rule() {
        let sums = [[0.0, 0.0], [2.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 3.0]];
        let votes: Vec<Votes> = sums
            .iter()
            .map(|&[inside, outside]| Votes {
                inside,
                outside,
                seen: 1.0,
            })
            .collect();
        let all = |o: LiftOptions| votes.iter().map(|v| vote(v, o)).collect::<Vec<_>>();
        assert_eq!(all(LiftOptions::default()), [0.0, 1.0, 0.0, 1.0, 0.0]);
        assert_eq!(all(opts(1.5, false, 0.5)), [0.0, 0.0, 0.0, 1.0, 0.0]);
        assert_eq!(all(opts(0.0, true, 0.5)), [0.0, 2.0 / 3.0, 0.5, 1.0, 0.0]);
    }

    /// Isotropic Gaussians `(centre, scale, opacity)` of SH degree 0.
    fn balls(g: &[([f32; 3], f32, f32)]) -> Scene {
        Scene {
            positions: g.iter().map(|b| b.0).collect(),
            log_scales: g.iter().map(|b| [b.1.ln(); 3]).collect(),
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; g.len()],
            opacity_logits: g.iter().map(|b| (b.2 / (1.0 - b.2)).ln()).collect(),
            sh_dc: vec![[0.0; 3]; g.len()],
            sh_rest: Vec::new(),
            sh_degree: 0,
        }
    }

    #[test]
    fn only_gaussians_seen_in_front_vote_and_hidden_ones_follow_what_they_overlap() {
        // A camera at the origin looking down +z; a wide opaque Gaussian at z = 2 (8 px
        // deviation), behind it a small one that overlaps it (z = 2.5, 2.5 of its own
        // deviations away) and a small one that overlaps nothing (z = 4). The mask is
        // all in.
        let scene = balls(&[
            ([0.0, 0.0, 2.0], 0.5, 0.9999),
            ([0.0, 0.0, 2.5], 0.2, 0.9),
            ([0.0, 0.0, 4.0], 0.2, 0.9),
        ]);
        let cam = Camera {
            name: "c".into(),
            width: 32,
            height: 32,
            fx: 32.0,
            fy: 32.0,
            cx: 16.0,
            cy: 16.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        };
        let mask = Mask {
            path: PathBuf::from("c.png"),
            width: 32,
            height: 32,
            values: vec![1.0; 32 * 32],
        };
        let views = [(cam, mask)];
        let v = contributions(&scene, &views).unwrap();
        // The front one is first at every pixel; the others only behind it: the light
        // left at their pixels is 1 - the front one's alpha there, at most ~0.2.
        assert_eq!(v[0].seen, 1.0);
        for b in &v[1..] {
            assert!(b.inside > 0.0 && b.seen > 0.0 && b.seen < 0.5, "{b:?}");
        }
        let sel = |o: LiftOptions| lift_with(&scene, &views, o).unwrap();
        let (s, fill) = sel(LiftOptions::default());
        assert_eq!(s.weights, [1.0, 1.0, 0.0]);
        assert_eq!(
            fill,
            Fill {
                hidden: 2,
                reached: 1,
                selected: 1
            }
        );
        // Occlusion 0: every Gaussian that blends votes (FlashSplat's sums alone), and
        // one below the light the hidden ones get lets them vote too.
        assert_eq!(sel(opts(0.0, false, 0.0)).0.weights, [1.0; 3]);
        let low = v[1].seen.min(v[2].seen) * 0.99;
        assert_eq!(sel(opts(0.0, false, low)).0.weights, [1.0; 3]);
        // Soft: a hidden Gaussian takes its neighbours' mean weight.
        assert_eq!(sel(opts(0.0, true, 0.5)).0.weights, [1.0, 1.0, 0.0]);
    }

    #[test]
    fn the_sums_are_the_caches_transposed_composite() {
        let scene = crate::sample::sample_scene(0);
        let cam = crate::camera::load_cameras("orbit:3", &scene.bounds(), 64, 48).unwrap();
        let values: Vec<f32> = (0..64 * 48).map(|p| (p % 64) as f32 / 63.0).collect();
        let mask = Mask {
            path: PathBuf::from("m.png"),
            width: 64,
            height: 48,
            values: values.clone(),
        };
        let v = contributions(&scene, &[(cam[1].clone(), mask)]).unwrap();
        let cache = ViewCache::build(&scene, &cam[1]).unwrap();
        let grad: Vec<f32> = values.iter().flat_map(|&m| [m, 1.0 - m, 0.0]).collect();
        let mut blended = 0;
        for (&g, s) in cache.gaussians().iter().zip(cache.backward(&grad)) {
            let b = &v[g as usize];
            for (x, y) in [(b.inside, s[0]), (b.outside, s[1])] {
                assert!(
                    (x - f64::from(y)).abs() <= 1e-5 * (1.0 + x.abs()),
                    "{g}: {x} {y}"
                );
            }
            blended += usize::from(b.inside + b.outside > 0.0);
        }
        assert!(blended > 1000 && blended == v.iter().filter(|b| b.seen > 0.0).count());
    }

    #[test]
    fn a_full_mask_selects_the_seen_gaussians_and_the_hidden_ones_they_touch() {
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
        let votes = contributions(&scene, &views).unwrap();
        assert!(votes.iter().all(|v| v.outside == 0.0));
        let blended = votes.iter().filter(|v| v.inside > 0.0).count();
        assert!(blended > 1000 && blended < scene.len(), "{blended}");
        // FlashSplat's sums alone: exactly the Gaussians that blend.
        let flash = lift(&scene, &views, opts(0.0, false, 0.0)).unwrap();
        assert_eq!(flash.selected(), blended);
        // By default: the seen ones, and of the hidden ones those that overlap (through
        // any chain) a seen one, which is selected.
        let seen = votes
            .iter()
            .filter(|v| v.inside > 0.0 && v.seen >= DEFAULT_OCCLUSION)
            .count();
        let (sel, fill) = lift_with(&scene, &views, LiftOptions::default()).unwrap();
        assert_eq!(fill.hidden, blended - seen);
        assert!(fill.hidden > 100, "{fill:?}");
        assert_eq!(fill.selected, fill.reached);
        assert_eq!(sel.selected(), seen + fill.selected);
    }
}

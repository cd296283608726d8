//! Patch synthesis on the frozen scene: the deterministic t -> 0 end of the patch prior
//! (`finish = "patches"`). Texture optimisation (Kwatra et al., SIGGRAPH 2005) lifted to
//! the Gaussians' colours, coarse to fine:
//!
//! for each level s (render pixels per synthesis pixel, coarsest first), `rounds` times:
//! 1. **E-step** (every view): the object's k x k patches of the current render (over a
//!    fill of its own colours, pooled s times) on a grid of step `stride`; each takes the
//!    style patch nearest to it (the style image at `texture.style_size / s` pixels, so a
//!    patch covers k s render pixels: coarse levels place motifs at their own scale, fine
//!    ones draw their strokes), searched exactly in PCA coordinates; the chosen patches'
//!    overlapping pixels are averaged into the view's target (Kwatra's least-squares
//!    E-step with r = 2).
//! 2. **Balance**: a style patch's k-means cell that was used more than its share of the
//!    bank in the previous round costs `balance` x (the mean match distance) x (its
//!    excess use ratio): the occurrence penalty of self-tuning texture optimisation
//!    (Kaspar et al., EG 2015), in the form of the patch prior's cell-wise balance
//!    (docs/patch-prior.md), so the object takes all of the style's palette rather than
//!    its commonest patch.
//! 3. **M-step**: the colours fitted to every view's held target for `steps` Adam steps
//!    (L2, all views at once: the Gaussians that several views share take the
//!    least-squares compromise of their targets). A coarse level's target changes the
//!    render only in its own band: target = render + alpha up_s(vote - pool_s(colour)).
//!
//! It is the limit of the patch prior's denoiser as the noise goes to zero (a posterior
//! mean that concentrates on the nearest patch), run without noise and with the targets
//! held (docs/patch-prior.md, "The deterministic end").

use super::fill::fill_background;
use crate::imageio::Image;
use crate::optim::{ColourFit, FitParams};
use crate::prior::patch::bank::{Bank, Pca, patches, patches_at};
use crate::selection::Selection;
use crate::{Camera, Error, Result, Scene};
use ndarray::{Array2, Array3, Axis};
use rayon::prelude::*;

/// The settings of the patch synthesis (the `[synthesis]` section of the method's
/// configuration; `finish = "patches"` runs it).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthesisParams {
    /// Levels, coarsest first: render pixels per synthesis pixel (a patch covers
    /// patch x level render pixels: 7 x 8 = 56 px places motifs of that size).
    #[arg(long, value_delimiter = ',', default_value = "8,4,2,1")]
    pub levels: Vec<usize>,
    /// Patch side in synthesis pixels (odd).
    #[arg(long, default_value_t = 7)]
    pub patch: usize,
    /// Step of the grid of the object's patches (synthesis pixels).
    #[arg(long, default_value_t = 2)]
    pub stride: usize,
    /// Step of the grid the style's patches are taken on at the finest level (coarser
    /// levels take every pixel).
    #[arg(long, default_value_t = 2)]
    pub style_stride: usize,
    /// E/M rounds per level.
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// Colour-fit steps per round (Adam, every view).
    #[arg(long, default_value_t = 8)]
    pub steps: usize,
    /// Adam learning rate of the SH DC colours in the fit.
    #[arg(long, default_value_t = 0.05)]
    pub lr: f32,
    /// Weight of the occurrence penalty (0: plain nearest patches).
    #[arg(long, default_value_t = 1.0)]
    pub balance: f32,
    /// PCA dimensions of the search.
    #[arg(long, default_value_t = 24)]
    pub pca_dims: usize,
}

impl Default for SynthesisParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl SynthesisParams {
    /// Checked ranges.
    pub fn validate(&self) -> Result<()> {
        if self.patch % 2 == 0 || self.patch < 3 {
            return Err(Error::param("synthesis.patch must be odd and >= 3"));
        }
        if self.levels.is_empty() || self.levels.iter().any(|&s| s == 0 || s > 32) {
            return Err(Error::param("synthesis.levels: 1 to 32 each, at least one"));
        }
        if self.stride == 0 || self.style_stride == 0 || self.pca_dims == 0 {
            return Err(Error::param(
                "synthesis.stride, style_stride and pca_dims must be >= 1",
            ));
        }
        if !(self.lr.is_finite() && self.lr >= 0.0 && self.balance.is_finite() && self.balance >= 0.0)
        {
            return Err(Error::param("synthesis.lr and balance must be finite and >= 0"));
        }
        Ok(())
    }
}

/// Cells of a level's style bank (the balance's unit).
const CELLS: usize = 64;
/// A synthesis pixel is the object's when its pooled coverage exceeds this.
const OBJECT: f32 = 0.5;

/// One level's style model: the bank and each patch's cell.
struct StyleLevel {
    bank: Bank,
    cell_of: Vec<u32>,
    /// Each cell's share of the bank.
    share: Vec<f32>,
}

impl StyleLevel {
    fn new(style: &Image, side: usize, p: &SynthesisParams, stride: usize) -> Result<StyleLevel> {
        let img = style.with_shorter_side(side.max(p.patch)).to_chw();
        let pts = patches(img.view(), p.patch, stride);
        let pca = Pca::fit(pts.view(), p.pca_dims.min(pts.ncols()), 12)?;
        let bank = Bank::new(pts, p.patch, 3, Some(pca), CELLS)?;
        let m = bank.len();
        let mut cell_of = vec![0u32; m];
        let mut share = vec![1.0f32; 1];
        if let Some(ivf) = bank.reduced.as_ref().and_then(|r| r.ivf.as_ref()) {
            share = ivf.cells.iter().map(|c| c.len() as f32 / m as f32).collect();
            for (c, rows) in ivf.cells.iter().enumerate() {
                for &r in rows {
                    cell_of[r as usize] = c as u32;
                }
            }
        }
        Ok(StyleLevel {
            bank,
            cell_of,
            share,
        })
    }

    /// The nearest bank patch of each query `[P, D]` (PCA coordinates, exact search) with
    /// each cell's `penalty` added: (patch index, squared distance without the penalty).
    fn nearest(&self, q: &Array2<f32>, penalty: &[f32]) -> Vec<(u32, f32)> {
        let r = self.bank.reduced.as_ref().expect("synthesis banks have a PCA");
        let qc = r.pca.project(q.view(), 1.0);
        let qn: Vec<f32> = qc.rows().into_iter().map(|row| row.dot(&row)).collect();
        let pen: Vec<f32> = self.cell_of.iter().map(|&c| penalty[c as usize]).collect();
        let rows: Vec<usize> = (0..qc.nrows()).collect();
        rows.par_chunks(256)
            .flat_map_iter(|chunk| {
                let block = qc.slice(ndarray::s![chunk[0]..chunk[0] + chunk.len(), ..]);
                let dots = block.dot(&r.coords.t());
                let out: Vec<(u32, f32)> = dots
                    .rows()
                    .into_iter()
                    .zip(chunk)
                    .map(|(row, &i)| {
                        let mut best = (0u32, f32::INFINITY, f32::INFINITY);
                        for (j, (&d, (&n, &pj))) in row.iter().zip(r.norms.iter().zip(&pen)).enumerate() {
                            let dist = (qn[i] + n - 2.0 * d).max(0.0);
                            if dist + pj < best.2 {
                                best = (j as u32, dist, dist + pj);
                            }
                        }
                        (best.0, best.1)
                    })
                    .collect();
                out.into_iter()
            })
            .collect()
    }
}

/// What the synthesis did, per level.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LevelReport {
    pub level: usize,
    /// Style patches in the level's bank.
    pub bank: usize,
    /// Mean squared patch distance of the last round's matches.
    pub distance: f32,
    /// Cells used in the last round, of the bank's.
    pub cells_used: usize,
    pub cells: usize,
    /// Loss of the last fit step.
    pub loss: f64,
}

/// `scene`'s colours synthesised from `style` on the views of `cameras` (module docs);
/// `style_size` is the style's shorter side in render pixels (the motif scale), and a
/// `selection` scales each Gaussian's updates by its weight.
pub fn synthesize(
    scene: &Scene,
    cameras: &[Camera],
    style: &Image,
    background: [f32; 3],
    style_size: usize,
    p: &SynthesisParams,
    selection: Option<&Selection>,
) -> Result<(Scene, Vec<LevelReport>)> {
    p.validate()?;
    let _ph = crate::timing::span("patch synthesis");
    let fp = FitParams {
        lr_dc: p.lr,
        lr_rest: 0.0,
        background,
        ..FitParams::default()
    };
    let mut fit = ColourFit::without_targets(scene, cameras, &fp)?;
    fit.set_weights(selection)?;
    let alpha: Vec<Vec<f32>> = crate::render::render_all(scene, cameras, background)?
        .into_iter()
        .map(|r| r.alpha)
        .collect();
    let all: Vec<usize> = (0..cameras.len()).collect();
    let mut reports = Vec::new();
    let bar = indicatif::ProgressBar::new((p.levels.len() * p.rounds) as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} rounds {elapsed} (ETA {eta})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    for &s in &p.levels {
        let stride = if s == 1 { p.style_stride } else { 1 };
        let level = StyleLevel::new(style, style_size / s, p, stride)?;
        let mut penalty = vec![0.0f32; level.share.len()];
        let mut last = (0.0f32, 0usize, 0.0f64);
        for _ in 0..p.rounds {
            bar.set_message(format!("patch synthesis, level {s}"));
            let mut used = vec![0usize; level.share.len()];
            let mut dist_sum = 0.0f64;
            let mut count = 0usize;
            let mut targets = Vec::with_capacity(all.len());
            for &v in &all {
                let rgb = fit.render_view(v);
                let cam = &cameras[v];
                let (h, w) = (cam.height as usize, cam.width as usize);
                let view = ViewImage::new(&rgb, &alpha[v], background, (h, w), s);
                let (t, m) = view.target(&level, &penalty, p, &rgb, &alpha[v]);
                for &(j, d) in &m {
                    used[level.cell_of[j as usize] as usize] += 1;
                    dist_sum += d as f64;
                }
                count += m.len();
                targets.push(t);
            }
            let mean_d = (dist_sum / count.max(1) as f64) as f32;
            penalty = balance_penalty(&used, &level.share, mean_d, p.balance);
            let mut loss = 0.0;
            for _ in 0..p.steps {
                loss = fit.step_views(&all, &mut |v, rgb, _| Ok(l2(rgb, &targets[v])))?;
            }
            last = (mean_d, used.iter().filter(|&&u| u > 0).count(), loss);
            bar.inc(1);
        }
        tracing::info!(
            "patch synthesis level {s}: {} style patches, mean distance {:.4}, {} of {} cells used, loss {:.5}",
            level.bank.len(),
            last.0,
            last.1,
            level.share.len(),
            last.2
        );
        reports.push(LevelReport {
            level: s,
            bank: level.bank.len(),
            distance: last.0,
            cells_used: last.1,
            cells: level.share.len(),
            loss: last.2,
        });
    }
    bar.finish_and_clear();
    Ok((fit.scene().clone(), reports))
}

/// The mean squared error of `rgb` against `target` and its gradient.
fn l2(rgb: &[f32], target: &[f32]) -> (f64, Vec<f32>) {
    let n = rgb.len().max(1) as f32;
    let grad: Vec<f32> = rgb
        .iter()
        .zip(target)
        .map(|(a, b)| 2.0 * (a - b) / n)
        .collect();
    let loss = rgb
        .iter()
        .zip(target)
        .map(|(a, b)| ((a - b) * (a - b)) as f64)
        .sum::<f64>()
        / n as f64;
    (loss, grad)
}

/// Each cell's penalty for the next round: `weight` x `mean_d` x its use beyond its share.
fn balance_penalty(used: &[usize], share: &[f32], mean_d: f32, weight: f32) -> Vec<f32> {
    let total: usize = used.iter().sum();
    used.iter()
        .zip(share)
        .map(|(&u, &s)| {
            let expected = (s * total as f32).max(1e-6);
            weight * mean_d * (u as f32 / expected - 1.0).max(0.0)
        })
        .collect()
}

/// One view at one level: its colour over a fill of itself, pooled, and its coverage.
struct ViewImage {
    /// `[1, 3, h, w]`.
    colour: ndarray::Array4<f32>,
    /// `[h, w]`.
    alpha: Array2<f32>,
    s: usize,
}

impl ViewImage {
    fn new(rgb: &[f32], alpha: &[f32], bg: [f32; 3], (h, w): (usize, usize), s: usize) -> Self {
        let filled = fill_background(rgb, alpha, bg, h, w);
        let (hl, wl) = (h / s, w / s);
        let inv = 1.0 / (s * s) as f32;
        let mut colour = ndarray::Array4::<f32>::zeros((1, 3, hl, wl));
        let mut a = Array2::<f32>::zeros((hl, wl));
        for y in 0..hl * s {
            for x in 0..wl * s {
                let (yl, xl) = (y / s, x / s);
                for c in 0..3 {
                    colour[[0, c, yl, xl]] += filled[(y * w + x) * 3 + c] * inv;
                }
                a[[yl, xl]] += alpha[y * w + x] * inv;
            }
        }
        ViewImage {
            colour,
            alpha: a,
            s,
        }
    }

    /// The view's full-resolution target (`[H, W, 3]`: the render plus its coverage times
    /// the upsampled change of the vote over the pooled colour) and the matches.
    fn target(
        &self,
        level: &StyleLevel,
        penalty: &[f32],
        p: &SynthesisParams,
        rgb: &[f32],
        alpha: &[f32],
    ) -> (Vec<f32>, Vec<(u32, f32)>) {
        let (_, _, hl, wl) = self.colour.dim();
        let step = p.stride.max(1);
        let pixels: Vec<[usize; 3]> = (0..hl)
            .step_by(step)
            .flat_map(|y| (0..wl).step_by(step).map(move |x| [0, y, x]))
            .filter(|&[_, y, x]| self.alpha[[y, x]] > OBJECT)
            .collect();
        if pixels.is_empty() {
            return (rgb.to_vec(), Vec::new());
        }
        let q = patches_at(self.colour.view(), p.patch, &pixels);
        let m = level.nearest(&q, penalty);
        let delta = self.vote(level, &pixels, &m, p.patch);
        let (h, w) = (hl * self.s, wl * self.s);
        let full_w = rgb.len() / 3 / h.max(1);
        let mut t = rgb.to_vec();
        for y in 0..h {
            for x in 0..w {
                let d = upsample_at(&delta, y, x, self.s);
                let i = y * full_w + x;
                let a = alpha[i];
                for c in 0..3 {
                    t[i * 3 + c] = rgb[i * 3 + c] + a * d[c];
                }
            }
        }
        (t, m)
    }

    /// The average of the matched patches over each object pixel they cover, minus the
    /// pooled colour (`[3, h, w]`; 0 where no patch voted or off the object).
    fn vote(&self, level: &StyleLevel, pixels: &[[usize; 3]], m: &[(u32, f32)], k: usize) -> Array3<f32> {
        let (_, _, hl, wl) = self.colour.dim();
        let mut acc = Array3::<f32>::zeros((3, hl, wl));
        let mut wt = Array2::<f32>::zeros((hl, wl));
        let r = (k / 2) as isize;
        for (&[_, y, x], &(j, _)) in pixels.iter().zip(m) {
            let patch = level.bank.patches.row(j as usize);
            let mut q = 0;
            for dy in -r..=r {
                for dx in -r..=r {
                    let (yy, xx) = (y as isize + dy, x as isize + dx);
                    if yy >= 0 && xx >= 0 && (yy as usize) < hl && (xx as usize) < wl {
                        let (yy, xx) = (yy as usize, xx as usize);
                        for c in 0..3 {
                            acc[[c, yy, xx]] += patch[q + c];
                        }
                        wt[[yy, xx]] += 1.0;
                    }
                    q += 3;
                }
            }
        }
        let colour = self.colour.index_axis(Axis(0), 0);
        Array3::from_shape_fn((3, hl, wl), |(c, y, x)| {
            if wt[[y, x]] > 0.0 && self.alpha[[y, x]] > 0.0 {
                (acc[[c, y, x]] / wt[[y, x]]).clamp(0.0, 1.0) - colour[[c, y, x]]
            } else {
                0.0
            }
        })
    }
}

/// Bilinear upsampling of `d` `[3, h, w]` by `s` at full-resolution pixel (y, x) (pixel
/// centres aligned; clamped at the borders).
fn upsample_at(d: &Array3<f32>, y: usize, x: usize, s: usize) -> [f32; 3] {
    let (_, h, w) = d.dim();
    if s == 1 {
        return [d[[0, y, x]], d[[1, y, x]], d[[2, y, x]]];
    }
    let fy = ((y as f32 + 0.5) / s as f32 - 0.5).clamp(0.0, (h - 1) as f32);
    let fx = ((x as f32 + 0.5) / s as f32 - 0.5).clamp(0.0, (w - 1) as f32);
    let (y0, x0) = (fy.floor() as usize, fx.floor() as usize);
    let (y1, x1) = ((y0 + 1).min(h - 1), (x0 + 1).min(w - 1));
    let (ty, tx) = (fy - y0 as f32, fx - x0 as f32);
    std::array::from_fn(|c| {
        let top = d[[c, y0, x0]] * (1.0 - tx) + d[[c, y0, x1]] * tx;
        let bot = d[[c, y1, x0]] * (1.0 - tx) + d[[c, y1, x1]] * tx;
        top * (1.0 - ty) + bot * ty
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_penalty_falls_on_cells_used_beyond_their_share_only() {
        let p = balance_penalty(&[10, 0, 30], &[0.25, 0.25, 0.5], 2.0, 1.0);
        // 40 uses: expected 10, 10, 20.
        assert_eq!(p, vec![0.0, 0.0, 2.0 * 0.5]);
        assert_eq!(balance_penalty(&[10, 0, 30], &[0.25, 0.25, 0.5], 2.0, 0.0), vec![0.0; 3]);
    }

    #[test]
    fn upsampling_is_exact_at_level_one_and_constant_on_a_constant() {
        let d = Array3::from_shape_fn((3, 4, 4), |(c, y, x)| (c * 16 + y * 4 + x) as f32);
        assert_eq!(upsample_at(&d, 2, 3, 1), [11.0, 27.0, 43.0]);
        let k = Array3::from_elem((3, 4, 4), 0.25f32);
        for (y, x) in [(0, 0), (7, 3), (15, 15)] {
            assert_eq!(upsample_at(&k, y, x, 4), [0.25; 3]);
        }
    }

    #[test]
    fn a_style_of_one_patch_repeated_is_what_every_query_takes() {
        // A style made of two flat colours: a flat query of either colour takes a patch of
        // its own colour (the search is exact in PCA coordinates).
        let mut data = vec![0.0f32; 32 * 32 * 3];
        for y in 0..32 {
            for x in 0..32 {
                let v = if x < 16 { [0.9, 0.1, 0.1] } else { [0.1, 0.1, 0.9] };
                data[(y * 32 + x) * 3..(y * 32 + x) * 3 + 3].copy_from_slice(&v);
            }
        }
        let style = Image {
            width: 32,
            height: 32,
            data,
        };
        let p = SynthesisParams {
            patch: 3,
            pca_dims: 4,
            ..SynthesisParams::default()
        };
        let level = StyleLevel::new(&style, 32, &p, 1).unwrap();
        let red = Array2::from_shape_fn((1, 27), |(_, i)| [0.85, 0.15, 0.1][i % 3]);
        let blue = Array2::from_shape_fn((1, 27), |(_, i)| [0.1, 0.15, 0.85][i % 3]);
        for (q, want) in [(red, 0.9f32), (blue, 0.1)] {
            let pen = vec![0.0; level.share.len()];
            let (j, _) = level.nearest(&q, &pen)[0];
            assert_eq!(level.bank.centres[[j as usize, 0]], want);
        }
    }
}

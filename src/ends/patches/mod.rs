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
//!    overlapping pixels are averaged into the view's target (Kwatra's E-step with his
//!    robust weights, r = 0.8, and a Gaussian fall-off from each patch's centre).
//! 2. **Balance**: the matches of all views are made together, through an entropic
//!    coupling of the object's patches to the style bank's k-means cells (Sinkhorn in the
//!    log domain, the cells' marginal their share of the bank relaxed by the exponent
//!    `balance`, the KL-penalised unbalanced form of Chizat et al. 2018); each patch takes
//!    the nearest style patch of its cell. The patch prior balances its posterior the same
//!    way (docs/patch-prior.md); without it the object takes the style's patches nearest
//!    its own colour only (self-tuning texture optimisation, Kaspar et al. 2015, makes the
//!    same point with an occurrence penalty).
//! 3. **M-step**: the colours fitted to every view's held target for `steps` Adam steps
//!    (L2, all views at once: the Gaussians that several views share take the
//!    least-squares compromise of their targets). A coarse level's target changes the
//!    render only in its own band: target = render + alpha up_s(vote - pool_s(colour)).
//!
//! It is the limit of the patch prior's denoiser as the noise goes to zero (a posterior
//! mean that concentrates on the nearest patch), run without noise and with the targets
//! held (docs/patch-prior.md, "The deterministic end").

pub mod guide;
pub mod negative;

use super::fill::fill_background;
use crate::imageio::Image;
use crate::optim::{ColourFit, FitParams};
use crate::prior::patch::bank::{Bank, Pca, patches, patches_at};
use crate::prior::patch::latent::{pool, upsample};
use crate::selection::Selection;
use crate::{Camera, Error, Result, Scene};
use ndarray::{Array2, Array3, Array4, Axis};
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
    /// Balance of the style's patch use, in [0, 1]: the exponent of the cells' marginal
    /// in the coupling of the object's patches to the style's cells (0: each patch its
    /// nearest; 1: every cell used in proportion to its share of the style).
    #[arg(long, default_value_t = 1.0)]
    pub balance: f32,
    /// PCA dimensions of the search.
    #[arg(long, default_value_t = 24)]
    pub pca_dims: usize,
    /// The structure guide's weight (ControlNet's role): how much the frozen source
    /// render's luminance, remapped to the style's, counts beside the colours in the
    /// match and the coupling (0: unguided; 1: a pixel's guide weighs like its three
    /// colour channels). See `guide.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub control: f32,
    /// The guidance scale at t -> 0: how far each patch moves from the scene's own
    /// (the source branch) toward its style patch (the style branch): 1 takes the style
    /// patch, 0 keeps the scene.
    #[arg(long, default_value_t = 1.0)]
    pub guidance: f32,
    /// The negative scale at t -> 0: the cost, in mean match distances, of a style patch
    /// that continues the piece a neighbouring patch copied (the content branch's
    /// prediction, the style image's own layout); higher copies smaller pieces. See
    /// `negative.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub negative: f32,
}

impl Default for SynthesisParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl SynthesisParams {
    /// Checked ranges.
    pub fn validate(&self) -> Result<()> {
        if self.patch.is_multiple_of(2) || self.patch < 3 {
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
        if !(self.lr.is_finite() && self.lr >= 0.0) {
            return Err(Error::param("synthesis.lr must be finite and >= 0"));
        }
        if !(0.0..=1.0).contains(&self.balance) {
            return Err(Error::param("synthesis.balance must lie in [0, 1]"));
        }
        if !(self.control.is_finite() && (0.0..=100.0).contains(&self.control)) {
            return Err(Error::param("synthesis.control must lie in [0, 100]"));
        }
        if !(self.guidance.is_finite() && (0.0..=2.0).contains(&self.guidance)) {
            return Err(Error::param("synthesis.guidance must lie in [0, 2]"));
        }
        if !(self.negative.is_finite() && (0.0..=100.0).contains(&self.negative)) {
            return Err(Error::param("synthesis.negative must lie in [0, 100]"));
        }
        Ok(())
    }
}

/// Cells of a level's style bank (the balance's unit).
const CELLS: usize = 64;
/// A synthesis pixel is the object's when its pooled coverage exceeds this.
const OBJECT: f32 = 0.5;

/// One level's style model: the bank, each patch's cell, and the search space (the
/// patches' colour PCA coordinates, beside their guide's when the end is guided).
struct StyleLevel {
    bank: Bank,
    cell_of: Vec<u32>,
    /// Each cell's share of the bank.
    share: Vec<f32>,
    /// The guide's part of the search, when the end is guided.
    guide: Option<GuideSpace>,
    /// Search coordinates `[M, d]` of the bank's patches and their squared norms.
    coords: Array2<f32>,
    norms: Vec<f32>,
    /// Each bank patch's centre (y, x) in the level's style image.
    pos: Vec<[i32; 2]>,
}

/// The guide channel's reduced space: its PCA and its weight in the search (the square
/// root of `3 control`, module [`guide`]).
struct GuideSpace {
    pca: Pca,
    weight: f32,
}

impl GuideSpace {
    /// The search coordinates of guide patches `[P, k k]`, weighted: each patch's mean
    /// (times k, so that a mean difference counts over the patch's k k pixels) beside
    /// the PCA coordinates of its detail (the patch minus its mean). The mean is kept
    /// apart because a style's patches may all share one mean (regular stripes): a PCA
    /// of the patches would then drop the direction that says where the object is dark.
    fn coords(&self, g: &Array2<f32>) -> Array2<f32> {
        let (mean, detail) = split_mean(g);
        let k = (g.ncols() as f32).sqrt();
        let mut out = Array2::<f32>::zeros((g.nrows(), 1 + self.pca.basis.ncols()));
        out.column_mut(0).assign(&(mean * (k * self.weight)));
        let d = self.pca.project(detail.view(), 1.0) * self.weight;
        out.slice_mut(ndarray::s![.., 1..]).assign(&d);
        out
    }
}

/// Each row's mean `[P]` and the rows minus their means `[P, D]`.
fn split_mean(g: &Array2<f32>) -> (ndarray::Array1<f32>, Array2<f32>) {
    let mean = g.mean_axis(Axis(1)).expect("patches have pixels");
    let detail = g - &mean.view().insert_axis(Axis(1));
    (mean, detail)
}

/// Fewest motif patches a level keeps its background out with.
const MIN_MOTIF_PATCHES: usize = 16;

/// PCA dimensions of the guide's patches.
const GUIDE_DIMS: usize = 8;
/// A style patch joins the bank when at least this share of its pixels is motif
/// ([`guide::motif_mask`]).
const MOTIF_SHARE: f32 = 0.5;

impl StyleLevel {
    /// The level's model of `style` at `side` px on its shorter side, its patches on the
    /// grid of step `stride`; guided (the style's own luma beside its colours) when
    /// `guided` and `p.control` > 0.
    fn new(
        style: &Image,
        side: usize,
        p: &SynthesisParams,
        stride: usize,
        guided: bool,
    ) -> Result<StyleLevel> {
        let sized = style.with_shorter_side(side.max(p.patch));
        let motif = guide::motif_mask(&sized);
        let keep = motif_rows(&motif, &sized, p.patch, stride);
        let sized = if keep.is_empty() {
            sized
        } else {
            guide::fill_background(&sized, &motif)
        };
        let img = sized.to_chw();
        let (h, w) = (sized.height, sized.width);
        let xs = w.div_ceil(stride);
        let pos: Vec<[i32; 2]> = (0..h.div_ceil(stride) * xs)
            .filter(|&r| keep.is_empty() || keep[r])
            .map(|r| [((r / xs) * stride) as i32, ((r % xs) * stride) as i32])
            .collect();
        let pts = select_rows(patches(img.view(), p.patch, stride), &keep);
        let pca = Pca::fit(pts.view(), p.pca_dims.min(pts.ncols()), 12)?;
        let bank = Bank::new(pts, p.patch, 3, Some(pca), CELLS)?;
        let m = bank.len();
        let mut cell_of = vec![0u32; m];
        let mut share = vec![1.0f32; 1];
        let r = bank.reduced.as_ref().expect("synthesis banks have a PCA");
        if let Some(ivf) = r.ivf.as_ref() {
            share = ivf
                .cells
                .iter()
                .map(|c| c.len() as f32 / m as f32)
                .collect();
            for (c, rows) in ivf.cells.iter().enumerate() {
                for &row in rows {
                    cell_of[row as usize] = c as u32;
                }
            }
        }
        let (guide, coords) = if guided && p.control > 0.0 {
            let l = Array3::from_shape_vec((1, h, w), guide::luma(&sized.data))
                .expect("one luma per pixel");
            let gp = select_rows(patches(l.view(), p.patch, stride), &keep);
            let (_, detail) = split_mean(&gp);
            let gpca = Pca::fit(detail.view(), GUIDE_DIMS.min(gp.ncols()), 12)?;
            let space = GuideSpace {
                weight: (3.0 * p.control).sqrt(),
                pca: gpca,
            };
            let gc = space.coords(&gp);
            let coords = ndarray::concatenate(Axis(1), &[r.coords.view(), gc.view()])
                .expect("one row per patch");
            (Some(space), coords)
        } else {
            (None, r.coords.clone())
        };
        let norms = coords.rows().into_iter().map(|row| row.dot(&row)).collect();
        Ok(StyleLevel {
            bank,
            cell_of,
            share,
            guide,
            coords,
            norms,
            pos,
        })
    }

    /// The search coordinates of queries: colour patches `q` `[P, k k 3]` and, when the
    /// level is guided, their guide patches `g` `[P, k k]`.
    fn project(&self, q: &Array2<f32>, g: Option<&Array2<f32>>) -> Array2<f32> {
        let r = self
            .bank
            .reduced
            .as_ref()
            .expect("synthesis banks have a PCA");
        let qc = r.pca.project(q.view(), 1.0);
        match (&self.guide, g) {
            (Some(space), Some(g)) => {
                let gc = space.coords(g);
                ndarray::concatenate(Axis(1), &[qc.view(), gc.view()]).expect("one row each")
            }
            _ => qc,
        }
    }

    /// For each query (search coordinates `qc` `[P, d]`) and each cell of the bank, the
    /// nearest patch of that cell (exact search): `[P x cells]` squared distances and
    /// patch indices (infinite distance for an empty cell).
    fn nearest_per_cell(&self, qc: &Array2<f32>) -> (Vec<f32>, Vec<u32>) {
        let cells = self.share.len();
        let qn: Vec<f32> = qc.rows().into_iter().map(|row| row.dot(&row)).collect();
        let rows: Vec<usize> = (0..qc.nrows()).collect();
        let out: Vec<(Vec<f32>, Vec<u32>)> = rows
            .par_chunks(256)
            .map(|chunk| {
                let block = qc.slice(ndarray::s![chunk[0]..chunk[0] + chunk.len(), ..]);
                let dots = block.dot(&self.coords.t());
                let mut dist = vec![f32::INFINITY; chunk.len() * cells];
                let mut arg = vec![0u32; chunk.len() * cells];
                for (k, (row, &i)) in dots.rows().into_iter().zip(chunk).enumerate() {
                    let (d, a) = (&mut dist[k * cells..], &mut arg[k * cells..]);
                    for (j, (&dot, &n)) in row.iter().zip(self.norms.iter()).enumerate() {
                        let c = self.cell_of[j] as usize;
                        let v = (qn[i] + n - 2.0 * dot).max(0.0);
                        if v < d[c] {
                            d[c] = v;
                            a[c] = j as u32;
                        }
                    }
                }
                (dist, arg)
            })
            .collect();
        let (mut dist, mut arg) = (Vec::new(), Vec::new());
        for (d, a) in out {
            dist.extend(d);
            arg.extend(a);
        }
        (dist, arg)
    }

    /// Each query's style patch (index, squared distance): for search coordinates `qc`
    /// ([`Self::project`]), the nearest patch of the cell the balanced coupling gives it (module docs, step 2). `balance` is the exponent
    /// rho of the cells' marginal (0: every query its nearest patch; 1: the cells used in
    /// proportion to their share of the bank), `eps` the coupling's temperature relative
    /// to the mean nearest distance.
    fn assign(&self, qc: &Array2<f32>, balance: f32, eps: f32) -> Vec<(u32, f32)> {
        let (dist, arg) = self.nearest_per_cell(qc);
        let cells = self.share.len();
        self.couple(&dist, balance, eps)
            .into_iter()
            .enumerate()
            .map(|(i, c)| (arg[i * cells + c], dist[i * cells + c]))
            .collect()
    }

    /// Each query's style patch (index, squared distance) as [`Self::assign`] gives it,
    /// with the negative branch ([`negative`]) when `p.negative` > 0: a first pass, then
    /// every candidate coherent with a neighbour's first match pays the negative cost
    /// and the coupling is made again. `nbrs`: each query's neighbours.
    fn match_all(
        &self,
        qc: &Array2<f32>,
        nbrs: &[Vec<negative::Neighbour>],
        p: &SynthesisParams,
    ) -> Vec<(u32, f32)> {
        if p.negative <= 0.0 {
            return self.assign(qc, p.balance, BALANCE_EPS);
        }
        let (raw, arg) = self.nearest_per_cell(qc);
        let cells = self.share.len();
        let pick = |d: &[f32]| -> Vec<usize> {
            self.couple(d, p.balance, BALANCE_EPS)
                .into_iter()
                .enumerate()
                .map(|(i, c)| i * cells + c)
                .collect()
        };
        let first: Vec<u32> = pick(&raw).into_iter().map(|k| arg[k]).collect();
        let n = first.len().max(1) as f64;
        let mean_min = raw
            .chunks(cells)
            .map(|r| r.iter().copied().fold(f32::INFINITY, f32::min) as f64)
            .sum::<f64>()
            / n;
        let mut dist = raw.clone();
        let cost = (p.negative as f64 * mean_min) as f32;
        negative::penalise(&mut dist, &arg, &first, nbrs, &self.pos, cost);
        pick(&dist).into_iter().map(|k| (arg[k], raw[k])).collect()
    }

    /// Each query's cell under the balanced coupling of its distances `dist`
    /// `[P x cells]` to the cells' nearest patches ([`Self::assign`]).
    fn couple(&self, dist: &[f32], balance: f32, eps: f32) -> Vec<usize> {
        let cells = self.share.len();
        let p = dist.len() / cells.max(1);
        let best = |row: &[f32], lv: &[f32], t: f32| -> usize {
            let mut b = (0usize, f32::NEG_INFINITY);
            for (c, (&d, &v)) in row.iter().zip(lv).enumerate() {
                let s = v - d / t;
                if s > b.1 {
                    b = (c, s);
                }
            }
            b.0
        };
        let mut log_v = vec![0.0f32; cells];
        if balance > 0.0 && p > 0 {
            let mean_min = dist
                .chunks(cells)
                .map(|r| r.iter().copied().fold(f32::INFINITY, f32::min) as f64)
                .sum::<f64>()
                / p as f64;
            let t = (eps as f64 * mean_min).max(1e-6) as f32;
            let log_share: Vec<f32> = self.share.iter().map(|s| s.max(1e-12).ln()).collect();
            let mut log_u = vec![0.0f32; p];
            for _ in 0..SINKHORN_ITERS {
                log_u
                    .par_iter_mut()
                    .zip(dist.par_chunks(cells))
                    .for_each(|(u, row)| {
                        *u = -logsumexp(row.iter().zip(&log_v).map(|(&d, &v)| v - d / t));
                    });
                let col = column_logsumexp(dist, &log_u, cells, t);
                // The cells' marginal p share_c, relaxed by the exponent rho = balance
                // (the KL-penalised unbalanced form, Chizat et al. 2018).
                let log_p = (p as f32).ln();
                for c in 0..cells {
                    log_v[c] = if col[c].is_finite() {
                        balance * (log_share[c] + log_p - col[c])
                    } else {
                        0.0
                    };
                }
            }
            return dist.chunks(cells).map(|row| best(row, &log_v, t)).collect();
        }
        dist.chunks(cells)
            .map(|row| best(row, &log_v, 1.0))
            .collect()
    }
}

/// Sinkhorn iterations of the balance.
const SINKHORN_ITERS: usize = 30;

/// Which patches of `style` (on the grid of step `stride`, [`patches`]' order) are
/// mostly `motif`, not a flat background ([`guide::motif_mask`]); empty (every patch)
/// when the style has no background or fewer than `MIN_MOTIF_PATCHES` would be kept.
fn motif_rows(motif: &[bool], style: &Image, k: usize, stride: usize) -> Vec<bool> {
    if motif.iter().all(|&m| m) {
        return Vec::new();
    }
    let m = Array3::from_shape_fn((1, style.height, style.width), |(_, y, x)| {
        f32::from(u8::from(motif[y * style.width + x]))
    });
    let share = patches(m.view(), k, stride)
        .mean_axis(Axis(1))
        .expect("k >= 1");
    let keep: Vec<bool> = share.iter().map(|&s| s >= MOTIF_SHARE).collect();
    if keep.iter().filter(|&&k| k).count() < MIN_MOTIF_PATCHES {
        return Vec::new();
    }
    keep
}

/// The rows of `x` whose `keep` holds (all of them when `keep` is empty).
fn select_rows(x: Array2<f32>, keep: &[bool]) -> Array2<f32> {
    if keep.is_empty() {
        return x;
    }
    let rows: Vec<usize> = (0..x.nrows()).filter(|&i| keep[i]).collect();
    x.select(Axis(0), &rows)
}

/// log sum exp of `xs` (stable).
fn logsumexp(xs: impl Iterator<Item = f32> + Clone) -> f32 {
    let m = xs.clone().fold(f32::NEG_INFINITY, f32::max);
    if !m.is_finite() {
        return m;
    }
    m + xs.map(|x| (x - m).exp()).sum::<f32>().ln()
}

/// For each cell c, log sum_q exp(log_u_q - dist_qc / t).
fn column_logsumexp(dist: &[f32], log_u: &[f32], cells: usize, t: f32) -> Vec<f32> {
    (0..cells)
        .into_par_iter()
        .map(|c| {
            logsumexp(
                dist.chunks(cells)
                    .zip(log_u)
                    .map(|(row, &u)| u - row[c] / t),
            )
        })
        .collect()
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
    /// The share of neighbouring object patches that copied neighbouring style patches
    /// in the last round (the pieces copied whole, [`negative::coherence`]).
    pub coherence: f32,
    /// Loss of the last fit step.
    pub loss: f64,
}

/// `scene`'s colours synthesised from `style` on the views of `cameras` (module docs);
/// `style_size` is the style's shorter side in render pixels (the motif scale), and a
/// `selection` scales each Gaussian's updates by its weight. The structure guide and
/// the source branch come from `source` (`[H, W, 3]` per view of `cameras`: the input
/// scene's renders, before any loop changed its colours) when given, else from
/// `scene`'s own renders.
#[allow(clippy::too_many_arguments)]
pub fn synthesize(
    scene: &Scene,
    cameras: &[Camera],
    style: &Image,
    background: [f32; 3],
    style_size: usize,
    p: &SynthesisParams,
    selection: Option<&Selection>,
    source: Option<&[Vec<f32>]>,
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
    let sizes: Vec<(usize, usize)> = cameras
        .iter()
        .map(|c| (c.height as usize, c.width as usize))
        .collect();
    let (rgb, alpha): (Vec<Vec<f32>>, Vec<Vec<f32>>) =
        crate::render::render_all(scene, cameras, background)?
            .into_iter()
            .map(|r| (r.rgb, r.alpha))
            .unzip();
    let rgb = match source {
        Some(src)
            if src.len() == rgb.len() && src.iter().zip(&rgb).all(|(a, b)| a.len() == b.len()) =>
        {
            src.to_vec()
        }
        Some(_) => {
            return Err(Error::param(
                "synthesis: the source views do not match the cameras",
            ));
        }
        None => rgb,
    };
    let src = Frozen::new(rgb, alpha, &sizes, style, background, p);
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
        let level = StyleLevel::new(style, style_size / s, p, stride, src.guides.is_some())?;
        let mut last = RoundStats::default();
        for _ in 0..p.rounds {
            bar.set_message(format!("patch synthesis, level {s}"));
            let renders: Vec<Vec<f32>> = all.iter().map(|&v| fit.render_view(v)).collect();
            let (targets, stats) = e_step(&renders, &sizes, &level, s, &src, p);
            for _ in 0..p.steps {
                last.loss = fit.step_views(&all, &mut |v, rgb, _| Ok(l2(rgb, &targets[v])))?;
            }
            (last.distance, last.cells_used) = (stats.distance, stats.cells_used);
            last.coherence = stats.coherence;
            bar.inc(1);
        }
        tracing::info!(
            "patch synthesis level {s}: {} style patches, mean distance {:.4}, {} of {} cells used, coherence {:.3}, loss {:.5}",
            level.bank.len(),
            last.distance,
            last.cells_used,
            level.share.len(),
            last.coherence,
            last.loss
        );
        reports.push(LevelReport {
            level: s,
            bank: level.bank.len(),
            distance: last.distance,
            cells_used: last.cells_used,
            cells: level.share.len(),
            coherence: last.coherence,
            loss: last.loss,
        });
    }
    bar.finish_and_clear();
    Ok((fit.scene().clone(), reports))
}

/// The same synthesis in 2D, view by view's images with nothing shared: the prior's own
/// stylization of each view (`images` `[H, W, 3]` composited over `background` with
/// coverage `alpha`, `sizes` (H, W) per view), each round's target becoming the image.
/// A quick look at what a style does before a 3D run, and the 2D ceiling that the colour
/// fit of [`synthesize`] approaches on the frozen Gaussians. The views are matched
/// together (one balanced coupling), as in 3D.
pub fn synthesize_images(
    images: &[Vec<f32>],
    alpha: &[Vec<f32>],
    sizes: &[(usize, usize)],
    style: &Image,
    background: [f32; 3],
    style_size: usize,
    p: &SynthesisParams,
) -> Result<Vec<Vec<f32>>> {
    p.validate()?;
    if images.len() != alpha.len() || images.len() != sizes.len() {
        return Err(Error::param(format!(
            "preview: {} images, {} coverages, {} sizes",
            images.len(),
            alpha.len(),
            sizes.len()
        )));
    }
    let src = Frozen::new(images.to_vec(), alpha.to_vec(), sizes, style, background, p);
    let mut out = images.to_vec();
    for &s in &p.levels {
        let stride = if s == 1 { p.style_stride } else { 1 };
        let level = StyleLevel::new(style, style_size / s, p, stride, src.guides.is_some())?;
        for _ in 0..p.rounds {
            out = e_step(&out, sizes, &level, s, &src, p).0;
        }
    }
    Ok(out)
}

/// What one round's matches were like.
#[derive(Debug, Clone, Copy, Default)]
struct RoundStats {
    distance: f32,
    cells_used: usize,
    coherence: f32,
    loss: f64,
}

/// What the synthesis holds fixed: the views as they were at its start (the source
/// branch's colours, `[H, W, 3]`), their coverage `[H, W]`, the background, and the
/// structure guides `[H, W]` when `control` > 0 ([`guide::source_guides`]).
struct Frozen {
    rgb: Vec<Vec<f32>>,
    alpha: Vec<Vec<f32>>,
    background: [f32; 3],
    guides: Option<Vec<Vec<f32>>>,
}

impl Frozen {
    fn new(
        rgb: Vec<Vec<f32>>,
        alpha: Vec<Vec<f32>>,
        sizes: &[(usize, usize)],
        style: &Image,
        background: [f32; 3],
        p: &SynthesisParams,
    ) -> Frozen {
        let guides = (p.control > 0.0).then(|| {
            let to = guide::style_moments(style);
            guide::source_guides(&rgb, &alpha, sizes, background, &to)
        });
        Frozen {
            rgb,
            alpha,
            background,
            guides,
        }
    }
}

/// The E-step of one round at level `s`: every view's object patches matched together
/// (one balanced coupling over all views), each view's target `[H, W, 3]`.
/// `renders` `[H, W, 3]` per view, `sizes` (H, W) per view.
fn e_step(
    renders: &[Vec<f32>],
    sizes: &[(usize, usize)],
    level: &StyleLevel,
    s: usize,
    src: &Frozen,
    p: &SynthesisParams,
) -> (Vec<Vec<f32>>, RoundStats) {
    let n = src.alpha.len();
    let views: Vec<ViewImage> = (0..n)
        .into_par_iter()
        .map(|v| ViewImage::new(&renders[v], src, v, sizes[v], s, p))
        .collect();
    let queries: Vec<Query> = views.iter().map(|v| v.queries(p)).collect();
    let stack = |f: &dyn Fn(&Query) -> Option<ndarray::ArrayView2<'_, f32>>| {
        let rows: Option<Vec<_>> = queries.iter().map(f).collect();
        rows.map(|r| ndarray::concatenate(Axis(0), &r).expect("patches of one width"))
    };
    let colour = stack(&|q| Some(q.colour.view())).expect("every view has colours");
    let guides = stack(&|q| q.guide.as_ref().map(|g| g.view()));
    let pixels: Vec<&[[usize; 3]]> = queries.iter().map(|q| &q.pixels[..]).collect();
    let nbrs = negative::neighbours(&pixels, p.stride.max(1));
    let m = level.match_all(&level.project(&colour, guides.as_ref()), &nbrs, p);
    let mut used = vec![false; level.share.len()];
    for &(j, _) in &m {
        used[level.cell_of[j as usize] as usize] = true;
    }
    let chosen: Vec<u32> = m.iter().map(|x| x.0).collect();
    let stats = RoundStats {
        distance: (m.iter().map(|x| x.1 as f64).sum::<f64>() / m.len().max(1) as f64) as f32,
        cells_used: used.iter().filter(|&&u| u).count(),
        coherence: negative::coherence(&chosen, &nbrs, &level.pos),
        loss: 0.0,
    };
    let mut offset = 0;
    let mut targets = Vec::with_capacity(n);
    for (v, q) in queries.iter().enumerate() {
        let mv = &m[offset..offset + q.pixels.len()];
        offset += q.pixels.len();
        targets.push(views[v].target(level, &q.pixels, mv, p, &renders[v], &src.alpha[v]));
    }
    (targets, stats)
}

/// One view's queries at one level: the object's pixels on the grid, their colour
/// patches `[P, k k 3]` and, when guided, their guide patches `[P, k k]`.
struct Query {
    pixels: Vec<[usize; 3]>,
    colour: Array2<f32>,
    guide: Option<Array2<f32>>,
}

/// The votes' Gaussian fall-off from a patch's centre, sigma as a fraction of the patch
/// side (overlapping patches that disagree average to a blur; weighing each by its
/// nearness to the centre keeps the strokes sharper).
const VOTE_SIGMA: f32 = 0.25;

/// The coupling's temperature relative to the mean nearest distance.
const BALANCE_EPS: f32 = 0.1;

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

/// One view at one level: its colour over a fill of itself, pooled, its coverage, and
/// (when the guidance scale is below 1 or the end is guided) its source colour and
/// its guide, pooled.
struct ViewImage {
    /// `[1, 3, h, w]`.
    colour: Array4<f32>,
    /// `[h, w]`.
    alpha: Array2<f32>,
    /// The source branch's colour `[1, 3, h, w]`, when `guidance` != 1.
    source: Option<Array4<f32>>,
    /// The structure guide `[1, 1, h, w]`, when guided.
    guide: Option<Array4<f32>>,
    s: usize,
    /// The full-resolution size (H, W).
    full: (usize, usize),
}

/// `[H, W, C]` values pooled over whole `s` x `s` blocks (the patch prior's pooling):
/// `[1, C, H / s, W / s]`.
fn pooled(x: &[f32], c: usize, (h, w): (usize, usize), s: usize) -> Array4<f32> {
    let (hc, wc) = ((h / s) * s, (w / s) * s);
    let img = Array4::from_shape_fn((1, c, hc, wc), |(_, ch, y, xx)| x[(y * w + xx) * c + ch]);
    pool(img.view(), s)
}

impl ViewImage {
    fn new(
        rgb: &[f32],
        src: &Frozen,
        v: usize,
        size: (usize, usize),
        s: usize,
        p: &SynthesisParams,
    ) -> Self {
        let (alpha, bg) = (&src.alpha[v][..], src.background);
        let filled = |x: &[f32]| fill_background(x, alpha, bg, size.0, size.1);
        let colour = pooled(&filled(rgb), 3, size, s);
        let a = pooled(alpha, 1, size, s)
            .index_axis_move(Axis(0), 0)
            .index_axis_move(Axis(0), 0);
        let source = (p.guidance != 1.0).then(|| pooled(&filled(&src.rgb[v]), 3, size, s));
        let guide = src.guides.as_ref().map(|g| pooled(&g[v], 1, size, s));
        ViewImage {
            colour,
            alpha: a,
            source,
            guide,
            s,
            full: size,
        }
    }

    /// The object's pixels on the grid of step `stride` and their patches.
    fn queries(&self, p: &SynthesisParams) -> Query {
        let (_, _, hl, wl) = self.colour.dim();
        let step = p.stride.max(1);
        let pixels: Vec<[usize; 3]> = (0..hl)
            .step_by(step)
            .flat_map(|y| (0..wl).step_by(step).map(move |x| [0, y, x]))
            .filter(|&[_, y, x]| self.alpha[[y, x]] > OBJECT)
            .collect();
        let colour = patches_at(self.colour.view(), p.patch, &pixels);
        let guide = self
            .guide
            .as_ref()
            .map(|g| patches_at(g.view(), p.patch, &pixels));
        Query {
            pixels,
            colour,
            guide,
        }
    }

    /// The view's full-resolution target (`[H, W, 3]`: the render plus its coverage times
    /// the upsampled change of the vote over the pooled colour) from the matches `m` of
    /// its `pixels`.
    fn target(
        &self,
        level: &StyleLevel,
        pixels: &[[usize; 3]],
        m: &[(u32, f32)],
        p: &SynthesisParams,
        rgb: &[f32],
        alpha: &[f32],
    ) -> Vec<f32> {
        if pixels.is_empty() {
            return rgb.to_vec();
        }
        let (_, _, hl, wl) = self.colour.dim();
        let delta = self.vote(level, pixels, m, p);
        let (h, w) = (hl * self.s, wl * self.s);
        let full_w = self.full.1;
        let up = upsample(delta.view().insert_axis(Axis(0)), self.s);
        let mut t = rgb.to_vec();
        for y in 0..h {
            for x in 0..w {
                let i = y * full_w + x;
                let a = alpha[i];
                for c in 0..3 {
                    t[i * 3 + c] = rgb[i * 3 + c] + a * up[[0, c, y, x]];
                }
            }
        }
        t
    }

    /// The average of the matched patches over each object pixel they cover, minus the
    /// pooled colour (`[3, h, w]`; 0 where no patch voted or off the object).
    fn vote(
        &self,
        level: &StyleLevel,
        pixels: &[[usize; 3]],
        m: &[(u32, f32)],
        p: &SynthesisParams,
    ) -> Array3<f32> {
        let k = p.patch;
        let (_, _, hl, wl) = self.colour.dim();
        let mut acc = Array3::<f32>::zeros((3, hl, wl));
        let mut wt = Array2::<f32>::zeros((hl, wl));
        let r = (k / 2) as isize;
        let sigma = VOTE_SIGMA * k as f32;
        let mean_d = m.iter().map(|x| x.1).sum::<f32>() / m.len().max(1) as f32;
        for (&[_, y, x], &(j, d)) in pixels.iter().zip(m) {
            let patch = level.bank.patches.row(j as usize);
            // Kwatra et al.'s robust weight |d|^(r - 2) with r = 0.8 (d: the match's
            // distance), relative to the mean distance so that it stays bounded.
            let robust = ((d + 0.01 * mean_d + 1e-12) / (mean_d + 1e-12)).powf(-0.6);
            let mut q = 0;
            for dy in -r..=r {
                for dx in -r..=r {
                    let (yy, xx) = (y as isize + dy, x as isize + dx);
                    if yy >= 0 && xx >= 0 && (yy as usize) < hl && (xx as usize) < wl {
                        let (yy, xx) = (yy as usize, xx as usize);
                        let g =
                            robust * (-((dy * dy + dx * dx) as f32) / (2.0 * sigma * sigma)).exp();
                        for c in 0..3 {
                            acc[[c, yy, xx]] += g * patch[q + c];
                        }
                        wt[[yy, xx]] += g;
                    }
                    q += 3;
                }
            }
        }
        let colour = self.colour.index_axis(Axis(0), 0);
        // The guidance scale: from the source's colour toward the style's vote (at 1 the
        // vote itself, bit for bit).
        let g = p.guidance;
        Array3::from_shape_fn((3, hl, wl), |(c, y, x)| {
            if wt[[y, x]] > 0.0 && self.alpha[[y, x]] > 0.0 {
                let vote = (acc[[c, y, x]] / wt[[y, x]]).clamp(0.0, 1.0);
                let to = match &self.source {
                    Some(src) => src[[0, c, y, x]] + g * (vote - src[[0, c, y, x]]),
                    None => vote,
                };
                to - colour[[c, y, x]]
            } else {
                0.0
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upsampling_is_exact_at_level_one_and_constant_on_a_constant() {
        // The targets' upsampling is the patch prior's (`latent::upsample`).
        let d = ndarray::Array4::from_shape_fn((1, 3, 4, 4), |(_, c, y, x)| {
            (c * 16 + y * 4 + x) as f32
        });
        let at = |u: &ndarray::Array4<f32>, y: usize, x: usize| [0, 1, 2].map(|c| u[[0, c, y, x]]);
        assert_eq!(at(&upsample(d.view(), 1), 2, 3), [11.0, 27.0, 43.0]);
        let k = ndarray::Array4::from_elem((1, 3, 4, 4), 0.25f32);
        for (y, x) in [(0, 0), (7, 3), (15, 15)] {
            assert_eq!(at(&upsample(k.view(), 4), y, x), [0.25; 3]);
        }
    }

    #[test]
    fn a_style_of_one_patch_repeated_is_what_every_query_takes() {
        // A style made of two flat colours: a flat query of either colour takes a patch of
        // its own colour (the search is exact in PCA coordinates).
        let mut data = vec![0.0f32; 32 * 32 * 3];
        for y in 0..32 {
            for x in 0..32 {
                let v = if x < 16 {
                    [0.9, 0.1, 0.1]
                } else {
                    [0.1, 0.1, 0.9]
                };
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
        let level = StyleLevel::new(&style, 32, &p, 1, false).unwrap();
        let red = Array2::from_shape_fn((1, 27), |(_, i)| [0.85, 0.15, 0.1][i % 3]);
        let blue = Array2::from_shape_fn((1, 27), |(_, i)| [0.1, 0.15, 0.85][i % 3]);
        for (q, want) in [(red, 0.9f32), (blue, 0.1)] {
            let (j, _) = level.assign(&level.project(&q, None), 0.0, BALANCE_EPS)[0];
            assert_eq!(level.bank.centres[[j as usize, 0]], want);
        }
    }
}

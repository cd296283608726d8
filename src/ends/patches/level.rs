//! One level of the synthesis: the style's model at that scale (its patches on a grid,
//! their bank of k-means cells, each patch's search coordinates: the colours' PCA beside
//! each channel's, [`super::parts::Channel`]) and the search of the object's patches in
//! it: the nearest patch of every cell, exact, then the balanced coupling
//! ([`super::couple`]) and the parts' rematches.
//!
//! Timing phases ([`crate::timing`]): the search is `search`, the coupling `balance`; a
//! channel's work (its style image and PCA, its query coordinates) and a rematch (its
//! penalty and the coupling made again) are each under the part's name.

use super::coherence::Neighbour;
use super::couple::couple;
use super::guide::Moments;
use super::motif::{fill_background, motif_at};
use super::parts::{Channel, Rematch};
use super::search::{CellSearch, Path};
use super::{BALANCE_EPS, CELLS, Named, SynthesisParams};
use crate::Result;
use crate::imageio::Image;
use crate::prior::patch::bank::{Bank, Pca, patches};
use ndarray::{Array2, Array3, Axis};

/// One level's style model: the bank, each patch's cell, and the search space (the
/// patches' colour PCA coordinates, beside their guide's when the end is guided).
pub(super) struct StyleLevel {
    pub(super) bank: Bank,
    pub(super) cell_of: Vec<u32>,
    /// Each cell's share of the bank.
    pub(super) share: Vec<f32>,
    /// The channels' parts of the search ([`super::parts::Channel`]), in order.
    channels: Vec<ChannelSpace>,
    /// Each channel's moments over the bank's patches (each style's with its weight):
    /// the spread the object's channel is narrowed to at this level when its part asks
    /// ([`super::parts::Channel::matched_at_level`]).
    pub(super) channel_moments: Vec<Moments>,
    /// The bank's search coordinates (`[M, d]`: the colours' PCA beside each channel's)
    /// packed for the search.
    search: CellSearch,
    /// Each bank patch's centre (y, x) in the level's style image.
    pub(super) pos: Vec<[i32; 2]>,
}

/// A channel's reduced space: its part's name, its PCA and its weight in the search
/// (the structure guide's: the square root of `3 control`, [`super::guide`]).
struct ChannelSpace {
    name: &'static str,
    pca: Pca,
    weight: f32,
}

impl ChannelSpace {
    /// The search coordinates of channel patches `[P, k k]`, weighted: each patch's mean
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

/// The moments of a channel's patches over a blend's styles (`each_style[i]` style i's
/// patches), each style's with its weight.
fn blend_moments(each_style: &[Array2<f32>], styles: &[(&Image, f32)]) -> Moments {
    Moments::blend(
        each_style
            .iter()
            .zip(styles)
            .map(|(g, &(_, w))| (Moments::of(g.iter().map(|&v| (v, true))), w)),
    )
}

/// Fewest motif patches a level keeps its background out with.
const MIN_MOTIF_PATCHES: usize = 16;

/// PCA dimensions of a channel's patches.
const GUIDE_DIMS: usize = 8;
/// A style patch joins the bank when at least this share of its pixels is motif
/// ([`super::motif::motif_mask`]).
const MOTIF_SHARE: f32 = 0.5;

impl StyleLevel {
    /// The level's model of `styles` (one image, or a blend: images with weights summing
    /// to 1) at `side` px on their shorter side, their patches on the grid of step
    /// `stride`, with each style's own image of each of `channels` beside its colours. A
    /// blend's bank holds every style's patches, one PCA over them all; a cell's share is
    /// the weighted mixture of the styles' shares (each patch of style i counts w_i / M_i,
    /// M_i its patches), so the balance uses each style in proportion to its weight.
    pub(super) fn new(
        styles: &[(&Image, f32)],
        motifs: &[Vec<bool>],
        side: usize,
        p: &SynthesisParams,
        stride: usize,
        channels: &[Named<dyn Channel>],
    ) -> Result<StyleLevel> {
        let each: Vec<Sized> = styles
            .iter()
            .enumerate()
            .map(|(i, &(style, _))| {
                Sized::new((style, &motifs[i]), side.max(p.patch), p, stride, i)
            })
            .collect();
        let pos: Vec<[i32; 2]> = each.iter().flat_map(|e| e.pos.iter().copied()).collect();
        let counts: Vec<usize> = each.iter().map(|e| e.pts.nrows()).collect();
        let pts = stack(each.iter().map(|e| e.pts.view()).collect());
        let pca = Pca::fit(pts.view(), p.pca_dims.min(pts.ncols()), 12)?;
        let bank = Bank::new(pts, p.patch, 3, Some(pca), CELLS)?;
        let m = bank.len();
        let mut cell_of = vec![0u32; m];
        let mut share = vec![1.0f32; 1];
        let r = bank.reduced.as_ref().expect("synthesis banks have a PCA");
        if let Some(ivf) = r.ivf.as_ref() {
            // Which style each bank row came from (rows are the styles' in order).
            let style_of: Vec<usize> = counts
                .iter()
                .enumerate()
                .flat_map(|(i, &n)| std::iter::repeat_n(i, n))
                .collect();
            share = ivf
                .cells
                .iter()
                .map(|c| {
                    let mut per = vec![0usize; styles.len()];
                    for &row in c {
                        per[style_of[row as usize]] += 1;
                    }
                    per.iter()
                        .zip(styles)
                        .zip(&counts)
                        .fold(0.0f32, |acc, ((&n, &(_, w)), &total)| {
                            acc + w * (n as f32 / total as f32)
                        })
                })
                .collect();
            for (c, rows) in ivf.cells.iter().enumerate() {
                for &row in rows {
                    cell_of[row as usize] = c as u32;
                }
            }
        }
        let mut spaces = Vec::with_capacity(channels.len());
        let mut channel_moments = Vec::with_capacity(channels.len());
        let mut parts = vec![r.coords.clone()];
        for &(name, ch) in channels {
            let each_style: Vec<Array2<f32>> =
                each.iter().map(|e| e.channel(ch, p, stride)).collect();
            channel_moments.push(blend_moments(&each_style, styles));
            let gp = stack(each_style.iter().map(|g| g.view()).collect());
            let (_, detail) = split_mean(&gp);
            let gpca = Pca::fit(detail.view(), GUIDE_DIMS.min(gp.ncols()), 12)?;
            let space = ChannelSpace {
                name,
                weight: ch.weight(p),
                pca: gpca,
            };
            parts.push(space.coords(&gp));
            spaces.push(space);
        }
        let coords = if parts.len() == 1 {
            parts.pop().expect("the colours")
        } else {
            let views: Vec<_> = parts.iter().map(|c| c.view()).collect();
            ndarray::concatenate(Axis(1), &views).expect("one row per patch")
        };
        let norms: Vec<f32> = coords.rows().into_iter().map(|row| row.dot(&row)).collect();
        let search = CellSearch::new(&coords, &norms, &cell_of, share.len());
        Ok(StyleLevel {
            bank,
            cell_of,
            share,
            channels: spaces,
            channel_moments,
            search,
            pos,
        })
    }

    /// The search coordinates of queries: colour patches `q` `[P, k k 3]` and their
    /// patches of each of the level's channels `g` `[P, k k]`.
    pub(super) fn project(&self, q: &Array2<f32>, g: &[Array2<f32>]) -> Array2<f32> {
        let r = self
            .bank
            .reduced
            .as_ref()
            .expect("synthesis banks have a PCA");
        let qc = r.pca.project(q.view(), 1.0);
        debug_assert_eq!(g.len(), self.channels.len(), "one patch set per channel");
        if self.channels.is_empty() {
            return qc;
        }
        let mut parts = vec![qc];
        parts.extend(
            self.channels
                .iter()
                .zip(g)
                .map(|(space, g)| crate::timing::phase(space.name, || space.coords(g))),
        );
        let views: Vec<_> = parts.iter().map(|c| c.view()).collect();
        ndarray::concatenate(Axis(1), &views).expect("one row each")
    }

    /// For each query (search coordinates `qc` `[P, d]`) and each cell of the bank, the
    /// nearest patch of that cell (exact search, [`super::search`]): `[P x cells]`
    /// squared distances and patch indices (infinite distance for an empty cell).
    pub(super) fn nearest_per_cell(&self, qc: &Array2<f32>) -> (Vec<f32>, Vec<u32>) {
        self.search.nearest_per_cell(qc, Path::Best)
    }

    /// Each query's style patch (index, squared distance): for search coordinates `qc`
    /// ([`Self::project`]), the nearest patch of the cell the balanced coupling gives it (module docs, step 2). `balance` is the exponent
    /// rho of the cells' marginal (0: every query its nearest patch; 1: the cells used in
    /// proportion to their share of the bank), `eps` the coupling's temperature relative
    /// to the mean nearest distance.
    pub(super) fn assign(&self, qc: &Array2<f32>, balance: f32, eps: f32) -> Vec<(u32, f32)> {
        let (dist, arg) = crate::timing::phase("search", || self.nearest_per_cell(qc));
        let cells = self.share.len();
        crate::timing::phase("balance", || couple(&self.share, &dist, balance, eps))
            .into_iter()
            .enumerate()
            .map(|(i, c)| (arg[i * cells + c], dist[i * cells + c]))
            .collect()
    }

    /// Each query's style patch (index, squared distance) as [`Self::assign`] gives it,
    /// with the `rematches` of the parts that are on ([`super::parts::Rematch`]; the
    /// negative branch, [`super::negative`]): a first pass, then each changes the
    /// distances and the coupling is made again. `nbrs`: each query's neighbours.
    pub(super) fn match_all(
        &self,
        qc: &Array2<f32>,
        nbrs: &[Vec<Neighbour>],
        p: &SynthesisParams,
        rematches: &[Named<dyn Rematch>],
    ) -> Vec<(u32, f32)> {
        if rematches.is_empty() {
            return self.assign(qc, p.balance, BALANCE_EPS);
        }
        let (raw, arg) = crate::timing::phase("search", || self.nearest_per_cell(qc));
        let cells = self.share.len();
        let pick = |d: &[f32]| -> Vec<usize> {
            crate::timing::phase("balance", || couple(&self.share, d, p.balance, BALANCE_EPS))
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
        // The second pass is the rematches' cost: its coupling is timed under their name.
        let names: Vec<&str> = rematches.iter().map(|r| r.0).collect();
        let _ph = crate::timing::span(&names.join(" + "));
        let mut dist = raw.clone();
        for (_, r) in rematches {
            r.penalise(&mut dist, &arg, &first, nbrs, &self.pos, mean_min, p);
        }
        pick(&dist).into_iter().map(|k| (arg[k], raw[k])).collect()
    }
}

/// One style of a level, sized: its image (its background filled when it has one), the
/// rows of its patch grid the bank keeps, those patches `[M_i, k k 3]` and their centres
/// (the `i`-th style's shifted by `i` << 20 columns: no patch continues another style's).
struct Sized {
    image: Image,
    keep: Vec<bool>,
    pts: Array2<f32>,
    pos: Vec<[i32; 2]>,
}

impl Sized {
    fn new(
        (style, motif): (&Image, &[bool]),
        side: usize,
        p: &SynthesisParams,
        stride: usize,
        i: usize,
    ) -> Sized {
        let sized = style.with_shorter_side(side);
        let motif = motif_at(style, motif, (sized.width, sized.height));
        let keep = motif_rows(&motif, &sized, p.patch, stride);
        let image = if keep.is_empty() {
            sized
        } else {
            fill_background(&sized, &motif)
        };
        let (h, w) = (image.height, image.width);
        let xs = w.div_ceil(stride);
        let shift = (i as i32) << 20;
        let pos: Vec<[i32; 2]> = (0..h.div_ceil(stride) * xs)
            .filter(|&r| keep.is_empty() || keep[r])
            .map(|r| {
                [
                    ((r / xs) * stride) as i32,
                    ((r % xs) * stride) as i32 + shift,
                ]
            })
            .collect();
        let pts = select_rows(patches(image.to_chw().view(), p.patch, stride), &keep);
        Sized {
            image,
            keep,
            pts,
            pos,
        }
    }

    /// Its patches of `ch`'s image of it `[M_i, k k]`.
    fn channel(&self, ch: &dyn Channel, p: &SynthesisParams, stride: usize) -> Array2<f32> {
        let (h, w) = (self.image.height, self.image.width);
        let l = Array3::from_shape_vec((1, h, w), ch.style(&self.image, p))
            .expect("one value per pixel");
        select_rows(patches(l.view(), p.patch, stride), &self.keep)
    }
}

/// Row blocks stacked (the one block itself, not copied through a concatenation, when
/// there is one).
fn stack(blocks: Vec<ndarray::ArrayView2<'_, f32>>) -> Array2<f32> {
    if blocks.len() == 1 {
        return blocks[0].to_owned();
    }
    ndarray::concatenate(Axis(0), &blocks).expect("patches of one width")
}

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

#[cfg(test)]
mod tests {
    use super::super::guide::StructureGuide;
    use super::super::motif::luma;
    use super::super::motif::masks;
    use super::super::motif::tests::image;
    use super::*;

    /// The guide's moments at a level are those of the bank's guide patches: for a style
    /// of fine stripes the blur at the motif scale leaves a small part of its spread, for
    /// a style of two halves nearly all of it (what the object's guide is narrowed to,
    /// [`super::super::view`]).
    #[test]
    fn a_levels_guide_moments_are_its_blurred_patches() {
        let p = SynthesisParams {
            patch: 5,
            pca_dims: 4,
            control: 1.0,
            guide_blur: 2.0,
            ..SynthesisParams::default()
        };
        let guide: &[Named<dyn Channel>] = &[("guide", &StructureGuide)];
        let stripes = image(48, 48, |_, x| [if x % 2 == 0 { 0.1 } else { 0.9 }; 3]);
        let halves = image(48, 48, |_, x| [if x < 24 { 0.1 } else { 0.9 }; 3]);
        let moments = |style: &Image| {
            StyleLevel::new(&[(style, 1.0)], &masks(&[(style, 1.0)]), 48, &p, 1, guide)
                .unwrap()
                .channel_moments[0]
        };
        let (s, h) = (moments(&stripes), moments(&halves));
        // Both images have luma spread 0.4 before the blur; the stripes keep little of it
        // after (what they keep is at the image borders, where the blur repeats the edge).
        let full = Moments::of(luma(&stripes.data).into_iter().map(|v| (v, true)));
        assert!((full.std - 0.4).abs() < 1e-3, "{full:?}");
        assert!(
            s.std < 0.15 * full.std,
            "stripes keep {s:?} (their borders)"
        );
        assert!(h.std > 0.8 * full.std, "halves keep {h:?}");
        assert!((s.mean - 0.5).abs() < 0.02 && (h.mean - 0.5).abs() < 0.02);
        // A blend of the two is their mixture's moments.
        let blend = [(&stripes, 0.5), (&halves, 0.5)];
        let b = StyleLevel::new(&blend, &masks(&blend), 48, &p, 1, guide)
            .unwrap()
            .channel_moments[0];
        let want = Moments::blend([(s, 0.5), (h, 0.5)].into_iter());
        assert!((b.mean - want.mean).abs() < 1e-5 && (b.std - want.std).abs() < 1e-5);
    }
}

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
//!    coupling of the object's patches to the style bank's k-means cells (Sinkhorn's
//!    iterations, [`crate::maths::sinkhorn_scaling`], the cells' marginal their share of the bank relaxed by the exponent
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
//!
//! The files: [`level`] (a level's style model), [`search`] (the exact search in
//! it), [`couple`] (the
//! balance), [`view`] (a view's queries, votes and target), [`motif`] (a style's
//! background), [`coherence`] (the pieces copied whole). The parts ([`PARTS`], their
//! kinds in [`parts`]: the structure guide [`guide`], the edge guide [`edges`], the
//! negative branch [`negative`])
//! are switched on by their keys; a new part is one file and one line of [`PARTS`].
//!
//! Timing ([`crate::timing`], `pipeline report`): [`synthesize`] is the phase `patch
//! synthesis`, its parts summed over the levels and rounds: `setup` (the colour fit's
//! views, the source renders, the channels' source images), `style bank` (every level's
//! [`level::StyleLevel`], built at the start, the levels on all cores), `level views` (each
//! view's frozen images at a level, [`view::ViewLevel`], once per level), `render`,
//! `queries`, `search`, `balance`, `stats`, `votes`, `consensus` (with
//! `synthesis.consensus`, [`consensus`]) and `colour fit` (the Adam steps); a part's own work is under its name (`guide`,
//! `negative`). Each level's wall time is in its log line.

pub mod coherence;
pub mod consensus;
pub mod couple;
pub mod detail;
pub mod edges;
pub mod guide;
pub mod level;
pub mod motif;
pub mod negative;
pub mod parts;
pub mod regions;
pub mod scale;
pub mod search;
pub mod settings;
#[cfg(test)]
mod test_red;
pub mod view;

use crate::imageio::Image;
use crate::optim::{ColourFit, FitParams};
use crate::scene::colour::Bands;
use crate::selection::Selection;
use crate::{Camera, Error, Result, Scene};
use level::StyleLevel;
use parts::{Channel, Hook, PartKind, Rematch};
use rayon::prelude::*;
use regions::RegionStyle;
pub use settings::SynthesisParams;
use view::{Query, ViewImage, ViewLevel};

/// The parts, in the order their channels join the search and their rematches apply.
#[rustfmt::skip]
pub const PARTS: &[PartKind] = &[
    PartKind { name: "guide", key: "synthesis.control", help: "the structure guide: the source render's luma, remapped to the style's, matched beside the colours (ControlNet's role)", on: |p| p.control > 0.0 && p.guide_weight > 0.0, hook: Hook::Channel(&guide::StructureGuide) },
    PartKind { name: "edges", key: "synthesis.edges", help: "the edge guide: the style's own edges chosen at the object's strongest edges (EbSynth's edge guide as a cost), the texture free elsewhere", on: |p| p.edges > 0.0 && p.control > 0.0, hook: Hook::Channel(&edges::EdgeGuide) },
    PartKind { name: "negative", key: "synthesis.negative", help: "CSD's negative branch at t -> 0: a style patch continuing a neighbour's piece pays a cost", on: |p| p.negative > 0.0, hook: Hook::Rematch(&negative::Negative) },
    #[cfg(test)]
    PartKind { name: "test-red", key: "(tests only)", help: "the source's red channel as a guide (a test-only part)", on: |_| test_red::on(), hook: Hook::Channel(&test_red::Red) },
];

/// The parts `p` switches on.
pub fn active_parts(p: &SynthesisParams) -> Vec<&'static PartKind> {
    PARTS.iter().filter(|k| (k.on)(p)).collect()
}

/// A part that is on: its name (also the timing phase of its own work,
/// [`crate::timing`]) and what it does.
pub type Named<T> = (&'static str, &'static T);

/// The channels of the parts `p` switches on.
pub fn channels(p: &SynthesisParams) -> Vec<Named<dyn Channel>> {
    active_parts(p)
        .into_iter()
        .filter_map(|k| match k.hook {
            Hook::Channel(c) => Some((k.name, c)),
            Hook::Rematch(_) => None,
        })
        .collect()
}

/// The rematches of the parts `p` switches on.
pub fn rematches(p: &SynthesisParams) -> Vec<Named<dyn Rematch>> {
    active_parts(p)
        .into_iter()
        .filter_map(|k| match k.hook {
            Hook::Rematch(r) => Some((k.name, r)),
            Hook::Channel(_) => None,
        })
        .collect()
}

/// Every part with its key and help, for `--help`.
pub fn parts_help() -> String {
    PARTS
        .iter()
        .map(|k| format!("          {} ({} > 0): {}\n", k.name, k.key, k.help))
        .collect()
}

/// Cells of a level's style bank (the balance's unit).
pub(super) const CELLS: usize = 64;
/// A synthesis pixel is the object's when its pooled coverage exceeds this.
pub(super) const OBJECT: f32 = 0.5;

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

/// `scene`'s colours synthesised from the `regions`' styles on the views of `cameras`
/// (module docs; one region: the whole scene in one style, [`RegionStyle::one`];
/// several: [`regions`]); `style_size` is the styles' shorter side in render pixels
/// (the motif scale), and a `selection` scales each Gaussian's updates by its weight. The structure guide and
/// the source branch come from `source` (`[H, W, 3]` per view of `cameras`: the input
/// scene's renders, before any loop changed its colours) when given, else from
/// `scene`'s own renders. `bands` says whether the fit moves the view-dependent bands
/// (`fit`, at `lr / 20`) or leaves them as `scene` has them.
#[allow(clippy::too_many_arguments)]
pub fn synthesize(
    scene: &Scene,
    cameras: &[Camera],
    regions: &[RegionStyle<'_>],
    background: [f32; 3],
    style_size: usize,
    p: &SynthesisParams,
    selection: Option<&Selection>,
    source: Option<&[Vec<f32>]>,
    bands: Bands,
) -> Result<(Scene, Vec<LevelReport>)> {
    p.validate()?;
    regions::check(regions)?;
    let _ph = crate::timing::span("patch synthesis");
    let fp = FitParams {
        lr_dc: p.lr,
        lr_rest: if bands.fitted() { p.lr / 20.0 } else { 0.0 },
        background,
        ..FitParams::default()
    };
    let sizes: Vec<(usize, usize)> = cameras
        .iter()
        .map(|c| (c.height as usize, c.width as usize))
        .collect();
    let (mut fit, src) = crate::timing::phase("setup", || {
        set_up(
            scene,
            (cameras, &sizes, style_size),
            regions,
            &fp,
            p,
            selection,
            source,
        )
    })?;
    let all: Vec<usize> = (0..cameras.len()).collect();
    let mut reports = Vec::new();
    let bar = indicatif::ProgressBar::new((p.levels.len() * p.rounds) as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg} [{bar:30}] {pos}/{len} rounds {elapsed} (ETA {eta})",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let banks = crate::timing::phase("style bank", || style_banks(regions, style_size, p, &src))?;
    for (at, (&s, levels)) in p.levels.iter().zip(banks).enumerate() {
        let started = std::time::Instant::now();
        // The views' consensus reconciles the finest level's targets only ([`consensus`]).
        let consensus = src.consensus.as_ref().filter(|_| at + 1 == p.levels.len());
        let mut last = RoundStats::default();
        let frozen = crate::timing::phase("level views", || {
            view::levels(&src, &sizes, (s, &levels), p)
        });
        for _ in 0..p.rounds {
            bar.set_message(format!("patch synthesis, level {s}"));
            let renders: Vec<Vec<f32>> = crate::timing::phase("render", || {
                all.par_iter().map(|&v| fit.render_view(v)).collect()
            });
            let (targets, stats) = e_step(&renders, &frozen, &levels, (&src, consensus), p);
            let fit_phase = crate::timing::span("colour fit");
            for _ in 0..p.steps {
                last.loss = fit.step_l2(&targets)?;
            }
            drop(fit_phase);
            (last.distance, last.cells_used) = (stats.distance, stats.cells_used);
            last.coherence = stats.coherence;
            bar.inc(1);
        }
        let bank: usize = levels.iter().map(|l| l.bank.len()).sum();
        let cells: usize = levels.iter().map(|l| l.share.len()).sum();
        tracing::info!(
            "patch synthesis level {s}: {bank} style patches, mean distance {:.4}, {} of {cells} cells used, coherence {:.3}, loss {:.5} ({:.2} s)",
            last.distance,
            last.cells_used,
            last.coherence,
            last.loss,
            started.elapsed().as_secs_f64()
        );
        reports.push(LevelReport {
            level: s,
            bank,
            distance: last.distance,
            cells_used: last.cells_used,
            cells,
            coherence: last.coherence,
            loss: last.loss,
        });
    }
    bar.finish_and_clear();
    Ok((fit.scene().clone(), reports))
}

/// Every level's style bank of each region, the levels on all cores (each depends only
/// on the styles and the frozen views), coarsest first.
fn style_banks(
    regions: &[RegionStyle<'_>],
    style_size: usize,
    p: &SynthesisParams,
    src: &Frozen,
) -> Result<Vec<Vec<StyleLevel>>> {
    let motifs: Vec<_> = regions.iter().map(|r| motif::masks(&r.styles)).collect();
    p.levels
        .par_iter()
        .map(|&s| {
            let stride = if s == 1 { p.style_stride } else { 1 };
            (regions.iter().zip(&motifs))
                .map(|(r, m)| StyleLevel::new(&r.styles, m, style_size / s, p, stride, &src.parts))
                .collect::<Result<Vec<_>>>()
        })
        .collect()
}

/// The synthesis's set-up ([`synthesize`]'s arguments; `sizes` (H, W) per camera): the
/// colour fit of the views and the frozen views (`source` or `scene`'s renders).
fn set_up<'a>(
    scene: &Scene,
    (cameras, sizes, style_size): (&'a [Camera], &[(usize, usize)], usize),
    regions: &[RegionStyle<'_>],
    fp: &FitParams,
    p: &SynthesisParams,
    selection: Option<&Selection>,
    source: Option<&[Vec<f32>]>,
) -> Result<(ColourFit<'a>, Frozen)> {
    let background = fp.background;
    let mut fit = crate::timing::phase("colour fit", || {
        ColourFit::without_targets(scene, cameras, fp)
    })?;
    fit.set_weights(selection)?;
    // The views' coverage, and their colours when no source is given, from the fit's
    // caches: bit for bit the renderer's.
    let own = source.is_none();
    let (alpha, rendered): (Vec<Vec<f32>>, Vec<Vec<f32>>) = crate::timing::phase("render", || {
        (0..cameras.len())
            .into_par_iter()
            .map(|v| {
                let rgb = if own { fit.render_view(v) } else { Vec::new() };
                (fit.alpha_view(v), rgb)
            })
            .unzip()
    });
    let rgb = match source {
        Some(src)
            if src.len() == sizes.len()
                && src
                    .iter()
                    .zip(sizes)
                    .all(|(a, &(h, w))| a.len() == h * w * 3) =>
        {
            src.to_vec()
        }
        Some(_) => {
            return Err(Error::param(
                "synthesis: the source views do not match the cameras",
            ));
        }
        None => rendered,
    };
    let cover = crate::timing::phase("regions", || regions::cover(scene, cameras, regions))?;
    let mut src = Frozen::new(
        rgb,
        alpha,
        (sizes, style_size),
        regions,
        cover,
        background,
        p,
    );
    if p.consensus > 0.0 {
        // The frozen geometry's depth (the colours do not change it).
        let depth: Vec<Vec<f32>> = crate::timing::phase("render", || {
            crate::render::render_all(scene, cameras, background)
        })?
        .into_iter()
        .map(|r| r.depth)
        .collect();
        src.consensus = Some(crate::timing::phase("consensus", || {
            consensus::Consensus::new(cameras, (&depth, &src.alpha), p.consensus, p.detail_blur)
        }));
    }
    Ok((fit, src))
}

/// The `patches` finish ([`super::ENDS`]): [`synthesize`] with the configuration's
/// `[synthesis]` and `texture.style_size`, its structure guide and source branch from the
/// source views, in the style of the inputs or in each of their regions' styles.
pub fn run(_: super::Role, scene: &Scene, inputs: &super::EndInputs<'_>) -> Result<Scene> {
    let p: SynthesisParams = inputs.section("synthesis")?;
    let texture: crate::terms::texture::TextureParams = inputs.section("texture")?;
    let s = inputs.source;
    let regions: Vec<RegionStyle<'_>> = match inputs.regions {
        Some(r) => r
            .list
            .iter()
            .map(|reg| RegionStyle {
                styles: reg
                    .styles
                    .iter()
                    .filter(|s| s.2 > 0.0)
                    .map(|(_, img, w)| (img, *w))
                    .collect(),
                weights: Some(&reg.weights),
                strength: reg.strength,
            })
            .collect(),
        None => vec![RegionStyle::one(inputs.style)],
    };
    let style_size = scale::style_size(&p, texture.style_size, &regions, s);
    let (out, _) = synthesize(
        scene,
        inputs.cameras,
        &regions,
        s.background,
        style_size,
        &p,
        inputs.selection,
        Some(&s.rgb),
        inputs.bands()?,
    )?;
    Ok(out)
}

/// The same synthesis in 2D, view by view's images with nothing shared: the prior's own
/// stylization of each view (`images` `[H, W, 3]` composited over `background` with
/// coverage `alpha`, `sizes` (H, W) per view) in `styles` (one image of weight 1, or a
/// blend), each round's target becoming the image.
/// A quick look at what a style does before a 3D run, and the 2D ceiling that the colour
/// fit of [`synthesize`] approaches on the frozen Gaussians. The views are matched
/// together (one balanced coupling), as in 3D.
pub fn synthesize_images(
    images: &[Vec<f32>],
    alpha: &[Vec<f32>],
    sizes: &[(usize, usize)],
    styles: &[(&Image, f32)],
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
    let region = [RegionStyle {
        styles: styles.to_vec(),
        ..RegionStyle::one(styles[0].0)
    }];
    regions::check(&region)?;
    let src = Frozen::new(
        images.to_vec(),
        alpha.to_vec(),
        (sizes, style_size),
        &region,
        Vec::new(),
        background,
        p,
    );
    let mut out = images.to_vec();
    let motifs = motif::masks(styles);
    for &s in &p.levels {
        let stride = if s == 1 { p.style_stride } else { 1 };
        let level = crate::timing::phase("style bank", || {
            StyleLevel::new(styles, &motifs, style_size / s, p, stride, &src.parts)
        })?;
        let levels = std::slice::from_ref(&level);
        let frozen = view::levels(&src, sizes, (s, levels), p);
        for _ in 0..p.rounds {
            out = e_step(&out, &frozen, levels, (&src, None), p).0;
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
/// branch's colours, `[H, W, 3]`), their coverage `[H, W]`, the background, the parts
/// the settings switch on ([`active_parts`]), and per region: each channel's image of
/// every view (`[H, W]`, [`parts::Channel::source`] with the region's style; timed as the
/// part's phase), its share of every view's pixels ([`regions::cover`]; none with one
/// region) and its guidance scale.
struct Frozen {
    rgb: Vec<Vec<f32>>,
    alpha: Vec<Vec<f32>>,
    background: [f32; 3],
    parts: Vec<Named<dyn Channel>>,
    rematches: Vec<Named<dyn Rematch>>,
    regions: Vec<FrozenRegion>,
    /// The detail layer of every view ([`detail`]; empty when `synthesis.detail` is 0).
    detail: Vec<Vec<f32>>,
    /// The views' consensus ([`consensus`]; with `synthesis.consensus` > 0 in 3D).
    consensus: Option<consensus::Consensus>,
}

/// A region's frozen images: `channels[c][view]`, `cover[view]` (empty with one region).
struct FrozenRegion {
    channels: Vec<Vec<Vec<f32>>>,
    cover: Vec<Vec<f32>>,
    guidance: f32,
}

impl Frozen {
    fn new(
        rgb: Vec<Vec<f32>>,
        alpha: Vec<Vec<f32>>,
        (sizes, style_size): (&[(usize, usize)], usize),
        regions: &[RegionStyle<'_>],
        cover: Vec<Vec<Vec<f32>>>,
        background: [f32; 3],
        p: &SynthesisParams,
    ) -> Frozen {
        let parts = channels(p);
        let mut cover = cover.into_iter();
        let frozen: Vec<FrozenRegion> = regions
            .iter()
            .map(|r| FrozenRegion {
                channels: parts
                    .iter()
                    .map(|&(name, c)| {
                        crate::timing::phase(name, || {
                            c.source(&rgb, &alpha, sizes, background, r.lead())
                        })
                    })
                    .collect(),
                cover: cover.next().unwrap_or_default(),
                guidance: p.guidance * r.strength,
            })
            .collect();
        let detail = if detail::weight(p) > 0.0 {
            crate::timing::phase("detail", || {
                let each: Vec<_> = (regions.iter().zip(&frozen))
                    .map(|(r, f)| (r.lead(), f.guidance, &f.cover[..]))
                    .collect();
                detail::layer(&rgb, &alpha, (sizes, style_size), background, &each, p)
            })
        } else {
            Vec::new()
        };
        Frozen {
            regions: frozen,
            detail,
            rgb,
            alpha,
            background,
            parts,
            rematches: rematches(p),
            consensus: None,
        }
    }
}

/// The E-step of one round at a level: every view's object patches matched together
/// (one balanced coupling over all views), each view's target `[H, W, 3]`.
/// `renders` `[H, W, 3]` per view, `frozen` each view's images at the level
/// ([`view::levels`]), `consensus` the views' consensus that reconciles the targets
/// (3D, the finest level; [`consensus`]). Timed as the phases
/// `queries` (the views pooled, their patches in search coordinates), `search`,
/// `balance` and the rematches' ([`StyleLevel::match_all`]), `stats` and `votes`.
fn e_step(
    renders: &[Vec<f32>],
    frozen: &[ViewLevel],
    levels: &[StyleLevel],
    (src, consensus): (&Frozen, Option<&consensus::Consensus>),
    p: &SynthesisParams,
) -> (Vec<Vec<f32>>, RoundStats) {
    let n = src.alpha.len();
    let lifted;
    let renders = if src.detail.is_empty() {
        renders
    } else {
        lifted = detail::with(renders, &src.detail, -detail::weight(p));
        &lifted[..]
    };
    let ph = crate::timing::span("queries");
    let views: Vec<ViewImage> = (0..n)
        .into_par_iter()
        .map(|v| ViewImage::new(&renders[v], src, v, &frozen[v]))
        .collect();
    let queries: Vec<Query> = views.par_iter().map(|v| v.queries(p)).collect();
    // Each region's queries in its level's search coordinates (one region: all of them).
    let owned: Vec<_> = levels
        .iter()
        .enumerate()
        .map(|(r, level)| {
            let own = regions::Owned::new(&queries, r, levels.len() == 1);
            let colour = own.stack(&queries, |q| q.colour.view());
            let channels: Vec<_> = (0..src.parts.len())
                .map(|c| own.stack(&queries, |q| q.channels[r][c].view()))
                .collect();
            let pixels: Vec<&[[usize; 3]]> = own.pixels.iter().map(|p| &p[..]).collect();
            let nbrs = coherence::neighbours(&pixels, p.stride.max(1));
            let qc = level.project(&colour, &channels);
            (own, nbrs, qc)
        })
        .collect();
    drop(ph);
    let total: usize = queries.iter().map(|q| q.pixels.len()).sum();
    let mut m = vec![(0u32, 0.0f32); total];
    let (mut used, mut coherent) = (0, 0.0f64);
    for (level, (own, nbrs, qc)) in levels.iter().zip(&owned) {
        let mr = level.match_all(qc, nbrs, p, &src.rematches);
        let _ph = crate::timing::span("stats");
        let mut hit = vec![false; level.share.len()];
        for &(j, _) in &mr {
            hit[level.cell_of[j as usize] as usize] = true;
        }
        used += hit.iter().filter(|&&u| u).count();
        let chosen: Vec<u32> = mr.iter().map(|x| x.0).collect();
        let c = coherence::coherence(&chosen, nbrs, &level.pos) as f64;
        coherent += c * mr.len() as f64 / total.max(1) as f64;
        for (&i, x) in own.index.iter().zip(mr) {
            m[i] = x;
        }
    }
    let stats = RoundStats {
        distance: (m.iter().map(|x| x.1 as f64).sum::<f64>() / m.len().max(1) as f64) as f32,
        cells_used: used,
        coherence: coherent as f32,
        loss: 0.0,
    };
    let _ph = crate::timing::span("votes");
    let offsets: Vec<usize> = queries
        .iter()
        .scan(0, |at, q| {
            *at += q.pixels.len();
            Some(*at - q.pixels.len())
        })
        .collect();
    let mut targets: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|v| {
            let (q, o) = (&queries[v], offsets[v]);
            let mv = &m[o..o + q.pixels.len()];
            views[v].target(levels, q, mv, p, &renders[v], &src.alpha[v])
        })
        .collect();
    drop(_ph);
    if let Some(c) = consensus {
        targets = crate::timing::phase("consensus", || c.apply(targets));
    }
    if !src.detail.is_empty() {
        detail::lay(&mut targets, &src.detail, detail::weight(p));
    }
    (targets, stats)
}

/// The coupling's temperature relative to the mean nearest distance.
pub(super) const BALANCE_EPS: f32 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prior::patch::latent::upsample;
    use ndarray::Array2;

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
        let one = [(&style, 1.0)];
        let level = StyleLevel::new(&one, &motif::masks(&one), 32, &p, 1, &[]).unwrap();
        let red = Array2::from_shape_fn((1, 27), |(_, i)| [0.85, 0.15, 0.1][i % 3]);
        let blue = Array2::from_shape_fn((1, 27), |(_, i)| [0.1, 0.15, 0.85][i % 3]);
        for (q, want) in [(red, 0.9f32), (blue, 0.1)] {
            let (j, _) = level.assign(&level.project(&q, &[]), 0.0, BALANCE_EPS)[0];
            assert_eq!(level.bank.centres[[j as usize, 0]], want);
        }
    }

    /// The synthesis times its parts for `pipeline report` ([`crate::timing`]): under
    /// `patch synthesis`, its set-up, each level's bank, each round's steps, and the
    /// parts' own work (the guide's images and coordinates, the negative branch's
    /// penalty and second coupling) apart.
    #[test]
    fn the_synthesis_times_its_parts() {
        let scene = crate::sample::sample_scene(1);
        let cams = crate::camera::load_cameras("orbit:2", &scene.bounds(), 32, 32).unwrap();
        let p = SynthesisParams {
            levels: vec![2, 1],
            rounds: 2,
            steps: 1,
            control: 1.0,
            negative: 1.0,
            ..SynthesisParams::default()
        };
        // Under a phase of its own, so that the synthesis of tests running beside it on
        // other threads (the phases are one table per process) does not count here.
        const OWN: &str = "the_synthesis_times_its_parts";
        let calls = |name: &str| {
            let full = format!("{OWN}/patch synthesis/{name}");
            let p = crate::timing::phases();
            p.iter().find(|e| e.name == full).map_or(0, |e| e.calls)
        };
        let want = [
            ("setup", 1),
            ("setup/colour fit", 1),
            ("setup/render", 1),
            ("setup/guide", 1),
            ("style bank", 1),
            ("level views", 2),
            ("render", 4),
            ("queries", 4),
            ("queries/guide", 4),
            ("search", 4),
            ("balance", 4),
            ("negative", 4),
            ("negative/balance", 4),
            ("stats", 4),
            ("votes", 4),
            ("colour fit", 4),
        ];
        let before: Vec<u64> = want.iter().map(|(n, _)| calls(n)).collect();
        let style = motif::tests::disc();
        crate::timing::phase(OWN, || {
            synthesize(
                &scene,
                &cams,
                &[RegionStyle::one(&style)],
                [0.0; 3],
                32,
                &p,
                None,
                None,
                Bands::Keep,
            )
        })
        .unwrap();
        for ((name, n), b) in want.into_iter().zip(before) {
            assert_eq!(calls(name) - b, n, "phase `patch synthesis/{name}`");
        }
    }

    /// A part added as one file and one line of [`PARTS`] (the test-only `test-red`,
    /// src/ends/patches/test_red.rs) joins the search when it is on, and `--help` lists
    /// it: on a style of red and blue halves, the synthesis with the part on is not the
    /// synthesis without it.
    #[test]
    fn a_new_part_is_one_file_and_one_line() {
        assert!(parts_help().contains("test-red"));
        let style = motif::tests::image(32, 32, |_, x| {
            if x < 16 {
                [0.9, 0.1, 0.1]
            } else {
                [0.1, 0.1, 0.9]
            }
        });
        let (h, w) = (16, 16);
        let src: Vec<f32> = (0..h * w)
            .flat_map(|i| {
                if i % w < 8 {
                    [0.8, 0.4, 0.4]
                } else {
                    [0.2, 0.4, 0.4]
                }
            })
            .collect();
        let alpha = vec![vec![1.0f32; h * w]];
        let p = SynthesisParams {
            levels: vec![1],
            patch: 3,
            pca_dims: 4,
            rounds: 1,
            ..SynthesisParams::default()
        };
        let run = |images: &[Vec<f32>]| {
            synthesize_images(
                images,
                &alpha,
                &[(h, w)],
                &[(&style, 1.0)],
                [0.0; 3],
                32,
                &p,
            )
            .unwrap()
        };
        assert!(channels(&p).is_empty());
        let images = std::slice::from_ref(&src);
        let on = test_red::switched_on(|| {
            assert_eq!(channels(&p).len(), 1);
            run(images)
        });
        assert!(!test_red::on());
        assert_ne!(on, run(images), "the part changed nothing");
    }
}

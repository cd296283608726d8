//! The evaluation of a stylized view set (the `evaluate` stage's computation; the stage
//! reads the artifacts and writes `metrics.json` and the report of [`super::report`]).
//!
//! Metrics (FantasyStyle's experiments; see [`crate::metrics`] for each definition):
//! LPIPS_content (original vs stylized, per view); FID_style (stylized renders vs crops
//! of the style image) and FID_content (stylized vs original renders), each with KID;
//! ArtFID = (1 + LPIPS_content)(1 + FID_style) with the standard FID Inception;
//! short/long-range consistency (LPIPS and RMSE after depth warping), also on the
//! original renders as a floor; a VGG16 Gram-matrix distance to the style image; and the
//! texture measures of [`super::texture`] (among them KID over squares of the object's
//! surface against squares of the style, which the whole-view KID cannot see); the
//! content leakage of [`super::leakage`]; and the structure kept of [`super::structure`]
//! (the source's edges and shading detail still where they were), with the interior
//! structure, edge recall, motif contrast and style texture of [`super::interior`] (the
//! same band pass inside the object only, away from its silhouette).
//!
//! The Inception measures (FID, KID, ArtFID and the object KID) are computed only with
//! [`EvalParams`]`::inception` (`evaluate --inception`, on by default; the sample DAGs
//! turn it off): without it they are `None` with [`fid::OFF_NOTE`], Inception is not
//! loaded, and every other measure is the same bit for bit (docs/evaluation.md "The
//! measures").
//!
//! The half of it that depends only on the original views and the style image is
//! [`super::reference::Reference`], computed here or read from an `eval-reference`
//! artifact (`evaluate --reference`): the same metrics either way.
//!
//! Style crops for FID_style: `K = max(N, 2)` crops at the views' aspect ratio, each
//! spanning half the style image's height (or its full width if that is smaller), at
//! positions drawn uniformly with the seeded [`crate::rng::Rng`], each resized to the
//! view resolution so both sets go through the same Inception resize.

use super::consistency::{self, PairScore};
use super::fid::{self, FeatureSet};
use super::gram;
use super::interior::{self, Interior};
use super::leakage::{self, Leakage};
use super::lpips;
use super::nets::{Inception, LpipsModel, LpipsNet, Nets};
use super::reference::{EvalParams, GRAM_MAX_SIDE, Reference, style_crops};
use super::structure;
use super::texture::{self, TextureMetrics};
use super::views::ViewSet;
use crate::imageio::Image;
use crate::maths::warp::Warped;
use crate::{Error, Result};
use serde::Serialize;
use std::path::Path;

/// Below this many images per set, FID's covariance is rank-deficient (feature dim 2048).
pub const FID_FULL_RANK: usize = 2048;

/// An evaluation: the metrics and what the report shows beside them.
#[derive(Debug, Clone)]
pub struct Evaluation {
    pub metrics: Metrics,
    /// The style crops FID_style used.
    pub crops: Vec<Image>,
    /// The warped views of the short- and long-range pairs (for the report's examples).
    pub short_warps: Vec<Warped>,
    pub long_warps: Vec<Warped>,
}

/// One distribution distance (FID or KID) with its sample counts.
#[derive(Debug, Clone, Serialize)]
pub struct SetDistance {
    pub value: Option<f64>,
    pub n_a: usize,
    pub n_b: usize,
    /// False when the sample counts make the value biased or impossible.
    pub reliable: bool,
    pub note: String,
}

impl SetDistance {
    /// Whether this is a measure not computed because the Inception measures are off.
    pub fn is_off(&self) -> bool {
        self.value.is_none() && self.note == fid::OFF_NOTE
    }

    /// A measure not computed because the Inception measures are off.
    fn off() -> SetDistance {
        SetDistance {
            value: None,
            n_a: 0,
            n_b: 0,
            reliable: false,
            note: fid::OFF_NOTE.into(),
        }
    }
}

/// Consistency at one pair offset.
#[derive(Debug, Clone, Serialize)]
pub struct RangeConsistency {
    pub offset: usize,
    pub lpips_mean: Option<f64>,
    pub rmse_mean: Option<f64>,
    pub original_lpips_mean: Option<f64>,
    pub original_rmse_mean: Option<f64>,
    /// The mean excess over the warp's own loss ([`consistency`]'s module doc): what the
    /// other view adds (seams, view-dependent blends), stylized and original.
    pub excess_lpips_mean: Option<f64>,
    pub excess_rmse_mean: Option<f64>,
    pub original_excess_lpips_mean: Option<f64>,
    pub original_excess_rmse_mean: Option<f64>,
    pub stylized: Vec<PairScore>,
    pub original: Vec<PairScore>,
}

/// `metrics.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Metrics {
    pub format: &'static str,
    pub views: usize,
    pub width: usize,
    pub height: usize,
    pub lpips_net: LpipsNet,
    pub lpips_content: Option<f64>,
    pub lpips_content_per_view: Vec<f64>,
    /// Structure kept ([`super::structure`], issue 47): the mean over views of the Pearson
    /// correlation, over the object's pixels, of the source's and the stylized view's
    /// band-passed luminance (difference of Gaussians, sigma 1 px minus 4 px); 1 = every
    /// edge and shading detail still where it was. `None` when no view has a value.
    pub structure_kept: Option<f64>,
    /// Structure kept per view; `None` for a view with fewer than
    /// [`structure::MIN_PIXELS`] object pixels or a flat band-pass image.
    pub structure_kept_per_view: Vec<Option<f64>>,
    /// What structure_kept means ([`structure::NOTE`]).
    pub structure_kept_note: &'static str,
    /// Interior structure, edge recall, motif contrast and style texture
    /// ([`super::interior`], issue 53):
    /// their means, per-view values with why any is missing, and notes, as top-level keys
    /// beside structure kept.
    #[serde(flatten)]
    pub interior: Interior,
    pub fid_style: SetDistance,
    pub kid_style: SetDistance,
    pub fid_content: SetDistance,
    pub kid_content: SetDistance,
    pub artfid: Option<f64>,
    pub artfid_note: &'static str,
    pub short_range: RangeConsistency,
    pub long_range: RangeConsistency,
    pub gram_style: Option<f64>,
    pub gram_style_original: Option<f64>,
    pub gram_style_per_view: Vec<f64>,
    pub style_crops: String,
    pub warnings: Vec<String>,
    /// Measures that see texture ([`super::texture`]).
    pub texture: TextureMetrics,
    /// Content leakage ([`super::leakage`]).
    pub leakage: Leakage,
}

/// What ArtFID means here (written beside the value).
pub const ARTFID_NOTE: &str = "ArtFID = (1 + LPIPS_content)(1 + FID_style) computed with the standard FID Inception-v3 \
     (TF 2015, pool3); the art-trained Inception of the ArtFID paper is not obtainable, so values are not \
     comparable with published ArtFID numbers";

fn set_distances(
    a: &[Vec<f32>],
    b: &[Vec<f32>],
    what: &str,
    warnings: &mut Vec<String>,
) -> (SetDistance, SetDistance) {
    let (na, nb) = (a.len(), b.len());
    if na < fid::MIN_IMAGES || nb < fid::MIN_IMAGES {
        let note = format!(
            "not computed: FID/KID need at least {} images per set, have {na} and {nb}",
            fid::MIN_IMAGES
        );
        warnings.push(format!("{what}: {note}"));
        let d = SetDistance {
            value: None,
            n_a: na,
            n_b: nb,
            reliable: false,
            note,
        };
        return (d.clone(), d);
    }
    let (fa, fb) = (FeatureSet::from_rows(a), FeatureSet::from_rows(b));
    let f = fid::fid(&fa, &fb).ok();
    let k = fid::kid(&fa, &fb).ok();
    let full = na.min(nb) >= FID_FULL_RANK;
    let fid_note = if full {
        format!("{na} vs {nb} images")
    } else {
        format!(
            "{na} vs {nb} images, fewer than the 2048 feature dimensions: the covariances are rank-deficient \
             and FID is biased upward; compare only at equal image counts, and prefer KID"
        )
    };
    if !full {
        warnings.push(format!("{what}: FID on {na} vs {nb} images is biased (unreliable in absolute terms); KID is reported beside it"));
    }
    (
        SetDistance {
            value: f,
            n_a: na,
            n_b: nb,
            reliable: full,
            note: fid_note,
        },
        SetDistance {
            value: k,
            n_a: na,
            n_b: nb,
            reliable: na.min(nb) >= 10,
            note: "unbiased MMD² estimate (can be slightly negative when the sets match), cubic polynomial \
                   kernel, all images in one set; high variance below 10 images"
                .into(),
        },
    )
}

/// The stylized views' pairs at one offset, scored against the original's geometry.
fn score_range(
    model: &mut LpipsModel,
    orig: &ViewSet,
    styl: &ViewSet,
    offset: usize,
    warnings: &mut Vec<String>,
) -> Result<(Vec<PairScore>, Vec<Warped>)> {
    let pairs = consistency::pairs(orig.n, offset);
    if pairs.is_empty() {
        warnings.push(format!(
            "consistency at offset {offset}: needs more than {offset} views, have {}",
            orig.n
        ));
    }
    let (s, warps) = consistency::score_pairs(model, orig, &styl.images, &pairs)?;
    let skipped = s.iter().filter(|p| p.lpips.is_none()).count();
    if skipped > 0 {
        warnings.push(format!(
            "consistency at offset {offset}: {skipped} of {} pairs overlap less than {:.0}% and were skipped",
            s.len(),
            consistency::MIN_OVERLAP * 100.0
        ));
    }
    Ok((s, warps))
}

impl RangeConsistency {
    /// The stylized pairs' scores `s` beside the original views' own `original`.
    fn new(offset: usize, s: Vec<PairScore>, original: &[PairScore]) -> RangeConsistency {
        let o = original;
        let mean = |v: &[PairScore], f: fn(&PairScore) -> Option<f64>| {
            consistency::mean_of(v.iter().map(f))
        };
        RangeConsistency {
            offset,
            lpips_mean: mean(&s, |p| p.lpips),
            rmse_mean: mean(&s, |p| p.rmse),
            original_lpips_mean: mean(o, |p| p.lpips),
            original_rmse_mean: mean(o, |p| p.rmse),
            excess_lpips_mean: mean(&s, |p| p.excess_lpips),
            excess_rmse_mean: mean(&s, |p| p.excess_rmse),
            original_excess_lpips_mean: mean(o, |p| p.excess_lpips),
            original_excess_rmse_mean: mean(o, |p| p.excess_rmse),
            stylized: s,
            original: o.to_vec(),
        }
    }
}

fn progress(len: u64, msg: &'static str) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(len);
    if let Ok(st) = indicatif::ProgressStyle::with_template("{msg:>14} [{bar:30}] {pos}/{len}") {
        pb.set_style(st);
    }
    pb.set_message(msg);
    pb
}

/// The Gram distance of every stylized view to the style (VGG16 taps) and the per-layer
/// object Gram distances, with the original's from the reference `r`.
fn gram_distances(
    nets: &mut Nets,
    orig: &ViewSet,
    styl: &ViewSet,
    r: &Reference,
) -> Result<(Vec<f64>, texture::ObjectGram)> {
    let (w, h) = (orig.width, orig.height);
    let vgg = nets.vgg();
    let mut gram_per_view = Vec::with_capacity(orig.n);
    let mut object_gram = texture::ObjectGram::new(&r.style_grams);
    for i in 0..orig.n {
        let f = crate::timing::phase("vgg", || vgg.features(&[&styl.images[i]]))?;
        let d = object_gram.view_distances(&f[0], orig.geometry(i).1, w, h);
        object_gram.push(&d, &r.scores.object_gram_original[i]);
        let g = crate::timing::phase("gram matrices", || gram::grams(&f[0]));
        gram_per_view.push(gram::gram_distance(&g, &r.style_grams));
    }
    Ok((gram_per_view, object_gram))
}

/// Inception pool3 of the stylized object's squares, at the reference's positions (the
/// object's surface against the style's: [`texture::kid_interval`]).
fn object_squares_pool3(
    inc: &mut Inception,
    orig: &ViewSet,
    styl: &ViewSet,
    p: &EvalParams,
    r: &Reference,
) -> Result<Vec<Vec<f32>>> {
    let _squares = crate::timing::span("object squares");
    let (w, h) = (orig.width, orig.height);
    let at = texture::object_patch_positions(&orig.alpha, w, h, p.object_squares, p.seed);
    if at.len() != r.object_squares_pool3.len() {
        return Err(Error::param(
            "the reference's object squares differ from this evaluation's: it was made from another original views set",
        ));
    }
    inc.pool3(
        &texture::object_patches(styl, &at)
            .iter()
            .collect::<Vec<_>>(),
    )
}

/// Inception pool3 features of a set of images, one 2048-vector each.
type Pool3 = [Vec<f32>];

/// The measures that see texture, from the object Gram distances and the pool3 features
/// `(fs, fps)` of the stylized views and object squares (`None`: Inception is off).
fn texture_metrics(
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    r: &Reference,
    object_gram: texture::ObjectGram,
    pool3: Option<(&Pool3, &Pool3)>,
) -> TextureMetrics {
    let (fc, fpo, fpc) = (
        &r.crops_pool3,
        &r.object_squares_pool3,
        &r.style_squares_pool3,
    );
    let kid = |a: Option<&Pool3>, b, sets| {
        a.map_or_else(texture::KidInterval::off, |a| {
            texture::kid_interval(a, b, sets)
        })
    };
    let (fs, fps) = (pool3.map(|p| p.0), pool3.map(|p| p.1));
    TextureMetrics {
        gram_object: object_gram.finish(),
        kid_style: kid(fs, fc, ["stylized views", "style crops"]),
        kid_object: kid(fps, fpc, ["object squares", "style squares"]),
        kid_object_original: kid(
            pool3.map(|_| fpo.as_slice()),
            fpc,
            ["original object squares", "style squares"],
        ),
        spectrum: texture::spectrum_metrics(orig, styl, &style.fit_within(GRAM_MAX_SIDE)),
        object: texture::object_colour(orig, styl, style),
        notes: texture::NOTES.to_vec(),
    }
}

/// LPIPS content per view and the short- and long-range consistency scores with their
/// warps.
struct LpipsScores {
    per_view: Vec<f64>,
    short: (Vec<PairScore>, Vec<Warped>),
    long: (Vec<PairScore>, Vec<Warped>),
}

/// [`LpipsScores`] (geometry from the original views; cameras are checked equal).
fn lpips_scores(
    lp: &mut LpipsModel,
    orig: &ViewSet,
    styl: &ViewSet,
    p: &EvalParams,
    warnings: &mut Vec<String>,
    pb: &indicatif::ProgressBar,
) -> Result<LpipsScores> {
    let si: Vec<&Image> = styl.images.iter().collect();
    let ph = crate::timing::span("lpips content");
    let per_view = lpips::pairwise(lp, &orig.images.iter().collect::<Vec<_>>(), &si)?;
    drop(ph);
    pb.inc(1);
    let ph = crate::timing::span("consistency");
    let short = score_range(lp, orig, styl, p.short_range, warnings)?;
    let long = score_range(lp, orig, styl, p.long_range, warnings)?;
    drop(ph);
    pb.inc(1);
    Ok(LpipsScores {
        per_view,
        short,
        long,
    })
}

/// The measures against the style and content sets (Inception pool3): FID and KID, and
/// the texture measures.
struct StyleMeasures {
    crops: Vec<Image>,
    fid_style: SetDistance,
    kid_style: SetDistance,
    fid_content: SetDistance,
    kid_content: SetDistance,
    texture: TextureMetrics,
}

/// [`StyleMeasures`] of the stylized views (`(orig, styl, style)`), with the reference.
fn style_measures(
    nets: &mut Nets,
    (orig, styl, style): (&ViewSet, &ViewSet, &Image),
    p: &EvalParams,
    r: &Reference,
    object_gram: texture::ObjectGram,
    warnings: &mut Vec<String>,
) -> Result<StyleMeasures> {
    let k = orig.n.max(fid::MIN_IMAGES);
    let crops = style_crops(style, k, orig.width, orig.height, p.seed);
    let Some(inc) = nets.inception.as_mut().filter(|_| p.inception) else {
        let off = SetDistance::off();
        return Ok(StyleMeasures {
            crops,
            fid_style: off.clone(),
            kid_style: off.clone(),
            fid_content: off.clone(),
            kid_content: off,
            texture: texture_metrics(orig, styl, style, r, object_gram, None),
        });
    };
    let ph = crate::timing::span("inception");
    let fs = inc.pool3(&styl.images.iter().collect::<Vec<_>>())?;
    let fps = object_squares_pool3(inc, orig, styl, p, r)?;
    drop(ph);
    let _ph = crate::timing::span("fid kid");
    let (fc, fo) = (&r.crops_pool3, &r.views_pool3);
    let (fid_style, kid_style) = set_distances(&fs, fc, "FID_style", warnings);
    let (fid_content, kid_content) = set_distances(&fs, fo, "FID_content", warnings);
    let texture = texture_metrics(orig, styl, style, r, object_gram, Some((&fs, &fps)));
    Ok(StyleMeasures {
        crops,
        fid_style,
        kid_style,
        fid_content,
        kid_content,
        texture,
    })
}

/// Evaluate `styl` against `orig` (the same views, checked by
/// [`ViewSet::check_same_views`]) and the style image, with the metric networks of the
/// models directory `models` (see [`crate::models`]). `reference`: the half that depends
/// only on `orig` and `style` ([`Reference`]; the caller checks it was made from them,
/// with [`Reference::check`]); `None` computes it here, through the same function.
pub fn evaluate(
    models: &Path,
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    p: &EvalParams,
    reference: Option<&Reference>,
) -> Result<Evaluation> {
    p.validate()?;
    orig.check_same_views(styl)?;
    let mut warnings = Vec::new();
    let (n, w, h) = (orig.n, orig.width, orig.height);
    tracing::info!(
        "evaluate: {n} views at {w}x{h}, LPIPS-{}",
        p.lpips_net.name()
    );
    let pb = progress(5, "evaluate");
    // LPIPS first; the other networks load on a second thread while LPIPS content and
    // consistency run (creating a session is mostly one thread's work; the wait for them
    // counts as load).
    let mut lp = crate::timing::load(|| LpipsModel::load(models, p.lpips_net, p.threads))?;
    let loading = {
        let (models, net, threads) = (models.to_path_buf(), p.lpips_net, p.threads);
        let inception = p.inception;
        std::thread::spawn(move || Nets::load_rest(&models, net, inception, threads))
    };

    let scores = lpips_scores(&mut lp, orig, styl, p, &mut warnings, &pb)?;
    let (vgg, inception) = crate::timing::load(|| loading.join())
        .map_err(|_| Error::Other("loading the metric networks panicked".into()))??;
    let mut nets = Nets {
        lpips: lp,
        vgg,
        inception,
    };
    let owned;
    let r = match reference {
        Some(r) => r,
        None => {
            owned = Reference::compute(&mut nets, orig, style, p)?;
            &owned
        }
    };
    measure(&mut nets, r, (orig, styl, style), p, scores, warnings, &pb)
}

/// Structure kept per view and its mean ([`structure::structure_kept`]), with a warning
/// naming the views that have no value.
fn structure_scores(
    orig: &ViewSet,
    styl: &ViewSet,
    warnings: &mut Vec<String>,
) -> (Option<f64>, Vec<Option<f64>>) {
    let (mean, per_view) =
        crate::timing::phase("structure", || structure::structure_kept(orig, styl));
    let none: Vec<String> = (0..per_view.len())
        .filter(|&i| per_view[i].is_none())
        .map(|i| i.to_string())
        .collect();
    if !none.is_empty() {
        warnings.push(format!(
            "structure kept: no value for view(s) {} (fewer than {} object pixels, or a flat band-pass image)",
            none.join(", "),
            structure::MIN_PIXELS
        ));
    }
    (mean, per_view)
}

/// The rest of [`evaluate`] with the networks and the reference: the Gram distances,
/// FID and KID, the texture measures; the metrics.
fn measure(
    nets: &mut Nets,
    r: &Reference,
    (orig, styl, style): (&ViewSet, &ViewSet, &Image),
    p: &EvalParams,
    scores: LpipsScores,
    mut warnings: Vec<String>,
    pb: &indicatif::ProgressBar,
) -> Result<Evaluation> {
    let (n, w, h) = (orig.n, orig.width, orig.height);
    let LpipsScores {
        per_view: lpips_per_view,
        short: (short, short_warps),
        long: (long, long_warps),
    } = scores;
    let lpips_content = Some(lpips_per_view.iter().sum::<f64>() / n as f64);
    let rs = &r.scores;
    let short = RangeConsistency::new(p.short_range, short, &rs.short_original);
    let long = RangeConsistency::new(p.long_range, long, &rs.long_original);

    // Gram distance to the style image (VGG16).
    let ph = crate::timing::span("gram");
    let (gram_per_view, object_gram) = gram_distances(nets, orig, styl, r)?;
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    drop(ph);
    pb.inc(1);

    let sm = style_measures(nets, (orig, styl, style), p, r, object_gram, &mut warnings)?;
    pb.inc(2);
    let leakage = crate::timing::phase("leakage", || leakage::leakage(orig, styl, style));
    let (structure_kept, structure_per_view) = structure_scores(orig, styl, &mut warnings);
    let interior = crate::timing::phase("interior", || {
        interior::interior(orig, styl, style, p.style_size)
    });
    warnings.extend(interior.warnings());
    if style.width < 64 || style.height < 64 {
        warnings.push(format!(
            "the style image is only {}x{}: its crops are upsampled for FID_style and the Gram distance sees few positions",
            style.width, style.height
        ));
    }
    let metrics = Metrics {
        format: "fantasystyle-evaluation-1",
        views: n,
        width: w,
        height: h,
        lpips_net: p.lpips_net,
        lpips_content,
        lpips_content_per_view: lpips_per_view,
        structure_kept,
        structure_kept_per_view: structure_per_view,
        structure_kept_note: structure::NOTE,
        interior,
        artfid: match (lpips_content, sm.fid_style.value) {
            (Some(l), Some(f)) => Some(fid::artfid(l, f)),
            _ => None,
        },
        fid_style: sm.fid_style,
        kid_style: sm.kid_style,
        fid_content: sm.fid_content,
        kid_content: sm.kid_content,
        artfid_note: ARTFID_NOTE,
        short_range: short,
        long_range: long,
        gram_style: mean(&gram_per_view),
        gram_style_original: mean(&rs.gram_original_per_view),
        gram_style_per_view: gram_per_view,
        style_crops: format!(
            "{} crops of the style image at the views' aspect ratio spanning half its height, seeded positions (seed {}), resized to {w}x{h}",
            sm.crops.len(),
            p.seed
        ),
        warnings,
        texture: sm.texture,
        leakage,
    };
    pb.finish_and_clear();
    Ok(Evaluation {
        metrics,
        crops: sm.crops,
        short_warps,
        long_warps,
    })
}

//! The half of an evaluation that depends only on the original views and the style image
//! (the `eval-reference` artifact, `evaluate --reference-only`).
//!
//! Of the sample's 152 Inception passes, 120 are of the original views, the style crops,
//! the original's object squares and the style's squares; the VGG16 pass of the style
//! image alone costs four views'. None of it changes while a user re-runs `distill` with
//! other settings, nor between the methods of the quality benchmark on one scene and
//! style. [`Reference::compute`] does that half once; [`super::evaluate::evaluate`] takes
//! it (or computes it itself, through the same function, so that both ways give the same
//! `metrics.json` bit for bit) and adds the stylized views' half.
//!
//! What it holds, per measure of [`super::evaluate`]: the Inception pool3 features of the
//! original views (FID/KID_content), of the style crops (FID/KID_style), of the original's
//! object squares and of the style's squares (`kid_object` of [`super::texture::TextureMetrics`]); the style
//! image's VGG16 Gram matrices per tap and, per original view, its Gram distance to them
//! (whole view, and per layer over the object); the original views' own short- and
//! long-range consistency (the floor the report shows). [`Settings`] records what it was
//! made with; a reference made with other settings is refused.
//!
//! It comes whole (`evaluate --reference-only`, the `eval-reference` artifact) or in two
//! parts ([`parts`]: `--reference-only source`, what depends only on the original views,
//! and `--reference-only style`, what depends only on the style image), which
//! [`Reference::merge`] joins; the whole one is computed as its two parts merged, so the
//! two ways give the same values bit for bit.
//!
//! Timing ([`crate::timing`]): [`Reference::compute`] is the phase `reference`, in parts
//! `consistency` (its `warp` and `lpips`), `vgg`, `gram matrices`, `object gram` and
//! `inception` (per image set: `views`, `style crops`, `object squares`, `style
//! squares`, each with the making of its images).

mod parts;
pub use parts::{
    SourceReference, StyleReference, StyleSettings, from_upper_triangle, upper_triangle,
};

use super::consistency::{self, PairScore};
use super::gram;
use super::nets::{LpipsNet, Nets};
use super::texture;
use super::views::ViewSet;
use crate::imageio::{Filter, Image};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// Largest side of the style image fed to VGG for the Gram distance.
pub const GRAM_MAX_SIDE: usize = 512;

/// Settings of an evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EvalParams {
    /// LPIPS backbone for LPIPS_content and consistency.
    pub lpips_net: LpipsNet,
    /// Short- and long-range pair offsets (>= 1).
    pub short_range: usize,
    pub long_range: usize,
    /// Seed of the style crops and of the object KID's squares.
    pub seed: u64,
    /// Object squares per view for the object KID (0: not computed).
    pub object_squares: usize,
    /// Whether the Inception measures are computed (FID and KID of the style and the
    /// content, ArtFID, the object KID); off, Inception is not even loaded.
    pub inception: bool,
    /// onnxruntime intra-op threads (0 = all cores).
    pub threads: usize,
    /// The style's shorter side in render pixels that the end laid it at (its
    /// `texture.style_size`): motif contrast and style texture take the style at it.
    pub style_size: usize,
}

/// Which part of the evaluation `evaluate --reference-only` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ReferencePart {
    /// The whole reference (`eval-reference`).
    All,
    /// What depends on the original views alone (`eval-source`).
    Source,
    /// What depends on the style image alone (`eval-style`).
    Style,
}

impl EvalParams {
    /// The options an evaluation (and its reference) records.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "lpips_net": self.lpips_net.name(), "short_range": self.short_range, "long_range": self.long_range, "seed": self.seed,
            "object_squares": self.object_squares, "inception": self.inception,
        })
    }

    /// Error unless both pair offsets are at least 1.
    pub fn validate(&self) -> Result<()> {
        if self.short_range == 0 || self.long_range == 0 {
            return Err(Error::param(
                "--short-range and --long-range must be at least 1",
            ));
        }
        if self.style_size < 8 {
            return Err(Error::param(format!(
                "--style-size {}: the style's shorter side must be at least 8 px",
                self.style_size
            )));
        }
        Ok(())
    }
}

/// Deterministic crops of the style image for FID_style ([`super::evaluate`]'s module
/// docs).
pub fn style_crops(style: &Image, k: usize, width: usize, height: usize, seed: u64) -> Vec<Image> {
    let aspect = width as f64 / height as f64;
    let mut ch = (style.height as f64 * 0.5).max(1.0);
    let mut cw = ch * aspect;
    if cw > style.width as f64 {
        cw = style.width as f64;
        ch = cw / aspect;
    }
    let (cw, ch) = (
        (cw.round() as usize).clamp(1, style.width),
        (ch.round() as usize).clamp(1, style.height),
    );
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-style-crops");
    (0..k)
        .map(|_| {
            let x0 = (rng.uniform() * (style.width - cw + 1) as f64) as usize;
            let y0 = (rng.uniform() * (style.height - ch + 1) as f64) as usize;
            style
                .crop(x0.min(style.width - cw), y0.min(style.height - ch), cw, ch)
                .resized(width, height, Filter::Bilinear)
        })
        .collect()
}

/// The settings a reference was computed with: an evaluation must use the same.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Settings {
    pub views: usize,
    pub width: usize,
    pub height: usize,
    pub short_range: usize,
    pub long_range: usize,
    pub seed: u64,
    pub object_squares: usize,
    /// The Inception measures computed (a reference made before this field: yes).
    #[serde(default = "yes")]
    pub inception: bool,
}

/// `true` (serde's default for fields added later).
pub(crate) fn yes() -> bool {
    true
}

impl Settings {
    /// The settings of evaluating `orig` with `p`.
    pub fn of(orig: &ViewSet, p: &EvalParams) -> Settings {
        Settings {
            views: orig.n,
            width: orig.width,
            height: orig.height,
            short_range: p.short_range,
            long_range: p.long_range,
            seed: p.seed,
            object_squares: p.object_squares,
            inception: p.inception,
        }
    }

    /// The fields where `self` differs from `other`, as `name a vs b`.
    pub fn differences(&self, other: &Settings) -> Vec<String> {
        let (a, b) = (
            serde_json::to_value(self).unwrap_or_default(),
            serde_json::to_value(other).unwrap_or_default(),
        );
        let Some(a) = a.as_object() else {
            return Vec::new();
        };
        a.iter()
            .filter(|(k, v)| b.get(k.as_str()) != Some(*v))
            .map(|(k, v)| format!("{k} {v} vs {}", b.get(k.as_str()).unwrap_or_default()))
            .collect()
    }
}

/// The scalar part (`reference.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scores {
    pub settings: Settings,
    /// Per original view, its VGG16 Gram distance to the style (all taps).
    pub gram_original_per_view: Vec<f64>,
    /// Per original view, per layer of [`texture::GRAM_LAYERS`], the object's Gram
    /// distance to the style's (`None`: too little coverage).
    pub object_gram_original: Vec<Vec<Option<f64>>>,
    /// The original views' own consistency at the short and the long offset.
    pub short_original: Vec<PairScore>,
    pub long_original: Vec<PairScore>,
}

/// The reference half of an evaluation (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Reference {
    pub scores: Scores,
    /// Inception pool3 features (2048 each) of the original views, the style crops, the
    /// original's object squares and the style's squares.
    pub views_pool3: Vec<Vec<f32>>,
    pub crops_pool3: Vec<Vec<f32>>,
    pub object_squares_pool3: Vec<Vec<f32>>,
    pub style_squares_pool3: Vec<Vec<f32>>,
    /// The style image's (at most [`GRAM_MAX_SIDE`] px) VGG16 Gram matrices, per tap.
    pub style_grams: Vec<Vec<f64>>,
}

impl Reference {
    /// Compute the reference of evaluating against `orig` and `style` with `p`: its
    /// source and style parts, merged ([`Self::merge`]).
    pub fn compute(
        nets: &mut Nets,
        orig: &ViewSet,
        style: &Image,
        p: &EvalParams,
    ) -> Result<Reference> {
        let source = SourceReference::compute(nets, orig, p)?;
        let settings = StyleSettings::of(&source.settings);
        let squares = !source.object_squares_pool3.is_empty();
        let style = StyleReference::compute_with(nets, style, settings, squares)?;
        Self::merge(source, style, std::path::Path::new("the style part"))
    }

    /// Join a source part and a style part made for the same views' count and size and
    /// the same seed and object squares (else an error naming `style_origin`, where the
    /// style part came from, and what differs): the original views' Gram distances to the
    /// style are made here, from the source's Gram matrices.
    pub fn merge(
        source: SourceReference,
        style: StyleReference,
        style_origin: &std::path::Path,
    ) -> Result<Reference> {
        let diff = style
            .settings
            .differences(&StyleSettings::of(&source.settings));
        if !diff.is_empty() {
            return Err(Error::input(
                style_origin,
                format!(
                    "this style part was made for other views or options ({}; style part vs \
                     source part): make it again with `evaluate --reference-only style` for \
                     these views",
                    diff.join(", ")
                ),
            ));
        }
        let taps_ok = style.style_grams.len() >= texture::GRAM_LAYERS.len()
            && source
                .view_grams
                .iter()
                .all(|g| g.len() == style.style_grams.len())
            && source
                .object_grams
                .iter()
                .all(|g| g.len() == texture::GRAM_LAYERS.len());
        if !taps_ok {
            return Err(Error::input(
                style_origin,
                "the style part's Gram matrices do not match the source part's taps",
            ));
        }
        let object_gram = texture::ObjectGram::new(&style.style_grams);
        let gram_original_per_view = source
            .view_grams
            .iter()
            .map(|g| gram::gram_distance(g, &style.style_grams))
            .collect();
        let object_gram_original = source
            .object_grams
            .iter()
            .map(|g| object_gram.distances(g))
            .collect();
        // The style's squares only serve beside object squares (none fit: none used).
        let style_squares_pool3 = if source.object_squares_pool3.is_empty() {
            Vec::new()
        } else {
            style.style_squares_pool3
        };
        Ok(Reference {
            scores: Scores {
                settings: source.settings,
                gram_original_per_view,
                object_gram_original,
                short_original: source.short_original,
                long_original: source.long_original,
            },
            views_pool3: source.views_pool3,
            crops_pool3: style.crops_pool3,
            object_squares_pool3: source.object_squares_pool3,
            style_squares_pool3,
            style_grams: style.style_grams,
        })
    }

    /// Error (naming `origin`, where the reference came from) unless it was made for
    /// evaluating `orig` with `p`, and its parts have the sizes those settings give.
    pub fn check(&self, origin: &std::path::Path, orig: &ViewSet, p: &EvalParams) -> Result<()> {
        let want = Settings::of(orig, p);
        let diff = self.scores.settings.differences(&want);
        if !diff.is_empty() {
            return Err(Error::input(
                origin,
                format!(
                    "this reference was made with other settings ({}; reference vs this evaluation): \
                     make it again with `evaluate --reference-only` and the same options",
                    diff.join(", ")
                ),
            ));
        }
        let s = &self.scores;
        let pool3_views = if want.inception { want.views } else { 0 };
        let sizes_ok = self.views_pool3.len() == pool3_views
            && s.gram_original_per_view.len() == want.views
            && s.object_gram_original.len() == want.views
            && s.object_gram_original
                .iter()
                .all(|v| v.len() == texture::GRAM_LAYERS.len())
            && self.style_grams.len() >= texture::GRAM_LAYERS.len()
            && s.short_original.len() == consistency::pairs(want.views, want.short_range).len()
            && s.long_original.len() == consistency::pairs(want.views, want.long_range).len();
        if !sizes_ok {
            return Err(Error::input(
                origin,
                "the reference's parts do not match its settings (a damaged or hand-edited artifact)",
            ));
        }
        let measured = |v: &[consistency::PairScore]| {
            v.iter().any(|p| p.excess_lpips.is_some()) || v.iter().all(|p| p.lpips.is_none())
        };
        if !measured(&s.short_original) || !measured(&s.long_original) {
            return Err(Error::input(
                origin,
                "this reference predates the consistency excess (its pairs have no round trip): \
                 make it again with `evaluate --reference-only`",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maths::warp::look_at;
    use ndarray::{Array3, Array4};

    /// The reference times its parts for `pipeline report` ([`crate::timing`]): each
    /// network's loading, the consistency's warps and LPIPS, VGG, the Grams, Inception
    /// per image set (calls counted process-wide: each must have grown).
    #[test]
    fn the_reference_times_its_parts() {
        let Some(models) = super::super::nets::tests::setup() else {
            return;
        };
        let (n, s) = (2, 64);
        let cams = (0..n)
            .map(|i| {
                let eye = [0.05 * i as f64, -3.0, 1.0];
                look_at(&format!("v{i}"), eye, [0.0; 3], s as u32, s as u32, 60.0)
            })
            .collect();
        // A square of 30 px covered: no 32 px object square fits (no Inception of the
        // style's squares, the slow part).
        let inside = |y: usize, x: usize| (17..47).contains(&y) && (17..47).contains(&x);
        let rgb = Array4::from_shape_fn((n, s, s, 3), |(i, y, x, c)| {
            ((x / 3 + y / 5 + c + i) % 7) as f32 / 7.0
        });
        let alpha = Array3::from_shape_fn((n, s, s), |(_, y, x)| f32::from(u8::from(inside(y, x))));
        let depth = alpha.mapv(|a| 3.16 * a);
        let orig = ViewSet::new(std::path::Path::new("o"), rgb, depth, alpha, cams).unwrap();
        let style = Image::from_fn(32, 32, |x, y| [x as f32 / 32.0, y as f32 / 32.0, 0.5]);
        let p = EvalParams {
            lpips_net: LpipsNet::Alex,
            short_range: 1,
            long_range: 1,
            seed: 1,
            object_squares: 4,
            inception: true,
            threads: 1,
            style_size: 256,
        };
        let names = [
            "lpips alex",
            "lpips vgg16",
            "inception",
            "reference/consistency/warp",
            "reference/consistency/lpips",
            "reference/vgg",
            "reference/gram matrices",
            "reference/object gram",
            "reference/inception/views",
            "reference/inception/style crops",
            "reference/inception/object squares",
        ];
        let calls = || {
            let ph = crate::timing::phases();
            names.map(|n| ph.iter().find(|e| e.name == n).map_or(0, |e| e.calls))
        };
        let before = calls();
        let mut nets = Nets::load(&models, p.lpips_net, p.inception, p.threads).unwrap();
        let mut r = Reference::compute(&mut nets, &orig, &style, &p).unwrap();
        for ((name, after), b) in names.iter().zip(calls()).zip(before) {
            assert!(after > b, "phase `{name}` not timed");
        }
        // A reference from before the consistency excess (its pairs without one) is
        // refused with a way out.
        let origin = std::path::Path::new("ref");
        r.check(origin, &orig, &p).unwrap();
        assert!(
            r.scores
                .short_original
                .iter()
                .any(|q| q.excess_lpips.is_some())
        );
        for q in &mut r.scores.short_original {
            (q.excess_lpips, q.excess_rmse) = (None, None);
        }
        let e = r.check(origin, &orig, &p).unwrap_err().to_string();
        assert!(e.contains("predates the consistency excess"), "{e}");
    }
}

//! The two parts of the evaluation reference ([`crate::metrics::reference::parts`]):
//!
//! - `eval-source` (`evaluate --reference-only source`): `views_pool3.npy` and
//!   `object_squares_pool3.npy` `[M, 2048]` f32; per VGG16 tap `view_gram_{tap}.npy` and
//!   per object layer `object_gram_{layer}.npy`, `[N, C (C + 1) / 2]` f64, each view's
//!   symmetric Gram matrix as its upper triangle (an object Gram a view has none of is
//!   zeros, `object_gram_covered` in `source.json` says which); `source.json` (the
//!   settings and the original's own consistency); `meta.view_gram_taps`.
//! - `eval-style` (`evaluate --reference-only style`): `crops_pool3.npy` and
//!   `style_squares_pool3.npy` `[M, 2048]` f32, `style_gram_{tap}.npy` `[C, C]` f64 (as
//!   the whole reference's), `style.json` (what it was made for); `meta.style_gram_taps`.

use super::{meta_count, read_pool3, read_style_grams, write_pool3, write_style_grams};
use crate::metrics::consistency::PairScore;
use crate::metrics::reference::{
    Settings, SourceReference, StyleReference, StyleSettings, from_upper_triangle, upper_triangle,
};
use crate::metrics::texture::GRAM_LAYERS;
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind, ArtifactWriter};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The scalar part of an `eval-source` artifact.
const SOURCE_JSON: &str = "source.json";
/// The scalar part of an `eval-style` artifact.
const STYLE_JSON: &str = "style.json";

/// `source.json`.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SourceScores {
    settings: Settings,
    short_original: Vec<PairScore>,
    long_original: Vec<PairScore>,
    /// Per view, per layer of [`GRAM_LAYERS`]: whether it has an object Gram matrix.
    object_gram_covered: Vec<Vec<bool>>,
}

/// `style.json`.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StyleScores {
    settings: StyleSettings,
}

fn view_gram_file(tap: usize) -> String {
    format!("view_gram_{tap}.npy")
}

fn object_gram_file(layer: usize) -> String {
    format!("object_gram_{layer}.npy")
}

/// Write the source part into `out` (an `eval-source` artifact).
pub fn write_eval_source(out: &mut ArtifactWriter, r: &SourceReference) -> Result<()> {
    write_pool3(out, "views_pool3.npy", &r.views_pool3)?;
    write_pool3(out, "object_squares_pool3.npy", &r.object_squares_pool3)?;
    let n = r.view_grams.len();
    let taps = r.view_grams.first().map_or(0, Vec::len);
    for tap in 0..taps {
        let rows: Vec<Vec<f64>> = r
            .view_grams
            .iter()
            .map(|g| upper_triangle(&g[tap]))
            .collect();
        let len = rows.first().map_or(0, Vec::len);
        out.write_tensor(&view_gram_file(tap), &[n, len], &rows.concat())?;
        if tap < GRAM_LAYERS.len() {
            let zeros = vec![0.0; len];
            let rows: Vec<Vec<f64>> = r
                .object_grams
                .iter()
                .map(|g| {
                    g[tap]
                        .as_deref()
                        .map_or_else(|| zeros.clone(), upper_triangle)
                })
                .collect();
            out.write_tensor(&object_gram_file(tap), &[n, len], &rows.concat())?;
        }
    }
    let scores = SourceScores {
        settings: r.settings.clone(),
        short_original: r.short_original.clone(),
        long_original: r.long_original.clone(),
        object_gram_covered: r
            .object_grams
            .iter()
            .map(|g| g.iter().map(Option::is_some).collect())
            .collect(),
    };
    out.write_json(SOURCE_JSON, &scores)?;
    out.set_meta(serde_json::json!({"view_gram_taps": taps}));
    Ok(())
}

/// Write the style part into `out` (an `eval-style` artifact).
pub fn write_eval_style(out: &mut ArtifactWriter, r: &StyleReference) -> Result<()> {
    write_pool3(out, "crops_pool3.npy", &r.crops_pool3)?;
    write_pool3(out, "style_squares_pool3.npy", &r.style_squares_pool3)?;
    write_style_grams(out, &r.style_grams)?;
    out.write_json(
        STYLE_JSON,
        &StyleScores {
            settings: r.settings.clone(),
        },
    )?;
    Ok(())
}

/// Per view, the symmetric matrices of the `[N, C (C + 1) / 2]` tensor `name`.
fn read_triangles(art: &Artifact, name: &str, n: usize) -> Result<Vec<Vec<f64>>> {
    let a = art.read_tensor::<f64>(name)?;
    let bad = || {
        Error::input(
            art.path(name),
            format!("shape {:?}, expected [{n}, C (C + 1) / 2]", a.shape),
        )
    };
    if a.shape.len() != 2 || a.shape[0] != n || a.shape[1] == 0 {
        return Err(bad());
    }
    a.data
        .chunks(a.shape[1])
        .map(|t| from_upper_triangle(t).ok_or_else(bad))
        .collect()
}

/// Read an `eval-source` artifact.
pub(super) fn read_eval_source(dir: &Path) -> Result<(Artifact, SourceReference)> {
    let art = Artifact::open(dir, ArtifactKind::EvalSource)?;
    let s: SourceScores = art.read_json(SOURCE_JSON)?;
    let n = s.settings.views;
    let taps = meta_count(&art, dir, "view_gram_taps")?;
    let covered_ok = s.object_gram_covered.len() == n
        && s.object_gram_covered
            .iter()
            .all(|c| c.len() == GRAM_LAYERS.len());
    if taps < GRAM_LAYERS.len() || !covered_ok {
        return Err(Error::input(
            art.path(SOURCE_JSON),
            "the source part's Gram matrices do not match its settings (a damaged or \
             hand-edited artifact)",
        ));
    }
    let mut view_grams = vec![Vec::with_capacity(taps); n];
    let mut object_grams = vec![Vec::with_capacity(GRAM_LAYERS.len()); n];
    for tap in 0..taps {
        for (v, g) in read_triangles(&art, &view_gram_file(tap), n)?
            .into_iter()
            .enumerate()
        {
            view_grams[v].push(g);
        }
        if tap < GRAM_LAYERS.len() {
            let grams = read_triangles(&art, &object_gram_file(tap), n)?;
            for (v, g) in grams.into_iter().enumerate() {
                object_grams[v].push(s.object_gram_covered[v][tap].then_some(g));
            }
        }
    }
    let r = SourceReference {
        settings: s.settings,
        short_original: s.short_original,
        long_original: s.long_original,
        views_pool3: read_pool3(&art, "views_pool3.npy")?,
        object_squares_pool3: read_pool3(&art, "object_squares_pool3.npy")?,
        view_grams,
        object_grams,
    };
    Ok((art, r))
}

/// Read an `eval-style` artifact.
pub(super) fn read_eval_style(dir: &Path) -> Result<(Artifact, StyleReference)> {
    let art = Artifact::open(dir, ArtifactKind::EvalStyle)?;
    let s: StyleScores = art.read_json(STYLE_JSON)?;
    let r = StyleReference {
        settings: s.settings,
        crops_pool3: read_pool3(&art, "crops_pool3.npy")?,
        style_squares_pool3: read_pool3(&art, "style_squares_pool3.npy")?,
        style_grams: read_style_grams(&art, dir)?,
    };
    Ok((art, r))
}

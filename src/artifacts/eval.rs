//! The evaluation's reference artifacts: what the evaluation computes once per source
//! views and style (the Inception pool3 features, the Gram matrices, the source's own
//! scores), reused while the method's settings change. Whole (`eval-reference`,
//! `evaluate --reference-only`) or in two parts (`eval-source`: the original views';
//! `eval-style`: the style image's), read here in one place: [`read_references`] takes
//! what `--reference` names (one whole reference, or one part of each kind) and gives the
//! [`Reference`] an evaluation reads, refusing anything else with an error naming the
//! artifact.

use crate::metrics::nets::POOL3;
use crate::metrics::reference::Reference;
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind, ArtifactWriter};
use std::path::{Path, PathBuf};

mod parts;
pub use parts::{write_eval_source, write_eval_style};

/// The Inception pool3 feature files of an `eval-reference` artifact, in the order of
/// [`crate::metrics::reference::Reference`]'s fields.
const REFERENCE_POOL3: [&str; 4] = [
    "views_pool3.npy",
    "crops_pool3.npy",
    "object_squares_pool3.npy",
    "style_squares_pool3.npy",
];
/// Its scores.
const REFERENCE_SCORES: &str = "reference.json";

fn style_gram_file(tap: usize) -> String {
    format!("style_gram_{tap}.npy")
}

/// Write an evaluation reference into `out` (an `eval-reference` artifact): what
/// [`read_references`] reads.
pub fn write_eval_reference(out: &mut ArtifactWriter, r: &Reference) -> Result<()> {
    let sets = [
        &r.views_pool3,
        &r.crops_pool3,
        &r.object_squares_pool3,
        &r.style_squares_pool3,
    ];
    for (name, rows) in REFERENCE_POOL3.iter().zip(sets) {
        write_pool3(out, name, rows)?;
    }
    write_style_grams(out, &r.style_grams)?;
    out.write_json(REFERENCE_SCORES, &r.scores)?;
    Ok(())
}

/// Inception pool3 features, one row each: `[M, 2048]` f32.
fn write_pool3(out: &mut ArtifactWriter, name: &str, rows: &[Vec<f32>]) -> Result<()> {
    out.write_tensor(name, &[rows.len(), POOL3], &rows.concat())?;
    Ok(())
}

/// What [`write_pool3`] wrote, its shape checked.
fn read_pool3(art: &Artifact, name: &str) -> Result<Vec<Vec<f32>>> {
    let a = art.read_tensor::<f32>(name)?;
    if a.shape.len() != 2 || a.shape[1] != POOL3 {
        return Err(Error::input(
            art.path(name),
            format!("shape {:?}, expected [M, {POOL3}]", a.shape),
        ));
    }
    Ok(a.data.chunks(POOL3).map(<[f32]>::to_vec).collect())
}

/// The style image's Gram matrices, `[C, C]` f64 per tap, their count in
/// `meta.style_gram_taps`.
fn write_style_grams(out: &mut ArtifactWriter, grams: &[Vec<f64>]) -> Result<()> {
    for (tap, g) in grams.iter().enumerate() {
        let c = g.len().isqrt();
        out.write_tensor(&style_gram_file(tap), &[c, c], g)?;
    }
    out.set_meta(serde_json::json!({"style_gram_taps": grams.len()}));
    Ok(())
}

/// What [`write_style_grams`] wrote, its shapes checked.
fn read_style_grams(art: &Artifact, dir: &Path) -> Result<Vec<Vec<f64>>> {
    let taps = meta_count(art, dir, "style_gram_taps")?;
    let mut style_grams = Vec::with_capacity(taps);
    for tap in 0..taps {
        let name = style_gram_file(tap);
        let a = art.read_tensor::<f64>(&name)?;
        if a.shape.len() != 2 || a.shape[0] != a.shape[1] {
            return Err(Error::input(
                art.path(&name),
                format!("shape {:?}, expected [C, C]", a.shape),
            ));
        }
        style_grams.push(a.data);
    }
    Ok(style_grams)
}

/// The count `meta.KEY` of `art` (an error naming its manifest when missing).
fn meta_count(art: &Artifact, dir: &Path, key: &str) -> Result<usize> {
    art.manifest.meta[key]
        .as_u64()
        .map(|v| v as usize)
        .ok_or_else(|| Error::input(dir.join("manifest.json"), format!("meta.{key} missing")))
}

/// What an evaluation's `--reference` names, and what it evaluates against.
#[derive(Debug, Clone, Copy)]
pub struct ReferenceFor<'a> {
    /// The `--reference` directories, in order.
    pub dirs: &'a [PathBuf],
    /// The original views and the style image the evaluation uses.
    pub original: &'a Path,
    pub style: &'a Path,
    /// Its LPIPS backbone's name.
    pub lpips_net: &'a str,
}

/// Read the references `r.dirs` names for an evaluation of `r.original` against
/// `r.style` with the LPIPS backbone `r.lpips_net`: one `eval-reference` artifact, or
/// one `eval-source` and one `eval-style` (in any order), merged
/// ([`Reference::merge`]). Refused, naming the artifact: one of another kind, a part
/// without its other half, two of a kind, a whole reference beside a part, a part made
/// from another original or style (their blake3 in its manifest) or with another
/// backbone. Also returns the artifact the caller names when checking the evaluation's
/// settings ([`Reference::check`]): the whole one, or the source part.
pub fn read_references(r: ReferenceFor<'_>) -> Result<(PathBuf, Reference)> {
    let (mut whole, mut source, mut style) = (None, None, None);
    for dir in r.dirs {
        let kind = Artifact::open_unverified(dir)?.manifest.kind;
        let slot = match kind {
            ArtifactKind::EvalReference => &mut whole,
            ArtifactKind::EvalSource => &mut source,
            ArtifactKind::EvalStyle => &mut style,
            _ => {
                return Err(Error::input(
                    dir,
                    format!(
                        "an artifact of kind `{kind}`, not an evaluation reference: --reference \
                         takes an eval-reference artifact (`evaluate --reference-only`), or an \
                         eval-source and an eval-style artifact (`--reference-only source`, \
                         `--reference-only style`)"
                    ),
                ));
            }
        };
        if let Some(first) = slot.replace(dir.as_path()) {
            return Err(Error::input(
                dir,
                format!(
                    "a second {kind} artifact (the first: {}): give one of each kind",
                    first.display()
                ),
            ));
        }
    }
    match (whole, source, style) {
        (Some(dir), None, None) => {
            let (art, reference) = read_eval_reference(dir)?;
            made_from(&art, dir, &[("original", r.original), ("style", r.style)])?;
            same_lpips(&art, dir, r.lpips_net)?;
            Ok((dir.to_path_buf(), reference))
        }
        (Some(dir), ..) => Err(Error::input(
            dir,
            "a whole reference (eval-reference) is read alone, not beside an eval-source or \
             eval-style part",
        )),
        (None, Some(src), Some(sty)) => {
            let (art, source) = parts::read_eval_source(src)?;
            made_from(&art, src, &[("original", r.original)])?;
            same_lpips(&art, src, r.lpips_net)?;
            let (art, style) = parts::read_eval_style(sty)?;
            made_from(&art, sty, &[("style", r.style)])?;
            Ok((src.to_path_buf(), Reference::merge(source, style, sty)?))
        }
        (None, Some(dir), None) => Err(Error::input(
            dir,
            "an eval-source part needs its eval-style part beside it: add --reference DIR of \
             `evaluate --reference-only style` for this style",
        )),
        (None, None, Some(dir)) => Err(Error::input(
            dir,
            "an eval-style part needs its eval-source part beside it: add --reference DIR of \
             `evaluate --reference-only source` for these original views",
        )),
        (None, None, None) => Err(Error::param("--reference names no artifact")),
    }
}

/// Error, naming `dir`, unless the artifact `art` records each `(role, path)` as an input
/// with the blake3 `path` has now.
fn made_from(art: &Artifact, dir: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    for &(role, path) in inputs {
        let here = fantasystyle_schemas::hash_path(path)?;
        let recorded = art.manifest.inputs.iter().find(|i| i.role == role);
        if recorded.map(|i| &i.blake3) != Some(&here) {
            return Err(Error::input(
                dir,
                format!(
                    "this reference was made from another {role} ({}), not {}: make it again \
                     with `evaluate --reference-only`",
                    recorded.map_or("none recorded", |i| i.path.as_str()),
                    path.display()
                ),
            ));
        }
    }
    Ok(())
}

/// Error, naming `dir`, unless `art` was made with the LPIPS backbone `lpips_net`.
fn same_lpips(art: &Artifact, dir: &Path, lpips_net: &str) -> Result<()> {
    if art.manifest.producer.params.get("lpips_net") != Some(&serde_json::json!(lpips_net)) {
        return Err(Error::input(
            dir,
            format!(
                "this reference was made with another --lpips-net (this evaluation: {lpips_net})"
            ),
        ));
    }
    Ok(())
}

/// Read an `eval-reference` artifact (see [`crate::metrics::reference`]).
fn read_eval_reference(dir: &Path) -> Result<(Artifact, Reference)> {
    let art = Artifact::open(dir, ArtifactKind::EvalReference)?;
    let mut sets = Vec::new();
    for name in REFERENCE_POOL3 {
        sets.push(read_pool3(&art, name)?);
    }
    let style_grams = read_style_grams(&art, dir)?;
    let scores = art.read_json(REFERENCE_SCORES)?;
    let [
        views_pool3,
        crops_pool3,
        object_squares_pool3,
        style_squares_pool3,
    ]: [Vec<Vec<f32>>; 4] = sets.try_into().expect("four sets");
    Ok((
        art,
        Reference {
            scores,
            views_pool3,
            crops_pool3,
            object_squares_pool3,
            style_squares_pool3,
            style_grams,
        },
    ))
}

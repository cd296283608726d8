//! The `eval-reference` artifact: what the evaluation computes once per source views and
//! style (the Inception pool3 features, the style's Gram matrices, the source's own
//! scores), reused while the method's settings change.

use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use std::path::Path;

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
/// [`read_eval_reference_for`] reads.
pub fn write_eval_reference(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    r: &crate::metrics::reference::Reference,
) -> Result<()> {
    let sets = [
        &r.views_pool3,
        &r.crops_pool3,
        &r.object_squares_pool3,
        &r.style_squares_pool3,
    ];
    for (name, rows) in REFERENCE_POOL3.iter().zip(sets) {
        out.write_tensor(
            name,
            &[rows.len(), crate::metrics::nets::POOL3],
            &rows.concat(),
        )?;
    }
    for (tap, g) in r.style_grams.iter().enumerate() {
        let c = g.len().isqrt();
        out.write_tensor(&style_gram_file(tap), &[c, c], g)?;
    }
    out.write_json(REFERENCE_SCORES, &r.scores)?;
    out.set_meta(serde_json::json!({"style_gram_taps": r.style_grams.len()}));
    Ok(())
}

/// Read the `eval-reference` artifact `dir` (see [`crate::metrics::reference`]) for an
/// evaluation of `original` against `style` with the LPIPS backbone `lpips_net`: refused,
/// naming `dir` and what differs, when it was made from other files (their blake3 in its
/// manifest) or with another backbone. The caller checks the evaluation's settings
/// ([`crate::metrics::reference::Reference::check`]).
pub fn read_eval_reference_for(
    dir: &Path,
    original: &Path,
    style: &Path,
    lpips_net: &str,
) -> Result<crate::metrics::reference::Reference> {
    let (art, r) = read_eval_reference(dir)?;
    for (role, path) in [("original", original), ("style", style)] {
        let here = fantasystyle_schemas::hash_path(path)?;
        let made_from = art.manifest.inputs.iter().find(|i| i.role == role);
        if made_from.map(|i| &i.blake3) != Some(&here) {
            return Err(Error::input(
                dir,
                format!(
                    "this reference was made from another {role} ({}), not {}: make it again \
                     with `evaluate --reference-only`",
                    made_from.map_or("none recorded", |i| i.path.as_str()),
                    path.display()
                ),
            ));
        }
    }
    if art.manifest.producer.params.get("lpips_net") != Some(&serde_json::json!(lpips_net)) {
        return Err(Error::input(
            dir,
            format!(
                "this reference was made with another --lpips-net (this evaluation: {lpips_net})"
            ),
        ));
    }
    Ok(r)
}

/// Read an `eval-reference` artifact (see [`crate::metrics::reference`]).
fn read_eval_reference(dir: &Path) -> Result<(Artifact, crate::metrics::reference::Reference)> {
    let art = Artifact::open(dir, ArtifactKind::EvalReference)?;
    let mut sets = Vec::new();
    for name in REFERENCE_POOL3 {
        let a = art.read_tensor::<f32>(name)?;
        if a.shape.len() != 2 || a.shape[1] != crate::metrics::nets::POOL3 {
            return Err(Error::input(
                art.path(name),
                format!(
                    "shape {:?}, expected [M, {}]",
                    a.shape,
                    crate::metrics::nets::POOL3
                ),
            ));
        }
        sets.push(
            a.data
                .chunks(crate::metrics::nets::POOL3)
                .map(<[f32]>::to_vec)
                .collect(),
        );
    }
    let taps = art.manifest.meta["style_gram_taps"]
        .as_u64()
        .ok_or_else(|| Error::input(dir.join("manifest.json"), "meta.style_gram_taps missing"))?
        as usize;
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
    let scores = art.read_json(REFERENCE_SCORES)?;
    let [
        views_pool3,
        crops_pool3,
        object_squares_pool3,
        style_squares_pool3,
    ]: [Vec<Vec<f32>>; 4] = sets.try_into().expect("four sets");
    Ok((
        art,
        crate::metrics::reference::Reference {
            scores,
            views_pool3,
            crops_pool3,
            object_squares_pool3,
            style_squares_pool3,
            style_grams,
        },
    ))
}

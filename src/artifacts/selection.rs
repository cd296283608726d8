//! The `selection` artifact (`select`): one weight in [0, 1] per Gaussian of one scene.

use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use std::path::Path;

/// The weights file of a `selection` artifact.
pub const SELECTION_WEIGHTS: &str = "weights.npy";

/// Read the `selection` artifact `dir`: one weight per Gaussian, each in [0, 1] (errors
/// name the file).
pub fn read_selection(dir: &Path) -> Result<crate::selection::Selection> {
    let art = Artifact::open(dir, ArtifactKind::Selection)?;
    let t = art.read_f32(SELECTION_WEIGHTS)?;
    let path = art.path(SELECTION_WEIGHTS);
    if t.shape.len() != 1 {
        return Err(Error::input(
            path,
            format!("expected shape [N], found {:?}", t.shape),
        ));
    }
    crate::selection::Selection::new(t.data, &path)
}

/// Write `sel` into `out` (a `selection` artifact): the weights, and in `meta` the
/// number of Gaussians, how many are selected and `meta`'s own fields.
pub fn write_selection(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    sel: &crate::selection::Selection,
    meta: serde_json::Value,
) -> Result<()> {
    out.write_tensor(SELECTION_WEIGHTS, &[sel.len()], &sel.weights)?;
    let mut m = serde_json::json!({"gaussians": sel.len(), "selected": sel.selected()});
    if let (Some(m), serde_json::Value::Object(extra)) = (m.as_object_mut(), meta) {
        m.extend(extra);
    }
    out.set_meta(m);
    Ok(())
}

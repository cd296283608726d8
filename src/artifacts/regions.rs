//! A scene artifact's regions (`distill --region`/`--regions`, [`crate::regions`]):
//! `regions.npy` `[R, N]`, each region's weight per Gaussian, and in the manifest's
//! `meta.regions` each region's name, selection, style (paths and weights) and
//! strength. The report draws them ([`crate::metrics::report`]).

use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use std::path::{Path, PathBuf};

/// The regions' weights inside a scene artifact.
pub const REGIONS_WEIGHTS: &str = "regions.npy";

/// One region as the artifact records it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionRecord {
    pub name: String,
    pub selection: String,
    /// Each style image and its weight.
    pub styles: Vec<(PathBuf, f32)>,
    pub strength: f32,
    /// Gaussians of weight above 0.
    pub selected: usize,
}

/// A scene artifact's regions: their records and weights `[R][N]`.
#[derive(Debug, Clone, PartialEq)]
pub struct RegionsRecord {
    pub regions: Vec<RegionRecord>,
    pub weights: Vec<Vec<f32>>,
    /// Gaussians whose weights were normalised (their sum past 1).
    pub overlapping: usize,
}

/// Write `r` into `out` (a scene artifact).
pub fn write_regions(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    r: &crate::regions::Regions,
) -> Result<()> {
    let n = r.combined.len();
    let flat: Vec<f32> = r
        .list
        .iter()
        .flat_map(|x| x.weights.iter().copied())
        .collect();
    out.write_tensor(REGIONS_WEIGHTS, &[r.list.len(), n], &flat)?;
    let records: Vec<RegionRecord> = r
        .list
        .iter()
        .map(|x| RegionRecord {
            name: x.name.clone(),
            selection: x.selection.clone(),
            styles: x.styles.iter().map(|(p, _, w)| (p.clone(), *w)).collect(),
            strength: x.strength,
            selected: x.weights.iter().filter(|&&w| w > 0.0).count(),
        })
        .collect();
    out.set_meta(serde_json::json!({"regions": records, "overlapping": r.overlapping}));
    Ok(())
}

/// The regions of scene artifact `dir` (`None`: a scene styled whole, or not an
/// artifact).
pub fn read_regions(dir: &Path) -> Result<Option<RegionsRecord>> {
    if !dir.is_dir() || !dir.join(REGIONS_WEIGHTS).is_file() {
        return Ok(None);
    }
    let art = Artifact::open(dir, ArtifactKind::Scene)?;
    let t = art.read_f32(REGIONS_WEIGHTS)?;
    let path = art.path(REGIONS_WEIGHTS);
    let meta = &art.manifest.meta;
    let regions: Vec<RegionRecord> = serde_json::from_value(meta["regions"].clone())
        .map_err(|e| Error::input(&path, format!("meta.regions: {e}")))?;
    let overlapping = meta["overlapping"].as_u64().unwrap_or(0) as usize;
    if t.shape.len() != 2 || t.shape[0] != regions.len() {
        return Err(Error::input(
            path,
            format!(
                "expected shape [{}, N] (one row per region), found {:?}",
                regions.len(),
                t.shape
            ),
        ));
    }
    let n = t.shape[1];
    let weights = t.data.chunks(n.max(1)).map(<[f32]>::to_vec).collect();
    Ok(Some(RegionsRecord {
        regions,
        weights,
        overlapping,
    }))
}

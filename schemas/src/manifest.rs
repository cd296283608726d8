//! The artifact manifest (`manifest.json`) and the registry of artifact kinds.
//!
//! A manifest records what an artifact is (`kind`, `schema_version`), who made it
//! (`producer`: stage, stage version, a hash of its parameters), what it was made from
//! (`inputs`, each with the blake3 of the input: an artifact's manifest, or a plain
//! file's bytes), and what it holds (`files`, each with blake3, size and, for tensors,
//! dtype and shape). `meta` carries kind-specific values (e.g. the timestep of a
//! noised-latents artifact).
//!
//! Versioning: each kind has a current schema version and the set of versions this
//! build can still read. Old versions keep loading; fixtures of each live in
//! `schemas/fixtures/` and are tested.

use crate::DType;
use serde::{Deserialize, Serialize};

/// File name of the manifest inside an artifact directory.
pub const MANIFEST_FILE: &str = "manifest.json";
/// The value of `format` in every manifest.
pub const FORMAT: &str = "fantasystyle-artifact";

/// The kinds of artifact the stages exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ArtifactKind {
    /// Rendered views: `rgb.npy` `[N,H,W,3]`, `depth.npy` `[N,H,W]`, `alpha.npy` `[N,H,W]`,
    /// `cameras.json`.
    Views,
    /// VAE latents: `latents.npy` `[N,C,h,w]`.
    Latents,
    /// Noised source and (MVFC-filtered) target latents sharing one eps: `z_src.npy`,
    /// `z_tgt.npy`, `eps.npy` `[N,C,h,w]`; `meta.timestep`.
    NoisedLatents,
    /// Target images for the colour fit: `rgb.npy` `[N,H,W,3]`, `cameras.json`.
    Targets,
    /// A Gaussian scene: `scene.ply`, optionally `loss.json`.
    Scene,
    /// Evaluation results: `metrics.json`, `report.html`.
    Evaluation,
    /// What an evaluation computes from the original views and the style image alone
    /// (Inception features, the style's Gram matrices, the original's scores):
    /// `reference.json` and `.npy` features; `meta` holds the settings it was made with.
    EvalReference,
    /// The part of an evaluation reference that depends only on the original views
    /// (their Inception features and Gram matrices, their own consistency):
    /// `source.json` and `.npy` tensors.
    EvalSource,
    /// The part of an evaluation reference that depends only on the style image (and the
    /// views' count and size): the style's Inception features and Gram matrices;
    /// `style.json` and `.npy` tensors.
    EvalStyle,
    /// A weight in [0, 1] per Gaussian of one scene (which Gaussians a stylization may
    /// change, and how much): `weights.npy` `[N]` f32; `meta` holds the count selected,
    /// their bounds and what the selection was made from.
    Selection,
}

impl ArtifactKind {
    pub const ALL: [ArtifactKind; 10] = [
        ArtifactKind::Views,
        ArtifactKind::Latents,
        ArtifactKind::NoisedLatents,
        ArtifactKind::Targets,
        ArtifactKind::Scene,
        ArtifactKind::Evaluation,
        ArtifactKind::EvalReference,
        ArtifactKind::EvalSource,
        ArtifactKind::EvalStyle,
        ArtifactKind::Selection,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            ArtifactKind::Views => "views",
            ArtifactKind::Latents => "latents",
            ArtifactKind::NoisedLatents => "noised-latents",
            ArtifactKind::Targets => "targets",
            ArtifactKind::Scene => "scene",
            ArtifactKind::Evaluation => "evaluation",
            ArtifactKind::EvalReference => "eval-reference",
            ArtifactKind::EvalSource => "eval-source",
            ArtifactKind::EvalStyle => "eval-style",
            ArtifactKind::Selection => "selection",
        }
    }

    /// The schema version this build writes.
    pub fn current_version(self) -> u32 {
        1
    }

    /// The schema versions this build reads.
    pub fn readable_versions(self) -> &'static [u32] {
        &[1]
    }

    /// Files every artifact of this kind must list.
    pub fn required_files(self) -> &'static [&'static str] {
        match self {
            ArtifactKind::Views => &["rgb.npy", "depth.npy", "alpha.npy", "cameras.json"],
            ArtifactKind::Latents => &["latents.npy"],
            ArtifactKind::NoisedLatents => &["z_src.npy", "z_tgt.npy", "eps.npy"],
            ArtifactKind::Targets => &["rgb.npy", "cameras.json"],
            ArtifactKind::Scene => &["scene.ply"],
            ArtifactKind::Evaluation => &["metrics.json"],
            ArtifactKind::EvalReference => &["reference.json"],
            ArtifactKind::EvalSource => &["source.json"],
            ArtifactKind::EvalStyle => &["style.json"],
            ArtifactKind::Selection => &["weights.npy"],
        }
    }
}

impl std::fmt::Display for ArtifactKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Who produced an artifact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Producer {
    /// Stage name, e.g. `render-views`.
    pub stage: String,
    /// Version of the stage binary (crate version).
    pub version: String,
    /// blake3 of the canonical JSON of `params`.
    pub params_hash: String,
    /// The parameters the stage ran with.
    #[serde(default)]
    pub params: serde_json::Value,
}

impl Producer {
    /// Build a producer record, hashing `params` canonically.
    pub fn new(stage: &str, version: &str, params: serde_json::Value) -> Self {
        let params_hash = blake3::hash(canonical_json(&params).as_bytes())
            .to_hex()
            .to_string();
        Producer {
            stage: stage.to_string(),
            version: version.to_string(),
            params_hash,
            params,
        }
    }
}

/// JSON with object keys sorted, so equal values hash equally.
pub fn canonical_json(v: &serde_json::Value) -> String {
    fn sort(v: &serde_json::Value) -> serde_json::Value {
        match v {
            serde_json::Value::Object(m) => {
                let mut keys: Vec<_> = m.keys().collect();
                keys.sort();
                let mut out = serde_json::Map::new();
                for k in keys {
                    out.insert(k.clone(), sort(&m[k]));
                }
                serde_json::Value::Object(out)
            }
            serde_json::Value::Array(a) => serde_json::Value::Array(a.iter().map(sort).collect()),
            x => x.clone(),
        }
    }
    serde_json::to_string(&sort(v)).unwrap_or_default()
}

/// An input an artifact was made from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputRef {
    /// What the input was for, e.g. `scene`, `cameras`, `views`.
    pub role: String,
    /// The path as given to the stage.
    pub path: String,
    /// blake3 of the input (its manifest for an artifact, its bytes for a file).
    pub blake3: String,
}

/// A file inside an artifact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileEntry {
    pub name: String,
    pub blake3: String,
    pub bytes: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dtype: Option<DType>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shape: Option<Vec<usize>>,
}

/// The manifest of an artifact directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    pub kind: ArtifactKind,
    pub schema_version: u32,
    pub producer: Producer,
    #[serde(default)]
    pub inputs: Vec<InputRef>,
    pub files: Vec<FileEntry>,
    #[serde(default, skip_serializing_if = "serde_json::Value::is_null")]
    pub meta: serde_json::Value,
}

impl Manifest {
    pub fn file(&self, name: &str) -> Option<&FileEntry> {
        self.files.iter().find(|f| f.name == name)
    }
}

//! The on-disk contract of fantasystyle.
//!
//! Every stage reads and writes **artifacts**: a directory holding a `manifest.json`
//! ([`Manifest`]) and tensors as NumPy `.npy` files (so anyone can `np.load` an
//! intermediate latent), plus free-form files such as PNG previews or camera JSON.
//!
//! * [`npy`]: reading and writing `.npy` (format 1.0 to 3.0, little-endian, C order),
//!   whole or item by item along the first axis ([`NpyReader`]).
//! * [`manifest`]: the manifest, artifact kinds and their schema versions.
//! * [`artifact`]: [`ArtifactWriter`] (write into a temporary sibling, then rename into
//!   place; tensors whole or streamed piece by piece, [`TensorStream`]) and [`Artifact`]
//!   (open, check kind, version and hashes, read tensors whole or item by item).
//! * [`atomic`]: single-file atomic writes (temporary sibling, fsync, rename).
//!
//! This crate has no dependency on onnxruntime or on the numerical core, so the DAG
//! runner can depend on it alone.

pub mod artifact;
pub mod atomic;
pub mod manifest;
pub mod npy;

pub use artifact::{Artifact, ArtifactWriter, TensorStream, hash_file, hash_path};
pub use atomic::{atomic_write, atomic_write_json};
pub use manifest::{ArtifactKind, FileEntry, InputRef, MANIFEST_FILE, Manifest, Producer};
pub use npy::{DType, NpyArray, NpyElement, NpyReader, read_npy, read_npy_f32, write_npy};

use std::path::PathBuf;

/// Everything that can go wrong reading or writing the on-disk contract.
/// Every variant names the file it is about.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a valid .npy file: {reason}")]
    Npy { path: PathBuf, reason: String },
    #[error("{path}: invalid manifest: {reason}")]
    Manifest { path: PathBuf, reason: String },
    #[error("{path}: expected an artifact of kind `{expected}`, found `{found}`")]
    WrongKind {
        path: PathBuf,
        expected: String,
        found: String,
    },
    #[error(
        "{path}: artifact kind `{kind}` has schema version {found}, this build reads versions {supported}"
    )]
    UnsupportedVersion {
        path: PathBuf,
        kind: String,
        found: u32,
        supported: String,
    },
    #[error(
        "{path}: content hash mismatch (manifest says {expected}, file has {found}); the artifact was modified or half-written"
    )]
    HashMismatch {
        path: PathBuf,
        expected: String,
        found: String,
    },
    #[error("{path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
}

impl SchemaError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        SchemaError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn invalid(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        SchemaError::Invalid {
            path: path.into(),
            reason: reason.into(),
        }
    }
}

pub type Result<T, E = SchemaError> = std::result::Result<T, E>;

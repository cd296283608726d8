//! Reading an artifact directory: [`Artifact::open`] checks format, kind, schema
//! version, the presence of required files and every file's blake3 before anything is
//! read; tensors are read whole or item by item along their first axis.

use super::hash::hash_file;
use crate::manifest::{FORMAT, canonical_json};
use crate::npy::{NpyArray, NpyElement, NpyReader, decode_npy};
use crate::{ArtifactKind, MANIFEST_FILE, Manifest, Result, SchemaError};
use std::fs;
use std::path::{Path, PathBuf};

/// An artifact opened for reading; its manifest has been validated and its files'
/// hashes checked.
#[derive(Debug, Clone)]
pub struct Artifact {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

impl Artifact {
    /// Open `dir`, requiring kind `kind`, a readable schema version, the required files
    /// and matching hashes.
    pub fn open(dir: &Path, kind: ArtifactKind) -> Result<Self> {
        let a = Self::open_any(dir)?;
        if a.manifest.kind != kind {
            return Err(SchemaError::WrongKind {
                path: dir.to_path_buf(),
                expected: kind.to_string(),
                found: a.manifest.kind.to_string(),
            });
        }
        Ok(a)
    }

    /// Open an artifact of any kind (for inspection tools).
    pub fn open_any(dir: &Path) -> Result<Self> {
        let a = Self::open_unverified(dir)?;
        for f in &a.manifest.files {
            let p = dir.join(&f.name);
            if !p.is_file() {
                return Err(SchemaError::invalid(
                    &p,
                    "listed in the manifest but missing",
                ));
            }
            let h = hash_file(&p)?;
            if h != f.blake3 {
                return Err(SchemaError::HashMismatch {
                    path: p,
                    expected: f.blake3.clone(),
                    found: h,
                });
            }
        }
        Ok(a)
    }

    /// Read and validate the manifest without hashing the files.
    pub fn open_unverified(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(SchemaError::invalid(
                dir,
                if dir.exists() {
                    "not a directory (an artifact is a directory)"
                } else {
                    "artifact directory does not exist"
                },
            ));
        }
        let mpath = dir.join(MANIFEST_FILE);
        let text = fs::read_to_string(&mpath).map_err(|e| SchemaError::io(&mpath, e))?;
        let manifest: Manifest =
            serde_json::from_str(&text).map_err(|e| SchemaError::Manifest {
                path: mpath.clone(),
                reason: e.to_string(),
            })?;
        if manifest.format != FORMAT {
            return Err(SchemaError::Manifest {
                path: mpath,
                reason: format!("format is `{}`, expected `{FORMAT}`", manifest.format),
            });
        }
        let kind = manifest.kind;
        if !kind.readable_versions().contains(&manifest.schema_version) {
            return Err(SchemaError::UnsupportedVersion {
                path: mpath,
                kind: kind.to_string(),
                found: manifest.schema_version,
                supported: format!("{:?}", kind.readable_versions()),
            });
        }
        for req in kind.required_files() {
            if manifest.file(req).is_none() {
                return Err(SchemaError::Manifest {
                    path: mpath,
                    reason: format!("kind `{kind}` requires file `{req}`, which is not listed"),
                });
            }
        }
        Ok(Artifact {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Path of a file inside the artifact.
    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Read tensor `name`, checking its dtype and shape against the manifest.
    pub fn read_tensor<T: NpyElement>(&self, name: &str) -> Result<NpyArray<T>> {
        let p = self.path(name);
        let entry = self
            .manifest
            .file(name)
            .ok_or_else(|| SchemaError::invalid(&p, "not listed in the artifact's manifest"))?;
        let bytes = fs::read(&p).map_err(|e| SchemaError::io(&p, e))?;
        let a = decode_npy::<T>(&p, &bytes)?;
        if let Some(shape) = entry.shape.as_ref().filter(|s| **s != a.shape) {
            return Err(SchemaError::invalid(
                &p,
                format!(
                    "shape {:?} differs from the manifest's {:?}",
                    a.shape, shape
                ),
            ));
        }
        Ok(a)
    }

    /// Open tensor `name` for reading item by item along its first axis (see
    /// [`NpyReader`]), checking its dtype and shape against the manifest.
    pub fn tensor_reader<T: NpyElement>(&self, name: &str) -> Result<NpyReader<T>> {
        let p = self.path(name);
        let entry = self
            .manifest
            .file(name)
            .ok_or_else(|| SchemaError::invalid(&p, "not listed in the artifact's manifest"))?;
        let r = NpyReader::<T>::open(&p)?;
        if let Some(shape) = entry.shape.as_ref().filter(|s| s[..] != *r.shape()) {
            return Err(SchemaError::invalid(
                &p,
                format!(
                    "shape {:?} differs from the manifest's {:?}",
                    r.shape(),
                    shape
                ),
            ));
        }
        Ok(r)
    }

    /// Read an `f32` tensor and refuse NaN or infinity.
    pub fn read_f32(&self, name: &str) -> Result<NpyArray<f32>> {
        let a = self.read_tensor::<f32>(name)?;
        if let Some(i) = crate::npy::first_non_finite(&a.data) {
            return Err(SchemaError::Npy {
                path: self.path(name),
                reason: format!("element {i} is {} (NaN or infinity not allowed)", a.data[i]),
            });
        }
        Ok(a)
    }

    /// Read and parse a JSON file.
    pub fn read_json<T: serde::de::DeserializeOwned>(&self, name: &str) -> Result<T> {
        let p = self.path(name);
        let text = fs::read_to_string(&p).map_err(|e| SchemaError::io(&p, e))?;
        serde_json::from_str(&text)
            .map_err(|e| SchemaError::invalid(&p, format!("invalid JSON: {e}")))
    }

    /// blake3 identifying this artifact (its manifest's hash).
    pub fn id(&self) -> Result<String> {
        hash_file(&self.dir.join(MANIFEST_FILE))
    }

    /// The producer's params as canonical JSON.
    pub fn params_canonical(&self) -> String {
        canonical_json(&self.manifest.producer.params)
    }
}

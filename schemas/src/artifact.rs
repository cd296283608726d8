//! Writing and reading artifact directories.
//!
//! [`ArtifactWriter`] writes every file into a temporary sibling directory
//! (`.NAME.partial-PID-N`), then writes the manifest last and renames the directory
//! into place. If the stage fails or is killed, the temporary directory is left behind
//! or removed, and the previous artifact at the target path (if any) is untouched until
//! the final rename. [`Artifact::open`] checks format, kind, schema version, the
//! presence of required files and every file's blake3 before anything is read.

use crate::manifest::{FORMAT, canonical_json};
use crate::npy::{NpyArray, NpyElement, NpyReader, decode_npy, encode_npy};
use crate::{
    ArtifactKind, FileEntry, InputRef, MANIFEST_FILE, Manifest, Producer, Result, SchemaError,
};
use std::fs;
use std::path::{Path, PathBuf};

/// blake3 of a file's bytes, as hex. Large files are read in 4 MiB pieces, each hashed
/// on all cores (blake3's tree makes the digest independent of how it is computed).
pub fn hash_file(path: &Path) -> Result<String> {
    use std::io::Read;
    let mut f = fs::File::open(path).map_err(|e| SchemaError::io(path, e))?;
    let mut h = blake3::Hasher::new();
    let mut buf = vec![0u8; 4 << 20];
    loop {
        let n = match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(SchemaError::io(path, e)),
        };
        hash_update(&mut h, &buf[..n]);
    }
    Ok(h.finalize().to_hex().to_string())
}

/// Write `bytes` at byte offset `at` of `file`: on Unix in 1 MiB pieces written in
/// parallel (positional writes do not move a shared cursor), elsewhere in one piece.
fn write_at(file: &fs::File, bytes: &[u8], at: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        use rayon::prelude::*;
        use std::os::unix::fs::FileExt;
        const PIECE: usize = 1 << 20;
        bytes
            .par_chunks(PIECE)
            .enumerate()
            .try_for_each(|(k, c)| file.write_all_at(c, at + (k * PIECE) as u64))
    }
    #[cfg(not(unix))]
    {
        use std::io::{Seek, SeekFrom, Write};
        let mut f = file;
        f.seek(SeekFrom::Start(at))?;
        f.write_all(bytes)
    }
}

/// Feed `bytes` to `h`, in parallel when they are large enough to pay for it.
pub(crate) fn hash_update(h: &mut blake3::Hasher, bytes: &[u8]) {
    if bytes.len() >= 1 << 20 {
        h.update_rayon(bytes);
    } else {
        h.update(bytes);
    }
}

/// blake3 identifying an input: for an artifact directory, the hash of its manifest
/// (which lists every file's hash); for a plain file, the hash of its bytes; for a
/// directory without manifest, the hash over its files' relative paths and hashes.
pub fn hash_path(path: &Path) -> Result<String> {
    if path.is_dir() {
        let m = path.join(MANIFEST_FILE);
        if m.is_file() {
            return hash_file(&m);
        }
        let mut entries = Vec::new();
        collect_files(path, path, &mut entries)?;
        entries.sort();
        let mut h = blake3::Hasher::new();
        for (rel, p) in entries {
            h.update(rel.as_bytes());
            h.update(hash_file(&p)?.as_bytes());
        }
        Ok(h.finalize().to_hex().to_string())
    } else {
        hash_file(path)
    }
}

fn collect_files(root: &Path, dir: &Path, out: &mut Vec<(String, PathBuf)>) -> Result<()> {
    for e in fs::read_dir(dir).map_err(|e| SchemaError::io(dir, e))? {
        let e = e.map_err(|e| SchemaError::io(dir, e))?;
        let p = e.path();
        if p.is_dir() {
            collect_files(root, &p, out)?;
        } else {
            let rel = p
                .strip_prefix(root)
                .unwrap_or(&p)
                .to_string_lossy()
                .replace('\\', "/");
            out.push((rel, p));
        }
    }
    Ok(())
}

/// Builds an artifact in a temporary sibling directory and renames it into place on
/// [`ArtifactWriter::commit`]. Dropping an uncommitted writer removes the temporary
/// directory.
#[derive(Debug)]
pub struct ArtifactWriter {
    target: PathBuf,
    tmp: PathBuf,
    kind: ArtifactKind,
    producer: Producer,
    inputs: Vec<InputRef>,
    files: Vec<FileEntry>,
    /// Names of tensors being streamed (reserved, not finished yet).
    streaming: Vec<String>,
    meta: serde_json::Value,
    committed: bool,
}

/// A tensor written into an artifact piece by piece along its first axis (say view by
/// view), so that the producer never holds all of it: the header is written when the
/// stream starts (the shape is known), data is appended in C order, hashed as it goes
/// and written into the artifact's staging directory, so the artifact stays atomic.
/// Start with [`ArtifactWriter::stream_tensor`], end with [`ArtifactWriter::finish_stream`];
/// the bytes are exactly those [`ArtifactWriter::write_tensor`] writes for the whole
/// tensor, and so is the manifest entry. Each append hashes (on all cores) and writes
/// (in 1 MiB pieces at their offsets, in parallel, on Unix) at the same time, so that a
/// producer on many cores is not held up by one thread copying into the page cache.
#[derive(Debug)]
pub struct TensorStream<T> {
    name: String,
    path: PathBuf,
    file: fs::File,
    hasher: blake3::Hasher,
    shape: Vec<usize>,
    /// Elements still expected.
    left: usize,
    bytes: u64,
    buf: Vec<u8>,
    _t: std::marker::PhantomData<T>,
}

impl<T: NpyElement> TensorStream<T> {
    /// Append `data` (C order, continuing where the last append stopped).
    pub fn append(&mut self, data: &[T]) -> Result<()> {
        let mut buf = std::mem::take(&mut self.buf);
        buf.clear();
        T::extend_le(data, &mut buf);
        let r = self.append_le_bytes(&buf);
        self.buf = buf;
        r
    }

    /// Append elements already encoded as little-endian bytes (see
    /// [`NpyElement::extend_le`]), e.g. by worker threads.
    pub fn append_le_bytes(&mut self, bytes: &[u8]) -> Result<()> {
        let size = T::DTYPE.size();
        if !bytes.len().is_multiple_of(size) {
            return Err(SchemaError::invalid(
                &self.path,
                format!("{} bytes are not whole {} elements", bytes.len(), T::DTYPE),
            ));
        }
        let n = bytes.len() / size;
        if n > self.left {
            return Err(SchemaError::invalid(
                &self.path,
                format!(
                    "{} more elements than shape {:?} holds",
                    n - self.left,
                    self.shape
                ),
            ));
        }
        let (hasher, file, at) = (&mut self.hasher, &self.file, self.bytes);
        let ((), written) =
            rayon::join(|| hash_update(hasher, bytes), || write_at(file, bytes, at));
        written.map_err(|e| SchemaError::io(&self.path, e))?;
        self.left -= n;
        self.bytes += bytes.len() as u64;
        Ok(())
    }

    /// Elements still to append.
    pub fn remaining(&self) -> usize {
        self.left
    }
}

impl ArtifactWriter {
    /// Start writing an artifact of `kind` that will live at `target`.
    pub fn create(target: &Path, kind: ArtifactKind, producer: Producer) -> Result<Self> {
        let parent = match target.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        fs::create_dir_all(&parent).map_err(|e| SchemaError::io(&parent, e))?;
        if target.exists() && !target.is_dir() {
            return Err(SchemaError::invalid(
                target,
                "output path exists and is not a directory",
            ));
        }
        // Replacing a previous artifact is the normal case; replacing a user's directory
        // that is not an artifact (say `--out data-sample`) would delete their files.
        if target.is_dir()
            && !target.join(MANIFEST_FILE).is_file()
            && fs::read_dir(target).map_or(true, |mut d| d.next().is_some())
        {
            return Err(SchemaError::invalid(
                target,
                "the directory exists, is not empty and is not an artifact (no manifest.json); refusing to replace it",
            ));
        }
        let tmp = crate::atomic::temp_sibling(target, "partial");
        fs::create_dir(&tmp).map_err(|e| SchemaError::io(&tmp, e))?;
        Ok(ArtifactWriter {
            target: target.to_path_buf(),
            tmp,
            kind,
            producer,
            inputs: Vec::new(),
            files: Vec::new(),
            streaming: Vec::new(),
            meta: serde_json::Value::Null,
            committed: false,
        })
    }

    /// The final path.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// The temporary directory files are being written into.
    pub fn staging_dir(&self) -> &Path {
        &self.tmp
    }

    /// Record an input (hashing it now).
    pub fn add_input(&mut self, role: &str, path: &Path) -> Result<()> {
        let blake3 = hash_path(path)?;
        self.inputs.push(InputRef {
            role: role.to_string(),
            path: path.to_string_lossy().into_owned(),
            blake3,
        });
        Ok(())
    }

    /// Record an input by a hash computed elsewhere (e.g. a generated orbit spec).
    pub fn add_input_hash(&mut self, role: &str, path: &str, blake3: String) {
        self.inputs.push(InputRef {
            role: role.to_string(),
            path: path.to_string(),
            blake3,
        });
    }

    /// Set kind-specific metadata.
    pub fn set_meta(&mut self, meta: serde_json::Value) {
        self.meta = meta;
    }

    fn check_name(&self, name: &str) -> Result<()> {
        if name.is_empty()
            || name.contains('/')
            || name.contains('\\')
            || name.starts_with('.')
            || name == MANIFEST_FILE
        {
            return Err(SchemaError::invalid(
                &self.target,
                format!("bad file name `{name}` inside an artifact"),
            ));
        }
        if self.files.iter().any(|f| f.name == name) {
            return Err(SchemaError::invalid(
                &self.target,
                format!("file `{name}` written twice"),
            ));
        }
        Ok(())
    }

    /// Add a tensor as `name` (should end in `.npy`).
    pub fn write_tensor<T: NpyElement>(
        &mut self,
        name: &str,
        shape: &[usize],
        data: &[T],
    ) -> Result<()> {
        self.check_name(name)?;
        if shape.iter().product::<usize>() != data.len() {
            return Err(SchemaError::invalid(
                self.tmp.join(name),
                format!(
                    "data has {} elements, shape {:?} needs {}",
                    data.len(),
                    shape,
                    shape.iter().product::<usize>()
                ),
            ));
        }
        let bytes = encode_npy(shape, data);
        let p = self.tmp.join(name);
        fs::write(&p, &bytes).map_err(|e| SchemaError::io(&p, e))?;
        let mut h = blake3::Hasher::new();
        hash_update(&mut h, &bytes);
        self.files.push(FileEntry {
            name: name.to_string(),
            blake3: h.finalize().to_hex().to_string(),
            bytes: bytes.len() as u64,
            dtype: Some(T::DTYPE),
            shape: Some(shape.to_vec()),
        });
        Ok(())
    }

    /// Start streaming a tensor `name` of `shape` (see [`TensorStream`]).
    pub fn stream_tensor<T: NpyElement>(
        &mut self,
        name: &str,
        shape: &[usize],
    ) -> Result<TensorStream<T>> {
        use std::io::Write;
        self.check_name(name)?;
        let p = self.tmp.join(name);
        let left = shape
            .iter()
            .try_fold(1usize, |a, &s| a.checked_mul(s))
            .ok_or_else(|| SchemaError::invalid(&p, format!("shape {shape:?} overflows")))?;
        let header = crate::npy::npy_header(T::DTYPE, shape);
        let mut file = fs::File::create(&p).map_err(|e| SchemaError::io(&p, e))?;
        file.write_all(&header)
            .map_err(|e| SchemaError::io(&p, e))?;
        let mut hasher = blake3::Hasher::new();
        hasher.update(&header);
        self.streaming.push(name.to_string());
        // The manifest lists files in the order they were started; the entry is filled
        // in by `finish_stream`.
        self.files.push(FileEntry {
            name: name.to_string(),
            blake3: String::new(),
            bytes: 0,
            dtype: Some(T::DTYPE),
            shape: Some(shape.to_vec()),
        });
        Ok(TensorStream {
            name: name.to_string(),
            path: p,
            file,
            hasher,
            shape: shape.to_vec(),
            left,
            bytes: header.len() as u64,
            buf: Vec::new(),
            _t: std::marker::PhantomData,
        })
    }

    /// Finish a stream: every element must have been appended. The file joins the
    /// manifest with its hash, size, dtype and shape.
    pub fn finish_stream<T: NpyElement>(&mut self, s: TensorStream<T>) -> Result<()> {
        let Some(i) = self.streaming.iter().position(|n| *n == s.name) else {
            return Err(SchemaError::invalid(
                &s.path,
                "this stream does not belong to this artifact",
            ));
        };
        if s.left != 0 {
            return Err(SchemaError::invalid(
                &s.path,
                format!(
                    "stream ended {} elements short of shape {:?}",
                    s.left, s.shape
                ),
            ));
        }
        self.streaming.swap_remove(i);
        let entry = self
            .files
            .iter_mut()
            .find(|f| f.name == s.name)
            .expect("a started stream has its manifest entry");
        entry.blake3 = s.hasher.finalize().to_hex().to_string();
        entry.bytes = s.bytes;
        Ok(())
    }

    /// Add an arbitrary file.
    pub fn write_bytes(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        self.check_name(name)?;
        let p = self.tmp.join(name);
        fs::write(&p, bytes).map_err(|e| SchemaError::io(&p, e))?;
        let mut h = blake3::Hasher::new();
        hash_update(&mut h, bytes);
        self.files.push(FileEntry {
            name: name.to_string(),
            blake3: h.finalize().to_hex().to_string(),
            bytes: bytes.len() as u64,
            dtype: None,
            shape: None,
        });
        Ok(())
    }

    /// Add a JSON file.
    pub fn write_json<T: serde::Serialize>(&mut self, name: &str, value: &T) -> Result<()> {
        let mut b = serde_json::to_vec_pretty(value).map_err(|e| {
            SchemaError::invalid(self.tmp.join(name), format!("cannot serialize: {e}"))
        })?;
        b.push(b'\n');
        self.write_bytes(name, &b)
    }

    /// Add a file written by `f` into the staging path (for writers that need a path,
    /// such as an image encoder). The file is hashed after `f` returns.
    pub fn write_with<F>(&mut self, name: &str, f: F) -> Result<()>
    where
        F: FnOnce(&Path) -> std::result::Result<(), String>,
    {
        self.check_name(name)?;
        let p = self.tmp.join(name);
        f(&p).map_err(|reason| SchemaError::invalid(&p, reason))?;
        let bytes = fs::metadata(&p).map_err(|e| SchemaError::io(&p, e))?.len();
        self.files.push(FileEntry {
            name: name.to_string(),
            blake3: hash_file(&p)?,
            bytes,
            dtype: None,
            shape: None,
        });
        Ok(())
    }

    /// Write the manifest and move the artifact into place, replacing any previous one.
    pub fn commit(mut self) -> Result<Manifest> {
        if let Some(n) = self.streaming.first() {
            return Err(SchemaError::invalid(
                self.tmp.join(n),
                "tensor stream was started but not finished",
            ));
        }
        for req in self.kind.required_files() {
            if !self.files.iter().any(|f| f.name == *req) {
                return Err(SchemaError::invalid(
                    &self.target,
                    format!(
                        "artifact of kind `{}` is missing required file `{req}`",
                        self.kind
                    ),
                ));
            }
        }
        let manifest = Manifest {
            format: FORMAT.to_string(),
            kind: self.kind,
            schema_version: self.kind.current_version(),
            producer: self.producer.clone(),
            inputs: self.inputs.clone(),
            files: self.files.clone(),
            meta: self.meta.clone(),
        };
        let mpath = self.tmp.join(MANIFEST_FILE);
        let mut b = serde_json::to_vec_pretty(&manifest)
            .map_err(|e| SchemaError::invalid(&mpath, e.to_string()))?;
        b.push(b'\n');
        fs::write(&mpath, &b).map_err(|e| SchemaError::io(&mpath, e))?;
        // fsync files so that a crash after the rename never exposes empty files (in
        // parallel: the device queues the writes of many files at once).
        let mut paths = Vec::new();
        for f in fs::read_dir(&self.tmp).map_err(|e| SchemaError::io(&self.tmp, e))? {
            paths.push(f.map_err(|e| SchemaError::io(&self.tmp, e))?.path());
        }
        {
            use rayon::prelude::*;
            paths.par_iter().for_each(|p| {
                if let Ok(file) = fs::File::open(p) {
                    let _ = file.sync_all();
                }
            });
        }
        let backup = if self.target.exists() {
            let b = crate::atomic::temp_sibling(&self.target, "old");
            fs::rename(&self.target, &b).map_err(|e| SchemaError::io(&self.target, e))?;
            Some(b)
        } else {
            None
        };
        if let Err(e) = fs::rename(&self.tmp, &self.target) {
            if let Some(b) = &backup {
                let _ = fs::rename(b, &self.target);
            }
            return Err(SchemaError::io(&self.target, e));
        }
        self.committed = true;
        if let Some(b) = backup {
            let _ = fs::remove_dir_all(b);
        }
        Ok(manifest)
    }
}

impl Drop for ArtifactWriter {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;

    fn producer() -> Producer {
        Producer::new("test", "0.1.0", serde_json::json!({"b": 1, "a": [1, 2]}))
    }

    #[test]
    fn write_open_read() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("lat");
        let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[1, 2, 2, 2], &[0.5f32; 8])
            .unwrap();
        w.set_meta(serde_json::json!({"t": 3}));
        w.commit().unwrap();
        let a = Artifact::open(&t, ArtifactKind::Latents).unwrap();
        assert_eq!(a.read_f32("latents.npy").unwrap().shape, vec![1, 2, 2, 2]);
        assert_eq!(a.manifest.meta["t"], 3);
        // Only the artifact remains: no staging directories.
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
        let e = Artifact::open(&t, ArtifactKind::Views)
            .unwrap_err()
            .to_string();
        assert!(e.contains("expected an artifact of kind `views`"), "{e}");
    }

    #[test]
    fn tamper_is_detected() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("lat");
        let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[2], &[1f32, 2.]).unwrap();
        w.commit().unwrap();
        crate::npy::write_npy(&t.join("latents.npy"), &[2], &[1f32, 3.]).unwrap();
        let e = Artifact::open(&t, ArtifactKind::Latents)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("hash mismatch") && e.contains("latents.npy"),
            "{e}"
        );
    }

    #[test]
    fn dropped_writer_leaves_old_artifact_and_no_temp() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("lat");
        let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[1], &[1f32]).unwrap();
        w.commit().unwrap();
        let before = fs::read(t.join(MANIFEST_FILE)).unwrap();
        {
            let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
            w.write_tensor("latents.npy", &[1], &[9f32]).unwrap();
            // dropped without commit (a failing stage)
        }
        assert_eq!(fs::read(t.join(MANIFEST_FILE)).unwrap(), before);
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_non_artifact_directory_is_never_replaced() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("user");
        fs::create_dir(&t).unwrap();
        fs::write(t.join("precious.txt"), b"x").unwrap();
        let e = ArtifactWriter::create(&t, ArtifactKind::Latents, producer())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("refusing to replace") && e.contains("user"),
            "{e}"
        );
        assert!(t.join("precious.txt").is_file());
        // An empty directory is fine (e.g. created by a DAG runner).
        let empty = d.path().join("empty");
        fs::create_dir(&empty).unwrap();
        let mut w = ArtifactWriter::create(&empty, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[1], &[1f32]).unwrap();
        w.commit().unwrap();
    }

    #[test]
    fn missing_required_file_refused_at_commit() {
        let d = tempfile::tempdir().unwrap();
        let w =
            ArtifactWriter::create(&d.path().join("v"), ArtifactKind::Views, producer()).unwrap();
        let e = w.commit().unwrap_err().to_string();
        assert!(e.contains("rgb.npy"), "{e}");
    }

    #[test]
    fn streamed_tensor_equals_written_tensor() {
        let d = tempfile::tempdir().unwrap();
        // Larger than the 1 MiB threshold of the parallel hash.
        let data: Vec<f32> = (0..3 * 300_000).map(|i| (i as f32).sin()).collect();
        let whole = d.path().join("whole");
        let mut w = ArtifactWriter::create(&whole, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[3, 300_000], &data).unwrap();
        let a = w.commit().unwrap();
        let streamed = d.path().join("streamed");
        let mut w = ArtifactWriter::create(&streamed, ArtifactKind::Latents, producer()).unwrap();
        let mut s = w
            .stream_tensor::<f32>("latents.npy", &[3, 300_000])
            .unwrap();
        // Files written while the stream is open are listed after it.
        w.write_bytes("notes.txt", b"x").unwrap();
        for piece in data.chunks(400_000) {
            s.append(piece).unwrap();
        }
        assert_eq!(s.remaining(), 0);
        assert!(
            s.append(&[1.0])
                .unwrap_err()
                .to_string()
                .contains("1 more elements")
        );
        w.finish_stream(s).unwrap();
        let b = w.commit().unwrap();
        assert_eq!(a.files[..], b.files[..1]);
        assert_eq!(b.files[1].name, "notes.txt");
        assert_eq!(
            fs::read(whole.join("latents.npy")).unwrap(),
            fs::read(streamed.join("latents.npy")).unwrap()
        );
        assert_eq!(
            a.files[0].blake3,
            hash_file(&streamed.join("latents.npy")).unwrap()
        );
        let art = Artifact::open(&streamed, ArtifactKind::Latents).unwrap();
        let mut r = art.tensor_reader::<f32>("latents.npy").unwrap();
        let mut v = Vec::new();
        r.read_items(3, &mut v).unwrap();
        assert_eq!(v, data);
    }

    #[test]
    fn unfinished_or_short_streams_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("lat");
        let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
        let mut s = w.stream_tensor::<f32>("latents.npy", &[2, 2]).unwrap();
        // The name is reserved while streaming.
        assert!(w.write_tensor("latents.npy", &[1], &[0f32]).is_err());
        s.append(&[1.0, 2.0, 3.0]).unwrap();
        let e = w.finish_stream(s).unwrap_err().to_string();
        assert!(
            e.contains("1 elements short") && e.contains("latents.npy"),
            "{e}"
        );
        let e = w.commit().unwrap_err().to_string();
        assert!(
            e.contains("not finished") && e.contains("latents.npy"),
            "{e}"
        );
        // Nothing was put in place, no staging directory is left.
        assert!(!t.exists());
        assert_eq!(fs::read_dir(d.path()).unwrap().count(), 0);
    }

    #[test]
    fn params_hash_is_key_order_independent() {
        let a = Producer::new("s", "1", serde_json::json!({"x": 1, "y": 2}));
        let b = Producer::new("s", "1", serde_json::json!({"y": 2, "x": 1}));
        assert_eq!(a.params_hash, b.params_hash);
    }
}

/// Fixtures of every artifact kind at every schema version this build reads. They are
/// checked into `schemas/fixtures/v{N}/{kind}/` and must keep loading: a change that
/// breaks one is a change to the on-disk contract and needs a new schema version plus a
/// reader for the old one.
#[cfg(test)]
mod fixtures {
    use super::*;
    use crate::ArtifactKind;

    fn fixture_root() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
    }

    /// Small, fully deterministic content for each kind (version 1).
    fn write_v1(kind: ArtifactKind, dir: &Path) -> Result<Manifest> {
        let params = serde_json::json!({"fixture": true, "kind": kind.as_str()});
        let mut w = ArtifactWriter::create(dir, kind, Producer::new("fixture", "0.1.0", params))?;
        let ramp = |n: usize| (0..n).map(|i| i as f32 / n as f32).collect::<Vec<f32>>();
        let cams = serde_json::json!([{"id": 0, "img_name": "orbit_000", "width": 4, "height": 2,
            "position": [0.0, 0.0, -3.0], "rotation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            "fx": 4.0, "fy": 4.0}]);
        match kind {
            ArtifactKind::Views => {
                w.write_tensor("rgb.npy", &[1, 2, 4, 3], &ramp(24))?;
                w.write_tensor("depth.npy", &[1, 2, 4], &ramp(8))?;
                w.write_tensor("alpha.npy", &[1, 2, 4], &[1.0f32; 8])?;
                w.write_json("cameras.json", &cams)?;
            }
            ArtifactKind::Latents => w.write_tensor("latents.npy", &[1, 4, 1, 2], &ramp(8))?,
            ArtifactKind::NoisedLatents => {
                w.write_tensor("z_src.npy", &[1, 4, 1, 2], &ramp(8))?;
                w.write_tensor("z_tgt.npy", &[1, 4, 1, 2], &ramp(8))?;
                w.write_tensor("eps.npy", &[1, 4, 1, 2], &ramp(8))?;
                w.set_meta(serde_json::json!({"timestep": 501}));
            }
            ArtifactKind::Targets => {
                w.write_tensor("rgb.npy", &[1, 2, 4, 3], &ramp(24))?;
                w.write_json("cameras.json", &cams)?;
            }
            ArtifactKind::Scene => w.write_bytes(
                "scene.ply",
                b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nend_header\n",
            )?,
            ArtifactKind::Evaluation => {
                w.write_json("metrics.json", &serde_json::json!({"lpips": 0.25}))?
            }
            ArtifactKind::EvalReference => {
                w.write_json(
                    "reference.json",
                    &serde_json::json!({"gram_original": [0.5]}),
                )?;
                w.write_tensor("views_pool3.npy", &[1, 2], &ramp(2))?;
            }
            ArtifactKind::Selection => {
                w.write_tensor("weights.npy", &[4], &[0.0, 1.0, 0.5, 1.0])?;
                w.set_meta(serde_json::json!({"selected": 3, "gaussians": 4}));
            }
        }
        w.commit()
    }

    /// Regenerate the fixtures of the current version:
    /// `cargo test -p fantasystyle-schemas -- --ignored regenerate_fixtures`.
    #[test]
    #[ignore]
    fn regenerate_fixtures() {
        for kind in ArtifactKind::ALL {
            let dir = fixture_root()
                .join(format!("v{}", kind.current_version()))
                .join(kind.as_str());
            write_v1(kind, &dir).unwrap();
        }
    }

    #[test]
    fn every_kind_has_a_fixture_for_every_readable_version_and_it_loads() {
        for kind in ArtifactKind::ALL {
            for v in kind.readable_versions() {
                let dir = fixture_root().join(format!("v{v}")).join(kind.as_str());
                let a = Artifact::open(&dir, kind)
                    .unwrap_or_else(|e| panic!("fixture {}: {e}", dir.display()));
                assert_eq!(a.manifest.schema_version, *v);
                for f in &a.manifest.files {
                    if f.dtype == Some(crate::DType::F32) {
                        let t = a.read_f32(&f.name).unwrap();
                        assert_eq!(Some(&t.shape), f.shape.as_ref());
                    }
                }
            }
        }
    }

    #[test]
    fn fixtures_match_what_this_build_writes() {
        // The current version's fixture must be byte-identical to a fresh write: if this
        // fails, the writer changed the format without bumping the schema version.
        let d = tempfile::tempdir().unwrap();
        for kind in ArtifactKind::ALL {
            let fresh = d.path().join(kind.as_str());
            write_v1(kind, &fresh).unwrap();
            let fixture = fixture_root()
                .join(format!("v{}", kind.current_version()))
                .join(kind.as_str());
            for f in fs::read_dir(&fixture).unwrap() {
                let name = f.unwrap().file_name();
                assert_eq!(
                    fs::read(fresh.join(&name)).unwrap(),
                    fs::read(fixture.join(&name)).unwrap(),
                    "{kind}/{}",
                    name.to_string_lossy()
                );
            }
        }
    }

    #[test]
    fn a_future_version_is_refused_with_a_clear_message() {
        let d = tempfile::tempdir().unwrap();
        let dir = d.path().join("lat");
        write_v1(ArtifactKind::Latents, &dir).unwrap();
        let m = dir.join(MANIFEST_FILE);
        let text = fs::read_to_string(&m)
            .unwrap()
            .replace("\"schema_version\": 1", "\"schema_version\": 99");
        fs::write(&m, text).unwrap();
        let e = Artifact::open(&dir, ArtifactKind::Latents)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("schema version 99") && e.contains("manifest.json"),
            "{e}"
        );
    }
}

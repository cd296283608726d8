//! Writing an artifact directory.
//!
//! [`ArtifactWriter`] writes every file into a temporary sibling directory
//! (`.NAME.partial-PID-N`), then writes the manifest last and renames the directory
//! into place. If the stage fails or is killed, the temporary directory is left behind
//! or removed, and the previous artifact at the target path (if any) is untouched until
//! the final rename. Tensors are written whole or streamed piece by piece ([`TensorStream`]).

use super::hash::{hash_file, hash_path, hash_update};
use crate::manifest::FORMAT;
use crate::npy::{NpyElement, encode_npy};
use crate::{
    ArtifactKind, FileEntry, InputRef, MANIFEST_FILE, Manifest, Producer, Result, SchemaError,
};
use std::fs;
use std::path::{Path, PathBuf};

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

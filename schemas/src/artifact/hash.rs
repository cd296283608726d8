//! Content hashes (blake3, as hex) of files, of byte buffers and of directories: what
//! a manifest records for each of its files and what identifies an input.

use crate::{MANIFEST_FILE, Result, SchemaError};
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

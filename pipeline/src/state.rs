//! Staleness: a stage's current fingerprint (cmd, binary, deps, params) compared with
//! what the lock recorded, plus the presence and hashes of its outputs.
//!
//! A stage is up to date when the lock has an `ok` entry whose cmd, binary hash, dep
//! hashes and param hashes equal the current ones and every output exists with the
//! recorded hash, and every file an artifact output's manifest lists is still the file
//! the manifest describes. Anything else is a [`Reason`] to run it. Because outputs
//! are compared by content, an output replaced or half-written behind the runner's
//! back makes its stage stale, and a rerun that reproduces byte-identical outputs
//! leaves downstream stages up to date.
//!
//! Output integrity, cheaply (as DVC does): an artifact directory hashes as its
//! manifest, which lists each file's size and blake3; the lock keeps each file's size
//! and mtime as the runner saw them after the stage. A file whose size and mtime still
//! match is taken as unchanged; a missing file, or one of another size than the
//! manifest says, is broken without hashing; only a file whose mtime changed is
//! hashed and compared with the manifest.

use crate::dag::{Dag, Stage, is_value_dep};
use crate::lock::{Binary, Entry, FileStamp, Status};
use std::collections::{BTreeMap, HashMap};
use std::ffi::OsString;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a stage must run.
#[derive(Debug, Clone, PartialEq)]
pub enum Reason {
    NeverRun,
    LastRunFailed,
    Forced,
    ChangedCmd,
    ChangedBinary(String),
    ChangedDep(String),
    MissingDep(String),
    ChangedParam(String),
    MissingOutput(String),
    NewOutput(String),
    ChangedOutput(String),
    /// A file of an artifact output no longer matches the output's manifest.
    BrokenOutput {
        out: String,
        file: String,
        how: String,
    },
    /// An upstream stage will run first (used by `status` and `--dry-run`).
    Upstream(String),
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reason::NeverRun => write!(f, "never run"),
            Reason::LastRunFailed => write!(f, "last run failed"),
            Reason::Forced => write!(f, "forced"),
            Reason::ChangedCmd => write!(f, "changed cmd"),
            Reason::ChangedBinary(b) => write!(f, "changed binary {b}"),
            Reason::ChangedDep(d) => write!(f, "changed dep {d}"),
            Reason::MissingDep(d) => write!(f, "missing dep {d}"),
            Reason::ChangedParam(k) => write!(f, "changed params {k}"),
            Reason::MissingOutput(o) => write!(f, "missing output {o}"),
            Reason::NewOutput(o) => write!(f, "output {o} not recorded by the last run"),
            Reason::ChangedOutput(o) => write!(f, "output {o} modified since it was written"),
            Reason::BrokenOutput { out, file, how } => {
                write!(f, "output {out}: file {file} {how}")
            }
            Reason::Upstream(s) => write!(f, "upstream {s} is stale"),
        }
    }
}

/// What a stage would run with now.
#[derive(Debug, Clone, PartialEq)]
pub struct Fingerprint {
    pub cmd: String,
    pub binary: Binary,
    pub deps: BTreeMap<String, String>,
    pub params: BTreeMap<String, String>,
}

/// Hash marker of a path that does not exist.
pub const MISSING: &str = "missing";

/// Computes fingerprints; caches executable hashes (by path, size and mtime).
#[derive(Debug)]
pub struct Hasher {
    path_env: OsString,
    bins: HashMap<PathBuf, (u64, Option<std::time::SystemTime>, String)>,
}

impl Hasher {
    /// `path_env` is the PATH stages run with (see [`stage_path_env`]).
    pub fn new(path_env: OsString) -> Self {
        Hasher {
            path_env,
            bins: HashMap::new(),
        }
    }

    /// The current fingerprint of `stage`.
    pub fn fingerprint(&mut self, dag: &Dag, stage: &Stage) -> Fingerprint {
        let deps = stage
            .deps
            .iter()
            .map(|d| (d.clone(), hash_dep(dag, d)))
            .collect();
        let params = stage
            .params
            .iter()
            .map(|k| {
                let v = dag.params.get(k).cloned().unwrap_or_default();
                let c = fantasystyle_schemas::manifest::canonical_json(&v);
                (k.clone(), blake3::hash(c.as_bytes()).to_hex().to_string())
            })
            .collect();
        Fingerprint {
            cmd: stage.cmd(),
            binary: self.binary(&dag.workdir, stage.argv.first().map_or("", String::as_str)),
            deps,
            params,
        }
    }

    /// The executable the command's program (its first argument) resolves to, and its
    /// hash.
    pub fn binary(&mut self, dir: &Path, program: &str) -> Binary {
        let word = program.to_string();
        let Some(path) = resolve(dir, &word, &self.path_env) else {
            return Binary {
                path: word,
                blake3: "unresolved".into(),
            };
        };
        let meta = std::fs::metadata(&path).ok();
        let key = (
            meta.as_ref().map(|m| m.len()).unwrap_or(0),
            meta.as_ref().and_then(|m| m.modified().ok()),
        );
        if let Some((l, t, h)) = self.bins.get(&path)
            && (*l, *t) == key
        {
            return Binary {
                path: path.to_string_lossy().into_owned(),
                blake3: h.clone(),
            };
        }
        let h = hash_or_missing(&path);
        self.bins.insert(path.clone(), (key.0, key.1, h.clone()));
        Binary {
            path: path.to_string_lossy().into_owned(),
            blake3: h,
        }
    }
}

/// blake3 of a path (artifact dir: its manifest), or [`MISSING`].
pub fn hash_or_missing(p: &Path) -> String {
    if !p.exists() {
        return MISSING.into();
    }
    fantasystyle_schemas::hash_path(p).unwrap_or_else(|e| format!("unreadable: {e}"))
}

/// The hash of a dep: a value (`orbit:16`) by its text, a path by its content.
pub fn hash_dep(dag: &Dag, d: &str) -> String {
    if is_value_dep(d) {
        format!("value:{}", blake3::hash(d.as_bytes()).to_hex())
    } else {
        hash_or_missing(&dag.path(d))
    }
}

/// The stamps of the files an artifact output's manifest lists (empty for a plain
/// file or a directory without a manifest).
pub fn stamp_files(out: &Path) -> BTreeMap<String, FileStamp> {
    let Ok(a) = fantasystyle_schemas::Artifact::open_unverified(out) else {
        return BTreeMap::new();
    };
    a.manifest
        .files
        .iter()
        .filter_map(|f| FileStamp::of(&out.join(&f.name)).map(|s| (f.name.clone(), s)))
        .collect()
}

/// The files of artifact output `out` (at `dir`) that no longer match its manifest,
/// with how: missing, another size, or (size the same, mtime not) another blake3.
pub fn broken_files(out: &str, dir: &Path, recorded: &BTreeMap<String, FileStamp>) -> Vec<Reason> {
    let Ok(a) = fantasystyle_schemas::Artifact::open_unverified(dir) else {
        return vec![Reason::ChangedOutput(out.to_string())];
    };
    let mut r = Vec::new();
    let mut broken = |file: &str, how: String| {
        r.push(Reason::BrokenOutput {
            out: out.to_string(),
            file: file.to_string(),
            how,
        })
    };
    for f in &a.manifest.files {
        let p = dir.join(&f.name);
        let Some(now) = FileStamp::of(&p) else {
            broken(&f.name, "missing".into());
            continue;
        };
        if now.bytes < f.bytes {
            broken(
                &f.name,
                format!("truncated ({} of {} bytes)", now.bytes, f.bytes),
            );
        } else if now.bytes != f.bytes {
            broken(
                &f.name,
                format!(
                    "changed size ({} bytes, manifest says {})",
                    now.bytes, f.bytes
                ),
            );
        } else if recorded.get(&f.name) != Some(&now) {
            match fantasystyle_schemas::hash_file(&p) {
                Ok(h) if h == f.blake3 => {}
                Ok(_) => broken(
                    &f.name,
                    "changed (its blake3 differs from the manifest's)".into(),
                ),
                Err(e) => broken(&f.name, format!("unreadable ({e})")),
            }
        }
    }
    r
}

/// The PATH stage commands run with: the directory of the running `pipeline`
/// executable first (so sibling stage binaries in `target/<profile>/` are found), then
/// the inherited PATH.
pub fn stage_path_env() -> OsString {
    let mut dirs: Vec<PathBuf> = Vec::new();
    if let Some(d) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_path_buf))
    {
        dirs.push(d);
    }
    if let Some(p) = std::env::var_os("PATH") {
        dirs.extend(std::env::split_paths(&p));
    }
    std::env::join_paths(dirs).unwrap_or_default()
}

/// The executable `word` names: a path (with a `/`, relative to `dir`) or the first
/// executable of that name on `path_env`.
pub fn resolve(dir: &Path, word: &str, path_env: &OsString) -> Option<PathBuf> {
    if word.is_empty() {
        return None;
    }
    if word.contains('/') {
        let p = dir.join(word);
        return p.is_file().then_some(p);
    }
    std::env::split_paths(path_env)
        .map(|d| d.join(word))
        .find(|p| is_executable(p))
}

fn is_executable(p: &Path) -> bool {
    use std::os::unix::fs::PermissionsExt;
    std::fs::metadata(p)
        .map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
        .unwrap_or(false)
}

/// Reasons `stage` must run given its current fingerprint and its lock entry; empty
/// when it is up to date.
pub fn reasons(dag: &Dag, stage: &Stage, fp: &Fingerprint, entry: Option<&Entry>) -> Vec<Reason> {
    let mut r = Vec::new();
    for (d, h) in &fp.deps {
        if h == MISSING {
            r.push(Reason::MissingDep(d.clone()));
        }
    }
    let Some(e) = entry else {
        r.push(Reason::NeverRun);
        return r;
    };
    if e.status != Status::Ok {
        r.push(Reason::LastRunFailed);
        return r;
    }
    if e.cmd != fp.cmd {
        r.push(Reason::ChangedCmd);
    }
    if e.binary.blake3 != fp.binary.blake3 {
        r.push(Reason::ChangedBinary(fp.binary.path.clone()));
    }
    for (d, h) in &fp.deps {
        if h != MISSING && e.deps.get(d) != Some(h) {
            r.push(Reason::ChangedDep(d.clone()));
        }
    }
    for (k, h) in &fp.params {
        if e.params.get(k) != Some(h) {
            r.push(Reason::ChangedParam(k.clone()));
        }
    }
    for o in &stage.outs {
        let p = dag.path(o);
        if !p.exists() {
            r.push(Reason::MissingOutput(o.clone()));
        } else if !e.outs.contains_key(o) {
            r.push(Reason::NewOutput(o.clone()));
        } else if e.outs.get(o) != Some(&hash_or_missing(&p)) {
            r.push(Reason::ChangedOutput(o.clone()));
        } else if let Some(stamps) = e.files.get(o) {
            r.extend(broken_files(o, &p, stamps));
        }
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resolves_sh_on_path_and_hashes_it() {
        let mut h = Hasher::new(std::env::var_os("PATH").unwrap());
        let b = h.binary(Path::new("."), "sh");
        assert!(b.path.ends_with("/sh") && b.blake3.len() == 64, "{b:?}");
        let b = h.binary(Path::new("."), "no-such-binary-xyz");
        assert_eq!(b.blake3, "unresolved");
    }
}

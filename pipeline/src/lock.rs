//! The lock file (`<dag stem>.lock` next to the DAG, JSON): what each expanded stage
//! last ran with and produced, as blake3 hashes, so that a later run can tell what is
//! up to date. Written atomically (temporary sibling + rename) after every stage, so
//! a killed runner leaves either the previous lock or the new one, never a torn one.
//!
//! Per stage: the substituted `cmd`; the stage binary (resolved path of the command's
//! first word and the blake3 of that executable); every dep's hash (an artifact
//! directory hashes as its manifest, see `fantasystyle_schemas::hash_path`); every
//! tracked param's hash (blake3 of its canonical JSON); every output's hash; `status`
//! (`ok` or `failed`), wall time and the log file; and, per artifact output, the size
//! and modification time of each file its manifest lists (see [`FileStamp`]), so that
//! a file changed, truncated or deleted behind the runner's back is noticed cheaply.
//! `last_run` records the wall time of
//! the most recent `pipeline run` as a whole, for `pipeline report`.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Version of the lock file format.
pub const LOCK_VERSION: u32 = 1;

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lock {
    pub version: u32,
    pub stages: BTreeMap<String, Entry>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_run: Option<RunRecord>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Ok,
    Failed,
}

/// The executable a stage command runs.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Binary {
    /// Resolved path, or the bare word when it could not be resolved.
    pub path: String,
    /// blake3 of the executable, or `unresolved`.
    pub blake3: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    pub cmd: String,
    pub binary: Binary,
    pub deps: BTreeMap<String, String>,
    pub params: BTreeMap<String, String>,
    pub outs: BTreeMap<String, String>,
    pub status: Status,
    /// Wall time of the stage process, seconds.
    pub duration_s: f64,
    /// Exit code (None when killed by a signal).
    #[serde(default)]
    pub exit_code: Option<i32>,
    /// Seconds since the Unix epoch when the stage finished.
    pub finished_unix: u64,
    /// Log file, relative to the DAG directory.
    pub log: String,
    /// Timing the stage reported through `PIPELINE_TIMING_FILE` (seconds by phase,
    /// e.g. `load_s`, `compute_s`, `io_s`); empty when it reported none.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub timing: BTreeMap<String, f64>,
    /// Per artifact output, its manifest's files as they were when the stage finished
    /// (absent for plain-file outputs and for locks written before this field).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub files: BTreeMap<String, BTreeMap<String, FileStamp>>,
}

/// A file of an artifact output as the runner last saw it: size and modification
/// time (nanoseconds since the Unix epoch). When both still match, the file is taken
/// as unchanged without hashing it (the manifest holds its blake3); when either
/// differs, it is hashed and compared with the manifest (as DVC does with its cache).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileStamp {
    pub bytes: u64,
    pub mtime_ns: u64,
}

impl FileStamp {
    /// The stamp of `p` now, if it is a readable file.
    pub fn of(p: &Path) -> Option<FileStamp> {
        let m = std::fs::metadata(p).ok().filter(|m| m.is_file())?;
        let mtime_ns = m
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos() as u64);
        Some(FileStamp {
            bytes: m.len(),
            mtime_ns,
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunRecord {
    /// Wall time of the whole `pipeline run`, seconds.
    pub wall_s: f64,
    /// Stages it ran.
    pub ran: Vec<String>,
    pub jobs: usize,
    pub finished_unix: u64,
}

impl Lock {
    /// Read a lock file; a missing file is an empty lock.
    pub fn read(path: &Path) -> Result<Lock> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Ok(Lock {
                    version: LOCK_VERSION,
                    ..Lock::default()
                });
            }
            Err(e) => return Err(Error::io(path, e)),
        };
        let lock: Lock = serde_json::from_str(&text).map_err(|e| Error::Lock {
            path: path.to_path_buf(),
            reason: format!("not a valid lock file ({e})"),
        })?;
        if lock.version != LOCK_VERSION {
            return Err(Error::Lock {
                path: path.to_path_buf(),
                reason: format!(
                    "lock file version {} (this build reads {LOCK_VERSION})",
                    lock.version
                ),
            });
        }
        Ok(lock)
    }

    /// Write atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        Ok(fantasystyle_schemas::atomic_write_json(path, self)?)
    }
}

/// Seconds since the Unix epoch.
pub fn now_unix() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.lock");
        let mut l = Lock::read(&p).unwrap();
        assert!(l.stages.is_empty());
        l.stages.insert(
            "a".into(),
            Entry {
                cmd: "a".into(),
                binary: Binary {
                    path: "/bin/a".into(),
                    blake3: "h".into(),
                },
                deps: BTreeMap::new(),
                params: BTreeMap::new(),
                outs: BTreeMap::new(),
                status: Status::Ok,
                duration_s: 1.5,
                exit_code: Some(0),
                finished_unix: 1,
                log: ".pipeline/logs/a.log".into(),
                timing: BTreeMap::new(),
                files: BTreeMap::new(),
            },
        );
        l.write(&p).unwrap();
        assert_eq!(Lock::read(&p).unwrap().stages["a"], l.stages["a"]);
        std::fs::write(&p, "{\"version\": 1, \"stages\": {}, \"extra\": 1}").unwrap();
        let e = Lock::read(&p).unwrap_err().to_string();
        assert!(
            e.contains("not a valid lock file") && e.contains("extra"),
            "{e}"
        );
    }
}

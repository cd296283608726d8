//! The crate's one error type. Every fallible function of the runner returns
//! [`Result`]; `main` maps these errors to exit code 2 (a DAG or usage problem; a
//! failed stage is exit code 1) and prints them as they display: the file (and line, for DAG problems)
//! first, then the problem.

use std::path::PathBuf;

pub use crate::dag::DagError;

/// What can go wrong in the runner (stage failures are not errors: they are reported
/// in the run's summary).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Problems found in a DAG file, each with its line.
    #[error(transparent)]
    Dag(#[from] DagError),
    /// A `--set NAME=VALUE` (or another command-line value) that cannot be used.
    #[error("{0}")]
    Usage(String),
    /// A target named on the command line that the DAG does not have.
    #[error("no stage named `{name}` in {}", file.display())]
    NoSuchStage { name: String, file: PathBuf },
    /// A file or directory that could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A lock file that cannot be used as it is.
    #[error("{}: {reason}; delete it to rebuild everything", path.display())]
    Lock { path: PathBuf, reason: String },
    /// Another runner holds the DAG's work directory.
    #[error(
        "another pipeline run (pid {pid}) is using this DAG ({}); wait for it or remove the file if it is stale",
        path.display()
    )]
    Busy { pid: String, path: PathBuf },
    /// An artifact (or `.npy`) that cannot be read or written.
    #[error(transparent)]
    Schema(#[from] fantasystyle_schemas::SchemaError),
    /// A DAG that cannot be exported as asked (to Snakemake), with the reason.
    #[error("{0}")]
    Export(String),
    /// A tensor that `inspect` cannot show as asked.
    #[error("{0}")]
    Inspect(String),
}

impl Error {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

/// The crate's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

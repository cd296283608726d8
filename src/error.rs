//! The library's error type and its mapping to process exit codes.
//!
//! Module-level errors convert into [`Error`]; the stage binaries map it to an exit code
//! with [`Error::exit_code`]: 2 for bad input (malformed files, wrong shapes, NaN,
//! invalid parameters), 3 for a missing external resource (onnxruntime library, model
//! weights), 4 for I/O failures such as an unwritable output, 1 for anything else.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Bad input data: names the file and the problem.
    #[error("{path}: {reason}")]
    Input { path: PathBuf, reason: String },
    /// Invalid parameter values.
    #[error("invalid parameter: {0}")]
    Param(String),
    /// A resource that set-up should have installed is missing.
    #[error("{0}")]
    Missing(String),
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The on-disk contract (artifacts, manifests, .npy).
    #[error(transparent)]
    Schema(#[from] fantasystyle_schemas::SchemaError),
    /// onnxruntime failed.
    #[error("onnxruntime: {0}")]
    Onnx(String),
    /// Anything else.
    #[error("{0}")]
    Other(String),
}

impl Error {
    pub fn input(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::Input {
            path: path.into(),
            reason: reason.into(),
        }
    }
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
    pub fn param(reason: impl Into<String>) -> Self {
        Error::Param(reason.into())
    }

    /// Process exit code for this error (see module docs).
    pub fn exit_code(&self) -> u8 {
        use fantasystyle_schemas::SchemaError as S;
        match self {
            Error::Input { .. } | Error::Param(_) => 2,
            Error::Schema(S::Io { .. }) => 4,
            Error::Schema(_) => 2,
            Error::Missing(_) => 3,
            Error::Io { .. } => 4,
            Error::Onnx(_) | Error::Other(_) => 1,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

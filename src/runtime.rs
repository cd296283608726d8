//! The onnxruntime environment: one per process, shared by every session.
//!
//! `ort` is built with `load-dynamic`: the shared library `libonnxruntime.so.1.31.1` is
//! loaded at run time. [`library_path`] looks for it, in order, at
//! `$FANTASYSTYLE_ORT_LIB`, `$ORT_DYLIB_PATH`, `vendor/onnxruntime/` beside the running
//! executable's workspace, and `vendor/onnxruntime/` of the source tree this was built
//! from. When it is absent the error says which command installs it.

use crate::{Error, Result};
use ort::environment::Environment;
use ort::session::Session;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// File name of the onnxruntime shared library we load.
pub const ORT_LIB_NAME: &str = "libonnxruntime.so.1.31.1";

static ENV: OnceLock<std::result::Result<Environment, String>> = OnceLock::new();

/// Where the onnxruntime shared library is, or an error naming the set-up command.
pub fn library_path() -> Result<PathBuf> {
    for var in ["FANTASYSTYLE_ORT_LIB", "ORT_DYLIB_PATH"] {
        if let Ok(p) = std::env::var(var) {
            let p = PathBuf::from(p);
            if p.is_file() {
                return Ok(p);
            }
            return Err(Error::Missing(format!(
                "${var} points to {}, which does not exist",
                p.display()
            )));
        }
    }
    let mut candidates = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        // target/<profile>/<bin> or target/<profile>/deps/<test>: walk up to the workspace.
        for anc in exe.ancestors().skip(1).take(5) {
            candidates.push(anc.join("vendor/onnxruntime").join(ORT_LIB_NAME));
        }
    }
    candidates.push(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("vendor/onnxruntime")
            .join(ORT_LIB_NAME),
    );
    if let Some(p) = candidates.iter().find(|p| p.is_file()) {
        return Ok(p.clone());
    }
    Err(Error::Missing(format!(
        "onnxruntime shared library {ORT_LIB_NAME} not found (looked in $FANTASYSTYLE_ORT_LIB, \
         $ORT_DYLIB_PATH and {}); run `scripts/setup.sh` to install it into vendor/onnxruntime/",
        candidates
            .last()
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    )))
}

/// The process-wide onnxruntime environment, created on first use.
pub fn environment() -> Result<&'static Environment> {
    let r = ENV.get_or_init(|| {
        let lib = library_path().map_err(|e| e.to_string())?;
        ort::init_from(&lib)
            .map_err(|e| format!("loading {}: {e}", lib.display()))?
            .with_name("fantasystyle")
            .with_telemetry(false)
            .build()
            .map_err(|e| format!("creating the onnxruntime environment: {e}"))
    });
    match r {
        Ok(env) => Ok(env),
        Err(msg) if msg.contains("not found") || msg.contains("does not exist") => {
            Err(Error::Missing(msg.clone()))
        }
        Err(msg) => Err(Error::Onnx(msg.clone())),
    }
}

/// onnxruntime's graph optimisation level (applied when a session is created).
///
/// `Basic`: constant folding and redundant-node removal; `Extended`: adds operator
/// fusions (e.g. Conv+Add+Relu); `All` (the default): adds layout optimisations such as
/// NCHWc convolutions, the fastest on CPU. `Disable` runs the graph as written (useful
/// to compare against a reference).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Optimization {
    Disable,
    Basic,
    Extended,
    #[default]
    All,
}

/// How sessions are created.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SessionConfig {
    /// Intra-op threads (0 = onnxruntime's default: one per physical core).
    pub threads: usize,
    pub optimization: Optimization,
}

/// Load an ONNX graph into a session with `threads` intra-op threads (0 = onnxruntime's
/// default). Missing and corrupt files give an error naming the file.
pub fn load_session(path: &Path, threads: usize) -> Result<Session> {
    load_session_with(
        path,
        &SessionConfig {
            threads,
            ..Default::default()
        },
    )
}

/// Load an ONNX graph with explicit session options.
pub fn load_session_with(path: &Path, cfg: &SessionConfig) -> Result<Session> {
    use ort::session::builder::GraphOptimizationLevel as L;
    if !path.is_file() {
        return Err(Error::input(path, "ONNX graph not found"));
    }
    let env = environment()?;
    let mut b = Session::builder(env).map_err(|e| Error::Onnx(e.to_string()))?;
    if cfg.threads > 0 {
        b = b
            .with_intra_threads(cfg.threads)
            .map_err(|e| Error::Onnx(e.to_string()))?;
    }
    let level = match cfg.optimization {
        Optimization::Disable => L::Disable,
        Optimization::Basic => L::Level1,
        Optimization::Extended => L::Level2,
        Optimization::All => L::All,
    };
    b = b
        .with_optimization_level(level)
        .map_err(|e| Error::Onnx(e.to_string()))?;
    b.commit_from_file(path)
        .map_err(|e| Error::input(path, format!("cannot load ONNX graph: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrupt_graph_is_a_clean_error() {
        if library_path().is_err() {
            eprintln!("SKIPPED: onnxruntime not installed (scripts/setup.sh)");
            return;
        }
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("bad.onnx");
        std::fs::write(&p, b"this is not protobuf").unwrap();
        let e = load_session(&p, 1).unwrap_err().to_string();
        assert!(e.contains("bad.onnx") && e.contains("cannot load"), "{e}");
        let e = load_session(&d.path().join("none.onnx"), 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.onnx") && e.contains("not found"), "{e}");
    }
}

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

pub mod graph;

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

/// Where sessions run: onnxruntime's execution providers.
///
/// `cpu` is the default and what the set-up library has. `cuda[:N]` (NVIDIA GPU N,
/// default 0) and `tensorrt[:N]` (TensorRT on GPU N, with CUDA for what TensorRT does not
/// take) need onnxruntime's GPU build: its `libonnxruntime.so.1.31.1` with
/// `libonnxruntime_providers_shared.so` and `libonnxruntime_providers_cuda.so` (and
/// `_tensorrt.so`) beside it, pointed to by `$FANTASYSTYLE_ORT_LIB`, plus the CUDA and
/// cuDNN (and TensorRT) libraries that build was made for. A provider that the library
/// lacks, or that cannot start (no device, missing CUDA libraries), is an error, never
/// a silent fall back to the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Device {
    #[default]
    Cpu,
    Cuda(u32),
    TensorRt(u32),
}

impl std::str::FromStr for Device {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let (kind, id) = match s.split_once(':') {
            Some((k, n)) => (
                k,
                Some(
                    n.parse::<u32>()
                        .map_err(|_| format!("device `{s}`: `{n}` is not a device number"))?,
                ),
            ),
            None => (s, None),
        };
        match (kind, id) {
            ("cpu", None) => Ok(Device::Cpu),
            ("cuda", id) => Ok(Device::Cuda(id.unwrap_or(0))),
            ("tensorrt", id) => Ok(Device::TensorRt(id.unwrap_or(0))),
            _ => Err(format!(
                "unknown device `{s}`: expected cpu, cuda[:N] or tensorrt[:N]"
            )),
        }
    }
}

impl std::fmt::Display for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Device::Cpu => write!(f, "cpu"),
            Device::Cuda(n) => write!(f, "cuda:{n}"),
            Device::TensorRt(n) => write!(f, "tensorrt:{n}"),
        }
    }
}

/// Register `device`'s execution provider(s) on `b`, or say why it cannot run there.
fn with_device(
    b: ort::session::builder::SessionBuilder,
    device: Device,
) -> Result<ort::session::builder::SessionBuilder> {
    use ort::ep::{self, ExecutionProvider};
    let lib = library_path()
        .map(|p| p.display().to_string())
        .unwrap_or_default();
    let (name, eps) = match device {
        Device::Cpu => return Ok(b),
        Device::Cuda(id) => (
            ep::CUDA::NAME,
            vec![ep::CUDA::default().with_device_id(id as i32).build()],
        ),
        Device::TensorRt(id) => (
            ep::TensorRT::NAME,
            vec![
                ep::TensorRT::default().with_device_id(id as i32).build(),
                ep::CUDA::default().with_device_id(id as i32).build(),
            ],
        ),
    };
    let available = |n: &str| match n {
        _ if n == ep::CUDA::NAME => ep::CUDA::is_available(),
        _ => ep::TensorRT::is_available(),
    };
    for n in std::iter::once(name).chain((name != ep::CUDA::NAME).then_some(ep::CUDA::NAME)) {
        if !available(n).map_err(|e| Error::Onnx(e.to_string()))? {
            return Err(Error::Missing(format!(
                "--device {device}: the onnxruntime library {lib} has no {n} (it is a CPU \
                 build). Install onnxruntime's GPU build 1.31 (libonnxruntime.so.1.31.1 with \
                 libonnxruntime_providers_shared.so and libonnxruntime_providers_cuda.so \
                 beside it) and set FANTASYSTYLE_ORT_LIB to it, or use --device cpu"
            )));
        }
    }
    let eps: Vec<_> = eps.into_iter().map(|e| e.error_on_failure()).collect();
    b.with_execution_providers(eps).map_err(|e| {
        Error::Missing(format!(
            "--device {device}: onnxruntime ({lib}) could not start {name}: {e} (is there an \
             NVIDIA GPU {}, and are the CUDA 12 / cuDNN 9 libraries onnxruntime needs on the \
             library path?)",
            match device {
                Device::Cuda(n) | Device::TensorRt(n) => n,
                Device::Cpu => 0,
            }
        ))
    })
}

/// How sessions are created.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SessionConfig {
    /// Intra-op threads (0 = onnxruntime's default: one per physical core).
    pub threads: usize,
    pub optimization: Optimization,
    /// Execution provider.
    pub device: Device,
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
    if !path.is_file() {
        return Err(Error::input(path, "ONNX graph not found"));
    }
    builder(cfg)?
        .commit_from_file(path)
        .map_err(|e| Error::input(path, format!("cannot load ONNX graph: {e}")))
}

/// A session for a graph built in memory with onnxruntime's model editor (`what` names it
/// in errors), with the same session options as [`load_session_with`].
pub fn session_from_model(
    model: ort::editor::Model,
    cfg: &SessionConfig,
    what: &str,
) -> Result<Session> {
    model
        .into_session(&builder(cfg)?)
        .map_err(|e| Error::Onnx(format!("{what}: cannot create the session: {e}")))
}

/// A session builder with `cfg`'s options.
fn builder(cfg: &SessionConfig) -> Result<ort::session::builder::SessionBuilder> {
    use ort::session::builder::GraphOptimizationLevel as L;
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
    // onnxruntime's pool threads spin between operators by default; here they would
    // burn the cores that rayon's workers (rendering, the colour step, other sessions
    // run side by side) and other processes need.
    b = b
        .with_intra_op_spinning(false)
        .map_err(|e| Error::Onnx(e.to_string()))?;
    b = b
        .with_inter_op_spinning(false)
        .map_err(|e| Error::Onnx(e.to_string()))?;
    with_device(b, cfg.device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corrupt_graph_is_a_clean_error() {
        if let Err(e) = library_path() {
            // Under CI set-up has installed it: a missing library must not pass as green.
            let ci = std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"));
            assert!(!ci, "missing under CI: {e}");
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

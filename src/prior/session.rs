//! ONNX sessions of the priors, loaded and checked against what we will feed: the one
//! input/output check of the crate, shared by the ONNX diffusion prior
//! ([`super::onnx`]) and the 2D stylizer ([`super::stylizer`]).
//!
//! [`Graph::check`] requires each named input or output to exist, floating-point I/O to
//! be float32, ranks and static dimensions to agree with what we feed;
//! [`Graph::check_all_fed`] refuses a graph with inputs we would not feed. Errors name
//! the file, the graph and the input. [`LazyGraph`] loads (and checks) on first use.

use super::manifest::ModelDir;
use crate::runtime::{SessionConfig, load_session_with};
use crate::{Error, Result};
use ndarray::{Array, ArrayD, IxDyn};
use ort::session::{Session, SessionInputValue};
use ort::value::{Tensor, TensorElementType, ValueType};
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// One ONNX session with the name it has in the manifest.
pub struct Graph {
    pub name: &'static str,
    pub file: PathBuf,
    pub session: Session,
}

/// What we require of one input or output.
#[derive(Debug, Clone, Copy)]
pub enum Kind {
    /// Float32 tensor of one of these ranks, with these static dims (axis, value).
    F32(&'static [usize]),
    /// The timestep: int64 or float32, rank 0 or 1.
    Timestep,
    /// Int64 tensor of one of these ranks (token ids).
    I64(&'static [usize]),
}

impl Graph {
    /// Load `file` as graph `name` of the model.
    pub fn load(
        md: &ModelDir,
        name: &'static str,
        file: &str,
        cfg: &SessionConfig,
    ) -> Result<Self> {
        Self::open(md.file(file), name, cfg)
    }

    /// Load the graph at `path`, called `name` in errors.
    pub fn open(path: PathBuf, name: &'static str, cfg: &SessionConfig) -> Result<Self> {
        let session = load_session_with(&path, cfg).map_err(|e| match e {
            Error::Input { path, reason } => Error::Input {
                path,
                reason: format!("graph `{name}`: {reason}"),
            },
            e => e,
        })?;
        Ok(Graph {
            name,
            file: path,
            session,
        })
    }

    pub(crate) fn err(&self, reason: impl std::fmt::Display) -> Error {
        Error::input(&self.file, format!("graph `{}`: {reason}", self.name))
    }

    fn shape_of<'a>(
        &self,
        io: &str,
        dtype: &'a ValueType,
    ) -> Result<(TensorElementType, &'a [i64])> {
        match dtype {
            ValueType::Tensor { ty, shape, .. } => Ok((*ty, shape)),
            other => Err(self.err(format_args!("{io} is not a tensor ({other:?})"))),
        }
    }

    /// Check input (or output, `output = true`) `name` against `kind` and static dims
    /// `dims` (axis, expected value; checked only where the graph's dim is static).
    pub fn check(
        &self,
        output: bool,
        name: &str,
        kind: Kind,
        dims: &[(usize, usize)],
    ) -> Result<()> {
        let what = if output { "output" } else { "input" };
        let list = if output {
            self.session.outputs()
        } else {
            self.session.inputs()
        };
        let Some(o) = list.iter().find(|o| o.name() == name) else {
            let names: Vec<&str> = list.iter().map(|o| o.name()).collect();
            return Err(self.err(format_args!(
                "the manifest names {what} `{name}`, the graph has no such {what} (it has {names:?})"
            )));
        };
        let (ty, shape) = self.shape_of(&format!("{what} `{name}`"), o.dtype())?;
        let (ok_ty, ranks): (bool, &[usize]) = match kind {
            Kind::F32(r) => (ty == TensorElementType::Float32, r),
            Kind::Timestep => (
                matches!(ty, TensorElementType::Int64 | TensorElementType::Float32),
                &[0, 1],
            ),
            Kind::I64(r) => (ty == TensorElementType::Int64, r),
        };
        if !ok_ty {
            return Err(self.err(format_args!(
                "{what} `{name}` has element type {ty:?}; fantasystyle feeds {} (fp16 models \
                 must keep float32 I/O: re-export with scripts/export_models.py)",
                match kind {
                    Kind::Timestep => "int64 or float32",
                    Kind::I64(_) => "int64",
                    Kind::F32(_) => "float32",
                }
            )));
        }
        if !ranks.contains(&shape.len()) {
            return Err(self.err(format_args!(
                "{what} `{name}` has rank {} (shape {shape:?}), expected rank {}",
                shape.len(),
                ranks
                    .iter()
                    .map(|r| r.to_string())
                    .collect::<Vec<_>>()
                    .join(" or ")
            )));
        }
        for &(axis, want) in dims {
            if let Some(&d) = shape.get(axis)
                && d >= 0
                && d as usize != want
            {
                return Err(self.err(format_args!(
                    "{what} `{name}` has dimension {axis} = {d} (shape {shape:?}), expected {want}"
                )));
            }
        }
        Ok(())
    }

    /// Error if the graph has inputs the manifest does not name (we could not feed them).
    pub fn check_all_fed(&self, fed: &[&str]) -> Result<()> {
        for i in self.session.inputs() {
            if !fed.contains(&i.name()) {
                return Err(self.err(format_args!(
                    "input `{}` is not named in the manifest, so it cannot be fed",
                    i.name()
                )));
            }
        }
        Ok(())
    }

    /// Static shape of an input (`-1` for dynamic dims), if it exists.
    pub fn input_shape(&self, name: &str) -> Option<Vec<i64>> {
        let o = self.session.inputs().iter().find(|o| o.name() == name)?;
        match o.dtype() {
            ValueType::Tensor { shape, .. } => Some(shape.to_vec()),
            _ => None,
        }
    }

    fn input_type(&self, name: &str) -> Option<TensorElementType> {
        let o = self.session.inputs().iter().find(|o| o.name() == name)?;
        match o.dtype() {
            ValueType::Tensor { ty, .. } => Some(*ty),
            _ => None,
        }
    }

    /// The timestep tensor this graph wants for a batch of `batch`.
    pub fn timestep_value(
        &self,
        name: &str,
        t: usize,
        batch: usize,
    ) -> Result<SessionInputValue<'static>> {
        let shape = self.input_shape(name).unwrap_or_else(|| vec![-1]);
        let dims: Vec<usize> = match shape.as_slice() {
            [] => vec![],
            [1] => vec![1],
            _ => vec![batch],
        };
        let n = dims.iter().product::<usize>();
        let v: SessionInputValue<'static> = match self.input_type(name) {
            Some(TensorElementType::Float32) => Tensor::from_array((dims, vec![t as f32; n]))
                .map_err(|e| self.err(e))?
                .into(),
            _ => Tensor::from_array((dims, vec![t as i64; n]))
                .map_err(|e| self.err(e))?
                .into(),
        };
        Ok(v)
    }

    /// Run with named inputs; return the named outputs as f32 arrays.
    pub fn run(
        &mut self,
        inputs: Vec<(Cow<'static, str>, SessionInputValue<'static>)>,
        outputs: &[&str],
    ) -> Result<Vec<ArrayD<f32>>> {
        let (name, file) = (self.name, self.file.clone());
        let err = |r: String| Error::Onnx(format!("graph `{name}` ({}): {r}", file.display()));
        let out = crate::timing::phase(name, || self.session.run(inputs))
            .map_err(|e| err(e.to_string()))?;
        outputs
            .iter()
            .map(|o| {
                let v = out.get(*o).ok_or_else(|| err(format!("no output `{o}`")))?;
                let (shape, data) = v
                    .try_extract_tensor::<f32>()
                    .map_err(|e| err(format!("output `{o}`: {e}")))?;
                let dims: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
                ArrayD::from_shape_vec(IxDyn(&dims), data.to_vec())
                    .map_err(|e| err(format!("output `{o}`: {e}")))
            })
            .collect()
    }
}

/// One check [`LazyGraph`] runs on loading: (output?, name, kind, static dims).
type Check = (bool, String, Kind, Vec<(usize, usize)>);

/// A graph loaded, and checked, on first use: a stage that never runs it never pays for
/// loading it (the stylizer's pixel-space VAE is the identity, so `encode-latents` loads
/// none of its graphs).
pub struct LazyGraph {
    path: PathBuf,
    name: &'static str,
    cfg: SessionConfig,
    checks: Vec<Check>,
    graph: Option<Graph>,
}

impl LazyGraph {
    /// The graph at `path` (which must exist now), called `name` in errors.
    pub fn new(path: PathBuf, name: &'static str, cfg: SessionConfig) -> Result<Self> {
        if !path.is_file() {
            return Err(Error::input(
                &path,
                format!("graph `{name}`: ONNX graph named by the model manifest not found"),
            ));
        }
        // The environment (and the onnxruntime library) must exist before any tensor is
        // made, sessions or not: ort would otherwise look for a library by default name.
        crate::runtime::environment()?;
        Ok(LazyGraph {
            path,
            name,
            cfg,
            checks: Vec::new(),
            graph: None,
        })
    }

    /// Require input (or output, `output = true`) `io` to pass [`Graph::check`] when the
    /// graph is loaded; the inputs named this way must be all the graph has.
    pub fn expect(mut self, output: bool, io: &str, kind: Kind, dims: &[(usize, usize)]) -> Self {
        self.checks
            .push((output, io.to_string(), kind, dims.to_vec()));
        self
    }

    /// An unloaded copy with the same checks and session options `cfg` (for one more
    /// session of the same graph, e.g. one per worker thread).
    pub fn with_config(&self, cfg: SessionConfig) -> Self {
        LazyGraph {
            path: self.path.clone(),
            name: self.name,
            cfg,
            checks: self.checks.clone(),
            graph: None,
        }
    }

    /// The session options.
    pub fn config(&self) -> SessionConfig {
        self.cfg
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The loaded and checked graph.
    pub fn get(&mut self) -> Result<&mut Graph> {
        if self.graph.is_none() {
            let g = Graph::open(self.path.clone(), self.name, &self.cfg)?;
            for (output, io, kind, dims) in &self.checks {
                g.check(*output, io, *kind, dims)?;
            }
            let fed: Vec<&str> = self
                .checks
                .iter()
                .filter(|c| !c.0)
                .map(|c| c.1.as_str())
                .collect();
            g.check_all_fed(&fed)?;
            self.graph = Some(g);
        }
        Ok(self.graph.as_mut().expect("loaded above"))
    }
}

/// An f32 input value from an array (copied into onnxruntime's memory).
pub fn f32_value<D: ndarray::Dimension>(a: Array<f32, D>) -> Result<SessionInputValue<'static>> {
    let shape = a.shape().to_vec();
    let data = if a.is_standard_layout() {
        a.into_raw_vec_and_offset().0
    } else {
        a.iter().copied().collect()
    };
    Ok(Tensor::from_array((shape, data))
        .map_err(|e| Error::Onnx(e.to_string()))?
        .into())
}

pub(crate) fn input(
    name: &str,
    v: SessionInputValue<'static>,
) -> (Cow<'static, str>, SessionInputValue<'static>) {
    (Cow::Owned(name.to_string()), v)
}

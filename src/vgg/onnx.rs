//! VGG16's forward pass and its input gradient as onnxruntime graphs, built in memory
//! from the same weights with onnxruntime's model editor: what [`super::Vgg16`]'s Rust
//! engine computes, on onnxruntime's convolution kernels (MLAS), which run the VGG shapes
//! 1.6-1.8x faster than im2col + `matrixmultiply` on this CPU (BENCHMARKS.md, "VGG16 and
//! the NNFM search on onnxruntime").
//!
//! The forward graph to layer `L` is the conv stack (3x3 convolution with bias, ReLU, 2x2
//! floor max-pooling between blocks) with every ReLU output `F_0..F_L` as an output (the
//! statistics read some, the backward pass needs all of them).
//!
//! The backward graph, for the tapped layers `T` (deepest `L`), is the vector-Jacobian
//! product written out as a forward graph: for i = L down to 0,
//! `g <- g + dLoss/dF_i` (i in T), `g <- where(F_i > 0, g, 0)`, `g <- conv(g, W_i')` with
//! `W_i'` the kernel flipped in both axes with in/out channels swapped (the transposed
//! convolution, as the Rust engine does), and where a pooling precedes layer i,
//! `g <- MaxUnpool(g, argmax of MaxPool(F_{i-1}))`: each pooled gradient goes to its
//! window's maximum, the first in row-major order on ties, as in the Rust engine.
//!
//! Sessions are built on first use, one per forward depth and one per set of tapped
//! layers, and kept; a session runs one call at a time (`Session::run` takes `&mut`), so
//! each sits behind the engine's mutex.

use super::{Conv, Layer, Tensor3, pooled_before};
use crate::runtime::graph::{constant, ints, model, node, outlet};
use crate::runtime::{SessionConfig, session_from_model};
use crate::{Error, Result};
use ort::editor::{Graph, Model};
use ort::operator::Attribute;
use ort::session::{Session, SessionInputValue};
use ort::value::{Outlet, TensorElementType, TensorRef};
use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Mutex;

fn onnx(e: impl std::fmt::Display) -> Error {
    Error::Onnx(format!("VGG16 on onnxruntime: {e}"))
}

/// The built sessions, keyed by what they compute.
pub(super) struct Engine {
    cfg: SessionConfig,
    forward: Mutex<HashMap<Layer, Session>>,
    backward: Mutex<HashMap<Vec<Layer>, Session>>,
}

impl std::fmt::Debug for Engine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Engine")
            .field("threads", &self.cfg.threads)
            .finish_non_exhaustive()
    }
}

impl Engine {
    /// An engine whose sessions use `threads` intra-op threads (0 = onnxruntime's
    /// default); loads onnxruntime now, so that a missing library is an error here.
    pub(super) fn new(threads: usize) -> Result<Self> {
        crate::runtime::environment()?;
        Ok(Engine {
            cfg: SessionConfig {
                threads,
                ..Default::default()
            },
            forward: Mutex::new(HashMap::new()),
            backward: Mutex::new(HashMap::new()),
        })
    }

    /// Intra-op threads of the sessions (0 = onnxruntime's default).
    pub(super) fn threads(&self) -> usize {
        self.cfg.threads
    }

    /// ReLU outputs `F_0..=F_upto` of the normalised `[3, H, W]` input `x`.
    pub(super) fn forward(&self, convs: &[Conv], x: &Tensor3, upto: Layer) -> Result<Vec<Tensor3>> {
        let mut sessions = self.forward.lock().map_err(onnx)?;
        let session = cached(&mut sessions, upto, || {
            session_from_model(
                forward_graph(convs, upto)?,
                &self.cfg,
                "VGG16 forward graph",
            )
        })?;
        let input = view(x)?;
        let out = session.run(ort::inputs!["x" => input]).map_err(onnx)?;
        (0..=upto.index())
            .map(|i| tensor3(&out, &format!("relu{i}")))
            .collect()
    }

    /// dLoss/dx (normalised input space, `[3, H, W]`) given `acts` (the forward's ReLU
    /// outputs, at least to the deepest tapped layer) and `grads` (shapes checked by the
    /// caller; several at one layer add up).
    pub(super) fn backward(
        &self,
        convs: &[Conv],
        acts: &[Tensor3],
        grads: &[(Layer, &Tensor3)],
    ) -> Result<Tensor3> {
        let mut taps: Vec<Layer> = grads.iter().map(|(l, _)| *l).collect();
        taps.sort();
        taps.dedup();
        let last = *taps.last().ok_or_else(|| onnx("no layer gradient"))?;
        let mut sessions = self.backward.lock().map_err(onnx)?;
        let session = cached(&mut sessions, taps.clone(), || {
            session_from_model(
                backward_graph(convs, &taps)?,
                &self.cfg,
                "VGG16 backward graph",
            )
        })?;
        // Several gradients at one layer add up, as in the Rust engine.
        let summed: Vec<(Layer, Cow<'_, Tensor3>)> = taps
            .iter()
            .map(|&l| {
                let mut parts = grads.iter().filter(|(k, _)| *k == l).map(|(_, g)| *g);
                let mut sum = Cow::Borrowed(parts.next().expect("each tap comes from grads"));
                for g in parts {
                    for (a, b) in sum.to_mut().data.iter_mut().zip(&g.data) {
                        *a += b;
                    }
                }
                (l, sum)
            })
            .collect();
        let mut inputs: Vec<(String, SessionInputValue<'_>)> = Vec::new();
        for (i, a) in acts.iter().enumerate().take(last.index() + 1) {
            inputs.push((format!("act{i}"), view(a)?.into()));
        }
        for (l, g) in &summed {
            inputs.push((format!("grad{}", l.index()), view(g)?.into()));
        }
        let out = session.run(inputs).map_err(onnx)?;
        tensor3(&out, "back0")
    }
}

/// The session under `key`, built by `build` on first use.
fn cached<K: std::hash::Hash + Eq>(
    sessions: &mut HashMap<K, Session>,
    key: K,
    build: impl FnOnce() -> Result<Session>,
) -> Result<&mut Session> {
    Ok(match sessions.entry(key) {
        std::collections::hash_map::Entry::Occupied(e) => e.into_mut(),
        std::collections::hash_map::Entry::Vacant(e) => e.insert(build()?),
    })
}

/// A `[1, C, H, W]` view of a feature map (no copy).
fn view(t: &Tensor3) -> Result<TensorRef<'_, f32>> {
    TensorRef::from_array_view(([1usize, t.c, t.h, t.w], t.data.as_slice())).map_err(onnx)
}

/// The output `name` as a feature map.
fn tensor3(out: &ort::session::SessionOutputs<'_>, name: &str) -> Result<Tensor3> {
    let (shape, data) = out
        .get(name)
        .ok_or_else(|| onnx(format!("no output {name}")))?
        .try_extract_tensor::<f32>()
        .map_err(onnx)?;
    if shape.len() != 4 || shape[0] != 1 {
        return Err(onnx(format!("output {name} has shape {shape:?}")));
    }
    Ok(Tensor3 {
        c: shape[1] as usize,
        h: shape[2] as usize,
        w: shape[3] as usize,
        data: data.to_vec(),
    })
}

/// A `[1, C, H, W]` float tensor declaration, spatial dims named by pooling level.
fn feature(name: &str, c: usize, level: usize) -> Outlet {
    let (h, w) = (format!("h{level}"), format!("w{level}"));
    outlet(
        name,
        TensorElementType::Float32,
        &[1, c as i64, -1, -1],
        &["", "", &h, &w],
    )
}

fn conv_attrs() -> Result<Vec<Attribute>> {
    Ok(vec![
        ints("kernel_shape", &[3, 3]).map_err(onnx)?,
        ints("pads", &[1, 1, 1, 1]).map_err(onnx)?,
    ])
}

fn pool_attrs() -> Result<Vec<Attribute>> {
    Ok(vec![
        ints("kernel_shape", &[2, 2]).map_err(onnx)?,
        ints("strides", &[2, 2]).map_err(onnx)?,
    ])
}

/// Pooling level (spatial size = input / 2^level) of convolution `i`.
fn level(i: usize) -> usize {
    Layer::ALL[i].pools()
}

fn forward_graph(convs: &[Conv], upto: Layer) -> Result<Model> {
    let mut g = Graph::new().map_err(onnx)?;
    g.set_inputs([feature("x", 3, 0)]).map_err(onnx)?;
    let mut outputs = Vec::new();
    let mut cur = "x".to_string();
    for (i, c) in convs.iter().enumerate().take(upto.index() + 1) {
        if pooled_before(i) {
            let p = format!("pool{i}");
            node(&mut g, "MaxPool", &[&cur], &[&p], pool_attrs()?).map_err(onnx)?;
            cur = p;
        }
        let (w, b, conv, relu) = (
            format!("w{i}"),
            format!("b{i}"),
            format!("conv{i}"),
            format!("relu{i}"),
        );
        let weights = c.w.as_slice().expect("standard layout");
        constant(&mut g, &w, &[c.cout, c.cin, 3, 3], weights).map_err(onnx)?;
        constant(&mut g, &b, &[c.cout], &c.b).map_err(onnx)?;
        node(&mut g, "Conv", &[&cur, &w, &b], &[&conv], conv_attrs()?).map_err(onnx)?;
        node(&mut g, "Relu", &[&conv], &[&relu], vec![]).map_err(onnx)?;
        outputs.push(feature(&relu, c.cout, level(i)));
        cur = relu;
    }
    g.set_outputs(outputs).map_err(onnx)?;
    model(g).map_err(onnx)
}

/// `taps`: sorted, distinct, non-empty.
fn backward_graph(convs: &[Conv], taps: &[Layer]) -> Result<Model> {
    let last = taps[taps.len() - 1].index();
    let mut g = Graph::new().map_err(onnx)?;
    let mut inputs: Vec<Outlet> = (0..=last)
        .map(|i| feature(&format!("act{i}"), convs[i].cout, level(i)))
        .collect();
    inputs.extend(taps.iter().map(|l| {
        let i = l.index();
        feature(&format!("grad{i}"), convs[i].cout, level(i))
    }));
    g.set_inputs(inputs).map_err(onnx)?;
    constant(&mut g, "zero", &[1], &[0.0]).map_err(onnx)?;
    let mut cur: Option<String> = None;
    for i in (0..=last).rev() {
        let (act, grad) = (format!("act{i}"), format!("grad{i}"));
        let tapped = taps.iter().any(|l| l.index() == i);
        let summed = match (cur, tapped) {
            (None, _) => grad,
            (Some(c), false) => c,
            (Some(c), true) => {
                let s = format!("sum{i}");
                node(&mut g, "Add", &[&c, &grad], &[&s], vec![]).map_err(onnx)?;
                s
            }
        };
        let (pos, masked, back) = (format!("pos{i}"), format!("masked{i}"), format!("back{i}"));
        node(&mut g, "Greater", &[&act, "zero"], &[&pos], vec![]).map_err(onnx)?;
        node(
            &mut g,
            "Where",
            &[&pos, &summed, "zero"],
            &[&masked],
            vec![],
        )
        .map_err(onnx)?;
        let wb = format!("wb{i}");
        let c = &convs[i];
        let weights = c.w_back.as_slice().expect("standard layout");
        constant(&mut g, &wb, &[c.cin, c.cout, 3, 3], weights).map_err(onnx)?;
        node(&mut g, "Conv", &[&masked, &wb], &[&back], conv_attrs()?).map_err(onnx)?;
        cur = Some(if pooled_before(i) {
            let below = format!("act{}", i - 1);
            let (pooled, idx, shape, unpool) = (
                format!("pooled{i}"),
                format!("idx{i}"),
                format!("shape{i}"),
                format!("unpool{i}"),
            );
            node(
                &mut g,
                "MaxPool",
                &[&below],
                &[&pooled, &idx],
                pool_attrs()?,
            )
            .map_err(onnx)?;
            node(&mut g, "Shape", &[&below], &[&shape], vec![]).map_err(onnx)?;
            node(
                &mut g,
                "MaxUnpool",
                &[&back, &idx, &shape],
                &[&unpool],
                pool_attrs()?,
            )
            .map_err(onnx)?;
            unpool
        } else {
            back
        });
    }
    g.set_outputs([feature("back0", 3, 0)]).map_err(onnx)?;
    model(g).map_err(onnx)
}

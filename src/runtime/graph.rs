//! Graphs built in memory with onnxruntime's model editor, for computations whose weights
//! we already hold (VGG16's forward and backward passes, [`crate::vgg`]; the NNFM
//! nearest-neighbour search, [`crate::baselines::nnfm`]): small helpers over
//! `ort::editor` so that a graph reads as a list of operators. Sessions come from
//! [`super::session_from_model`], with the same options as graphs loaded from files.

use ort::editor::{Graph, Model, Node, ONNX_DOMAIN, Opset};
use ort::memory::Allocator;
use ort::operator::Attribute;
use ort::value::{Outlet, Shape, SymbolicDimensions, Tensor, TensorElementType, ValueType};

/// ONNX operator set of the built graphs (every operator used is unchanged since).
pub const OPSET: u32 = 17;

/// A graph input or output: element type `ty`, `dims` (-1 = dynamic) with a symbol per
/// dimension (`""` = unnamed; equal symbols mean equal sizes).
pub fn outlet(name: &str, ty: TensorElementType, dims: &[i64], symbols: &[&str]) -> Outlet {
    Outlet::new(
        name,
        ValueType::Tensor {
            ty,
            shape: Shape::new(dims.iter().copied()),
            dimension_symbols: SymbolicDimensions::new(symbols.iter().map(|s| s.to_string())),
        },
    )
}

/// A float constant (initializer) `name` of `shape` holding `data`.
pub fn constant(g: &mut Graph, name: &str, shape: &[usize], data: &[f32]) -> ort::Result<()> {
    let dims: Vec<i64> = shape.iter().map(|&d| d as i64).collect();
    let mut t = Tensor::<f32>::new(&Allocator::default(), dims)?;
    t.extract_tensor_mut().1.copy_from_slice(data);
    g.add_initializer(name, t, false)
}

/// Operator `op` (ONNX domain) from `inputs` to `outputs`, named after its first output.
pub fn node(
    g: &mut Graph,
    op: &str,
    inputs: &[&str],
    outputs: &[&str],
    attrs: Vec<Attribute>,
) -> ort::Result<()> {
    g.add_node(Node::new(
        op,
        ONNX_DOMAIN,
        outputs[0],
        inputs,
        outputs,
        attrs,
    )?)
}

/// An integer-list attribute.
pub fn ints(name: &str, v: &[i64]) -> ort::Result<Attribute> {
    Attribute::new(name, v.to_vec())
}

/// An integer attribute.
pub fn int(name: &str, v: i64) -> ort::Result<Attribute> {
    Attribute::new(name, v)
}

/// The model holding `g`, at [`OPSET`].
pub fn model(g: Graph) -> ort::Result<Model> {
    let mut m = Model::new([Opset::new(ONNX_DOMAIN, OPSET)?])?;
    m.set_graph(g)?;
    Ok(m)
}

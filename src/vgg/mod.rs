//! VGG16 (Simonyan & Zisserman 2015) feature extractor with its input gradient, for the
//! VGG-based stylization baselines ([`crate::baselines`]) and `distill`'s texture term
//! ([`crate::terms::texture`]).
//!
//! What it computes: ImageNet normalisation `(x - mean) / std` of an `[H, W, 3]` image in
//! [0, 1], then the VGG16 conv stack — 3x3 convolutions (stride 1, zero padding 1) each
//! followed by ReLU, with 2x2 max-pooling (stride 2, floor) between blocks — up to
//! **relu4_3** (10 convolutions). The backward pass is the vector-Jacobian product: given
//! dL/dF for any set of tapped ReLU outputs, it returns dL/dx for the input image.
//!
//! Why relu4_3 and not relu5_1: the Gram baseline (Gatys et al. 2016, as SGSST uses it)
//! taps relu1_2, relu2_2, relu3_3 and relu4_3, ARF's NNFM uses the relu3 block, and the
//! content loss uses relu4_3; nothing needs block 5, which would add a pooling and a
//! 512-channel convolution and raise the receptive field to 132 px for no loss term.
//! Receptive field of relu4_3: 92 px ([`receptive_field`]).
//!
//! Two engines compute these passes. The Rust engine (this module) is the reference:
//! convolutions are im2col + SGEMM on `matrixmultiply` (through
//! `ndarray::linalg::general_mat_mul`; measured against the `gemm` crate, BENCHMARKS.md
//! "VGG16 and the NNFM search on onnxruntime"), parallel over bands of output rows (each
//! band: its own im2col buffer and a single-threaded GEMM into its column block of the
//! output), which bounds the im2col memory and needs no synchronisation; it is tested
//! against finite differences and an f64 forward in-process. The onnxruntime engine (`src/vgg/onnx.rs`, after
//! [`Vgg16::on_onnxruntime`]) builds the forward pass and the backward pass as forward
//! graphs from the same weights (the backward's transposed convolutions, ReLU masks and
//! max-unpooling written out as operators) and runs them on onnxruntime's convolution
//! kernels, 1.6-1.8x faster on 2 cores (BENCHMARKS.md, "VGG16 and the NNFM search on
//! onnxruntime"); it is tested against the Rust engine. The stages use it (the Rust engine,
//! with a warning, where the onnxruntime library is missing:
//! [`crate::stages::fast_vgg`]); tests and the golden check use both.
//!
//! The input gradient of a stride-1, pad-1 3x3 convolution is the convolution of the output
//! gradient with the kernel flipped in both axes and its in/out channels swapped (the
//! transposed convolution), so forward and backward share one routine.
//!
//! One module per part: `layer` (the tapped ReLUs, the block structure and the
//! receptive field), `style` (the style image's size limits), `tensor` ([`Tensor3`]),
//! `ops` (the Rust engine's convolution and pooling) and `onnx` (the onnxruntime
//! engine); the network itself ([`Vgg16`]) is here.

use crate::{Error, Result};
use std::path::Path;
use std::sync::Arc;

mod layer;
mod onnx;
mod ops;
mod style;
mod tensor;

use layer::pooled_before;
pub use layer::{Layer, receptive_field};
use ops::{Conv, conv3x3, max_pool, max_pool_backward};
pub use style::{MIN_STYLE_SIDE, prepare_style};
pub use tensor::Tensor3;

/// ImageNet channel means for inputs in [0, 1] (torchvision convention, which the
/// LPIPS/torchvision VGG16 weights were trained with).
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// ImageNet channel standard deviations.
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// Output channels of each convolution in the standard VGG16.
const VGG16_CHANNELS: [usize; 10] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512];

/// The VGG16 conv stack up to relu4_3. Channel widths come from the weights, so a narrow
/// network with the same topology (the golden test's) runs through the same code.
///
/// Two engines compute the same passes: the Rust one of this module (the reference, tested
/// against finite differences and an f64 forward) and, after [`Vgg16::on_onnxruntime`],
/// onnxruntime graphs built from the same weights (`onnx.rs`, tested against the Rust one).
#[derive(Debug, Clone)]
pub struct Vgg16 {
    convs: Vec<Conv>,
    /// onnxruntime sessions, shared by clones; `None` = the Rust engine.
    engine: Option<Arc<onnx::Engine>>,
}

/// Forward activations kept for the backward pass.
#[derive(Debug, Clone)]
pub struct Forward {
    /// Input size.
    pub h: usize,
    pub w: usize,
    /// ReLU outputs of convolutions `0..=last`.
    pub acts: Vec<Tensor3>,
}

impl Forward {
    /// The ReLU output `layer` (must have been computed).
    pub fn get(&self, layer: Layer) -> &Tensor3 {
        &self.acts[layer.index()]
    }
    /// The deepest layer computed.
    pub fn last(&self) -> Layer {
        Layer::ALL[self.acts.len() - 1]
    }
}

impl Vgg16 {
    /// Weights from a directory of `conv{i}_weight.npy` (OIHW f32) and `conv{i}_bias.npy`,
    /// i = 0..9 in network order (`vendor/models/lpips/vgg16/`, made by set-up). Later
    /// convolutions, LPIPS heads and `layout.json` are ignored. Checks shapes against VGG16
    /// (channel chaining, 3x3 kernels, 3 input channels) and refuses NaN.
    pub fn load(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::Missing(format!(
                "{}: VGG16 weights directory is absent (run scripts/setup.sh, step 30_lpips_weights.py)",
                dir.display()
            )));
        }
        let mut layers = Vec::new();
        for i in 0..VGG16_CHANNELS.len() {
            let wp = dir.join(format!("conv{i}_weight.npy"));
            let bp = dir.join(format!("conv{i}_bias.npy"));
            for p in [&wp, &bp] {
                if !p.is_file() {
                    return Err(Error::Missing(format!(
                        "{}: VGG16 weight file is absent (run scripts/setup.sh)",
                        p.display()
                    )));
                }
            }
            let w = fantasystyle_schemas::read_npy_f32(&wp)?;
            let b = fantasystyle_schemas::read_npy_f32(&bp)?;
            layers.push(((wp, w.shape, w.data), (bp, b.shape, b.data)));
        }
        Self::from_layers(layers)
    }

    /// Weights given in memory (path names only for error messages).
    #[allow(clippy::type_complexity)]
    pub fn from_layers(
        layers: Vec<(
            (std::path::PathBuf, Vec<usize>, Vec<f32>),
            (std::path::PathBuf, Vec<usize>, Vec<f32>),
        )>,
    ) -> Result<Self> {
        if layers.len() != VGG16_CHANNELS.len() {
            return Err(Error::param(format!(
                "VGG16 up to relu4_3 needs 10 convolutions, got {}",
                layers.len()
            )));
        }
        let mut convs = Vec::new();
        let mut cin = 3;
        for ((wp, ws, wd), (bp, bs, bd)) in layers {
            if ws.len() != 4 || ws[1] != cin || ws[2] != 3 || ws[3] != 3 {
                return Err(Error::input(
                    &wp,
                    format!("expected shape [O, {cin}, 3, 3] (OIHW), found {ws:?}"),
                ));
            }
            let cout = ws[0];
            if bs != [cout] {
                return Err(Error::input(
                    &bp,
                    format!("expected shape [{cout}], found {bs:?}"),
                ));
            }
            convs.push(Conv::new(cout, cin, &wd, bd));
            cin = cout;
        }
        Ok(Vgg16 {
            convs,
            engine: None,
        })
    }

    /// A network with He-initialised random weights (for tests and benchmarks), channel
    /// widths `VGG16 / shrink`.
    pub fn random(seed: u64, shrink: usize) -> Self {
        let mut rng = crate::rng::Rng::new(seed);
        let mut cin = 3;
        let mut convs = Vec::new();
        for &c in &VGG16_CHANNELS {
            let cout = (c / shrink.max(1)).max(1);
            let std = (2.0 / (9.0 * cin as f64)).sqrt();
            let w: Vec<f32> = (0..cout * cin * 9)
                .map(|_| (rng.normal() * std) as f32)
                .collect();
            let b: Vec<f32> = (0..cout).map(|_| (rng.normal() * 0.05) as f32).collect();
            convs.push(Conv::new(cout, cin, &w, b));
            cin = cout;
        }
        Vgg16 {
            convs,
            engine: None,
        }
    }

    /// The same network on onnxruntime (`onnx.rs`: about 1.7x faster here), with `threads`
    /// intra-op threads (0 = onnxruntime's default). Errors when onnxruntime cannot be
    /// loaded.
    pub fn on_onnxruntime(mut self, threads: usize) -> Result<Self> {
        self.engine = Some(Arc::new(onnx::Engine::new(threads)?));
        Ok(self)
    }

    /// The onnxruntime engine's intra-op threads, `None` on the Rust engine (statistics
    /// that run their own graphs next to the VGG's follow it: [`crate::baselines::nnfm`]).
    pub fn onnxruntime_threads(&self) -> Option<usize> {
        self.engine.as_ref().map(|e| e.threads())
    }

    /// Output channels of `layer`.
    pub fn channels(&self, layer: Layer) -> usize {
        self.convs[layer.index()].cout
    }

    /// Forward pass of an `[H, W, 3]` image in [0, 1] up to `upto`. Needs
    /// `H, W >= 2^pools(upto)` so that every layer has at least one position.
    pub fn forward(&self, rgb: &[f32], h: usize, w: usize, upto: Layer) -> Result<Forward> {
        if rgb.len() != h * w * 3 {
            return Err(Error::param(format!(
                "VGG input has {} values, expected {h}x{w}x3",
                rgb.len()
            )));
        }
        let min = 1usize << upto.pools();
        if h < min || w < min {
            return Err(Error::param(format!(
                "a {h}x{w} image is too small for VGG layer {} (needs at least {min}x{min})",
                upto.name()
            )));
        }
        let mut x = Tensor3::zeros(3, h, w);
        for c in 0..3 {
            for p in 0..h * w {
                x.data[c * h * w + p] = (rgb[p * 3 + c] - IMAGENET_MEAN[c]) / IMAGENET_STD[c];
            }
        }
        if let Some(engine) = &self.engine {
            let acts = engine.forward(&self.convs, &x, upto)?;
            return Ok(Forward { h, w, acts });
        }
        let mut acts: Vec<Tensor3> = Vec::with_capacity(upto.index() + 1);
        for i in 0..=upto.index() {
            let input = match acts.last() {
                None => &x,
                Some(a) if pooled_before(i) => {
                    x = max_pool(a);
                    &x
                }
                Some(a) => a,
            };
            let conv = &self.convs[i];
            let mut y = conv3x3(input, &conv.w, conv.cout);
            for (o, row) in y.data.chunks_mut(y.h * y.w).enumerate() {
                let b = conv.b[o];
                for v in row {
                    *v = (*v + b).max(0.0);
                }
            }
            acts.push(y);
        }
        Ok(Forward { h, w, acts })
    }

    /// Vector-Jacobian product: given `grads` = (layer, dL/dF_layer) pairs (each shaped as
    /// that layer's `[C, H, W]` output), returns dL/dx as `[H, W, 3]` for the input image
    /// of `fwd`. Layers deeper than `fwd.last()` are an error.
    pub fn backward(&self, fwd: &Forward, grads: &[(Layer, &Tensor3)]) -> Result<Vec<f32>> {
        let last = grads
            .iter()
            .map(|(l, _)| *l)
            .max()
            .ok_or_else(|| Error::param("VGG backward needs at least one layer gradient"))?;
        if last > fwd.last() {
            return Err(Error::param(format!(
                "gradient given at {} but the forward pass stopped at {}",
                last.name(),
                fwd.last().name()
            )));
        }
        for (l, g) in grads {
            let a = fwd.get(*l);
            if (g.c, g.h, g.w) != (a.c, a.h, a.w) {
                return Err(Error::param(format!(
                    "gradient at {} is {}x{}x{}, the layer is {}x{}x{}",
                    l.name(),
                    g.c,
                    g.h,
                    g.w,
                    a.c,
                    a.h,
                    a.w
                )));
            }
        }
        let g = match &self.engine {
            Some(engine) => engine.backward(&self.convs, &fwd.acts, grads)?,
            None => self.backward_rust(fwd, last, grads),
        };
        let (h, w) = (fwd.h, fwd.w);
        let mut out = vec![0.0; h * w * 3];
        for c in 0..3 {
            for p in 0..h * w {
                out[p * 3 + c] = g.data[c * h * w + p] / IMAGENET_STD[c];
            }
        }
        Ok(out)
    }

    /// The Rust engine's backward pass to the normalised input, `[3, H, W]`.
    fn backward_rust(&self, fwd: &Forward, last: Layer, grads: &[(Layer, &Tensor3)]) -> Tensor3 {
        let mut g = Tensor3::zeros(0, 0, 0);
        for i in (0..=last.index()).rev() {
            let act = &fwd.acts[i];
            if g.data.is_empty() {
                g = Tensor3::zeros(act.c, act.h, act.w);
            }
            for (l, dg) in grads {
                if l.index() == i {
                    for (a, b) in g.data.iter_mut().zip(&dg.data) {
                        *a += b;
                    }
                }
            }
            for (gv, &av) in g.data.iter_mut().zip(&act.data) {
                if av <= 0.0 {
                    *gv = 0.0;
                }
            }
            let conv = &self.convs[i];
            g = conv3x3(&g, &conv.w_back, conv.cin);
            if pooled_before(i) {
                g = max_pool_backward(&g, &fwd.acts[i - 1]);
            }
        }
        g
    }
}

#[cfg(test)]
mod tests;

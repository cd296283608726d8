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

use crate::{Error, Result};
use ndarray::{Array2, ArrayView2, ArrayViewMut2, Axis, linalg::general_mat_mul};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;

mod onnx;

/// ImageNet channel means for inputs in [0, 1] (torchvision convention, which the
/// LPIPS/torchvision VGG16 weights were trained with).
pub const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
/// ImageNet channel standard deviations.
pub const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

/// Convolutions per block in VGG16 (blocks 1-4; block 5 is not built, see module docs).
const BLOCKS: [usize; 4] = [2, 2, 3, 3];
/// Output channels of each convolution in the standard VGG16.
const VGG16_CHANNELS: [usize; 10] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512];

/// A tapped ReLU output, in network order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Layer {
    Relu1_1,
    Relu1_2,
    Relu2_1,
    Relu2_2,
    Relu3_1,
    Relu3_2,
    Relu3_3,
    Relu4_1,
    Relu4_2,
    Relu4_3,
}

impl Layer {
    pub const ALL: [Layer; 10] = [
        Layer::Relu1_1,
        Layer::Relu1_2,
        Layer::Relu2_1,
        Layer::Relu2_2,
        Layer::Relu3_1,
        Layer::Relu3_2,
        Layer::Relu3_3,
        Layer::Relu4_1,
        Layer::Relu4_2,
        Layer::Relu4_3,
    ];
    /// Index of the convolution this ReLU follows (0..10).
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn name(self) -> &'static str {
        [
            "relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3", "relu4_1",
            "relu4_2", "relu4_3",
        ][self.index()]
    }
    /// Number of 2x2 poolings before this layer (its stride is `2^pools`).
    pub fn pools(self) -> usize {
        block_of(self.index())
    }
}

impl std::str::FromStr for Layer {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Layer::ALL
            .iter()
            .copied()
            .find(|l| l.name() == s)
            .ok_or_else(|| Error::param(format!("unknown VGG layer `{s}` (relu1_1 .. relu4_3)")))
    }
}

impl serde::Serialize for Layer {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Layer {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let s = <String as serde::Deserialize>::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Block (0-based) of convolution `i`.
fn block_of(i: usize) -> usize {
    let mut end = 0;
    for (b, n) in BLOCKS.iter().enumerate() {
        end += n;
        if i < end {
            return b;
        }
    }
    BLOCKS.len() - 1
}

/// Whether convolution `i` starts a block after the first (a max-pool precedes it).
fn pooled_before(i: usize) -> bool {
    i > 0 && block_of(i) != block_of(i - 1)
}

/// Receptive field, in input pixels, of one unit of `layer`: each 3x3 convolution adds
/// 2 strides, each 2x2 pool adds 1 stride and doubles the stride. relu4_3: 92.
pub fn receptive_field(layer: Layer) -> usize {
    let (mut rf, mut stride) = (1, 1);
    for i in 0..=layer.index() {
        if pooled_before(i) {
            rf += stride;
            stride *= 2;
        }
        rf += 2 * stride;
    }
    rf
}

/// Smallest accepted style image side for the VGG losses: the receptive field of relu4_3
/// (92 px). A smaller image cannot fill even one deepest-layer unit, so its "style" at
/// that layer would be the zero padding's.
pub const MIN_STYLE_SIDE: usize = 92;

/// Check that a style image is large enough (see module docs) and resize it so its
/// shorter side is `style_size` ([`crate::imageio::Image::with_shorter_side`]; aspect kept). `path` names it in
/// errors.
pub fn prepare_style(
    img: &crate::imageio::Image,
    style_size: usize,
    path: &std::path::Path,
) -> Result<crate::imageio::Image> {
    debug_assert_eq!(receptive_field(Layer::Relu4_3), MIN_STYLE_SIDE);
    let short = img.width.min(img.height);
    if short < MIN_STYLE_SIDE {
        return Err(Error::input(
            path,
            format!(
                "style image is {}x{}; VGG16 needs a shorter side of at least {MIN_STYLE_SIDE} px (the receptive field of relu4_3)",
                img.width, img.height
            ),
        ));
    }
    if style_size < MIN_STYLE_SIDE {
        return Err(Error::param(format!(
            "--style-size {style_size} is below the VGG receptive field ({MIN_STYLE_SIDE} px)"
        )));
    }
    Ok(img.with_shorter_side(style_size))
}

/// A `[C, H, W]` feature map, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor3 {
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub data: Vec<f32>,
}

impl Tensor3 {
    pub fn zeros(c: usize, h: usize, w: usize) -> Self {
        Tensor3 {
            c,
            h,
            w,
            data: vec![0.0; c * h * w],
        }
    }
    /// Spatial positions `H W`.
    pub fn hw(&self) -> usize {
        self.h * self.w
    }
    /// The map as a `[C, H W]` matrix.
    pub fn matrix(&self) -> ArrayView2<'_, f32> {
        ArrayView2::from_shape((self.c, self.hw()), &self.data).expect("shape matches data")
    }
}

/// One 3x3 convolution: weights as the `[O, I*9]` GEMM matrix, bias, and the transposed,
/// flipped `[I, O*9]` matrix for the input gradient.
#[derive(Debug, Clone)]
struct Conv {
    cin: usize,
    cout: usize,
    w: Array2<f32>,
    w_back: Array2<f32>,
    b: Vec<f32>,
}

impl Conv {
    /// From OIHW weights `[O, I, 3, 3]` and a bias `[O]`.
    fn new(cout: usize, cin: usize, oihw: &[f32], b: Vec<f32>) -> Self {
        let w = Array2::from_shape_vec((cout, cin * 9), oihw.to_vec()).expect("OIHW shape");
        let mut w_back = Array2::zeros((cin, cout * 9));
        for o in 0..cout {
            for i in 0..cin {
                for k in 0..9 {
                    w_back[[i, o * 9 + (8 - k)]] = oihw[(o * cin + i) * 9 + k];
                }
            }
        }
        Conv {
            cin,
            cout,
            w,
            w_back,
            b,
        }
    }
}

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

/// Pixels per im2col band: bounds the `[9 C, band]` buffer to about 4 M floats (16 MiB).
fn band_rows(k: usize, h: usize, w: usize) -> usize {
    let by_mem = (4 << 20) / (k * w).max(1);
    // At least two bands per thread when the image allows, for load balance.
    let by_par = h.div_ceil(2 * rayon::current_num_threads());
    by_mem.min(by_par).clamp(1, h)
}

/// 3x3, stride 1, zero-pad 1 convolution of `x` with the `[cout, cin*9]` matrix `wm`
/// (no bias): im2col per band of output rows, one GEMM per band, bands in parallel.
fn conv3x3(x: &Tensor3, wm: &Array2<f32>, cout: usize) -> Tensor3 {
    let (cin, h, w) = (x.c, x.h, x.w);
    let k = cin * 9;
    debug_assert_eq!(wm.dim(), (cout, k));
    let mut out = Array2::<f32>::zeros((cout, h * w));
    let rows = band_rows(k, h, w);
    let mut bands: Vec<(usize, ArrayViewMut2<'_, f32>)> = Vec::new();
    let mut rest = out.view_mut();
    let mut y0 = 0;
    while y0 < h {
        let n = rows.min(h - y0);
        let (band, tail) = rest.split_at(Axis(1), n * w);
        bands.push((y0, band));
        rest = tail;
        y0 += n;
    }
    bands.into_par_iter().for_each(|(y0, mut band)| {
        let n = band.ncols() / w;
        let mut col = Array2::<f32>::zeros((k, n * w));
        for ci in 0..cin {
            let plane = &x.data[ci * h * w..(ci + 1) * h * w];
            for ky in 0..3 {
                for kx in 0..3 {
                    let mut row = col.row_mut(ci * 9 + ky * 3 + kx);
                    let row = row.as_slice_mut().expect("contiguous row");
                    for dy in 0..n {
                        let sy = (y0 + dy + ky) as isize - 1;
                        if sy < 0 || sy >= h as isize {
                            continue;
                        }
                        let src = &plane[sy as usize * w..(sy as usize + 1) * w];
                        let dst = &mut row[dy * w..(dy + 1) * w];
                        match kx {
                            0 => dst[1..].copy_from_slice(&src[..w - 1]),
                            1 => dst.copy_from_slice(src),
                            _ => dst[..w - 1].copy_from_slice(&src[1..]),
                        }
                    }
                }
            }
        }
        general_mat_mul(1.0, wm, &col, 0.0, &mut band);
    });
    Tensor3 {
        c: cout,
        h,
        w,
        data: out.into_raw_vec_and_offset().0,
    }
}

/// 2x2 max-pool, stride 2, floor (odd trailing rows/columns dropped).
fn max_pool(x: &Tensor3) -> Tensor3 {
    let (h2, w2) = (x.h / 2, x.w / 2);
    let mut y = Tensor3::zeros(x.c, h2, w2);
    for c in 0..x.c {
        let src = &x.data[c * x.h * x.w..];
        for i in 0..h2 {
            for j in 0..w2 {
                let p = (2 * i) * x.w + 2 * j;
                let m = src[p]
                    .max(src[p + 1])
                    .max(src[p + x.w])
                    .max(src[p + x.w + 1]);
                y.data[(c * h2 + i) * w2 + j] = m;
            }
        }
    }
    y
}

/// Route each pooled gradient to its window's maximum (the first in row-major order on
/// ties); `x` is the pool's input.
fn max_pool_backward(g: &Tensor3, x: &Tensor3) -> Tensor3 {
    let mut out = Tensor3::zeros(x.c, x.h, x.w);
    for c in 0..x.c {
        let base = c * x.h * x.w;
        for i in 0..g.h {
            for j in 0..g.w {
                let p = base + (2 * i) * x.w + 2 * j;
                let cand = [p, p + 1, p + x.w, p + x.w + 1];
                let mut best = cand[0];
                for &q in &cand[1..] {
                    if x.data[q] > x.data[best] {
                        best = q;
                    }
                }
                out.data[best] += g.data[(c * g.h + i) * g.w + j];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(seed: u64, h: usize, w: usize) -> Vec<f32> {
        let mut r = crate::rng::Rng::new(seed);
        (0..h * w * 3).map(|_| r.uniform() as f32).collect()
    }

    #[test]
    fn receptive_fields() {
        assert_eq!(receptive_field(Layer::Relu1_1), 3);
        assert_eq!(receptive_field(Layer::Relu1_2), 5);
        assert_eq!(receptive_field(Layer::Relu2_2), 14);
        assert_eq!(receptive_field(Layer::Relu3_3), 40);
        assert_eq!(receptive_field(Layer::Relu4_3), 92);
    }

    /// The support of one relu4_3 unit's input gradient fits in the closed-form
    /// receptive field (an independent check of `receptive_field`).
    #[test]
    fn gradient_support_within_receptive_field() {
        let net = Vgg16::random(3, 16);
        let (h, w) = (120, 120);
        let img = image(1, h, w);
        let f = net.forward(&img, h, w, Layer::Relu4_3).unwrap();
        let a = f.get(Layer::Relu4_3);
        let mut g = Tensor3::zeros(a.c, a.h, a.w);
        // All channels of the centre unit (some are active).
        let (cy, cx) = (a.h / 2, a.w / 2);
        for c in 0..a.c {
            g.data[(c * a.h + cy) * a.w + cx] = 1.0;
        }
        let dx = net.backward(&f, &[(Layer::Relu4_3, &g)]).unwrap();
        let (mut y0, mut y1) = (usize::MAX, 0);
        for p in 0..h * w {
            if (0..3).any(|c| dx[p * 3 + c] != 0.0) {
                y0 = y0.min(p / w);
                y1 = y1.max(p / w);
            }
        }
        assert!(y1 >= y0, "gradient is all zero");
        assert!(y1 - y0 < 92, "support {} rows", y1 - y0 + 1);
    }

    /// An independent f64 forward pass (direct convolution loops, no im2col, no GEMM):
    /// returns the ReLU outputs of convolutions `0..=upto`.
    fn forward_f64(net: &Vgg16, rgb: &[f64], h: usize, w: usize, upto: Layer) -> Vec<Vec<f64>> {
        let mut x: Vec<f64> = (0..3 * h * w)
            .map(|q| {
                let (c, p) = (q / (h * w), q % (h * w));
                (rgb[p * 3 + c] - IMAGENET_MEAN[c] as f64) / IMAGENET_STD[c] as f64
            })
            .collect();
        let (mut hh, mut ww) = (h, w);
        let mut out = Vec::new();
        for i in 0..=upto.index() {
            if pooled_before(i) {
                let (h2, w2) = (hh / 2, ww / 2);
                let c = net.convs[i].cin;
                let mut y = vec![0.0; c * h2 * w2];
                for ch in 0..c {
                    for a in 0..h2 {
                        for b in 0..w2 {
                            let at =
                                |dy: usize, dx: usize| x[(ch * hh + 2 * a + dy) * ww + 2 * b + dx];
                            y[(ch * h2 + a) * w2 + b] =
                                at(0, 0).max(at(0, 1)).max(at(1, 0)).max(at(1, 1));
                        }
                    }
                }
                x = y;
                hh = h2;
                ww = w2;
            }
            let conv = &net.convs[i];
            let mut y = vec![0.0; conv.cout * hh * ww];
            for o in 0..conv.cout {
                for a in 0..hh {
                    for b in 0..ww {
                        let mut s = conv.b[o] as f64;
                        for ci in 0..conv.cin {
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    let (sy, sx) = (a + ky, b + kx);
                                    if sy < 1 || sx < 1 || sy > hh || sx > ww {
                                        continue;
                                    }
                                    s += conv.w[[o, ci * 9 + ky * 3 + kx]] as f64
                                        * x[(ci * hh + sy - 1) * ww + sx - 1];
                                }
                            }
                        }
                        y[(o * hh + a) * ww + b] = s.max(0.0);
                    }
                }
            }
            out.push(y.clone());
            x = y;
        }
        out
    }

    /// The f32 GEMM forward agrees with the f64 direct forward, and the f32 backward agrees
    /// with central differences of the f64 forward (eps 1e-6, where ReLU/max-pool kinks are
    /// practically never straddled): directional derivative along a random direction and
    /// 40 single entries. Tolerance: 1e-3 of the gradient scale.
    #[test]
    fn backward_matches_finite_differences() {
        let net = Vgg16::random(11, 16);
        let (h, w) = (18, 21);
        let img = image(5, h, w);
        let f0 = net.forward(&img, h, w, Layer::Relu4_3).unwrap();
        let img64: Vec<f64> = img.iter().map(|&v| v as f64).collect();
        let r64 = forward_f64(&net, &img64, h, w, Layer::Relu4_3);
        for (a, b) in f0.acts.iter().zip(&r64) {
            let scale = b.iter().fold(0f64, |m, v| m.max(v.abs()));
            let err = a
                .data
                .iter()
                .zip(b)
                .fold(0f64, |m, (&x, &y)| m.max((x as f64 - y).abs()));
            assert!(
                err <= 1e-5 * scale.max(1.0),
                "forward err {err} scale {scale}"
            );
        }
        let taps = [
            Layer::Relu1_2,
            Layer::Relu2_2,
            Layer::Relu3_3,
            Layer::Relu4_3,
        ];
        let mut r = crate::rng::Rng::new(9);
        let weights: Vec<Tensor3> = taps
            .iter()
            .map(|&l| {
                let a = f0.get(l);
                let mut t = Tensor3::zeros(a.c, a.h, a.w);
                t.data.iter_mut().for_each(|v| *v = r.normal() as f32);
                t
            })
            .collect();
        let loss = |x: &[f64]| -> f64 {
            let f = forward_f64(&net, x, h, w, Layer::Relu4_3);
            taps.iter()
                .zip(&weights)
                .map(|(&l, wt)| {
                    f[l.index()]
                        .iter()
                        .zip(&wt.data)
                        .map(|(&a, &b)| a * b as f64)
                        .sum::<f64>()
                })
                .sum()
        };
        let gl: Vec<(Layer, &Tensor3)> = taps.iter().copied().zip(weights.iter()).collect();
        let g = net.backward(&f0, &gl).unwrap();
        let gmax = g.iter().fold(0f32, |m, x| m.max(x.abs())) as f64;
        let eps = 1e-6;
        let v: Vec<f64> = (0..img.len()).map(|_| r.normal()).collect();
        let plus: Vec<f64> = img64.iter().zip(&v).map(|(a, b)| a + eps * b).collect();
        let minus: Vec<f64> = img64.iter().zip(&v).map(|(a, b)| a - eps * b).collect();
        let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps);
        let an: f64 = g.iter().zip(&v).map(|(&a, &b)| a as f64 * b).sum();
        let vnorm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!(
            (fd - an).abs() <= 1e-3 * gmax * vnorm,
            "directional: fd {fd} analytic {an}"
        );
        for _ in 0..40 {
            let i = (r.next_u64() % img.len() as u64) as usize;
            let mut p = img64.clone();
            p[i] += eps;
            let mut m = img64.clone();
            m[i] -= eps;
            let fd = (loss(&p) - loss(&m)) / (2.0 * eps);
            assert!(
                (fd - g[i] as f64).abs() <= 1e-3 * gmax,
                "pixel {i}: fd {fd} analytic {} (max |g| {gmax})",
                g[i]
            );
        }
    }

    #[test]
    fn too_small_and_bad_gradient_are_errors() {
        let net = Vgg16::random(1, 16);
        assert!(net.forward(&image(1, 7, 9), 7, 9, Layer::Relu4_3).is_err());
        assert!(net.forward(&image(1, 8, 8), 8, 8, Layer::Relu4_3).is_ok());
        assert!(net.forward(&[0.0; 5], 8, 8, Layer::Relu1_1).is_err());
        let f = net
            .forward(&image(1, 16, 16), 16, 16, Layer::Relu2_2)
            .unwrap();
        let t = Tensor3::zeros(1, 1, 1);
        assert!(net.backward(&f, &[(Layer::Relu2_2, &t)]).is_err());
        let a = f.get(Layer::Relu2_2).clone();
        assert!(net.backward(&f, &[(Layer::Relu3_1, &a)]).is_err());
        assert!(net.backward(&f, &[]).is_err());
    }

    #[test]
    fn banding_does_not_change_results() {
        // A single-thread pool gives different band splits than the default pool.
        let net = Vgg16::random(2, 8);
        let (h, w) = (37, 29);
        let img = image(4, h, w);
        let a = net.forward(&img, h, w, Layer::Relu3_3).unwrap();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let b = pool.install(|| net.forward(&img, h, w, Layer::Relu3_3).unwrap());
        assert_eq!(a.get(Layer::Relu3_3), b.get(Layer::Relu3_3));
    }

    #[test]
    fn style_size_limits() {
        let p = std::path::Path::new("style.png");
        let small = crate::imageio::Image {
            width: 91,
            height: 300,
            data: vec![0.5; 91 * 300 * 3],
        };
        let e = prepare_style(&small, 256, p).unwrap_err().to_string();
        assert!(e.contains("style.png") && e.contains("92"), "{e}");
        let ok = crate::imageio::Image {
            width: 92,
            height: 184,
            data: vec![0.5; 92 * 184 * 3],
        };
        let s = prepare_style(&ok, 128, p).unwrap();
        assert_eq!((s.width, s.height), (128, 256));
        assert!(s.data.iter().all(|&v| (v - 0.5).abs() < 1e-6));
        assert!(prepare_style(&ok, 64, p).is_err());
    }
}

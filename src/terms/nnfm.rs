//! Nearest-neighbour feature matching (NNFM), the loss of ARF (Zhang et al. 2022,
//! "ARF: Artistic Radiance Fields", Eq. 1): the matching itself, which the method's `nnfm`
//! texture term ([`super::texture`]) and the NNFM baseline ([`crate::baselines::nnfm`],
//! which adds a content loss) both use.
//!
//! Features are the relu3 block of VGG16 (relu3_1, relu3_2, relu3_3 concatenated along
//! channels, as ARF does), `F(x)` with one column `f_i` per position. For the style image
//! the columns `s_j` are normalised once. Then
//!
//! `L_nnfm = 1/N sum_i (1 - cos(f_i, s_{j*(i)}))`, `j*(i) = argmax_j cos(f_i, s_j)`,
//!
//! with `cos(f, s) = f . s_hat / sqrt(|f|^2 + 1e-10)` (the small constant keeps an
//! all-zero ReLU column finite). The matching `j*` is piecewise constant, so the gradient
//! treats it as fixed: `d cos / d f = s_hat / n - cos f / n^2`.

use crate::vgg::{Forward, Layer, Tensor3};
use crate::{Error, Result};
use ndarray::{Array2, ArrayView2, Axis, linalg::general_mat_mul};
use ort::session::Session;
use rayon::prelude::*;
use std::sync::Mutex;

/// The layers whose features are matched.
pub const NNFM_LAYERS: [Layer; 3] = [Layer::Relu3_1, Layer::Relu3_2, Layer::Relu3_3];

const NORM_EPS: f32 = 1e-10;
/// Render positions per similarity tile (bounds the `[tile, N_style]` matrix).
const TILE: usize = 256;

/// `[C_total, N]` concatenation of `layers` of a forward pass (layers of one VGG block:
/// the same spatial size).
pub fn stacked(fw: &Forward, layers: &[Layer]) -> Array2<f32> {
    let parts: Vec<ArrayView2<'_, f32>> = layers.iter().map(|&l| fw.get(l).matrix()).collect();
    ndarray::concatenate(Axis(0), &parts).expect("same spatial size")
}

/// The style's stacked features at `layers` with every column scaled to unit length
/// (the `s_hat` of [`nnfm_loss_grad`]).
pub fn normalised_style(fw: &Forward, layers: &[Layer]) -> Array2<f32> {
    let mut s = stacked(fw, layers);
    for mut col in s.columns_mut() {
        let n = (col.iter().map(|v| v * v).sum::<f32>() + NORM_EPS).sqrt();
        col.mapv_inplace(|v| v / n);
    }
    s
}

/// dL/d(stacked features) `[C_total, N]` split back into one tensor per layer, for the
/// VGG backward.
pub fn split_stacked(fw: &Forward, layers: &[Layer], g: &Array2<f32>) -> Vec<(Layer, Tensor3)> {
    let mut row = 0;
    layers
        .iter()
        .map(|&l| {
            let a = fw.get(l);
            let part = g.slice(ndarray::s![row..row + a.c, ..]);
            row += a.c;
            let data = part.iter().copied().collect();
            (
                l,
                Tensor3 {
                    c: a.c,
                    h: a.h,
                    w: a.w,
                    data,
                },
            )
        })
        .collect()
}

/// NNFM loss of stacked features `f` against normalised style columns `s_hat`, and
/// dL/df scaled by `scale`. With `weights` (one per position, >= 0) the loss is the
/// weighted mean `sum_i w_i (1 - cos_i) / sum_i w_i` (a coverage mask: positions of
/// weight 0 are not searched and get no gradient); without, the plain mean. The nearest
/// columns are searched in Rust ([`StyleColumns`] can search on onnxruntime instead).
pub fn nnfm_loss_grad(
    f: ArrayView2<'_, f32>,
    s_hat: ArrayView2<'_, f32>,
    weights: Option<&[f32]>,
    scale: f32,
) -> (f64, Array2<f32>) {
    let search = |ft: ArrayView2<'_, f32>| Ok(nearest_tiled(ft, s_hat));
    loss_grad_with(f, s_hat, weights, scale, search).expect("the Rust search cannot fail")
}

/// The style's unit columns `s_hat` (`[C, N_style]`) with the search for each render
/// position's nearest one, `argmax_j f_i . s_hat_j`: one GEMM and a row argmax, on
/// onnxruntime (one `MatMul` + `ArgMax` graph holding `s_hat` as a constant; the first
/// maximum on ties, as the Rust search) or, without, in Rust ([`nnfm_loss_grad`]).
/// The search is most of the NNFM statistic's cost (`2 n C N_style` flops).
pub struct StyleColumns {
    s_hat: Array2<f32>,
    search: Option<Mutex<Session>>,
}

impl std::fmt::Debug for StyleColumns {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StyleColumns")
            .field("shape", &self.s_hat.dim())
            .field("on_onnxruntime", &self.search.is_some())
            .finish()
    }
}

impl StyleColumns {
    /// `s_hat` searched on onnxruntime with that many intra-op threads when
    /// `onnxruntime` is `Some` (the VGG's engine, [`crate::vgg::Vgg16::onnxruntime_threads`]), else
    /// in Rust.
    pub fn new(s_hat: Array2<f32>, onnxruntime: Option<usize>) -> Result<Self> {
        let search = match onnxruntime {
            None => None,
            Some(threads) => Some(Mutex::new(search_session(s_hat.view(), threads)?)),
        };
        Ok(StyleColumns { s_hat, search })
    }

    /// [`nnfm_loss_grad`] against these columns.
    pub fn loss_grad(
        &self,
        f: ArrayView2<'_, f32>,
        weights: Option<&[f32]>,
        scale: f32,
    ) -> Result<(f64, Array2<f32>)> {
        let s_hat = self.s_hat.view();
        match &self.search {
            None => Ok(nnfm_loss_grad(f, s_hat, weights, scale)),
            Some(session) => loss_grad_with(f, s_hat, weights, scale, |ft| {
                let mut session = session.lock().map_err(onnx)?;
                nearest_onnx(&mut session, ft, s_hat.ncols())
            }),
        }
    }
}

fn onnx(e: impl std::fmt::Display) -> Error {
    Error::Onnx(format!("NNFM search on onnxruntime: {e}"))
}

/// `nearest = ArgMax(MatMul(ft, s_hat), axis 1)` for `ft` = `[n, C]`.
fn search_session(s_hat: ArrayView2<'_, f32>, threads: usize) -> Result<Session> {
    use crate::runtime::graph::{constant, int, model, node, outlet};
    use ort::value::TensorElementType as T;
    crate::runtime::environment()?;
    let (c, ns) = s_hat.dim();
    let mut g = ort::editor::Graph::new().map_err(onnx)?;
    g.set_inputs([outlet("f", T::Float32, &[-1, c as i64], &["n", ""])])
        .map_err(onnx)?;
    let data = s_hat.as_standard_layout();
    let data = data.as_slice().expect("standard layout");
    constant(&mut g, "s", &[c, ns], data).map_err(onnx)?;
    node(&mut g, "MatMul", &["f", "s"], &["sims"], vec![]).map_err(onnx)?;
    let attrs = vec![
        int("axis", 1).map_err(onnx)?,
        int("keepdims", 0).map_err(onnx)?,
    ];
    node(&mut g, "ArgMax", &["sims"], &["nearest"], attrs).map_err(onnx)?;
    g.set_outputs([outlet("nearest", T::Int64, &[-1], &["n"])])
        .map_err(onnx)?;
    let cfg = crate::runtime::SessionConfig {
        threads,
        ..Default::default()
    };
    crate::runtime::session_from_model(model(g).map_err(onnx)?, &cfg, "NNFM search graph")
}

fn nearest_onnx(session: &mut Session, ft: ArrayView2<'_, f32>, ns: usize) -> Result<Vec<usize>> {
    let ft = ft.as_standard_layout();
    let input = ort::value::TensorRef::from_array_view((
        [ft.nrows(), ft.ncols()],
        ft.as_slice().expect("standard layout"),
    ))
    .map_err(onnx)?;
    let out = session.run(ort::inputs!["f" => input]).map_err(onnx)?;
    let (_, nn) = out
        .get("nearest")
        .ok_or_else(|| onnx("no output nearest"))?
        .try_extract_tensor::<i64>()
        .map_err(onnx)?;
    nn.iter()
        .map(|&j| {
            usize::try_from(j)
                .ok()
                .filter(|&j| j < ns)
                .ok_or_else(|| onnx(format!("index {j} out of range")))
        })
        .collect()
}

/// Nearest column of `s_hat` for each row of `ft` (`[n, C]`), tile by tile in parallel.
fn nearest_tiled(ft: ArrayView2<'_, f32>, s_hat: ArrayView2<'_, f32>) -> Vec<usize> {
    let starts: Vec<usize> = (0..ft.nrows()).step_by(TILE).collect();
    starts
        .par_iter()
        .flat_map_iter(|&k0| {
            let k1 = (k0 + TILE).min(ft.nrows());
            let mut sims = Array2::zeros((k1 - k0, s_hat.ncols()));
            general_mat_mul(
                1.0,
                &ft.slice(ndarray::s![k0..k1, ..]),
                &s_hat,
                0.0,
                &mut sims,
            );
            (0..k1 - k0)
                .map(|r| {
                    let row = sims.row(r);
                    let mut best = 0;
                    for (j, &v) in row.iter().enumerate() {
                        if v > row[best] {
                            best = j;
                        }
                    }
                    best
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// The loss and gradient with the nearest columns found by `search` (given the searched
/// positions' features as rows, `[n_active, C]`; unnormalised `f` suffices for the argmax).
fn loss_grad_with(
    f: ArrayView2<'_, f32>,
    s_hat: ArrayView2<'_, f32>,
    weights: Option<&[f32]>,
    scale: f32,
    search: impl FnOnce(ArrayView2<'_, f32>) -> Result<Vec<usize>>,
) -> Result<(f64, Array2<f32>)> {
    let (c, n) = f.dim();
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let wsum: f64 = (0..n).map(|i| w(i) as f64).sum();
    if wsum <= 0.0 {
        return Ok((0.0, Array2::zeros((c, n))));
    }
    // `f` is `[C, N]` row-major: per-position sums run along its rows (contiguous), not
    // down its columns.
    let mut sq = vec![0.0f32; n];
    for row in f.rows() {
        for (s, v) in sq.iter_mut().zip(row) {
            *s += v * v;
        }
    }
    let norms: Vec<f32> = sq.iter().map(|s| (s + NORM_EPS).sqrt()).collect();
    // Only searched positions (weight > 0) are gathered: weight-0 ones cost nothing.
    let active: Vec<usize> = (0..n).filter(|&i| w(i) > 0.0).collect();
    let ft = Array2::from_shape_fn((active.len(), c), |(r, ch)| f[[ch, active[r]]]);
    let found = search(ft.view())?;
    let mut nn = vec![0usize; n];
    for (&i, j) in active.iter().zip(found) {
        nn[i] = j;
    }
    let mut dot = vec![0.0f32; n];
    for (frow, srow) in f.rows().into_iter().zip(s_hat.rows()) {
        for i in 0..n {
            dot[i] += frow[i] * srow[nn[i]];
        }
    }
    let cos: Vec<f32> = dot.iter().zip(&norms).map(|(d, m)| d / m).collect();
    // dL/df_i = -k_i (s_hat_j*(i) / |f_i| - cos_i f_i / |f_i|^2), k_i the position's share
    // of `scale` (0 where unsearched).
    let k: Vec<f32> = (0..n)
        .map(|i| match (w(i), weights) {
            (0.0, _) => 0.0,
            (_, None) => scale / n as f32,
            (wi, Some(_)) => scale * (wi as f64 / wsum) as f32,
        })
        .collect();
    let loss: f64 = (0..n)
        .filter(|&i| w(i) > 0.0)
        .map(|i| w(i) as f64 * (1.0 - cos[i] as f64))
        .sum();
    let mut grad = vec![0.0f32; c * n];
    grad.par_chunks_mut(n).enumerate().for_each(|(ch, g)| {
        let (frow, srow) = (f.row(ch), s_hat.row(ch));
        for i in 0..n {
            if k[i] != 0.0 {
                let nrm = norms[i];
                g[i] = -k[i] * (srow[nn[i]] / nrm - cos[i] * frow[i] / (nrm * nrm));
            }
        }
    });
    let grad = Array2::from_shape_vec((c, n), grad).expect("c x n values");
    Ok((loss / wsum, grad))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rand(seed: u64, r: usize, c: usize) -> Array2<f32> {
        let mut g = crate::rng::Rng::new(seed);
        Array2::from_shape_fn((r, c), |_| g.normal() as f32)
    }

    /// Random style columns scaled to unit length (an `s_hat`).
    fn unit_columns(seed: u64, r: usize, c: usize) -> Array2<f32> {
        let mut s = rand(seed, r, c);
        for mut col in s.columns_mut() {
            let n = col.iter().map(|v| v * v).sum::<f32>().sqrt();
            col.mapv_inplace(|v| v / n);
        }
        s
    }

    /// NNFM gradient w.r.t. features vs central differences (the nearest neighbour does not
    /// switch within eps for these random features; checked by recomputing it).
    #[test]
    fn nnfm_gradient_matches_finite_differences() {
        let f = rand(1, 6, 9);
        let s = unit_columns(2, 6, 13);
        let (l0, g) = nnfm_loss_grad(f.view(), s.view(), None, 1.0);
        assert!(l0 > 0.0 && l0 < 2.0);
        let eps = 1e-3f32;
        for i in 0..6 {
            for j in 0..9 {
                let mut p = f.clone();
                p[[i, j]] += eps;
                let mut m = f.clone();
                m[[i, j]] -= eps;
                let fd = (nnfm_loss_grad(p.view(), s.view(), None, 1.0).0
                    - nnfm_loss_grad(m.view(), s.view(), None, 1.0).0)
                    / (2.0 * eps as f64);
                assert!(
                    (fd - g[[i, j]] as f64).abs() <= 1e-3,
                    "({i},{j}): fd {fd} analytic {}",
                    g[[i, j]]
                );
            }
        }
    }

    /// Coverage weights: the weighted loss against central differences, weight-0
    /// positions get no gradient, and all-ones weights give the unweighted loss.
    #[test]
    fn weighted_nnfm_gradient_matches_finite_differences() {
        let f = rand(4, 5, 8);
        let s = unit_columns(5, 5, 11);
        let w = [0.0f32, 0.3, 1.0, 0.0, 0.7, 1.0, 0.5, 0.9];
        let (l0, g) = nnfm_loss_grad(f.view(), s.view(), Some(&w), 1.0);
        assert!(l0 > 0.0);
        let eps = 1e-3f32;
        for i in 0..5 {
            for j in 0..8 {
                let (mut p, mut m) = (f.clone(), f.clone());
                p[[i, j]] += eps;
                m[[i, j]] -= eps;
                let fd = (nnfm_loss_grad(p.view(), s.view(), Some(&w), 1.0).0
                    - nnfm_loss_grad(m.view(), s.view(), Some(&w), 1.0).0)
                    / (2.0 * eps as f64);
                assert!(
                    (fd - g[[i, j]] as f64).abs() <= 1e-3,
                    "({i},{j}): fd {fd}, {}",
                    g[[i, j]]
                );
                if w[j] == 0.0 {
                    assert_eq!(g[[i, j]], 0.0);
                }
            }
        }
        let (lu, _) = nnfm_loss_grad(f.view(), s.view(), None, 1.0);
        let (l1, _) = nnfm_loss_grad(f.view(), s.view(), Some(&[1.0; 8]), 1.0);
        assert!((lu - l1).abs() < 1e-12, "{lu} vs {l1}");
        let (lz, gz) = nnfm_loss_grad(f.view(), s.view(), Some(&[0.0; 8]), 1.0);
        assert!(lz == 0.0 && gz.iter().all(|&v| v == 0.0));
    }

    /// A feature equal to a style column has zero loss there; the loss is in [0, 2].
    #[test]
    fn exact_match_has_zero_loss() {
        let s = unit_columns(3, 4, 5);
        let f = s.mapv(|v| 3.0 * v);
        let (l, _) = nnfm_loss_grad(f.view(), s.view(), None, 1.0);
        assert!(l.abs() < 1e-6, "{l}");
    }
}

//! Patch banks: the clean k x k patches of an image (a style image, or the source views)
//! with their centre pixels, and a PCA basis that reduces them for the nearest-neighbour
//! search ([`super::denoise`]).
//!
//! A patch of a `[C, h, w]` image around pixel (y, x) is the vector of its k x k x C
//! values in the order (dy, dx, c), taken with mirror padding at the borders (numpy's
//! `np.pad(mode="reflect")`: the edge pixel is not repeated), so every pixel has a patch
//! and the denoiser's output has the image's size.

use crate::rng::Rng;
use crate::{Error, Result};
use ndarray::{Array1, Array2, ArrayView2, ArrayView3, Axis};
use rayon::prelude::*;

/// Mirror index `i` into `0..n` without repeating the edge (numpy's "reflect").
pub fn reflect(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let mut j = i.rem_euclid(period);
    if j >= n as isize {
        j = period - j;
    }
    j as usize
}

/// The k x k patches of `img` `[C, h, w]` around the pixels of the grid with step
/// `stride` (1: every pixel), row-major over the grid: `[M, k k C]` in (dy, dx, c) order.
pub fn patches(img: ArrayView3<'_, f32>, k: usize, stride: usize) -> Array2<f32> {
    let (c, h, w) = img.dim();
    let stride = stride.max(1);
    let ys: Vec<usize> = (0..h).step_by(stride).collect();
    let xs: Vec<usize> = (0..w).step_by(stride).collect();
    let r = (k / 2) as isize;
    let d = k * k * c;
    let mut out = vec![0.0f32; ys.len() * xs.len() * d];
    out.par_chunks_mut(xs.len() * d)
        .zip(ys.par_iter())
        .for_each(|(rows, &y)| {
            let mut q = 0;
            for &x in &xs {
                for dy in -r..=r {
                    let yy = reflect(y as isize + dy, h);
                    for dx in -r..=r {
                        let xx = reflect(x as isize + dx, w);
                        for ci in 0..c {
                            rows[q] = img[[ci, yy, xx]];
                            q += 1;
                        }
                    }
                }
            }
        });

    Array2::from_shape_vec((ys.len() * xs.len(), d), out).expect("length matches")
}

/// The k x k patches `[P, k k C]` of a batch `[B, C, h, w]` around `pixels` (b, y, x),
/// in their order (the same vectors as [`patches`]).
pub fn patches_at(z: ndarray::ArrayView4<'_, f32>, k: usize, pixels: &[[usize; 3]]) -> Array2<f32> {
    let (_, c, h, w) = z.dim();
    let r = (k / 2) as isize;
    let d = k * k * c;
    let mut out = vec![0.0f32; pixels.len() * d];
    out.par_chunks_mut(d)
        .zip(pixels.par_iter())
        .for_each(|(row, &[b, y, x])| {
            let mut q = 0;
            for dy in -r..=r {
                let yy = reflect(y as isize + dy, h);
                for dx in -r..=r {
                    let xx = reflect(x as isize + dx, w);
                    for ci in 0..c {
                        row[q] = z[[b, ci, yy, xx]];
                        q += 1;
                    }
                }
            }
        });
    Array2::from_shape_vec((pixels.len(), d), out).expect("length matches")
}

/// The centre pixels `[M, C]` of patches `[M, k k C]`.
pub fn centres(patches: ArrayView2<'_, f32>, k: usize, channels: usize) -> Array2<f32> {
    let mid = (k / 2) * k + k / 2;
    patches
        .slice(ndarray::s![.., mid * channels..(mid + 1) * channels])
        .to_owned()
}

/// A PCA basis of patch vectors: `mean` `[D]`, `basis` `[D, d]` with orthonormal columns
/// (the leading principal directions).
#[derive(Debug, Clone)]
pub struct Pca {
    pub mean: Array1<f32>,
    pub basis: Array2<f32>,
}

impl Pca {
    /// The leading `dims` principal directions of the rows of `x` `[M, D]`, by subspace
    /// iteration (block power method, Golub & Van Loan Sec. 8.2.4) on the centred rows:
    /// V <- orth(X^T (X V)), `iters` times from a seeded Gaussian start. Deterministic for
    /// a given input. `dims` is capped at D.
    pub fn fit(x: ArrayView2<'_, f32>, dims: usize, iters: usize) -> Result<Pca> {
        let (m, d) = x.dim();
        if m == 0 || d == 0 {
            return Err(Error::param("PCA of an empty patch set"));
        }
        let dims = dims.min(d).max(1);
        let mean = x.mean_axis(Axis(0)).expect("non-empty");
        let xc = &x - &mean.view().insert_axis(Axis(0));
        let mut rng = Rng::derive(0, "patch-pca");
        let mut v =
            Array2::from_shape_vec((d, dims), rng.normals_f32(d * dims)).expect("length matches");
        orthonormalise(&mut v);
        for _ in 0..iters.max(1) {
            let xv = xc.dot(&v);
            v = xc.t().dot(&xv);
            orthonormalise(&mut v);
        }
        Ok(Pca { mean, basis: v })
    }

    /// Coordinates `[M, d]` of rows `x` `[M, D]` minus `shift` times the mean:
    /// (x - shift mean) basis.
    pub fn project(&self, x: ArrayView2<'_, f32>, shift: f32) -> Array2<f32> {
        let offset = self.mean.dot(&self.basis) * shift;
        let mut p = x.dot(&self.basis);
        p -= &offset.view().insert_axis(Axis(0));
        p
    }
}

/// Modified Gram-Schmidt on the columns of `v` (in place, f64 accumulation); a column
/// that vanishes is replaced by a unit vector not yet spanned.
fn orthonormalise(v: &mut Array2<f32>) {
    let (d, k) = v.dim();
    for j in 0..k {
        for i in 0..j {
            let dot: f64 = (0..d).map(|r| v[[r, i]] as f64 * v[[r, j]] as f64).sum();
            for r in 0..d {
                v[[r, j]] -= (dot * v[[r, i]] as f64) as f32;
            }
        }
        let norm: f64 = (0..d)
            .map(|r| (v[[r, j]] as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        if norm > 1e-12 {
            for r in 0..d {
                v[[r, j]] = (v[[r, j]] as f64 / norm) as f32;
            }
        } else {
            v.column_mut(j).fill(0.0);
            v[[j % d, j]] = 1.0;
        }
    }
}

/// Lloyd rounds of the inverted file's k-means.
const KMEANS_ITERS: usize = 10;

/// The clean patches of one model at one patch size, ready for the search.
#[derive(Debug, Clone)]
pub struct Bank {
    /// Patch side k (odd).
    pub k: usize,
    /// Channels C of the images the patches come from.
    pub channels: usize,
    /// `[M, k k C]`.
    pub patches: Array2<f32>,
    /// Centre pixels `[M, C]`: what a matched patch says its pixel is.
    pub centres: Array2<f32>,
    /// Squared norms of the patches `[M]`.
    pub norms: Array1<f32>,
    /// The reduced search space, if any.
    pub reduced: Option<Reduced>,
}

/// A bank in PCA coordinates.
#[derive(Debug, Clone)]
pub struct Reduced {
    pub pca: Pca,
    /// (patch - mean) basis, `[M, d]`.
    pub coords: Array2<f32>,
    /// Squared norms of `coords`, `[M]`.
    pub norms: Array1<f32>,
    /// An inverted-file index of `coords` (k-means cells), if the bank is large enough.
    pub ivf: Option<Ivf>,
}

/// An inverted-file index (Jegou et al. 2011's IVF, without quantisation): the bank's
/// coordinates clustered by k-means; a query searches only the cells of its nearest
/// centroids.
#[derive(Debug, Clone)]
pub struct Ivf {
    /// `[K, d]`.
    pub centroids: Array2<f32>,
    /// Squared norms of the centroids `[K]`.
    pub norms: Array1<f32>,
    /// The bank rows of each cell.
    pub cells: Vec<Vec<u32>>,
}

impl Ivf {
    /// `cells` k-means cells of `x` `[M, d]` (Lloyd's algorithm, `iters` rounds, from
    /// evenly spaced rows; an emptied cell keeps its centroid).
    pub fn fit(x: ArrayView2<'_, f32>, cells: usize, iters: usize) -> Ivf {
        let m = x.nrows();
        let k = cells.clamp(1, m);
        let mut centroids = Array2::from_shape_fn((k, x.ncols()), |(i, j)| x[[i * m / k, j]]);
        let mut assign = vec![0u32; m];
        for _ in 0..iters.max(1) {
            assign = nearest(x, centroids.view());
            let mut sum = Array2::<f64>::zeros(centroids.dim());
            let mut count = vec![0usize; k];
            for (i, &a) in assign.iter().enumerate() {
                count[a as usize] += 1;
                for (s, v) in sum.row_mut(a as usize).iter_mut().zip(x.row(i)) {
                    *s += *v as f64;
                }
            }
            for c in (0..k).filter(|&c| count[c] > 0) {
                for (dst, s) in centroids.row_mut(c).iter_mut().zip(sum.row(c)) {
                    *dst = (*s / count[c] as f64) as f32;
                }
            }
        }
        let mut lists = vec![Vec::new(); k];
        for (i, a) in assign.iter().enumerate() {
            lists[*a as usize].push(i as u32);
        }
        let norms = row_norms(centroids.view());
        Ivf {
            centroids,
            norms,
            cells: lists,
        }
    }
}

/// The nearest centroid of every row of `x` (one matrix product).
fn nearest(x: ArrayView2<'_, f32>, c: ArrayView2<'_, f32>) -> Vec<u32> {
    let cn = row_norms(c);
    let dots = x.dot(&c.t());
    dots.rows()
        .into_iter()
        .map(|row| {
            let mut best = (f32::INFINITY, 0u32);
            for (j, (d, n)) in row.iter().zip(cn.iter()).enumerate() {
                let v = n - 2.0 * d;
                if v < best.0 {
                    best = (v, j as u32);
                }
            }
            best.1
        })
        .collect()
}

impl Bank {
    /// The bank of `patches` `[M, k k C]` (from [`patches`]); with `pca` the search runs
    /// in its coordinates ([`Reduced`]), and with `cells` > 0 through an inverted file of
    /// that many cells.
    pub fn new(
        patches: Array2<f32>,
        k: usize,
        channels: usize,
        pca: Option<Pca>,
        cells: usize,
    ) -> Result<Bank> {
        if k.is_multiple_of(2) || patches.ncols() != k * k * channels || patches.nrows() == 0 {
            return Err(Error::param(format!(
                "patch bank: {} patches of width {} for k = {k}, C = {channels} (k odd, width k k C)",
                patches.nrows(),
                patches.ncols()
            )));
        }
        let centres = centres(patches.view(), k, channels);
        let norms = row_norms(patches.view());
        let reduced = pca.map(|pca| {
            let coords = pca.project(patches.view(), 1.0);
            let norms = row_norms(coords.view());
            let ivf = (cells > 0).then(|| Ivf::fit(coords.view(), cells, KMEANS_ITERS));
            Reduced {
                pca,
                coords,
                norms,
                ivf,
            }
        });
        Ok(Bank {
            k,
            channels,
            patches,
            centres,
            norms,
            reduced,
        })
    }

    /// Patches in the bank.
    pub fn len(&self) -> usize {
        self.patches.nrows()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Inverted-file cells (0: none).
    pub fn cells(&self) -> usize {
        self.reduced
            .as_ref()
            .and_then(|r| r.ivf.as_ref())
            .map_or(0, |i| i.cells.len())
    }

    /// Dimension the candidates are searched in (d with PCA, else k k C).
    pub fn search_dims(&self) -> usize {
        self.reduced
            .as_ref()
            .map_or(self.patches.ncols(), |r| r.coords.ncols())
    }
}

/// The moment-matched Gaussian of a bank's patches in probabilistic-PCA form (Tipping &
/// Bishop 1999): covariance U diag(lambda) U^T + residual (I - U U^T), from the bank's
/// PCA. The generic model the content mixture weighs the style's layout against.
#[derive(Debug, Clone)]
pub struct PatchGaussian {
    /// Variance of each PCA coordinate.
    pub lambda: Vec<f32>,
    /// Variance of each residual dimension.
    pub residual: f32,
    /// Patch dimension D.
    pub dims: usize,
}

impl PatchGaussian {
    /// The Gaussian of `bank`'s patches (its PCA coordinates' variances, and the rest of
    /// the total variance spread over the remaining dimensions); `None` without PCA.
    pub fn of(bank: &Bank) -> Option<PatchGaussian> {
        let red = bank.reduced.as_ref()?;
        let m = bank.len().max(1) as f64;
        let lambda: Vec<f32> = red
            .coords
            .columns()
            .into_iter()
            .map(|c| (c.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / m) as f32)
            .collect();
        let centred = &bank.patches - &red.pca.mean.view().insert_axis(Axis(0));
        let total = centred.iter().map(|v| (*v as f64).powi(2)).sum::<f64>() / m;
        let kept: f64 = lambda.iter().map(|v| *v as f64).sum();
        let dims = bank.patches.ncols();
        let rest = (dims - lambda.len()).max(1) as f64;
        Some(PatchGaussian {
            residual: (((total - kept) / rest).max(1e-6)) as f32,
            lambda,
            dims,
        })
    }

    /// log N(x; sa mu, sa^2 S + sb^2 I) for a query whose PCA coordinates (of x - sa mu)
    /// are `coords` and whose squared distance to sa mu is `dist2`.
    pub fn log_density(
        &self,
        coords: ndarray::ArrayView1<'_, f32>,
        dist2: f32,
        sa: f32,
        sb: f32,
    ) -> f32 {
        let two_pi = 2.0 * std::f32::consts::PI;
        let mut ll = 0.0f32;
        let mut kept = 0.0f32;
        for (c, l) in coords.iter().zip(&self.lambda) {
            let v = sa * sa * l + sb * sb;
            ll -= 0.5 * (c * c / v + (two_pi * v).ln());
            kept += c * c;
        }
        let v = sa * sa * self.residual + sb * sb;
        let rest = (self.dims - self.lambda.len()) as f32;
        ll - 0.5 * ((dist2 - kept).max(0.0) / v + rest * (two_pi * v).ln())
    }
}

/// Squared Euclidean norm of every row.
pub fn row_norms(x: ArrayView2<'_, f32>) -> Array1<f32> {
    x.rows().into_iter().map(|r| r.dot(&r)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::Array3;

    #[test]
    fn reflect_mirrors_without_repeating_the_edge() {
        let got: Vec<usize> = (-3..8).map(|i| reflect(i, 5)).collect();
        assert_eq!(got, vec![3, 2, 1, 0, 1, 2, 3, 4, 3, 2, 1]);
        assert_eq!(reflect(-2, 1), 0);
    }

    #[test]
    fn patch_centres_are_the_pixels() {
        let img = Array3::from_shape_fn((2, 4, 5), |(c, y, x)| (c * 100 + y * 10 + x) as f32);
        let p = patches(img.view(), 3, 1);
        assert_eq!(p.dim(), (20, 18));
        let c = centres(p.view(), 3, 2);
        for y in 0..4 {
            for x in 0..5 {
                assert_eq!(c[[y * 5 + x, 0]], img[[0, y, x]]);
                assert_eq!(c[[y * 5 + x, 1]], img[[1, y, x]]);
            }
        }
        // Top-left neighbour of (0, 0) is the mirrored (1, 1).
        assert_eq!(p[[0, 0]], img[[0, 1, 1]]);
        let strided = patches(img.view(), 3, 2);
        assert_eq!(strided.nrows(), 2 * 3);
        assert_eq!(strided.row(1), p.row(2));
    }

    #[test]
    fn pca_finds_the_dominant_directions() {
        // Points on a 2D plane in 6D plus tiny noise: two components carry everything.
        let mut rng = Rng::new(3);
        let x = Array2::from_shape_fn((400, 6), |(_, j)| match j {
            0 | 1 => 0.0,
            _ => 0.0,
        });
        let mut x = x;
        for mut r in x.rows_mut() {
            let (a, b) = (rng.normal() as f32, rng.normal() as f32);
            let v = [a + b, a - b, 2.0 * a, 0.5 * b, 0.0, 1.0];
            for j in 0..6 {
                r[j] = v[j] + 1e-3 * rng.normal() as f32;
            }
        }
        let pca = Pca::fit(x.view(), 2, 30).unwrap();
        let gram = pca.basis.t().dot(&pca.basis);
        for i in 0..2 {
            for j in 0..2 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((gram[[i, j]] - want).abs() < 1e-5, "{gram:?}");
            }
        }
        // Reconstruction from two coordinates loses only the noise.
        let coords = pca.project(x.view(), 1.0);
        let back = coords.dot(&pca.basis.t()) + pca.mean.view().insert_axis(Axis(0));
        let err = (&back - &x).mapv(|v| v * v).mean().unwrap().sqrt();
        assert!(err < 5e-3, "rms reconstruction error {err}");
    }
}

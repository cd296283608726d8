//! Dense symmetric linear algebra in `f64` for the Fréchet distance: the cyclic Jacobi
//! eigenvalue method (Golub & Van Loan, "Matrix Computations", Sec. 8.5) and the square
//! root of a positive semi-definite matrix built from it.
//!
//! Matrices are row-major `n x n` slices.

/// Eigen-decomposition of a symmetric matrix: `a = V diag(values) V^T`; `vectors` holds
/// V row-major (eigenvector `k` is column `k`). Eigenvalues are sorted descending.
#[derive(Debug, Clone)]
pub struct SymEig {
    pub n: usize,
    pub values: Vec<f64>,
    pub vectors: Vec<f64>,
}

/// Cyclic Jacobi: sweep all off-diagonal pairs with plane rotations until the
/// off-diagonal norm is below `1e-14` of the Frobenius norm (at most 100 sweeps;
/// convergence is quadratic, typically 6-12 sweeps). The input is symmetrised first.
pub fn sym_eig(a: &[f64], n: usize) -> SymEig {
    assert_eq!(a.len(), n * n, "sym_eig: matrix is not n x n");
    let mut m: Vec<f64> = (0..n * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            0.5 * (a[i * n + j] + a[j * n + i])
        })
        .collect();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    let fro: f64 = m.iter().map(|x| x * x).sum::<f64>().sqrt();
    let tol = 1e-14 * fro.max(f64::MIN_POSITIVE);
    for _sweep in 0..100 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| m[i * n + j] * m[i * n + j])
            .sum::<f64>()
            .sqrt();
        if off <= tol {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = m[p * n + q];
                if apq.abs() <= 1e-300 {
                    continue;
                }
                let (app, aqq) = (m[p * n + p], m[q * n + q]);
                // Rotation angle zeroing m[p][q] (stable formulation).
                let theta = (aqq - app) / (2.0 * apq);
                let sign = if theta >= 0.0 { 1.0 } else { -1.0 };
                let t = sign / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // m <- J^T m J on rows/cols p, q.
                for k in 0..n {
                    let (mkp, mkq) = (m[k * n + p], m[k * n + q]);
                    m[k * n + p] = c * mkp - s * mkq;
                    m[k * n + q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let (mpk, mqk) = (m[p * n + k], m[q * n + k]);
                    m[p * n + k] = c * mpk - s * mqk;
                    m[q * n + k] = s * mpk + c * mqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| m[b * n + b].total_cmp(&m[a * n + a]));
    let values = order.iter().map(|&k| m[k * n + k]).collect();
    let mut vectors = vec![0.0; n * n];
    for (newk, &k) in order.iter().enumerate() {
        for i in 0..n {
            vectors[i * n + newk] = v[i * n + k];
        }
    }
    SymEig { n, values, vectors }
}

/// `V f(diag) V^T` for a decomposition.
pub fn reconstruct(e: &SymEig, f: impl Fn(f64) -> f64) -> Vec<f64> {
    let n = e.n;
    let fv: Vec<f64> = e.values.iter().map(|&x| f(x)).collect();
    let mut out = vec![0.0; n * n];
    for i in 0..n {
        for j in i..n {
            let mut s = 0.0;
            for k in 0..n {
                s += e.vectors[i * n + k] * fv[k] * e.vectors[j * n + k];
            }
            out[i * n + j] = s;
            out[j * n + i] = s;
        }
    }
    out
}

/// Square root of a symmetric positive semi-definite matrix; eigenvalues below zero
/// (rounding) are clamped to zero.
pub fn sqrtm_psd(a: &[f64], n: usize) -> Vec<f64> {
    reconstruct(&sym_eig(a, n), |x| x.max(0.0).sqrt())
}

/// `a (n x k) * b (k x m)`, row-major.
pub fn matmul(a: &[f64], b: &[f64], n: usize, k: usize, m: usize) -> Vec<f64> {
    let mut out = vec![0.0; n * m];
    for i in 0..n {
        for t in 0..k {
            let x = a[i * k + t];
            if x == 0.0 {
                continue;
            }
            for j in 0..m {
                out[i * m + j] += x * b[t * m + j];
            }
        }
    }
    out
}

/// Trace of a square matrix.
pub fn trace(a: &[f64], n: usize) -> f64 {
    (0..n).map(|i| a[i * n + i]).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_sym(n: usize, seed: u64) -> Vec<f64> {
        let mut r = Rng::new(seed);
        let g: Vec<f64> = (0..n * n).map(|_| r.normal()).collect();
        (0..n * n)
            .map(|k| {
                let (i, j) = (k / n, k % n);
                g[i * n + j] + g[j * n + i]
            })
            .collect()
    }

    #[test]
    fn jacobi_reconstructs_and_is_orthonormal() {
        for (n, seed) in [(1, 1), (2, 2), (7, 3), (30, 4)] {
            let a = random_sym(n, seed);
            let e = sym_eig(&a, n);
            let back = reconstruct(&e, |x| x);
            let err = a
                .iter()
                .zip(&back)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(err < 1e-10, "n={n} reconstruction error {err}");
            let vtv = matmul(
                &(0..n * n)
                    .map(|k| e.vectors[(k % n) * n + k / n])
                    .collect::<Vec<_>>(),
                &e.vectors,
                n,
                n,
                n,
            );
            for i in 0..n {
                for j in 0..n {
                    let want = if i == j { 1.0 } else { 0.0 };
                    assert!((vtv[i * n + j] - want).abs() < 1e-10);
                }
            }
            assert!(e.values.windows(2).all(|w| w[0] >= w[1]));
            // trace is preserved
            assert!((trace(&a, n) - e.values.iter().sum::<f64>()).abs() < 1e-9);
        }
    }

    #[test]
    fn jacobi_known_2x2() {
        // [[2,1],[1,2]] has eigenvalues 3 and 1.
        let e = sym_eig(&[2.0, 1.0, 1.0, 2.0], 2);
        assert!((e.values[0] - 3.0).abs() < 1e-14 && (e.values[1] - 1.0).abs() < 1e-14);
    }

    #[test]
    fn sqrtm_squares_back() {
        let n = 12;
        let g = random_sym(n, 9);
        let a = matmul(&g, &g, n, n, n); // PSD
        let s = sqrtm_psd(&a, n);
        let ss = matmul(&s, &s, n, n, n);
        let err = a
            .iter()
            .zip(&ss)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        let scale = a.iter().map(|x| x.abs()).fold(0.0, f64::max);
        assert!(err < 1e-10 * scale, "sqrtm error {err}");
    }
}

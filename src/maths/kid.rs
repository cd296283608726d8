//! The estimate behind the Kernel Inception Distance (Bińkowski et al. 2018): the
//! unbiased MMD² between two sets of feature vectors with the polynomial kernel
//! `k(x, y) = (x·y / d + 1)^3`, from kernel matrices, over the kept rows of each set
//! (all of them for KID itself, all but one for a jackknife replicate).
//!
//! The one copy of the kernel: [`crate::metrics::fid::kid`] and the jackknife of
//! [`crate::metrics::texture::kid_jackknife`] both build on it. All sums are in f64, in
//! index order (`i` outer, `j` inner), as each of them summed before.

/// The kernel matrix `k(x_i, y_j) = (x_i . y_j / d + 1)^3` of the `na` rows of `a` and
/// the `nb` rows of `b` (row-major, `d` values per row), `na x nb` row-major.
pub fn kernel_matrix(a: &[f64], na: usize, b: &[f64], nb: usize, d: usize) -> Vec<f64> {
    let df = d as f64;
    let mut k = vec![0.0; na * nb];
    for (i, x) in a.chunks(d).enumerate() {
        for (j, y) in b.chunks(d).enumerate() {
            let dot: f64 = x.iter().zip(y).map(|(p, q)| p * q).sum();
            k[i * nb + j] = (dot / df + 1.0).powi(3);
        }
    }
    k
}

/// The mean of an `n x n` kernel matrix `k` over the pairs `i != j` of kept rows
/// (`keep[i]`): the sum, `i` outer and `j` inner, divided by `m (m - 1)` for `m` kept.
pub fn within_mean(k: &[f64], n: usize, keep: &[bool]) -> f64 {
    let (mut s, m) = (0.0, keep.iter().filter(|&&x| x).count());
    for i in (0..n).filter(|&i| keep[i]) {
        for j in (0..n).filter(|&j| keep[j] && j != i) {
            s += k[i * n + j];
        }
    }
    s / (m * (m - 1)) as f64
}

/// The sum of an `na x nb` kernel matrix `kab` over the kept rows (`ka`) and columns
/// (`kb`), `i` outer and `j` inner.
pub fn cross_sum(kab: &[f64], na: usize, nb: usize, ka: &[bool], kb: &[bool]) -> f64 {
    let mut cross = 0.0;
    for i in (0..na).filter(|&i| ka[i]) {
        for j in (0..nb).filter(|&j| kb[j]) {
            cross += kab[i * nb + j];
        }
    }
    cross
}

/// Unbiased MMD² from kernel matrices, over the kept rows/columns:
/// `within(kaa) + within(kbb) - 2 cross / (ma mb)` (the doubling before the division;
/// [`crate::metrics::fid::kid`] divides first and composes the same parts itself).
pub fn mmd2(
    kaa: &[f64],
    kbb: &[f64],
    kab: &[f64],
    na: usize,
    nb: usize,
    ka: &[bool],
    kb: &[bool],
) -> f64 {
    let (ma, mb) = (
        ka.iter().filter(|&&x| x).count(),
        kb.iter().filter(|&&x| x).count(),
    );
    let cross = cross_sum(kab, na, nb, ka, kb);
    within_mean(kaa, na, ka) + within_mean(kbb, nb, kb) - 2.0 * cross / (ma * mb) as f64
}

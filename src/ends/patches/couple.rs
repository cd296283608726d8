//! The balance of the synthesis: an entropic coupling of the object's patches to the
//! style bank's k-means cells, made in the log domain by Sinkhorn's iterations, the
//! cells' marginal their share of the bank relaxed by the exponent `balance` (the
//! KL-penalised unbalanced form of Chizat et al. 2018); each patch then takes the cell
//! its row of the coupling favours most.

use rayon::prelude::*;

/// Each query's cell under the balanced coupling of its distances `dist`
/// `[P x cells]` to the cells' nearest patches, the cells' shares of the bank `share`
/// (module docs; [`super::level::StyleLevel::assign`]).
pub fn couple(share: &[f32], dist: &[f32], balance: f32, eps: f32) -> Vec<usize> {
    let cells = share.len();
    let p = dist.len() / cells.max(1);
    let best = |row: &[f32], lv: &[f32], t: f32| -> usize {
        let mut b = (0usize, f32::NEG_INFINITY);
        for (c, (&d, &v)) in row.iter().zip(lv).enumerate() {
            let s = v - d / t;
            if s > b.1 {
                b = (c, s);
            }
        }
        b.0
    };
    let mut log_v = vec![0.0f32; cells];
    if balance > 0.0 && p > 0 {
        let mean_min = dist
            .chunks(cells)
            .map(|r| r.iter().copied().fold(f32::INFINITY, f32::min) as f64)
            .sum::<f64>()
            / p as f64;
        let t = (eps as f64 * mean_min).max(1e-6) as f32;
        let log_share: Vec<f32> = share.iter().map(|s| s.max(1e-12).ln()).collect();
        let mut log_u = vec![0.0f32; p];
        for _ in 0..SINKHORN_ITERS {
            log_u
                .par_iter_mut()
                .zip(dist.par_chunks(cells))
                .for_each(|(u, row)| {
                    *u = -logsumexp(row.iter().zip(&log_v).map(|(&d, &v)| v - d / t));
                });
            let col = column_logsumexp(dist, &log_u, cells, t);
            // The cells' marginal p share_c, relaxed by the exponent rho = balance
            // (the KL-penalised unbalanced form, Chizat et al. 2018).
            let log_p = (p as f32).ln();
            for c in 0..cells {
                log_v[c] = if col[c].is_finite() {
                    balance * (log_share[c] + log_p - col[c])
                } else {
                    0.0
                };
            }
        }
        return dist.chunks(cells).map(|row| best(row, &log_v, t)).collect();
    }
    dist.chunks(cells)
        .map(|row| best(row, &log_v, 1.0))
        .collect()
}

/// Sinkhorn iterations of the balance.
pub const SINKHORN_ITERS: usize = 30;

/// log sum exp of `xs` (stable).
fn logsumexp(xs: impl Iterator<Item = f32> + Clone) -> f32 {
    let m = xs.clone().fold(f32::NEG_INFINITY, f32::max);
    if !m.is_finite() {
        return m;
    }
    m + xs.map(|x| (x - m).exp()).sum::<f32>().ln()
}

/// For each cell c, log sum_q exp(log_u_q - dist_qc / t).
fn column_logsumexp(dist: &[f32], log_u: &[f32], cells: usize, t: f32) -> Vec<f32> {
    (0..cells)
        .into_par_iter()
        .map(|c| {
            logsumexp(
                dist.chunks(cells)
                    .zip(log_u)
                    .map(|(row, &u)| u - row[c] / t),
            )
        })
        .collect()
}

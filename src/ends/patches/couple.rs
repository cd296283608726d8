//! The balance of the synthesis: an entropic coupling of the object's patches to the
//! style bank's k-means cells, made by Sinkhorn's iterations, the
//! cells' marginal their share of the bank relaxed by the exponent `balance` (the
//! KL-penalised unbalanced form of Chizat et al. 2018); each patch then takes the cell
//! its row of the coupling favours most. The iterations are
//! [`crate::maths::sinkhorn_scaling`]'s: the log-domain rounds of [`crate::maths::sinkhorn`]
//! (log units, the patch prior's denoiser's scheme) in the scaling form, at one temperature.

use crate::maths::sinkhorn_scaling;
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
    if balance > 0.0 && p > 0 {
        // The rows' minima on all cores, their sum in row order.
        let mins: Vec<f32> = dist
            .par_chunks(cells)
            .map(|r| r.iter().copied().fold(f32::INFINITY, f32::min))
            .collect();
        let mean_min = mins.iter().map(|&m| m as f64).sum::<f64>() / p as f64;
        let t = (eps as f64 * mean_min).max(1e-6) as f32;
        // The cells' marginal p share_c, relaxed by the exponent rho = balance (the
        // KL-penalised unbalanced form, Chizat et al. 2018), potentials in log units.
        let log_p = (p as f32).ln();
        let target: Vec<f32> = share.iter().map(|s| s.max(1e-12).ln() + log_p).collect();
        let scaled: Vec<f32> = dist.par_iter().map(|d| d / t).collect();
        let (log_v, _) = sinkhorn_scaling::run(&scaled, cells, balance, &target, SINKHORN_ITERS);
        return dist
            .par_chunks(cells)
            .map(|row| best(row, &log_v, t))
            .collect();
    }
    let zero = vec![0.0f32; cells];
    dist.chunks(cells)
        .map(|row| best(row, &zero, 1.0))
        .collect()
}

/// Sinkhorn iterations of the balance.
pub const SINKHORN_ITERS: usize = 30;

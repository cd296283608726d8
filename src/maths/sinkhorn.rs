//! Log-sum-exp, max-shifted exponentials and the entropic coupling by Sinkhorn iterations
//! in the log domain (Cuturi 2013; the log-domain, epsilon-scaled form of Schmitzer 2019;
//! the KL-relaxed column marginals of the unbalanced form, Chizat et al. 2018).
//!
//! For costs C_qc, a temperature tau, row marginals 1 and column marginals exp(t_c), the
//! coupling is P_qc = exp((f_q + g_c - C_qc) / tau) with potentials found by alternating
//!
//! ```text
//! f_q = -tau lse_c((g_c - C_qc) / tau)          (rows: every row sums to 1)
//! g_c =  tau rho (t_c - lse_q((f_q - C_qc) / tau))  (columns: sums pushed to exp(t_c))
//! ```
//!
//! with rho = 1 the balanced problem and rho < 1 its KL relaxation, the potentials in
//! cost units (the patch prior's cell coupling). The synthesis's balance, in log units at
//! one temperature, is [`super::sinkhorn_scaling`]'s. The costs are a dense matrix or, per
//! row, a short list of columns ([`Costs`]).
//!
//! Every function here keeps its callers' float type and order of operations: a max
//! shift folds from -inf with `max` in the order given, sums run in that order.

use rayon::prelude::*;

/// log sum exp of `xs` (f32, stable: shifted by the maximum; a non-finite maximum is
/// returned as is).
pub fn logsumexp(xs: impl Iterator<Item = f32> + Clone) -> f32 {
    let top = xs.clone().fold(f32::NEG_INFINITY, f32::max);
    if !top.is_finite() {
        return top;
    }
    top + xs.map(|v| (v - top).exp()).sum::<f32>().ln()
}

/// exp(l - max l) of each logit and their sum (f32, summed in order): unnormalised
/// softmax weights.
pub fn shifted_exp(logits: &[f32]) -> (Vec<f32>, f32) {
    let top = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let w: Vec<f32> = logits.iter().map(|l| (l - top).exp()).collect();
    let z: f32 = w.iter().sum();
    (w, z)
}

/// [`shifted_exp`] in f64.
pub fn shifted_exp_f64(logits: &[f64]) -> (Vec<f64>, f64) {
    let top = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = logits.iter().map(|l| (l - top).exp()).collect();
    let z: f64 = w.iter().sum();
    (w, z)
}

/// The softmax of the `w.len()` logits `logit(0..)` into `w` (f32 weights, their sum
/// accumulated in f64, then scaled by its f32 inverse).
pub fn softmax_into(w: &mut [f32], logit: impl Fn(usize) -> f32) {
    let n = w.len();
    let top = (0..n).map(&logit).fold(f32::NEG_INFINITY, f32::max);
    let mut z = 0.0f64;
    for k in 0..n {
        w[k] = (logit(k) - top).exp();
        z += w[k] as f64;
    }
    let inv = (1.0 / z) as f32;
    w.iter_mut().for_each(|v| *v *= inv);
}

/// The costs of a coupling, `per` entries per row: a dense `[rows, cols]` matrix
/// (`index` `None`, entry l of a row is column l) or each row's `per` columns `index`.
#[derive(Debug, Clone, Copy)]
pub struct Costs<'a> {
    pub cost: &'a [f32],
    pub index: Option<&'a [u32]>,
    pub per: usize,
    pub cols: usize,
}

impl Costs<'_> {
    /// The column of entry `e` (row-major: row e / per).
    fn col(&self, e: usize) -> usize {
        self.index.map_or(e % self.per.max(1), |ix| ix[e] as usize)
    }
}

/// One log-domain Sinkhorn scheme in cost units, its column log-sum-exps summed in f64
/// (a column with no positive sum, no entry or a non-finite maximum, keeps its
/// potential), with the column relaxation `rho` (1: balanced).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sinkhorn {
    pub rho: f32,
}

impl Sinkhorn {
    /// One round per temperature of `taus`: the row potentials `f` from `g`, then the
    /// column potentials `g` toward the log column marginals `target` from `f`.
    pub fn run(
        &self,
        costs: Costs<'_>,
        target: &[f32],
        taus: impl IntoIterator<Item = f32>,
        f: &mut [f32],
        g: &mut [f32],
    ) {
        for tau in taus {
            self.rows(costs, g, f, tau);
            self.columns(costs, f, target, g, tau);
        }
    }

    /// The row potentials `f` (every row's mass 1) given the column potentials `g`.
    pub fn rows(&self, costs: Costs<'_>, g: &[f32], f: &mut [f32], tau: f32) {
        let per = costs.per;
        f.par_iter_mut().enumerate().for_each(|(i, fi)| {
            let entries = i * per..(i + 1) * per;
            let cost = &costs.cost[entries.clone()];
            let terms = entries.map(|e| (costs.col(e), e - i * per));
            *fi = -tau * logsumexp(terms.map(|(c, l)| (g[c] - cost[l]) / tau));
        });
    }

    /// The column potentials `g` given the row potentials `f`: each column's log-sum-exp
    /// over its entries (rows in order), then `g_c` from `target_c` (module docs).
    pub fn columns(&self, costs: Costs<'_>, f: &[f32], target: &[f32], g: &mut [f32], tau: f32) {
        let (k, per) = (costs.cols, costs.per);
        let term = |e: usize| (f[e / per] - costs.cost[e]) / tau;
        let n = costs.cost.len();
        let mut col_max = vec![f32::NEG_INFINITY; k];
        for e in 0..n {
            let c = costs.col(e);
            col_max[c] = col_max[c].max(term(e));
        }
        let mut col = vec![0.0f64; k];
        for e in 0..n {
            let c = costs.col(e);
            col[c] += (term(e) - col_max[c]).exp() as f64;
        }
        for c in 0..k {
            if col[c] > 0.0 {
                g[c] = tau * self.rho * (target[c] - (col_max[c] + (col[c] as f32).ln()));
            }
        }
    }
}

/// Epsilon scaling (Schmitzer 2019): `iters` temperatures falling geometrically from
/// `hot` to `cold` (just `cold` when `iters` is 1).
pub fn epsilon_scaling(hot: f32, cold: f32, iters: usize) -> impl Iterator<Item = f32> {
    (0..iters).map(move |r| {
        let frac = if iters > 1 {
            r as f32 / (iters - 1) as f32
        } else {
            1.0
        };
        hot * (cold / hot).powf(frac)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn uniform(r: &mut Rng, n: usize, scale: f32) -> Vec<f32> {
        (0..n).map(|_| r.uniform() as f32 * scale).collect()
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The patch prior's coupling loop as it was written inline (`prior::patch`'s cell
    /// coupling before this module): sparse rows, cost units, f64 column sums.
    fn inline_sparse(
        idx: &[u32],
        cost: &[f32],
        near: usize,
        share: &[f32],
        (hot, cold, iters): (f32, f32, usize),
    ) -> (Vec<f32>, Vec<f32>) {
        let (q, k) = (cost.len() / near, share.len());
        let (mut f, mut g) = (vec![0.0f32; q], vec![0.0f32; k]);
        let rows = |g: &[f32], f: &mut [f32], tau: f32| {
            f.par_iter_mut().enumerate().for_each(|(i, fi)| {
                let (ci, cc) = (
                    &idx[i * near..(i + 1) * near],
                    &cost[i * near..(i + 1) * near],
                );
                *fi = -tau * logsumexp((0..near).map(|l| (g[ci[l] as usize] - cc[l]) / tau));
            });
        };
        for r in 0..iters {
            let frac = if iters > 1 {
                r as f32 / (iters - 1) as f32
            } else {
                1.0
            };
            let tau = hot * (cold / hot).powf(frac);
            rows(&g, &mut f, tau);
            let mut col_max = vec![f32::NEG_INFINITY; k];
            for i in 0..q {
                for l in 0..near {
                    let c = idx[i * near + l] as usize;
                    col_max[c] = col_max[c].max((f[i] - cost[i * near + l]) / tau);
                }
            }
            let mut col = vec![0.0f64; k];
            for i in 0..q {
                for l in 0..near {
                    let c = idx[i * near + l] as usize;
                    col[c] += (((f[i] - cost[i * near + l]) / tau) - col_max[c]).exp() as f64;
                }
            }
            for c in 0..k {
                if col[c] > 0.0 {
                    g[c] = tau * (share[c] - (col_max[c] + (col[c] as f32).ln()));
                }
            }
        }
        rows(&g, &mut f, cold);
        (f, g)
    }

    #[test]
    fn the_sparse_cost_unit_scheme_is_the_patch_priors_loop_bit_for_bit() {
        let mut r = Rng::new(3);
        let (q, k, near) = (300, 40, 7);
        // Each row's `near` distinct columns; column 39 is never used (kept potential).
        let idx: Vec<u32> = (0..q)
            .flat_map(|i| (0..near).map(move |l| ((i * 5 + l * 3) % (k - 1)) as u32))
            .collect();
        let cost = uniform(&mut r, q * near, 30.0);
        let share: Vec<f32> = (0..k).map(|c| ((c % 5 + 1) as f32 / 3.0).ln()).collect();
        for (hot, cold, iters) in [(12.0, 0.5, 9), (3.0, 3.0, 1), (5.0, 0.05, 20)] {
            let (f0, g0) = inline_sparse(&idx, &cost, near, &share, (hot, cold, iters));
            let costs = Costs {
                cost: &cost,
                index: Some(&idx),
                per: near,
                cols: k,
            };
            let scheme = Sinkhorn { rho: 1.0 };
            let (mut f, mut g) = (vec![0.0f32; q], vec![0.0f32; k]);
            scheme.run(
                costs,
                &share,
                epsilon_scaling(hot, cold, iters),
                &mut f,
                &mut g,
            );
            scheme.rows(costs, &g, &mut f, cold);
            assert_eq!(bits(&f), bits(&f0));
            assert_eq!(bits(&g), bits(&g0));
        }
    }

    #[test]
    fn shifted_exponentials_are_the_inline_max_shifts() {
        let mut r = Rng::new(9);
        let l = uniform(&mut r, 50, -40.0);
        let top = l.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let w0: Vec<f32> = l.iter().map(|x| (x - top).exp()).collect();
        let (w, z) = shifted_exp(&l);
        assert_eq!(bits(&w), bits(&w0));
        assert_eq!(z.to_bits(), w0.iter().sum::<f32>().to_bits());
        let l64: Vec<f64> = l.iter().map(|&x| x as f64).collect();
        let (w, z) = shifted_exp_f64(&l64);
        assert!((z - w.iter().sum::<f64>()).abs() == 0.0 && w.iter().all(|&x| x <= 1.0));
        let mut s = vec![0.0f32; l.len()];
        softmax_into(&mut s, |k| l[k]);
        let total: f32 = s.iter().sum();
        assert!((total - 1.0).abs() < 1e-5, "{total}");
        assert_eq!(
            logsumexp([f32::NEG_INFINITY; 3].into_iter()),
            f32::NEG_INFINITY
        );
        let lse = logsumexp(l.iter().copied());
        assert!((lse - (top + w0.iter().sum::<f32>().ln())).abs() == 0.0);
    }
}

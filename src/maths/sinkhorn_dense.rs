//! The dense log-unit rounds of [`super::sinkhorn::Sinkhorn::run`] (`Units::Log`,
//! `Columns::F32Zero`, a dense cost matrix: the synthesis's balance,
//! [`crate::ends::patches::couple`]) rearranged for speed, with the same floating-point
//! operations in the same order, so the potentials are bit for bit the generic loop's:
//!
//! - each round's `C / tau` is divided once (the generic loop divides every entry
//!   twice in the rows' log-sum-exp and twice in the columns');
//! - a row's terms `g_c - C_qc / tau` are formed once, then their log-sum-exp
//!   ([`super::sinkhorn::logsumexp`]: the maximum, then the shifted exponentials summed
//!   in order);
//! - the columns are taken `GROUP` at a time on all cores (the generic loop finds the
//!   columns' maxima on one thread), each column's maximum and sum still over the rows
//!   in order.
//! - the exponentials are taken many at a time ([`super::expf::exp_in_place`]: the
//!   platform's `expf`, bit for bit, four lanes at a time where the CPU has AVX2 and
//!   FMA; `expf` was a fifth of the synthesis's time, and glibc's takes a slow path
//!   that sets `errno` below -103.3).

use super::expf::exp_in_place;
use rayon::prelude::*;

/// Columns per task in the column pass (a cache line of f32).
const GROUP: usize = 16;

/// The rounds of `rho`-relaxed dense log-unit Sinkhorn (module docs): `cost`
/// `[rows, per]`, log column marginals `target` `[per]`, one round per temperature of
/// `taus`, row potentials `f` `[rows]` and column potentials `g` `[per]` updated.
pub fn run(
    cost: &[f32],
    per: usize,
    rho: f32,
    target: &[f32],
    taus: impl IntoIterator<Item = f32>,
    f: &mut [f32],
    g: &mut [f32],
) {
    let mut scaled = vec![0.0f32; cost.len()];
    let mut scaled_at: Option<u32> = None;
    for tau in taus {
        if scaled_at != Some(tau.to_bits()) {
            scaled
                .par_chunks_mut(1 << 14)
                .zip(cost.par_chunks(1 << 14))
                .for_each(|(s, c)| s.iter_mut().zip(c).for_each(|(s, &c)| *s = c / tau));
            scaled_at = Some(tau.to_bits());
        }
        rows(&scaled, per, g, f);
        columns(&scaled, per, f, target, rho, g);
    }
}

/// The row potentials: `f_q = -lse_c(g_c - C_qc / tau)` (`scaled` holds `C / tau`), each
/// row's log-sum-exp as [`super::sinkhorn::logsumexp`] makes it: the maximum, then the
/// shifted exponentials summed in order.
fn rows(scaled: &[f32], per: usize, g: &[f32], f: &mut [f32]) {
    f.par_iter_mut().zip(scaled.par_chunks(per)).for_each_init(
        || vec![0.0f32; per],
        |terms, (fi, row)| {
            for ((t, &gc), &s) in terms.iter_mut().zip(g).zip(row) {
                *t = gc - s;
            }
            let top = terms.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            if !top.is_finite() {
                *fi = -top;
                return;
            }
            terms.iter_mut().for_each(|t| *t -= top);
            exp_in_place(terms);
            *fi = -(top + terms.iter().sum::<f32>().ln());
        },
    );
}

/// The column potentials: `g_c = rho (target_c - lse_q(f_q - C_qc / tau))`, 0 where the
/// log-sum-exp is not finite.
fn columns(scaled: &[f32], per: usize, f: &[f32], target: &[f32], rho: f32, g: &mut [f32]) {
    let lse: Vec<f32> = (0..per.div_ceil(GROUP))
        .into_par_iter()
        .flat_map_iter(|k| {
            let (c0, c1) = (k * GROUP, ((k + 1) * GROUP).min(per));
            let w = c1 - c0;
            let mut top = [f32::NEG_INFINITY; GROUP];
            for (row, &fi) in scaled.chunks_exact(per).zip(f) {
                for (t, &s) in top[..w].iter_mut().zip(&row[c0..c1]) {
                    *t = t.max(fi - s);
                }
            }
            let (mut sum, mut e) = ([0.0f32; GROUP], [0.0f32; GROUP]);
            for (row, &fi) in scaled.chunks_exact(per).zip(f) {
                for ((e, &s), &t) in e[..w].iter_mut().zip(&row[c0..c1]).zip(&top) {
                    *e = (fi - s) - t;
                }
                exp_in_place(&mut e[..w]);
                for (a, &e) in sum[..w].iter_mut().zip(&e[..w]) {
                    *a += e;
                }
            }
            (0..w).map(move |c| {
                if top[c].is_finite() {
                    top[c] + sum[c].ln()
                } else {
                    top[c]
                }
            })
        })
        .collect();
    for (c, gc) in g.iter_mut().enumerate() {
        *gc = if lse[c].is_finite() {
            rho * (target[c] - lse[c])
        } else {
            0.0
        };
    }
}

#[cfg(test)]
mod tests {
    use super::super::sinkhorn::{Columns, Costs, Sinkhorn, Units, epsilon_scaling};
    use crate::rng::Rng;

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// The rearranged rounds against the generic rows and columns passes, round by
    /// round: the same bits (columns no row reaches, a row that reaches none, changing
    /// temperatures, a column count that is not a multiple of the group).
    #[test]
    fn the_rearranged_rounds_are_the_generic_ones_bit_for_bit() {
        let mut r = Rng::new(11);
        for (p, per, rho) in [(300, 64, 1.0f32), (37, 21, 0.4), (5, 1, 0.7)] {
            let mut cost: Vec<f32> = (0..p * per).map(|_| 4.0 * r.uniform() as f32).collect();
            for i in 0..p {
                cost[i * per + per / 2] = f32::INFINITY;
            }
            cost[per..2 * per].fill(f32::INFINITY);
            for i in (0..p).step_by(3) {
                cost[i * per] = 30.0; // exponentials below -104 (0) and just above
            }
            let target: Vec<f32> = (0..per).map(|c| ((c % 7 + 1) as f32).ln()).collect();
            let scheme = Sinkhorn {
                units: Units::Log,
                columns: Columns::F32Zero,
                rho,
            };
            let costs = Costs {
                cost: &cost,
                index: None,
                per,
                cols: per,
            };
            let (mut f0, mut g0) = (vec![0.0f32; p], vec![0.0f32; per]);
            let (mut f1, mut g1) = (f0.clone(), g0.clone());
            for tau in epsilon_scaling(2.0, 0.05, 6).chain([0.05; 3]) {
                scheme.rows(costs, &g0, &mut f0, tau);
                scheme.columns(costs, &f0, &target, &mut g0, tau);
                super::run(&cost, per, rho, &target, [tau], &mut f1, &mut g1);
                assert_eq!(bits(&f0), bits(&f1), "rows, tau {tau}");
                assert_eq!(bits(&g0), bits(&g1), "columns, tau {tau}");
            }
        }
    }
}

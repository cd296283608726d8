//! The synthesis's balance ([`crate::ends::patches::couple`]): rounds of dense,
//! `rho`-relaxed Sinkhorn at one temperature in log units (`f_q = -lse_c(g_c - C_qc / tau)`,
//! `g_c = rho (t_c - lse_q(f_q - C_qc / tau))`, 0 where that log-sum-exp is not finite;
//! [`super::sinkhorn`]'s rounds with the potentials over tau), computed in
//! the scaling form with absorption (Schmitzer 2019, section 4.1) instead of the log
//! domain.
//!
//! The log-domain rounds take two exponentials per entry of the `[P, cells]` cost matrix
//! per round (a row log-sum-exp and a column one): 60 passes of `exp` over 3.6M entries at
//! the sample's finest level. Here the kernel `K_qc = exp(fh_q + gh_c - C_qc / tau)` is
//! made once with potentials `fh`, `gh` absorbed so far, and a round is two products with
//! it:
//!
//! ```text
//! a_q = 1 / sum_c K_qc b_c                       (rows: f_q = fh_q + ln a_q)
//! S_c = sum_q a_q K_qc,  g_c = rho (t_c - (ln S_c - gh_c)),  b_c = exp(g_c - gh_c)
//! ```
//!
//! the same potentials in exact arithmetic. When a scaling leaves `[e^-ABSORB, e^ABSORB]`
//! its log goes into `fh` or `gh` and the kernel is made again, so the kernel's entries
//! stay the coupling's own (at most about 1): an entry that underflows f32 (below
//! `e^-103`) weighs less than `e^-70` of its row's mass. A column whose entries are all
//! below `COLUMN_FLOOR` (a cell no patch is near yet, or an empty one) takes its
//! log-sum-exp in the log domain, in f64.
//!
//! The result is not bit for bit the f32 log-domain loop's that the balance ran before
//! (it rounds differently): its potentials agree with the log domain in f64 to about
//! 1e-5 in log units (the tests), and the assignment that follows
//! (each patch's most favoured cell) differs only where two cells tie to that precision
//! (BENCHMARKS.md "The sample DAG's wall time" gives the count on the sample).
//!
//! The kernel's exponentials are [`super::expf::exp_in_place`]'s (the platform's `expf`, bit
//! for bit on every CPU); every sum is in f64 in a fixed order (a row's entries in eight
//! interleaved partial sums added pairwise, a column's rows `ROWS` at a time, the blocks
//! added in order), so the result does not depend on the thread count or the CPU.

use super::expf::exp_in_place;
use rayon::prelude::*;

/// Largest |log| of a row or column scaling before it is absorbed into the potentials.
const ABSORB: f64 = 16.0;
/// A column whose kernel entries are all below this takes the log-domain log-sum-exp.
const COLUMN_FLOOR: f32 = 1e-30;
/// Rows per task (fixed, so that the column sums are added in the same order on any
/// number of threads).
const ROWS: usize = 1024;

/// What the rounds did besides the potentials (the tests look at it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rounds {
    /// Kernels made (1 + the absorptions).
    pub kernels: usize,
    /// Columns whose log-sum-exp was taken in the log domain, over all rounds.
    pub log_columns: usize,
}

/// `rounds` rounds of `rho`-relaxed dense log-unit Sinkhorn (module docs) on `scaled`
/// `[rows, per]` (the costs over the temperature, `C / tau`; +inf for an entry that
/// takes no mass) toward the log column marginals `target` `[per]`, from zero
/// potentials: the column potentials `g` in log units, and what the rounds did.
pub fn run(
    scaled: &[f32],
    per: usize,
    rho: f32,
    target: &[f32],
    rounds: usize,
) -> (Vec<f32>, Rounds) {
    assert!(
        per > 0 && scaled.len().is_multiple_of(per),
        "a dense [rows, per] matrix"
    );
    assert_eq!(target.len(), per, "one marginal per column");
    let p = scaled.len() / per;
    // A row's absorbed potential starts at its smallest cost, so its largest entry is 1;
    // a row with no finite cost (no mass anywhere) stays out (a = 0).
    let mut fh: Vec<f64> = scaled
        .chunks_exact(per)
        .map(|r| r.iter().copied().fold(f32::INFINITY, f32::min) as f64)
        .collect();
    let live: Vec<bool> = fh.iter().map(|f| f.is_finite()).collect();
    fh.iter_mut()
        .filter(|f| !f.is_finite())
        .for_each(|f| *f = 0.0);
    let mut gh = vec![0.0f64; per];
    let (mut a, mut b) = (vec![0.0f64; p], vec![1.0f64; per]);
    let mut g = vec![0.0f64; per];
    let mut kernel = vec![0.0f32; scaled.len()];
    let mut stats = Rounds {
        kernels: 0,
        log_columns: 0,
    };
    let (hi, lo) = (ABSORB.exp(), (-ABSORB).exp());
    let mut stale = true;
    for _ in 0..rounds {
        if stale {
            make_kernel(&mut kernel, scaled, per, &fh, &gh, &live);
            stats.kernels += 1;
        }
        let (mut sums, mut tops) = scale_rows_sum_columns(&kernel, per, &b, &mut a);
        if a.iter().any(|&x| x > 0.0 && (x > hi || x < lo)) {
            // Absorb the rows (and the columns with them), make the kernel again and
            // redo the pass (its column sums were the old kernel's).
            absorb(&mut fh, &mut a, &mut gh, &g, &mut b);
            make_kernel(&mut kernel, scaled, per, &fh, &gh, &live);
            stats.kernels += 1;
            (sums, tops) = scale_rows_sum_columns(&kernel, per, &b, &mut a);
        }
        // The columns below the floor take the log domain, on all cores (each column's
        // sum in row order).
        let floor: Vec<usize> = (0..per)
            .filter(|&c| !(tops[c] >= COLUMN_FLOOR && sums[c] > 0.0))
            .collect();
        let mut lses = vec![0.0f64; per];
        if !floor.is_empty() {
            stats.log_columns += floor.len();
            let f: Vec<f64> = fh
                .par_iter()
                .zip(&a)
                .map(|(&fh, &a)| {
                    if a > 0.0 {
                        fh + a.ln()
                    } else {
                        f64::NEG_INFINITY
                    }
                })
                .collect();
            let l: Vec<f64> = floor
                .par_iter()
                .map(|&c| column_lse(scaled, per, c, &f))
                .collect();
            floor.iter().zip(l).for_each(|(&c, l)| lses[c] = l);
        }
        for c in 0..per {
            let lse = if tops[c] >= COLUMN_FLOOR && sums[c] > 0.0 {
                sums[c].ln() - gh[c]
            } else {
                lses[c]
            };
            g[c] = if lse.is_finite() {
                rho as f64 * (target[c] as f64 - lse)
            } else {
                0.0
            };
            b[c] = (g[c] - gh[c]).exp();
        }
        stale = g.iter().zip(&gh).any(|(g, h)| (g - h).abs() > ABSORB);
        if stale {
            absorb(&mut fh, &mut a, &mut gh, &g, &mut b);
        }
    }
    (g.iter().map(|&x| x as f32).collect(), stats)
}

/// The potentials' logs into `fh` and `gh` (their scalings back to 1).
fn absorb(fh: &mut [f64], a: &mut [f64], gh: &mut [f64], g: &[f64], b: &mut [f64]) {
    for (f, a) in fh.iter_mut().zip(a.iter_mut()) {
        if *a > 0.0 {
            *f += a.ln();
            *a = 1.0;
        }
    }
    gh.copy_from_slice(g);
    b.fill(1.0);
}

/// `K_qc = exp(fh_q + gh_c - scaled_qc)` (0 for a row that takes no mass).
fn make_kernel(
    kernel: &mut [f32],
    scaled: &[f32],
    per: usize,
    fh: &[f64],
    gh: &[f64],
    live: &[bool],
) {
    kernel
        .par_chunks_mut(per)
        .zip(scaled.par_chunks(per))
        .enumerate()
        .for_each(|(q, (k, s))| {
            if !live[q] {
                k.fill(0.0);
                return;
            }
            for ((k, &s), &h) in k.iter_mut().zip(s).zip(gh) {
                *k = (fh[q] + h - s as f64) as f32;
            }
            exp_in_place(k);
        });
}

/// `a_q = 1 / sum_c K_qc b_c` of a kernel row `k` (0 where the sum is 0: a row that
/// takes no mass): the entries in eight interleaved f64 partial sums added pairwise.
fn row_scaling(k: &[f32], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let (k8, b8) = (k.chunks_exact(8), b.chunks_exact(8));
    let (kt, bt) = (k8.remainder(), b8.remainder());
    for (k, b) in k8.zip(b8) {
        for j in 0..8 {
            acc[j] += k[j] as f64 * b[j];
        }
    }
    for (j, (&k, &b)) in kt.iter().zip(bt).enumerate() {
        acc[j] += k as f64 * b;
    }
    let s = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
    if s > 0.0 { 1.0 / s } else { 0.0 }
}

/// A round's pass over the kernel: every row's scaling `a_q` ([`row_scaling`]), then
/// each column's `S_c = sum_q a_q K_qc` and its largest kernel entry, `ROWS` rows at a
/// time while they are in cache (one read of the kernel per round; the blocks' sums
/// added in order).
fn scale_rows_sum_columns(
    kernel: &[f32],
    per: usize,
    b: &[f64],
    a: &mut [f64],
) -> (Vec<f64>, Vec<f32>) {
    let parts: Vec<(Vec<f64>, Vec<f32>)> = kernel
        .par_chunks(ROWS * per)
        .zip(a.par_chunks_mut(ROWS))
        .map(|(k, a)| {
            let (mut sum, mut top) = (vec![0.0f64; per], vec![0.0f32; per]);
            for (row, aq) in k.chunks_exact(per).zip(a) {
                *aq = row_scaling(row, b);
                for ((s, t), &kv) in sum.iter_mut().zip(top.iter_mut()).zip(row) {
                    *s += *aq * kv as f64;
                    *t = t.max(kv);
                }
            }
            (sum, top)
        })
        .collect();
    let (mut sum, mut top) = (vec![0.0f64; per], vec![0.0f32; per]);
    for (s, t) in parts {
        sum.iter_mut().zip(&s).for_each(|(a, b)| *a += b);
        top.iter_mut().zip(&t).for_each(|(a, b)| *a = a.max(*b));
    }
    (sum, top)
}

/// Column `c`'s `lse_q(f_q - scaled_qc)` in the log domain (f64; -inf when no row
/// reaches it), `f` the rows' potentials `fh_q + ln a_q` (-inf for a row with `a_q` 0).
fn column_lse(scaled: &[f32], per: usize, c: usize, f: &[f64]) -> f64 {
    let term = |q: usize| f[q] - scaled[q * per + c] as f64;
    let p = f.len();
    let top = (0..p).map(term).fold(f64::NEG_INFINITY, f64::max);
    if !top.is_finite() {
        return top;
    }
    top + (0..p).map(|q| (term(q) - top).exp()).sum::<f64>().ln()
}

#[cfg(test)]
mod tests {
    use crate::rng::Rng;

    /// The log-domain rounds, written out in f64 (`f_q = -lse_c(g_c - s_qc)`,
    /// `g_c = rho (t_c - lse_q(f_q - s_qc))`, 0 where that log-sum-exp is not finite): the
    /// potentials the scaling form must give.
    fn log_domain(scaled: &[f32], per: usize, rho: f32, target: &[f32], rounds: usize) -> Vec<f32> {
        let lse = |xs: &mut dyn Iterator<Item = f64>| {
            let v: Vec<f64> = xs.collect();
            let top = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if top.is_finite() {
                top + v.iter().map(|x| (x - top).exp()).sum::<f64>().ln()
            } else {
                top
            }
        };
        let p = scaled.len() / per;
        let s = |q: usize, c: usize| scaled[q * per + c] as f64;
        let (mut f, mut g) = (vec![0.0f64; p], vec![0.0f64; per]);
        for _ in 0..rounds {
            for q in 0..p {
                f[q] = -lse(&mut (0..per).map(|c| g[c] - s(q, c)));
            }
            for c in 0..per {
                let l = lse(&mut (0..p).map(|q| f[q] - s(q, c)));
                g[c] = if l.is_finite() {
                    rho as f64 * (target[c] as f64 - l)
                } else {
                    0.0
                };
            }
        }
        g.iter().map(|&x| x as f32).collect()
    }

    /// A `[p, per]` problem: costs over the temperature spread up to `spread`, column
    /// `far` reached only at `far_at` above every row's smallest cost, column `empty`
    /// reached by no row.
    fn problem(
        r: &mut Rng,
        p: usize,
        per: usize,
        spread: f32,
        far_at: f32,
    ) -> (Vec<f32>, Vec<f32>) {
        let mut s: Vec<f32> = (0..p * per).map(|_| spread * r.uniform() as f32).collect();
        for q in 0..p {
            let row = &mut s[q * per..(q + 1) * per];
            let lo = row.iter().copied().fold(f32::INFINITY, f32::min);
            row[1] = lo + far_at + 3.0 * r.uniform() as f32;
            row[per - 1] = f32::INFINITY;
        }
        let target: Vec<f32> = (0..per)
            .map(|c| (((c % 5 + 1) as f32 / 3.0) * p as f32 / per as f32).ln())
            .collect();
        (s, target)
    }

    #[test]
    fn the_scaling_form_gives_the_log_domains_potentials() {
        let mut r = Rng::new(5);
        // (rows, columns, spread, far column, rho, rounds): small costs; the balance's
        // spreads (hundreds of temperatures, a column only far rows reach, so that the
        // kernel must be made again); relaxed columns; a column count not a multiple of 8.
        for (p, per, spread, far, rho, rounds) in [
            (400, 24, 4.0, 2.0, 1.0, 30),
            (3000, 64, 400.0, 250.0, 1.0, 30),
            (700, 13, 60.0, 120.0, 0.5, 12),
            (50, 3, 900.0, 700.0, 1.0, 40),
        ] {
            let (s, target) = problem(&mut r, p, per, spread, far);
            let want = log_domain(&s, per, rho, &target, rounds);
            let (got, stats) = super::run(&s, per, rho, &target, rounds);
            for c in 0..per {
                let tol = 2e-5 * (1.0 + want[c].abs());
                assert!(
                    (got[c] - want[c]).abs() <= tol,
                    "case {p}x{per}: column {c}: {} vs {}",
                    got[c],
                    want[c]
                );
            }
            assert_eq!(got[per - 1], 0.0, "an empty column keeps potential 0");
            assert!(stats.log_columns >= rounds, "the empty column every round");
            if far > 200.0 {
                assert!(
                    stats.kernels > 1,
                    "case {p}x{per}: the far column needs absorption"
                );
            }
        }
    }

    #[test]
    fn the_result_does_not_depend_on_the_thread_count() {
        let mut r = Rng::new(9);
        let (s, target) = problem(&mut r, 5000, 32, 300.0, 150.0);
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| super::run(&s, 32, 0.8, &target, 20))
        };
        let (g1, s1) = on(1);
        let (g3, s3) = on(3);
        assert_eq!(s1, s3);
        assert_eq!(
            g1.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            g3.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }
}

//! The exact denoiser of a patch distribution (Kamb & Ganguli, ICML 2025, the equivariant
//! local score machine; Niedoba et al. 2025): for clean patches {y_j} with centre pixels
//! {c_j} and z_t = sqrt(ab) x0 + sqrt(1 - ab) eps, the minimum-mean-squared-error estimate
//! of pixel i is
//!
//! ```text
//! x0_hat[i] = sum_j softmax_j( -|| P_i(z_t) - sqrt(ab) y_j ||^2 / (2 (1 - ab)) ) c_j
//! ```
//!
//! with P_i(z_t) the noisy k x k patch around pixel i. [`denoise_exact`] computes it by
//! brute force in f64 (the tests' reference); [`denoise`] is the fast form: a shortlist of
//! candidates per pixel from one matrix product in PCA coordinates (||x - a y||^2 =
//! ||x||^2 - 2 a x.y + a^2 ||y||^2), then the exact distances of the shortlisted patches in
//! the full patch space and the softmax over them. With the whole bank as the shortlist
//! it is the exact posterior mean again.
//!
//! Two departures from the plain posterior, both optional:
//! * **guide** (Image Analogies, Hertzmann et al. 2001; StyLit, Fiser et al. 2016): a
//!   noise-free descriptor of each query pixel (a structure channel of the source view)
//!   and of each bank patch (the same channel of the style) adds
//!   `-weight ||g_i - g_j||^2` to the logits, so an edge of the scene prefers patches of
//!   the style with an edge;
//! * **balance** (bidirectional similarity, Simakov et al. 2008; the patch-distribution
//!   optimal transport of Houdard et al. 2021): the per-pixel softmax becomes a Sinkhorn
//!   coupling whose columns are pushed toward equal use, so that over the batch every
//!   style patch is used about equally and no single flat patch wins everywhere.

use super::bank::{Bank, row_norms};
use crate::maths::sinkhorn::{
    Costs, Sinkhorn, epsilon_scaling, logsumexp, shifted_exp, shifted_exp_f64, softmax_into,
};
use ndarray::{Array2, ArrayView2, ArrayView3, ArrayView4, Axis, s};
use rayon::prelude::*;

mod cells;
mod local;

use cells::CellSearch;
pub use local::denoise_local;

/// The noise level of z_t = `sa` x0 + `sb` eps (`sa` = sqrt(ab), `sb` = sqrt(1 - ab)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Level {
    pub sa: f32,
    pub sb: f32,
}

/// How the fast denoiser searches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Search {
    /// Candidates per pixel (0 = the whole bank: the exact posterior).
    pub shortlist: usize,
    /// Inverted-file cells searched per pixel (0, or a bank without an index: the whole
    /// bank is scanned for the shortlist).
    pub probe: usize,
    /// Sinkhorn iterations that balance the patches' use over the batch (0 = the
    /// per-pixel softmax, the exact posterior).
    pub balance: usize,
}

/// A noise-free descriptor per query `[Q, G]` and per bank patch `[M, G]`, and its weight.
#[derive(Debug, Clone, Copy)]
pub struct Guide<'a> {
    pub query: ArrayView2<'a, f32>,
    pub bank: ArrayView2<'a, f32>,
    pub weight: f32,
}

/// The exact posterior mean `[Q, C]` of the noisy patches `x` `[Q, k k C]` under `bank`,
/// by brute force in f64 (with `guide`'s term when given).
pub fn denoise_exact(
    bank: &Bank,
    x: ArrayView2<'_, f32>,
    level: Level,
    guide: Option<Guide<'_>>,
) -> Array2<f32> {
    let (sa, var2) = (level.sa as f64, 2.0 * (level.sb as f64).powi(2));
    let c = bank.channels;
    let mut out = Array2::<f32>::zeros((x.nrows(), c));
    for (i, xi) in x.rows().into_iter().enumerate() {
        let logits: Vec<f64> = bank
            .patches
            .rows()
            .into_iter()
            .enumerate()
            .map(|(j, y)| {
                let d: f64 = xi
                    .iter()
                    .zip(y)
                    .map(|(a, b)| (*a as f64 - sa * *b as f64).powi(2))
                    .sum();
                -d / var2 - guide.map_or(0.0, |g| guide_distance(g, i, j))
            })
            .collect();
        let (w, z) = shifted_exp_f64(&logits);
        for ch in 0..c {
            let v: f64 = (0..bank.len())
                .map(|j| w[j] * bank.centres[[j, ch]] as f64)
                .sum();
            out[[i, ch]] = (v / z) as f32;
        }
    }
    out
}

/// `weight ||g_i - g_j||^2` in f64.
fn guide_distance(g: Guide<'_>, i: usize, j: usize) -> f64 {
    let d: f64 = g
        .query
        .row(i)
        .iter()
        .zip(g.bank.row(j))
        .map(|(a, b)| (*a as f64 - *b as f64).powi(2))
        .sum();
    g.weight as f64 * d
}

/// Each pixel's candidates: bank indices and their exact logits, `per` per pixel.
#[derive(Debug, Clone)]
struct Candidates {
    per: usize,
    index: Vec<u32>,
    logit: Vec<f32>,
}

/// Queries per block of the search (one matrix product each, blocks in parallel).
const BLOCK: usize = 256;

/// The fast posterior mean `[Q, C]` of the noisy patches `x` `[Q, k k C]` (module docs):
/// shortlist, exact logits of the shortlisted patches, then softmax or balanced coupling.
pub fn denoise(
    bank: &Bank,
    x: ArrayView2<'_, f32>,
    level: Level,
    search: Search,
    guide: Option<Guide<'_>>,
) -> Array2<f32> {
    if search.balance > 0
        && let Some(red) = bank.reduced.as_ref().filter(|r| r.ivf.is_some())
    {
        return CellSearch {
            red,
            ivf: red.ivf.as_ref().expect("filtered"),
            probe: search.probe.max(1),
        }
        .balanced(bank, x, level, (search.balance, search.shortlist), guide);
    }
    let cand = candidates(bank, x, level, (search.shortlist, search.probe), guide);
    let weights = softmax_rows(&cand, None);
    let c = bank.channels;
    let q = x.nrows();
    let mut out = vec![0.0f32; q * c];
    out.par_chunks_mut(c).enumerate().for_each(|(i, o)| {
        for l in 0..cand.per {
            let (j, w) = (
                cand.index[i * cand.per + l] as usize,
                weights[i * cand.per + l],
            );
            for ch in 0..c {
                o[ch] += w * bank.centres[[j, ch]];
            }
        }
    });
    Array2::from_shape_vec((q, c), out).expect("length matches")
}

/// [`denoise`] without balance, with each query's log evidence: the log-sum-exp of its
/// candidates' logits (over the whole bank with shortlist 0; a lower bound otherwise),
/// i.e. log sum_j exp(-||x - sa y_j||^2 / (2 sb^2)).
pub fn denoise_with_evidence(
    bank: &Bank,
    x: ArrayView2<'_, f32>,
    level: Level,
    search: Search,
) -> (Array2<f32>, Vec<f32>) {
    let cand = candidates(bank, x, level, (search.shortlist, search.probe), None);
    let weights = softmax_rows(&cand, None);
    let c = bank.channels;
    let mut out = Array2::<f32>::zeros((x.nrows(), c));
    let mut evidence = Vec::with_capacity(x.nrows());
    for (i, mut o) in out.rows_mut().into_iter().enumerate() {
        let l = &cand.logit[i * cand.per..(i + 1) * cand.per];
        evidence.push(logsumexp(l.iter().copied()));
        for k in 0..cand.per {
            let (j, w) = (
                cand.index[i * cand.per + k] as usize,
                weights[i * cand.per + k],
            );
            for ch in 0..c {
                o[ch] += w * bank.centres[[j, ch]];
            }
        }
    }
    (out, evidence)
}

/// Shortlist every query (blocks of [`BLOCK`] in parallel) and compute the exact logits
/// of its candidates.
fn candidates(
    bank: &Bank,
    x: ArrayView2<'_, f32>,
    level: Level,
    (shortlist, probe): (usize, usize),
    guide: Option<Guide<'_>>,
) -> Candidates {
    let m = bank.len();
    let per = if shortlist == 0 { m } else { shortlist.min(m) };
    let q = x.nrows();
    let mut index = vec![0u32; q * per];
    let mut logit = vec![0.0f32; q * per];
    let ivf = bank
        .reduced
        .as_ref()
        .and_then(|r| r.ivf.as_ref().map(|i| (r, i)))
        .filter(|_| probe > 0 && per < m);
    index
        .par_chunks_mut(BLOCK * per)
        .zip(logit.par_chunks_mut(BLOCK * per))
        .enumerate()
        .for_each(|(b, (idx, lg))| {
            let lo = b * BLOCK;
            let hi = (lo + BLOCK).min(q);
            let xb = x.slice(s![lo..hi, ..]);
            let gb = guide.map(|g| Guide {
                query: g.query.slice_move(s![lo..hi, ..]),
                ..g
            });
            let (mut scratch, mut vals) = (Vec::with_capacity(m), Vec::with_capacity(m));
            let mut keep = |r: usize, chosen: &[u32]| {
                for (l, &j) in chosen.iter().enumerate() {
                    idx[r * per + l] = j;
                    lg[r * per + l] = exact_logit(bank, xb.row(r), j as usize, level, gb, r);
                }
            };
            if let Some((red, ivf)) = ivf {
                let cells = CellSearch { red, ivf, probe };
                for (r, chosen) in cells.shortlists(xb, level, gb, per).iter().enumerate() {
                    keep(r, chosen);
                }
                return;
            }
            let approx = approximate_logits(bank, xb, level, gb);
            for r in 0..hi - lo {
                let row = approx.row(r);
                let row = row.as_slice().expect("standard layout");
                top_indices(row, per, &mut scratch, &mut vals);
                keep(r, &scratch);
            }
        });
    Candidates { per, index, logit }
}

/// Logits of every bank patch for queries `x` `[q, D]`, from one matrix product in the
/// bank's search space (PCA coordinates when the bank has them: an approximation used
/// only to choose candidates).
fn approximate_logits(
    bank: &Bank,
    x: ArrayView2<'_, f32>,
    level: Level,
    guide: Option<Guide<'_>>,
) -> Array2<f32> {
    let Level { sa, sb } = level;
    let var2 = 2.0 * sb * sb;
    let (xs, ys, yn) = match &bank.reduced {
        Some(r) => (r.pca.project(x, sa), r.coords.view(), r.norms.view()),
        None => (x.to_owned(), bank.patches.view(), bank.norms.view()),
    };
    let xn = row_norms(xs.view());
    let mut dots = xs.dot(&ys.t());
    for (mut row, xi) in dots.axis_iter_mut(Axis(0)).zip(xn.iter()) {
        for (v, yj) in row.iter_mut().zip(yn.iter()) {
            let d = (xi - 2.0 * sa * *v + sa * sa * yj).max(0.0);
            *v = -d / var2;
        }
    }
    if let Some(g) = guide {
        let (gqn, gbn) = (row_norms(g.query), row_norms(g.bank));
        let gd = g.query.dot(&g.bank.t());
        for ((mut row, gi), grow) in dots.axis_iter_mut(Axis(0)).zip(gqn.iter()).zip(gd.rows()) {
            for ((v, gj), dot) in row.iter_mut().zip(gbn.iter()).zip(grow) {
                *v -= g.weight * (gi - 2.0 * dot + gj).max(0.0);
            }
        }
    }
    dots
}

/// The exact logit of bank patch `j` for query row `x` (query `r` of the guide's block).
fn exact_logit(
    bank: &Bank,
    x: ndarray::ArrayView1<'_, f32>,
    j: usize,
    level: Level,
    guide: Option<Guide<'_>>,
    r: usize,
) -> f32 {
    let y = bank.patches.row(j);
    let d: f32 = x
        .iter()
        .zip(y)
        .map(|(a, b)| {
            let e = a - level.sa * b;
            e * e
        })
        .sum();
    let g = guide.map_or(0.0, |g| {
        let d: f32 = g
            .query
            .row(r)
            .iter()
            .zip(g.bank.row(j))
            .map(|(a, b)| (a - b) * (a - b))
            .sum();
        g.weight * d
    });
    -d / (2.0 * level.sb * level.sb) - g
}

/// Indices of the `n` largest values of `row` into `out`, ascending (all of them when
/// `n` >= len): the n-th largest value found by selection on a copy, then one pass.
fn top_indices(row: &[f32], n: usize, out: &mut Vec<u32>, vals: &mut Vec<f32>) {
    out.clear();
    if n >= row.len() {
        out.extend(0..row.len() as u32);
        return;
    }
    vals.clear();
    vals.extend_from_slice(row);
    let (_, nth, _) = vals.select_nth_unstable_by(n - 1, |a, b| b.total_cmp(a));
    let thr = *nth;
    // Strictly above the threshold first, then ties up to n, in index order.
    let above = row.iter().filter(|v| **v > thr).count();
    let mut ties = n - above;
    for (j, v) in row.iter().enumerate() {
        if *v > thr {
            out.push(j as u32);
        } else if *v == thr && ties > 0 {
            out.push(j as u32);
            ties -= 1;
        }
    }
}

/// Per-pixel softmax of the candidates' logits (plus column potentials `g`, if given).
fn softmax_rows(c: &Candidates, g: Option<&[f32]>) -> Vec<f32> {
    let mut w = vec![0.0f32; c.logit.len()];
    w.par_chunks_mut(c.per)
        .zip(c.logit.par_chunks(c.per))
        .zip(c.index.par_chunks(c.per))
        .for_each(|((w, l), idx)| {
            softmax_into(w, |k| l[k] + g.map_or(0.0, |g| g[idx[k] as usize]));
        });
    w
}

#[cfg(test)]
mod tests {
    use super::super::bank::{Pca, patches};
    use super::*;
    use crate::rng::Rng;
    use ndarray::Array3;

    fn noisy_image(seed: u64, c: usize, h: usize, w: usize) -> Array3<f32> {
        let mut r = Rng::new(seed);
        Array3::from_shape_vec((c, h, w), r.normals_f32(c * h * w)).unwrap()
    }

    fn bank(k: usize, pca: Option<usize>) -> Bank {
        let style = noisy_image(1, 3, 12, 10).mapv(|v| (0.5 * v).tanh());
        let p = patches(style.view(), k, 1);
        let pca = pca.map(|d| Pca::fit(p.view(), d, 20).unwrap());
        Bank::new(p, k, 3, pca, 0).unwrap()
    }

    #[test]
    fn the_whole_bank_as_shortlist_is_the_exact_posterior() {
        let b = bank(3, None);
        let z = noisy_image(2, 3, 6, 7);
        let x = patches(z.view(), 3, 1);
        let level = Level { sa: 0.8, sb: 0.6 };
        let exact = denoise_exact(&b, x.view(), level, None);
        let search = Search {
            shortlist: 0,
            probe: 0,
            balance: 0,
        };
        let fast = denoise(&b, x.view(), level, search, None);
        let err = (&fast - &exact)
            .mapv(f32::abs)
            .fold(0.0f32, |a, v| a.max(*v));
        assert!(err < 1e-5, "max error {err}");
    }

    #[test]
    fn the_limits_of_the_noise_level() {
        let b = bank(3, None);
        // t -> 0: a query that is bank patch j, noised by almost nothing, returns c_j.
        let level = Level {
            sa: (1.0f32 - 1e-6).sqrt(),
            sb: 1e-3,
        };
        let j = 37;
        let x = b.patches.slice(s![j..j + 1, ..]).to_owned() * level.sa;
        let got = denoise_exact(&b, x.view(), level, None);
        for c in 0..3 {
            assert!((got[[0, c]] - b.centres[[j, c]]).abs() < 1e-6);
        }
        // A one-patch bank returns its patch at any noise level.
        let one = Bank::new(b.patches.slice(s![j..j + 1, ..]).to_owned(), 3, 3, None, 0).unwrap();
        let z = noisy_image(9, 3, 4, 4);
        let q = patches(z.view(), 3, 1);
        let got = denoise_exact(&one, q.view(), Level { sa: 0.5, sb: 0.87 }, None);
        assert!(
            got.rows()
                .into_iter()
                .all(|r| (0..3).all(|c| r[c] == one.centres[[0, c]]))
        );
        // Large t (ab -> 0): every patch equally likely, the bank's mean centre.
        let far = Level { sa: 1e-4, sb: 1.0 };
        let got = denoise_exact(&b, q.view(), far, None);
        let mean = b.centres.mean_axis(Axis(0)).unwrap();
        for r in got.rows() {
            for c in 0..3 {
                assert!((r[c] - mean[c]).abs() < 1e-3, "{} vs {}", r[c], mean[c]);
            }
        }
    }

    /// A smooth test image `[3, h, w]` (a few sinusoids per channel) in [-1, 1].
    fn smooth(h: usize, w: usize) -> ndarray::Array3<f32> {
        ndarray::Array3::from_shape_fn((3, h, w), |(c, y, x)| {
            let (y, x, c) = (y as f32, x as f32, c as f32);
            (0.5 * (0.7 * x + 0.3 * c).sin() + 0.4 * (0.45 * y - 0.2 * x + c).cos()).tanh()
        })
    }

    #[test]
    fn a_shortlist_in_pca_coordinates_keeps_the_posterior_at_low_noise() {
        // Noisy patches of a smooth image at low noise: the posterior sits on a few
        // patches, and a shortlist of 16 chosen in 8 PCA dimensions (of 27) holds them.
        let style = smooth(14, 12);
        let p = patches(style.view(), 3, 1);
        let pca = Pca::fit(p.view(), 8, 20).unwrap();
        let b = Bank::new(p, 3, 3, Some(pca), 0).unwrap();
        let level = Level { sa: 0.99, sb: 0.14 };
        let z = &style * level.sa + &(noisy_image(4, 3, 14, 12) * level.sb);
        let x = patches(z.view(), 3, 1);
        let exact = denoise_exact(&b, x.view(), level, None);
        let search = Search {
            shortlist: 16,
            probe: 0,
            balance: 0,
        };
        let fast = denoise(&b, x.view(), level, search, None);
        let err = (&fast - &exact).mapv(f32::abs).mean().unwrap();
        assert!(err < 0.01, "mean error {err}");
    }

    #[test]
    fn balancing_spreads_the_use_of_the_bank() {
        // Noisy copies of one flat patch: the plain posterior gives them the patches
        // nearest to it; the balanced coupling spreads them over the bank's cells in the
        // bank's proportions, so the mean estimate approaches the bank's mean centre.
        let style = smooth(24, 24);
        let p = patches(style.view(), 3, 1);
        let pca = Pca::fit(p.view(), 8, 20).unwrap();
        let b = Bank::new(p, 3, 3, Some(pca), 16).unwrap();
        let level = Level { sa: 0.95, sb: 0.3 };
        let flat = ndarray::Array3::<f32>::from_elem((3, 20, 20), 0.4);
        let z = &flat * level.sa + &(noisy_image(5, 3, 20, 20) * level.sb);
        let x = patches(z.view(), 3, 1);
        let run = |balance| {
            let search = Search {
                shortlist: 16,
                probe: 3,
                balance,
            };
            denoise(&b, x.view(), level, search, None)
        };
        let want = b.centres.mean_axis(Axis(0)).unwrap();
        let gap = |e: &Array2<f32>| {
            (&e.mean_axis(Axis(0)).unwrap() - &want)
                .mapv(f32::abs)
                .sum()
        };
        let (plain, bal) = (gap(&run(0)), gap(&run(30)));
        assert!(bal < 0.25 * plain, "mean gap balanced {bal}, plain {plain}");
    }

    /// The local model by offsets and summed-area tables equals the patch-by-patch
    /// posterior (the candidates' patches read with reflection, compared in full).
    #[test]
    fn the_local_model_by_offsets_is_the_patchwise_posterior() {
        use super::super::bank::patches_at;
        let (c, h, w, k, r) = (3, 9, 11, 5, 2);
        let src = noisy_image(5, c, h, w).insert_axis(Axis(0));
        let z = noisy_image(6, c, h, w).insert_axis(Axis(0));
        let level = Level { sa: 0.8, sb: 0.6 };
        let pixels: Vec<[usize; 3]> = (0..h * w).map(|i| [0, i / w, i % w]).collect();
        let fast = denoise_local(src.view(), z.view(), &pixels, k, r, level);
        let bank = patches(src.index_axis(Axis(0), 0), k, 1);
        let x = patches_at(z.view(), k, &pixels);
        let mid = ((k / 2) * k + k / 2) * c;
        for (i, &[_, y, xx]) in pixels.iter().enumerate() {
            let mut cand = Vec::new();
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xc in xx.saturating_sub(r)..(xx + r + 1).min(w) {
                    let j = yy * w + xc;
                    let d: f64 = x
                        .row(i)
                        .iter()
                        .zip(bank.row(j))
                        .map(|(a, b)| ((a - level.sa * b) as f64).powi(2))
                        .sum();
                    cand.push((-d / (2.0 * (level.sb as f64).powi(2)), j));
                }
            }
            let top = cand.iter().map(|v| v.0).fold(f64::NEG_INFINITY, f64::max);
            let zs: f64 = cand.iter().map(|v| (v.0 - top).exp()).sum();
            for ch in 0..c {
                let want: f64 = cand
                    .iter()
                    .map(|&(l, j)| (l - top).exp() * bank[[j, mid + ch]] as f64)
                    .sum::<f64>()
                    / zs;
                let got = fast[[i, ch]] as f64;
                assert!(
                    (got - want).abs() < 1e-5,
                    "pixel {i} channel {ch}: {got} vs {want}"
                );
            }
        }
    }
}

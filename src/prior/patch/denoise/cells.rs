//! The inverted-file search of the fast patch denoiser: each query's shortlist among the
//! members of its `probe` nearest cells, and the balanced estimate, which couples the
//! queries to the cells by entropic optimal transport (Sinkhorn iterations in the log
//! domain with epsilon scaling, Schmitzer 2019; [`crate::maths::sinkhorn`]) so that over
//! the batch the style's patches are used in their own proportions (bidirectional
//! similarity, Simakov et al. 2008; patch-distribution optimal transport, Houdard et al.
//! 2021), then mixes the exact posterior means (Kamb & Ganguli, ICML 2025) within each
//! query's heaviest cells.

use super::*;

/// The shortlist search through an inverted file.
pub(super) struct CellSearch<'a> {
    pub(super) red: &'a crate::prior::patch::bank::Reduced,
    pub(super) ivf: &'a crate::prior::patch::bank::Ivf,
    pub(super) probe: usize,
}

impl CellSearch<'_> {
    /// The `per` best candidates of every query of `x` `[q, D]` by approximate logit
    /// among the members of its `probe` nearest cells (by the distance to sa times the
    /// cell's centroid in PCA coordinates).
    pub(super) fn shortlists(
        &self,
        x: ArrayView2<'_, f32>,
        level: Level,
        guide: Option<Guide<'_>>,
        per: usize,
    ) -> Vec<Vec<u32>> {
        let Level { sa, sb } = level;
        let var2 = 2.0 * sb * sb;
        let xp = self.red.pca.project(x, sa);
        let xn = row_norms(xp.view());
        let cd = xp.dot(&self.ivf.centroids.t());
        let (mut members, mut vals, mut top, mut tmp) = (vec![], vec![], vec![], vec![]);
        (0..x.nrows())
            .map(|r| {
                let cells = cell_order(cd.row(r), &self.ivf.norms, sa, self.probe);
                members.clear();
                for c in cells {
                    members.extend_from_slice(&self.ivf.cells[c]);
                }
                if members.is_empty() {
                    // Every probed cell empty (k-means leaves some on a small bank): the
                    // nearest cell that has members.
                    let all = cell_order(cd.row(r), &self.ivf.norms, sa, self.ivf.cells.len());
                    if let Some(c) = all.into_iter().find(|&c| !self.ivf.cells[c].is_empty()) {
                        members.extend_from_slice(&self.ivf.cells[c]);
                    }
                }
                vals.clear();
                let xr = xp.row(r);
                for &j in &members {
                    let y = self.red.coords.row(j as usize);
                    let d = (xn[r] - 2.0 * sa * xr.dot(&y) + sa * sa * self.red.norms[j as usize])
                        .max(0.0);
                    let g = guide.map_or(0.0, |g| {
                        let (a, b) = (g.query.row(r), g.bank.row(j as usize));
                        g.weight * a.iter().zip(b).map(|(p, q)| (p - q) * (p - q)).sum::<f32>()
                    });
                    vals.push(-d / var2 - g);
                }
                top_indices(&vals, per.min(vals.len()), &mut top, &mut tmp);
                let mut chosen: Vec<u32> = top.iter().map(|&i| members[i as usize]).collect();
                // Too few members: pad with the first candidate (weight split evenly).
                while chosen.len() < per {
                    chosen.push(chosen[0]);
                }
                chosen
            })
            .collect()
    }
}

/// A cell's share of the coupling below which it is not searched.
const CELL_FLOOR: f32 = 0.01;

impl CellSearch<'_> {
    /// The balanced estimate `[Q, C]`: the queries are coupled to the index's cells by
    /// entropic optimal transport (`iters` Sinkhorn rounds in the log domain) at the
    /// posterior's temperature 2 sb^2, with every cell's column mass its share of the bank
    /// (so that over the batch the style's patches are used in their own proportions, and
    /// no single flat patch wins everywhere); then each query's estimate is the coupling-
    /// weighted mix of the exact posterior means within its `probe` heaviest cells.
    pub(super) fn balanced(
        &self,
        bank: &Bank,
        x: ArrayView2<'_, f32>,
        level: Level,
        (iters, per): (usize, usize),
        guide: Option<Guide<'_>>,
    ) -> Array2<f32> {
        let Level { sa, sb } = level;
        let var2 = 2.0 * sb * sb;
        let xp = self.red.pca.project(x, sa);
        let xn = row_norms(xp.view());
        let coupling = self.coupling(xp.view(), &xn, level, iters);
        let (c, k) = (bank.channels, self.ivf.cells.len());
        let mut out = vec![0.0f32; x.nrows() * c];
        out.par_chunks_mut(c).enumerate().for_each(|(i, o)| {
            let row = &coupling[i * k..(i + 1) * k];
            let mut cells: Vec<usize> = (0..k).collect();
            cells.sort_unstable_by(|a, b| row[*b].total_cmp(&row[*a]));
            cells.truncate(self.probe);
            let best = row[cells[0]];
            cells.retain(|&cc| row[cc] >= CELL_FLOOR * best);
            let total: f32 = cells.iter().map(|&cc| row[cc]).sum();
            let (mut approx, mut top, mut tmp) = (Vec::new(), Vec::new(), Vec::new());
            for &cc in &cells {
                // Candidates of the cell by approximate logit, then exact logits.
                let members = &self.ivf.cells[cc];
                approx.clear();
                let xr = xp.row(i);
                for &j in members {
                    let y = self.red.coords.row(j as usize);
                    let d = xn[i] - 2.0 * sa * xr.dot(&y) + sa * sa * self.red.norms[j as usize];
                    approx.push(-d.max(0.0) / var2);
                }
                let n = if per == 0 {
                    members.len()
                } else {
                    per.min(members.len())
                };
                top_indices(&approx, n, &mut top, &mut tmp);
                let logits: Vec<(u32, f32)> = top
                    .iter()
                    .map(|&m| {
                        let j = members[m as usize];
                        (j, exact_logit(bank, x.row(i), j as usize, level, guide, i))
                    })
                    .collect();
                let l: Vec<f32> = logits.iter().map(|l| l.1).collect();
                let (w, z) = shifted_exp(&l);
                let share = row[cc] / total / z;
                for ((j, _), wj) in logits.iter().zip(&w) {
                    for ch in 0..c {
                        o[ch] += share * wj * bank.centres[[*j as usize, ch]];
                    }
                }
            }
        });
        Array2::from_shape_vec((x.nrows(), c), out).expect("length matches")
    }

    /// The entropic coupling `[Q, K]` of queries to cells (rows sum to 1, columns to the
    /// cells' shares of Q), costs ||x - sa centroid||^2 in PCA coordinates.
    fn coupling(
        &self,
        xp: ArrayView2<'_, f32>,
        xn: &ndarray::Array1<f32>,
        level: Level,
        iters: usize,
    ) -> Vec<f32> {
        let Level { sa, sb } = level;
        let var2 = 2.0 * sb * sb;
        let dots = xp.dot(&self.ivf.centroids.t());
        let (q, k) = dots.dim();
        // Each query's NEAR nearest cells and their costs (squared-distance units).
        let near = NEAR.min(k);
        let mut idx = vec![0u32; q * near];
        let mut cost = vec![0.0f32; q * near];
        let mut all = vec![0.0f32; k];
        let (mut top, mut tmp) = (Vec::new(), Vec::new());
        for i in 0..q {
            for c in 0..k {
                all[c] = -(xn[i] - 2.0 * sa * dots[[i, c]] + sa * sa * self.ivf.norms[c]).max(0.0);
            }
            top_indices(&all, near, &mut top, &mut tmp);
            for (l, &c) in top.iter().enumerate() {
                idx[i * near + l] = c;
                cost[i * near + l] = -all[c as usize];
            }
        }
        let m: usize = self.ivf.cells.iter().map(Vec::len).sum();
        let share: Vec<f32> = self
            .ivf
            .cells
            .iter()
            .map(|c| (c.len().max(1) as f32 / m as f32 * q as f32).ln())
            .collect();
        // epsilon-scaling (Schmitzer 2019): the temperature falls geometrically from the
        // costs' mean to the posterior's 2 sb^2 over the rounds, the potentials (in cost
        // units) carried from round to round, so that a cold coupling still converges.
        let mean = cost.iter().map(|v| *v as f64).sum::<f64>() / cost.len().max(1) as f64;
        let cold = var2;
        let hot = (mean as f32).max(cold);
        let (mut f, mut g) = (vec![0.0f32; q], vec![0.0f32; k]);
        let costs = Costs {
            cost: &cost,
            index: Some(&idx),
            per: near,
            cols: k,
        };
        let scheme = Sinkhorn { rho: 1.0 };
        scheme.run(
            costs,
            &share,
            epsilon_scaling(hot, cold, iters),
            &mut f,
            &mut g,
        );
        scheme.rows(costs, &g, &mut f, cold);
        let mut out = vec![0.0f32; q * k];
        out.par_chunks_mut(k).enumerate().for_each(|(i, o)| {
            for l in 0..near {
                let c = idx[i * near + l] as usize;
                o[c] = ((f[i] + g[c] - cost[i * near + l]) / cold).exp();
            }
        });
        out
    }
}

/// Cells a query may be coupled to (its nearest by centroid distance).
const NEAR: usize = 24;

/// The `probe` cells whose centroid, times `sa`, is nearest to the query (its centroid
/// dot products `dots` `[K]`).
fn cell_order(
    dots: ndarray::ArrayView1<'_, f32>,
    norms: &ndarray::Array1<f32>,
    sa: f32,
    probe: usize,
) -> Vec<usize> {
    let d: Vec<f32> = dots
        .iter()
        .zip(norms)
        .map(|(p, n)| sa * sa * n - 2.0 * sa * p)
        .collect();
    let mut order: Vec<usize> = (0..d.len()).collect();
    let p = probe.min(d.len());
    if p < d.len() {
        order.select_nth_unstable_by(p - 1, |a, b| d[*a].total_cmp(&d[*b]));
        order.truncate(p);
    }
    order
}

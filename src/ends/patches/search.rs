//! The exact search of a level ([`super::level::StyleLevel::nearest_per_cell`]): for
//! every query and every cell of the style bank, the cell's nearest patch (squared
//! distance and index), in blocks that stay in cache.
//!
//! The bank's search coordinates are packed cell by cell, eight patches to a chunk
//! (coordinate-major within a chunk, so eight patches' k-th coordinates are one
//! vector); a task takes `BLOCK` queries and walks the cells, each cell's chunks
//! against `GROUP` queries at a time. Every (query, patch) distance is the same
//! floating-point computation as the search it replaced (a matrix product of
//! `matrixmultiply`'s sgemm, whose kernel on AVX2 + FMA CPUs sums each dot product
//! over the coordinates in order, fused, from zero, in blocks of `KC` coordinates
//! added up after), `max(|q|^2 + |b|^2 - 2 q.b, 0)`, and each cell keeps the first
//! patch (lowest index) at its minimum: the results are bit for bit the old ones.
//!
//! Two paths give the same bits on every CPU: x86-64 CPUs with AVX2 and FMA run eight
//! patches per instruction (chosen at run time), others a portable loop; both fuse the
//! same multiply-adds (`f32::mul_add` is exact everywhere) in the same order, and the
//! per-lane minima of the vector path reduce to the same first minimum as the portable
//! path's scan (see the tests).

use ndarray::Array2;
use rayon::prelude::*;

/// Patches per chunk (one AVX2 vector).
const LANES: usize = 8;
/// Coordinates summed from zero before being added to the dot product (the depth block
/// `S_KC` of matrixmultiply's sgemm, which the old search used).
const KC: usize = 256;
/// Queries per task.
const BLOCK: usize = 64;
/// Queries against one chunk at a time (the vector path's accumulators).
const GROUP: usize = 8;

/// A level's bank packed for the search, cell by cell.
pub(super) struct CellSearch {
    dims: usize,
    cells: usize,
    /// Cell c's chunks are `starts[c]..starts[c + 1]`.
    starts: Vec<usize>,
    /// `[chunk][dims][LANES]`; padding lanes 0.
    coords: Vec<f32>,
    /// `[chunk][LANES]` squared norms; padding lanes +inf (never nearest).
    norms: Vec<f32>,
    /// `[chunk][LANES]` bank indices, ascending within a cell; padding `u32::MAX`.
    ids: Vec<u32>,
}

/// Which implementation a search runs (tests run both).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Path {
    /// The vector path where the CPU has AVX2 and FMA, else the portable one.
    Best,
    #[cfg_attr(not(test), allow(dead_code))]
    Portable,
}

impl CellSearch {
    /// The bank's search coordinates `coords` `[M, d]`, their squared norms `norms` and
    /// each patch's cell `cell_of` (of `cells`).
    pub(super) fn new(
        coords: &Array2<f32>,
        norms: &[f32],
        cell_of: &[u32],
        cells: usize,
    ) -> CellSearch {
        let (m, dims) = coords.dim();
        let mut members = vec![Vec::new(); cells];
        for j in 0..m {
            members[cell_of[j] as usize].push(j as u32);
        }
        let mut starts = vec![0];
        let (mut packed, mut nrm, mut ids) = (Vec::new(), Vec::new(), Vec::new());
        for mem in &members {
            for chunk in mem.chunks(LANES) {
                let base = packed.len();
                packed.resize(base + dims * LANES, 0.0);
                let (mut n, mut id) = ([f32::INFINITY; LANES], [u32::MAX; LANES]);
                for (l, &j) in chunk.iter().enumerate() {
                    for k in 0..dims {
                        packed[base + k * LANES + l] = coords[[j as usize, k]];
                    }
                    n[l] = norms[j as usize];
                    id[l] = j;
                }
                nrm.extend(n);
                ids.extend(id);
            }
            starts.push(ids.len() / LANES);
        }
        CellSearch {
            dims,
            cells,
            starts,
            coords: packed,
            norms: nrm,
            ids,
        }
    }

    /// For each query (search coordinates `qc` `[P, d]`) and each cell, the nearest
    /// patch of that cell: `[P x cells]` squared distances and patch indices (infinite
    /// distance and index 0 for an empty cell).
    pub(super) fn nearest_per_cell(&self, qc: &Array2<f32>, path: Path) -> (Vec<f32>, Vec<u32>) {
        assert_eq!(qc.ncols(), self.dims, "queries in the bank's coordinates");
        let qn: Vec<f32> = qc.rows().into_iter().map(|row| row.dot(&row)).collect();
        let q = qc.as_standard_layout();
        let q = q.as_slice().expect("standard layout");
        let (p, cells, dims) = (qc.nrows(), self.cells, self.dims);
        let mut dist = vec![f32::INFINITY; p * cells];
        let mut arg = vec![0u32; p * cells];
        dist.par_chunks_mut(BLOCK * cells)
            .zip(arg.par_chunks_mut(BLOCK * cells))
            .enumerate()
            .for_each(|(b, (d, a))| {
                let (lo, n) = (b * BLOCK, d.len() / cells);
                let (q, qn) = (&q[lo * dims..(lo + n) * dims], &qn[lo..lo + n]);
                self.block(q, qn, d, a, path);
            });
        (dist, arg)
    }

    /// One task's queries `q` `[n, d]` (squared norms `qn`) into `dist`, `arg`
    /// `[n x cells]`.
    fn block(&self, q: &[f32], qn: &[f32], dist: &mut [f32], arg: &mut [u32], path: Path) {
        #[cfg(target_arch = "x86_64")]
        if path == Path::Best
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the function requires AVX2 and FMA, which the CPU has (checked just
            // above); its loads stay inside the slices (see there).
            #[allow(unsafe_code)]
            unsafe {
                avx2::block(self, q, qn, dist, arg)
            };
            return;
        }
        let _ = path;
        self.block_portable(q, qn, dist, arg);
    }

    /// [`Self::block`] without vectors: each cell's patches scanned in index order, the
    /// first strictly smaller distance kept (the old search's scan).
    fn block_portable(&self, q: &[f32], qn: &[f32], dist: &mut [f32], arg: &mut [u32]) {
        let (dims, cells) = (self.dims, self.cells);
        for (i, qi) in q.chunks_exact(dims).enumerate() {
            for c in 0..cells {
                let (mut best, mut at) = (f32::INFINITY, 0u32);
                for ch in self.starts[c]..self.starts[c + 1] {
                    let x = &self.coords[ch * dims * LANES..(ch + 1) * dims * LANES];
                    for l in 0..LANES {
                        let id = self.ids[ch * LANES + l];
                        if id == u32::MAX {
                            continue;
                        }
                        let v = distance(qn[i], self.norms[ch * LANES + l], dot_lane(qi, x, l));
                        if v < best {
                            (best, at) = (v, id);
                        }
                    }
                }
                dist[i * cells + c] = best;
                arg[i * cells + c] = at;
            }
        }
    }
}

/// The squared distance from the norms and the dot product, clamped at 0 as the vector
/// path's `max(v, 0)` does (0 for NaN).
#[inline(always)]
fn distance(qn: f32, n: f32, dot: f32) -> f32 {
    let v = qn + n - 2.0 * dot;
    if v > 0.0 { v } else { 0.0 }
}

/// The dot product of query `q` with lane `l` of chunk `x` (`[d][LANES]`): fused
/// multiply-adds over the coordinates in order from zero, `KC` at a time, the blocks'
/// sums added in order.
#[inline(always)]
fn dot_lane(q: &[f32], x: &[f32], l: usize) -> f32 {
    let mut total = 0.0f32;
    for k0 in (0..q.len()).step_by(KC) {
        let mut s = 0.0f32;
        for k in k0..(k0 + KC).min(q.len()) {
            s = q[k].mul_add(x[k * LANES + l], s);
        }
        total = if k0 == 0 { s } else { total + s };
    }
    total
}

/// The vector path (AVX2 + FMA).
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2 {
    use super::{CellSearch, GROUP, KC, LANES};
    use std::arch::x86_64::*;

    /// [`CellSearch::block`] with eight patches per instruction: `GROUP` queries'
    /// dot products with one chunk at a time, then per query and lane the first
    /// strictly smaller distance kept; at a cell's end the lanes' minima reduce to the
    /// smallest distance and, among the lanes that hold it, the smallest index (the
    /// first in index order, as the portable scan finds it).
    ///
    /// # Safety
    /// The CPU must have AVX2 and FMA. Every load reads inside `s.coords`, `s.norms`,
    /// `s.ids` (a chunk's `dims * LANES` values and `LANES` norms and indices) or `q`
    /// (a query's `dims` values: row indices are clamped to the last query).
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn block(
        s: &CellSearch,
        q: &[f32],
        qn: &[f32],
        dist: &mut [f32],
        arg: &mut [u32],
    ) {
        let (dims, cells, nq) = (s.dims, s.cells, qn.len());
        let (zero, two) = (_mm256_setzero_ps(), _mm256_set1_ps(2.0));
        for c in 0..cells {
            for i0 in (0..nq).step_by(GROUP) {
                let rows: [usize; GROUP] = std::array::from_fn(|t| (i0 + t).min(nq - 1));
                let qp: [*const f32; GROUP] = rows.map(|r| q[r * dims..].as_ptr());
                let qnv: [__m256; GROUP] = rows.map(|r| _mm256_set1_ps(qn[r]));
                let mut bv = [_mm256_set1_ps(f32::INFINITY); GROUP];
                let mut bi = [_mm256_setzero_si256(); GROUP];
                for ch in s.starts[c]..s.starts[c + 1] {
                    let x = s.coords[ch * dims * LANES..].as_ptr();
                    let mut dot = [zero; GROUP];
                    for k0 in (0..dims).step_by(KC) {
                        let mut acc = [zero; GROUP];
                        for k in k0..(k0 + KC).min(dims) {
                            // SAFETY: k < dims, inside the chunk and each query row.
                            let xv = unsafe { _mm256_loadu_ps(x.add(k * LANES)) };
                            for t in 0..GROUP {
                                let qv = unsafe { _mm256_set1_ps(*qp[t].add(k)) };
                                acc[t] = _mm256_fmadd_ps(qv, xv, acc[t]);
                            }
                        }
                        for t in 0..GROUP {
                            dot[t] = if k0 == 0 {
                                acc[t]
                            } else {
                                _mm256_add_ps(dot[t], acc[t])
                            };
                        }
                    }
                    // SAFETY: chunk `ch` has LANES norms and indices.
                    let n = unsafe { _mm256_loadu_ps(s.norms[ch * LANES..].as_ptr()) };
                    let ids = unsafe {
                        _mm256_loadu_si256(s.ids[ch * LANES..].as_ptr() as *const __m256i)
                    };
                    for t in 0..GROUP {
                        let v = _mm256_sub_ps(_mm256_add_ps(qnv[t], n), _mm256_mul_ps(two, dot[t]));
                        let v = _mm256_max_ps(v, zero);
                        let lt = _mm256_cmp_ps::<_CMP_LT_OQ>(v, bv[t]);
                        bv[t] = _mm256_blendv_ps(bv[t], v, lt);
                        bi[t] = _mm256_castps_si256(_mm256_blendv_ps(
                            _mm256_castsi256_ps(bi[t]),
                            _mm256_castsi256_ps(ids),
                            lt,
                        ));
                    }
                }
                for t in 0..GROUP.min(nq - i0) {
                    let (mut v, mut id) = ([0.0f32; LANES], [0u32; LANES]);
                    // SAFETY: both arrays hold one vector.
                    unsafe {
                        _mm256_storeu_ps(v.as_mut_ptr(), bv[t]);
                        _mm256_storeu_si256(id.as_mut_ptr() as *mut __m256i, bi[t]);
                    }
                    let best = v.iter().copied().fold(f32::INFINITY, f32::min);
                    let at = if best < f32::INFINITY {
                        (0..LANES)
                            .filter(|&l| v[l] == best)
                            .map(|l| id[l])
                            .min()
                            .expect("a lane holds the minimum")
                    } else {
                        0
                    };
                    dist[(i0 + t) * cells + c] = best;
                    arg[(i0 + t) * cells + c] = at;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// The search as it was (a matrix product, then each cell's first minimum in index
    /// order): the reference the packed search must match bit for bit.
    fn old_search(
        coords: &Array2<f32>,
        norms: &[f32],
        cell_of: &[u32],
        cells: usize,
        qc: &Array2<f32>,
    ) -> (Vec<f32>, Vec<u32>) {
        let qn: Vec<f32> = qc.rows().into_iter().map(|row| row.dot(&row)).collect();
        let dots = qc.dot(&coords.t());
        let mut dist = vec![f32::INFINITY; qc.nrows() * cells];
        let mut arg = vec![0u32; qc.nrows() * cells];
        for (i, row) in dots.rows().into_iter().enumerate() {
            let (d, a) = (&mut dist[i * cells..], &mut arg[i * cells..]);
            for (j, (&dot, &n)) in row.iter().zip(norms).enumerate() {
                let c = cell_of[j] as usize;
                let v = (qn[i] + n - 2.0 * dot).max(0.0);
                if v < d[c] {
                    d[c] = v;
                    a[c] = j as u32;
                }
            }
        }
        (dist, arg)
    }

    /// A bank of `m` patches in `dims` coordinates and `p` queries: normal draws, or
    /// (`coarse`) values on a grid of step 1/4, so that distances tie often.
    fn case(seed: u64, m: usize, dims: usize, p: usize, coarse: bool) -> [Array2<f32>; 2] {
        let mut r = Rng::new(seed);
        let mut draw = |n: usize| {
            Array2::from_shape_fn((n, dims), |_| {
                let v = r.normal() as f32;
                if coarse { (v * 4.0).round() / 4.0 } else { v }
            })
        };
        [draw(m), draw(p)]
    }

    fn cells_of(m: usize, cells: usize) -> Vec<u32> {
        (0..m)
            .map(|j| {
                let c = (j * 7 + j / 3) % cells;
                if c == 1 { 0 } else { c as u32 }
            })
            .collect()
    }

    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn both_paths_give_the_same_bits() {
        for (seed, m, dims, cells, p) in
            [(1, 300, 33, 8, 70), (2, 61, 5, 3, 9), (3, 40, 300, 4, 13)]
        {
            for coarse in [false, true] {
                let [coords, qc] = case(seed, m, dims, p, coarse);
                let norms: Vec<f32> = coords.rows().into_iter().map(|r| r.dot(&r)).collect();
                let s = CellSearch::new(&coords, &norms, &cells_of(m, cells), cells);
                let (d0, a0) = s.nearest_per_cell(&qc, Path::Portable);
                let (d1, a1) = s.nearest_per_cell(&qc, Path::Best);
                assert_eq!(bits(&d0), bits(&d1), "distances, case {seed}");
                assert_eq!(a0, a1, "indices, case {seed}");
                assert!(
                    d0[1..].iter().step_by(cells).all(|d| d.is_infinite()),
                    "empty cell"
                );
            }
        }
    }

    /// The old search's kernel fuses its multiply-adds where the CPU has AVX2 and FMA
    /// (matrixmultiply's choice; elsewhere it rounded each product, which the packed
    /// search, the same on every CPU, does not reproduce): there the results are its
    /// bits, ties broken alike.
    #[test]
    fn the_packed_search_is_the_old_search_bit_for_bit() {
        #[cfg(target_arch = "x86_64")]
        if !(std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma"))
        {
            return;
        }
        #[cfg(not(target_arch = "x86_64"))]
        return;
        for (seed, m, dims, cells, p) in [
            (4, 500, 33, 16, 130),
            (5, 64, 24, 1, 17),
            (6, 50, 300, 4, 9),
        ] {
            for coarse in [false, true] {
                let [coords, qc] = case(seed, m, dims, p, coarse);
                let norms: Vec<f32> = coords.rows().into_iter().map(|r| r.dot(&r)).collect();
                let cell_of = cells_of(m, cells);
                let (d0, a0) = old_search(&coords, &norms, &cell_of, cells, &qc);
                let s = CellSearch::new(&coords, &norms, &cell_of, cells);
                for path in [Path::Best, Path::Portable] {
                    let (d, a) = s.nearest_per_cell(&qc, path);
                    assert_eq!(bits(&d), bits(&d0), "distances, case {seed}, {path:?}");
                    assert_eq!(a, a0, "indices, case {seed}, {path:?}");
                }
            }
        }
    }
}

//! Binning of projected splats into 16x16 tiles, front to back (the CPU form of the
//! tile sort of Kerbl et al. 2023, Sec. 6).
//!
//! 1. Depth order: an LSD radix sort (three stable 11-bit passes) of the keys
//!    `(depth bits) << 32 | index`. Depths are positive floats, whose bit patterns order
//!    like the values, and the index breaks ties, so the order is total.
//! 2. A counting sort of the (tile, splat) pairs by tile that visits the splats in that
//!    order, so every tile's list comes out front to back.
//!
//! Both are parallel: the input is cut into pieces, each piece counts its own
//! histogram, a prefix sum over (bucket, piece) gives every piece the positions of its
//! elements, and the pieces scatter in parallel. A stable counting sort's result does
//! not depend on where the pieces are cut, so the output is the same for any thread
//! count. The scatter writes to disjoint positions of a shared array; they are relaxed
//! atomic stores, which compile to plain stores.

use super::project::{Frame, Splats, TILE};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};

/// Pieces for a parallel pass over `n` items: a few per thread, none smaller than
/// `min_piece`, at most `max_pieces`.
fn pieces(n: usize, min_piece: usize, max_pieces: usize) -> usize {
    (4 * rayon::current_num_threads())
        .min(n.div_ceil(min_piece))
        .min(max_pieces)
        .max(1)
}

const DIGIT: u32 = 11;
const BUCKETS: usize = 1 << DIGIT;

/// Keys `(depth bits) << 32 | index` of all splats, sorted.
pub(crate) fn depth_order(depth: &[f32]) -> Vec<u64> {
    let n = depth.len();
    let key = |i: usize| ((depth[i].to_bits() as u64) << 32) | i as u64;
    let p = pieces(n, 16_384, 256);
    let piece = n.div_ceil(p).max(1);
    let mut src: Vec<AtomicU64> = (0..n)
        .into_par_iter()
        .map(|i| AtomicU64::new(key(i)))
        .collect();
    let mut dst: Vec<AtomicU64> = (0..n).into_par_iter().map(|_| AtomicU64::new(0)).collect();
    for pass in 0..3 {
        let shift = 32 + DIGIT * pass;
        let digit = |k: u64| ((k >> shift) as usize) & (BUCKETS - 1);
        let hists: Vec<Vec<u32>> = src
            .par_chunks(piece)
            .map(|c| {
                let mut h = vec![0u32; BUCKETS];
                for k in c {
                    h[digit(k.load(Relaxed))] += 1;
                }
                h
            })
            .collect();
        let mut total = vec![0usize; BUCKETS];
        for h in &hists {
            for (t, &v) in total.iter_mut().zip(h) {
                *t += v as usize;
            }
        }
        // A pass where every key has the same digit changes nothing.
        if total.contains(&n) {
            continue;
        }
        let mut start = vec![0usize; BUCKETS];
        let mut acc = 0;
        for (s, &t) in start.iter_mut().zip(&total) {
            *s = acc;
            acc += t;
        }
        let offsets: Vec<Vec<usize>> = hists
            .iter()
            .map(|h| {
                let cur = start.clone();
                for (s, &v) in start.iter_mut().zip(h) {
                    *s += v as usize;
                }
                cur
            })
            .collect();
        src.par_chunks(piece).zip(offsets).for_each(|(c, mut o)| {
            for k in c {
                let k = k.load(Relaxed);
                let b = digit(k);
                dst[o[b]].store(k, Relaxed);
                o[b] += 1;
            }
        });
        std::mem::swap(&mut src, &mut dst);
    }
    src.into_iter().map(AtomicU64::into_inner).collect()
}

/// Counting sort of (tile, splat) pairs by tile, visiting splats front to back.
pub(crate) fn bin(splats: Splats, width: usize, height: usize) -> Frame {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let nt = tiles_x * tiles_y;
    let order = depth_order(&splats.depth);
    let rects = &splats.tiles;
    // Per-piece tile counts cost nt words each: keep them under ~16 MB in all.
    let p = pieces(order.len(), 8192, (1 << 22) / nt.max(1));
    let piece = order.len().div_ceil(p).max(1);
    let counts: Vec<Vec<u32>> = order
        .par_chunks(piece)
        .map(|c| {
            let mut cnt = vec![0u32; nt];
            for &k in c {
                let r = rects[k as u32 as usize];
                for ty in r[1] as usize..r[3] as usize {
                    for tx in r[0] as usize..r[2] as usize {
                        cnt[ty * tiles_x + tx] += 1;
                    }
                }
            }
            cnt
        })
        .collect();
    // tile_start[t] = pairs of the tiles before t; piece c writes tile t's pairs after
    // those of pieces 0..c.
    let mut tile_start = vec![0u32; nt + 1];
    let mut cursors: Vec<Vec<u32>> = vec![Vec::new(); counts.len()];
    for cur in &mut cursors {
        cur.reserve_exact(nt);
    }
    let mut acc = 0u32;
    for t in 0..nt {
        tile_start[t] = acc;
        for (cnt, cur) in counts.iter().zip(&mut cursors) {
            cur.push(acc);
            acc += cnt[t];
        }
    }
    tile_start[nt] = acc;
    let list: Vec<AtomicU32> = (0..acc as usize)
        .into_par_iter()
        .map(|_| AtomicU32::new(0))
        .collect();
    order
        .par_chunks(piece)
        .zip(cursors)
        .for_each(|(c, mut cur)| {
            for &k in c {
                let i = k as u32;
                let r = rects[i as usize];
                for ty in r[1] as usize..r[3] as usize {
                    for tx in r[0] as usize..r[2] as usize {
                        let t = ty * tiles_x + tx;
                        list[cur[t] as usize].store(i, Relaxed);
                        cur[t] += 1;
                    }
                }
            }
        });
    Frame {
        width,
        height,
        tiles_x,
        tiles_y,
        splats,
        tile_start,
        tile_list: list.into_iter().map(AtomicU32::into_inner).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(f)
    }

    #[test]
    fn depth_order_sorts_keys_like_sort_unstable() {
        let mut rng = crate::rng::Rng::new(3);
        for n in [0usize, 1, 8, 1000, 70_000] {
            let mut depth: Vec<f32> = (0..n).map(|_| 0.2 + 20.0 * rng.uniform() as f32).collect();
            // Ties.
            for i in (0..n).step_by(7) {
                depth[i] = 3.0;
            }
            let mut want: Vec<u64> = depth
                .iter()
                .enumerate()
                .map(|(i, z)| ((z.to_bits() as u64) << 32) | i as u64)
                .collect();
            want.sort_unstable();
            for threads in [1, 3] {
                assert_eq!(with_threads(threads, || depth_order(&depth)), want, "{n}");
            }
        }
    }

    #[test]
    fn tile_lists_are_front_to_back_and_complete() {
        let mut rng = crate::rng::Rng::new(4);
        let n = 30_000;
        let (w, h) = (200usize, 130usize);
        let (tx, ty) = (w.div_ceil(TILE) as u16, h.div_ceil(TILE) as u16);
        let mut s = Splats::default();
        for i in 0..n {
            let x0 = (rng.uniform() * tx as f64) as u16;
            let y0 = (rng.uniform() * ty as f64) as u16;
            let x1 = (x0 + 1 + (rng.uniform() * 3.0) as u16).min(tx);
            let y1 = (y0 + 1 + (rng.uniform() * 3.0) as u16).min(ty);
            s.ids.push(i as u32);
            s.recs.push(Default::default());
            s.depth.push(if i % 5 == 0 {
                1.0
            } else {
                rng.uniform() as f32 + 0.2
            });
            s.tiles.push([x0, y0, x1, y1]);
        }
        let a = with_threads(1, || bin(s.clone(), w, h));
        let b = with_threads(4, || bin(s.clone(), w, h));
        assert_eq!(a.tile_start, b.tile_start);
        assert_eq!(a.tile_list, b.tile_list);
        let nt = a.tiles_x * a.tiles_y;
        for t in 0..nt {
            let (x, y) = ((t % a.tiles_x) as u16, (t / a.tiles_x) as u16);
            let want: Vec<u32> = {
                let mut v: Vec<u32> = (0..n as u32)
                    .filter(|&i| {
                        let r = s.tiles[i as usize];
                        r[0] <= x && x < r[2] && r[1] <= y && y < r[3]
                    })
                    .collect();
                v.sort_by_key(|&i| (s.depth[i as usize].to_bits(), i));
                v
            };
            assert_eq!(a.tile(t), &want[..], "tile {t}");
        }
    }
}

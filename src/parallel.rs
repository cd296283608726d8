//! Ordered parallel pipelines: items are produced on all cores, a window at a time, and
//! consumed one by one in index order while the next window is produced.
//!
//! Stages that walk views use this to keep a few views in memory instead of all of
//! them (render-views writes each view into its artifact as soon as it is rendered)
//! while every core stays busy. The consumer sees items in index order whatever the
//! thread count, so what it writes is the same for any number of threads.

use crate::Result;
use rayon::prelude::*;

/// Views (or other items) produced at once for `threads` workers: enough to keep them
/// busy when one item does not parallelise perfectly, few enough to bound memory (the
/// pipeline holds at most two windows).
pub fn window_for(threads: usize) -> usize {
    threads.clamp(2, 8)
}

/// Produce items `0..n` with `produce` (in parallel, `window` at a time) and hand each to
/// `consume` in index order. While one window is consumed the next is produced, so at
/// most `2 * window` items exist at once. The first error (of either side, in order)
/// stops the pipeline and is returned.
pub fn ordered<R, P, C>(n: usize, window: usize, produce: P, mut consume: C) -> Result<()>
where
    R: Send,
    P: Fn(usize) -> Result<R> + Sync,
    C: FnMut(usize, R) -> Result<()> + Send,
{
    let window = window.max(1);
    let mut ready: Vec<R> = Vec::new();
    let mut ready_at = 0;
    let mut next = 0;
    while next < n || !ready.is_empty() {
        let (lo, hi) = (next, (next + window).min(n));
        let batch = std::mem::take(&mut ready);
        let (consumed, produced) = rayon::join(
            || -> Result<()> {
                for (k, r) in batch.into_iter().enumerate() {
                    consume(ready_at + k, r)?;
                }
                Ok(())
            },
            || {
                (lo..hi)
                    .into_par_iter()
                    .map(&produce)
                    .collect::<Result<Vec<R>>>()
            },
        );
        consumed?;
        ready = produced?;
        ready_at = lo;
        next = hi;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Error;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn consumes_in_order_with_bounded_items_in_flight() {
        for (n, window, threads) in [(0, 3, 2), (1, 1, 1), (17, 3, 4), (40, 8, 3)] {
            let live = AtomicUsize::new(0);
            let peak = AtomicUsize::new(0);
            let mut seen = Vec::new();
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    ordered(
                        n,
                        window,
                        |i| {
                            let l = live.fetch_add(1, Ordering::SeqCst) + 1;
                            peak.fetch_max(l, Ordering::SeqCst);
                            Ok(i * 10)
                        },
                        |i, r| {
                            assert_eq!(r, i * 10);
                            live.fetch_sub(1, Ordering::SeqCst);
                            seen.push(i);
                            Ok(())
                        },
                    )
                })
                .unwrap();
            assert_eq!(seen, (0..n).collect::<Vec<_>>());
            assert!(peak.load(Ordering::SeqCst) <= 2 * window);
        }
    }

    #[test]
    fn errors_stop_the_pipeline() {
        let e = ordered(
            10,
            2,
            |i| {
                if i == 5 {
                    Err(Error::param("bad item 5"))
                } else {
                    Ok(i)
                }
            },
            |_, _| Ok(()),
        )
        .unwrap_err();
        assert!(e.to_string().contains("bad item 5"));
        let mut got = Vec::new();
        let e = ordered(10, 2, Ok, |i, _| {
            got.push(i);
            if i == 3 {
                Err(Error::param("cannot write 3"))
            } else {
                Ok(())
            }
        })
        .unwrap_err();
        assert!(e.to_string().contains("cannot write 3"));
        assert_eq!(got, vec![0, 1, 2, 3]);
    }
}

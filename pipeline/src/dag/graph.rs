//! Phase 4 of loading a DAG: the graph. Edges come from validation (stage -> the
//! stages producing its deps); here a cycle is found and named stage by stage, or the
//! stages are put in a topological order (Kahn's, ties broken by file order) with
//! their `upstream` indices renumbered to that order.

use super::expand::Expanded;
use super::{Diag, Stage};

/// The stages in topological order, or the diagnostic naming a cycle.
pub(super) fn order(stages: Vec<Expanded>, upstream: &[Vec<usize>]) -> Result<Vec<Stage>, Diag> {
    if let Some(cycle) = find_cycle(upstream) {
        let names: Vec<&str> = cycle
            .iter()
            .map(|&i| stages[i].stage.name.as_str())
            .collect();
        return Err(Diag {
            line: Some(stages[cycle[0]].stage.line),
            msg: format!("dependency cycle: {}", names.join(" -> ")),
        });
    }
    let order = topo_order(upstream);
    let mut pos = vec![0; stages.len()];
    for (k, &i) in order.iter().enumerate() {
        pos[i] = k;
    }
    let mut slots: Vec<Option<Stage>> = stages.into_iter().map(|e| Some(e.stage)).collect();
    Ok(order
        .iter()
        .map(|&i| {
            let mut s = slots[i].take().expect("each stage is placed once");
            s.upstream = upstream[i].iter().map(|&u| pos[u]).collect();
            s.upstream.sort();
            s
        })
        .collect())
}

/// A cycle in `upstream` (stage -> its producers), as stage indices reading producer
/// first: `a -> b -> ... -> a` where each stage consumes the previous one's output.
fn find_cycle(upstream: &[Vec<usize>]) -> Option<Vec<usize>> {
    // 0 = unvisited, 1 = on stack, 2 = done
    let n = upstream.len();
    let mut state = vec![0u8; n];
    let mut stack: Vec<(usize, usize)> = Vec::new();
    for root in 0..n {
        if state[root] != 0 {
            continue;
        }
        stack.push((root, 0));
        state[root] = 1;
        while let Some(&mut (v, ref mut k)) = stack.last_mut() {
            if *k < upstream[v].len() {
                let u = upstream[v][*k];
                *k += 1;
                match state[u] {
                    0 => {
                        state[u] = 1;
                        stack.push((u, 0));
                    }
                    1 => {
                        let at = stack.iter().position(|&(x, _)| x == u).unwrap_or(0);
                        // stack[at..] goes consumer -> producer; print producer -> consumer.
                        let mut c: Vec<usize> = stack[at..].iter().map(|&(x, _)| x).collect();
                        c.reverse();
                        c.push(c[0]);
                        return Some(c);
                    }
                    _ => {}
                }
            } else {
                state[v] = 2;
                stack.pop();
            }
        }
    }
    None
}

fn topo_order(upstream: &[Vec<usize>]) -> Vec<usize> {
    let n = upstream.len();
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    while order.len() < n {
        let next = (0..n)
            .find(|&i| !done[i] && upstream[i].iter().all(|&u| done[u]))
            .expect("acyclic graph always has a ready stage");
        done[next] = true;
        order.push(next);
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cycle_reads_producer_first_and_order_is_stable() {
        // 0 <- 1 <- 2 <- 0
        let c = find_cycle(&[vec![2], vec![0], vec![1]]).unwrap();
        assert_eq!(c.len(), 4);
        assert_eq!(c[0], c[3]);
        assert!(find_cycle(&[vec![], vec![0], vec![0, 1]]).is_none());
        assert_eq!(topo_order(&[vec![1], vec![], vec![]]), [1, 0, 2]);
    }
}

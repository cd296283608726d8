//! The negative branch of CSD at t -> 0 (`synthesis.negative`; FantasyStyle Sec. 4.2,
//! eq. 8: Phi_tgt = beta (eps(z, [P, style]) - eps(z, content))).
//!
//! The content conditioning's prediction is the style image's own layout: what the style
//! image shows at that place, large coherent pieces of it. At t -> 0 the style branch is
//! each object patch's nearest style patch; a prediction *coherent* with the neighbours'
//! (the style patch that continues the piece a neighbour copied: the neighbour's source
//! position shifted by the offset between the two object patches) is what the content
//! branch would give, and negative guidance moves away from it. Here that is a cost:
//! every candidate coherent with a neighbour's first-pass match pays
//! `negative x` the mean nearest distance, in the match and in the coupling, so the
//! object's patches stop copying whole pieces of a photograph (a helmet, a cup) and
//! take the style's patches one by one. 0 is no negative guidance (the default).
//!
//! [`coherence`] measures what it acts on: the share of neighbouring object patches
//! whose style patches are neighbours too, by the same offset (within a pixel); the end
//! reports it per level.

/// A neighbour of an object patch: its index among the queries and its offset (dy, dx)
/// in synthesis pixels.
pub type Neighbour = (usize, [i32; 2]);

/// Each query's neighbours on its view's grid of step `stride`: the queries at
/// (y +- stride, x) and (y, x +- stride) of the same view. `views` holds each view's
/// query pixels `[_, y, x]` in order; queries are numbered across views in that order.
pub fn neighbours(views: &[&[[usize; 3]]], stride: usize) -> Vec<Vec<Neighbour>> {
    let mut out = Vec::new();
    let mut offset = 0;
    let st = stride as i64;
    for pixels in views {
        let index: std::collections::HashMap<(usize, usize), usize> = pixels
            .iter()
            .enumerate()
            .map(|(i, &[_, y, x])| ((y, x), offset + i))
            .collect();
        for &[_, y, x] in pixels.iter() {
            let mut n = Vec::with_capacity(4);
            for (dy, dx) in [(0, st), (st, 0), (0, -st), (-st, 0)] {
                let (yy, xx) = (y as i64 + dy, x as i64 + dx);
                if yy < 0 || xx < 0 {
                    continue;
                }
                if let Some(&j) = index.get(&(yy as usize, xx as usize)) {
                    n.push((j, [dy as i32, dx as i32]));
                }
            }
            out.push(n);
        }
        offset += pixels.len();
    }
    out
}

/// Whether style patch `b` (at `pos[b]`) continues the piece that style patch `a`
/// starts, for object patches `offset` apart: `pos[b] - pos[a]` is `offset` within a
/// pixel.
fn coherent(pos: &[[i32; 2]], a: u32, b: u32, offset: [i32; 2]) -> bool {
    let (pa, pb) = (pos[a as usize], pos[b as usize]);
    (pb[0] - pa[0] - offset[0]).abs() <= 1 && (pb[1] - pa[1] - offset[1]).abs() <= 1
}

/// The share of neighbouring query pairs whose `matches` are coherent (module docs).
pub fn coherence(matches: &[u32], nbrs: &[Vec<Neighbour>], pos: &[[i32; 2]]) -> f32 {
    let (mut pairs, mut same) = (0usize, 0usize);
    for (i, n) in nbrs.iter().enumerate() {
        for &(j, off) in n {
            pairs += 1;
            same += usize::from(coherent(pos, matches[i], matches[j], off));
        }
    }
    same as f32 / pairs.max(1) as f32
}

/// Adds `cost` to every entry of `dist` (`[P x cells]`, each cell's nearest patch
/// `arg`) whose patch is coherent with a neighbour's `first` match.
pub fn penalise(
    dist: &mut [f32],
    arg: &[u32],
    first: &[u32],
    nbrs: &[Vec<Neighbour>],
    pos: &[[i32; 2]],
    cost: f32,
) {
    let cells = dist.len() / first.len().max(1);
    for (i, n) in nbrs.iter().enumerate() {
        for c in 0..cells {
            let k = i * cells + c;
            if !dist[k].is_finite() {
                continue;
            }
            // The neighbour j at offset o matched first[j]; the patch continuing its
            // piece at i sits at pos[first[j]] - o: coherent(pos, arg, first[j], o).
            if n.iter().any(|&(j, o)| coherent(pos, arg[k], first[j], o)) {
                dist[k] += cost;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_piece_copied_whole_is_coherent_and_a_shuffle_is_not() {
        // Four queries on a 2 x 2 grid of step 2.
        let pixels = [[0, 0, 0], [0, 0, 2], [0, 2, 0], [0, 2, 2]];
        let nbrs = neighbours(&[&pixels], 2);
        assert_eq!(nbrs[0].len(), 2);
        // Style patches on a 4 x 4 grid, and a 17th far from all of them.
        let mut pos: Vec<[i32; 2]> = (0..16).map(|i| [i / 4, i % 4]).collect();
        pos.push([40, 40]);
        // Copied whole: query (y, x) takes the style patch at (y, x).
        let whole = [0u32, 2, 8, 10];
        assert_eq!(coherence(&whole, &nbrs, &pos), 1.0);
        // Every query the same patch: nothing continues a piece.
        assert_eq!(coherence(&[5, 5, 5, 5], &nbrs, &pos), 0.0);
        // The penalty lands on the coherent candidates only.
        let mut dist = vec![1.0f32; 4 * 2];
        let arg = [0u32, 16, 2, 16, 8, 16, 10, 16];
        penalise(&mut dist, &arg, &whole, &nbrs, &pos, 0.5);
        assert_eq!(dist, [1.5, 1.0, 1.5, 1.0, 1.5, 1.0, 1.5, 1.0]);
    }
}

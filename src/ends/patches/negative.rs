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
//! [`super::coherence`] measures what it acts on. It is a part of the synthesis of the
//! [`Rematch`] kind ([`super::PARTS`]' `negative`, on when `synthesis.negative`
//! > 0).

use super::SynthesisParams;
use super::coherence::{Neighbour, coherent};
use super::parts::Rematch;

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

/// The negative branch as a part of the synthesis ([`super::PARTS`]).
#[derive(Debug, Clone, Copy)]
pub struct Negative;

impl Rematch for Negative {
    fn penalise(
        &self,
        dist: &mut [f32],
        arg: &[u32],
        first: &[u32],
        nbrs: &[Vec<Neighbour>],
        pos: &[[i32; 2]],
        mean_min: f64,
        p: &SynthesisParams,
    ) {
        let cost = (p.negative as f64 * mean_min) as f32;
        penalise(dist, arg, first, nbrs, pos, cost);
    }
}

#[cfg(test)]
mod tests {
    use super::super::coherence::neighbours;
    use super::*;

    #[test]
    fn the_penalty_lands_on_the_coherent_candidates_only() {
        let pixels = [[0, 0, 0], [0, 0, 2], [0, 2, 0], [0, 2, 2]];
        let nbrs = neighbours(&[&pixels], 2);
        // Style patches on a 4 x 4 grid, and a 17th far from all of them.
        let mut pos: Vec<[i32; 2]> = (0..16).map(|i| [i / 4, i % 4]).collect();
        pos.push([40, 40]);
        let whole = [0u32, 2, 8, 10];
        let mut dist = vec![1.0f32; 4 * 2];
        let arg = [0u32, 16, 2, 16, 8, 16, 10, 16];
        penalise(&mut dist, &arg, &whole, &nbrs, &pos, 0.5);
        assert_eq!(dist, [1.5, 1.0, 1.5, 1.0, 1.5, 1.0, 1.5, 1.0]);
    }
}

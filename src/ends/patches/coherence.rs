//! How much of the style's layout the object copies whole: two neighbouring object
//! patches are *coherent* when their style patches are neighbours too, by the same
//! offset (within a pixel). [`coherence`] is the share of such pairs, which the end
//! reports per level; the negative part ([`super::negative`]) acts on it.

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
pub(super) fn coherent(pos: &[[i32; 2]], a: u32, b: u32, offset: [i32; 2]) -> bool {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_piece_copied_whole_is_coherent_and_a_shuffle_is_not() {
        // Four queries on a 2 x 2 grid of step 2.
        let pixels = [[0, 0, 0], [0, 0, 2], [0, 2, 0], [0, 2, 2]];
        let nbrs = neighbours(&[&pixels], 2);
        assert_eq!(nbrs[0].len(), 2);
        let pos: Vec<[i32; 2]> = (0..16).map(|i| [i / 4, i % 4]).collect();
        // Copied whole: query (y, x) takes the style patch at (y, x).
        assert_eq!(coherence(&[0, 2, 8, 10], &nbrs, &pos), 1.0);
        // Every query the same patch: nothing continues a piece.
        assert_eq!(coherence(&[5, 5, 5, 5], &nbrs, &pos), 0.0);
    }
}

//! The squares of the KID over the object's surface: [`PATCH_SIDE`]-pixel squares from
//! inside the object of each view, and [`STYLE_PATCHES`] squares of the style image at
//! the scale the texture term and the VGG baselines draw it.

use crate::imageio::Image;
use crate::metrics::views::ViewSet;

/// Side of the object KID's squares, pixels: fixed in pixels, since the methods draw the
/// style at a fixed pixel scale; 32 is what fits inside the benchmark's objects (7-9% of
/// a 256 px view: the plant's pot, the fish's body; no 48 px square fits the plant).
pub const PATCH_SIDE: usize = 32;
/// Least mean alpha of an object square.
pub const PATCH_COVERAGE: f64 = 0.95;
/// Object squares per view, at most (`evaluate --object-squares`'s default).
pub const PATCHES_PER_VIEW: usize = 4;
/// Squares of the style image.
pub const STYLE_PATCHES: usize = 64;
/// The style's shorter side for its squares (the texture term's and the VGG baselines'
/// default `--style-size`).
pub const PATCH_STYLE_SIDE: usize = 256;
const _: () = assert!(
    PATCH_STYLE_SIDE >= PATCH_SIDE,
    "a style square must fit the style"
);

/// Where the object squares lie: `(view, x0, y0)` of [`PATCH_SIDE`]-pixel squares whose
/// mean alpha is at least [`PATCH_COVERAGE`], on a grid of stride `PATCH_SIDE / 4`, drawn
/// in a seeded order, each kept only if it is at least half a side away (in x or in y)
/// from the ones kept before it, up to `per_view` per view. `alpha` holds the
/// `w x h` alpha of each view, one after the other (a [`ViewSet`]'s `alpha`).
pub fn object_patch_positions(
    alpha: &[f32],
    w: usize,
    h: usize,
    per_view: usize,
    seed: u64,
) -> Vec<(usize, usize, usize)> {
    let p = PATCH_SIDE;
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-object-patches");
    let mut out = Vec::new();
    if w < p || h < p {
        return out;
    }
    let stride = p / 4;
    for (i, alpha) in alpha.chunks_exact(w * h).enumerate() {
        // Summed-area table, (h + 1) x (w + 1).
        let mut sat = vec![0.0f64; (h + 1) * (w + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += alpha[y * w + x] as f64;
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
            }
        }
        let sum = |x: usize, y: usize| {
            sat[(y + p) * (w + 1) + x + p] - sat[y * (w + 1) + x + p] - sat[(y + p) * (w + 1) + x]
                + sat[y * (w + 1) + x]
        };
        let mut cand: Vec<(usize, usize)> = (0..=(h - p) / stride)
            .flat_map(|gy| (0..=(w - p) / stride).map(move |gx| (gx * stride, gy * stride)))
            .filter(|&(x, y)| sum(x, y) >= PATCH_COVERAGE * (p * p) as f64)
            .collect();
        let mut kept: Vec<(usize, usize)> = Vec::new();
        while kept.len() < per_view && !cand.is_empty() {
            let k = ((rng.uniform() * cand.len() as f64) as usize).min(cand.len() - 1);
            let (x, y) = cand.swap_remove(k);
            if kept
                .iter()
                .all(|&(a, b)| x.abs_diff(a) >= p / 2 || y.abs_diff(b) >= p / 2)
            {
                kept.push((x, y));
            }
        }
        out.extend(kept.into_iter().map(|(x, y)| (i, x, y)));
    }
    out
}

/// The squares of `views` at `positions` (from [`object_patch_positions`]).
pub fn object_patches(views: &ViewSet, positions: &[(usize, usize, usize)]) -> Vec<Image> {
    positions
        .iter()
        .map(|&(i, x, y)| views.images[i].crop(x, y, PATCH_SIDE, PATCH_SIDE))
        .collect()
}

/// [`STYLE_PATCHES`] seeded squares of the style at shorter side [`PATCH_STYLE_SIDE`].
pub fn style_patches(style: &Image, seed: u64) -> Vec<Image> {
    // Shorter side PATCH_STYLE_SIDE >= PATCH_SIDE: every square fits.
    let (s, p) = (style.with_shorter_side(PATCH_STYLE_SIDE), PATCH_SIDE);
    let mut rng = crate::rng::Rng::derive(seed, "evaluate-style-patches");
    (0..STYLE_PATCHES)
        .map(|_| {
            let x = ((rng.uniform() * (s.width - p + 1) as f64) as usize).min(s.width - p);
            let y = ((rng.uniform() * (s.height - p + 1) as f64) as usize).min(s.height - p);
            s.crop(x, y, p, p)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::texture::NOTES;

    /// The object squares lie inside the object (by their mean alpha, recomputed here
    /// pixel by pixel), inside the view, at most four per view, half a side apart; none in
    /// an empty view or on a thin ring; the same seed gives the same squares.
    #[test]
    fn object_squares_lie_inside_the_object() {
        let (w, h) = (200, 160);
        // View 0: a disk of radius 70 (alpha 1 inside); view 1: empty; view 2: a ring
        // 20 px wide (no 32 px square fits); view 3: the disk again.
        let disk = |x: usize, y: usize, r0: f64, r1: f64| {
            let r = ((x as f64 - 100.0).powi(2) + (y as f64 - 80.0).powi(2)).sqrt();
            if r >= r0 && r < r1 { 1.0f32 } else { 0.0 }
        };
        let mut alpha = Vec::new();
        for v in 0..4 {
            for y in 0..h {
                for x in 0..w {
                    alpha.push(match v {
                        0 | 3 => disk(x, y, 0.0, 70.0),
                        1 => 0.0,
                        _ => disk(x, y, 50.0, 70.0),
                    });
                }
            }
        }
        let at = object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 7);
        let p = PATCH_SIDE;
        for v in 0..4 {
            let here: Vec<_> = at.iter().filter(|q| q.0 == v).collect();
            match v {
                0 | 3 => assert_eq!(here.len(), PATCHES_PER_VIEW, "view {v}: {here:?}"),
                _ => assert!(here.is_empty(), "view {v}: {here:?}"),
            }
            for (k, &&(_, x, y)) in here.iter().enumerate() {
                assert!(x + p <= w && y + p <= h);
                let mean: f64 = (y..y + p)
                    .flat_map(|yy| (x..x + p).map(move |xx| (xx, yy)))
                    .map(|(xx, yy)| alpha[(v * h + yy) * w + xx] as f64)
                    .sum::<f64>()
                    / (p * p) as f64;
                assert!(
                    mean >= PATCH_COVERAGE,
                    "view {v} square {k} at ({x}, {y}): mean alpha {mean}"
                );
                for &&(_, a, b) in &here[..k] {
                    assert!(x.abs_diff(a) >= p / 2 || y.abs_diff(b) >= p / 2);
                }
            }
        }
        assert_eq!(
            at,
            object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 7)
        );
        assert_ne!(
            at,
            object_patch_positions(&alpha, w, h, PATCHES_PER_VIEW, 8)
        );
        // Views smaller than a square give none.
        let n = PATCH_SIDE - 1;
        assert!(object_patch_positions(&vec![1.0; n * n], n, n, 4, 7).is_empty());
        // A view exactly one square in size, fully covered, gives that one square.
        let n = PATCH_SIDE;
        assert_eq!(
            object_patch_positions(&vec![1.0; n * n], n, n, 4, 7),
            vec![(0, 0, 0)]
        );
    }

    /// The note written beside kid_object states the constants the code uses.
    #[test]
    fn object_kid_note_states_the_constants() {
        let note = NOTES.iter().find(|n| n.starts_with("kid_object")).unwrap();
        for want in [
            format!("{PATCH_SIDE} px squares"),
            format!("mean alpha >= {PATCH_COVERAGE}"),
            format!("up to {PATCHES_PER_VIEW} per view"),
            format!("vs {STYLE_PATCHES} squares"),
            format!("shorter side {PATCH_STYLE_SIDE}"),
        ] {
            assert!(note.contains(&want), "the note lacks `{want}`: {note}");
        }
    }

    /// The style squares: the right count and side, crops of the style at shorter side
    /// 256 (a style already that size is cropped as it is; a twice larger one is halved
    /// first, which a square's span of a linear ramp shows).
    #[test]
    fn style_squares_come_from_the_style_at_the_drawing_scale() {
        let ramp = |w: usize, h: usize| {
            Image::from_fn(w, h, |x, y| {
                [x as f32 / (w - 1) as f32, y as f32 / (h - 1) as f32, 0.5]
            })
        };
        let style = ramp(256, 512);
        let sq = style_patches(&style, 3);
        assert_eq!(sq.len(), STYLE_PATCHES);
        for q in &sq {
            assert_eq!((q.width, q.height), (PATCH_SIDE, PATCH_SIDE));
            let [r, g, _] = q.px(0, 0);
            let (x0, y0) = ((r * 255.0).round() as usize, (g * 511.0).round() as usize);
            assert_eq!(q.data, style.crop(x0, y0, PATCH_SIDE, PATCH_SIDE).data);
        }
        // Twice the size: a square spans its side at the 256 px scale, not at 512 px.
        for q in style_patches(&ramp(512, 1024), 3) {
            let span = q.px(PATCH_SIDE - 1, 0)[0] - q.px(0, 0)[0];
            let want = (PATCH_SIDE - 1) as f32 / 255.0;
            assert!((span - want).abs() < 0.01, "span {span}, want {want}");
        }
    }
}

//! `layout`, a start for the patch end: the object cut into 3D cells at the motif scale
//! (a Voronoi diagram of jittered grid points, `synthesis.motifs_across` cells across the
//! object's largest extent), every Gaussian of a cell given one colour of the style's
//! motifs drawn at random.
//!
//! Why: from the object's own smooth colours the patch end's balance settles into a few
//! large regions of one cell colour each, whatever the style's scale (docs/structure-guide-history.md
//! "Motifs and the object", the motif-scale table): nothing in a smooth render varies at
//! the motif scale. A diffusion model takes its layout from the noise it starts from;
//! this is that noise for the deterministic end, in 3D so that every view sees the same
//! one (Worley's cellular texture, SIGGRAPH 1996, as the seed; the patch end then draws
//! the style's outlines at the cells' borders). The structure guide at full weight
//! overwrites it (the guide asks for colour by shading), so the start pairs with a weak
//! guide and the shading carried by the detail layer (the `motifs` preset).

use super::{EndInputs, Role};
use crate::ends::patches::SynthesisParams;
use crate::ends::patches::motif::motif_mask;
use crate::{Result, Scene};

/// `scene` with its object cut into cells of the style's colours ([`super::ENDS`]'
/// `layout`).
pub fn run(_: Role, scene: &Scene, inputs: &EndInputs<'_>) -> Result<Scene> {
    let _ph = crate::timing::span("layout");
    let p: SynthesisParams = inputs.section("synthesis")?;
    let seed: u64 = inputs.section("seed")?;
    let palette = motif_colours(inputs.style);
    let extent = object_extent(scene);
    let cell = (extent / p.motifs_across).max(1e-6);
    tracing::info!(
        "layout: cells of {cell:.3e} world units ({} across the object's {extent:.3e}), {} style colours",
        p.motifs_across,
        palette.len()
    );
    let weights = inputs.selection.map(|s| &s.weights[..]);
    Ok(paint(scene, &palette, cell, seed, weights))
}

/// `scene` with each Gaussian's base colour that of its cell (cells of side `cell`,
/// sites from `seed`), one of `palette` drawn by the cell's hash; a Gaussian of selection
/// weight `w` moves that share of the way.
fn paint(
    scene: &Scene,
    palette: &[[f32; 3]],
    cell: f32,
    seed: u64,
    weights: Option<&[f32]>,
) -> Scene {
    let mut out = scene.clone();
    for (i, dc) in out.sh_dc.iter_mut().enumerate() {
        let id = nearest_site(scene.positions[i], cell, seed);
        let c = palette[(mix(id ^ 0x5eed) % palette.len() as u64) as usize];
        let w = weights.map_or(1.0, |w| w[i]);
        for k in 0..3 {
            let to = (c[k] - 0.5) / crate::scene::SH_C0;
            dc[k] = w * to + (1.0 - w) * dc[k];
        }
    }
    out
}

/// The style's motif pixels' colours (every pixel's when none is found).
fn motif_colours(style: &crate::imageio::Image) -> Vec<[f32; 3]> {
    let px: Vec<[f32; 3]> = style
        .data
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let mask = motif_mask(style);
    let motifs: Vec<[f32; 3]> = px
        .iter()
        .zip(&mask)
        .filter(|(_, m)| **m)
        .map(|(c, _)| *c)
        .collect();
    if motifs.is_empty() { px } else { motifs }
}

/// The largest side of the box holding the 2nd to 98th percentile of the opaque
/// (opacity > 0.5) Gaussians' positions on each axis (all of them when none is opaque).
fn object_extent(scene: &Scene) -> f32 {
    let opaque: Vec<[f32; 3]> = (0..scene.len())
        .filter(|&i| scene.opacity(i) > 0.5)
        .map(|i| scene.positions[i])
        .collect();
    let pts = if opaque.is_empty() {
        &scene.positions
    } else {
        &opaque
    };
    if pts.is_empty() {
        return 1.0;
    }
    (0..3)
        .map(|k| {
            let mut v: Vec<f32> = pts.iter().map(|p| p[k]).collect();
            v.sort_by(f32::total_cmp);
            let at = |q: f32| v[((v.len() - 1) as f32 * q).round() as usize];
            at(0.98) - at(0.02)
        })
        .fold(0.0f32, f32::max)
}

/// The id of the site nearest `p`: one site per grid cell of side `cell`, jittered inside
/// it by a hash of the cell and `seed`.
fn nearest_site(p: [f32; 3], cell: f32, seed: u64) -> u64 {
    let c = p.map(|v| (v / cell).floor() as i64);
    let mut best = (f32::INFINITY, 0u64);
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let g = [c[0] + dx, c[1] + dy, c[2] + dz];
                let id = mix(seed ^ mix(g[0] as u64 ^ mix(g[1] as u64 ^ mix(g[2] as u64))));
                let j = [mix(id ^ 1), mix(id ^ 2), mix(id ^ 3)];
                let d2: f32 = (0..3)
                    .map(|k| {
                        let site = (g[k] as f32 + (j[k] >> 40) as f32 / (1u64 << 24) as f32) * cell;
                        (p[k] - site).powi(2)
                    })
                    .sum();
                if d2 < best.0 {
                    best = (d2, id);
                }
            }
        }
    }
    best.1
}

/// SplitMix64's finaliser: a well-mixed 64-bit hash of `x`.
fn mix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sites_cut_space_into_cells_of_about_the_asked_size() {
        // Along a line through 20 cells the site changes about 20 times (a Voronoi
        // diagram of one site per cell), and the same point gets the same site.
        let cell = 0.1;
        let ids: Vec<u64> = (0..2000)
            .map(|i| nearest_site([i as f32 * 1e-3, 0.05, 0.05], cell, 7))
            .collect();
        let changes = ids.windows(2).filter(|w| w[0] != w[1]).count();
        assert!((8..=40).contains(&changes), "{changes}");
        assert_eq!(nearest_site([0.3, 0.05, 0.05], cell, 7), ids[300]);
        assert_ne!(nearest_site([0.3, 0.05, 0.05], cell, 8), ids[300]);
    }

    #[test]
    fn every_gaussian_takes_a_palette_colour_and_a_cell_is_one_colour() {
        use crate::scene::SH_C0;
        let mut scene = crate::sample::sample_scene(0);
        let palette = [
            [0.9, 0.1, 0.1],
            [0.1, 0.8, 0.2],
            [0.1, 0.2, 0.9],
            [0.95, 0.9, 0.2],
        ];
        let extent = object_extent(&scene);
        assert!(extent > 0.0 && extent.is_finite());
        let base = |s: &Scene, i: usize| s.sh_dc[i].map(|d| 0.5 + SH_C0 * d);
        let out = paint(&scene, &palette, extent / 6.0, 0, None);
        let mut used = std::collections::HashSet::new();
        for i in 0..out.len() {
            let c = base(&out, i);
            let k = palette
                .iter()
                .position(|p| (0..3).all(|j| (p[j] - c[j]).abs() < 1e-5));
            used.insert(k.expect("a palette colour"));
            // The same cell, the same colour.
            let j = (i * 7919) % out.len();
            let (a, b) = (scene.positions[i], scene.positions[j]);
            if nearest_site(a, extent / 6.0, 0) == nearest_site(b, extent / 6.0, 0) {
                assert_eq!(out.sh_dc[i], out.sh_dc[j]);
            }
        }
        assert!(used.len() >= 3, "{used:?}");
        // A selection: weight 0 keeps the colour, 1/2 goes half way.
        scene.sh_dc[1] = [0.0; 3];
        let mut w = vec![0.0f32; scene.len()];
        w[1] = 0.5;
        let half = paint(&scene, &palette, extent / 6.0, 0, Some(&w));
        assert_eq!(half.sh_dc[0], scene.sh_dc[0]);
        let full = paint(&scene, &palette, extent / 6.0, 0, None);
        for k in 0..3 {
            assert!((half.sh_dc[1][k] - 0.5 * full.sh_dc[1][k]).abs() < 1e-5);
        }
    }
}

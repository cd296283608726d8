//! The screen-space tail shared by both paths: tiles, rows and columns from the mean,
//! the 2D covariance diagonal, the radius and the opacity level. f32 throughout.

use super::{BoxMargin, One, SplatRec, TILE};

/// Largest f32 below `size` (a positive integer below 2^24): the last coordinate that
/// still belongs to the image.
#[inline(always)]
fn below(size: f32) -> f32 {
    f32::from_bits(size.to_bits() - 1)
}

#[inline(always)]
fn tile_range(lo: f32, hi: f32, size: f32) -> Option<[u16; 2]> {
    let ts = TILE as f32;
    let lo = lo.max(0.0);
    let hi = hi.min(below(size));
    (hi >= lo).then(|| [(lo / ts).floor() as u16, (hi / ts).floor() as u16 + 1])
}

/// Screen-space quantities of a Gaussian that passed the 3D tests.
pub(super) struct Screen {
    pub(super) mean: [f32; 2],
    /// Dilated 2D covariance diagonal `a`, `c`.
    pub(super) cov_a: f32,
    pub(super) cov_c: f32,
    pub(super) radius: f32,
    /// `ln(opacity / ALPHA_MIN)`, >= 0.
    pub(super) level: f32,
    /// `cov_a cov_c / det`, >= 1.
    pub(super) cond: f32,
}

#[inline(always)]
pub(super) fn finish(
    margin: BoxMargin,
    id: u32,
    s: &Screen,
    conic: [f32; 3],
    opacity: f32,
    depth: f32,
    width: usize,
    height: usize,
) -> Option<One> {
    let [mx, my] = s.mean;
    let radius = s.radius;
    let (w, h) = (width as f32, height as f32);
    if mx + radius < 0.0 || my + radius < 0.0 || mx - radius >= w || my - radius >= h {
        return None;
    }
    // Opacity-aware ellipse box: power >= floor = -(level + 1e-3), with the margin.
    let grow = 1.0 + margin.rel * s.cond;
    let reach = 2.0 * (s.level + 1e-3);
    let ex = (reach * s.cov_a).sqrt() * grow + margin.px;
    let ey = (reach * s.cov_c).sqrt() * grow + margin.px;
    // Tiles: those of the radius square that also meet the ellipse box.
    let sq_x = tile_range(mx - radius, mx + radius, w)?;
    let sq_y = tile_range(my - radius, my + radius, h)?;
    let el_x = tile_range(mx - ex, mx + ex, w)?;
    let el_y = tile_range(my - ey, my + ey, h)?;
    let tiles = [
        sq_x[0].max(el_x[0]),
        sq_y[0].max(el_y[0]),
        sq_x[1].min(el_x[1]),
        sq_y[1].min(el_y[1]),
    ];
    if tiles[2] <= tiles[0] || tiles[3] <= tiles[1] {
        return None;
    }
    // Pixel rows whose centre (y + 0.5) lies in the ellipse box.
    let rows = [
        (my - ey - 0.5).ceil().max(0.0) as u16,
        ((my + ey - 0.5).floor() + 1.0).clamp(0.0, h) as u16,
    ];
    let cols = [
        (mx - ex - 0.5).ceil().max(0.0) as u16,
        ((mx + ex - 0.5).floor() + 1.0).clamp(0.0, w) as u16,
    ];
    if rows[1] <= rows[0] || cols[1] <= cols[0] {
        return None;
    }
    Some(One {
        id,
        rec: SplatRec {
            mean: s.mean,
            conic,
            opacity,
            power_floor: -(s.level + 1e-3),
            rows,
            cols,
        },
        depth,
        tiles,
    })
}

//! Projection of 3D Gaussians into screen-space splats.
//!
//! For each Gaussian (Kerbl et al. 2023, Sec. 4; Zwicker et al. 2001, EWA splatting):
//! - mean in camera space `t = W p + w` (W, w: world-to-camera rotation/translation);
//!   culled when `t.z < NEAR` (0.2, as INRIA's `in_frustum`);
//! - 3D covariance `Sigma = R S S^T R^T` from the normalised quaternion and the linear
//!   scales (Kerbl Eq. 6);
//! - 2D covariance `Sigma' = J W Sigma W^T J^T` (Kerbl Eq. 5, Zwicker Eq. 31) with the
//!   affine Jacobian of the perspective map at the mean,
//!   `J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]`, where x/z and y/z are clamped
//!   to the image frustum widened by 30% on each side (the guard band used by INRIA and
//!   gsplat, which keeps J bounded for Gaussians far outside the view), then the
//!   low-pass dilation `Sigma' + 0.3 I` (EWA's screen-space pre-filter);
//! - conic `Sigma'^-1`, radius `ceil(3 sqrt(lambda_max))` with INRIA's
//!   `lambda_max = mid + sqrt(max(0.1, mid^2 - det))`;
//! - the 16x16 tiles of the square `mean ± radius` (pixel centres at `i + 0.5`), cut
//!   down to the tiles that meet the bounding box of the ellipse where
//!   `opacity * exp(-power) >= 1/255`: pixels outside that box can never pass the 1/255
//!   test, so this cut changes no output, it only saves work. The box is widened by a
//!   margin ([`BOX_MARGIN`]) that covers the rounding of the compositor's own `power`
//!   (which grows with the ellipse's condition number); a test checks that a far wider
//!   margin gives the same bits.
//!
//! Arithmetic: f32, eight Gaussians at a time (the lane loops vectorise; `exp` and `ln`
//! are polynomials, [`exp_f32`] and [`ln_f32`]), as the CUDA rasterizers do. With
//! `Sigma' = U U^T + 0.3 I` (`U = J W R S`, 2x3) the determinant is evaluated as
//! `|u0 x u1|^2 + 0.3 (|u0|^2 + |u1|^2) + 0.09` and `mid^2 - det` as
//! `((a - c) / 2)^2 + b^2`: sums of non-negative terms, so thin Gaussians lose no
//! precision to cancellation. A Gaussian whose f32 evaluation overflows or meets a
//! non-finite value (absurd scales or positions) is projected again by the f64 code
//! (`project_one_f64`), which is also the reference the f32 path is tested against.
//!
//! Binning into tiles: [`super::bin`].

use crate::{Camera, Scene};
use rayon::prelude::*;

/// Tile edge in pixels.
pub const TILE: usize = 16;
/// Near-plane distance (camera-space z) below which Gaussians are culled.
pub const NEAR: f64 = 0.2;
/// Low-pass dilation added to the 2D covariance diagonal (pixels^2).
pub const DILATION: f64 = 0.3;
/// Minimum alpha that is composited.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Maximum alpha of one splat.
pub const ALPHA_MAX: f32 = 0.99;
/// Compositing stops for a pixel before a splat would take transmittance below this.
pub const T_MIN: f32 = 1e-4;

/// Margin of the opacity-aware ellipse box: the half-widths `sqrt(2 (L + 1e-3) S_xx)`
/// (`L = ln(opacity / ALPHA_MIN)`, `S` the dilated 2D covariance) are multiplied by
/// `1 + rel * cond` (`cond = S_xx S_yy / det S`, which bounds how much f32 rounding of
/// the conic and of `power` can move the ellipse's edge, relative to its size) and
/// widened by `px` pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxMargin {
    pub rel: f32,
    pub px: f32,
}

/// The margin used: f32 rounding moves the edge by about `1e-7 cond` relative, so this
/// is a hundredfold bound, plus a hundredth of a pixel for the pixel-centre offsets.
pub const BOX_MARGIN: BoxMargin = BoxMargin {
    rel: 1e-5,
    px: 0.01,
};

/// What the compositor reads of one splat, packed so that one splat is one load.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
#[repr(C)]
pub struct SplatRec {
    /// Projected mean, pixels.
    pub mean: [f32; 2],
    /// Conic (inverse 2D covariance) `[[a, b], [b, c]]` as `[a, b, c]`.
    pub conic: [f32; 3],
    pub opacity: f32,
    /// `power` below which `opacity * exp(power) < 1/255` with a margin of 1e-3 (far
    /// above f32 rounding and the compositor's exp error): a pixel below it never blends.
    pub power_floor: f32,
    /// Pixel rows `[y0, y1)` (image coordinates) that can receive alpha >= 1/255.
    pub rows: [u16; 2],
    /// Pixel columns `[x0, x1)` that can receive alpha >= 1/255.
    pub cols: [u16; 2],
}

/// Screen-space splats of the Gaussians that survive culling. Index `i` here is the
/// "local" index; `ids[i]` is the index in the scene.
#[derive(Debug, Default, Clone)]
pub struct Splats {
    pub ids: Vec<u32>,
    pub recs: Vec<SplatRec>,
    /// Camera-space z.
    pub depth: Vec<f32>,
    /// Tile rectangle `[tx0, ty0, tx1, ty1)`.
    pub tiles: Vec<[u16; 4]>,
}

impl Splats {
    /// Number of splats.
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// A projected and binned view: everything the compositing needs.
#[derive(Debug, Default, Clone)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub tiles_x: usize,
    pub tiles_y: usize,
    pub splats: Splats,
    /// `tile_start[t]..tile_start[t+1]` indexes `tile_list` for tile `t` (row-major).
    pub tile_start: Vec<u32>,
    /// Local splat indices per tile, front to back.
    pub tile_list: Vec<u32>,
}

impl Frame {
    /// Local splat indices of tile `t`, front to back.
    #[inline]
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.tile_list[self.tile_start[t] as usize..self.tile_start[t + 1] as usize]
    }
}

/// One projected Gaussian (before it is stored in [`Splats`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct One {
    pub id: u32,
    pub rec: SplatRec,
    pub depth: f32,
    pub tiles: [u16; 4],
}

// ---------------------------------------------------------------------------------------
// Polynomial exp and ln built from plain float operations (so that lane loops vectorise).

/// `exp(x)` for x in [-87, 88] (clamped outside), Cephes-style polynomial, relative
/// error about 2e-7. NaN in gives an unspecified value (callers mask such lanes).
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    exp_poly(x.clamp(-87.0, 88.0))
}

/// The polynomial behind [`exp_f32`] and the rasterizer's `exp_neg`, for `x` in
/// [-87, 88] (the callers clamp to the part of that range they need).
#[inline(always)]
pub(crate) fn exp_poly(x: f32) -> f32 {
    let magic = 12_582_912.0f32;
    let kf = x * std::f32::consts::LOG2_E + magic;
    let k = kf - magic;
    let r = x - k * 0.693_359_4 - k * -2.121_944_4e-4;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_2e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    let bits = ((kf.to_bits() as i32 - magic.to_bits() as i32 + 127) as u32) << 23;
    e * f32::from_bits(bits)
}

/// Natural log for finite normal `x > 0` (Cephes `logf`), relative error about 1e-7.
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    let bits = x.to_bits();
    // x = m 2^e with m in [0.5, 1).
    let e = ((bits >> 23) & 0xff) as i32 - 126;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000);
    let small = m < std::f32::consts::FRAC_1_SQRT_2;
    let e = (e - small as i32) as f32;
    let m = if small { m + m } else { m } - 1.0;
    let z = m * m;
    let mut y = 7.037_683_6e-2f32;
    y = y * m - 1.151_461e-1;
    y = y * m + 1.167_699_9e-1;
    y = y * m - 1.242_014_1e-1;
    y = y * m + 1.424_932_3e-1;
    y = y * m - 1.666_805_8e-1;
    y = y * m + 2.000_071_4e-1;
    y = y * m - 2.499_999_4e-1;
    y = y * m + 0.333_333_3;
    y = y * m * z;
    y += -2.121_944_4e-4 * e;
    y += -0.5 * z;
    m + y + 0.693_359_4 * e
}

// ---------------------------------------------------------------------------------------
// Camera constants.

/// Camera in f64 with the guard-band limits precomputed.
struct Cam {
    r: [[f64; 3]; 3],
    t: [f64; 3],
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    width: usize,
    height: usize,
    lim_x_pos: f64,
    lim_x_neg: f64,
    lim_y_pos: f64,
    lim_y_neg: f64,
}

impl Cam {
    fn new(c: &Camera) -> Cam {
        let mut r = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                r[a][b] = c.rotation[a][b] as f64;
            }
        }
        let (fx, fy, cx, cy) = (c.fx as f64, c.fy as f64, c.cx as f64, c.cy as f64);
        let (w, h) = (c.width as f64, c.height as f64);
        let tan_x = 0.5 * w / fx;
        let tan_y = 0.5 * h / fy;
        Cam {
            r,
            t: [
                c.translation[0] as f64,
                c.translation[1] as f64,
                c.translation[2] as f64,
            ],
            fx,
            fy,
            cx,
            cy,
            width: c.width as usize,
            height: c.height as usize,
            lim_x_pos: (w - cx) / fx + 0.3 * tan_x,
            lim_x_neg: cx / fx + 0.3 * tan_x,
            lim_y_pos: (h - cy) / fy + 0.3 * tan_y,
            lim_y_neg: cy / fy + 0.3 * tan_y,
        }
    }
}

/// The same camera in f32 for the lane path.
struct CamF {
    r: [[f32; 3]; 3],
    t: [f32; 3],
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    lim_x_pos: f32,
    lim_x_neg: f32,
    lim_y_pos: f32,
    lim_y_neg: f32,
}

impl CamF {
    fn new(c: &Cam) -> CamF {
        CamF {
            r: c.r.map(|row| row.map(|v| v as f32)),
            t: c.t.map(|v| v as f32),
            fx: c.fx as f32,
            fy: c.fy as f32,
            cx: c.cx as f32,
            cy: c.cy as f32,
            lim_x_pos: c.lim_x_pos as f32,
            lim_x_neg: c.lim_x_neg as f32,
            lim_y_pos: c.lim_y_pos as f32,
            lim_y_neg: c.lim_y_neg as f32,
        }
    }
}

// ---------------------------------------------------------------------------------------
// The screen-space tail shared by both paths: tiles, rows and columns from the mean,
// the 2D covariance diagonal, the radius and the opacity level. f32 throughout.

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
struct Screen {
    mean: [f32; 2],
    /// Dilated 2D covariance diagonal `a`, `c`.
    cov_a: f32,
    cov_c: f32,
    radius: f32,
    /// `ln(opacity / ALPHA_MIN)`, >= 0.
    level: f32,
    /// `cov_a cov_c / det`, >= 1.
    cond: f32,
}

#[inline(always)]
fn finish(
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

// ---------------------------------------------------------------------------------------
// The f64 path (fallback and reference).

/// The screen-space covariance `[a, b, c]` (dilated) of Gaussian `i` at camera-space
/// position `t`, in f64: `J W R S (J W R S)^T`; `None` for a degenerate rotation.
fn cov2d_f64(scene: &Scene, cam: &Cam, i: usize, t: [f64; 3]) -> Option<[f64; 3]> {
    let r = &cam.r;
    let rq = crate::geometry::rows(crate::geometry::quat_to_mat(
        scene.rotations[i].map(f64::from),
    )?);
    let ls = scene.log_scales[i];
    let s = [
        (ls[0] as f64).exp(),
        (ls[1] as f64).exp(),
        (ls[2] as f64).exp(),
    ];
    let mut m = [[0.0f64; 3]; 3];
    for a in 0..3 {
        for b in 0..3 {
            m[a][b] = rq[a][b] * s[b];
        }
    }
    let z = t[2];
    let tx = z * (t[0] / z).clamp(-cam.lim_x_neg, cam.lim_x_pos);
    let ty = z * (t[1] / z).clamp(-cam.lim_y_neg, cam.lim_y_pos);
    let j = [
        [cam.fx / z, 0.0, -cam.fx * tx / (z * z)],
        [0.0, cam.fy / z, -cam.fy * ty / (z * z)],
    ];
    let mut tw = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            tw[a][b] = j[a][0] * r[0][b] + j[a][1] * r[1][b] + j[a][2] * r[2][b];
        }
    }
    let mut u = [[0.0f64; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            u[a][b] = tw[a][0] * m[0][b] + tw[a][1] * m[1][b] + tw[a][2] * m[2][b];
        }
    }
    let ca = u[0][0] * u[0][0] + u[0][1] * u[0][1] + u[0][2] * u[0][2] + DILATION;
    let cb = u[0][0] * u[1][0] + u[0][1] * u[1][1] + u[0][2] * u[1][2];
    let cc = u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2] + DILATION;
    Some([ca, cb, cc])
}

/// Project Gaussian `i` in f64; `None` when culled. The slow path: used where the f32
/// lanes overflow, and as the reference in tests.
fn project_one_f64(scene: &Scene, cam: &Cam, margin: BoxMargin, i: usize) -> Option<One> {
    let p = scene.positions[i];
    let p = [p[0] as f64, p[1] as f64, p[2] as f64];
    let r = &cam.r;
    let t = [
        r[0][0] * p[0] + r[0][1] * p[1] + r[0][2] * p[2] + cam.t[0],
        r[1][0] * p[0] + r[1][1] * p[1] + r[1][2] * p[2] + cam.t[1],
        r[2][0] * p[0] + r[2][1] * p[1] + r[2][2] * p[2] + cam.t[2],
    ];
    // Written so that NaN is rejected too.
    let in_front = t[2] >= NEAR && t.iter().all(|v| v.is_finite());
    if !in_front {
        return None;
    }
    let opacity = 1.0 / (1.0 + (-(scene.opacity_logits[i] as f64)).exp());
    if opacity.is_nan() || opacity < ALPHA_MIN as f64 {
        return None;
    }
    let [ca, cb, cc] = cov2d_f64(scene, cam, i, t)?;
    let z = t[2];
    let det = ca * cc - cb * cb;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let conic = [cc / det, -cb / det, ca / det];
    let mx = cam.fx * t[0] / z + cam.cx;
    let my = cam.fy * t[1] / z + cam.cy;
    if !mx.is_finite() || !my.is_finite() {
        return None;
    }
    let mid = 0.5 * (ca + cc);
    let lambda = mid + (mid * mid - det).max(0.1).sqrt();
    let radius = (3.0 * lambda.sqrt()).ceil();
    let level = (opacity / ALPHA_MIN as f64).ln().max(0.0);
    let screen = Screen {
        mean: [mx as f32, my as f32],
        cov_a: ca as f32,
        cov_c: cc as f32,
        radius: radius as f32,
        level: level as f32,
        cond: (ca * cc / det) as f32,
    };
    // Values beyond f32 (a Gaussian larger than any image by far) are clamped so that
    // the tail still sees a huge, finite splat.
    let big = |v: f32| if v.is_finite() { v } else { f32::MAX };
    let screen = Screen {
        cov_a: big(screen.cov_a),
        cov_c: big(screen.cov_c),
        radius: big(screen.radius),
        cond: big(screen.cond),
        ..screen
    };
    finish(
        margin,
        i as u32,
        &screen,
        conic.map(|v| v as f32),
        opacity as f32,
        z as f32,
        cam.width,
        cam.height,
    )
}

// ---------------------------------------------------------------------------------------
// The f32 lane path.

/// Gaussians per lane block.
const LANES: usize = 8;

/// Per-lane results of the vectorised part.
#[derive(Default)]
struct LaneOut {
    /// 0: culled for good; 1: projected in f32; 2: redo in f64.
    state: [u8; LANES],
    mean: [[f32; LANES]; 2],
    conic: [[f32; LANES]; 3],
    cov: [[f32; LANES]; 2],
    radius: [f32; LANES],
    level: [f32; LANES],
    cond: [f32; LANES],
    opacity: [f32; LANES],
    depth: [f32; LANES],
}

/// The lane inputs of Gaussians `lo..lo + LANES`, one array per component: positions,
/// rotations, log-scales, opacity logits.
#[inline(always)]
#[allow(clippy::type_complexity)]
fn gather_lanes(
    scene: &Scene,
    lo: usize,
) -> (
    [[f32; LANES]; 3],
    [[f32; LANES]; 4],
    [[f32; LANES]; 3],
    [f32; LANES],
) {
    let mut p = [[0.0f32; LANES]; 3];
    let mut q = [[0.0f32; LANES]; 4];
    let mut ls = [[0.0f32; LANES]; 3];
    let mut logit = [0.0f32; LANES];
    for l in 0..LANES {
        let i = lo + l;
        let (pp, qq, ll) = (scene.positions[i], scene.rotations[i], scene.log_scales[i]);
        for k in 0..3 {
            p[k][l] = pp[k];
            ls[k][l] = ll[k];
        }
        for k in 0..4 {
            q[k][l] = qq[k];
        }
        logit[l] = scene.opacity_logits[i];
    }
    (p, q, ls, logit)
}

/// `U = J W R S` (2x3) from the Jacobian's non-zero entries `[j00, j02, j11, j12]`, the
/// camera rotation `r`, the Gaussian's rotation `rq` and scales `s`.
#[inline(always)]
fn jwrs_f32(r: &[[f32; 3]; 3], j: [f32; 4], rq: &[[f32; 3]; 3], s: [f32; 3]) -> [[f32; 3]; 2] {
    let [j00, j02, j11, j12] = j;
    let mut tw = [[0.0f32; 3]; 2];
    for b in 0..3 {
        tw[0][b] = j00 * r[0][b] + j02 * r[2][b];
        tw[1][b] = j11 * r[1][b] + j12 * r[2][b];
    }
    let mut u = [[0.0f32; 3]; 2];
    for a in 0..2 {
        for b in 0..3 {
            u[a][b] = (tw[a][0] * rq[0][b] + tw[a][1] * rq[1][b] + tw[a][2] * rq[2][b]) * s[b];
        }
    }
    u
}

/// The screen-space covariance `[a, b, c]` of `U U^T` dilated by `dil`, and its
/// determinant (Lagrange's identity: the cross product of U's rows, free of the
/// cancellation in `a c - b^2`).
#[inline(always)]
fn cov2d_f32(u: &[[f32; 3]; 2], dil: f32) -> [f32; 4] {
    let n0 = u[0][0] * u[0][0] + u[0][1] * u[0][1] + u[0][2] * u[0][2];
    let n1 = u[1][0] * u[1][0] + u[1][1] * u[1][1] + u[1][2] * u[1][2];
    let cb = u[0][0] * u[1][0] + u[0][1] * u[1][1] + u[0][2] * u[1][2];
    let cross = [
        u[0][1] * u[1][2] - u[0][2] * u[1][1],
        u[0][2] * u[1][0] - u[0][0] * u[1][2],
        u[0][0] * u[1][1] - u[0][1] * u[1][0],
    ];
    let ca = n0 + dil;
    let cc = n1 + dil;
    let det = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2])
        + dil * (n0 + n1)
        + dil * dil;
    [ca, cb, cc, det]
}

/// The f32 arithmetic of `LANES` Gaussians `lo..lo + LANES` (all present). Branch-free
/// per lane so that the loops vectorise.
#[inline(always)]
fn lanes(scene: &Scene, cam: &CamF, lo: usize, out: &mut LaneOut) {
    let (p, q, ls, logit) = gather_lanes(scene, lo);
    let r = &cam.r;
    let near = NEAR as f32;
    let dil = DILATION as f32;
    for l in 0..LANES {
        let (px, py, pz) = (p[0][l], p[1][l], p[2][l]);
        let tx = r[0][0] * px + r[0][1] * py + r[0][2] * pz + cam.t[0];
        let ty = r[1][0] * px + r[1][1] * py + r[1][2] * pz + cam.t[1];
        let tz = r[2][0] * px + r[2][1] * py + r[2][2] * pz + cam.t[2];
        let t_ok = tx.is_finite() & ty.is_finite() & tz.is_finite();
        let front = tz >= near;
        let opacity = 1.0 / (1.0 + exp_f32(-logit[l]));
        let visible = opacity >= ALPHA_MIN;
        // Rotation from the normalised quaternion (w, x, y, z).
        let (qw, qx, qy, qz) = (q[0][l], q[1][l], q[2][l], q[3][l]);
        let qn = (qw * qw + qx * qx + qy * qy + qz * qz).sqrt();
        let q_finite = qn.is_finite();
        let q_ok = qn >= 1e-12;
        let inv = 1.0 / qn;
        let (w, x, y, z) = (qw * inv, qx * inv, qy * inv, qz * inv);
        let rq = crate::geometry::unit_quat_rows(w, x, y, z);
        let s = [exp_f32(ls[0][l]), exp_f32(ls[1][l]), exp_f32(ls[2][l])];
        // The polynomial exp clamps at 88; a larger log-scale is left to the f64 path.
        let s_ok = (ls[0][l] < 88.0) & (ls[1][l] < 88.0) & (ls[2][l] < 88.0);
        // Jacobian with the guard-band clamp; z is at least NEAR where it matters.
        let zc = tz.max(near);
        let txc = zc * (tx / zc).clamp(-cam.lim_x_neg, cam.lim_x_pos);
        let tyc = zc * (ty / zc).clamp(-cam.lim_y_neg, cam.lim_y_pos);
        let j00 = cam.fx / zc;
        let j02 = -cam.fx * txc / (zc * zc);
        let j11 = cam.fy / zc;
        let j12 = -cam.fy * tyc / (zc * zc);
        // T = J W (2x3), then U = T R S (2x3).
        let u = jwrs_f32(r, [j00, j02, j11, j12], &rq, s);
        let [ca, cb, cc, det] = cov2d_f32(&u, dil);
        let conic = [cc / det, -cb / det, ca / det];
        let mx = cam.fx * tx / zc + cam.cx;
        let my = cam.fy * ty / zc + cam.cy;
        let mid = 0.5 * (ca + cc);
        let half_diff = 0.5 * (ca - cc);
        let lambda = mid + (half_diff * half_diff + cb * cb).max(0.1).sqrt();
        let radius = (3.0 * lambda.sqrt()).ceil();
        let level = ln_f32((opacity / ALPHA_MIN).max(1.0)).max(0.0);
        let geo_ok = (det > 0.0)
            & det.is_finite()
            & conic[0].is_finite()
            & conic[1].is_finite()
            & conic[2].is_finite()
            & mx.is_finite()
            & my.is_finite()
            & radius.is_finite()
            & (ca * cc).is_finite()
            & (2.0 * (level + 1e-3) * ca).is_finite()
            & (2.0 * (level + 1e-3) * cc).is_finite();
        // Clean culls first (behind the camera, transparent, zero quaternion); then
        // anything the f32 arithmetic could not represent goes to the f64 path.
        let culled = t_ok & (!front | (front & !visible) | (front & visible & q_finite & !q_ok));
        let projected = t_ok & front & visible & q_finite & q_ok & s_ok & geo_ok;
        out.state[l] = if culled {
            0
        } else if projected {
            1
        } else {
            2
        };
        out.mean[0][l] = mx;
        out.mean[1][l] = my;
        out.conic[0][l] = conic[0];
        out.conic[1][l] = conic[1];
        out.conic[2][l] = conic[2];
        out.cov[0][l] = ca;
        out.cov[1][l] = cc;
        out.radius[l] = radius;
        out.level[l] = level;
        out.cond[l] = ca * cc / det;
        out.opacity[l] = opacity;
        out.depth[l] = tz;
    }
}

/// Project Gaussians `lo..hi`, keeping the survivors in order.
///
/// On x86-64 CPUs with AVX2 and FMA this runs a copy compiled with those features (8
/// lanes per instruction; `floor`/`ceil` become single instructions). Rust never fuses
/// `a * b + c`, so both copies give identical bits.
fn project_range(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function only requires AVX2 and FMA, which the CPU has (checked
        // just above); it is otherwise ordinary safe code.
        #[allow(unsafe_code)]
        return unsafe { project_range_avx2(scene, cam, camf, m, lo, hi) };
    }
    project_range_impl(scene, cam, camf, m, lo, hi)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_range_avx2(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    project_range_impl(scene, cam, camf, m, lo, hi)
}

#[inline(always)]
fn project_range_impl(
    scene: &Scene,
    cam: &Cam,
    camf: &CamF,
    m: BoxMargin,
    lo: usize,
    hi: usize,
) -> Vec<One> {
    let mut out = Vec::with_capacity(hi - lo);
    let mut lane = LaneOut::default();
    let mut i = lo;
    while i + LANES <= hi {
        lanes(scene, camf, i, &mut lane);
        for l in 0..LANES {
            let id = i + l;
            let o = match lane.state[l] {
                0 => None,
                1 => finish(
                    m,
                    id as u32,
                    &Screen {
                        mean: [lane.mean[0][l], lane.mean[1][l]],
                        cov_a: lane.cov[0][l],
                        cov_c: lane.cov[1][l],
                        radius: lane.radius[l],
                        level: lane.level[l],
                        cond: lane.cond[l],
                    },
                    [lane.conic[0][l], lane.conic[1][l], lane.conic[2][l]],
                    lane.opacity[l],
                    lane.depth[l],
                    cam.width,
                    cam.height,
                ),
                _ => project_one_f64(scene, cam, m, id),
            };
            out.extend(o);
        }
        i += LANES;
    }
    // The last few Gaussians of the scene: f64.
    for id in i..hi {
        out.extend(project_one_f64(scene, cam, m, id));
    }
    out
}

/// Split `s` into consecutive pieces of the given lengths (which must sum to its length).
pub(crate) fn split_lengths<T>(
    mut s: &mut [T],
    lens: impl IntoIterator<Item = usize>,
) -> Vec<&mut [T]> {
    let mut out = Vec::new();
    for n in lens {
        let (a, b) = s.split_at_mut(n);
        out.push(a);
        s = b;
    }
    out
}

/// Gaussians per projection task.
const CHUNK: usize = 4096;

/// Project every Gaussian of `scene` for `camera` (validated by the caller), in scene
/// order, without binning.
pub fn project_splats(scene: &Scene, camera: &Camera) -> Splats {
    project_splats_with(scene, camera, BOX_MARGIN)
}

/// [`project_splats`] with another ellipse-box margin (for tests).
pub(crate) fn project_splats_with(scene: &Scene, camera: &Camera, margin: BoxMargin) -> Splats {
    let cam = Cam::new(camera);
    let camf = CamF::new(&cam);
    let n = scene.len();
    // Parallel in fixed-size chunks, concatenated in order: deterministic.
    let chunks: Vec<Vec<One>> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let lo = c * CHUNK;
            project_range(scene, &cam, &camf, margin, lo, (lo + CHUNK).min(n))
        })
        .collect();
    let m: usize = chunks.iter().map(Vec::len).sum();
    let mut s = Splats {
        ids: vec![0; m],
        recs: vec![SplatRec::default(); m],
        depth: vec![0.0; m],
        tiles: vec![[0; 4]; m],
    };
    let lens = || chunks.iter().map(Vec::len);
    split_lengths(&mut s.ids, lens())
        .into_par_iter()
        .zip(split_lengths(&mut s.recs, lens()))
        .zip(split_lengths(&mut s.depth, lens()))
        .zip(split_lengths(&mut s.tiles, lens()))
        .zip(&chunks)
        .for_each(|((((ids, recs), depth), tiles), c)| {
            for (k, o) in c.iter().enumerate() {
                ids[k] = o.id;
                recs[k] = o.rec;
                depth[k] = o.depth;
                tiles[k] = o.tiles;
            }
        });
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::tests::{front_camera, random_scene};

    #[test]
    fn exp_and_ln_are_accurate() {
        let mut worst_exp = 0.0f64;
        for i in -870_000..=880_000 {
            let x = i as f32 * 1e-4;
            let (a, b) = (exp_f32(x) as f64, (x as f64).exp());
            worst_exp = worst_exp.max(((a - b) / b).abs());
        }
        assert!(worst_exp < 5e-7, "exp relative error {worst_exp}");
        let mut worst_ln = 0.0f64;
        let mut x = 1e-30f32;
        while x < 1e30 {
            let (a, b) = (ln_f32(x) as f64, (x as f64).ln());
            worst_ln = worst_ln.max((a - b).abs() / b.abs().max(1.0));
            x *= 1.0007;
        }
        assert!(worst_ln < 3e-7, "ln error {worst_ln}");
        assert_eq!(ln_f32(1.0), 0.0);
    }

    /// The f32 lanes against the f64 path on random scenes and cameras: the same
    /// Gaussians survive (up to threshold cases), means within 1e-4 px, conics and
    /// opacities within 1e-5 relative, identical or neighbouring tiles.
    #[test]
    fn f32_lanes_agree_with_f64() {
        let mut checked = 0;
        for seed in 0..6 {
            let scene = random_scene(4000, 1, 100 + seed);
            let cam_c = front_camera(160, 120, 140.0, 2.0 + seed as f32 * 0.3);
            let cam = Cam::new(&cam_c);
            let camf = CamF::new(&cam);
            let fast = project_range_impl(&scene, &cam, &camf, BOX_MARGIN, 0, scene.len());
            let slow: Vec<One> = (0..scene.len())
                .filter_map(|i| project_one_f64(&scene, &cam, BOX_MARGIN, i))
                .collect();
            let diff = fast.len().abs_diff(slow.len());
            assert!(diff <= 2, "{} vs {} survivors", fast.len(), slow.len());
            let mut j = 0;
            for a in &fast {
                while j < slow.len() && slow[j].id < a.id {
                    j += 1;
                }
                let Some(b) = slow.get(j).filter(|b| b.id == a.id) else {
                    continue;
                };
                for k in 0..2 {
                    assert!((a.rec.mean[k] - b.rec.mean[k]).abs() < 1e-4, "{a:?} {b:?}");
                }
                for k in 0..3 {
                    let tol = 1e-5 * (b.rec.conic[0].abs() + b.rec.conic[2].abs());
                    assert!(
                        (a.rec.conic[k] - b.rec.conic[k]).abs() <= tol,
                        "{a:?} {b:?}"
                    );
                }
                assert!((a.rec.opacity - b.rec.opacity).abs() <= 1e-6);
                assert!((a.rec.power_floor - b.rec.power_floor).abs() <= 1e-5);
                for k in 0..4 {
                    assert!(a.tiles[k].abs_diff(b.tiles[k]) <= 1, "{a:?} {b:?}");
                }
                assert!((a.depth - b.depth).abs() <= 1e-6 * b.depth);
                checked += 1;
            }
        }
        assert!(checked > 10_000, "{checked}");
    }

    /// Lanes that overflow in f32 are projected by the f64 path: a Gaussian of scale
    /// e^40 covers the whole image instead of being culled.
    #[test]
    fn overflowing_lanes_fall_back_to_f64() {
        let mut scene = random_scene(16, 0, 7);
        scene.log_scales[3] = [40.0, 40.0, 40.0];
        scene.opacity_logits[3] = 5.0;
        let c = front_camera(64, 48, 60.0, 3.0);
        let cam = Cam::new(&c);
        let fast = project_range_impl(&scene, &cam, &CamF::new(&cam), BOX_MARGIN, 0, 16);
        let big = fast.iter().find(|o| o.id == 3).expect("huge Gaussian kept");
        assert_eq!(big.tiles, [0, 0, 4, 3]);
        assert_eq!(Some(*big), project_one_f64(&scene, &cam, BOX_MARGIN, 3));
    }
}

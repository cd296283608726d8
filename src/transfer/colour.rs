//! Colour-statistics transfer (issue 21's "colour transfer" baseline): the object's
//! colour mean and covariance moved onto the style image's by the linear Monge-Kantorovich
//! map, written into the Gaussians' SH colours. No texture, no optimisation: seconds.
//!
//! **Statistics.** Source: over every pixel of the source views with alpha above 1e-3,
//! the un-premultiplied colour `c = (rgb - (1 - a) bg) / a`, weighted by `a`
//! (`mu = sum a c / sum a`, `S = sum a (c - mu)(c - mu)^T / sum a`), so the fringe counts
//! as much as it covers. Style: every pixel of the style image, equally weighted.
//!
//! **Map** (Pitié & Kokaram 2007, the linear Monge-Kantorovich solution; Reinhard et al.
//! 2001 is its diagonal special case): `c' = T (c - mu_s) + mu_t` with
//! `T = S_s^-1/2 (S_s^1/2 S_t S_s^1/2)^1/2 S_s^-1/2`, the symmetric map that sends
//! `N(mu_s, S_s)` to `N(mu_t, S_t)` with the least mean squared displacement. `S_s` gets
//! `1e-5 I` added (a standard deviation of 0.003) so a grey or flat object stays
//! invertible.
//!
//! **Into the scene.** A render's un-premultiplied colour is a convex combination of the
//! visible Gaussians' colours (the blending weights over a pixel sum to its alpha), and
//! each Gaussian's colour is `0.5 + C0 f_dc + sum_k Y_k(d) f_rest_k`, affine in the
//! coefficients. So mapping every Gaussian's DC colour `0.5 + C0 f_dc` by the affine map
//! and every higher-order coefficient `f_rest_k` by its linear part `T` maps every
//! rendered colour by exactly the same affine map (up to the renderer's clamp of negative
//! colours to 0): the views' colour statistics become the style's. View-dependent colour
//! is kept, transformed like the rest.
//!
//! **Clamping into the style's extent (the colour start and finish, [`crate::ends`]).** The
//! linear map reproduces the style's mean and covariance, not its shape: along an axis
//! where the style is one-sided (an op-art print's red against its neutrals, with no cyan), the
//! object's colours on the other side of its mean come out in a hue the style lacks (a
//! salmon fish turned partly teal). [`clamp_to_extent`] moves each Gaussian's DC colour
//! back into the style's extent along the style's principal axes (the 0.5th to 99.5th
//! percentile of the style's pixels' coordinates on each axis, [`style_extent`]); a
//! style present on both sides of its mean (a painting's blue and yellow) clamps almost
//! nothing. The colour-transfer baseline stays the pure mean + covariance map.
//!
//! **Before and after distillation** ([`move_palette`]). ARF (Zhang et al., ECCV 2022)
//! transfers the colour statistics onto the style's before its NNFM optimisation and
//! again on the result (its reference code's pre- and post-colour-transfer steps).
//! The colour start is the first (statistics of the source views),
//! the colour finish the second (statistics of the result's own renders from the same
//! cameras, [`crate::render::render_all`]): a map of colours only, so the texture the loop drew keeps
//! its arrangement while its palette drift is taken back to the style's mean and
//! covariance.

use crate::imageio::Image;
use crate::maths::linalg::{matmul, reconstruct, sym_eig};
use crate::render::sh::C0;
use crate::{Error, Result, Scene};

/// Mean and covariance of a colour distribution (row-major 3x3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ColourStats {
    pub mean: [f64; 3],
    pub cov: [f64; 9],
}

/// Regulariser added to the source covariance's diagonal.
pub const COV_EPS: f64 = 1e-5;

/// Alpha-weighted statistics of the object's un-premultiplied colours over `views`
/// (`(rgb [H W 3], alpha [H W])` each), rendered over `background`.
pub fn object_stats(views: &[(&[f32], &[f32])], background: [f32; 3]) -> Result<ColourStats> {
    let (mut sw, mut s1) = (0.0f64, [0.0f64; 3]);
    let un = |rgb: &[f32], p: usize, a: f64| -> [f64; 3] {
        std::array::from_fn(|c| (rgb[p * 3 + c] as f64 - (1.0 - a) * background[c] as f64) / a)
    };
    for (rgb, alpha) in views {
        for (p, &a) in alpha.iter().enumerate() {
            let a = a as f64;
            if a > 1e-3 {
                let c = un(rgb, p, a);
                sw += a;
                (0..3).for_each(|k| s1[k] += a * c[k]);
            }
        }
    }
    if sw < 1.0 {
        return Err(Error::param(
            "colour transfer: the object covers no pixel of the source views",
        ));
    }
    let mean = s1.map(|v| v / sw);
    let mut cov = [0.0f64; 9];
    for (rgb, alpha) in views {
        for (p, &a) in alpha.iter().enumerate() {
            let a = a as f64;
            if a > 1e-3 {
                let c = un(rgb, p, a);
                for i in 0..3 {
                    for j in 0..3 {
                        cov[i * 3 + j] += a * (c[i] - mean[i]) * (c[j] - mean[j]);
                    }
                }
            }
        }
    }
    cov.iter_mut().for_each(|v| *v /= sw);
    Ok(ColourStats { mean, cov })
}

/// Statistics of every pixel of an image.
pub fn image_stats(img: &Image) -> ColourStats {
    let n = (img.width * img.height).max(1) as f64;
    let mut mean = [0.0f64; 3];
    for p in img.data.chunks_exact(3) {
        (0..3).for_each(|c| mean[c] += p[c] as f64 / n);
    }
    let mut cov = [0.0f64; 9];
    for p in img.data.chunks_exact(3) {
        for i in 0..3 {
            for j in 0..3 {
                cov[i * 3 + j] += (p[i] as f64 - mean[i]) * (p[j] as f64 - mean[j]) / n;
            }
        }
    }
    ColourStats { mean, cov }
}

/// The affine map `c -> T c + b` taking `src` to `dst` (see module docs): `(T, b)`.
pub fn monge_kantorovich(src: &ColourStats, dst: &ColourStats) -> ([f64; 9], [f64; 3]) {
    let mut ss = src.cov;
    for i in 0..3 {
        ss[i * 4] += COV_EPS;
    }
    let e = sym_eig(&ss, 3);
    let sh = reconstruct(&e, |x| x.max(0.0).sqrt());
    let sih = reconstruct(&e, |x| 1.0 / x.max(1e-12).sqrt());
    let mid = matmul(&matmul(&sh, &dst.cov, 3, 3, 3), &sh, 3, 3, 3);
    let mid_h = reconstruct(&sym_eig(&mid, 3), |x| x.max(0.0).sqrt());
    let t = matmul(&matmul(&sih, &mid_h, 3, 3, 3), &sih, 3, 3, 3);
    let tv: [f64; 9] = std::array::from_fn(|k| t[k]);
    let b = std::array::from_fn(|i| {
        dst.mean[i] - (0..3).map(|j| tv[i * 3 + j] * src.mean[j]).sum::<f64>()
    });
    (tv, b)
}

/// A computed transfer: the two distributions' statistics and the affine map between
/// them (`c' = t c + b`, row-major `t`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transfer {
    pub source: ColourStats,
    pub style: ColourStats,
    pub t: [f64; 9],
    pub b: [f64; 3],
}

/// The whole transfer: the object's statistics over `views` (`(rgb, alpha)` each,
/// rendered over `background`), the map onto `style`'s, applied to `scene`'s colours.
pub fn transfer_scene(
    scene: &Scene,
    views: &[(&[f32], &[f32])],
    background: [f32; 3],
    style: &Image,
) -> Result<(Scene, Transfer)> {
    let source = object_stats(views, background)?;
    let style = image_stats(style);
    let (t, b) = monge_kantorovich(&source, &style);
    Ok((
        apply_to_scene(scene, &t, &b),
        Transfer {
            source,
            style,
            t,
            b,
        },
    ))
}

/// The scene with every Gaussian's colour mapped by `c -> T c + b` (DC) and every
/// higher-order SH coefficient by `T` (see module docs). Geometry is untouched.
pub fn apply_to_scene(scene: &Scene, t: &[f64; 9], b: &[f64; 3]) -> Scene {
    let mut out = scene.clone();
    let c0 = C0 as f64;
    let lin = |v: [f64; 3]| -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| t[i * 3 + j] * v[j]).sum())
    };
    for dc in out.sh_dc.iter_mut() {
        let c: [f64; 3] = std::array::from_fn(|k| 0.5 + c0 * dc[k] as f64);
        let m = lin(c);
        *dc = std::array::from_fn(|k| ((m[k] + b[k] - 0.5) / c0) as f32);
    }
    for coeff in out.sh_rest.chunks_exact_mut(3) {
        let m = lin([coeff[0] as f64, coeff[1] as f64, coeff[2] as f64]);
        coeff.iter_mut().zip(m).for_each(|(x, v)| *x = v as f32);
    }
    out
}

/// Share of the style's pixels left outside its extent at each end of an axis.
pub const EXTENT_TAIL: f64 = 0.005;

/// The style's colour extent along its principal axes: `axes[k]` the k-th eigenvector of
/// its covariance, `lo[k]..hi[k]` the [`EXTENT_TAIL`] and `1 - EXTENT_TAIL` quantiles of
/// the pixels' coordinates `axes[k] . (p - mean)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StyleExtent {
    pub mean: [f64; 3],
    pub axes: [[f64; 3]; 3],
    pub lo: [f64; 3],
    pub hi: [f64; 3],
}

/// The extent of every pixel of `img` (see [`StyleExtent`]), given its statistics `st`
/// ([`image_stats`]; a [`Transfer`] holds them as `style`).
pub fn style_extent(img: &Image, st: &ColourStats) -> StyleExtent {
    let e = sym_eig(&st.cov, 3);
    let axes: [[f64; 3]; 3] =
        std::array::from_fn(|k| std::array::from_fn(|i| e.vectors[i * 3 + k]));
    let (mut lo, mut hi) = ([0.0; 3], [0.0; 3]);
    for k in 0..3 {
        let mut coord: Vec<f64> = img
            .data
            .chunks_exact(3)
            .map(|p| {
                (0..3)
                    .map(|i| axes[k][i] * (p[i] as f64 - st.mean[i]))
                    .sum()
            })
            .collect();
        if coord.is_empty() {
            continue;
        }
        coord.sort_by(f64::total_cmp);
        let at = |q: f64| coord[((coord.len() - 1) as f64 * q).round() as usize];
        (lo[k], hi[k]) = (at(EXTENT_TAIL), at(1.0 - EXTENT_TAIL));
    }
    StyleExtent {
        mean: st.mean,
        axes,
        lo,
        hi,
    }
}

/// The scene with every Gaussian's DC colour `0.5 + C0 f_dc` clamped into `ext` along
/// the style's axes (coordinates outside `lo..hi` set to the nearer end; higher-order
/// coefficients untouched), and how many Gaussians changed.
pub fn clamp_to_extent(scene: &Scene, ext: &StyleExtent) -> (Scene, usize) {
    let mut out = scene.clone();
    let c0 = C0 as f64;
    let mut changed = 0;
    for dc in out.sh_dc.iter_mut() {
        let c: [f64; 3] = std::array::from_fn(|k| 0.5 + c0 * dc[k] as f64);
        let d: [f64; 3] = std::array::from_fn(|i| c[i] - ext.mean[i]);
        let mut moved = [0.0f64; 3];
        let mut any = false;
        for k in 0..3 {
            let x: f64 = (0..3).map(|i| ext.axes[k][i] * d[i]).sum();
            let y = x.clamp(ext.lo[k], ext.hi[k]);
            if y != x {
                any = true;
                (0..3).for_each(|i| moved[i] += (y - x) * ext.axes[k][i]);
            }
        }
        if any {
            changed += 1;
            *dc = std::array::from_fn(|k| ((c[k] + moved[k] - 0.5) / c0) as f32);
        }
    }
    (out, changed)
}

/// The palette move of the colour start and finish ([`crate::ends`]): [`transfer_scene`]
/// (the object's statistics over `views`, rendered over `background`, onto `style`'s),
/// then [`clamp_to_extent`] into the style's extent. Returns the scene, the transfer and
/// how many Gaussians the clamp moved.
pub fn move_palette(
    scene: &Scene,
    views: &[(&[f32], &[f32])],
    background: [f32; 3],
    style: &Image,
) -> Result<(Scene, Transfer, usize)> {
    let (mapped, tr) = transfer_scene(scene, views, background, style)?;
    let (clamped, n) = clamp_to_extent(&mapped, &style_extent(style, &tr.style));
    Ok((clamped, tr, n))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn apply(t: &[f64; 9], b: &[f64; 3], c: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| (0..3).map(|j| t[i * 3 + j] * c[j]).sum::<f64>() + b[i])
    }

    fn stats_of(v: &[[f64; 3]]) -> ColourStats {
        let n = v.len() as f64;
        let mut mean = [0.0; 3];
        v.iter()
            .for_each(|p| (0..3).for_each(|c| mean[c] += p[c] / n));
        let mut cov = [0.0; 9];
        for p in v {
            for i in 0..3 {
                for j in 0..3 {
                    cov[i * 3 + j] += (p[i] - mean[i]) * (p[j] - mean[j]) / n;
                }
            }
        }
        ColourStats { mean, cov }
    }

    /// The map sends the source's samples to samples with the target's mean and
    /// covariance (up to the regulariser), and T is symmetric positive definite.
    #[test]
    fn map_matches_moments() {
        let mut r = Rng::new(3);
        let src: Vec<[f64; 3]> = (0..4000)
            .map(|_| {
                let (x, y, z) = (r.normal(), r.normal(), r.normal());
                [0.4 + 0.1 * x, 0.3 + 0.05 * x + 0.08 * y, 0.2 + 0.06 * z]
            })
            .collect();
        let dst = ColourStats {
            mean: [0.6, 0.2, 0.5],
            cov: [0.02, 0.005, 0.0, 0.005, 0.01, -0.002, 0.0, -0.002, 0.03],
        };
        let s = stats_of(&src);
        let (t, b) = monge_kantorovich(&s, &dst);
        let mapped: Vec<[f64; 3]> = src.iter().map(|&c| apply(&t, &b, c)).collect();
        let m = stats_of(&mapped);
        for k in 0..3 {
            assert!((m.mean[k] - dst.mean[k]).abs() < 1e-9, "mean {k}");
        }
        for k in 0..9 {
            // S_s + eps I was matched, so S_t is reached up to about eps T^2 (< 1e-4 here).
            assert!(
                (m.cov[k] - dst.cov[k]).abs() < 1e-4,
                "cov {k}: {} vs {}",
                m.cov[k],
                dst.cov[k]
            );
        }
        for i in 0..3 {
            for j in 0..3 {
                assert!((t[i * 3 + j] - t[j * 3 + i]).abs() < 1e-9);
            }
        }
        // Identity when the statistics already agree (up to the regulariser).
        let (t, b) = monge_kantorovich(&s, &s);
        for i in 0..3 {
            assert!((t[i * 4] - 1.0).abs() < 0.1 && b[i].abs() < 0.1);
        }
    }

    /// Mapping the scene's SH coefficients maps each Gaussian's raw colour (any view
    /// direction) by the same affine map.
    #[test]
    fn scene_colours_map_affinely() {
        let mut r = Rng::new(9);
        let n = 5;
        let k = 3; // SH degree 1
        let scene = Scene {
            positions: (0..n).map(|i| [i as f32, 0.0, 1.0]).collect(),
            log_scales: vec![[0.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![0.0; n],
            sh_degree: 1,
            sh_dc: (0..n)
                .map(|_| [r.normal() as f32, r.normal() as f32, r.normal() as f32])
                .collect(),
            sh_rest: (0..n * k * 3).map(|_| 0.3 * r.normal() as f32).collect(),
        };
        let t = [1.2, 0.1, 0.0, 0.1, 0.8, 0.05, 0.0, 0.05, 0.5];
        let b = [0.1, -0.2, 0.3];
        let out = apply_to_scene(&scene, &t, &b);
        let ids: Vec<u32> = (0..n as u32).collect();
        for centre in [[0.0, 0.0, -3.0], [2.0, 5.0, 1.0]] {
            let before = crate::render::raw_colours(&scene, &ids, centre);
            let after = crate::render::raw_colours(&out, &ids, centre);
            for (x, y) in before.iter().zip(&after) {
                let want = apply(&t, &b, [x[0] as f64, x[1] as f64, x[2] as f64]);
                for c in 0..3 {
                    assert!((y[c] as f64 - want[c]).abs() < 1e-5, "{y:?} vs {want:?}");
                }
            }
        }
        assert_eq!(out.positions, scene.positions);
        assert_eq!(out.opacity_logits, scene.opacity_logits);
    }

    /// A one-sided style (an op-art print's red, white and black, no cyan): a cyan
    /// Gaussian is pulled back toward the style's extent along the red-cyan axis (its
    /// "redness" r - (g + b) / 2 from -0.4 to above -0.15: a box in the style's principal
    /// frame, so not all the way to neutral), colours inside the extent are left bit for
    /// bit, and only the moved Gaussian is counted.
    #[test]
    fn clamping_keeps_colours_inside_the_style_extent() {
        let mut r = Rng::new(4);
        let mut data = Vec::new();
        for i in 0..4000 {
            let base = [[0.85f32, 0.1, 0.1], [0.95, 0.95, 0.95], [0.05, 0.05, 0.05]][i % 3];
            data.extend(base.map(|v| (v + 0.01 * r.normal() as f32).clamp(0.0, 1.0)));
        }
        let style = Image {
            width: 80,
            height: 50,
            data,
        };
        let ext = style_extent(&style, &image_stats(&style));
        let to_dc = |c: [f64; 3]| c.map(|v| ((v - 0.5) / C0 as f64) as f32);
        let inside = [
            [0.5, 0.5, 0.5],
            [0.8, 0.14, 0.13],
            [0.9, 0.9, 0.9],
            [0.1, 0.1, 0.1],
        ];
        let cyan = [0.2, 0.6, 0.6];
        let n = inside.len() + 1;
        let scene = Scene {
            positions: vec![[0.0; 3]; n],
            log_scales: vec![[0.0; 3]; n],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![0.0; n],
            sh_degree: 0,
            sh_dc: inside.iter().chain([&cyan]).map(|&c| to_dc(c)).collect(),
            sh_rest: vec![],
        };
        let (out, changed) = clamp_to_extent(&scene, &ext);
        assert_eq!(changed, 1);
        assert_eq!(out.sh_dc[..4], scene.sh_dc[..4]);
        let c: Vec<f64> = out.sh_dc[4]
            .iter()
            .map(|&v| 0.5 + C0 as f64 * v as f64)
            .collect();
        // "Redness" r - (g + b) / 2: the style's lies in [0, 0.75]; cyan's was -0.4.
        let red = c[0] - 0.5 * (c[1] + c[2]);
        assert!(red > -0.15, "still cyan after clamping: {c:?}");
        for k in 0..3 {
            let x: f64 = (0..3).map(|i| ext.axes[k][i] * (c[i] - ext.mean[i])).sum();
            assert!(
                x >= ext.lo[k] - 1e-6 && x <= ext.hi[k] + 1e-6,
                "axis {k}: {x}"
            );
        }
    }

    #[test]
    fn object_stats_unpremultiply_and_weight() {
        // Two pixels of colour (0.8, 0.4, 0.2): one at alpha 1, one at alpha 0.5 over a
        // grey background; one empty pixel. Mean is that colour, covariance 0.
        let bg = [0.5f32; 3];
        let rgb = [
            0.8,
            0.4,
            0.2, //
            0.5 * 0.8 + 0.25,
            0.5 * 0.4 + 0.25,
            0.5 * 0.2 + 0.25, //
            0.5,
            0.5,
            0.5,
        ];
        let alpha = [1.0, 0.5, 0.0];
        let s = object_stats(&[(&rgb, &alpha)], bg).unwrap();
        for (m, w) in s.mean.iter().zip([0.8, 0.4, 0.2]) {
            assert!((m - w).abs() < 1e-6);
        }
        assert!(s.cov.iter().all(|v| v.abs() < 1e-10));
        assert!(object_stats(&[(&rgb[6..], &alpha[2..])], bg).is_err());
    }
}

//! Image preprocessing shared by the priors: the image encoder's square crop (resized with
//! the crate's one resizer, [`crate::imageio::Image::resized`]), the ControlNet control
//! images made from renders ([`control_image`]), and shape checks.

use super::ControlKind;
use crate::imageio::{Filter, Image};
use crate::{Error, Result};
use ndarray::{Array4, ArrayView4, Axis};

/// Resize so that the shorter side is `size`, then crop the centre `size` x `size`
/// (CLIP's preprocessing, with [`Filter::Bilinear`] instead of bicubic resampling).
/// `img` is `[B, 3, H, W]`.
pub fn fit_square(img: ArrayView4<'_, f32>, size: usize) -> Array4<f32> {
    let (b, _, h, w) = img.dim();
    let (rh, rw) = if h <= w {
        (
            size,
            ((w as f64 * size as f64 / h as f64).round() as usize).max(size),
        )
    } else {
        (
            ((h as f64 * size as f64 / w as f64).round() as usize).max(size),
            size,
        )
    };
    let (y0, x0) = ((rh - size) / 2, (rw - size) / 2);
    let mut out = Array4::zeros((b, 3, size, size));
    for (bi, mut o) in out.axis_iter_mut(Axis(0)).enumerate() {
        let r = Image::from_chw(img.index_axis(Axis(0), bi)).resized(rw, rh, Filter::Bilinear);
        o.assign(&r.crop(x0, y0, size, size).to_chw());
    }
    out
}

/// Check that `images` is `[B, 3, H, W]` with H and W multiples of `downsample`,
/// B >= 1, and every value finite. `what` names the input in the error.
pub fn check_images(images: ArrayView4<'_, f32>, downsample: usize, what: &str) -> Result<()> {
    let (b, c, h, w) = images.dim();
    if b == 0 || c != 3 || h == 0 || w == 0 {
        return Err(Error::param(format!(
            "{what}: expected images [B>=1, 3, H, W], got {:?}",
            images.shape()
        )));
    }
    if h % downsample != 0 || w % downsample != 0 {
        return Err(Error::param(format!(
            "{what}: image size {h}x{w} is not divisible by the model's downsampling \
             factor {downsample}"
        )));
    }
    check_finite(images, what)
}

/// Error if any value is NaN or infinite.
pub fn check_finite(a: ArrayView4<'_, f32>, what: &str) -> Result<()> {
    if let Some(x) = a.iter().find(|x| !x.is_finite()) {
        return Err(Error::param(format!(
            "{what}: contains {x} (NaN or infinity)"
        )));
    }
    Ok(())
}

/// The control image a ControlNet of `kind` wants, `[B, 3, H, W]` in [0, 1], from a
/// views artifact's `rgb` `[B, H, W, 3]`, `depth` `[B, H, W]` and `alpha` `[B, H, W]`.
/// * Depth: inverse depth normalised per view over covered pixels (alpha > 0.5) to
///   [0, 1], near = 1, background 0 (the MiDaS convention depth ControlNets use).
/// * Edges: Sobel gradient magnitude of the luminance, normalised per view to [0, 1].
///
/// Both are replicated to 3 channels.
pub fn control_image(
    kind: ControlKind,
    rgb: ndarray::ArrayView4<'_, f32>,
    depth: ndarray::ArrayView3<'_, f32>,
    alpha: ndarray::ArrayView3<'_, f32>,
) -> Result<Array4<f32>> {
    let (b, h, w) = depth.dim();
    if alpha.dim() != (b, h, w) || rgb.dim() != (b, h, w, 3) {
        return Err(Error::param(format!(
            "control image: rgb {:?}, depth {:?} and alpha {:?} do not agree",
            rgb.shape(),
            depth.shape(),
            alpha.shape()
        )));
    }
    if kind == ControlKind::SourceAlpha {
        let rgba = ndarray::concatenate(Axis(3), &[rgb.view(), alpha.view().insert_axis(Axis(3))])
            .map_err(|e| Error::Other(e.to_string()))?;
        return Ok(rgba.permuted_axes([0, 3, 1, 2]).to_owned());
    }
    let mut out = Array4::<f32>::zeros((b, 3, h, w));
    if kind == ControlKind::Source {
        out.assign(&rgb.permuted_axes([0, 3, 1, 2]));
        return Ok(out);
    }
    for bi in 0..b {
        let vals: Vec<Option<f32>> = match kind {
            ControlKind::Source | ControlKind::SourceAlpha => unreachable!("returned above"),
            ControlKind::Depth => depth
                .index_axis(Axis(0), bi)
                .iter()
                .zip(alpha.index_axis(Axis(0), bi).iter())
                .map(|(&d, &a)| (a > 0.5 && d > 0.0 && d.is_finite()).then(|| 1.0 / d))
                .collect(),
            ControlKind::Edges => {
                let lum = |y: usize, x: usize| {
                    let p = rgb.slice(ndarray::s![bi, y.min(h - 1), x.min(w - 1), ..]);
                    0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2]
                };
                (0..h * w)
                    .map(|i| {
                        let (y, x) = (i / w, i % w);
                        let (ym, xm) = (y.saturating_sub(1), x.saturating_sub(1));
                        let gx = lum(ym, x + 1) + 2.0 * lum(y, x + 1) + lum(y + 1, x + 1)
                            - lum(ym, xm)
                            - 2.0 * lum(y, xm)
                            - lum(y + 1, xm);
                        let gy = lum(y + 1, xm) + 2.0 * lum(y + 1, x) + lum(y + 1, x + 1)
                            - lum(ym, xm)
                            - 2.0 * lum(ym, x)
                            - lum(ym, x + 1);
                        Some((gx * gx + gy * gy).sqrt())
                    })
                    .collect()
            }
        };
        let (lo, hi) = vals
            .iter()
            .flatten()
            .fold((f32::MAX, f32::MIN), |(l, u), &v| (l.min(v), u.max(v)));
        let span = (hi - lo).max(1e-12);
        for (i, v) in vals.iter().enumerate() {
            let x = v.map(|v| (v - lo) / span).unwrap_or(0.0);
            for ch in 0..3 {
                out[[bi, ch, i / w, i % w]] = x;
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_square_crops_the_centre() {
        let img = Array4::from_shape_fn((1, 3, 4, 8), |(_, _, _, x)| x as f32);
        let sq = fit_square(img.view(), 4);
        assert_eq!(sq.dim(), (1, 3, 4, 4));
        assert_eq!(sq[[0, 2, 0, 0]], 2.0);
        assert_eq!(sq[[0, 2, 3, 3]], 5.0);
        let tall = Array4::<f32>::ones((1, 3, 10, 5));
        assert_eq!(fit_square(tall.view(), 3).dim(), (1, 3, 3, 3));
    }

    #[test]
    fn bad_images_are_named() {
        let a = Array4::<f32>::zeros((1, 3, 12, 16));
        let e = check_images(a.view(), 8, "views").unwrap_err().to_string();
        assert!(e.contains("12x16") && e.contains("divisible"), "{e}");
        let mut b = Array4::<f32>::zeros((1, 3, 16, 16));
        b[[0, 1, 2, 3]] = f32::NAN;
        assert!(check_images(b.view(), 8, "views").is_err());
        let c = Array4::<f32>::zeros((1, 4, 16, 16));
        assert!(check_images(c.view(), 8, "views").is_err());
    }
}

//! Image preprocessing shared by the priors: resizing (bilinear, half-pixel centres as
//! in PyTorch's `align_corners=False`, no antialiasing) and shape checks.

use crate::{Error, Result};
use ndarray::{Array4, ArrayView4};

/// Resize `[B, C, H, W]` to `[B, C, h, w]` bilinearly (half-pixel centres, edge clamp).
/// Returns a copy when the size is unchanged.
pub fn resize_bilinear(img: ArrayView4<'_, f32>, h: usize, w: usize) -> Array4<f32> {
    let (b, c, ih, iw) = img.dim();
    if (ih, iw) == (h, w) {
        return img.to_owned();
    }
    let axis = |out: usize, inp: usize| -> Vec<(usize, usize, f32)> {
        let scale = inp as f64 / out as f64;
        (0..out)
            .map(|o| {
                let x = ((o as f64 + 0.5) * scale - 0.5).max(0.0);
                let i0 = (x.floor() as usize).min(inp - 1);
                let i1 = (i0 + 1).min(inp - 1);
                (i0, i1, (x - i0 as f64) as f32)
            })
            .collect()
    };
    let ys = axis(h, ih);
    let xs = axis(w, iw);
    let mut out = Array4::<f32>::zeros((b, c, h, w));
    for bi in 0..b {
        for ci in 0..c {
            for (oy, &(y0, y1, fy)) in ys.iter().enumerate() {
                for (ox, &(x0, x1, fx)) in xs.iter().enumerate() {
                    let p = |y: usize, x: usize| img[[bi, ci, y, x]];
                    let top = p(y0, x0) * (1.0 - fx) + p(y0, x1) * fx;
                    let bot = p(y1, x0) * (1.0 - fx) + p(y1, x1) * fx;
                    out[[bi, ci, oy, ox]] = top * (1.0 - fy) + bot * fy;
                }
            }
        }
    }
    out
}

/// Resize so that the shorter side is `size`, then crop the centre `size` x `size`
/// (CLIP's preprocessing, with bilinear instead of bicubic resampling).
pub fn fit_square(img: ArrayView4<'_, f32>, size: usize) -> Array4<f32> {
    let (_, _, h, w) = img.dim();
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
    let r = resize_bilinear(img, rh, rw);
    let (y0, x0) = ((rh - size) / 2, (rw - size) / 2);
    r.slice(ndarray::s![.., .., y0..y0 + size, x0..x0 + size])
        .to_owned()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resize_preserves_constants_and_linear_ramps() {
        let img = Array4::from_shape_fn((1, 1, 4, 4), |(_, _, _, x)| x as f32);
        let up = resize_bilinear(img.view(), 8, 8);
        // Half-pixel centres: output x maps to input 0.5 x - 0.25 (clamped at 0).
        assert!((up[[0, 0, 0, 3]] - 1.25).abs() < 1e-6);
        assert!((up[[0, 0, 5, 0]] - 0.0).abs() < 1e-6);
        let c = Array4::from_elem((2, 3, 5, 7), 0.3f32);
        let r = resize_bilinear(c.view(), 3, 11);
        assert!(r.iter().all(|x| (x - 0.3).abs() < 1e-6));
        let down = resize_bilinear(img.view(), 2, 2);
        assert!((down[[0, 0, 0, 0]] - 0.5).abs() < 1e-6);
        assert!((down[[0, 0, 0, 1]] - 2.5).abs() < 1e-6);
    }

    #[test]
    fn fit_square_crops_the_centre() {
        let img = Array4::from_shape_fn((1, 1, 4, 8), |(_, _, _, x)| x as f32);
        let sq = fit_square(img.view(), 4);
        assert_eq!(sq.dim(), (1, 1, 4, 4));
        assert_eq!(sq[[0, 0, 0, 0]], 2.0);
        assert_eq!(sq[[0, 0, 3, 3]], 5.0);
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

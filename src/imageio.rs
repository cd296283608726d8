//! Image files: PNG writing of float images and PNG/JPEG reading to float RGB, through
//! the `image` crate.
//!
//! * Writing: `[H, W, 3]` f32 RGB in [0, 1] (clamped; NaN written as 0) to 8-bit RGB,
//!   `round(255 x)`; a `[H, W]` single-channel image (depth, alpha) to 8-bit grayscale,
//!   either as is in [0, 1] or normalised min..max over its finite values. File writes
//!   are atomic (temporary sibling, rename); the `encode_*` functions return bytes for
//!   writing into an artifact.
//! * Reading: PNG (8 or 16 bit) or JPEG to `[H, W, 3]` f32 RGB in [0, 1]; grayscale is
//!   expanded to three equal channels, and **an alpha channel is dropped** (not
//!   composited over any background), since style images and photos are used as colour.

use crate::{Error, Result};
use std::path::Path;

/// A float RGB image, row-major `[height][width][3]`, values in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

fn to_u8(v: f32) -> u8 {
    if v.is_nan() {
        0
    } else {
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

fn encode(buf: Vec<u8>, w: usize, h: usize, color: image::ExtendedColorType) -> Result<Vec<u8>> {
    let (w32, h32) = (u32::try_from(w), u32::try_from(h));
    let (Ok(w32), Ok(h32)) = (w32, h32) else {
        return Err(Error::param(format!(
            "image size {w}x{h} is too large for PNG"
        )));
    };
    if w == 0 || h == 0 {
        return Err(Error::param(format!(
            "cannot encode an empty {w}x{h} image"
        )));
    }
    let mut out = Vec::new();
    let enc = image::codecs::png::PngEncoder::new(&mut out);
    image::ImageEncoder::write_image(enc, &buf, w32, h32, color)
        .map_err(|e| Error::Other(format!("PNG encoding failed: {e}")))?;
    Ok(out)
}

/// Encode `[h, w, 3]` RGB in [0, 1] as an 8-bit PNG.
pub fn encode_png_rgb(rgb: &[f32], w: usize, h: usize) -> Result<Vec<u8>> {
    if rgb.len() != w * h * 3 {
        return Err(Error::param(format!(
            "RGB image of {} values is not {h}x{w}x3",
            rgb.len()
        )));
    }
    encode(
        rgb.iter().map(|&v| to_u8(v)).collect(),
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )
}

/// Encode a `[h, w]` single-channel image as an 8-bit grayscale PNG; with `normalise`,
/// its finite min..max is mapped to 0..1 first (a constant image becomes 0).
pub fn encode_png_gray(v: &[f32], w: usize, h: usize, normalise: bool) -> Result<Vec<u8>> {
    if v.len() != w * h {
        return Err(Error::param(format!(
            "grayscale image of {} values is not {h}x{w}",
            v.len()
        )));
    }
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    if normalise {
        for &x in v.iter().filter(|x| x.is_finite()) {
            lo = lo.min(x);
            hi = hi.max(x);
        }
    }
    let map = |x: f32| {
        if !normalise {
            x
        } else if hi > lo {
            (x - lo) / (hi - lo)
        } else {
            0.0
        }
    };
    encode(
        v.iter().map(|&x| to_u8(map(x))).collect(),
        w,
        h,
        image::ExtendedColorType::L8,
    )
}

/// Write `[h, w, 3]` RGB in [0, 1] to `path` as PNG, atomically.
pub fn write_png_rgb(path: &Path, rgb: &[f32], w: usize, h: usize) -> Result<()> {
    let b = encode_png_rgb(rgb, w, h)?;
    fantasystyle_schemas::atomic_write(path, &b)?;
    Ok(())
}

/// Write a `[h, w]` image to `path` as grayscale PNG, atomically (see [`encode_png_gray`]).
pub fn write_png_gray(path: &Path, v: &[f32], w: usize, h: usize, normalise: bool) -> Result<()> {
    let b = encode_png_gray(v, w, h, normalise)?;
    fantasystyle_schemas::atomic_write(path, &b)?;
    Ok(())
}

/// Read a PNG or JPEG as float RGB in [0, 1] (grayscale expanded, alpha dropped).
pub fn read_rgb(path: &Path) -> Result<RgbImage> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let img = image::load_from_memory(&bytes)
        .map_err(|e| Error::input(path, format!("cannot decode image: {e}")))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    if width == 0 || height == 0 {
        return Err(Error::input(path, "image has zero width or height"));
    }
    let data = img.into_rgb32f().into_raw();
    if data.iter().any(|v| !v.is_finite()) {
        return Err(Error::input(path, "image holds non-finite values"));
    }
    Ok(RgbImage {
        width,
        height,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip_and_grayscale_and_alpha() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.png");
        let rgb: Vec<f32> = (0..2 * 3 * 3).map(|i| i as f32 / 17.0).collect();
        write_png_rgb(&p, &rgb, 3, 2).unwrap();
        let back = read_rgb(&p).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        for (a, b) in rgb.iter().zip(&back.data) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        // Grayscale, normalised: min -> 0, max -> 1, expanded to RGB on read.
        write_png_gray(&p, &[2.0, 4.0, 3.0, f32::NAN], 2, 2, true).unwrap();
        let g = read_rgb(&p).unwrap();
        assert_eq!(&g.data[..6], &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        // RGBA: alpha dropped, colour kept as stored.
        let img = image::RgbaImage::from_raw(1, 1, vec![255, 0, 51, 0]).unwrap();
        img.save(&p).unwrap();
        assert_eq!(read_rgb(&p).unwrap().data, vec![1.0, 0.0, 0.2]);
    }

    #[test]
    fn jpeg_is_read_as_rgb() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.jpg");
        let img = image::RgbImage::from_pixel(16, 8, image::Rgb([200, 100, 50]));
        img.save(&p).unwrap();
        let back = read_rgb(&p).unwrap();
        assert_eq!(
            (back.width, back.height, back.data.len()),
            (16, 8, 16 * 8 * 3)
        );
        // Lossy, but a flat colour survives within a few levels.
        for px in back.data.chunks(3) {
            for (a, b) in px.iter().zip([200.0f32, 100.0, 50.0]) {
                assert!((a * 255.0 - b).abs() < 4.0, "{px:?}");
            }
        }
    }

    #[test]
    fn bad_files_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("junk.png");
        std::fs::write(&p, b"not an image").unwrap();
        let e = read_rgb(&p).unwrap_err().to_string();
        assert!(e.contains("junk.png") && e.contains("cannot decode"), "{e}");
        assert!(encode_png_rgb(&[0.0; 5], 1, 1).is_err());
        assert!(encode_png_rgb(&[], 0, 0).is_err());
        let e = write_png_rgb(&d.path().join("no/x.png"), &[0.0; 3], 1, 1).unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
    }
}

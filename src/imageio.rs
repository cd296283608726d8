//! The one image type ([`Image`]: RGB, row-major HWC, `f32` in `[0, 1]`), its one resizer
//! ([`Image::resized`], with a [`Filter`]), and image files through the `image` crate.
//! Metrics, baselines, priors and stages all use this type; tensors in NCHW/CHW layout
//! convert with [`Image::from_chw`] / [`Image::to_chw`].
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
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// `height * width * 3` values.
    pub data: Vec<f32>,
}

/// How [`Image::resized`] resamples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Filter {
    /// Bilinear with half-pixel centres (PyTorch's `align_corners=False`), edge clamp;
    /// when shrinking by 2x or more on both axes, 2x2 box halvings come first so the
    /// bilinear step never skips pixels.
    Bilinear,
    /// The `image` crate's separable triangle filter, whose support widens with the
    /// shrink factor (area-aware when shrinking); the 2D stylizer's resampling.
    Triangle,
}

impl Image {
    /// A constant image.
    pub fn filled(width: usize, height: usize, rgb: [f32; 3]) -> Image {
        let mut data = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            data.extend_from_slice(&rgb);
        }
        Image {
            width,
            height,
            data,
        }
    }

    /// Build from a function of the pixel coordinates.
    pub fn from_fn(width: usize, height: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Image {
        let mut data = Vec::with_capacity(width * height * 3);
        for y in 0..height {
            for x in 0..width {
                data.extend_from_slice(&f(x, y));
            }
        }
        Image {
            width,
            height,
            data,
        }
    }

    /// Pixel `(x, y)`.
    #[inline]
    pub fn px(&self, x: usize, y: usize) -> [f32; 3] {
        let i = (y * self.width + x) * 3;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Load a PNG or JPEG as RGB in `[0, 1]` through [`read_rgb`] (grey expanded, alpha
    /// dropped). A missing file is bad input naming the file.
    pub fn load(path: &Path) -> Result<Image> {
        if !path.is_file() {
            return Err(Error::input(path, "image file not found"));
        }
        read_rgb(path)
    }

    /// PNG bytes (values clamped to `[0, 1]`, rounded to 8 bits).
    pub fn to_png(&self) -> Vec<u8> {
        encode_png_rgb(&self.data, self.width, self.height)
            .expect("PNG encoding of a non-empty in-memory image cannot fail")
    }

    /// From a `[3, H, W]` array.
    pub fn from_chw(a: ndarray::ArrayView3<'_, f32>) -> Image {
        let (c, height, width) = a.dim();
        assert_eq!(c, 3, "an RGB image has 3 channels, got {c}");
        Image {
            width,
            height,
            data: a.permuted_axes([1, 2, 0]).iter().copied().collect(),
        }
    }

    /// As a `[3, H, W]` array.
    pub fn to_chw(&self) -> ndarray::Array3<f32> {
        ndarray::Array3::from_shape_fn((3, self.height, self.width), |(c, y, x)| {
            self.data[(y * self.width + x) * 3 + c]
        })
    }

    /// Bilinear sample at continuous pixel coordinates (pixel centres at integers),
    /// clamped at the border.
    #[inline]
    pub fn sample(&self, u: f64, v: f64) -> [f32; 3] {
        let u = u.clamp(0.0, (self.width - 1) as f64);
        let v = v.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((u - x0 as f64) as f32, (v - y0 as f64) as f32);
        let (a, b, c, d) = (
            self.px(x0, y0),
            self.px(x1, y0),
            self.px(x0, y1),
            self.px(x1, y1),
        );
        let mut out = [0.0; 3];
        for k in 0..3 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bot = c[k] + (d[k] - c[k]) * fx;
            out[k] = top + (bot - top) * fy;
        }
        out
    }

    /// Resize to `width` x `height` with `filter` (see [`Filter`]); the same size is a copy.
    pub fn resized(&self, width: usize, height: usize, filter: Filter) -> Image {
        if (width, height) == (self.width, self.height) {
            return self.clone();
        }
        match filter {
            Filter::Bilinear => self.resized_bilinear(width, height),
            Filter::Triangle => self.resized_triangle(width, height),
        }
    }

    fn resized_triangle(&self, width: usize, height: usize) -> Image {
        let buf: image::ImageBuffer<image::Rgb<f32>, Vec<f32>> =
            image::ImageBuffer::from_raw(self.width as u32, self.height as u32, self.data.clone())
                .expect("buffer size matches");
        let r = image::imageops::resize(
            &buf,
            width as u32,
            height as u32,
            image::imageops::FilterType::Triangle,
        );
        Image {
            width,
            height,
            data: r.into_raw(),
        }
    }

    fn resized_bilinear(&self, width: usize, height: usize) -> Image {
        let mut src = self.clone();
        while src.width >= 2 * width.max(1) && src.height >= 2 * height.max(1) {
            src = src.halved();
        }
        let sx = src.width as f64 / width as f64;
        let sy = src.height as f64 / height as f64;
        Image::from_fn(width, height, |x, y| {
            src.sample((x as f64 + 0.5) * sx - 0.5, (y as f64 + 0.5) * sy - 0.5)
        })
    }

    /// 2x2 box downsampling.
    fn halved(&self) -> Image {
        let (w, h) = (self.width / 2, self.height / 2);
        Image::from_fn(w, h, |x, y| {
            let mut o = [0.0; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = self.px(2 * x + dx, 2 * y + dy);
                for k in 0..3 {
                    o[k] += 0.25 * p[k];
                }
            }
            o
        })
    }

    /// Fit within `max_side` pixels (aspect kept); unchanged if already small enough.
    pub fn fit_within(&self, max_side: usize) -> Image {
        let m = self.width.max(self.height);
        if m <= max_side {
            return self.clone();
        }
        let s = max_side as f64 / m as f64;
        let w = ((self.width as f64 * s).round() as usize).max(1);
        let h = ((self.height as f64 * s).round() as usize).max(1);
        self.resized(w, h, Filter::Bilinear)
    }

    /// Resized so the shorter side is `side` pixels (aspect kept, [`Filter::Bilinear`]):
    /// the scale at which the style is drawn (the texture term, the VGG baselines, the
    /// object KID).
    pub fn with_shorter_side(&self, side: usize) -> Image {
        let s = side as f64 / self.width.min(self.height).max(1) as f64;
        let w = ((self.width as f64 * s).round() as usize).max(1);
        let h = ((self.height as f64 * s).round() as usize).max(1);
        self.resized(w, h, Filter::Bilinear)
    }

    /// The sub-image `[x0, x0 + w) x [y0, y0 + h)` (must lie inside).
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Image {
        assert!(
            x0 + w <= self.width && y0 + h <= self.height,
            "crop outside image"
        );
        Image::from_fn(w, h, |x, y| self.px(x0 + x, y0 + y))
    }

    /// Separable Gaussian blur with standard deviation `sigma` pixels, each channel, the
    /// edge pixel repeated outside ([`crate::maths::blur`]).
    pub fn blurred(&self, sigma: f32) -> Image {
        use crate::maths::blur::{Border, gaussian};
        if sigma <= 0.0 {
            return self.clone();
        }
        let (w, h) = (self.width, self.height);
        let planes: Vec<Vec<f32>> = (0..3)
            .map(|c| {
                let plane: Vec<f32> = self.data.iter().skip(c).step_by(3).copied().collect();
                gaussian(&plane, (h, w), sigma, Border::Clamp)
            })
            .collect();
        Image::from_fn(w, h, |x, y| {
            let p = y * w + x;
            [planes[0][p], planes[1][p], planes[2][p]]
        })
    }

    /// Add Gaussian noise of standard deviation `std` (deterministic in `seed`), clamped.
    pub fn noisy(&self, std: f32, seed: u64) -> Image {
        let mut rng = crate::rng::Rng::derive(seed, "metrics-image-noise");
        let noise = rng.normals_f32(self.data.len());
        Image {
            width: self.width,
            height: self.height,
            data: self
                .data
                .iter()
                .zip(noise)
                .map(|(v, n)| (v + std * n).clamp(0.0, 1.0))
                .collect(),
        }
    }

    /// Stack images of one size into an NCHW batch.
    pub fn to_nchw(images: &[&Image]) -> (Vec<usize>, Vec<f32>) {
        let (w, h) = (images[0].width, images[0].height);
        let mut out = Vec::with_capacity(images.len() * 3 * w * h);
        for img in images {
            assert_eq!(
                (img.width, img.height),
                (w, h),
                "batch images differ in size"
            );
            for c in 0..3 {
                out.extend(img.data.iter().skip(c).step_by(3));
            }
        }
        (vec![images.len(), 3, h, w], out)
    }
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

/// Box-downsample by an integer `factor` (floor: trailing rows/columns dropped).
pub fn downsample(img: &Image, factor: usize) -> Image {
    if factor == 1 {
        return img.clone();
    }
    let (h, w) = (img.height / factor, img.width / factor);
    let mut out = vec![0.0f32; h * w * 3];
    let inv = 1.0 / (factor * factor) as f32;
    for y in 0..h {
        for x in 0..w {
            for dy in 0..factor {
                for dx in 0..factor {
                    let p = ((y * factor + dy) * img.width + x * factor + dx) * 3;
                    for c in 0..3 {
                        out[(y * w + x) * 3 + c] += img.data[p + c] * inv;
                    }
                }
            }
        }
    }
    Image {
        width: w,
        height: h,
        data: out,
    }
}

/// Adjoint of [`downsample`]: add the small image's gradient back onto `grad` (full size
/// `h x w`), each small pixel spread evenly over its `factor^2` sources.
pub fn downsample_adjoint_add(small: &[f32], factor: usize, h: usize, w: usize, grad: &mut [f32]) {
    let (hs, ws) = (h / factor, w / factor);
    let inv = 1.0 / (factor * factor) as f32;
    for y in 0..hs {
        for x in 0..ws {
            for dy in 0..factor {
                for dx in 0..factor {
                    let p = ((y * factor + dy) * w + x * factor + dx) * 3;
                    for c in 0..3 {
                        grad[p + c] += small[(y * ws + x) * 3 + c] * inv;
                    }
                }
            }
        }
    }
}

/// Read a PNG or JPEG as float RGB in [0, 1] (grayscale expanded, alpha dropped).
/// The shortest side a style image must have to carry a style for the 2D priors: the
/// stylizer's style network sees 256 px, and a smaller image would reach it as mostly
/// interpolation (the VGG losses need 92 px, [`crate::vgg::MIN_STYLE_SIDE`]).
pub const MIN_STYLE_SIDE: usize = 64;

/// Load a style image (PNG or JPEG, grey expanded, alpha dropped), refusing a missing
/// file and one whose shorter side is under `min_side`, with the size named.
pub fn load_style(path: &Path, min_side: usize) -> Result<Image> {
    if !path.is_file() {
        return Err(Error::input(path, "style image not found"));
    }
    let img = read_rgb(path)?;
    if img.width.min(img.height) < min_side {
        return Err(Error::input(
            path,
            format!(
                "style image is {}x{}: too small to carry a style (the shorter side must be at least {min_side} px)",
                img.width, img.height
            ),
        ));
    }
    Ok(img)
}

pub fn read_rgb(path: &Path) -> Result<Image> {
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
    Ok(Image {
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

    #[test]
    fn png_roundtrip_and_load_conversions() {
        let d = tempfile::tempdir().unwrap();
        let img = Image::from_fn(7, 5, |x, y| [x as f32 / 6.0, y as f32 / 4.0, 0.5]);
        let p = d.path().join("a.png");
        std::fs::write(&p, img.to_png()).unwrap();
        let back = Image::load(&p).unwrap();
        assert_eq!((back.width, back.height), (7, 5));
        for (a, b) in img.data.iter().zip(&back.data) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
        // grey + alpha: grey expanded, alpha dropped (imageio's convention)
        let ga = image::GrayAlphaImage::from_raw(2, 1, vec![255, 0, 0, 255]).unwrap();
        let p2 = d.path().join("ga.png");
        ga.save(&p2).unwrap();
        let g = Image::load(&p2).unwrap();
        assert_eq!(g.px(0, 0), [1.0, 1.0, 1.0]);
        assert_eq!(g.px(1, 0), [0.0, 0.0, 0.0]);
        let e = Image::load(&d.path().join("none.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.png") && e.contains("not found"), "{e}");
        std::fs::write(d.path().join("bad.png"), b"nope").unwrap();
        let e = Image::load(&d.path().join("bad.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.png") && e.contains("cannot decode"), "{e}");
    }

    #[test]
    fn resize_of_constant_is_constant_and_sample_hits_pixels() {
        let img = Image::filled(40, 30, [0.2, 0.4, 0.6]);
        let r = img.resized(9, 7, Filter::Bilinear);
        assert!(
            r.data
                .iter()
                .zip([0.2, 0.4, 0.6].iter().cycle())
                .all(|(a, b)| (a - b).abs() < 1e-6)
        );
        let g = Image::from_fn(5, 4, |x, y| [x as f32, y as f32, 0.0]);
        assert_eq!(g.sample(3.0, 2.0), [3.0, 2.0, 0.0]);
        let s = g.sample(1.25, 0.5);
        assert!((s[0] - 1.25).abs() < 1e-6 && (s[1] - 0.5).abs() < 1e-6);
    }

    #[test]
    fn resize_filters_and_chw_round_trip() {
        let img = Image::from_fn(13, 9, |x, y| {
            [x as f32 / 12.0, y as f32 / 8.0, ((x * y) % 5) as f32 / 4.0]
        });
        assert_eq!(img.resized(13, 9, Filter::Triangle), img);
        assert_eq!(img.resized(13, 9, Filter::Bilinear), img);
        assert_eq!(Image::from_chw(img.to_chw().view()), img);
        // Half-pixel bilinear: upsampling 2x puts output x at input 0.5 x - 0.25.
        let up = img.resized(26, 18, Filter::Bilinear);
        assert!((up.px(3, 0)[0] - 1.25 / 12.0).abs() < 1e-6);
        // Shrinking by 4 is two 2x2 box halvings: the mean of each 4x4 block.
        let big = Image::from_fn(8, 8, |x, y| [(x + 8 * y) as f32, 0.0, 1.0]);
        let small = big.resized(2, 2, Filter::Bilinear);
        assert_eq!(
            small.px(0, 0)[0],
            (0..4)
                .map(|y| (0..4).map(|x| (x + 8 * y) as f32).sum::<f32>())
                .sum::<f32>()
                / 16.0
        );
        // Triangle shrinks area-aware too: a constant stays constant either way.
        let c = Image::filled(40, 30, [0.25, 0.5, 0.75]);
        for f in [Filter::Bilinear, Filter::Triangle] {
            let r = c.resized(7, 5, f);
            assert!(
                r.data
                    .iter()
                    .zip([0.25, 0.5, 0.75].iter().cycle())
                    .all(|(a, b)| (a - b).abs() < 1e-6)
            );
        }
    }

    #[test]
    fn nchw_layout() {
        let a = Image::from_fn(2, 1, |x, _| [x as f32, 10.0 + x as f32, 20.0 + x as f32]);
        let (s, d) = Image::to_nchw(&[&a]);
        assert_eq!(s, vec![1, 3, 1, 2]);
        assert_eq!(d, vec![0.0, 1.0, 10.0, 11.0, 20.0, 21.0]);
    }

    #[test]
    fn downsample_adjoint_is_the_transpose() {
        let mut r = crate::rng::Rng::new(3);
        let (h, w) = (7, 9);
        let x = Image {
            width: w,
            height: h,
            data: (0..h * w * 3).map(|_| r.normal() as f32).collect(),
        };
        let y = downsample(&x, 2);
        let g: Vec<f32> = (0..y.data.len()).map(|_| r.normal() as f32).collect();
        let mut back = vec![0.0; x.data.len()];
        downsample_adjoint_add(&g, 2, h, w, &mut back);
        let lhs: f64 = y.data.iter().zip(&g).map(|(&a, &b)| (a * b) as f64).sum();
        let rhs: f64 = x
            .data
            .iter()
            .zip(&back)
            .map(|(&a, &b)| (a * b) as f64)
            .sum();
        assert!((lhs - rhs).abs() < 1e-4, "{lhs} vs {rhs}");
    }
}

//! The image type the metrics work on: RGB, row-major HWC, `f32` in `[0, 1]`; loading a
//! style image and PNG encoding (both through [`crate::imageio`]), bilinear resampling,
//! crops, and the blur/noise perturbations the LPIPS sanity tests use.

use crate::{Error, Result};
use std::path::Path;

/// An RGB image, HWC, values in `[0, 1]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// `height * width * 3` values.
    pub data: Vec<f32>,
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

    /// Load a PNG or JPEG as RGB in `[0, 1]` through [`crate::imageio::read_rgb`] (grey
    /// expanded, alpha dropped). A missing file is bad input naming the file.
    pub fn load(path: &Path) -> Result<Image> {
        if !path.is_file() {
            return Err(Error::input(path, "image file not found"));
        }
        let img = crate::imageio::read_rgb(path)?;
        Ok(Image {
            width: img.width,
            height: img.height,
            data: img.data,
        })
    }

    /// PNG bytes (values clamped to `[0, 1]`, rounded to 8 bits).
    pub fn to_png(&self) -> Vec<u8> {
        crate::imageio::encode_png_rgb(&self.data, self.width, self.height)
            .expect("PNG encoding of a non-empty in-memory image cannot fail")
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

    /// Resize with bilinear interpolation (half-pixel centres); when shrinking by more
    /// than 2x, a box pre-filter avoids aliasing.
    pub fn resized(&self, width: usize, height: usize) -> Image {
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
        self.resized(w, h)
    }

    /// The sub-image `[x0, x0 + w) x [y0, y0 + h)` (must lie inside).
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Image {
        assert!(
            x0 + w <= self.width && y0 + h <= self.height,
            "crop outside image"
        );
        Image::from_fn(w, h, |x, y| self.px(x0 + x, y0 + y))
    }

    /// Separable Gaussian blur with standard deviation `sigma` pixels (clamped border).
    pub fn blurred(&self, sigma: f32) -> Image {
        if sigma <= 0.0 {
            return self.clone();
        }
        let r = (3.0 * sigma).ceil() as i64;
        let k: Vec<f32> = (-r..=r)
            .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
            .collect();
        let ks: f32 = k.iter().sum();
        let (w, h) = (self.width as i64, self.height as i64);
        let pass = |img: &Image, horizontal: bool| {
            Image::from_fn(img.width, img.height, |x, y| {
                let mut o = [0.0; 3];
                for (t, kv) in k.iter().enumerate() {
                    let d = t as i64 - r;
                    let (sx, sy) = if horizontal {
                        ((x as i64 + d).clamp(0, w - 1), y as i64)
                    } else {
                        (x as i64, (y as i64 + d).clamp(0, h - 1))
                    };
                    let p = img.px(sx as usize, sy as usize);
                    for c in 0..3 {
                        o[c] += kv * p[c] / ks;
                    }
                }
                o
            })
        };
        pass(&pass(self, true), false)
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

/// Standard base64 (RFC 4648, with padding), for embedding PNGs in HTML.
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for ch in bytes.chunks(3) {
        let b = [ch[0], *ch.get(1).unwrap_or(&0), *ch.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        s.push(T[(n >> 18) as usize & 63] as char);
        s.push(T[(n >> 12) as usize & 63] as char);
        s.push(if ch.len() > 1 {
            T[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        s.push(if ch.len() > 2 {
            T[n as usize & 63] as char
        } else {
            '='
        });
    }
    s
}

/// `data:image/png;base64,...` URI of an image.
pub fn png_data_uri(img: &Image) -> String {
    format!("data:image/png;base64,{}", base64(&img.to_png()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
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
        let r = img.resized(9, 7);
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
    fn nchw_layout() {
        let a = Image::from_fn(2, 1, |x, _| [x as f32, 10.0 + x as f32, 20.0 + x as f32]);
        let (s, d) = Image::to_nchw(&[&a]);
        assert_eq!(s, vec![1, 3, 1, 2]);
        assert_eq!(d, vec![0.0, 1.0, 10.0, 11.0, 20.0, 21.0]);
    }
}

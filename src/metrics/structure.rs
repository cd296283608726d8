//! Structure kept (issue 47): how much of the object's edges and shading detail is still
//! where it was after stylization, per view and as the mean over views.
//!
//! **Definition.** Per view, with `Y = 0.299 R + 0.587 G + 0.114 B` (Rec. 601 luma of the
//! rgb as stored in the views artifact, composited over its background), the band-passed
//! luminance is the difference of Gaussians `D = G_1 * Y - G_4 * Y` (as in band-pass
//! structure measures: it keeps edges and shading at 1-4 px scales, drops the flat
//! colour and the large-scale gradient): `G_s` a separable Gaussian blur of standard
//! deviation `s` px, taps `exp(-i^2 / (2 s^2))` for `|i| <= ceil(3 s)` divided by their
//! sum, the edge pixel repeated outside the image (clamp to edge). The view's value is the
//! Pearson correlation of the source's and the stylized view's `D` over the object's
//! pixels (source alpha > [`ALPHA_MIN`]), in f64.
//!
//! **Meaning.** 1: every edge and shading detail is still where it was, whatever its
//! colour or contrast (a brightness or contrast change keeps 1); about 0: the detail is
//! unrelated to the source's (blurred away, or replaced by other strokes); -1: the
//! luminance is inverted.
//!
//! **No value.** A view with fewer than [`MIN_PIXELS`] object pixels, or whose band-pass
//! image has no variance over them (mean squared deviation below [`MIN_VARIANCE`]: flat
//! colour), has no value (`None`); the mean is over the views that have one.
//!
//! Reference: `scripts/reference/structure_ref.py` (numpy, written from this definition)
//! computes the same; `tests/integration/structure.rs` compares the two on renders of the
//! sample scene.

use super::views::ViewSet;
use crate::imageio::Image;
use crate::maths::blur::{Border, gaussian};

/// Object pixels: source alpha above this.
pub const ALPHA_MIN: f32 = 0.5;
/// Standard deviation of the fine Gaussian, px.
pub const SIGMA_FINE: f64 = 1.0;
/// Standard deviation of the coarse Gaussian, px.
pub const SIGMA_COARSE: f64 = 4.0;
/// Fewest object pixels a view needs for a value.
pub const MIN_PIXELS: usize = 16;
/// Least variance of either band-pass image over the object for a value (luminance in
/// [0, 1]: a standard deviation of 1e-6, far below one 8-bit step).
pub const MIN_VARIANCE: f64 = 1e-12;

/// What the value means, written beside it in `metrics.json` and the report.
pub const NOTE: &str = "structure kept: per view, the Pearson correlation over the object's pixels (source alpha > 0.5) \
     of the source's and the stylized view's band-passed luminance (Rec. 601 luma, difference of Gaussians sigma 1 px \
     minus sigma 4 px, clamp to edge); 1 = every edge and shading detail still where it was (whatever its colour or \
     contrast), 0 = unrelated detail, -1 = inverted; mean over the views with a value; a view with fewer than 16 \
     object pixels or a flat band-pass image has none (null)";

/// Rec. 601 luma of an image, row-major, f64.
pub fn luma(img: &Image) -> Vec<f64> {
    img.data
        .chunks_exact(3)
        .map(|p| 0.299 * f64::from(p[0]) + 0.587 * f64::from(p[1]) + 0.114 * f64::from(p[2]))
        .collect()
}

/// Separable Gaussian blur of a row-major `w x h` plane, edge pixels repeated outside.
fn blur_clamped(x: &[f64], w: usize, h: usize, sigma: f64) -> Vec<f64> {
    gaussian(x, (h, w), sigma, Border::Clamp)
}

/// The band-passed luminance `G_1 * Y - G_4 * Y` of an image (row-major).
pub fn band_pass(img: &Image) -> Vec<f64> {
    let (w, h) = (img.width, img.height);
    let y = luma(img);
    let fine = blur_clamped(&y, w, h, SIGMA_FINE);
    let coarse = blur_clamped(&y, w, h, SIGMA_COARSE);
    fine.iter().zip(&coarse).map(|(a, b)| a - b).collect()
}

/// Pearson correlation of `a` and `b` over the pixels where `inside` holds; `None` with
/// fewer than [`MIN_PIXELS`] of them or a variance below [`MIN_VARIANCE`].
pub fn correlation(a: &[f64], b: &[f64], inside: &[bool]) -> Option<f64> {
    let pairs: Vec<(f64, f64)> = inside
        .iter()
        .zip(a.iter().zip(b))
        .filter(|(m, _)| **m)
        .map(|(_, (x, y))| (*x, *y))
        .collect();
    let n = pairs.len();
    if n < MIN_PIXELS {
        return None;
    }
    let (ma, mb) = pairs
        .iter()
        .fold((0.0, 0.0), |(s, t), (x, y)| (s + x, t + y));
    let (ma, mb) = (ma / n as f64, mb / n as f64);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in &pairs {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    let (va, vb) = (saa / n as f64, sbb / n as f64);
    if va < MIN_VARIANCE || vb < MIN_VARIANCE {
        return None;
    }
    Some((sab / (saa * sbb).sqrt()).clamp(-1.0, 1.0))
}

/// The object's pixels of a view: `alpha > ALPHA_MIN`.
pub fn object_pixels(alpha: &[f32]) -> Vec<bool> {
    alpha.iter().map(|a| *a > ALPHA_MIN).collect()
}

/// Structure kept of one view: source image `src`, its alpha, and the stylized image.
pub fn view_structure(src: &Image, alpha: &[f32], styl: &Image) -> Option<f64> {
    assert_eq!(
        (src.width, src.height),
        (styl.width, styl.height),
        "structure: image sizes"
    );
    assert_eq!(alpha.len(), src.width * src.height, "structure: alpha size");
    correlation(&band_pass(src), &band_pass(styl), &object_pixels(alpha))
}

/// Structure kept of every view of `styl` against `src` (the same views), and the mean
/// over the views that have a value.
pub fn structure_kept(src: &ViewSet, styl: &ViewSet) -> (Option<f64>, Vec<Option<f64>>) {
    let per_view: Vec<Option<f64>> = (0..src.n)
        .map(|i| view_structure(&src.images[i], src.geometry(i).1, &styl.images[i]))
        .collect();
    (mean_present(&per_view), per_view)
}

/// Mean of the values present (`None` when there is none).
pub fn mean_present(v: &[Option<f64>]) -> Option<f64> {
    let have: Vec<f64> = v.iter().flatten().copied().collect();
    (!have.is_empty()).then(|| have.iter().sum::<f64>() / have.len() as f64)
}

/// The view with the lowest value (the first of equals), if any has one.
pub fn worst_view(per_view: &[Option<f64>]) -> Option<usize> {
    per_view
        .iter()
        .enumerate()
        .filter_map(|(i, v)| v.map(|v| (i, v)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::fixtures::{map, textured_disc};
    use super::*;

    const W: usize = 64;
    const H: usize = 40;

    /// The textured disc of radius 17 at (24, 20).
    fn object() -> (Image, Vec<f32>) {
        textured_disc(W, H, (24.0, 20.0), 17.0)
    }

    #[test]
    fn identical_images_keep_all_structure() {
        let (img, alpha) = object();
        let r = view_structure(&img, &alpha, &img).unwrap();
        assert!((r - 1.0).abs() < 1e-12, "{r}");
    }

    #[test]
    fn brightness_and_contrast_keep_all_structure() {
        let (img, alpha) = object();
        let changed = map(&img, |v| 0.1 + 0.6 * v);
        let r = view_structure(&img, &alpha, &changed).unwrap();
        assert!((r - 1.0).abs() < 1e-9, "{r}");
    }

    #[test]
    fn negated_luminance_gives_minus_one() {
        let (img, alpha) = object();
        let r = view_structure(&img, &alpha, &map(&img, |v| 1.0 - v)).unwrap();
        assert!((r + 1.0).abs() < 1e-9, "{r}");
    }

    #[test]
    fn detail_blurred_away_keeps_little() {
        let (img, alpha) = object();
        let soft = view_structure(&img, &alpha, &img.blurred(1.0)).unwrap();
        let gone = view_structure(&img, &alpha, &img.blurred(4.0)).unwrap();
        assert!(
            gone < 0.6 && gone < soft - 0.2,
            "sigma 4: {gone}, sigma 1: {soft}"
        );
        // Detail of its own, unrelated to the source's (two seeds' textures over the
        // whole frame): about 0.
        let noise = |seed| {
            let n = crate::rng::Rng::new(seed).normals_f32(W * H);
            Image::from_fn(W, H, |x, y| [0.5 + 0.1 * n[y * W + x]; 3])
        };
        let r = view_structure(&noise(1), &[1.0; W * H], &noise(2)).unwrap();
        assert!(r.abs() < 0.2, "{r}");
    }

    #[test]
    fn the_background_beyond_the_kernel_does_not_count() {
        let (img, alpha) = object();
        let mut styl = img.clone();
        // Columns beyond the coarse kernel's reach (radius 12 px, a square support) from
        // the disc (x <= 24 + 17 = 41): x >= 54.
        for y in 0..H {
            for x in 54..W {
                let p = 3 * (y * W + x);
                styl.data[p..p + 3].copy_from_slice(&[((x * 7 + y * 3) % 5) as f32 / 5.0; 3]);
            }
        }
        assert_ne!(styl, img, "the background changed");
        let r = view_structure(&img, &alpha, &styl).unwrap();
        assert!((r - 1.0).abs() < 1e-12, "{r}");
    }

    #[test]
    fn too_few_pixels_or_flat_colour_give_none() {
        let (img, alpha) = object();
        let mut few = vec![0.0f32; W * H];
        for p in few.iter_mut().skip(500).take(MIN_PIXELS - 1) {
            *p = 1.0;
        }
        assert_eq!(view_structure(&img, &few, &img), None);
        let flat = Image::filled(W, H, [0.3, 0.6, 0.2]);
        assert_eq!(view_structure(&img, &alpha, &flat), None);
        assert_eq!(view_structure(&flat, &alpha, &img), None);
    }

    #[test]
    fn blur_keeps_constants_at_the_borders() {
        let x = vec![0.25; 9 * 5];
        for v in blur_clamped(&x, 9, 5, SIGMA_COARSE) {
            assert!((v - 0.25).abs() < 1e-15, "{v}");
        }
        // A step is blurred symmetrically about its edge (odd symmetry of the blur).
        let step: Vec<f64> = (0..40).map(|i| f64::from(u8::from(i >= 20))).collect();
        let b = blur_clamped(&step, 40, 1, SIGMA_FINE);
        for d in 0..8 {
            assert!((b[20 + d] + b[19 - d] - 1.0).abs() < 1e-12, "{d}");
        }
    }

    #[test]
    fn mean_and_worst_skip_views_without_a_value() {
        let v = [Some(0.9), None, Some(0.3), Some(0.3)];
        assert!((mean_present(&v).unwrap() - 0.5).abs() < 1e-12);
        assert_eq!(worst_view(&v), Some(2));
        assert_eq!(mean_present(&[None, None]), None);
        assert_eq!(worst_view(&[None]), None);
    }
}

/// Test images shared by the structure measures' tests (here and in
/// [`super::interior`]).
#[cfg(test)]
pub(crate) mod fixtures {
    use crate::imageio::Image;

    /// A textured object: seeded noise detail on smooth shading inside a disc of
    /// `radius` at `centre` (alpha 1) on black (alpha 0), `w` x `h`.
    pub fn textured_disc(w: usize, h: usize, centre: (f32, f32), radius: f32) -> (Image, Vec<f32>) {
        let noise = crate::rng::Rng::new(7).normals_f32(w * h);
        let inside = |x: usize, y: usize| {
            let (dx, dy) = (x as f32 - centre.0, y as f32 - centre.1);
            dx * dx + dy * dy < radius * radius
        };
        let img = Image::from_fn(w, h, |x, y| {
            if !inside(x, y) {
                return [0.0; 3];
            }
            let shade = 0.15 * ((x as f32) / 7.0).sin() * ((y as f32) / 11.0).cos();
            let n = 0.08 * noise[y * w + x];
            [0.5 + shade + n, 0.45 + shade + 0.5 * n, 0.4 + shade]
        });
        let alpha = (0..w * h)
            .map(|p| f32::from(u8::from(inside(p % w, p / w))))
            .collect();
        (img, alpha)
    }

    /// `img` with `f` applied to every value.
    pub fn map(img: &Image, f: impl Fn(f32) -> f32) -> Image {
        Image {
            data: img.data.iter().map(|v| f(*v)).collect(),
            ..img.clone()
        }
    }
}

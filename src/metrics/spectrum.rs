//! The motif scale of a texture: the radially averaged power spectrum of luminance
//! (issue 21, "measures that see texture"), for the object in the views and for the
//! style image.
//!
//! **Signal.** Luminance `Y = 0.2126 R + 0.7152 G + 0.0722 B` (Rec. 709 weights on the
//! stored values). For a view, the object's texture with the object's own mean and the
//! background taken out: with the rendered alpha `a`, the background's luminance
//! `Y_bg` (the mean over pixels with `a < 1e-3`, 0 if there are none) and the
//! alpha-weighted mean `mu` of the object's un-premultiplied luminance,
//! `s = Y - (1 - a) Y_bg - a mu = a (Y_obj - mu)`: the alpha itself is the window, so the
//! silhouette is a soft edge of a zero-mean signal and the black background carries no
//! power. For the style image, `s = (Y - mean Y) * hann(x) * hann(y)` (periodic Hann
//! window), the usual windowed periodogram.
//!
//! **Spectrum.** `P(k) = |FFT2(s)(k)|^2` on the image's own frequency grid, in cycles per
//! pixel (`fx = kx / W`, `fy = ky / H`, signed, radius `f = hypot(fx, fy)`), averaged over
//! the samples in each of [`BINS`] log-spaced bands of [`BINS_PER_OCTAVE`] per octave from
//! [`F_MIN`] (a period of 128 px) to [`F_MAX`] (Nyquist); band `b` holds
//! `F_MIN 2^(b/4) <= f < F_MIN 2^((b+1)/4)` (the last band includes `f = 0.5`). Each
//! band's mean is divided by the mean of `P` over every non-DC sample, so a spectrum
//! says how power is *distributed* over scales, independent of contrast and of image
//! size (for a stationary texture the normalised spectrum of a 128 px and a 256 px
//! image agree). A band without samples (small images) is `None`.
//!
//! **Distance and peak.** `distance(a, b) = sqrt(mean_b (log10 a_b - log10 b_b)^2)` over the
//! bands both have (decades, RMS; band powers floored at 1e-8 of the mean): 0 for the
//! same distribution of power over scales.
//! The *peak* is the band with the most energy per band, `P_b (f_hi^2 - f_lo^2)` (the
//! band's mean power times its annulus area, i.e. power per quarter octave, so the
//! `1/f^2` fall-off of natural images does not put every peak in the lowest band);
//! reported as the band's geometric centre in cycles per pixel. A stripe pattern of
//! period `p` px peaks in the band that holds `1/p`.
//!
//! **Resolution.** A quarter-octave band at `f` is `0.19 f` wide; the Hann window's main
//! lobe is `+-2/N` for an `N`-pixel image (an object's silhouette is a window of its own
//! size). Below `f = 10/N` (a period of `N/10` px: 26 px at 256) the bands are narrower
//! than that, and a peak can land one band off (tested).
//!
//! Reference: `scripts/reference/spectrum_ref.py` (numpy) computes the same from the
//! definitions above; `tests/golden/spectrum` holds its output, checked below.

use crate::imageio::Image;
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;

/// Lowest band edge, cycles per pixel (a period of 128 px).
pub const F_MIN: f64 = 1.0 / 128.0;
/// Highest band edge (Nyquist).
pub const F_MAX: f64 = 0.5;
/// Bands per octave.
pub const BINS_PER_OCTAVE: usize = 4;
/// Number of bands: 6 octaves from `F_MIN` to `F_MAX`.
pub const BINS: usize = 24;

/// Lower edge of band `b` (`b = BINS` gives the top edge, `F_MAX`).
pub fn band_edge(b: usize) -> f64 {
    F_MIN * 2f64.powf(b as f64 / BINS_PER_OCTAVE as f64)
}

/// Geometric centre of band `b`, cycles per pixel.
pub fn band_centre(b: usize) -> f64 {
    F_MIN * 2f64.powf((b as f64 + 0.5) / BINS_PER_OCTAVE as f64)
}

/// The band of radius `f`, if it lies in `[F_MIN, F_MAX]`.
pub fn band_of(f: f64) -> Option<usize> {
    if !(F_MIN..=F_MAX + 1e-12).contains(&f) {
        return None;
    }
    let b = ((f / F_MIN).log2() * BINS_PER_OCTAVE as f64).floor() as usize;
    Some(b.min(BINS - 1))
}

/// Rec. 709 luminance of every pixel.
pub fn luminance(img: &Image) -> Vec<f64> {
    img.data
        .chunks_exact(3)
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .collect()
}

/// The object's zero-mean, alpha-windowed luminance in a view (see module docs); `None`
/// when the view has no coverage.
pub fn object_signal(img: &Image, alpha: &[f32]) -> Option<Vec<f64>> {
    let y = luminance(img);
    assert_eq!(y.len(), alpha.len(), "object_signal: alpha size");
    let (mut bg, mut nbg) = (0.0, 0usize);
    for (v, &a) in y.iter().zip(alpha) {
        if a < 1e-3 {
            bg += v;
            nbg += 1;
        }
    }
    let bg = if nbg > 0 { bg / nbg as f64 } else { 0.0 };
    let sa: f64 = alpha.iter().map(|&a| a as f64).sum();
    if sa < 1.0 {
        return None;
    }
    // sum a * Y_obj = sum (Y - (1 - a) Y_bg)
    let mu = y
        .iter()
        .zip(alpha)
        .map(|(v, &a)| v - (1.0 - a as f64) * bg)
        .sum::<f64>()
        / sa;
    Some(
        y.iter()
            .zip(alpha)
            .map(|(v, &a)| v - (1.0 - a as f64) * bg - a as f64 * mu)
            .collect(),
    )
}

/// Periodic Hann window of length `n`: `0.5 - 0.5 cos(2 pi i / n)`.
fn hann(n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).cos())
        .collect()
}

/// A whole image's zero-mean luminance under a 2D Hann window (see module docs).
pub fn windowed_signal(img: &Image) -> Vec<f64> {
    let y = luminance(img);
    let mean = y.iter().sum::<f64>() / y.len().max(1) as f64;
    let (wy, wx) = (hann(img.height), hann(img.width));
    y.iter()
        .enumerate()
        .map(|(i, v)| (v - mean) * wy[i / img.width] * wx[i % img.width])
        .collect()
}

/// `|FFT2(s)|^2` of a row-major `h x w` signal.
pub fn power_2d(s: &[f64], w: usize, h: usize) -> Vec<f64> {
    assert_eq!(s.len(), w * h, "power_2d: size");
    let mut planner = FftPlanner::<f64>::new();
    let (fw, fh) = (planner.plan_fft_forward(w), planner.plan_fft_forward(h));
    let mut buf: Vec<Complex64> = s.iter().map(|&v| Complex64::new(v, 0.0)).collect();
    for row in buf.chunks_exact_mut(w) {
        fw.process(row);
    }
    let mut col = vec![Complex64::default(); h];
    for x in 0..w {
        for y in 0..h {
            col[y] = buf[y * w + x];
        }
        fh.process(&mut col);
        for y in 0..h {
            buf[y * w + x] = col[y];
        }
    }
    buf.iter().map(|c| c.norm_sqr()).collect()
}

/// Signed frequency of index `k` of an `n`-point DFT (numpy's `fftfreq`), cycles/sample.
fn freq(k: usize, n: usize) -> f64 {
    let k = k as i64;
    let n = n as i64;
    let s = if k < (n + 1) / 2 { k } else { k - n };
    s as f64 / n as f64
}

/// The normalised radially averaged power spectrum of a signal (see module docs).
pub fn radial_spectrum(s: &[f64], w: usize, h: usize) -> Vec<Option<f64>> {
    let p = power_2d(s, w, h);
    let mut sum = [0.0f64; BINS];
    let mut cnt = [0usize; BINS];
    let (mut total, mut n) = (0.0, 0usize);
    for ky in 0..h {
        let fy = freq(ky, h);
        for kx in 0..w {
            if kx == 0 && ky == 0 {
                continue;
            }
            let v = p[ky * w + kx];
            total += v;
            n += 1;
            if let Some(b) = band_of(fy.hypot(freq(kx, w))) {
                sum[b] += v;
                cnt[b] += 1;
            }
        }
    }
    let norm = if n > 0 && total > 0.0 {
        total / n as f64
    } else {
        return vec![None; BINS];
    };
    (0..BINS)
        .map(|b| (cnt[b] > 0).then(|| sum[b] / cnt[b] as f64 / norm))
        .collect()
}

/// Normalised band power below this counts as this (no power: 8 decades below the mean),
/// so a band that is numerically empty does not dominate a log distance.
pub const POWER_FLOOR: f64 = 1e-8;

/// RMS difference of the log10 spectra (each band floored at [`POWER_FLOOR`]) over the
/// bands both have; `None` if they share none.
pub fn distance(a: &[Option<f64>], b: &[Option<f64>]) -> Option<f64> {
    let d: Vec<f64> = a
        .iter()
        .zip(b)
        .filter_map(|(x, y)| match (x, y) {
            (Some(x), Some(y)) => Some(x.max(POWER_FLOOR).log10() - y.max(POWER_FLOOR).log10()),
            _ => None,
        })
        .collect();
    (!d.is_empty()).then(|| (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt())
}

/// The band with the most energy per band (see module docs): its centre in cycles per
/// pixel, or `None` for an empty spectrum.
pub fn peak(s: &[Option<f64>]) -> Option<f64> {
    let mut best: Option<(usize, f64)> = None;
    for (b, v) in s.iter().enumerate() {
        if let Some(v) = v {
            let e = v * (band_edge(b + 1).powi(2) - band_edge(b).powi(2));
            if best.is_none_or(|(_, m)| e > m) {
                best = Some((b, e));
            }
        }
    }
    best.map(|(b, _)| band_centre(b))
}

/// The mean of several spectra band by band (bands missing from every one stay `None`).
pub fn mean_spectrum(spectra: &[Vec<Option<f64>>]) -> Vec<Option<f64>> {
    (0..spectra.first().map_or(BINS, |s| s.len()))
        .map(|b| {
            let v: Vec<f64> = spectra.iter().filter_map(|s| s[b]).collect();
            (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn stripes(w: usize, h: usize, period: f64, angle: f64) -> Image {
        let (c, s) = (angle.cos(), angle.sin());
        Image::from_fn(w, h, |x, y| {
            let t = (x as f64 * c + y as f64 * s) / period;
            let v = (0.5 + 0.4 * (2.0 * std::f64::consts::PI * t).sin()) as f32;
            [v, v, v]
        })
    }

    #[test]
    fn bands_cover_six_octaves() {
        assert!((band_edge(0) - F_MIN).abs() < 1e-15);
        assert!((band_edge(BINS) - F_MAX).abs() < 1e-12);
        assert_eq!(band_of(F_MIN), Some(0));
        assert_eq!(band_of(0.5), Some(BINS - 1));
        assert_eq!(band_of(0.0), None);
        assert_eq!(band_of(0.7), None);
        for b in 0..BINS {
            assert_eq!(band_of(band_centre(b)), Some(b));
        }
    }

    /// Stripes of period p (vertical, horizontal, diagonal; two image sizes) peak in the
    /// band that holds 1/p, on the style path and on the object path.
    #[test]
    fn stripes_peak_at_their_frequency() {
        for (w, h) in [(128, 128), (256, 192)] {
            for period in [5.0, 10.0, 20.0, 40.0] {
                for angle in [0.0, std::f64::consts::FRAC_PI_2, 0.6] {
                    let img = stripes(w, h, period, angle);
                    let want = band_of(1.0 / period).unwrap();
                    // Exact where a band is wider than the window's main lobe, else
                    // within one band (see module docs, "Resolution").
                    let tol = if 1.0 / period > 10.0 / w.min(h) as f64 {
                        0
                    } else {
                        1
                    };
                    let s = radial_spectrum(&windowed_signal(&img), w, h);
                    let got = band_of(peak(&s).unwrap()).unwrap();
                    assert!(
                        got.abs_diff(want) <= tol,
                        "{w}x{h} period {period} angle {angle}: band {got}, want {want}"
                    );
                    // The same stripes on a disc-shaped object over black.
                    let alpha: Vec<f32> = (0..w * h)
                        .map(|i| {
                            let (x, y) = ((i % w) as f64, (i / w) as f64);
                            let r = ((x - w as f64 / 2.0).hypot(y - h as f64 / 2.0)
                                - 0.4 * h as f64)
                                .clamp(-1.0, 1.0);
                            (0.5 - 0.5 * r) as f32
                        })
                        .collect();
                    let mut obj = img.clone();
                    for (p, &a) in obj.data.chunks_exact_mut(3).zip(&alpha) {
                        p.iter_mut().for_each(|v| *v *= a);
                    }
                    let so = object_signal(&obj, &alpha).unwrap();
                    let got = band_of(peak(&radial_spectrum(&so, w, h)).unwrap()).unwrap();
                    assert!(
                        got.abs_diff(want) <= tol,
                        "object {w}x{h} period {period} angle {angle}: band {got}, want {want}"
                    );
                }
            }
        }
    }

    /// The object signal ignores the background's colour and the object's mean: the
    /// same texture over black, over grey, and brightened by a constant gives the same
    /// signal.
    #[test]
    fn object_signal_removes_background_and_mean() {
        let (w, h) = (32, 24);
        let tex = stripes(w, h, 6.0, 0.3);
        let alpha: Vec<f32> = (0..w * h)
            .map(|i| if (4..20).contains(&(i % w)) { 1.0 } else { 0.0 })
            .collect();
        let comp = |bg: f32, lift: f32| {
            let mut d = tex.data.clone();
            for (p, &a) in d.chunks_exact_mut(3).zip(&alpha) {
                p.iter_mut()
                    .for_each(|v| *v = a * (*v + lift) + (1.0 - a) * bg);
            }
            object_signal(
                &Image {
                    width: w,
                    height: h,
                    data: d,
                },
                &alpha,
            )
            .unwrap()
        };
        let a = comp(0.0, 0.0);
        for (bg, lift) in [(0.5, 0.0), (0.0, 0.2), (0.3, 0.1)] {
            let b = comp(bg, lift);
            let m = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0, f64::max);
            assert!(m < 1e-6, "bg {bg} lift {lift}: {m}");
        }
        assert!(object_signal(&tex, &vec![0.0; w * h]).is_none());
    }

    #[test]
    fn distance_is_rms_of_log_ratios() {
        let a = vec![Some(1.0), Some(10.0), None, Some(0.0)];
        let b = vec![Some(10.0), Some(10.0), Some(3.0), Some(1.0)];
        // bands 0, 1, 3: 1, 0 and 8 decades (0 is floored at 1e-8) -> sqrt(65/3)
        assert!((distance(&a, &b).unwrap() - (65.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(distance(&a, &a), Some(0.0));
        assert_eq!(distance(&[None], &[Some(1.0)]), None);
        let m = mean_spectrum(&[a.clone(), b.clone()]);
        assert_eq!(m, vec![Some(5.5), Some(10.0), Some(3.0), Some(0.5)]);
    }

    fn golden_dir() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/golden/spectrum")
    }

    fn load(name: &str) -> (Vec<usize>, Vec<f64>) {
        let a = fantasystyle_schemas::read_npy_f32(&golden_dir().join(name)).unwrap();
        (
            a.shape.clone(),
            a.data.iter().map(|&v| v as f64).collect::<Vec<_>>(),
        )
    }

    /// Against `scripts/reference/spectrum_ref.py` (numpy, float64; inputs stored as
    /// float32; an empty band stored as -1): both signal paths, odd and even sizes;
    /// spectra to 1e-4 relative (the float32 golden), distances and peaks to 1e-4.
    /// Committed bytes, on purpose: float64 numpy of the formulas (no network), the same
    /// on every CPU to float64 rounding, far below the tolerances.
    #[test]
    fn matches_numpy_golden() {
        let cases: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(golden_dir().join("cases.json")).unwrap(),
        )
        .unwrap();
        let cases = cases.as_array().unwrap();
        assert!(cases.len() >= 3);
        for c in cases {
            let name = c["name"].as_str().unwrap();
            let (shape, rgb) = load(&format!("{name}_rgb.npy"));
            let (h, w) = (shape[0], shape[1]);
            let img = Image {
                width: w,
                height: h,
                data: rgb.iter().map(|&v| v as f32).collect(),
            };
            let sig = if c["kind"] == "object" {
                let (_, alpha) = load(&format!("{name}_alpha.npy"));
                let alpha: Vec<f32> = alpha.iter().map(|&v| v as f32).collect();
                object_signal(&img, &alpha).unwrap()
            } else {
                windowed_signal(&img)
            };
            let got = radial_spectrum(&sig, w, h);
            let (_, want) = load(&format!("{name}_spectrum.npy"));
            for b in 0..BINS {
                match got[b] {
                    None => assert!(want[b] < 0.0, "{name} band {b}: None vs {}", want[b]),
                    Some(g) => {
                        let e = (g - want[b]).abs() / want[b].abs().max(1e-6);
                        assert!(e < 1e-4, "{name} band {b}: {g} vs {}", want[b]);
                    }
                }
            }
            let pk = peak(&got).unwrap();
            assert!(
                (pk - c["peak"].as_f64().unwrap()).abs() < 1e-9,
                "{name}: peak {pk} vs {}",
                c["peak"]
            );
            if let Some(other) = c["distance_to"].as_str() {
                let (_, ws) = load(&format!("{other}_spectrum.npy"));
                let os: Vec<Option<f64>> = ws.iter().map(|&v| (v >= 0.0).then_some(v)).collect();
                let d = distance(&got, &os).unwrap();
                let want = c["distance"].as_f64().unwrap();
                assert!((d - want).abs() < 1e-4, "{name}: distance {d} vs {want}");
            }
        }
    }
}

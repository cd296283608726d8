//! `pipeline inspect`: what is inside an artifact (or a lone `.npy`), and pictures of
//! its tensors.
//!
//! Text: the manifest, then per tensor its shape, dtype, min, max, mean, std (over the
//! finite elements) and NaN/Inf counts. PNG: latents `[N,C,h,w]` as a grid of views
//! (rows) by channels (columns), each channel normalised to its min..max over all
//! views, or (`rgb` mode) the first three channels as colour, each normalised the same
//! way; images `[N,H,W,3]` as a row (values as 0..1, clipped; min..max when the values
//! are clearly in another range);
//! `[N,H,W]` (depth, alpha) as a grey row.

use crate::error::{Error, Result};
use fantasystyle_schemas::npy::parse_header;
use fantasystyle_schemas::{Artifact, DType};
use image::{Rgb, RgbImage};
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// Statistics of one tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct Stats {
    pub name: String,
    pub shape: Vec<usize>,
    pub dtype: DType,
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub std: f64,
    pub nan: usize,
    pub inf: usize,
}

/// A tensor as f64 values.
#[derive(Debug, Clone)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub dtype: DType,
    pub data: Vec<f64>,
}

/// Read any supported `.npy` as f64.
pub fn read_any(path: &Path) -> Result<Tensor> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let (dtype, shape, off) = parse_header(path, &bytes)?;
    let n: usize = shape.iter().product();
    let body = &bytes[off..];
    if body.len() != n * dtype.size() {
        return Err(Error::Inspect(format!(
            "{}: shape {shape:?} needs {} data bytes, file has {}",
            path.display(),
            n * dtype.size(),
            body.len()
        )));
    }
    let c = body.chunks_exact(dtype.size());
    let data: Vec<f64> = match dtype {
        DType::F32 => c
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()) as f64)
            .collect(),
        DType::F64 => c
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect(),
        DType::U8 => body.iter().map(|&b| b as f64).collect(),
        DType::I32 => c
            .map(|b| i32::from_le_bytes(b.try_into().unwrap()) as f64)
            .collect(),
        DType::U32 => c
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()) as f64)
            .collect(),
        DType::I64 => c
            .map(|b| i64::from_le_bytes(b.try_into().unwrap()) as f64)
            .collect(),
    };
    Ok(Tensor { shape, dtype, data })
}

/// Statistics over the finite elements; NaN and infinities are counted apart.
pub fn stats(name: &str, t: &Tensor) -> Stats {
    let (mut nan, mut inf, mut n) = (0usize, 0usize, 0usize);
    let (mut min, mut max, mut sum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
    for &v in &t.data {
        if v.is_nan() {
            nan += 1;
        } else if v.is_infinite() {
            inf += 1;
        } else {
            n += 1;
            min = min.min(v);
            max = max.max(v);
            sum += v;
        }
    }
    let mean = if n > 0 { sum / n as f64 } else { f64::NAN };
    let var = if n > 0 {
        t.data
            .iter()
            .filter(|v| v.is_finite())
            .map(|v| (v - mean) * (v - mean))
            .sum::<f64>()
            / n as f64
    } else {
        f64::NAN
    };
    if n == 0 {
        (min, max) = (f64::NAN, f64::NAN);
    }
    Stats {
        name: name.to_string(),
        shape: t.shape.clone(),
        dtype: t.dtype,
        min,
        max,
        mean,
        std: var.sqrt(),
        nan,
        inf,
    }
}

/// How latents are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LatentMode {
    /// Views (rows) by channels (columns), each channel normalised.
    Grid,
    /// The first three channels as red, green, blue, each normalised; one view per column.
    Rgb,
}

/// The text report for `path` (an artifact directory or a `.npy` file), the tensors
/// found (name, path), and a verification warning if the hashes did not check out.
pub fn inspect(path: &Path) -> Result<(String, Vec<(String, PathBuf)>)> {
    let mut out = String::new();
    let mut tensors = Vec::new();
    if path.is_dir() {
        describe_artifact(path, &mut out, &mut tensors)?;
    } else if path.is_file() {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        tensors.push((name, path.to_path_buf()));
    } else {
        return Err(Error::Inspect(format!(
            "{}: no such file or directory",
            path.display()
        )));
    }
    if !tensors.is_empty() {
        let _ = writeln!(
            out,
            "{:<14} {:<18} {:<5} {:>11} {:>11} {:>11} {:>11} {:>5} {:>5}",
            "tensor", "shape", "dtype", "min", "max", "mean", "std", "nan", "inf"
        );
    }
    for (name, p) in &tensors {
        let t = read_any(p)?;
        let s = stats(name, &t);
        let _ = writeln!(
            out,
            "{:<14} {:<18} {:<5} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>5} {:>5}",
            s.name,
            format!("{:?}", s.shape),
            s.dtype.to_string(),
            s.min,
            s.max,
            s.mean,
            s.std,
            s.nan,
            s.inf
        );
    }
    Ok((out, tensors))
}

/// The manifest of the artifact at `path` written to `out` (with a warning when its
/// hashes do not check out), its tensors added to `tensors`.
fn describe_artifact(
    path: &Path,
    out: &mut String,
    tensors: &mut Vec<(String, PathBuf)>,
) -> Result<()> {
    let art = match Artifact::open_any(path) {
        Ok(a) => a,
        Err(e) => {
            let _ = writeln!(out, "WARNING: {e}");
            Artifact::open_unverified(path)?
        }
    };
    let m = &art.manifest;
    let _ = writeln!(out, "artifact  {}", path.display());
    let _ = writeln!(
        out,
        "kind      {} (schema version {})",
        m.kind, m.schema_version
    );
    let _ = writeln!(
        out,
        "producer  {} {} params {}",
        m.producer.stage,
        m.producer.version,
        fantasystyle_schemas::manifest::canonical_json(&m.producer.params)
    );
    for i in &m.inputs {
        let _ = writeln!(
            out,
            "input     {:<10} {} ({})",
            i.role,
            i.path,
            &i.blake3[..i.blake3.len().min(12)]
        );
    }
    if !m.meta.is_null() {
        let _ = writeln!(out, "meta      {}", m.meta);
    }
    if m.kind == fantasystyle_schemas::ArtifactKind::Selection {
        describe_selection(&art, out)?;
    }
    for f in &m.files {
        if f.name.ends_with(".npy") {
            tensors.push((f.name.clone(), art.path(&f.name)));
        } else {
            let _ = writeln!(out, "file      {} ({} bytes)", f.name, f.bytes);
        }
    }
    Ok(())
}

/// A selection's summary: how many Gaussians are selected (weight > 0) and fully (1),
/// from `weights.npy`, and the bounds of their centres, from the meta `select` writes.
fn describe_selection(art: &Artifact, out: &mut String) -> Result<()> {
    let t = read_any(&art.path("weights.npy"))?;
    let n = t.data.len();
    let some = t.data.iter().filter(|&&w| w > 0.0).count();
    let full = t.data.iter().filter(|&&w| w >= 1.0).count();
    let _ = writeln!(
        out,
        "selected  {some} of {n} Gaussians ({full} with weight 1)"
    );
    let b = &art.manifest.meta["bounds"];
    if b.is_object() {
        let _ = writeln!(out, "bounds    min {} max {}", b["min"], b["max"]);
    }
    Ok(())
}

/// Pick the tensor to draw: `want`, else the first of latents, z_tgt, rgb, else the
/// first tensor of rank 2 to 4.
pub fn pick(tensors: &[(String, PathBuf)], want: Option<&str>) -> Result<PathBuf> {
    if let Some(w) = want {
        return tensors
            .iter()
            .find(|(n, _)| n == w || n.trim_end_matches(".npy") == w)
            .map(|(_, p)| p.clone())
            .ok_or_else(|| Error::Inspect(format!("no tensor named `{w}`")));
    }
    for pref in ["latents.npy", "z_tgt.npy", "rgb.npy"] {
        if let Some((_, p)) = tensors.iter().find(|(n, _)| n == pref) {
            return Ok(p.clone());
        }
    }
    tensors
        .first()
        .map(|(_, p)| p.clone())
        .ok_or_else(|| Error::Inspect("no tensor to draw".into()))
}

/// Draw a tensor (see the module docs).
pub fn draw(t: &Tensor, mode: LatentMode) -> Result<RgbImage> {
    let s = &t.shape;
    match s.len() {
        4 if s[3] == 3 => Ok(draw_images(t, (s[0], s[1], s[2]))),
        4 => draw_latents(t, (s[0], s[1], s[2], s[3]), mode),
        2 | 3 => {
            let (n, h, w) = if s.len() == 3 {
                (s[0], s[1], s[2])
            } else {
                (1, s[0], s[1])
            };
            Ok(draw_planes(t, (n, h, w)))
        }
        _ => Err(Error::Inspect(format!(
            "cannot draw a tensor of shape {s:?} (rank 2 to 4 only)"
        ))),
    }
}

/// Gap between drawn panels, pixels.
const GAP: u32 = 2;

/// Images `[N, H, W, 3]` in a row: 0..1 (clipped); clearly other ranges (e.g. -1..1 or
/// 0..255) normalised to their min..max.
fn draw_images(t: &Tensor, (n, h, w): (usize, usize, usize)) -> RgbImage {
    let (lo, hi) = finite_range(&t.data);
    let (lo, hi) = if lo >= -0.5 && hi <= 2.0 {
        (0.0, 1.0)
    } else {
        (lo, hi)
    };
    let mut img = canvas(n as u32 * (w as u32 + GAP), h as u32);
    for v in 0..n {
        for y in 0..h {
            for x in 0..w {
                let b = ((v * h + y) * w + x) * 3;
                let px = [0, 1, 2].map(|c| to_u8(t.data[b + c], lo, hi));
                img.put_pixel(v as u32 * (w as u32 + GAP) + x as u32, y as u32, Rgb(px));
            }
        }
    }
    img
}

/// Planes `[N, H, W]` in a row, grey, normalised to their min..max.
fn draw_planes(t: &Tensor, (n, h, w): (usize, usize, usize)) -> RgbImage {
    let (lo, hi) = finite_range(&t.data);
    let mut img = canvas(n as u32 * (w as u32 + GAP), h as u32);
    for v in 0..n {
        for y in 0..h {
            for x in 0..w {
                let g = to_u8(t.data[(v * h + y) * w + x], lo, hi);
                img.put_pixel(
                    v as u32 * (w as u32 + GAP) + x as u32,
                    y as u32,
                    Rgb([g, g, g]),
                );
            }
        }
    }
    img
}

/// Latents `[N, C, h, w]`, enlarged to at least 64 px tall, each channel normalised
/// over all views: views by channels (grid), or the first three channels as colour.
fn draw_latents(
    t: &Tensor,
    (n, c, h, w): (usize, usize, usize, usize),
    mode: LatentMode,
) -> Result<RgbImage> {
    let plane = h * w;
    let ranges: Vec<(f64, f64)> = (0..c)
        .map(|ch| {
            finite_range(
                &(0..n)
                    .flat_map(|v| {
                        t.data[(v * c + ch) * plane..(v * c + ch + 1) * plane]
                            .iter()
                            .copied()
                    })
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    let k = 64usize.div_ceil(h.max(1)).max(1) as u32;
    let (cw, chh) = (w as u32 * k, h as u32 * k);
    let at = |v: usize, ch: usize, x: u32, y: u32| {
        t.data[(v * c + ch) * plane + (y / k) as usize * w + (x / k) as usize]
    };
    match mode {
        LatentMode::Grid => {
            let mut img = canvas(c as u32 * (cw + GAP), n as u32 * (chh + GAP));
            for v in 0..n {
                for (ch, &(lo, hi)) in ranges.iter().enumerate() {
                    for y in 0..chh {
                        for x in 0..cw {
                            let g = to_u8(at(v, ch, x, y), lo, hi);
                            let (px, py) = (ch as u32 * (cw + GAP) + x, v as u32 * (chh + GAP) + y);
                            img.put_pixel(px, py, Rgb([g, g, g]));
                        }
                    }
                }
            }
            Ok(img)
        }
        LatentMode::Rgb => {
            if c < 3 {
                return Err(Error::Inspect(format!(
                    "rgb mode needs at least 3 channels, the tensor has {c}"
                )));
            }
            let mut img = canvas(n as u32 * (cw + GAP), chh);
            for v in 0..n {
                for y in 0..chh {
                    for x in 0..cw {
                        let px =
                            [0, 1, 2].map(|ch| to_u8(at(v, ch, x, y), ranges[ch].0, ranges[ch].1));
                        img.put_pixel(v as u32 * (cw + GAP) + x, y, Rgb(px));
                    }
                }
            }
            Ok(img)
        }
    }
}

/// Encode as PNG and write atomically.
pub fn save_png(img: &RgbImage, out: &Path) -> Result<()> {
    let mut buf = std::io::Cursor::new(Vec::new());
    img.write_to(&mut buf, image::ImageFormat::Png)
        .map_err(|e| Error::Inspect(format!("{}: {e}", out.display())))?;
    Ok(fantasystyle_schemas::atomic_write(out, buf.get_ref())?)
}

fn canvas(w: u32, h: u32) -> RgbImage {
    RgbImage::from_pixel(w.max(1), h.max(1), Rgb([40, 40, 40]))
}

fn finite_range(d: &[f64]) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &v in d.iter().filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi { (0.0, 1.0) } else { (lo, hi) }
}

/// Map `v` from lo..hi to 0..255; NaN is drawn black, infinities clamp.
fn to_u8(v: f64, lo: f64, hi: f64) -> u8 {
    if v.is_nan() {
        return 0;
    }
    let x = if hi > lo { (v - lo) / (hi - lo) } else { 0.5 };
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};

    #[test]
    fn stats_match_a_hand_computation_and_count_nan_inf() {
        let t = Tensor {
            shape: vec![6],
            dtype: DType::F32,
            data: vec![1.0, 2.0, 3.0, 4.0, f64::NAN, f64::INFINITY],
        };
        let s = stats("x", &t);
        assert_eq!((s.min, s.max, s.mean, s.nan, s.inf), (1.0, 4.0, 2.5, 1, 1));
        assert!((s.std - 1.25f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn inspect_artifact_and_draw_latents_both_ways() {
        let d = tempfile::tempdir().unwrap();
        let t = d.path().join("lat");
        let mut w = ArtifactWriter::create(
            &t,
            ArtifactKind::Latents,
            Producer::new("s", "1", serde_json::json!({})),
        )
        .unwrap();
        let data: Vec<f32> = (0..2 * 4 * 8 * 8).map(|i| i as f32).collect();
        w.write_tensor("latents.npy", &[2, 4, 8, 8], &data).unwrap();
        w.commit().unwrap();
        let (text, tensors) = inspect(&t).unwrap();
        assert!(
            text.contains("kind      latents") && text.contains("[2, 4, 8, 8]"),
            "{text}"
        );
        let tensor = read_any(&pick(&tensors, None).unwrap()).unwrap();
        assert_eq!(tensor.data[511], 511.0);
        let g = draw(&tensor, LatentMode::Grid).unwrap();
        assert_eq!((g.width(), g.height()), (4 * (64 + 2), 2 * (64 + 2)));
        // Each channel is normalised over views: the first pixel of channel 0, view 0 is black,
        // the last pixel of channel 0, view 1 is white.
        assert_eq!(g.get_pixel(0, 0).0, [0, 0, 0]);
        assert_eq!(g.get_pixel(63, 66 + 63).0, [255, 255, 255]);
        let c = draw(&tensor, LatentMode::Rgb).unwrap();
        assert_eq!((c.width(), c.height()), (2 * 66, 64));
        let out = d.path().join("g.png");
        save_png(&g, &out).unwrap();
        assert!(image::open(&out).is_ok());
        // Images [N,H,W,3] as a row.
        let img = Tensor {
            shape: vec![2, 3, 5, 3],
            dtype: DType::F32,
            data: vec![0.5; 90],
        };
        let r = draw(&img, LatentMode::Grid).unwrap();
        assert_eq!((r.width(), r.height()), (2 * 7, 3));
        assert_eq!(r.get_pixel(0, 0).0, [128, 128, 128]);
        assert!(
            draw(
                &Tensor {
                    shape: vec![5],
                    dtype: DType::F32,
                    data: vec![0.0; 5]
                },
                LatentMode::Grid
            )
            .is_err()
        );
    }
}

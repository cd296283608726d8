//! COLMAP sparse models (`sparse/0`): `cameras.{txt,bin}` and `images.{txt,bin}`
//! (format as documented at colmap.github.io/format.html and written by COLMAP's
//! `Reconstruction::Write{Text,Binary}`).
//!
//! * `cameras.txt`: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`; `cameras.bin`: u64 count,
//!   then per camera i32 id, i32 model id, u64 width, u64 height, f64 params.
//! * `images.txt`: per image two lines, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` and
//!   the 2D points (ignored, possibly empty); `images.bin`: u64 count, then per image
//!   i32 id, f64 `qvec[4]`, f64 `tvec[3]`, i32 camera id, NUL-terminated name, u64 point
//!   count, 24 bytes per point.
//!
//! `qvec` (w, x, y, z) and `tvec` are world-to-camera, OpenCV axes: exactly [`Camera`]'s
//! convention. Camera models: `SIMPLE_PINHOLE` (f, cx, cy), `PINHOLE` (fx, fy, cx, cy),
//! and, with their distortion ignored (a warning is logged), `SIMPLE_RADIAL`,
//! `RADIAL` (f, cx, cy, k..) and `OPENCV` (fx, fy, cx, cy, k1, k2, p1, p2). Other models
//! are refused when an image uses them. Cameras are returned sorted by image name (as the
//! INRIA loader does). When both binary and text files exist the binary ones are read.

use super::Camera;
use crate::geometry::{mat_to_quat, mat3, quat_to_mat, rows};
use crate::{Error, Result};
use std::collections::BTreeMap;
use std::path::Path;

/// Model names by COLMAP model id, with their parameter counts.
const MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// An intrinsics record as stored.
#[derive(Debug, Clone)]
struct Intr {
    model: String,
    width: u64,
    height: u64,
    params: Vec<f64>,
}

impl Intr {
    /// (fx, fy, cx, cy), or why not.
    fn pinhole(&self) -> std::result::Result<[f64; 4], String> {
        let p = &self.params;
        let need = MODELS
            .iter()
            .find(|(m, _)| *m == self.model)
            .map(|(_, n)| *n);
        if need.is_some_and(|n| p.len() != n) {
            return Err(format!(
                "model {} needs {} parameters, found {}",
                self.model,
                need.unwrap_or(0),
                p.len()
            ));
        }
        match self.model.as_str() {
            "SIMPLE_PINHOLE" => Ok([p[0], p[0], p[1], p[2]]),
            "PINHOLE" => Ok([p[0], p[1], p[2], p[3]]),
            "SIMPLE_RADIAL" | "RADIAL" => {
                tracing::warn!("COLMAP {} camera: radial distortion ignored", self.model);
                Ok([p[0], p[0], p[1], p[2]])
            }
            "OPENCV" => {
                tracing::warn!("COLMAP OPENCV camera: distortion ignored");
                Ok([p[0], p[1], p[2], p[3]])
            }
            m => Err(format!(
                "unsupported camera model {m} (supported: SIMPLE_PINHOLE, PINHOLE, \
                 SIMPLE_RADIAL, RADIAL, OPENCV; undistort the images first)"
            )),
        }
    }
}

/// One registered image.
#[derive(Debug, Clone)]
struct Image {
    name: String,
    q: [f64; 4],
    t: [f64; 3],
    camera_id: i64,
}

/// Read a COLMAP sparse model directory (binary preferred over text).
pub fn read_colmap(dir: &Path) -> Result<Vec<Camera>> {
    let (cams_path, imgs_path, binary) = if dir.join("cameras.bin").is_file()
        && dir.join("images.bin").is_file()
    {
        (dir.join("cameras.bin"), dir.join("images.bin"), true)
    } else if dir.join("cameras.txt").is_file() && dir.join("images.txt").is_file() {
        (dir.join("cameras.txt"), dir.join("images.txt"), false)
    } else {
        return Err(Error::input(
            dir,
            "not a COLMAP sparse model (needs cameras.bin + images.bin or cameras.txt + images.txt)",
        ));
    };
    let read = |p: &Path| std::fs::read(p).map_err(|e| Error::io(p, e));
    let (intr, images) = if binary {
        (
            parse_cameras_bin(&cams_path, &read(&cams_path)?)?,
            parse_images_bin(&imgs_path, &read(&imgs_path)?)?,
        )
    } else {
        let text =
            |p: &Path| String::from_utf8(read(p)?).map_err(|_| Error::input(p, "not UTF-8 text"));
        (
            parse_cameras_txt(&cams_path, &text(&cams_path)?)?,
            parse_images_txt(&imgs_path, &text(&imgs_path)?)?,
        )
    };
    assemble(&cams_path, &imgs_path, &intr, images)
}

fn assemble(
    cams_path: &Path,
    imgs_path: &Path,
    intr: &BTreeMap<i64, Intr>,
    mut images: Vec<Image>,
) -> Result<Vec<Camera>> {
    if images.is_empty() {
        return Err(Error::input(imgs_path, "no registered images"));
    }
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut out = Vec::with_capacity(images.len());
    for im in images {
        let ci = intr.get(&im.camera_id).ok_or_else(|| {
            Error::input(
                imgs_path,
                format!(
                    "image `{}` uses camera {}, which cameras file lacks",
                    im.name, im.camera_id
                ),
            )
        })?;
        let k = ci.pinhole().map_err(|r| {
            Error::input(
                cams_path,
                format!("camera {} (image `{}`): {r}", im.camera_id, im.name),
            )
        })?;
        let (w, h) = (u32::try_from(ci.width), u32::try_from(ci.height));
        let (Ok(w), Ok(h)) = (w, h) else {
            return Err(Error::input(
                cams_path,
                format!(
                    "camera {}: image size {}x{} out of range",
                    im.camera_id, ci.width, ci.height
                ),
            ));
        };
        let r = quat_to_mat(im.q).map(rows).ok_or_else(|| {
            Error::input(
                imgs_path,
                format!(
                    "image `{}`: quaternion {:?} is zero or not finite",
                    im.name, im.q
                ),
            )
        })?;
        let cam = Camera::from_w2c(im.name, w, h, k, r, im.t);
        cam.validate(imgs_path)?;
        out.push(cam);
    }
    Ok(out)
}

fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

fn num<T: std::str::FromStr>(path: &Path, line: usize, what: &str, s: &str) -> Result<T> {
    s.parse()
        .map_err(|_| Error::input(path, format!("line {line}: {what} `{s}` is not a number")))
}

fn parse_cameras_txt(path: &Path, text: &str) -> Result<BTreeMap<i64, Intr>> {
    let mut out = BTreeMap::new();
    for (ln, l) in data_lines(text) {
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 4 {
            return Err(Error::input(
                path,
                format!("line {ln}: expected `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...`"),
            ));
        }
        let params = t[4..]
            .iter()
            .map(|p| num::<f64>(path, ln, "parameter", p))
            .collect::<Result<Vec<_>>>()?;
        out.insert(
            num(path, ln, "camera id", t[0])?,
            Intr {
                model: t[1].to_string(),
                width: num(path, ln, "width", t[2])?,
                height: num(path, ln, "height", t[3])?,
                params,
            },
        );
    }
    Ok(out)
}

fn parse_images_txt(path: &Path, text: &str) -> Result<Vec<Image>> {
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate();
    while let Some((i, l)) = lines.next() {
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let ln = i + 1;
        let t: Vec<&str> = l.split_whitespace().collect();
        if t.len() < 10 {
            return Err(Error::input(
                path,
                format!(
                    "line {ln}: expected `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, found {} fields",
                    t.len()
                ),
            ));
        }
        let f = |k: usize, what: &str| num::<f64>(path, ln, what, t[k]);
        out.push(Image {
            q: [f(1, "qw")?, f(2, "qx")?, f(3, "qy")?, f(4, "qz")?],
            t: [f(5, "tx")?, f(6, "ty")?, f(7, "tz")?],
            camera_id: num(path, ln, "camera id", t[8])?,
            name: t[9..].join(" "),
        });
        lines.next(); // the 2D points line (possibly empty)
    }
    Ok(out)
}

/// A little-endian cursor whose reads fail with "truncated" naming the file.
struct Cursor<'a> {
    path: &'a Path,
    b: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let end = self.at.checked_add(n).filter(|e| *e <= self.b.len());
        let Some(end) = end else {
            return Err(Error::input(
                self.path,
                format!(
                    "truncated: file ends while reading {what} at byte {}",
                    self.at
                ),
            ));
        };
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        let s = self.take(8, what)?;
        Ok(u64::from_le_bytes(s.try_into().unwrap_or([0; 8])))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        let s = self.take(4, what)?;
        Ok(i32::from_le_bytes(s.try_into().unwrap_or([0; 4])))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        let s = self.take(8, what)?;
        Ok(f64::from_le_bytes(s.try_into().unwrap_or([0; 8])))
    }
    fn trailing(&self) -> Result<()> {
        if self.at != self.b.len() {
            return Err(Error::input(
                self.path,
                format!(
                    "{} bytes of trailing data (the count lies?)",
                    self.b.len() - self.at
                ),
            ));
        }
        Ok(())
    }
}

fn parse_cameras_bin(path: &Path, b: &[u8]) -> Result<BTreeMap<i64, Intr>> {
    let mut c = Cursor { path, b, at: 0 };
    let n = c.u64("the camera count")?;
    let mut out = BTreeMap::new();
    for i in 0..n {
        let what = format!("camera {i}");
        let id = c.i32(&what)?;
        let model_id = c.i32(&what)?;
        let (model, np) = usize::try_from(model_id)
            .ok()
            .and_then(|m| MODELS.get(m))
            .ok_or_else(|| {
                Error::input(path, format!("camera {id}: unknown model id {model_id}"))
            })?;
        let width = c.u64(&what)?;
        let height = c.u64(&what)?;
        let params = (0..*np).map(|_| c.f64(&what)).collect::<Result<Vec<_>>>()?;
        out.insert(
            id as i64,
            Intr {
                model: model.to_string(),
                width,
                height,
                params,
            },
        );
    }
    c.trailing()?;
    Ok(out)
}

fn parse_images_bin(path: &Path, b: &[u8]) -> Result<Vec<Image>> {
    let mut c = Cursor { path, b, at: 0 };
    let n = c.u64("the image count")?;
    let mut out = Vec::new();
    for i in 0..n {
        let what = format!("image {i}");
        let _id = c.i32(&what)?;
        let mut q = [0.0; 4];
        for v in &mut q {
            *v = c.f64(&what)?;
        }
        let mut t = [0.0; 3];
        for v in &mut t {
            *v = c.f64(&what)?;
        }
        let camera_id = c.i32(&what)? as i64;
        let rest = &b[c.at..];
        let len = rest.iter().position(|&x| x == 0).ok_or_else(|| {
            Error::input(
                path,
                format!("truncated: {what}: name is not NUL-terminated"),
            )
        })?;
        let name = String::from_utf8_lossy(c.take(len + 1, &what)?[..len].as_ref()).into_owned();
        let np = c.u64(&what)?;
        let bytes = np
            .checked_mul(24)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| Error::input(path, format!("{what}: absurd point count {np}")))?;
        c.take(bytes, &what)?;
        out.push(Image {
            name,
            q,
            t,
            camera_id,
        });
    }
    c.trailing()?;
    Ok(out)
}

/// Write a COLMAP text model (`cameras.txt`, `images.txt`; PINHOLE, no points), for
/// fixtures and interchange.
pub fn write_colmap_txt(dir: &Path, cams: &[Camera]) -> Result<()> {
    let mut c = String::from("# CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]\n");
    let mut im = String::from("# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME\n# POINTS2D[]\n");
    for (i, cam) in cams.iter().enumerate() {
        c.push_str(&format!(
            "{} PINHOLE {} {} {} {} {} {}\n",
            i + 1,
            cam.width,
            cam.height,
            cam.fx,
            cam.fy,
            cam.cx,
            cam.cy
        ));
        let q = mat_to_quat(mat3(cam.rotation.map(|r| r.map(|v| v as f64))));
        let t = cam.translation;
        im.push_str(&format!(
            "{} {} {} {} {} {} {} {} {} {}\n\n",
            i + 1,
            q[0],
            q[1],
            q[2],
            q[3],
            t[0],
            t[1],
            t[2],
            i + 1,
            cam.name
        ));
    }
    fantasystyle_schemas::atomic_write(&dir.join("cameras.txt"), c.as_bytes())?;
    fantasystyle_schemas::atomic_write(&dir.join("images.txt"), im.as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_errors_name_file_and_line() {
        let p = Path::new("images.txt");
        let e = parse_images_txt(p, "# c\n1 1 0 0 0 0 0\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("images.txt") && e.contains("line 2"), "{e}");
        let e = parse_images_txt(p, "1 1 0 0 x 0 0 0 1 a.png\n\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("qz") && e.contains("`x`"), "{e}");
    }

    /// Fuzz-style: corrupted binary models never panic, and errors name the file.
    #[test]
    fn corrupted_binary_never_panics() {
        let mut cams = 1u64.to_le_bytes().to_vec();
        cams.extend_from_slice(&1i32.to_le_bytes());
        cams.extend_from_slice(&1i32.to_le_bytes());
        cams.extend_from_slice(&64u64.to_le_bytes());
        cams.extend_from_slice(&48u64.to_le_bytes());
        for v in [50.0f64, 50.0, 32.0, 24.0] {
            cams.extend_from_slice(&v.to_le_bytes());
        }
        let mut imgs = 1u64.to_le_bytes().to_vec();
        imgs.extend_from_slice(&1i32.to_le_bytes());
        for v in [1.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0] {
            imgs.extend_from_slice(&v.to_le_bytes());
        }
        imgs.extend_from_slice(&1i32.to_le_bytes());
        imgs.extend_from_slice(b"a.png\0");
        imgs.extend_from_slice(&1u64.to_le_bytes());
        imgs.extend_from_slice(&[0u8; 24]);
        let (pc, pi) = (Path::new("cameras.bin"), Path::new("images.bin"));
        let c = parse_cameras_bin(pc, &cams).unwrap();
        let i = parse_images_bin(pi, &imgs).unwrap();
        assemble(pc, pi, &c, i).unwrap();
        let mut rng = crate::rng::Rng::new(5);
        for _ in 0..3000 {
            let (mut c, mut i) = (cams.clone(), imgs.clone());
            for b in [&mut c, &mut i] {
                match rng.next_u64() % 3 {
                    0 => b.truncate((rng.next_u64() as usize) % (b.len() + 1)),
                    1 => {
                        let k = (rng.next_u64() as usize) % b.len();
                        b[k] = rng.next_u64() as u8;
                    }
                    _ => {}
                }
            }
            let r = std::panic::catch_unwind(|| {
                let c = parse_cameras_bin(pc, &c)?;
                let i = parse_images_bin(pi, &i)?;
                assemble(pc, pi, &c, i)
            })
            .expect("COLMAP reader panicked");
            if let Err(e) = r {
                let e = e.to_string();
                assert!(
                    e.starts_with("cameras.bin") || e.starts_with("images.bin"),
                    "{e}"
                );
            }
        }
    }

    #[test]
    fn binary_truncation_and_unknown_model() {
        let p = Path::new("cameras.bin");
        let mut b = 1u64.to_le_bytes().to_vec();
        b.extend_from_slice(&1i32.to_le_bytes());
        b.extend_from_slice(&99i32.to_le_bytes());
        let e = parse_cameras_bin(p, &b).unwrap_err().to_string();
        assert!(e.contains("unknown model id 99"), "{e}");
        let e = parse_cameras_bin(p, &b[..10]).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }
}

//! Niantic's `.spz`, the compressed splat format (github.com/nianticlabs/spz, its README's
//! "File Format"): read in versions 2 and 3, written in version 3.
//!
//! A file is one gzip stream. Decompressed, all little-endian:
//!
//! | bytes | what |
//! |---|---|
//! | 16 | header: magic `0x5053474e` ("NGSP") u32, version u32, Gaussian count N u32, SH degree u8 (0..=4), fractional bits u8, flags u8 (`0x1` antialiased, `0x2` extensions follow the header), reserved u8 |
//! | 9 N | positions: x, y, z as 24-bit signed fixed point with `fractional bits` fractional bits |
//! | N | opacity `round(255 sigmoid(logit))` |
//! | 3 N | base colour `round(255 (0.15 f_dc + 0.5))` (0.15, not the SH constant 0.2821, so colours a little outside [0, 1] fit) |
//! | 3 N | log-scales `round(16 (ln s + 10))` |
//! | 3 N / 4 N | rotation. Version 2: x, y, z of the normalised quaternion with w >= 0, `round(127.5 q + 127.5)`. Version 3 ("smallest three"): a u32 holding the index of the largest component (2 bits, order x y z w) and for each other component a sign bit and a 9-bit magnitude `round(511 abs(q) sqrt 2)`, with the largest made positive |
//! | 3 N K | SH coefficients of degree >= 1 (K = 3, 8, 15, 24 per channel), per Gaussian coefficient-major with the channel innermost (the layout of [`Scene::sh_rest`]), each `round(128 x) + 128` rounded to a multiple of 8 for degree 1 (5 bits) and of 16 above (4 bits), clamped to [0, 255] |
//!
//! Extensions (flag `0x2`) sit between the header and the positions; they are skipped
//! (with a warning: the SH-range extension changes how SH bytes decode, and SH is then
//! decoded with the default [-1, 1] range). The uncompressed NGSP container of version 4
//! is refused with a clear error, as are version 1 (float16 positions, never released),
//! truncated or trailing data and counts the data does not hold; nothing is allocated
//! from the header's count before the data is known to hold that many Gaussians.
//!
//! **Axes.** Values are stored in the scene's own axes, as the reference `ply_to_spz`
//! does by default (coordinate system "unspecified"): a `.spz` written here shows the
//! scene the way its `.ply` does in any viewer, and reading converts nothing.
//!
//! **What writing loses** (version 3, per Gaussian; reading is the exact inverse of each
//! map, opacity clamped half a step inside (0, 1) as for `.splat`):
//! - position: at most `2^-(fb+1)` per coordinate, fb the most fractional bits the
//!   largest coordinate leaves room for in 24 signed bits (23 below 1 unit, 22 below 2,
//!   ..., 12 below 2048: finer than the reference's fixed 12, which moved two nearly
//!   coincident Gaussians past each other in depth and a pixel of a stylized capture by
//!   0.17; the file grows by about a quarter);
//! - opacity: at most 0.5/255;
//! - base colour `0.5 + 0.2821 f_dc`: at most 0.2821 x 0.5 / (255 x 0.15) = 0.0037
//!   (f_dc is clamped to [-3.33, 3.33], base colours to [-0.44, 1.44]);
//! - log-scale: at most 1/32 (scales within 3.2%), clamped to [-10, 5.94];
//! - rotation: each of the three smaller components of the normalised quaternion within
//!   `sqrt(1/2) / 1022` = 6.9e-4, the largest (derived) within 2.1e-3: the rotation
//!   within 4.8e-3 rad (0.28 degrees); version 2 is far coarser near w = 0;
//! - SH degree 1: at most 4.5/128 = 0.035 per coefficient (rounding to 1/128, then to a
//!   multiple of 8/128); degrees 2, 3: 8.5/128 = 0.066; all clamped to [-1, 0.99].
//!
//! What that does to a render is [`SPZ_RENDER_MAX`] and [`SPZ_RENDER_MEAN`].

use super::splat::opacity_logit_u8;
use super::{Scene, sh_coeffs};
use crate::{Error, Result};
use std::io::Read;
use std::path::Path;

/// The header magic, "NGSP" read as a little-endian u32.
pub const MAGIC: u32 = 0x5053_474e;
/// Header bytes.
pub const HEADER: usize = 16;
/// The version written.
pub const VERSION: u32 = 3;
/// The most fractional bits of the fixed-point positions written (2^-23 units: all the
/// 24-bit field holds below 1 unit); a scene's largest coordinate takes fewer
/// ([`fractional_bits`]).
pub const FRACTIONAL_BITS: u8 = 23;
/// Scale of the stored base colour (`0.15 f_dc + 0.5`).
pub const COLOR_SCALE: f32 = 0.15;
/// Bits kept of SH degree-1 coefficients (as the reference writer's default).
pub const SH1_BITS: u32 = 5;
/// Bits kept of SH coefficients of degree 2 and 3.
pub const SH_REST_BITS: u32 = 4;
/// Flag: the scene was trained with antialiasing (mip-splatting's filter).
pub const FLAG_ANTIALIASED: u8 = 0x1;
/// Flag: extension records follow the header.
pub const FLAG_EXTENSIONS: u8 = 0x2;
/// The most extension bytes skipped (far more than any known extension needs).
pub const MAX_EXTENSION_BYTES: usize = 1 << 20;

/// Render tolerance of a written `.spz` against the scene it was written from (RGB in
/// [0, 1], per channel): the largest difference in any pixel. Colour alone moves a
/// pixel by at most the largest colour change of a Gaussian, [`SPZ_COLOUR_MAX`] (a pixel
/// is a convex combination of Gaussian colours); the quantised scales (3.2%), rotations
/// and opacities move silhouette edges by a fraction of a pixel, which can change an
/// edge pixel by more, and so can a colour the format's range clamps (writing warns).
/// Measured (orbit:4 at 128x128): max 0.055, mean 7.6e-4 on the sample scene (SH degree
/// 1, nothing clamped; the round-trip test). On stylized scenes (high contrast between
/// neighbours) the reference's 12 fractional position bits swapped nearly coincident
/// Gaussians in depth: one pixel of a 48 px `bob_10k` capture moved 0.167; with the
/// finest positions the field holds ([`fractional_bits`]) 0.0065 (the own-scene test).
pub const SPZ_RENDER_MAX: f32 = 0.15;
/// The largest change of a Gaussian's colour (degree <= 1) from writing: 0.0037 (base
/// colour) + 0.035 x 0.4886 x sqrt 3 = 0.030 (degree-1 SH: three coefficients within
/// 0.035 each, times the SH constant, over a unit view direction) = 0.034.
pub const SPZ_COLOUR_MAX: f32 = 0.034;
/// Mean absolute difference bound of the same comparison: [`SPZ_COLOUR_MAX`] holds
/// wherever coverage is unchanged, most pixels change far less (a change of the largest
/// size needs every SH error aligned with the view), and edges are a small share of the
/// pixels.
pub const SPZ_RENDER_MEAN: f64 = 2e-3;

/// SH coefficients per channel stored for `degree` (0, 3, 8, 15, 24).
fn sh_dim(degree: usize) -> usize {
    sh_coeffs(degree) - 1
}

/// Bytes per Gaussian after the header.
fn record_bytes(version: u32, degree: usize) -> usize {
    9 + 1 + 3 + 3 + if version >= 3 { 4 } else { 3 } + 3 * sh_dim(degree)
}

/// Read a `.spz` file.
pub fn read_spz(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_spz(path, &bytes)
}

/// Parse `.spz` bytes (the gzip-compressed file); `path` is used in error messages only.
pub fn parse_spz(path: &Path, bytes: &[u8]) -> Result<Scene> {
    let bad = |r: String| Error::input(path, r);
    check_gzip(bytes).map_err(bad)?;
    let mut dec = flate2::read::GzDecoder::new(bytes);
    let gz = |e: std::io::Error| bad(format!("corrupt gzip stream: {e}"));
    let mut h = [0u8; HEADER];
    let got = read_up_to(&mut dec, &mut h).map_err(gz)?;
    if got < HEADER {
        return Err(bad(format!(
            "truncated: the decompressed stream holds {got} bytes, fewer than the \
             {HEADER}-byte header"
        )));
    }
    let SpzHeader {
        version,
        n,
        degree,
        fb,
        flags,
    } = check_header(&h).map_err(bad)?;
    let per = record_bytes(version, degree);
    let data_len = (n as u64) * (per as u64);
    let extensions = flags & FLAG_EXTENSIONS != 0;
    let slack = if extensions { MAX_EXTENSION_BYTES } else { 0 };
    // Read what the stream holds, at most one byte more than the header allows: the
    // buffer grows with the data, never with the count alone.
    let mut rest = Vec::new();
    (&mut dec)
        .take(data_len + slack as u64 + 1)
        .read_to_end(&mut rest)
        .map_err(gz)?;
    let held = rest.len() as u64;
    if held < data_len {
        return Err(bad(format!(
            "truncated: the header says {n} Gaussians (version {version}, SH degree {degree}: \
             {data_len} bytes), the stream holds {held}"
        )));
    }
    let ext_len = (held - data_len) as usize;
    if ext_len > slack {
        return Err(bad(format!(
            "data continues after the {n} Gaussians the header announces (wrong count or \
             not a .spz file)"
        )));
    }
    // Reach the end of the stream, which checks gzip's CRC.
    let mut one = [0u8; 1];
    if read_up_to(&mut dec, &mut one).map_err(gz)? != 0 {
        return Err(bad(format!(
            "more data after {} bytes of extensions (at most {MAX_EXTENSION_BYTES} are \
             accepted)",
            ext_len
        )));
    }
    warn_unread(path, extensions.then_some(ext_len), flags, degree);
    let s = decode(&rest[ext_len..], n, version, degree, fb);
    s.validate(path)?;
    Ok(s)
}

/// Refuse what is not a gzip stream, naming an uncompressed `.spz` stream as such.
fn check_gzip(bytes: &[u8]) -> std::result::Result<(), String> {
    if bytes.len() >= 8 && u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) == MAGIC {
        let v = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        return Err(if v >= 4 {
            format!(
                "the uncompressed NGSP container of .spz version {v} is not supported; this \
                 reader reads versions 2 and 3 (gzip; re-save it as version 3)"
            )
        } else {
            format!(
                "an uncompressed .spz stream (version {v}); .spz files of versions 2 and 3 \
                 are gzip-compressed"
            )
        });
    }
    if bytes.len() < 2 || bytes[0] != 0x1f || bytes[1] != 0x8b {
        return Err(
            "not a gzip stream (a .spz file is gzip-compressed; truncated or not a .spz file?)"
                .into(),
        );
    }
    Ok(())
}

/// A `.spz` header's fields.
struct SpzHeader {
    version: u32,
    /// Gaussians.
    n: usize,
    degree: usize,
    /// Fractional bits of the 24-bit positions.
    fb: u8,
    flags: u8,
}

/// The decompressed header `h`, checked: magic, version 2 or 3, SH degree, fractional
/// bits, a count above 0.
fn check_header(h: &[u8; HEADER]) -> std::result::Result<SpzHeader, String> {
    let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
    let (magic, version, n) = (u32_at(0), u32_at(4), u32_at(8) as usize);
    let (degree, fb, flags) = (h[12] as usize, h[13], h[14]);
    if magic != MAGIC {
        return Err(format!(
            "bad magic {magic:#010x} (expected {MAGIC:#010x}, \"NGSP\"): not a .spz file"
        ));
    }
    match version {
        2 | 3 => {}
        1 => {
            return Err(
                "version 1 (float16 positions, never released) is not supported; this reader \
                 reads versions 2 and 3"
                    .into(),
            );
        }
        v => {
            return Err(format!(
                "unsupported version {v} (this reader reads versions 2 and 3)"
            ));
        }
    }
    if degree > 4 {
        return Err(format!("SH degree {degree} (the format allows 0..=4)"));
    }
    if fb > 30 {
        return Err(format!(
            "{fb} fractional bits for 24-bit positions (corrupt header?)"
        ));
    }
    if n == 0 {
        return Err("no Gaussians (the header's count is 0)".into());
    }
    Ok(SpzHeader {
        version,
        n,
        degree,
        fb,
        flags,
    })
}

/// Warn about what the reader skips or does not render: extensions (`ext_len` bytes),
/// antialiasing, SH degree 4's coefficients.
fn warn_unread(path: &Path, ext_len: Option<usize>, flags: u8, degree: usize) {
    if let Some(ext_len) = ext_len {
        tracing::warn!(
            "{}: skipped {ext_len} bytes of .spz extensions; SH coefficients are decoded with \
             the default [-1, 1] range",
            path.display()
        );
    }
    if flags & FLAG_ANTIALIASED != 0 {
        tracing::warn!(
            "{}: the scene was trained with antialiasing (mip-splatting); it is rendered \
             without the antialiasing filter",
            path.display()
        );
    }
    if degree == 4 {
        tracing::warn!(
            "{}: SH degree 4 is read as degree 3 (the degree-4 coefficients are dropped)",
            path.display()
        );
    }
}

/// Read until `buf` is full or the stream ends; the number of bytes read.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(k) => got += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// Decode the attribute arrays (`d` holds exactly `n` records of `version`, `degree`).
fn decode(d: &[u8], n: usize, version: u32, degree: usize, fb: u8) -> Scene {
    let dim = sh_dim(degree);
    let keep = dim.min(sh_dim(3));
    let rot_bytes = if version >= 3 { 4 } else { 3 };
    let (pos, d) = d.split_at(9 * n);
    let (alpha, d) = d.split_at(n);
    let (col, d) = d.split_at(3 * n);
    let (scl, d) = d.split_at(3 * n);
    let (rot, sh) = d.split_at(rot_bytes * n);
    let step = 0.5f64.powi(fb as i32);
    let fixed = |b: &[u8]| -> f32 {
        let v = (b[0] as i32) | (b[1] as i32) << 8 | (b[2] as i32) << 16;
        let v = (v << 8) >> 8; // sign-extend 24 bits
        (v as f64 * step) as f32
    };
    let mut s = Scene {
        sh_degree: degree.min(3),
        ..Scene::default()
    };
    s.positions = pos
        .chunks_exact(9)
        .map(|p| [fixed(&p[0..3]), fixed(&p[3..6]), fixed(&p[6..9])])
        .collect();
    s.opacity_logits = alpha.iter().map(|&a| opacity_logit_u8(a)).collect();
    s.sh_dc = col
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]].map(|v| (v as f32 / 255.0 - 0.5) / COLOR_SCALE))
        .collect();
    s.log_scales = scl
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]].map(|v| v as f32 / 16.0 - 10.0))
        .collect();
    s.rotations = rot
        .chunks_exact(rot_bytes)
        .map(|r| {
            let xyzw = if version >= 3 {
                unpack_smallest_three([r[0], r[1], r[2], r[3]])
            } else {
                unpack_first_three([r[0], r[1], r[2]])
            };
            [xyzw[3], xyzw[0], xyzw[1], xyzw[2]]
        })
        .collect();
    if dim > 0 {
        s.sh_rest = sh
            .chunks_exact(3 * dim)
            .flat_map(|g| g[..3 * keep].iter().map(|&b| (b as f32 - 128.0) / 128.0))
            .collect();
    }
    s
}

/// Version 2 rotation: x, y, z in [-1, 1], w = sqrt(1 - |xyz|^2) >= 0; (x, y, z, w).
fn unpack_first_three(r: [u8; 3]) -> [f32; 4] {
    let v = r.map(|b| b as f32 / 127.5 - 1.0);
    let w = (1.0 - v.iter().map(|x| x * x).sum::<f32>()).max(0.0).sqrt();
    [v[0], v[1], v[2], w]
}

/// Version 3 rotation ("smallest three"); (x, y, z, w).
fn unpack_smallest_three(r: [u8; 4]) -> [f32; 4] {
    let mut comp = u32::from_le_bytes(r);
    let largest = (comp >> 30) as usize;
    let mut q = [0f32; 4];
    let mut sum = 0.0;
    for i in (0..4).rev() {
        if i == largest {
            continue;
        }
        let mag = (comp & 511) as f32;
        let neg = (comp >> 9) & 1 == 1;
        comp >>= 10;
        let v = std::f32::consts::FRAC_1_SQRT_2 * mag / 511.0;
        q[i] = if neg { -v } else { v };
        sum += v * v;
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    q
}

/// The normalised quaternion of `s.rotations[i]` in the format's order (x, y, z, w).
fn xyzw(q: [f32; 4]) -> [f64; 4] {
    let q = q.map(f64::from);
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    [q[1] / n, q[2] / n, q[3] / n, q[0] / n]
}

/// Version 2 rotation bytes of a normalised (x, y, z, w).
fn pack_first_three(q: [f64; 4]) -> [u8; 3] {
    let s = if q[3] < 0.0 { -1.0 } else { 1.0 };
    [q[0], q[1], q[2]].map(|v| (s * v * 127.5 + 127.5).round().clamp(0.0, 255.0) as u8)
}

/// Version 3 rotation bytes of a normalised (x, y, z, w).
fn pack_smallest_three(q: [f64; 4]) -> [u8; 4] {
    let mut largest = 0;
    for i in 1..4 {
        if q[i].abs() > q[largest].abs() {
            largest = i;
        }
    }
    let flip = q[largest] < 0.0;
    let mut comp = largest as u32;
    for (i, &v) in q.iter().enumerate() {
        if i == largest {
            continue;
        }
        let neg = ((v < 0.0) != flip) as u32;
        let mag = (v.abs() * std::f64::consts::SQRT_2 * 511.0)
            .round()
            .min(511.0) as u32;
        comp = comp << 10 | neg << 9 | mag;
    }
    comp.to_le_bytes()
}

/// One SH coefficient as a byte: `round(128 x) + 128`, rounded to a multiple of
/// `2^(8 - bits)`, clamped to [0, 255].
fn quantize_sh(x: f32, bits: u32) -> u8 {
    let bucket = 1i64 << (8 - bits);
    let q = (x as f64 * 128.0).round() as i64 + 128;
    let q = (q + bucket / 2) / bucket * bucket;
    q.clamp(0, 255) as u8
}

/// `round(v)` clamped to [0, 255] (NaN: 0).
fn to_u8(v: f64) -> u8 {
    if v.is_nan() {
        0
    } else {
        v.round().clamp(0.0, 255.0) as u8
    }
}

/// What writing clamped (counts of values outside the format's ranges).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Clamped {
    /// Base-colour coefficients outside [-3.33, 3.33].
    pub colour: usize,
    /// Log-scales outside [-10, 5.94].
    pub log_scale: usize,
    /// Higher-order SH coefficients outside [-1, 1].
    pub sh: usize,
}

/// Fractional bits that fit the scene's largest coordinate into 24 signed bits, at most
/// [`FRACTIONAL_BITS`]; `None` if even 0 bits do not (|coordinate| >= 2^23).
pub fn fractional_bits(s: &Scene) -> Option<u8> {
    let m = s
        .positions
        .iter()
        .flatten()
        .fold(0f64, |m, v| m.max((*v as f64).abs()));
    (0..=FRACTIONAL_BITS)
        .rev()
        .find(|&fb| (m * f64::from(1u32 << fb)).round() < f64::from(1u32 << 23))
}

/// Encode `s` as `.spz` bytes of `version` (2 or 3; [`VERSION`] is what the stages write),
/// with what was clamped. The scene must be valid ([`Scene::validate`]); `path` names it
/// in errors (coordinates beyond the 24-bit range, an empty scene).
pub fn encode_spz_version(path: &Path, s: &Scene, version: u32) -> Result<(Vec<u8>, Clamped)> {
    assert!(version == 2 || version == 3, "spz version {version}");
    let n = s.len();
    if n == 0 {
        return Err(Error::input(path, "cannot write an empty scene as .spz"));
    }
    if u32::try_from(n).is_err() {
        return Err(Error::input(
            path,
            format!("{n} Gaussians do not fit .spz's count"),
        ));
    }
    let fb = fractional_bits(s).ok_or_else(|| {
        Error::input(
            path,
            "a coordinate is beyond +-8388607 scene units, outside .spz's 24-bit positions",
        )
    })?;
    let degree = s.sh_degree;
    let dim = sh_dim(degree);
    let mut raw = Vec::with_capacity(HEADER + n * record_bytes(version, degree));
    raw.extend_from_slice(&MAGIC.to_le_bytes());
    raw.extend_from_slice(&version.to_le_bytes());
    raw.extend_from_slice(&(n as u32).to_le_bytes());
    raw.extend_from_slice(&[degree as u8, fb, 0, 0]);
    let scale = f64::from(1u32 << fb);
    for p in &s.positions {
        for v in p {
            let f = (*v as f64 * scale).round() as i32;
            raw.extend_from_slice(&f.to_le_bytes()[..3]);
        }
    }
    for &l in &s.opacity_logits {
        raw.push(to_u8(255.0 / (1.0 + (-(l as f64)).exp())));
    }
    let mut clamped = Clamped::default();
    let cmax = 0.5 / COLOR_SCALE as f64 + 0.5 / (255.0 * COLOR_SCALE as f64);
    for c in &s.sh_dc {
        for v in c {
            clamped.colour += ((*v as f64).abs() > cmax) as usize;
            raw.push(to_u8(
                *v as f64 * (COLOR_SCALE as f64 * 255.0) + 0.5 * 255.0,
            ));
        }
    }
    for ls in &s.log_scales {
        for v in ls {
            let q = (*v as f64 + 10.0) * 16.0;
            clamped.log_scale += !(-0.5..255.5).contains(&q) as usize;
            raw.push(to_u8(q));
        }
    }
    for q in &s.rotations {
        let q = xyzw(*q);
        if version >= 3 {
            raw.extend_from_slice(&pack_smallest_three(q));
        } else {
            raw.extend_from_slice(&pack_first_three(q));
        }
    }
    if dim > 0 {
        for g in s.sh_rest.chunks_exact(3 * dim) {
            for (j, &v) in g.iter().enumerate() {
                clamped.sh += (v.abs() > 1.0) as usize;
                let bits = if j < 9 { SH1_BITS } else { SH_REST_BITS };
                raw.push(quantize_sh(v, bits));
            }
        }
    }
    debug_assert_eq!(raw.len(), HEADER + n * record_bytes(version, degree));
    let mut enc = flate2::GzBuilder::new()
        .mtime(0)
        .write(Vec::new(), flate2::Compression::default());
    use std::io::Write;
    enc.write_all(&raw).map_err(|e| Error::io(path, e))?;
    let bytes = enc.finish().map_err(|e| Error::io(path, e))?;
    Ok((bytes, clamped))
}

/// Encode `s` as version-3 `.spz` bytes, warning (naming `path`) about clamped values.
pub fn encode_spz(path: &Path, s: &Scene) -> Result<Vec<u8>> {
    let (bytes, c) = encode_spz_version(path, s, VERSION)?;
    if c != Clamped::default() {
        tracing::warn!(
            "{}: .spz clamped {} base-colour, {} log-scale and {} SH values outside its ranges",
            path.display(),
            c.colour,
            c.log_scale,
            c.sh
        );
    }
    Ok(bytes)
}

/// Validate `s` and write it to `path` as version-3 `.spz`, atomically.
pub fn write_spz(path: &Path, s: &Scene) -> Result<()> {
    s.validate(path)?;
    let bytes = encode_spz(path, s)?;
    fantasystyle_schemas::atomic_write(path, &bytes)?;
    Ok(())
}

#[cfg(test)]
mod tests;

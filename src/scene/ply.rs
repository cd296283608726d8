//! The INRIA 3D Gaussian Splatting `.ply` (Kerbl et al. 2023, `GaussianModel.save_ply`).
//!
//! Format (PLY, Turk 1994): an ASCII header (`ply`, `format ...`, `element vertex N`,
//! `property TYPE NAME` lines, `end_header`) followed by the vertex records, either as
//! whitespace-separated text (`ascii 1.0`) or packed little-endian binary
//! (`binary_little_endian 1.0`). Big-endian files are refused with a clear error.
//!
//! Per Gaussian the INRIA code writes, all `float`:
//! `x y z nx ny nz f_dc_0..2 f_rest_0..M-1 opacity scale_0..2 rot_0..3`, with
//! `M = 3 * (sh_coeffs(degree) - 1)` (0, 9, 24 or 45, from which the degree is inferred),
//! `opacity` a logit, `scale_*` natural logs, `rot_*` the quaternion (w, x, y, z).
//! `f_rest` is channel-major (`f_rest_{c*K + k}` for channel c, coefficient k of K); the
//! reader transposes it into [`Scene::sh_rest`]'s `[k][c]` layout and the writer back.
//!
//! The reader takes any property order, skips properties it does not use (normals,
//! gsplat/brush extras) of any numeric type (`char uchar short ushort int uint float
//! double` and the `int8 uint8 int16 uint16 int32 uint32 float32 float64` aliases), and
//! skips further elements with fixed-size properties. Values stored as `float` are kept
//! bit-exactly, so a read-write-read cycle is the identity on every field read.
//! The writer emits the INRIA layout (normals written as 0), so the usual viewers open it.

use super::{Scene, sh_coeffs};
use crate::{Error, Result};
use rayon::prelude::*;
use std::path::Path;

/// Scalar property types of the PLY format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl PType {
    fn parse(s: &str) -> Option<PType> {
        Some(match s {
            "char" | "int8" => PType::I8,
            "uchar" | "uint8" => PType::U8,
            "short" | "int16" => PType::I16,
            "ushort" | "uint16" => PType::U16,
            "int" | "int32" => PType::I32,
            "uint" | "uint32" => PType::U32,
            "float" | "float32" => PType::F32,
            "double" | "float64" => PType::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            PType::I8 | PType::U8 => 1,
            PType::I16 | PType::U16 => 2,
            PType::I32 | PType::U32 | PType::F32 => 4,
            PType::F64 => 8,
        }
    }
    /// Decode one little-endian value as f32 (`float` bit-exactly).
    fn read_le(self, b: &[u8]) -> f32 {
        match self {
            PType::I8 => b[0] as i8 as f32,
            PType::U8 => b[0] as f32,
            PType::I16 => i16::from_le_bytes([b[0], b[1]]) as f32,
            PType::U16 => u16::from_le_bytes([b[0], b[1]]) as f32,
            PType::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            PType::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
            PType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            PType::F64 => {
                let mut a = [0u8; 8];
                a.copy_from_slice(&b[..8]);
                f64::from_le_bytes(a) as f32
            }
        }
    }
    /// Parse one ASCII token (`float` parsed directly as f32, so shortest-repr text
    /// round-trips exactly).
    fn parse_text(self, t: &str) -> Option<f32> {
        match self {
            PType::F32 => t.parse::<f32>().ok(),
            PType::F64 => t.parse::<f64>().ok().map(|v| v as f32),
            _ => t.parse::<i64>().ok().map(|v| v as f32),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<(String, PType)>,
    /// Set when the element has a list property (only allowed for non-vertex elements
    /// in ASCII files or after the vertex element, where nothing needs to be skipped).
    has_list: bool,
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Byte offset of the body.
    body: usize,
}

fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
    let bad = |r: String| Error::input(path, r);
    if !bytes.starts_with(b"ply") {
        return Err(bad("not a PLY file (does not start with `ply`)".into()));
    }
    let (lines, body) = header_lines(bytes);
    let body = body.ok_or_else(|| bad("PLY header has no `end_header` line".into()))?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (ln, line) in lines.iter().enumerate().skip(1) {
        let tok: Vec<&str> = line.split_whitespace().collect();
        let at = |what: String| bad(format!("header line {}: {what}", ln + 1));
        match tok.first().copied() {
            None | Some("comment") | Some("obj_info") => {}
            Some("format") => format = Some(parse_format(tok.get(1).copied(), &at, &bad)?),
            Some("element") => {
                let (Some(name), Some(count)) = (tok.get(1), tok.get(2)) else {
                    return Err(at(format!("malformed `{line}`")));
                };
                let count = count.parse::<usize>().map_err(|_| {
                    at(format!(
                        "element count `{count}` is not a non-negative integer"
                    ))
                })?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                    has_list: false,
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(at("property before any element".into()));
                };
                parse_property(el, &tok, line, &at, &bad)?;
            }
            Some(other) => return Err(at(format!("unexpected keyword `{other}`"))),
        }
    }
    let format = format.ok_or_else(|| bad("PLY header has no `format` line".into()))?;
    Ok(Header {
        format,
        elements,
        body,
    })
}

/// The header's lines before `end_header` (trimmed) and the byte offset of the body
/// (`None` without an `end_header` line in the first megabyte).
fn header_lines(bytes: &[u8]) -> (Vec<String>, Option<usize>) {
    let mut pos = 0usize;
    let mut lines = Vec::new();
    while pos < bytes.len() {
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|e| pos + e);
        let line_end = end.unwrap_or(bytes.len());
        let line = String::from_utf8_lossy(&bytes[pos..line_end])
            .trim_end_matches('\r')
            .trim()
            .to_string();
        pos = end.map(|e| e + 1).unwrap_or(bytes.len());
        if line == "end_header" {
            return (lines, Some(pos));
        }
        lines.push(line);
        if pos > 1 << 20 {
            break; // a header is never a megabyte long
        }
    }
    (lines, None)
}

/// The `format` line's format (`at`: an error naming the line, `bad`: one naming only
/// the file).
fn parse_format(
    kind: Option<&str>,
    at: &dyn Fn(String) -> Error,
    bad: &dyn Fn(String) -> Error,
) -> Result<Format> {
    match kind {
        Some("ascii") => Ok(Format::Ascii),
        Some("binary_little_endian") => Ok(Format::BinaryLe),
        Some("binary_big_endian") => Err(bad(
            "big-endian PLY (binary_big_endian) is not supported; convert it to \
             binary_little_endian"
                .into(),
        )),
        other => Err(at(format!("unknown PLY format {:?}", other.unwrap_or("")))),
    }
}

/// A `property` line (`tok`, its words) of element `el`: a list marks the element, a
/// scalar property is added with its type.
fn parse_property(
    el: &mut Element,
    tok: &[&str],
    line: &str,
    at: &dyn Fn(String) -> Error,
    bad: &dyn Fn(String) -> Error,
) -> Result<()> {
    if tok.get(1) == Some(&"list") {
        el.has_list = true;
        return Ok(());
    }
    let (Some(ty), Some(name)) = (tok.get(1), tok.get(2)) else {
        return Err(at(format!("malformed `{line}`")));
    };
    let ty = PType::parse(ty).ok_or_else(|| {
        bad(format!(
            "unknown property type `{ty}` for property `{name}` of element `{}`",
            el.name
        ))
    })?;
    el.props.push((name.to_string(), ty));
    Ok(())
}

/// Column indices of the properties the INRIA parameterisation needs.
struct Columns {
    pos: [usize; 3],
    dc: [usize; 3],
    rest: Vec<usize>,
    opacity: usize,
    scale: [usize; 3],
    rot: [usize; 4],
    degree: usize,
}

fn columns(path: &Path, props: &[(String, PType)]) -> Result<Columns> {
    if props.iter().any(|(p, _)| p == "packed_position") {
        return Err(Error::input(
            path,
            "a compressed (SuperSplat/PlayCanvas `packed_*`) PLY is not supported; \
             decompress it to the INRIA layout first",
        ));
    }
    let find = |n: &str| -> Result<usize> {
        props.iter().position(|(p, _)| p == n).ok_or_else(|| {
            Error::input(
                path,
                format!("missing required vertex property `{n}` (not an INRIA 3DGS .ply?)"),
            )
        })
    };
    let n_rest = props
        .iter()
        .filter(|(p, _)| p.starts_with("f_rest_"))
        .count();
    let degree = match n_rest {
        0 => 0,
        9 => 1,
        24 => 2,
        45 => 3,
        m => {
            return Err(Error::input(
                path,
                format!("{m} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0..3)"),
            ));
        }
    };
    let rest = (0..n_rest)
        .map(|j| find(&format!("f_rest_{j}")))
        .collect::<Result<Vec<_>>>()?;
    Ok(Columns {
        pos: [find("x")?, find("y")?, find("z")?],
        dc: [find("f_dc_0")?, find("f_dc_1")?, find("f_dc_2")?],
        rest,
        opacity: find("opacity")?,
        scale: [find("scale_0")?, find("scale_1")?, find("scale_2")?],
        rot: [
            find("rot_0")?,
            find("rot_1")?,
            find("rot_2")?,
            find("rot_3")?,
        ],
        degree,
    })
}

/// Read an INRIA 3DGS `.ply` (binary little-endian or ASCII) and validate it.
pub fn read_ply(path: &Path) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_ply(path, &bytes)
}

/// Parse PLY bytes; `path` is used in error messages only.
pub fn parse_ply(path: &Path, bytes: &[u8]) -> Result<Scene> {
    let h = parse_header(path, bytes)?;
    let vi = h
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| Error::input(path, "PLY header declares no `vertex` element"))?;
    let vertex = &h.elements[vi];
    if vertex.has_list {
        return Err(Error::input(
            path,
            "the vertex element has a list property (not a 3DGS file)",
        ));
    }
    let cols = columns(path, &vertex.props)?;
    let n = vertex.count;
    if n == 0 {
        return Err(Error::input(
            path,
            "the PLY holds no Gaussians (vertex count 0)",
        ));
    }
    let r = cols.rest.len() / 3;
    let mut s = Scene {
        sh_degree: cols.degree,
        ..Scene::default()
    };
    match h.format {
        Format::BinaryLe => {
            let (body, offsets, stride) = binary_rows(path, bytes, &h, vi)?;
            s = gather_binary(body, &offsets, stride, &cols, r, n);
        }
        Format::Ascii => {
            // Rows are decoded one at a time into a small buffer and gathered into the
            // scene (no whole-file intermediate; capacities grow as data is read).
            let mut gather = |row: &[f32]| gather_row(&mut s, &cols, r, row);
            read_ascii_rows(path, bytes, &h, vi, &mut gather)?;
        }
    }
    s.validate(path)?;
    debug_assert_eq!(sh_coeffs(s.sh_degree) - 1, r);
    Ok(s)
}

/// Append one row's values to `s`.
fn gather_row(s: &mut Scene, cols: &Columns, r: usize, row: &[f32]) {
    let g3 = |c: [usize; 3]| [row[c[0]], row[c[1]], row[c[2]]];
    s.positions.push(g3(cols.pos));
    s.sh_dc.push(g3(cols.dc));
    s.log_scales.push(g3(cols.scale));
    s.rotations.push(cols.rot.map(|c| row[c]));
    s.opacity_logits.push(row[cols.opacity]);
    // PLY: f_rest_{c*r + k}; Scene: [k][c].
    for k in 0..r {
        for c in 0..3 {
            s.sh_rest.push(row[cols.rest[c * r + k]]);
        }
    }
}

/// Rows per parallel task of the binary reader and writer.
const ROWS: usize = 8192;

/// Decode `n` fixed-stride binary rows into a scene, in parallel blocks of rows written
/// straight into place (every row is one Gaussian, so each block's place is known).
fn gather_binary(
    body: &[u8],
    offsets: &[(usize, PType)],
    stride: usize,
    cols: &Columns,
    r: usize,
    n: usize,
) -> Scene {
    let k3 = r * 3;
    let mut s = Scene {
        positions: vec![[0.0; 3]; n],
        log_scales: vec![[0.0; 3]; n],
        rotations: vec![[0.0; 4]; n],
        opacity_logits: vec![0.0; n],
        sh_degree: cols.degree,
        sh_dc: vec![[0.0; 3]; n],
        sh_rest: vec![0.0; n * k3],
    };
    let rest_chunk = (ROWS * k3).max(1);
    let mut rest: Vec<&mut [f32]> = s.sh_rest.chunks_mut(rest_chunk).collect();
    rest.resize_with(n.div_ceil(ROWS), Default::default);
    s.positions
        .par_chunks_mut(ROWS)
        .zip(s.log_scales.par_chunks_mut(ROWS))
        .zip(s.rotations.par_chunks_mut(ROWS))
        .zip(s.opacity_logits.par_chunks_mut(ROWS))
        .zip(s.sh_dc.par_chunks_mut(ROWS))
        .zip(rest)
        .zip(body.par_chunks(ROWS * stride.max(1)))
        .for_each(|((((((pos, ls), rot), op), dc), rest), recs)| {
            let mut row = vec![0.0f32; offsets.len()];
            for (j, rec) in recs.chunks_exact(stride.max(1)).enumerate() {
                for (x, &(o, t)) in row.iter_mut().zip(offsets) {
                    *x = t.read_le(&rec[o..]);
                }
                let g3 = |c: [usize; 3]| [row[c[0]], row[c[1]], row[c[2]]];
                pos[j] = g3(cols.pos);
                dc[j] = g3(cols.dc);
                ls[j] = g3(cols.scale);
                rot[j] = cols.rot.map(|c| row[c]);
                op[j] = row[cols.opacity];
                for k in 0..r {
                    for c in 0..3 {
                        rest[j * k3 + k * 3 + c] = row[cols.rest[c * r + k]];
                    }
                }
            }
        });
    s
}

fn elem_stride(path: &Path, e: &Element) -> Result<usize> {
    if e.has_list {
        return Err(Error::input(
            path,
            format!(
                "element `{}` before the vertex data has a list property; cannot skip it",
                e.name
            ),
        ));
    }
    Ok(e.props.iter().map(|(_, t)| t.size()).sum())
}

/// Vertex rows: their bytes, each property's (offset, type) within a row, the stride.
type Rows<'b> = (&'b [u8], Vec<(usize, PType)>, usize);

/// The vertex rows of a binary file (checked against the header): their bytes, each
/// property's (offset, type) within a row, and the row stride.
fn binary_rows<'b>(path: &Path, bytes: &'b [u8], h: &Header, vi: usize) -> Result<Rows<'b>> {
    let mut off = h.body;
    for e in &h.elements[..vi] {
        off = elem_stride(path, e)?
            .checked_mul(e.count)
            .and_then(|b| b.checked_add(off))
            .ok_or_else(|| Error::input(path, "header element sizes overflow"))?;
    }
    let v = &h.elements[vi];
    let stride = elem_stride(path, v)?;
    let need = stride
        .checked_mul(v.count)
        .ok_or_else(|| Error::input(path, "header vertex count overflows"))?;
    let have = bytes.len().saturating_sub(off);
    if have < need {
        return Err(Error::input(
            path,
            format!(
                "truncated: the header declares {} vertices of {stride} bytes ({need} bytes), \
                 but only {have} bytes follow (the file is cut short or the count lies)",
                v.count
            ),
        ));
    }
    // Trailing data is only an error when nothing else is declared after the vertices.
    let mut expected_end = Some(off + need);
    for e in &h.elements[vi + 1..] {
        expected_end = match (e.has_list, expected_end) {
            (false, Some(end)) => e
                .props
                .iter()
                .map(|(_, t)| t.size())
                .sum::<usize>()
                .checked_mul(e.count)
                .and_then(|b| b.checked_add(end)),
            _ => None,
        };
    }
    if let Some(end) = expected_end {
        if bytes.len() > end {
            return Err(Error::input(
                path,
                format!(
                    "{} bytes of trailing data after the {} declared vertices \
                     (the header's vertex count lies or the file is corrupt)",
                    bytes.len() - end,
                    v.count
                ),
            ));
        }
        if bytes.len() < end {
            return Err(Error::input(
                path,
                "truncated: data of the elements after the vertices is cut short",
            ));
        }
    }
    let mut offsets = Vec::with_capacity(v.props.len());
    let mut o = 0;
    for (_, t) in &v.props {
        offsets.push((o, *t));
        o += t.size();
    }
    Ok((&bytes[off..off + need], offsets, stride))
}

/// Parse the vertex lines of an ASCII file, calling `sink` with each row's values.
fn read_ascii_rows(
    path: &Path,
    bytes: &[u8],
    h: &Header,
    vi: usize,
    sink: &mut dyn FnMut(&[f32]),
) -> Result<()> {
    let text = std::str::from_utf8(&bytes[h.body..])
        .map_err(|_| Error::input(path, "ASCII PLY body is not valid UTF-8 text"))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    // Skip the lines of elements declared before the vertices (one line per item).
    for e in &h.elements[..vi] {
        for _ in 0..e.count {
            if lines.next().is_none() {
                return Err(Error::input(
                    path,
                    format!("truncated: element `{}` data is cut short", e.name),
                ));
            }
        }
    }
    let v = &h.elements[vi];
    let mut row = Vec::with_capacity(v.props.len());
    for i in 0..v.count {
        let line = lines.next().ok_or_else(|| {
            Error::input(
                path,
                format!(
                    "truncated: the header declares {} vertices, the file has only {i}",
                    v.count
                ),
            )
        })?;
        let toks: Vec<&str> = line.split_whitespace().collect();
        if toks.len() != v.props.len() {
            return Err(Error::input(
                path,
                format!(
                    "vertex {i}: {} values on the line, the header declares {} properties",
                    toks.len(),
                    v.props.len()
                ),
            ));
        }
        row.clear();
        for (t, (name, ty)) in toks.iter().zip(&v.props) {
            let x = ty.parse_text(t).ok_or_else(|| {
                Error::input(
                    path,
                    format!("vertex {i}: property `{name}`: cannot parse `{t}`"),
                )
            })?;
            row.push(x);
        }
        sink(&row);
    }
    let later: usize = h.elements[vi + 1..].iter().map(|e| e.count).sum();
    let extra = lines.count();
    if extra > later {
        return Err(Error::input(
            path,
            format!(
                "{} lines of trailing data after the {} declared vertices \
                 (the header's vertex count lies or the file is corrupt)",
                extra - later,
                v.count
            ),
        ));
    }
    Ok(())
}

/// The INRIA property names, in the INRIA order, for `degree`.
fn property_names(degree: usize) -> Vec<String> {
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    for j in 0..3 * (sh_coeffs(degree) - 1) {
        names.push(format!("f_rest_{j}"));
    }
    names.push("opacity".into());
    for j in 0..3 {
        names.push(format!("scale_{j}"));
    }
    for j in 0..4 {
        names.push(format!("rot_{j}"));
    }
    names
}

/// One Gaussian's values in INRIA property order.
fn record(s: &Scene, i: usize, out: &mut Vec<f32>) {
    let r = s.rest_per_channel();
    out.extend_from_slice(&s.positions[i]);
    out.extend_from_slice(&[0.0; 3]);
    out.extend_from_slice(&s.sh_dc[i]);
    for c in 0..3 {
        for k in 0..r {
            out.push(s.sh_rest[(i * r + k) * 3 + c]);
        }
    }
    out.push(s.opacity_logits[i]);
    out.extend_from_slice(&s.log_scales[i]);
    out.extend_from_slice(&s.rotations[i]);
}

fn header_text(s: &Scene, format: &str) -> String {
    let mut h = format!(
        "ply\nformat {format} 1.0\ncomment written by fantasystyle {}\nelement vertex {}\n",
        crate::VERSION,
        s.len()
    );
    for n in property_names(s.sh_degree) {
        h.push_str(&format!("property float {n}\n"));
    }
    h.push_str("end_header\n");
    h
}

/// Encode `s` as an INRIA binary little-endian PLY (blocks of Gaussians in parallel,
/// each written into its place).
pub fn encode_ply(s: &Scene) -> Vec<u8> {
    let mut out = header_text(s, "binary_little_endian").into_bytes();
    let head = out.len();
    let stride = property_names(s.sh_degree).len() * 4;
    out.resize(head + s.len() * stride, 0);
    out[head..]
        .par_chunks_mut(ROWS * stride)
        .enumerate()
        .for_each(|(b, block)| {
            let mut rec = Vec::with_capacity(stride / 4);
            for (j, dst) in block.chunks_exact_mut(stride).enumerate() {
                rec.clear();
                record(s, b * ROWS + j, &mut rec);
                for (d, v) in dst.chunks_exact_mut(4).zip(&rec) {
                    d.copy_from_slice(&v.to_le_bytes());
                }
            }
        });
    out
}

/// Encode `s` as an ASCII PLY (shortest round-trip float text: reading it back is exact).
pub fn encode_ply_ascii(s: &Scene) -> Vec<u8> {
    let mut out = header_text(s, "ascii");
    let mut rec = Vec::new();
    for i in 0..s.len() {
        rec.clear();
        record(s, i, &mut rec);
        let line: Vec<String> = rec.iter().map(|v| format!("{v:?}")).collect();
        out.push_str(&line.join(" "));
        out.push('\n');
    }
    out.into_bytes()
}

/// Validate `s` and write it to `path` as an INRIA binary PLY, atomically.
pub fn write_ply(path: &Path, s: &Scene) -> Result<()> {
    s.validate(path)?;
    fantasystyle_schemas::atomic_write(path, &encode_ply(s))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(n: usize, degree: usize) -> Scene {
        let r = sh_coeffs(degree) - 1;
        let mut rng = crate::rng::Rng::new(degree as u64);
        let mut f = |k: usize| rng.normals_f32(k);
        Scene {
            positions: f(3 * n).chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
            log_scales: f(3 * n)
                .chunks(3)
                .map(|c| [c[0] - 3.0, c[1], c[2]])
                .collect(),
            rotations: f(4 * n)
                .chunks(4)
                .map(|c| [c[0] + 3.0, c[1], c[2], c[3]])
                .collect(),
            opacity_logits: f(n),
            sh_degree: degree,
            sh_dc: f(3 * n).chunks(3).map(|c| [c[0], c[1], c[2]]).collect(),
            sh_rest: f(n * r * 3),
        }
    }

    #[test]
    fn binary_and_ascii_round_trip_bit_exactly() {
        for d in 0..=3 {
            let s = scene(5, d);
            let p = Path::new("t.ply");
            let b = parse_ply(p, &encode_ply(&s)).unwrap();
            assert_eq!(b, s);
            let a = parse_ply(p, &encode_ply_ascii(&s)).unwrap();
            assert_eq!(a, s);
            for (x, y) in a.sh_rest.iter().zip(&s.sh_rest) {
                assert_eq!(x.to_bits(), y.to_bits());
            }
        }
    }

    /// Across the parallel blocks of rows, for any thread count.
    #[test]
    fn large_binary_round_trip_is_exact() {
        let s = scene(2 * ROWS + 17, 3);
        let p = Path::new("t.ply");
        for threads in [1, 3] {
            let (bytes, back) = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let b = encode_ply(&s);
                    let back = parse_ply(p, &b).unwrap();
                    (b, back)
                });
            assert_eq!(back, s);
            // The same bytes as a plain row-by-row writer.
            let mut want = header_text(&s, "binary_little_endian").into_bytes();
            let mut rec = Vec::new();
            for i in 0..s.len() {
                rec.clear();
                record(&s, i, &mut rec);
                for v in &rec {
                    want.extend_from_slice(&v.to_le_bytes());
                }
            }
            assert_eq!(bytes, want);
        }
    }

    /// Fuzz-style: random truncations, byte flips and header edits never panic.
    #[test]
    fn corrupted_files_never_panic() {
        let mut rng = crate::rng::Rng::new(99);
        let s = scene(4, 2);
        for good in [encode_ply(&s), encode_ply_ascii(&s)] {
            for _ in 0..1500 {
                let mut b = good.clone();
                match rng.next_u64() % 4 {
                    0 => b.truncate((rng.next_u64() as usize) % (b.len() + 1)),
                    1 => {
                        for _ in 0..1 + rng.next_u64() % 8 {
                            let i = (rng.next_u64() as usize) % b.len();
                            b[i] = rng.next_u64() as u8;
                        }
                    }
                    2 => {
                        let i = (rng.next_u64() as usize) % b.len();
                        b.insert(i, b"0123456789 \n-e.x"[(rng.next_u64() % 16) as usize]);
                    }
                    _ => {
                        let t = String::from_utf8_lossy(&b).replacen(
                            "element vertex 4",
                            &format!("element vertex {}", rng.next_u64()),
                            1,
                        );
                        b = t.into_bytes();
                    }
                }
                let r = std::panic::catch_unwind(|| parse_ply(Path::new("f.ply"), &b));
                let r = r.expect("parser panicked");
                if let Err(e) = r {
                    assert!(e.to_string().starts_with("f.ply: "), "{e}");
                }
            }
        }
    }

    #[test]
    fn f_rest_is_transposed_from_channel_major() {
        // Degree 1: f_rest_{c*3+k}. Write a file by hand with f_rest_j = j.
        let mut h = String::from("ply\nformat ascii 1.0\nelement vertex 1\n");
        for n in property_names(1) {
            h.push_str(&format!("property float {n}\n"));
        }
        h.push_str("end_header\n");
        let mut vals = ["0"; 9].join(" ");
        for j in 0..9 {
            vals.push_str(&format!(" {j}"));
        }
        vals.push_str(" 0 0 0 0 1 0 0 0\n");
        let s = parse_ply(Path::new("t.ply"), (h + &vals).as_bytes()).unwrap();
        // Scene layout [k][c]: value at (k, c) must be c*3 + k.
        for k in 0..3 {
            for c in 0..3 {
                assert_eq!(s.sh_rest[k * 3 + c], (c * 3 + k) as f32);
            }
        }
    }

    #[test]
    fn other_types_and_extra_properties_are_read() {
        let mut h = String::from(
            "ply\nformat binary_little_endian 1.0\ncomment x\nelement vertex 1\n\
             property double x\nproperty short y\nproperty uchar z\nproperty int8 extra\n",
        );
        for n in [
            "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
        ] {
            h.push_str(&format!("property float32 {n}\n"));
        }
        for n in ["rot_0", "rot_1", "rot_2", "rot_3"] {
            h.push_str(&format!("property uint16 {n}\n"));
        }
        h.push_str("end_header\n");
        let mut b = h.into_bytes();
        b.extend_from_slice(&1.5f64.to_le_bytes());
        b.extend_from_slice(&(-7i16).to_le_bytes());
        b.push(200);
        b.push(0xff);
        for v in [0.1f32, 0.2, 0.3, 2.0, -1.0, -2.0, -3.0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for v in [1u16, 0, 0, 0] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        let s = parse_ply(Path::new("t.ply"), &b).unwrap();
        assert_eq!(s.positions[0], [1.5, -7.0, 200.0]);
        // Elements before and after the vertices (fixed-size) are skipped.
        let with_more = String::from_utf8_lossy(&b)
            .replacen(
                "element vertex 1",
                "element camera 1\nproperty float a\nelement vertex 1",
                1,
            )
            .replacen(
                "end_header",
                "element face 1\nproperty uchar k\nend_header",
                1,
            );
        let hl = with_more.find("end_header\n").unwrap() + 11;
        let mut b2 = with_more.as_bytes()[..hl].to_vec();
        b2.extend_from_slice(&9f32.to_le_bytes());
        b2.extend_from_slice(&b[b.len() - (8 + 4 + 7 * 4 + 8)..]);
        b2.push(5);
        assert_eq!(parse_ply(Path::new("t.ply"), &b2).unwrap(), s);
        assert_eq!(s.opacity_logits[0], 2.0);
        assert_eq!(s.rotations[0], [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(s.sh_degree, 0);
    }
}

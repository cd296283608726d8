//! Reading the vertex records of an INRIA `.ply`, binary little-endian (in parallel
//! blocks of rows, written straight into place) or ASCII (row by row), into a
//! [`Scene`]; `f_rest` is transposed from channel-major into [`Scene::sh_rest`]'s
//! `[k][c]` layout.

use super::ROWS;
use super::header::{Element, Format, Header, PType, parse_header};
use crate::scene::{Scene, sh_coeffs};
use crate::{Error, Result};
use rayon::prelude::*;
use std::path::Path;

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

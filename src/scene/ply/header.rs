//! The PLY header (Turk 1994): the format line, the elements with their counts and
//! scalar properties of any numeric type (list properties are only marked), and the byte
//! offset of the body.

use crate::{Error, Result};
use std::path::Path;

/// Scalar property types of the PLY format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PType {
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
    pub(super) fn size(self) -> usize {
        match self {
            PType::I8 | PType::U8 => 1,
            PType::I16 | PType::U16 => 2,
            PType::I32 | PType::U32 | PType::F32 => 4,
            PType::F64 => 8,
        }
    }
    /// Decode one little-endian value as f32 (`float` bit-exactly).
    pub(super) fn read_le(self, b: &[u8]) -> f32 {
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
    pub(super) fn parse_text(self, t: &str) -> Option<f32> {
        match self {
            PType::F32 => t.parse::<f32>().ok(),
            PType::F64 => t.parse::<f64>().ok().map(|v| v as f32),
            _ => t.parse::<i64>().ok().map(|v| v as f32),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Format {
    Ascii,
    BinaryLe,
}

#[derive(Debug)]
pub(super) struct Element {
    pub(super) name: String,
    pub(super) count: usize,
    pub(super) props: Vec<(String, PType)>,
    /// Set when the element has a list property (only allowed for non-vertex elements
    /// in ASCII files or after the vertex element, where nothing needs to be skipped).
    pub(super) has_list: bool,
}

#[derive(Debug)]
pub(super) struct Header {
    pub(super) format: Format,
    pub(super) elements: Vec<Element>,
    /// Byte offset of the body.
    pub(super) body: usize,
}

pub(super) fn parse_header(path: &Path, bytes: &[u8]) -> Result<Header> {
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

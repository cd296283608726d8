//! NumPy `.npy` tensors (format versions 1.0, 2.0 and 3.0; little-endian; C order).
//!
//! Writing always produces version 1.0 (or 2.0 when the header would not fit), which
//! every NumPy since 1.0 reads. Reading validates the magic, the header dictionary,
//! the dtype and that the data length matches the shape, and names the file on error.

use crate::{Result, SchemaError};
use std::path::Path;

/// Element types we store.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DType {
    F32,
    F64,
    U8,
    I32,
    U32,
    I64,
}

impl DType {
    /// The NumPy `descr` string.
    pub fn descr(self) -> &'static str {
        match self {
            DType::F32 => "<f4",
            DType::F64 => "<f8",
            DType::U8 => "|u1",
            DType::I32 => "<i4",
            DType::U32 => "<u4",
            DType::I64 => "<i8",
        }
    }
    pub fn size(self) -> usize {
        match self {
            DType::U8 => 1,
            DType::F32 | DType::I32 | DType::U32 => 4,
            DType::F64 | DType::I64 => 8,
        }
    }
    fn from_descr(d: &str) -> Option<DType> {
        Some(match d {
            "<f4" => DType::F32,
            "<f8" => DType::F64,
            "|u1" | "<u1" => DType::U8,
            "<i4" => DType::I32,
            "<u4" => DType::U32,
            "<i8" => DType::I64,
            _ => return None,
        })
    }
}

impl std::fmt::Display for DType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            DType::F32 => "f32",
            DType::F64 => "f64",
            DType::U8 => "u8",
            DType::I32 => "i32",
            DType::U32 => "u32",
            DType::I64 => "i64",
        };
        f.write_str(s)
    }
}

/// A Rust element type that maps to a NumPy dtype.
pub trait NpyElement: Copy + Default + 'static {
    const DTYPE: DType;
    fn write_le(self, out: &mut Vec<u8>);
    fn read_le(b: &[u8]) -> Self;
}

macro_rules! elem {
    ($t:ty, $d:expr) => {
        impl NpyElement for $t {
            const DTYPE: DType = $d;
            fn write_le(self, out: &mut Vec<u8>) {
                out.extend_from_slice(&self.to_le_bytes());
            }
            fn read_le(b: &[u8]) -> Self {
                <$t>::from_le_bytes(b.try_into().expect("slice length equals element size"))
            }
        }
    };
}
elem!(f32, DType::F32);
elem!(f64, DType::F64);
elem!(u8, DType::U8);
elem!(i32, DType::I32);
elem!(u32, DType::U32);
elem!(i64, DType::I64);

/// A tensor read from disk: its shape and its elements in C order.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray<T> {
    pub shape: Vec<usize>,
    pub data: Vec<T>,
}

impl<T> NpyArray<T> {
    pub fn len(&self) -> usize {
        self.data.len()
    }
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
}

const MAGIC: &[u8] = b"\x93NUMPY";

/// Encode a tensor as `.npy` bytes. Panics only if `data.len()` differs from the product
/// of `shape` (a programming error, not an input error).
pub fn encode_npy<T: NpyElement>(shape: &[usize], data: &[T]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "npy: data length does not match shape"
    );
    let shape_str = match shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let dict = format!(
        "{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}",
        T::DTYPE.descr(),
        shape_str
    );
    // Header: magic(6) + version(2) + len(2 or 4) + dict + padding + '\n', total % 64 == 0.
    let (major, len_bytes) = if dict.len() + 1 + 10 <= 65535 {
        (1u8, 2usize)
    } else {
        (2u8, 4usize)
    };
    let pre = MAGIC.len() + 2 + len_bytes;
    let total = (pre + dict.len() + 1).div_ceil(64) * 64;
    let hlen = total - pre;
    let mut out = Vec::with_capacity(total + data.len() * T::DTYPE.size());
    out.extend_from_slice(MAGIC);
    out.push(major);
    out.push(0);
    if major == 1 {
        out.extend_from_slice(&(hlen as u16).to_le_bytes());
    } else {
        out.extend_from_slice(&(hlen as u32).to_le_bytes());
    }
    out.extend_from_slice(dict.as_bytes());
    out.resize(total - 1, b' ');
    out.push(b'\n');
    for &x in data {
        x.write_le(&mut out);
    }
    out
}

/// Write a tensor to `path` atomically (temporary sibling, then rename).
pub fn write_npy<T: NpyElement>(path: &Path, shape: &[usize], data: &[T]) -> Result<()> {
    if shape.iter().product::<usize>() != data.len() {
        return Err(SchemaError::invalid(
            path,
            format!(
                "data has {} elements but shape {:?} needs {}",
                data.len(),
                shape,
                shape.iter().product::<usize>()
            ),
        ));
    }
    crate::atomic::atomic_write(path, &encode_npy(shape, data))
}

/// Parse the header of `.npy` bytes: (dtype, shape, offset of the data).
pub fn parse_header(path: &Path, bytes: &[u8]) -> Result<(DType, Vec<usize>, usize)> {
    let bad = |reason: &str| SchemaError::Npy {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    };
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad(
            "missing the \\x93NUMPY magic (not a .npy file, or truncated)",
        ));
    }
    let major = bytes[6];
    let (hlen, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(bad("truncated header"));
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(bad(&format!("unsupported format version {v}"))),
    };
    let end = start
        .checked_add(hlen)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| bad("header length runs past the end of the file"))?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| bad("header is not text"))?;
    let field = |key: &str| -> Option<&str> {
        let k = format!("'{key}':");
        let i = header.find(&k)? + k.len();
        Some(header[i..].trim_start())
    };
    let descr = field("descr").ok_or_else(|| bad("header has no 'descr'"))?;
    let descr = descr
        .strip_prefix('\'')
        .and_then(|s| s.split('\'').next())
        .ok_or_else(|| bad("malformed 'descr'"))?;
    let dtype = DType::from_descr(descr).ok_or_else(|| {
        bad(&format!(
            "unsupported dtype '{descr}' (expected one of <f4 <f8 |u1 <i4 <u4 <i8)"
        ))
    })?;
    let fo = field("fortran_order").ok_or_else(|| bad("header has no 'fortran_order'"))?;
    if fo.starts_with("True") {
        return Err(bad(
            "Fortran-ordered arrays are not supported; save with np.ascontiguousarray",
        ));
    }
    let sh = field("shape").ok_or_else(|| bad("header has no 'shape'"))?;
    let sh = sh
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| bad("malformed 'shape'"))?;
    let mut shape = Vec::new();
    for part in sh.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        shape.push(
            part.trim_end_matches('L')
                .parse::<usize>()
                .map_err(|_| bad(&format!("malformed shape entry '{part}'")))?,
        );
    }
    Ok((dtype, shape, end))
}

/// Read a tensor of element type `T` from `path`. The file's dtype must be `T`'s.
pub fn read_npy<T: NpyElement>(path: &Path) -> Result<NpyArray<T>> {
    let bytes = std::fs::read(path).map_err(|e| SchemaError::io(path, e))?;
    decode_npy(path, &bytes)
}

/// Decode `.npy` bytes (`path` is used in error messages only).
pub fn decode_npy<T: NpyElement>(path: &Path, bytes: &[u8]) -> Result<NpyArray<T>> {
    let (dtype, shape, off) = parse_header(path, bytes)?;
    if dtype != T::DTYPE {
        return Err(SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!("dtype is {dtype}, expected {}", T::DTYPE),
        });
    }
    let n = shape
        .iter()
        .try_fold(1usize, |a, &s| a.checked_mul(s))
        .ok_or_else(|| SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!("shape {shape:?} overflows"),
        })?;
    let sz = dtype.size();
    let body = &bytes[off..];
    if body.len() != n * sz {
        return Err(SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!(
                "shape {shape:?} needs {} data bytes, file has {} (truncated or padded)",
                n * sz,
                body.len()
            ),
        });
    }
    let data = body.chunks_exact(sz).map(T::read_le).collect();
    Ok(NpyArray { shape, data })
}

/// Read an `f32` tensor, checking it has no NaN or infinity.
pub fn read_npy_f32(path: &Path) -> Result<NpyArray<f32>> {
    let a = read_npy::<f32>(path)?;
    if let Some(i) = a.data.iter().position(|x| !x.is_finite()) {
        return Err(SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!("element {i} is {} (NaN or infinity not allowed)", a.data[i]),
        });
    }
    Ok(a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_all_dtypes_and_ranks() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("a.npy");
        write_npy(&p, &[2, 3], &[1.0f32, 2., 3., 4., 5., -6.5]).unwrap();
        let a = read_npy::<f32>(&p).unwrap();
        assert_eq!(a.shape, vec![2, 3]);
        assert_eq!(a.data[5], -6.5);
        write_npy(&p, &[4], &[1u8, 2, 3, 255]).unwrap();
        assert_eq!(read_npy::<u8>(&p).unwrap().data, vec![1, 2, 3, 255]);
        write_npy(&p, &[], &[7i64]).unwrap();
        assert_eq!(read_npy::<i64>(&p).unwrap().shape, Vec::<usize>::new());
        write_npy::<f64>(&p, &[0, 5], &[]).unwrap();
        assert_eq!(read_npy::<f64>(&p).unwrap().shape, vec![0, 5]);
    }

    #[test]
    fn header_is_64_byte_aligned() {
        let b = encode_npy(&[3, 1, 2], &[0f32; 6]);
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0);
        assert_eq!(b[10 + hl - 1], b'\n');
    }

    #[test]
    fn rejects_bad_files_with_the_path() {
        let p = Path::new("x/bad.npy");
        for (bytes, want) in [
            (b"hello".to_vec(), "magic"),
            (
                {
                    let mut b = encode_npy(&[4], &[1f32; 4]);
                    b.truncate(b.len() - 3);
                    b
                },
                "truncated",
            ),
            (encode_npy(&[2], &[1f64; 2]), "dtype is f64"),
        ] {
            let e = decode_npy::<f32>(p, &bytes).unwrap_err().to_string();
            assert!(e.contains("bad.npy") && e.contains(want), "{e}");
        }
    }

    #[test]
    fn nan_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("n.npy");
        write_npy(&p, &[2], &[1.0f32, f32::NAN]).unwrap();
        let e = read_npy_f32(&p).unwrap_err().to_string();
        assert!(e.contains("NaN"), "{e}");
    }
}

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
pub trait NpyElement: Copy + Default + Send + Sync + 'static {
    const DTYPE: DType;
    fn write_le(self, out: &mut Vec<u8>);
    fn read_le(b: &[u8]) -> Self;
    /// Append the little-endian bytes of `data` to `out` (a copy on little-endian
    /// machines: the loop compiles to a memcpy-like move).
    fn extend_le(data: &[Self], out: &mut Vec<u8>);
    /// Decode `bytes` (a multiple of the element size) into `out`.
    fn decode_le(bytes: &[u8], out: &mut Vec<Self>);
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
            fn extend_le(data: &[Self], out: &mut Vec<u8>) {
                const S: usize = std::mem::size_of::<$t>();
                let start = out.len();
                out.resize(start + data.len() * S, 0);
                for (b, x) in out[start..].chunks_exact_mut(S).zip(data) {
                    b.copy_from_slice(&x.to_le_bytes());
                }
            }
            fn decode_le(bytes: &[u8], out: &mut Vec<Self>) {
                const S: usize = std::mem::size_of::<$t>();
                out.extend(
                    bytes
                        .chunks_exact(S)
                        .map(|b| <$t>::from_le_bytes(b.try_into().expect("element size"))),
                );
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

/// The `.npy` header (magic, version, dictionary, padding) of a tensor of `dtype` and
/// `shape`; its length is a multiple of 64.
pub fn npy_header(dtype: DType, shape: &[usize]) -> Vec<u8> {
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
        dtype.descr(),
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
    let mut out = Vec::with_capacity(total);
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
    out
}

/// Encode a tensor as `.npy` bytes. Panics only if `data.len()` differs from the product
/// of `shape` (a programming error, not an input error).
pub fn encode_npy<T: NpyElement>(shape: &[usize], data: &[T]) -> Vec<u8> {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "npy: data length does not match shape"
    );
    let mut out = npy_header(T::DTYPE, shape);
    out.reserve_exact(data.len() * T::DTYPE.size());
    T::extend_le(data, &mut out);
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
    // The byte count, checked: a shape whose elements fit in usize may still need more
    // bytes than usize holds (found by fuzzing: `(4611686018427387904,)` of `<f4`).
    let need = shape
        .iter()
        .try_fold(1usize, |a, &s| a.checked_mul(s))
        .and_then(|n| n.checked_mul(dtype.size()))
        .ok_or_else(|| SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!("shape {shape:?} overflows"),
        })?;
    let body = &bytes[off..];
    if body.len() != need {
        return Err(SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!(
                "shape {shape:?} needs {need} data bytes, file has {} (truncated or padded)",
                body.len()
            ),
        });
    }
    Ok(NpyArray {
        shape,
        data: decode_body::<T>(body),
    })
}

/// Decode little-endian elements, in parallel pieces when there are many.
fn decode_body<T: NpyElement>(body: &[u8]) -> Vec<T> {
    use rayon::prelude::*;
    const PIECE: usize = 1 << 16;
    let sz = T::DTYPE.size();
    let mut data = vec![T::default(); body.len() / sz];
    data.par_chunks_mut(PIECE)
        .zip(body.par_chunks(PIECE * sz))
        .for_each(|(d, b)| {
            for (x, c) in d.iter_mut().zip(b.chunks_exact(sz)) {
                *x = T::read_le(c);
            }
        });
    data
}

/// Read an `f32` tensor, checking it has no NaN or infinity.
pub fn read_npy_f32(path: &Path) -> Result<NpyArray<f32>> {
    let a = read_npy::<f32>(path)?;
    if let Some(i) = first_non_finite(&a.data) {
        return Err(SchemaError::Npy {
            path: path.to_path_buf(),
            reason: format!("element {i} is {} (NaN or infinity not allowed)", a.data[i]),
        });
    }
    Ok(a)
}

/// Index of the first NaN or infinity (searched in parallel).
pub(crate) fn first_non_finite(v: &[f32]) -> Option<usize> {
    use rayon::prelude::*;
    v.par_iter().position_first(|x| !x.is_finite())
}

/// A `.npy` file read in pieces along its first axis (say one view of `[N, H, W, 3]`
/// at a time), so that a reader holds a few items instead of the whole tensor. The
/// header, dtype and file length are checked on [`NpyReader::open`].
#[derive(Debug)]
pub struct NpyReader<T> {
    path: std::path::PathBuf,
    file: std::io::BufReader<std::fs::File>,
    shape: Vec<usize>,
    item: usize,
    next: usize,
    buf: Vec<u8>,
    _t: std::marker::PhantomData<T>,
}

impl<T: NpyElement> NpyReader<T> {
    /// Open `path`, whose dtype must be `T`'s and whose rank must be at least 1.
    pub fn open(path: &Path) -> Result<Self> {
        use std::io::Read;
        let io = |e| SchemaError::io(path, e);
        let f = std::fs::File::open(path).map_err(io)?;
        let len = f.metadata().map_err(io)?.len();
        let mut file = std::io::BufReader::with_capacity(1 << 20, f);
        // Magic, version and the header length, then the header itself.
        let mut head = vec![0u8; 12.min(len as usize)];
        file.read_exact(&mut head).map_err(io)?;
        let (hlen, start) = match head.get(6) {
            Some(1) if head.len() >= 10 => (u16::from_le_bytes([head[8], head[9]]) as usize, 10),
            Some(2 | 3) if head.len() >= 12 => (
                u32::from_le_bytes([head[8], head[9], head[10], head[11]]) as usize,
                12,
            ),
            _ => (0, 0),
        };
        let end = start + hlen;
        if end > head.len() && (end as u64) <= len {
            let mut rest = vec![0u8; end - head.len()];
            file.read_exact(&mut rest).map_err(io)?;
            head.extend_from_slice(&rest);
        }
        let (dtype, shape, off) = parse_header(path, &head)?;
        if dtype != T::DTYPE {
            return Err(SchemaError::Npy {
                path: path.to_path_buf(),
                reason: format!("dtype is {dtype}, expected {}", T::DTYPE),
            });
        }
        if shape.is_empty() {
            return Err(SchemaError::Npy {
                path: path.to_path_buf(),
                reason: "a scalar cannot be read item by item".into(),
            });
        }
        let n = shape.iter().try_fold(1usize, |a, &s| a.checked_mul(s));
        let need = n.and_then(|n| n.checked_mul(dtype.size()));
        let body = len.saturating_sub(off as u64);
        if need.map(|b| b as u64) != Some(body) {
            return Err(SchemaError::Npy {
                path: path.to_path_buf(),
                reason: format!(
                    "shape {shape:?} needs {} data bytes, file has {body} (truncated or padded)",
                    need.map_or("too many".to_string(), |b| b.to_string())
                ),
            });
        }
        // The body's size matched, so the item's element count fits unless the first
        // axis is 0 (found by fuzzing: `(0, 2^40, 2^40)` overflowed the product).
        let item = shape[1..]
            .iter()
            .try_fold(1usize, |a, &s| a.checked_mul(s))
            .filter(|i| i.checked_mul(dtype.size()).is_some())
            .ok_or_else(|| SchemaError::Npy {
                path: path.to_path_buf(),
                reason: format!("shape {shape:?} overflows"),
            })?;
        Ok(NpyReader {
            path: path.to_path_buf(),
            file,
            shape,
            item,
            next: 0,
            buf: Vec::new(),
            _t: std::marker::PhantomData,
        })
    }

    /// The tensor's shape.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Elements per item (the product of the shape after the first axis).
    pub fn item_len(&self) -> usize {
        self.item
    }

    /// Items not read yet.
    pub fn remaining(&self) -> usize {
        self.shape[0] - self.next
    }

    /// Replace `out` with the next `k` items (at most [`Self::remaining`]).
    pub fn read_items(&mut self, k: usize, out: &mut Vec<T>) -> Result<()> {
        use std::io::Read;
        if k > self.remaining() {
            return Err(SchemaError::invalid(
                &self.path,
                format!("asked for {k} items, {} remain", self.remaining()),
            ));
        }
        self.buf.resize(k * self.item * T::DTYPE.size(), 0);
        self.file
            .read_exact(&mut self.buf)
            .map_err(|e| SchemaError::io(&self.path, e))?;
        out.clear();
        T::decode_le(&self.buf, out);
        self.next += k;
        Ok(())
    }
}

impl NpyReader<f32> {
    /// [`Self::read_items`], refusing NaN and infinity (naming the element).
    pub fn read_items_finite(&mut self, k: usize, out: &mut Vec<f32>) -> Result<()> {
        let first = self.next * self.item;
        self.read_items(k, out)?;
        if let Some(i) = out.iter().position(|x| !x.is_finite()) {
            return Err(SchemaError::Npy {
                path: self.path.clone(),
                reason: format!(
                    "element {} is {} (NaN or infinity not allowed)",
                    first + i,
                    out[i]
                ),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fuzzing regressions (tests/integration/fuzz_npy_manifests.rs): shapes whose byte count or
    /// per-item element count overflows usize are errors, not overflow panics.
    #[test]
    fn overflowing_shapes_are_errors() {
        let p = Path::new("big.npy");
        let mut b = npy_header(DType::F32, &[4_611_686_018_427_387_904]);
        b.extend_from_slice(&[0; 16]);
        let e = decode_npy::<f32>(p, &b).unwrap_err().to_string();
        assert!(e.contains("big.npy") && e.contains("overflows"), "{e}");
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("zero.npy");
        std::fs::write(&f, npy_header(DType::F32, &[0, 1 << 40, 1 << 40])).unwrap();
        let e = NpyReader::<f32>::open(&f).err().unwrap().to_string();
        assert!(e.contains("zero.npy") && e.contains("overflows"), "{e}");
    }

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

    #[test]
    fn reader_reads_items_in_pieces_and_checks_the_file() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("v.npy");
        let data: Vec<f32> = (0..5 * 2 * 3).map(|i| i as f32).collect();
        write_npy(&p, &[5, 2, 3], &data).unwrap();
        let mut r = NpyReader::<f32>::open(&p).unwrap();
        assert_eq!(
            (r.shape(), r.item_len(), r.remaining()),
            (&[5, 2, 3][..], 6, 5)
        );
        let mut got = Vec::new();
        let mut all = Vec::new();
        for k in [2, 1, 2] {
            r.read_items_finite(k, &mut got).unwrap();
            assert_eq!(got.len(), k * 6);
            all.extend_from_slice(&got);
        }
        assert_eq!(all, data);
        assert!(
            r.read_items(1, &mut got)
                .unwrap_err()
                .to_string()
                .contains("0 remain")
        );
        // Truncated, wrong dtype, NaN.
        let mut b = std::fs::read(&p).unwrap();
        b.truncate(b.len() - 4);
        std::fs::write(&p, &b).unwrap();
        let e = NpyReader::<f32>::open(&p).unwrap_err().to_string();
        assert!(e.contains("v.npy") && e.contains("truncated"), "{e}");
        write_npy(&p, &[2], &[1.0f64, 2.0]).unwrap();
        assert!(
            NpyReader::<f32>::open(&p)
                .unwrap_err()
                .to_string()
                .contains("dtype is f64")
        );
        write_npy(&p, &[2, 1], &[1.0f32, f32::NAN]).unwrap();
        let mut r = NpyReader::<f32>::open(&p).unwrap();
        let e = r.read_items_finite(2, &mut got).unwrap_err().to_string();
        assert!(e.contains("element 1") && e.contains("NaN"), "{e}");
        std::fs::write(&p, b"\x93NUMPY").unwrap();
        assert!(NpyReader::<f32>::open(&p).is_err());
    }
}

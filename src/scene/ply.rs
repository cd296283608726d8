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
//!
//! One module per part: `header` (the header's lines, elements and property types),
//! `read` (the vertex records, binary or ASCII, into a [`Scene`](super::Scene)) and
//! `write` (the INRIA layout, binary or ASCII).

mod header;
mod read;
mod write;

pub use read::{parse_ply, read_ply};
pub use write::{encode_ply, encode_ply_ascii, write_ply};

/// Rows per parallel task of the binary reader and writer.
const ROWS: usize = 8192;

#[cfg(test)]
mod tests;

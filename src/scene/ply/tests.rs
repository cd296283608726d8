//! Round trips (binary and ASCII, bit-exact), corrupted files, the `f_rest` layout and
//! foreign property types and extra properties.

use super::write::{header_text, property_names, record};
use super::*;
use crate::scene::{Scene, sh_coeffs};
use std::path::Path;

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

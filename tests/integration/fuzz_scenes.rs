//! Fuzzing the scene readers (the machinery is in `fuzz`): PLY, binary and ASCII, with
//! its header lines edited too, and `.splat`; a returned scene is valid, and a header's
//! vertex count reserves no memory.

use crate::fuzz::{apply, apply_lines, edit, fuzz, guarded, line_edit, names_file};
use fantasystyle::Scene;
use fantasystyle::scene::{ply, splat};
use proptest::prelude::*;
use std::path::Path;

/// A small valid scene of `n` Gaussians at SH degree `deg`.
pub(crate) fn scene(n: usize, deg: usize, seed: u64) -> Scene {
    let mut r = fantasystyle::rng::Rng::new(seed);
    let mut u = || r.uniform() as f32;
    let k = (deg + 1) * (deg + 1) - 1;
    Scene {
        positions: (0..n).map(|_| [u() - 0.5, u() - 0.5, u() - 0.5]).collect(),
        log_scales: (0..n)
            .map(|_| [-3.0 - u(), -3.0 - u(), -3.0 - u()])
            .collect(),
        rotations: (0..n).map(|_| [1.0, u() - 0.5, 0.0, 0.1]).collect(),
        opacity_logits: (0..n).map(|_| 4.0 * u() - 2.0).collect(),
        sh_degree: deg,
        sh_dc: (0..n).map(|_| [u() - 0.5, u() - 0.5, u() - 0.5]).collect(),
        sh_rest: (0..n * k * 3).map(|_| 0.1 * (u() - 0.5)).collect(),
    }
}

/// The scene as an ASCII PLY with the INRIA properties in a shuffled order, normals,
/// a `uchar` and a `double` extra, a comment, and a `face` element after the vertices.
fn ascii_ply(s: &Scene, seed: u64) -> Vec<u8> {
    let k = s.rest_per_channel();
    let mut props: Vec<(String, &str)> = ["x", "y", "z", "nx", "ny", "nz"]
        .iter()
        .map(|p| (p.to_string(), "float"))
        .collect();
    props.extend((0..3).map(|c| (format!("f_dc_{c}"), "float")));
    props.extend((0..3 * k).map(|j| (format!("f_rest_{j}"), "float")));
    props.push(("opacity".into(), "float"));
    props.extend((0..3).map(|c| (format!("scale_{c}"), "float")));
    props.extend((0..4).map(|c| (format!("rot_{c}"), "float")));
    props.push(("red".into(), "uchar"));
    props.push(("extra".into(), "double"));
    // A deterministic shuffle.
    let mut r = fantasystyle::rng::Rng::new(seed);
    for i in (1..props.len()).rev() {
        let j = (r.uniform() * (i + 1) as f64) as usize % (i + 1);
        props.swap(i, j);
    }
    let mut out = format!(
        "ply\nformat ascii 1.0\ncomment fuzz seed\nelement vertex {}\n",
        s.len()
    );
    for (p, t) in &props {
        out += &format!("property {t} {p}\n");
    }
    out += "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    for i in 0..s.len() {
        let val = |p: &str| -> String {
            let f = |v: f32| format!("{v}");
            match p {
                "x" => f(s.positions[i][0]),
                "y" => f(s.positions[i][1]),
                "z" => f(s.positions[i][2]),
                "nx" | "ny" | "nz" => "0".into(),
                "opacity" => f(s.opacity_logits[i]),
                "red" => "200".into(),
                "extra" => "2.5".into(),
                _ => {
                    let (name, idx) = p.rsplit_once('_').unwrap();
                    let idx: usize = idx.parse().unwrap();
                    match name {
                        "f_dc" => f(s.sh_dc[i][idx]),
                        "scale" => f(s.log_scales[i][idx]),
                        "rot" => f(s.rotations[i][idx]),
                        "f_rest" => {
                            let (c, kk) = (idx / k, idx % k);
                            f(s.sh_rest[(i * k + kk) * 3 + c])
                        }
                        _ => unreachable!("{p}"),
                    }
                }
            }
        };
        let row: Vec<String> = props.iter().map(|(p, _)| val(p)).collect();
        out += &row.join(" ");
        out.push('\n');
    }
    out += "3 0 1 2\n";
    out.into_bytes()
}

fn ply_seeds() -> Vec<Vec<u8>> {
    let mut v = Vec::new();
    for (n, deg, seed) in [(1, 0, 1), (3, 1, 2), (5, 2, 3), (2, 3, 4), (9, 0, 5)] {
        let s = scene(n, deg, seed);
        v.push(ply::encode_ply(&s));
        v.push(ascii_ply(&s, seed));
    }
    v
}

fn header_lines(b: &[u8]) -> usize {
    let end = b
        .windows(11)
        .position(|w| w == b"end_header\n")
        .map_or(b.len(), |p| p + 11);
    b[..end].iter().filter(|c| **c == b'\n').count()
}

fn check_scene(r: fantasystyle::Result<Scene>, name: &str, len: usize) -> Result<(), String> {
    names_file(&r, name)?;
    if let Ok(s) = r {
        s.validate(Path::new(name))
            .map_err(|e| format!("returned an invalid scene: {e}"))?;
        if s.len() > len {
            return Err(format!("{} Gaussians from {len} bytes", s.len()));
        }
    }
    Ok(())
}

#[test]
fn fuzz_ply() {
    let seeds = ply_seeds();
    for s in &seeds {
        ply::parse_ply(Path::new("seed.ply"), s).expect("the seeds are valid");
    }
    let strategy = (
        prop::sample::select(seeds),
        prop::collection::vec(line_edit(), 0..3),
        prop::collection::vec(edit(), 0..4),
    );
    fuzz("ply", 3000, strategy, |(mut b, lines, edits)| {
        let head = header_lines(&b);
        apply_lines(&mut b, &lines, Some(head));
        apply(&mut b, &edits);
        let len = b.len();
        let r = guarded(len, move || ply::parse_ply(Path::new("fuzz.ply"), &b))?;
        check_scene(r, "fuzz.ply", len)
    });
}

/// A header that claims 4e9 (or 2^64 - 1) vertices over a few bytes of data: refused
/// without reserving them.
#[test]
fn ply_header_counts_do_not_reserve_memory() {
    let s = scene(3, 1, 9);
    for b in [ply::encode_ply(&s), ascii_ply(&s, 9)] {
        let text = String::from_utf8_lossy(&b[..b.len().min(4000)]).into_owned();
        for claim in ["4000000000", "18446744073709551615", "1152921504606846976"] {
            let bad = String::from_utf8_lossy(&b)
                .replacen("element vertex 3", &format!("element vertex {claim}"), 1)
                .into_bytes();
            assert!(text.contains("element vertex 3"));
            let len = bad.len();
            let r = guarded(len, move || ply::parse_ply(Path::new("big.ply"), &bad))
                .unwrap_or_else(|e| panic!("claim {claim}: {e}"));
            let e = r.expect_err("a lying count").to_string();
            assert!(e.contains("big.ply"), "{e}");
        }
    }
}

#[test]
fn fuzz_splat() {
    let seeds: Vec<Vec<u8>> = [(1, 1), (4, 2), (17, 3)]
        .iter()
        .map(|&(n, seed)| splat::encode_splat(&scene(n, 0, seed)))
        .collect();
    let strategy = (
        prop::sample::select(seeds),
        prop::collection::vec(edit(), 0..4),
    );
    fuzz("splat", 2000, strategy, |(mut b, edits)| {
        apply(&mut b, &edits);
        let len = b.len();
        let r = guarded(len, move || splat::parse_splat(Path::new("fuzz.splat"), &b))?;
        check_scene(r, "fuzz.splat", len)
    });
}

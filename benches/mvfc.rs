//! MVFC filter vs numpy's FFT on the same arrays (issue 5).
//!
//! `cargo bench --bench mvfc` writes random latents [N, 4, s, s] for N in {4, 8, 32} and
//! s in {64, 128} as .npy into `bench-out/mvfc/`, runs
//! `scripts/reference/mvfc_bench.py` on them (numpy, single-threaded pocketfft), times
//! our filter in the same process run (plan made once, as the stage does; 1 rayon thread
//! and all cores), checks both agree, and prints the markdown table for BENCHMARKS.md
//! (also written to `bench-out/mvfc/table.md`). Times are medians.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]

use fantasystyle::mvfc::{MvfcFilter, MvfcParams};
use fantasystyle::rng::Rng;
use ndarray::{Array3, Array4};
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("bench-out/mvfc");
    std::fs::create_dir_all(&dir).unwrap();
    let reps: usize = std::env::var("MVFC_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(7);
    let params = MvfcParams::default();
    let mut cases = Vec::new();
    let mut meta = serde_json::Map::new();
    for &s in &[64usize, 128] {
        for &n in &[4usize, 8, 32] {
            let name = format!("n{n}_s{s}");
            let shape = [n, 4, s, s];
            let mut rng = Rng::derive(7, &name);
            let z = Array4::from_shape_vec(shape, rng.normals_f32(n * 4 * s * s)).unwrap();
            let e = Array3::from_shape_vec([4, s, s], rng.normals_f32(4 * s * s)).unwrap();
            fantasystyle_schemas::write_npy(
                &dir.join(format!("{name}_z.npy")),
                &shape,
                z.as_slice().unwrap(),
            )
            .unwrap();
            fantasystyle_schemas::write_npy(
                &dir.join(format!("{name}_eps.npy")),
                &[4, s, s],
                e.as_slice().unwrap(),
            )
            .unwrap();
            meta.insert(
                name.clone(),
                serde_json::json!({"gamma": params.gamma, "d_s": params.d_s, "d_t": params.d_t}),
            );
            cases.push((name, shape, z, e));
        }
    }
    std::fs::write(
        dir.join("cases.json"),
        serde_json::to_string(&serde_json::Value::Object(meta)).unwrap(),
    )
    .unwrap();

    let py = root.join("vendor/venv/bin/python");
    let out = Command::new(&py)
        .env("OMP_NUM_THREADS", "1")
        .arg(root.join("scripts/reference/mvfc_bench.py"))
        .arg(&dir)
        .arg(reps.to_string())
        .output()
        .expect("running scripts/reference/mvfc_bench.py (run scripts/setup.sh first)");
    assert!(
        out.status.success(),
        "numpy bench failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let np: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();

    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let cores = rayon::current_num_threads();
    let mut table = String::new();
    table.push_str(&format!(
        "| views x 4 ch x size | numpy paper form (ms) | numpy 1-FFT form (ms) | ours, 1 thread (ms) | ours, {cores} threads (ms) | numpy paper / ours {cores}t | numpy 1-FFT / ours 1t | max abs diff |\n|---|---|---|---|---|---|---|---|\n"
    ));
    for (name, shape, z, e) in &cases {
        let f = MvfcFilter::new(*shape, params).unwrap();
        let time = |pool: Option<&rayon::ThreadPool>| {
            let run = || {
                let t0 = Instant::now();
                let o = f.apply(z.view(), e.view()).unwrap();
                (t0.elapsed().as_secs_f64(), o)
            };
            let mut ts = Vec::new();
            let mut last = None;
            for _ in 0..reps {
                let (t, o) = match pool {
                    Some(p) => p.install(run),
                    None => run(),
                };
                ts.push(t);
                last = Some(o);
            }
            (median(ts), last.unwrap())
        };
        let (t1, _) = time(Some(&one));
        let (tn, o) = time(None);
        let want = fantasystyle_schemas::read_npy_f32(&dir.join(format!("{name}_numpy.npy")))
            .unwrap()
            .data;
        let err = o
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        let p = np[name]["paper_s"].as_f64().unwrap();
        let l = np[name]["linear_s"].as_f64().unwrap();
        table.push_str(&format!(
            "| {} x 4 x {}x{} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1}x | {:.1}x | {:.1e} |\n",
            shape[0],
            shape[2],
            shape[3],
            p * 1e3,
            l * 1e3,
            t1 * 1e3,
            tn * 1e3,
            p / tn,
            l / t1,
            err
        ));
        assert!(err < 1e-4, "{name}: ours and numpy disagree by {err}");
    }
    println!("{table}");
    std::fs::write(dir.join("table.md"), &table).unwrap();
}

//! VGG16 forward + backward and the baseline objectives, per 256x256 image (issue 8).
//!
//! `cargo bench --bench baselines` times, on the Rust engine and on onnxruntime, each with
//! 1 and 2 threads, in the same run: VGG16 forward to relu4_3, forward + backward
//! (gradient of a loss on relu1_2..relu4_3 w.r.t. the image), one Gram objective
//! evaluation (two scales, four layers, content) and one NNFM evaluation (relu3 block,
//! 256x256 style). Real weights
//! from `vendor/models/lpips/vgg16` when present, else He-random full-width weights.
//! Prints the markdown table for BENCHMARKS.md. Times are medians of `BASELINES_BENCH_REPS`
//! (default 5) runs.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]

use fantasystyle::baselines::Objective;
use fantasystyle::baselines::gram::{GramConfig, GramObjective};
use fantasystyle::baselines::nnfm::{NnfmConfig, NnfmObjective};
use fantasystyle::imageio::Image;
use fantasystyle::rng::Rng;
use fantasystyle::vgg::{Layer, Tensor3, Vgg16};
use std::path::PathBuf;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn time<F: FnMut()>(reps: usize, mut f: F) -> f64 {
    f();
    median(
        (0..reps)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    )
}

fn image(seed: u64, s: usize) -> Image {
    let mut r = Rng::new(seed);
    Image {
        width: s,
        height: s,
        data: (0..s * s * 3).map(|_| r.uniform() as f32).collect(),
    }
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let reps: usize = std::env::var("BASELINES_BENCH_REPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let wdir = root.join("vendor/models/lpips/vgg16");
    let (vgg, which) = match Vgg16::load(&wdir) {
        Ok(v) => (v, "real VGG16 weights"),
        Err(_) => (Vgg16::random(1, 1), "random full-width weights"),
    };
    let s = 256;
    let x = image(1, s);
    let style = image(2, s);
    let orig = image(3, s);
    let taps = [
        Layer::Relu1_2,
        Layer::Relu2_2,
        Layer::Relu3_3,
        Layer::Relu4_3,
    ];
    let mut rows = Vec::new();
    for engine in ["Rust", "onnxruntime"] {
        for threads in [1usize, 2] {
            let vgg = match engine {
                "Rust" => vgg.clone(),
                _ => match vgg.clone().on_onnxruntime(threads) {
                    Ok(v) => v,
                    Err(e) => {
                        eprintln!("onnxruntime engine skipped: {e}");
                        continue;
                    }
                },
            };
            let gram = GramObjective::new(
                &vgg,
                GramConfig::default(),
                &style,
                std::slice::from_ref(&orig),
            )
            .unwrap();
            let nnfm = NnfmObjective::new(
                &vgg,
                NnfmConfig::default(),
                &style,
                std::slice::from_ref(&orig),
            )
            .unwrap();
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let fwd = time(reps, || {
                    vgg.forward(&x.data, s, s, Layer::Relu4_3).unwrap();
                });
                let fb = time(reps, || {
                    let f = vgg.forward(&x.data, s, s, Layer::Relu4_3).unwrap();
                    let g: Vec<(Layer, Tensor3)> =
                        taps.iter().map(|&l| (l, f.get(l).clone())).collect();
                    let r: Vec<(Layer, &Tensor3)> = g.iter().map(|(l, t)| (*l, t)).collect();
                    vgg.backward(&f, &r).unwrap();
                });
                let g = time(reps, || {
                    gram.eval(0, &x).unwrap();
                });
                let n = time(reps, || {
                    nnfm.eval(0, &x).unwrap();
                });
                rows.push((engine, threads, fwd, fb, g, n));
            });
        }
    }
    println!("VGG16 to relu4_3 on one 256x256 image, {which}, median of {reps} (ms):\n");
    println!(
        "| engine | threads | forward | forward + backward | Gram objective (2 scales) | NNFM objective |"
    );
    println!("|---|---|---|---|---|---|");
    for (e, t, a, b, c, d) in &rows {
        println!("| {e} | {t} | {a:.0} | {b:.0} | {c:.0} | {d:.0} |");
    }
    for e in ["Rust", "onnxruntime"] {
        let fb: Vec<f64> = rows.iter().filter(|r| r.0 == e).map(|r| r.3).collect();
        if let [one, two] = fb[..] {
            println!(
                "\n{e}: forward + backward speed-up 2 threads vs 1: {:.2}x",
                one / two
            );
        }
    }
    if let (Some(r), Some(o)) = (
        rows.iter().find(|r| r.0 == "Rust" && r.1 == 2),
        rows.iter().find(|r| r.0 == "onnxruntime" && r.1 == 2),
    ) {
        println!(
            "onnxruntime vs Rust at 2 threads: forward {:.2}x, forward + backward {:.2}x faster",
            r.2 / o.2,
            r.3 / o.3
        );
    }
}

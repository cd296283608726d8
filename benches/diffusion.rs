//! Benchmark: the diffusion path's speed-accuracy trade and its cost model.
//!
//! `cargo bench --bench diffusion` (release). Model: `$BENCH_MODEL` (default: the committed
//! tiny fixture `tests/fixtures/tiny-sd15`; for real sizes export a random-weight SD 1.5
//! with `scripts/export_models.py --random full --family sd15 --controlnet depth
//! --ip-adapter --out DIR`), `$BENCH_MODEL_FP16` (optional, the same with `--fp16`).
//! One evaluation = `OnnxPrior::predict_eps` with CSD's four conditionings on `views`
//! latents (the UNet sees 4 x views rows, the ControlNet the same batch) = one CSD step's
//! model work; a run is iterations x that, plus the VAE.
//!
//! Tables: time per evaluation over latent size x views x intra-op threads, against the
//! cost model ([`fantasystyle::prior::cost`]) before calibration (nominal rates) and
//! after calibrating on the first row; time and numerical deviation over onnxruntime's
//! graph optimisation levels and fp16 weights; VAE decode time; iterations (consecutive
//! evaluations against the calibrated prediction). 1-thread rows use the calling
//! thread's CPU time (onnxruntime computes on the caller), which a loaded machine does
//! not inflate; other rows are wall clock. Env: `BENCH_SIZES` (latent sizes, default
//! `16,32`), `BENCH_VIEWS` (`1,2,4`), `BENCH_THREADS` (`1,2`), `BENCH_REPS` (3).
//! Writes the tables to stdout and `bench-out/diffusion.md`.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]

use fantasystyle::prior::cost::{CostModel, GraphBytes, Plan};
use fantasystyle::prior::manifest::ModelManifest;
use fantasystyle::prior::{Cond, OnnxPrior, Prior, PriorOptions};
use fantasystyle::runtime::{Device, Optimization};
use ndarray::Array4;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

const CONDS: [Cond; 4] = [Cond::PromptStyle, Cond::Content, Cond::Prompt, Cond::Null];

fn list(name: &str, default: &str) -> Vec<usize> {
    std::env::var(name)
        .unwrap_or_else(|_| default.into())
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// CPU time of the calling thread.
fn thread_cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap_or_default();
    s.split_whitespace()
        .next()
        .and_then(|v| v.parse::<u64>().ok())
        .unwrap_or(0) as f64
        * 1e-9
}

/// Seconds `f` takes: the thread's CPU time with one intra-op thread, else wall clock.
fn timed<T>(threads: usize, f: impl FnOnce() -> T) -> (T, f64) {
    let (c, w) = (thread_cpu_s(), Instant::now());
    let out = f();
    let s = if threads == 1 {
        thread_cpu_s() - c
    } else {
        w.elapsed().as_secs_f64()
    };
    (out, s)
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

struct Bench {
    style: Array4<f32>,
    reps: usize,
}

impl Bench {
    fn open(&self, dir: &Path, threads: usize, optimization: Optimization) -> OnnxPrior {
        OnnxPrior::open(
            dir,
            &PriorOptions {
                style_image: Some(self.style.clone()),
                threads,
                optimization,
                ..Default::default()
            },
        )
        .expect("open the bench model")
    }

    fn inputs(views: usize, s: usize, f: usize) -> (Array4<f32>, Array4<f32>) {
        let mut rng = fantasystyle::rng::Rng::new(7);
        let z =
            Array4::from_shape_vec((views, 4, s, s), rng.normals_f32(views * 4 * s * s)).unwrap();
        let ctrl = Array4::from_shape_fn((views, 3, s * f, s * f), |(v, _, y, x)| {
            ((x + y + v) % 7) as f32 / 6.0
        });
        (z, ctrl)
    }

    /// (median seconds per evaluation, the eps of the last one).
    fn eval(&self, p: &mut OnnxPrior, views: usize, s: usize, threads: usize) -> (f64, Vec<f32>) {
        let f = p.info().downsample;
        let (z, ctrl) = Self::inputs(views, s, f);
        let c = p.info().control.is_some().then(|| ctrl.view());
        let mut run = || p.predict_eps(z.view(), 500, &CONDS, c).unwrap();
        run(); // warm-up (first-run allocations, kernel selection)
        let mut times = Vec::new();
        let mut last = Vec::new();
        for _ in 0..self.reps {
            let (e, t) = timed(threads, &mut run);
            times.push(t);
            last = e.iter().flat_map(|a| a.iter().copied()).collect();
        }
        (median(times), last)
    }
}

fn rel(a: &[f32], b: &[f32]) -> f64 {
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    (d / b.iter().fold(0f32, |m, x| m.max(x.abs())).max(1e-12)) as f64
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = std::env::var("BENCH_MODEL")
        .map(PathBuf::from)
        .unwrap_or_else(|_| root.join("tests/fixtures/tiny-sd15"));
    let sizes = list("BENCH_SIZES", "16,32");
    let views = list("BENCH_VIEWS", "1,2,4");
    let threads = list("BENCH_THREADS", "1,2");
    let reps = list("BENCH_REPS", "3")[0].max(1);
    let md = ModelManifest::load(&dir).expect("model.json");
    let bytes = GraphBytes::of(&md).unwrap().expect("a diffusion model");
    let b = Bench {
        style: Array4::from_shape_fn((1, 3, 224, 224), |(_, c, y, x)| {
            ((x * 3 + y * (c + 1)) % 17) as f32 / 16.0
        }),
        reps,
    };
    let mut out = String::new();
    writeln!(
        out,
        "Model `{}` ({}): UNet + ControlNet {:.1} MB, VAE decoder {:.1} MB. Load average \
         at start: {}. Median of {reps} after one warm-up.\n",
        md.manifest.name,
        dir.display(),
        (bytes.unet + bytes.controlnet) as f64 / 1e6,
        bytes.vae_decoder as f64 / 1e6,
        load_average()
    )
    .unwrap();

    // 1. Size x views x threads against the cost model.
    writeln!(
        out,
        "| latent | views | threads | rows | measured (s) | model, nominal (s) | model, calibrated on row 1 (s) | calibrated / measured |\n|---|---|---|---|---|---|---|---|"
    )
    .unwrap();
    let mut first: Option<CostModel> = None;
    let mut reference = None;
    for &t in &threads {
        let mut p = b.open(&dir, t, Optimization::All);
        let nominal = CostModel::new(bytes, t, Device::Cpu);
        for &s in &sizes {
            for &v in &views {
                let (secs, eps) = b.eval(&mut p, v, s, t);
                if reference.is_none() {
                    reference = Some((v, s, eps));
                }
                let plan = Plan {
                    evaluations: 1,
                    batch: v * CONDS.len(),
                    latent: (s, s),
                    downsample: 8,
                    ..Default::default()
                };
                let cal = first.get_or_insert_with(|| {
                    let mut c = nominal.clone();
                    c.calibrate_unet(plan.batch, plan.latent, secs);
                    c
                });
                // Calibrated at 1 thread; other thread counts scale as the model says.
                let mut scaled = nominal.clone();
                scaled.unet_rate = cal.unet_rate * nominal.unet_rate
                    / CostModel::new(bytes, threads[0], Device::Cpu).unet_rate;
                let (pn, pc) = (nominal.seconds(&plan), scaled.seconds(&plan));
                writeln!(
                    out,
                    "| {s}x{s} | {v} | {t} | {} | {secs:.3} | {pn:.3} | {pc:.3} | {:.2} |",
                    plan.batch,
                    pc / secs
                )
                .unwrap();
                eprintln!("{s}x{s} views {v} threads {t}: {secs:.3} s");
            }
        }
    }
    let (rv, rs, reps_eps) = reference.expect("at least one point");

    // 2. Optimisation levels: time and deviation from `All`.
    writeln!(
        out,
        "\nGraph optimisation level ({rs}x{rs} latents, {rv} view(s), 1 thread):\n\n| level | time (s) | max rel. deviation of eps from `all` |\n|---|---|---|"
    )
    .unwrap();
    for (name, level) in [
        ("disable", Optimization::Disable),
        ("basic", Optimization::Basic),
        ("extended", Optimization::Extended),
        ("all", Optimization::All),
    ] {
        let (mut p, load) = timed(1, || b.open(&dir, 1, level));
        let (secs, eps) = b.eval(&mut p, rv, rs, 1);
        writeln!(
            out,
            "| {name} | {secs:.3} (session creation {load:.2}) | {:.1e} |",
            rel(&eps, &reps_eps)
        )
        .unwrap();
    }

    // 3. fp16 weights.
    if let Ok(d16) = std::env::var("BENCH_MODEL_FP16") {
        let mut p = b.open(Path::new(&d16), 1, Optimization::All);
        let (secs, eps) = b.eval(&mut p, rv, rs, 1);
        writeln!(
            out,
            "\nfp16 weights (`{d16}`), same point: {secs:.3} s, max rel. deviation of eps from \
             fp32 {:.1e}.",
            rel(&eps, &reps_eps)
        )
        .unwrap();
    }

    // 4. VAE decode, and iterations.
    let mut p = b.open(&dir, 1, Optimization::All);
    writeln!(out, "\nVAE decode, 1 thread:\n\n| image | views | measured (s) | model, nominal (s) |\n|---|---|---|---|").unwrap();
    let nominal = CostModel::new(bytes, 1, Device::Cpu);
    for &s in &sizes {
        let (z, _) = Bench::inputs(1, s, 8);
        p.decode(z.view()).unwrap();
        let secs = median(
            (0..reps)
                .map(|_| timed(1, || p.decode(z.view()).unwrap()).1)
                .collect(),
        );
        let plan = Plan {
            latent: (s, s),
            downsample: 8,
            decodes: 1,
            ..Default::default()
        };
        writeln!(
            out,
            "| {0}x{0} | 1 | {secs:.3} | {1:.3} |",
            s * 8,
            nominal.seconds(&plan)
        )
        .unwrap();
    }
    let iters = 3;
    let (z, ctrl) = Bench::inputs(rv, rs, 8);
    let c = p.info().control.is_some().then(|| ctrl.view());
    let (_, one) = timed(1, || p.predict_eps(z.view(), 500, &CONDS, c).unwrap());
    let (_, all) = timed(1, || {
        for _ in 0..iters {
            p.predict_eps(z.view(), 500, &CONDS, c).unwrap();
        }
    });
    writeln!(
        out,
        "\nIterations ({rs}x{rs}, {rv} view(s), 1 thread): {iters} consecutive evaluations took \
         {all:.3} s; calibrated on one ({one:.3} s) the model predicts {:.3} s (ratio {:.2}).\n\n\
         Load average at the end: {}.",
        one * iters as f64,
        one * iters as f64 / all,
        load_average()
    )
    .unwrap();
    println!("{out}");
    let _ = std::fs::create_dir_all(root.join("bench-out"));
    let _ = std::fs::write(root.join("bench-out/diffusion.md"), &out);
}

//! Rasterizer and colour-fit benchmarks (issue: foundation, issue: update-gaussians).
//!
//! `cargo bench --bench render` prints markdown tables ("Rasterizer", its thread scaling,
//! "Colour fit") and writes them to `bench-out/render.md`. Every case runs in a child
//! process (this binary with `--case THREADS ...`) on a rayon pool of that many threads
//! (2 unless the table says otherwise), so that its peak resident memory (`VmHWM` from
//! `/proc/self/status`, which includes the loaded scene and the process baseline)
//! belongs to that case alone. The thread-scaling table runs each case on 1 and on 2
//! threads in turn, [`SCALING_ROUNDS`] times, and takes medians: pairing the two keeps
//! the ratio meaningful while the machine's speed drifts.
//!
//! Cameras: the default orbit of `../shared/TARGETS.md` (`orbit:N`: radius 2.2 x the
//! largest extent, 15 degrees elevation, 50 degrees fov), black background.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]

use fantasystyle::artifacts::load_scene;
use fantasystyle::camera::load_cameras;
use fantasystyle::optim::{ColourFit, FitParams};
use fantasystyle::render::{CacheMode, RenderOptions, ViewCache, project, render};
use fantasystyle::rng::Rng;
use fantasystyle::scene::sh_coeffs;
use fantasystyle::{Camera, Scene};
use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

const THREADS: usize = 2;
/// Rounds of the thread-scaling table (each: one child on 1 thread, one on 2).
const SCALING_ROUNDS: usize = 3;

fn scenes_dir() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/scenes");
    if p.is_dir() {
        p
    } else {
        PathBuf::from("/work/shared/data/scenes")
    }
}

/// A synthetic scene of `n` Gaussians in a unit ball, sizes shrinking like n^(-1/3)
/// so that image coverage stays comparable, SH degree 0.
fn synthetic(n: usize) -> Scene {
    let mut rng = Rng::new(n as u64);
    let k = sh_coeffs(0) - 1;
    let base = (0.6 * (n as f64).powf(-1.0 / 3.0)).ln();
    let mut s = Scene {
        sh_degree: 0,
        ..Default::default()
    };
    while s.len() < n {
        let p = [rng.normal(), rng.normal(), rng.normal()];
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        if r > 2.0 {
            continue;
        }
        s.positions
            .push([0.4 * p[0] as f32, 0.4 * p[1] as f32, 0.4 * p[2] as f32]);
        let ls = |rng: &mut Rng| (base + 0.5 * rng.normal()) as f32;
        s.log_scales
            .push([ls(&mut rng), ls(&mut rng), ls(&mut rng)]);
        s.rotations.push([
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ]);
        s.opacity_logits.push((1.0 + 2.0 * rng.normal()) as f32);
        s.sh_dc.push([
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ]);
        s.sh_rest.extend(std::iter::repeat_n(0.0, k * 3));
    }
    s
}

fn load(name: &str) -> Scene {
    if let Some(n) = name.strip_prefix("synthetic-") {
        let n: usize = n.parse().expect("synthetic-N");
        return synthetic(n);
    }
    load_scene(&scenes_dir().join(name)).expect("shared scene")
}

fn vm_hwm_mb() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// CPU time (user + system) of this process so far, ms (10 ms resolution).
fn cpu_ms() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which is in parentheses).
    let rest = s.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<f64> = rest
        .split_whitespace()
        .map(|x| x.parse::<f64>().unwrap_or(f64::NAN))
        .collect();
    // utime and stime are fields 14 and 15 (1-based) of the whole line, i.e. 11 and 12
    // after the command; clock ticks are 100 Hz on Linux.
    (f.get(11).copied().unwrap_or(f64::NAN) + f.get(12).copied().unwrap_or(f64::NAN)) * 10.0
}

fn cams(scene: &Scene, n: usize, size: u32) -> Vec<Camera> {
    load_cameras(&format!("orbit:{n}"), &scene.bounds(), size, size).expect("orbit")
}

/// Forward: mean ms per view over `reps` passes of an 8-view orbit (after one warm-up
/// pass), blends per view (from the cache, untimed).
fn case_forward(scene_name: &str, size: u32) -> serde_json::Value {
    let scene = load(scene_name);
    let cams = cams(&scene, 8, size);
    let opts = RenderOptions::default();
    let reps = if size >= 1024 || scene.len() >= 1_000_000 {
        1
    } else {
        3
    };
    for c in &cams {
        std::hint::black_box(render(&scene, c, &opts).unwrap());
    }
    let t0 = Instant::now();
    let c0 = cpu_ms();
    for _ in 0..reps {
        for c in &cams {
            std::hint::black_box(render(&scene, c, &opts).unwrap());
        }
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3 / (reps * cams.len()) as f64;
    let cpu = (cpu_ms() - c0) / (reps * cams.len()) as f64;
    // Phase split on view 0: projection + binning vs compositing.
    let t1 = Instant::now();
    let frame = project(&scene, &cams[0]);
    let proj_ms = t1.elapsed().as_secs_f64() * 1e3;
    let blends: f64 = cams
        .iter()
        .map(|c| ViewCache::build(&scene, c).unwrap().blends() as f64)
        .sum::<f64>()
        / cams.len() as f64;
    serde_json::json!({
        "scene": scene_name, "gaussians": scene.len(), "size": size, "ms": ms, "cpu_ms": cpu,
        "project_ms_view0": proj_ms, "splats_view0": frame.splats.ids.len(),
        "blends": blends, "peak_mb": vm_hwm_mb(),
    })
}

/// Colour fit: ms per Adam step (mean of `steps` steps after one warm-up step) for
/// `views` orbit views, cache on or off; cache bytes.
fn case_fit(scene_name: &str, size: u32, views: usize, cache: bool) -> serde_json::Value {
    let scene = load(scene_name);
    let cams = cams(&scene, views, size);
    let opts = RenderOptions::default();
    let targets: Vec<Vec<f32>> = cams
        .iter()
        .map(|c| render(&scene, c, &opts).unwrap().rgb)
        .collect();
    let p = FitParams {
        cache: if cache { CacheMode::On } else { CacheMode::Off },
        ..Default::default()
    };
    let t0 = Instant::now();
    let mut fit = ColourFit::new(&scene, &cams, &targets, &p).unwrap();
    let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
    fit.step();
    let steps = if views >= 32 && !cache { 1 } else { 2 };
    let t1 = Instant::now();
    let c1 = cpu_ms();
    for _ in 0..steps {
        fit.step();
    }
    let ms = t1.elapsed().as_secs_f64() * 1e3 / steps as f64;
    let cpu = (cpu_ms() - c1) / steps as f64;
    let (_, bytes) = fit.cache_stats();
    serde_json::json!({
        "scene": scene_name, "gaussians": scene.len(), "size": size, "views": views,
        "cache": cache, "step_ms": ms, "step_cpu_ms": cpu, "setup_ms": setup_ms,
        "cache_mb_per_view": bytes as f64 / 1e6 / views as f64, "peak_mb": vm_hwm_mb(),
    })
}

/// Phase times of one view (min over 5 runs), for tuning.
fn case_profile(scene_name: &str, size: u32) -> serde_json::Value {
    use fantasystyle::render::{clamp_colours, composite, raw_colours};
    let scene = load(scene_name);
    let cam = &cams(&scene, 8, size)[0];
    // CPU ms per call over 10 calls (robust to other processes on a shared machine) and
    // wall ms per call (what the pool's threads buy).
    let mut wall = Vec::new();
    let mut time = |f: &mut dyn FnMut()| {
        let (c, t) = (cpu_ms(), Instant::now());
        for _ in 0..10 {
            f();
        }
        wall.push(t.elapsed().as_secs_f64() * 1e3 / 10.0);
        (cpu_ms() - c) / 10.0
    };
    let frame = project(&scene, cam);
    let t_project = time(&mut || {
        std::hint::black_box(project(&scene, cam));
    });
    let raw = raw_colours(&scene, &frame.splats.ids, cam.center());
    let col = clamp_colours(&raw);
    let t_colour = time(&mut || {
        std::hint::black_box(raw_colours(&scene, &frame.splats.ids, cam.center()));
    });
    let t_composite = time(&mut || {
        std::hint::black_box(composite(&frame, &col, [0.0; 3]));
    });
    let pairs = frame.tile_list.len();
    let mut row_evals = 0usize;
    let ts = 16usize;
    for t in 0..frame.tiles_x * frame.tiles_y {
        let y0 = (t / frame.tiles_x) * ts;
        for &g in frame.tile(t) {
            let r = frame.splats.recs[g as usize].rows;
            let a = (r[0] as usize).max(y0);
            let b = (r[1] as usize).min(y0 + ts);
            row_evals += b.saturating_sub(a);
        }
    }
    serde_json::json!({
        "splats": frame.splats.ids.len(), "pairs": pairs, "pixel_evals": row_evals * 16,
        "project_cpu_ms": t_project, "colour_cpu_ms": t_colour, "composite_cpu_ms": t_composite,
        "project_ms": wall[0], "colour_ms": wall[1], "composite_ms": wall[2],
    })
}

fn child(args: &[String]) {
    let threads: usize = args[0].parse().expect("--case THREADS");
    let args = &args[1..];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let v = pool.install(|| match args[0].as_str() {
        "forward" => case_forward(&args[1], args[2].parse().unwrap()),
        "fit" => case_fit(
            &args[1],
            args[2].parse().unwrap(),
            args[3].parse().unwrap(),
            args[4] == "on",
        ),
        "profile" => case_profile(&args[1], args[2].parse().unwrap()),
        other => panic!("unknown case {other}"),
    });
    println!("RESULT {v}");
}

fn run_child(args: &[&str]) -> Option<serde_json::Value> {
    run_child_on(THREADS, args)
}

/// [`run_child`] on a pool of `threads` threads.
fn run_child_on(threads: usize, args: &[&str]) -> Option<serde_json::Value> {
    let exe = std::env::current_exe().ok()?;
    let out = Command::new(exe)
        .arg("--case")
        .arg(threads.to_string())
        .args(args)
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find_map(|l| l.strip_prefix("RESULT "));
    match line {
        Some(l) => serde_json::from_str(l).ok(),
        None => {
            eprintln!(
                "case {args:?} failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            None
        }
    }
}

fn f(v: &serde_json::Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or(f64::NAN)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(i) = args.iter().position(|a| a == "--case") {
        child(&args[i + 1..]);
        return;
    }
    if let Some(i) = args.iter().position(|a| a == "--profile") {
        // `--profile SCENE SIZE [THREADS]`
        let threads = args
            .get(i + 3)
            .and_then(|t| t.parse().ok())
            .unwrap_or(THREADS);
        let v = run_child_on(threads, &["profile", &args[i + 1], &args[i + 2]]);
        println!("{v:?}");
        return;
    }
    let quick = args.iter().any(|a| a == "--quick");
    let have = |n: &str| scenes_dir().join(n).is_file();
    let mut md = String::new();
    let mut out = |s: String| {
        println!("{s}");
        md.push_str(&s);
        md.push('\n');
    };
    out("### Forward, 8-view orbit, 2 threads".into());
    out(String::new());
    out("| scene | Gaussians | size | ms / view (wall) | CPU ms / view | blends / view | M blends / s (wall) | projection + binning, view 0 (ms) | peak RSS (MB) |".into());
    out("|---|---|---|---|---|---|---|---|---|".into());
    let mut forward_cases: Vec<(String, u32)> = Vec::new();
    for s in ["bob_100k.splat", "plant.splat"] {
        if !have(s) {
            out(format!("| {s} | absent | | | | | | | |"));
            continue;
        }
        let sizes: &[u32] = if quick { &[512] } else { &[256, 512, 1024] };
        for &size in sizes {
            forward_cases.push((s.to_string(), size));
        }
    }
    let synth: &[usize] = if quick {
        &[10_000]
    } else {
        &[10_000, 100_000, 1_000_000]
    };
    for &n in synth {
        forward_cases.push((format!("synthetic-{n}"), 512));
    }
    for (s, size) in &forward_cases {
        if let Some(v) = run_child(&["forward", s, &size.to_string()]) {
            out(format!(
                "| {s} | {} | {size} | {:.1} | {:.1} | {:.0} | {:.1} | {:.1} | {:.0} |",
                v["gaussians"],
                f(&v, "ms"),
                f(&v, "cpu_ms"),
                f(&v, "blends"),
                f(&v, "blends") / f(&v, "ms") / 1e3,
                f(&v, "project_ms_view0"),
                f(&v, "peak_mb"),
            ));
        }
    }
    out(String::new());
    out(format!(
        "### Forward thread scaling: 1 vs 2 threads, in turn, {SCALING_ROUNDS} rounds (medians; speed-up per round)"
    ));
    out(String::new());
    out("| scene | size | ms / view, 1 thread | ms / view, 2 threads | speed-up (min-max) | efficiency |".into());
    out("|---|---|---|---|---|---|".into());
    for (s, size) in forward_cases
        .iter()
        .filter(|(s, size)| *size == 512 && !s.ends_with("1000000"))
    {
        let (mut one, mut two, mut ratio) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..SCALING_ROUNDS {
            let a = run_child_on(1, &["forward", s, &size.to_string()]);
            let b = run_child_on(2, &["forward", s, &size.to_string()]);
            if let (Some(a), Some(b)) = (a, b) {
                one.push(f(&a, "ms"));
                two.push(f(&b, "ms"));
                ratio.push(f(&a, "ms") / f(&b, "ms"));
            }
        }
        if ratio.is_empty() {
            continue;
        }
        let (lo, hi) = ratio
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &r| {
                (l.min(r), h.max(r))
            });
        let sp = median(ratio);
        out(format!(
            "| {s} | {size} | {:.1} | {:.1} | {sp:.2} ({lo:.2}-{hi:.2}) | {:.2} |",
            median(one),
            median(two),
            sp / 2.0
        ));
    }
    out(String::new());
    out("### Colour fit: one Adam step over all views (render, L1 + D-SSIM, backward, update), 2 threads".into());
    out(String::new());
    out("| scene | Gaussians | size | views | ms / step, cache off | ms / step, cache on | off / on (wall) | CPU ms / step off / on | off / on (CPU) | cache MB / view | cache build (ms, all views) | peak RSS off / on (MB) |".into());
    out("|---|---|---|---|---|---|---|---|---|---|---|---|".into());
    let mut fit_cases: Vec<(String, u32, usize)> = Vec::new();
    if have("plant.splat") {
        if quick {
            fit_cases.push(("plant.splat".into(), 512, 8));
        } else {
            fit_cases.push(("plant.splat".into(), 512, 8));
            fit_cases.push(("plant.splat".into(), 512, 32));
            fit_cases.push(("plant.splat".into(), 256, 8));
            fit_cases.push(("plant.splat".into(), 1024, 8));
        }
    }
    for &n in synth {
        fit_cases.push((format!("synthetic-{n}"), 512, 8));
    }
    for (s, size, views) in &fit_cases {
        let a = &[size.to_string(), views.to_string()];
        let off = run_child(&["fit", s, &a[0], &a[1], "off"]);
        let on = run_child(&["fit", s, &a[0], &a[1], "on"]);
        if let (Some(off), Some(on)) = (off, on) {
            out(format!(
                "| {s} | {} | {size} | {views} | {:.0} | {:.0} | {:.1}x | {:.0} / {:.0} | {:.1}x | {:.2} | {:.0} | {:.0} / {:.0} |",
                on["gaussians"],
                f(&off, "step_ms"),
                f(&on, "step_ms"),
                f(&off, "step_ms") / f(&on, "step_ms"),
                f(&off, "step_cpu_ms"),
                f(&on, "step_cpu_ms"),
                f(&off, "step_cpu_ms") / f(&on, "step_cpu_ms"),
                f(&on, "cache_mb_per_view"),
                f(&on, "setup_ms"),
                f(&off, "peak_mb"),
                f(&on, "peak_mb"),
            ));
        }
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("bench-out");
    if std::fs::create_dir_all(&dir).is_ok() {
        let _ = std::fs::write(dir.join("render.md"), md);
    }
}

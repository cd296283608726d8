//! SGEMM micro-benchmark: matrixmultiply vs gemm on VGG16 im2col shapes (see Cargo.toml).
#![allow(unsafe_code)]
use std::time::Instant;
fn mm(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    unsafe { matrixmultiply::sgemm(m, k, n, 1.0, a.as_ptr(), k as isize, 1, b.as_ptr(), n as isize, 1, 0.0, c.as_mut_ptr(), n as isize, 1); }
}
fn gm(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32], par: gemm::Parallelism) {
    unsafe { gemm::gemm(m, n, k, c.as_mut_ptr(), 1, n as isize, false, a.as_ptr(), 1, k as isize, b.as_ptr(), 1, n as isize, 0.0f32, 1.0f32, false, false, false, par); }
}
fn main() {
    rayon::ThreadPoolBuilder::new().num_threads(2).build_global().unwrap();
    // (M=C_out, K=C_in*9, N=H*W) for VGG16 at 256x256
    let shapes = [(64usize, 27usize, 65536usize), (64, 576, 65536), (128, 1152, 16384), (256, 2304, 4096), (512, 4608, 1024)];
    for &(m, k, n) in &shapes {
        let a: Vec<f32> = (0..m * k).map(|i| ((i * 7919) % 1000) as f32 * 1e-3).collect();
        let b: Vec<f32> = (0..k * n).map(|i| ((i * 104729) % 1000) as f32 * 1e-3).collect();
        let mut c = vec![0f32; m * n];
        let mut c2 = vec![0f32; m * n];
        let reps = 3;
        let flop = 2.0 * (m * k * n) as f64 * reps as f64;
        mm(m, k, n, &a, &b, &mut c);
        let t = Instant::now(); for _ in 0..reps { mm(m, k, n, &a, &b, &mut c); } let t_mm = t.elapsed().as_secs_f64();
        gm(m, k, n, &a, &b, &mut c2, gemm::Parallelism::None);
        let t = Instant::now(); for _ in 0..reps { gm(m, k, n, &a, &b, &mut c2, gemm::Parallelism::None); } let t_g1 = t.elapsed().as_secs_f64();
        let t = Instant::now(); for _ in 0..reps { gm(m, k, n, &a, &b, &mut c2, gemm::Parallelism::Rayon(2)); } let t_g2 = t.elapsed().as_secs_f64();
        // matrixmultiply on 2 threads: split N columns in halves via rayon
        let t = Instant::now();
        for _ in 0..reps {
            let nh = n / 2;
            
            let cp = c.as_mut_ptr() as usize; let bp = b.as_ptr() as usize;
            rayon::join(|| unsafe { matrixmultiply::sgemm(m, k, nh, 1.0, a.as_ptr(), k as isize, 1, bp as *const f32, n as isize, 1, 0.0, cp as *mut f32, n as isize, 1) },
                        || unsafe { matrixmultiply::sgemm(m, k, n - nh, 1.0, a.as_ptr(), k as isize, 1, (bp as *const f32).add(nh), n as isize, 1, 0.0, (cp as *mut f32).add(nh), n as isize, 1) });
        }
        let t_mm2 = t.elapsed().as_secs_f64();
        let maxdiff = c.iter().zip(&c2).map(|(x, y)| (x - y).abs() / (1.0 + x.abs())).fold(0f32, f32::max);
        println!("M={m} K={k} N={n}: matrixmultiply 1t {:.1} GF/s, 2t(split N) {:.1} GF/s | gemm 1t {:.1} GF/s, 2t {:.1} GF/s (rel diff {maxdiff:.1e})",
            flop / t_mm / 1e9, flop / t_mm2 / 1e9, flop / t_g1 / 1e9, flop / t_g2 / 1e9);
    }
}

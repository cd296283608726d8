//! Unit tests of the rasterizer: determinism, the closed form of one Gaussian, cache
//! consistency, the colour gradient against f64 finite differences, input validation.

use super::*;
use crate::rng::Rng;
use crate::scene::sh_coeffs;

/// A camera at `(0, 0, -dist)` looking along +z, principal point at the centre.
pub(crate) fn front_camera(w: u32, h: u32, f: f32, dist: f32) -> Camera {
    Camera {
        name: "front".into(),
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: w as f32 / 2.0,
        cy: h as f32 / 2.0,
        rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        translation: [0.0, 0.0, dist],
    }
}

/// `n` random Gaussians in a unit cube, SH degree `deg`, colours around grey.
pub(crate) fn random_scene(n: usize, deg: usize, seed: u64) -> Scene {
    let mut rng = Rng::new(seed);
    let mut u = move || rng.uniform() as f32;
    let k = sh_coeffs(deg) - 1;
    let mut s = Scene {
        sh_degree: deg,
        ..Default::default()
    };
    for _ in 0..n {
        s.positions
            .push([u() * 2.0 - 1.0, u() * 2.0 - 1.0, u() * 2.0 - 1.0]);
        s.log_scales
            .push([-3.5 + 2.0 * u(), -3.5 + 2.0 * u(), -3.5 + 2.0 * u()]);
        s.rotations
            .push([u() - 0.5, u() - 0.5, u() - 0.5, u() - 0.5]);
        s.opacity_logits.push(4.0 * u() - 1.0);
        s.sh_dc
            .push([6.0 * u() - 3.0, 6.0 * u() - 3.0, 6.0 * u() - 3.0]);
        for _ in 0..k * 3 {
            s.sh_rest.push(0.8 * u() - 0.4);
        }
    }
    s
}

fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .unwrap()
        .install(f)
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

#[test]
fn deterministic_across_thread_counts() {
    let scene = random_scene(3000, 3, 1);
    let cam = front_camera(100, 70, 90.0, 3.0);
    let opts = RenderOptions {
        background: [0.2, 0.3, 0.4],
    };
    let a = with_threads(1, || render(&scene, &cam, &opts).unwrap());
    let b = with_threads(2, || render(&scene, &cam, &opts).unwrap());
    let c = with_threads(3, || render(&scene, &cam, &opts).unwrap());
    assert_eq!(bits(&a.rgb), bits(&b.rgb));
    assert_eq!(bits(&a.depth), bits(&b.depth));
    assert_eq!(bits(&a.alpha), bits(&b.alpha));
    assert_eq!(bits(&a.rgb), bits(&c.rgb));
    // Non-trivial image.
    assert!(a.alpha.iter().filter(|&&x| x > 0.5).count() > 1000);
}

/// One isotropic Gaussian seen head-on: its image is the analytic 2D footprint
/// `min(0.99, o exp(-d^T Sigma'^-1 d / 2))` with `Sigma' = s^2 J J^T + 0.3 I` (the EWA
/// dilation; J J^T is isotropic up to the small off-axis perspective term), where the
/// 1/255 cut-off applies. Tolerance 2e-6 absolute (f32 rounding).
#[test]
fn isotropic_gaussian_matches_closed_form() {
    let (w, h, f, dist) = (64u32, 48u32, 50.0f32, 4.0f32);
    let scale = 0.08f32;
    let opacity = 0.8f32;
    let scene = Scene {
        positions: vec![[0.1, -0.05, 0.0]],
        log_scales: vec![[scale.ln(); 3]],
        rotations: vec![[0.3, -0.2, 0.5, 0.1]], // any rotation: isotropic
        opacity_logits: vec![(opacity / (1.0 - opacity)).ln()],
        sh_degree: 0,
        sh_dc: vec![[1.0, 0.0, -1.0]],
        sh_rest: vec![],
    };
    let cam = front_camera(w, h, f, dist);
    let out = render(&scene, &cam, &RenderOptions::default()).unwrap();
    // Camera-space mean (0.1, -0.05, z); Sigma' = s^2 J J^T + 0.3 I.
    let (px, py, z) = (0.1f64, -0.05f64, dist as f64);
    let fz = f as f64 / z;
    let j = [[fz, 0.0, -fz * px / z], [0.0, fz, -fz * py / z]];
    let s2 = (scale as f64).powi(2);
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let (sa, sb, sc) = (
        s2 * dot(j[0], j[0]) + 0.3,
        s2 * dot(j[0], j[1]),
        s2 * dot(j[1], j[1]) + 0.3,
    );
    let det = sa * sc - sb * sb;
    let mx = f as f64 * px / z + w as f64 / 2.0;
    let my = f as f64 * py / z + h as f64 / 2.0;
    let colour = [sh::C0 as f64 + 0.5, 0.5, (0.5 - sh::C0 as f64).max(0.0)];
    let mut worst = 0.0f64;
    for y in 0..h as usize {
        for x in 0..w as usize {
            let dx = x as f64 + 0.5 - mx;
            let dy = y as f64 + 0.5 - my;
            let power = 0.5 * (sc * dx * dx - 2.0 * sb * dx * dy + sa * dy * dy) / det;
            let mut a = (opacity as f64 * (-power).exp()).min(0.99);
            if a < 1.0 / 255.0 {
                a = 0.0;
            }
            let o = y * w as usize + x;
            worst = worst.max((out.alpha[o] as f64 - a).abs());
            for c in 0..3 {
                worst = worst.max((out.rgb[o * 3 + c] as f64 - a * colour[c]).abs());
            }
            worst = worst.max((out.depth[o] as f64 - a * z).abs() / z);
        }
    }
    assert!(worst < 2e-6, "max abs error {worst}");
}

#[test]
fn cache_reproduces_render_and_gradients() {
    for deg in 0..=3 {
        let scene = random_scene(1500, deg, 10 + deg as u64);
        let cam = front_camera(90, 60, 80.0, 3.0);
        let bg = [0.1, 0.5, 0.9];
        let out = render(&scene, &cam, &RenderOptions { background: bg }).unwrap();
        let cache = ViewCache::build(&scene, &cam).unwrap();
        let col = clamp_colours(&raw_colours(&scene, cache.gaussians(), cam.center()));
        let rgb = cache.forward(&col, bg);
        assert_eq!(bits(&rgb), bits(&out.rgb), "degree {deg}");
        assert_eq!(bits(&cache.alpha()), bits(&out.alpha));

        let mut rng = Rng::new(5);
        let g: Vec<f32> = rng.normals_f32(rgb.len());
        let frame = project(&scene, &cam);
        let gu = backward::colour_grad_uncached(&frame, &g);
        let gc = cache.backward(&g);
        // Map both to scene indices.
        let mut a = vec![[0.0f32; 3]; scene.len()];
        let mut b = vec![[0.0f32; 3]; scene.len()];
        for (j, &id) in frame.splats.ids.iter().enumerate() {
            a[id as usize] = gu[j];
        }
        for (j, &id) in cache.gaussians().iter().enumerate() {
            b[id as usize] = gc[j];
        }
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for i in 0..scene.len() {
            for c in 0..3 {
                num += ((a[i][c] - b[i][c]) as f64).powi(2);
                den += (a[i][c] as f64).powi(2);
            }
        }
        assert!(den > 0.0);
        eprintln!(
            "degree {deg}: cached vs uncached colour gradients, relative difference {:.1e}",
            (num / den).sqrt()
        );
        assert!(
            (num / den).sqrt() < 1e-6,
            "cached vs uncached {}",
            (num / den).sqrt()
        );
    }
}

/// f64 reference of the colour path with the weights held fixed:
/// `L = sum_p r_p . (sum_i w_pi max(0, Y(d_i) f_i + 0.5) + T_p bg)`.
fn loss_f64(
    scene: &Scene,
    centre: [f32; 3],
    weights: &[(usize, usize, f64)],
    r: &[f64],
    dc: &[[f64; 3]],
    rest: &[f64],
) -> f64 {
    let k = scene.rest_per_channel();
    let col: Vec<[f64; 3]> = (0..scene.len())
        .map(|i| {
            let p = scene.positions[i];
            let d = [
                (p[0] - centre[0]) as f64,
                (p[1] - centre[1]) as f64,
                (p[2] - centre[2]) as f64,
            ];
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let (x, y, z) = (d[0] / n, d[1] / n, d[2] / n);
            // Independent transcription of the INRIA basis in f64.
            let c0 = 0.28209479177387814;
            let c1 = 0.4886025119029199;
            let c2 = [
                1.0925484305920792,
                -1.0925484305920792,
                0.31539156525252005,
                -1.0925484305920792,
                0.5462742152960396,
            ];
            let c3 = [
                -0.5900435899266435,
                2.890611442640554,
                -0.4570457994644658,
                0.3731763325901154,
                -0.4570457994644658,
                1.445305721320277,
                -0.5900435899266435,
            ];
            let (xx, yy, zz) = (x * x, y * y, z * z);
            let y_all = [
                c0,
                -c1 * y,
                c1 * z,
                -c1 * x,
                c2[0] * x * y,
                c2[1] * y * z,
                c2[2] * (2.0 * zz - xx - yy),
                c2[3] * x * z,
                c2[4] * (xx - yy),
                c3[0] * y * (3.0 * xx - yy),
                c3[1] * x * y * z,
                c3[2] * y * (4.0 * zz - xx - yy),
                c3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                c3[4] * x * (4.0 * zz - xx - yy),
                c3[5] * z * (xx - yy),
                c3[6] * x * (xx - 3.0 * yy),
            ];
            let mut c = [0.5; 3];
            for ch in 0..3 {
                c[ch] += y_all[0] * dc[i][ch];
                for kk in 0..k {
                    c[ch] += y_all[kk + 1] * rest[(i * k + kk) * 3 + ch];
                }
                c[ch] = c[ch].max(0.0);
            }
            c
        })
        .collect();
    weights
        .iter()
        .map(|&(p, i, w)| (0..3).map(|ch| r[p * 3 + ch] * w * col[i][ch]).sum::<f64>())
        .sum()
}

/// The fixed blend weights `(pixel, scene index, w)` of a view: a forward with unit
/// colours per Gaussian would be costly, so they are read from the cache by one-hot
/// colours on a tiny scene.
fn blend_weights(cache: &ViewCache, ids: &[u32], npix: usize) -> Vec<(usize, usize, f64)> {
    let mut weights = Vec::new();
    for (j, &id) in ids.iter().enumerate() {
        let mut col = vec![[0.0f32; 3]; ids.len()];
        col[j] = [1.0, 0.0, 0.0];
        let img = cache.forward(&col, [0.0; 3]);
        for p in 0..npix {
            if img[p * 3] != 0.0 {
                weights.push((p, id as usize, img[p * 3] as f64));
            }
        }
    }
    weights
}

/// Colour gradients agree with central finite differences of an f64 reference, for SH
/// degrees 0..3, with both clamped and unclamped colours present. Relative error (L2
/// over all coefficients whose raw colours are away from the clamp kink) < 1e-4
/// (measured 1.6e-7 to 2.0e-7: the f32 rounding of the analytic gradient).
#[test]
fn colour_gradient_matches_finite_differences() {
    for deg in 0..=3 {
        let scene = random_scene(60, deg, 100 + deg as u64);
        let cam = front_camera(40, 32, 40.0, 3.0);
        let centre = cam.center();
        let cache = ViewCache::build(&scene, &cam).unwrap();
        let ids = cache.gaussians().to_vec();
        let npix = 40 * 32;
        let weights = blend_weights(&cache, &ids, npix);
        let mut rng = Rng::new(7);
        let r: Vec<f64> = (0..npix * 3).map(|_| rng.normal()).collect();
        let rf: Vec<f32> = r.iter().map(|&v| v as f32).collect();

        // Analytic gradient.
        let raw = raw_colours(&scene, &ids, centre);
        let n_clamped = raw.iter().flatten().filter(|&&v| v < 0.0).count();
        let n_open = raw.iter().flatten().filter(|&&v| v > 0.0).count();
        assert!(
            n_clamped > 5 && n_open > 5,
            "deg {deg}: {n_clamped} clamped, {n_open} open"
        );
        let gc = cache.backward(&rf);
        let mut gdc = vec![[0.0f32; 3]; scene.len()];
        let k = scene.rest_per_channel();
        let mut grest = vec![0.0f32; scene.len() * k * 3];
        backward::sh_backward(&scene, &ids, centre, &raw, &gc, &mut gdc, &mut grest);

        let dc: Vec<[f64; 3]> = scene
            .sh_dc
            .iter()
            .map(|c| [c[0] as f64, c[1] as f64, c[2] as f64])
            .collect();
        let rest: Vec<f64> = scene.sh_rest.iter().map(|&v| v as f64).collect();
        let h = 1e-6;
        let near_kink = |i: usize, ch: usize| {
            ids.iter()
                .position(|&id| id as usize == i)
                .is_some_and(|j| raw[j][ch].abs() < 1e-3)
        };
        let (mut num, mut den, mut checked) = (0.0f64, 0.0f64, 0);
        for i in 0..scene.len() {
            for ch in 0..3 {
                if near_kink(i, ch) {
                    continue;
                }
                let mut dp = dc.clone();
                dp[i][ch] += h;
                let mut dm = dc.clone();
                dm[i][ch] -= h;
                let fd = (loss_f64(&scene, centre, &weights, &r, &dp, &rest)
                    - loss_f64(&scene, centre, &weights, &r, &dm, &rest))
                    / (2.0 * h);
                num += (fd - gdc[i][ch] as f64).powi(2);
                den += fd * fd;
                checked += 1;
                for kk in 0..k {
                    let o = (i * k + kk) * 3 + ch;
                    let mut rp = rest.clone();
                    rp[o] += h;
                    let mut rm = rest.clone();
                    rm[o] -= h;
                    let fd = (loss_f64(&scene, centre, &weights, &r, &dc, &rp)
                        - loss_f64(&scene, centre, &weights, &r, &dc, &rm))
                        / (2.0 * h);
                    num += (fd - grest[o] as f64).powi(2);
                    den += fd * fd;
                }
            }
        }
        let rel = (num / den).sqrt();
        eprintln!(
            "degree {deg}: {n_clamped} clamped, {n_open} open channels, relative error {rel:.2e}"
        );
        assert!(den > 0.0 && checked > 50);
        assert!(rel < 1e-4, "degree {deg}: relative error {rel}");
    }
}

#[test]
fn bad_cameras_are_errors() {
    let scene = random_scene(10, 0, 1);
    let mut cam = front_camera(0, 10, 10.0, 3.0);
    assert!(matches!(
        render(&scene, &cam, &RenderOptions::default()),
        Err(Error::Param(_))
    ));
    cam.width = 10;
    cam.fx = f32::NAN;
    assert!(render(&scene, &cam, &RenderOptions::default()).is_err());
    cam.fx = 10.0;
    cam.translation[1] = f32::INFINITY;
    assert!(render(&scene, &cam, &RenderOptions::default()).is_err());
    cam.translation[1] = 0.0;
    let mut bad = scene.clone();
    bad.sh_rest.push(1.0);
    assert!(render(&bad, &cam, &RenderOptions::default()).is_err());
}

/// Degenerate Gaussians (NaN position, zero quaternion, huge or tiny scales) are
/// culled or rendered without panicking, and never produce non-finite pixels.
#[test]
fn extreme_gaussians_do_not_break_the_image() {
    let mut scene = random_scene(200, 1, 3);
    scene.positions[0] = [f32::NAN, 0.0, 0.0];
    scene.rotations[1] = [0.0; 4];
    scene.log_scales[2] = [30.0, 30.0, 30.0];
    scene.log_scales[3] = [-40.0, -40.0, -40.0];
    scene.log_scales[4] = [f32::INFINITY, 0.0, 0.0];
    scene.opacity_logits[5] = f32::NAN;
    scene.positions[6] = [0.0, 0.0, -3.0]; // at the camera centre
    scene.positions[7] = [1e30, 1e30, 1.0];
    let cam = front_camera(50, 40, 40.0, 3.0);
    let out = render(&scene, &cam, &RenderOptions::default()).unwrap();
    assert!(
        out.rgb
            .iter()
            .chain(&out.alpha)
            .chain(&out.depth)
            .all(|v| v.is_finite())
    );
}

/// The ellipse-box margin only saves work: a hundred times wider box (and a whole
/// pixel more) renders the same bits, through all three sinks.
#[test]
fn tight_box_changes_no_output() {
    use crate::render::bin::bin;
    use crate::render::project::{BoxMargin, project_splats, project_splats_with};
    let wide = BoxMargin { rel: 1e-3, px: 1.0 };
    for (seed, deg) in [(1u64, 0usize), (2, 3)] {
        let mut scene = random_scene(3000, deg, 40 + seed);
        // Needles and discs as well as blobs.
        for (i, ls) in scene.log_scales.iter_mut().enumerate().step_by(3) {
            ls[i % 3] -= 3.0;
            ls[(i + 1) % 3] += 1.0;
        }
        let cam = front_camera(120, 90, 110.0, 2.5);
        let (w, h) = (cam.width as usize, cam.height as usize);
        let tight = bin(project_splats(&scene, &cam), w, h);
        let loose = bin(project_splats_with(&scene, &cam, wide), w, h);
        assert!(loose.tile_list.len() > tight.tile_list.len());
        // (A splat may survive only in the wide box; it then blends nowhere.)
        let col = |f: &Frame| clamp_colours(&raw_colours(&scene, &f.splats.ids, cam.center()));
        let a = composite(&tight, &col(&tight), [0.1, 0.2, 0.3]);
        let b = composite(&loose, &col(&loose), [0.1, 0.2, 0.3]);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.rgb), bits(&b.rgb));
        assert_eq!(bits(&a.depth), bits(&b.depth));
        assert_eq!(bits(&a.alpha), bits(&b.alpha));
        let g: Vec<f32> = crate::rng::Rng::new(9).normals_f32(w * h * 3);
        let by_id = |f: &Frame| {
            let mut out = vec![[0.0f32; 3]; scene.len()];
            for (j, gj) in backward::colour_grad_uncached(f, &g)
                .into_iter()
                .enumerate()
            {
                out[f.splats.ids[j] as usize] = gj;
            }
            out
        };
        assert_eq!(by_id(&tight), by_id(&loose));
        let (ca, cb) = (ViewCache::from_frame(&tight), ViewCache::from_frame(&loose));
        assert_eq!(ca, cb);
    }
}

use super::*;
use crate::render::tests::{front_camera, random_scene};
use crate::render::{CacheMode, RenderOptions, render};
use crate::rng::Rng;
use crate::{Camera, Result, Scene};

/// `n` copies of `cam` moved along `axis`: the i-th by `first + i step`.
fn cameras_along(n: usize, cam: Camera, axis: usize, step: f32, first: f32) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let mut c = cam.clone();
            c.translation[axis] = i as f32 * step + first;
            c
        })
        .collect()
}

fn image(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.uniform() as f32).collect()
}

/// Directional derivatives of the loss (L1 + D-SSIM, with and without mask) agree with
/// central differences (f32, h = 1e-2, pixels kept 0.05 away from the L1 kink):
/// relative error < 1e-2 (f32 rounding of the loss dominates).
#[test]
fn loss_gradient_matches_finite_differences() {
    let (h, w) = (13, 17);
    let n = h * w * 3;
    let mut rng = Rng::new(3);
    let target = image(&mut rng, n);
    let render: Vec<f32> = target
        .iter()
        .map(|&t| {
            let d = 0.05 + 0.2 * rng.uniform() as f32;
            if rng.uniform() < 0.5 { t + d } else { t - d }
        })
        .collect();
    let mask: Vec<f32> = (0..h * w).map(|_| rng.uniform() as f32).collect();
    for (lambda, use_mask) in [(0.2, false), (1.0, false), (0.0, true), (0.2, true)] {
        let lp = LossParams {
            ssim_weight: lambda,
        };
        let m = use_mask.then_some(&mask[..]);
        let (_, g) = loss_and_grad(&render, &target, m, h, w, lp);
        for dir in 0..3 {
            let v: Vec<f32> = (0..n).map(|_| rng.normal() as f32 * 0.1).collect();
            let step = 1e-2f32;
            let shift =
                |s: f32| -> Vec<f32> { render.iter().zip(&v).map(|(r, d)| r + s * d).collect() };
            let (lp_, _) = loss_and_grad(&shift(step), &target, m, h, w, lp);
            let (lm_, _) = loss_and_grad(&shift(-step), &target, m, h, w, lp);
            let fd = (lp_ as f64 - lm_ as f64) / (2.0 * step as f64);
            let an: f64 = g.iter().zip(&v).map(|(a, b)| *a as f64 * *b as f64).sum();
            let rel = (fd - an).abs() / an.abs().max(1e-12);
            assert!(
                rel < 1e-2,
                "lambda {lambda} mask {use_mask} dir {dir}: fd {fd} analytic {an}"
            );
        }
    }
}

#[test]
fn ssim_of_identical_images_is_one() {
    let mut rng = Rng::new(1);
    let a = image(&mut rng, 20 * 20 * 3);
    assert!((ssim(&a, &a, 20, 20) - 1.0).abs() < 1e-6);
    let b = image(&mut rng, 20 * 20 * 3);
    assert!(ssim(&a, &b, 20, 20) < 0.5);
}

#[test]
fn adam_minimises_a_quadratic() {
    let mut p = vec![3.0f32, -2.0];
    let mut adam = Adam::new(2, 0.1);
    for _ in 0..500 {
        let g: Vec<f32> = p.iter().map(|x| 2.0 * (x - 1.0)).collect();
        adam.step(&mut p, &g);
    }
    assert!(p.iter().all(|x| (x - 1.0).abs() < 1e-2), "{p:?}");
}

/// Cached and uncached fits give the same colours (same weights and summation order)
/// and the non-colour fields are untouched; the loss decreases.
#[test]
fn cached_and_uncached_fits_agree() {
    let truth = random_scene(400, 2, 21);
    let cams = cameras_along(3, front_camera(40, 32, 40.0, 3.0), 0, 0.3, -0.3);
    let opts = RenderOptions {
        background: [0.3; 3],
    };
    let targets: Vec<Vec<f32>> = cams
        .iter()
        .map(|c| render(&truth, c, &opts).unwrap().rgb)
        .collect();
    let mut start = truth.clone();
    let mut rng = Rng::new(9);
    for c in start.sh_dc.iter_mut() {
        *c = [
            rng.normal() as f32,
            rng.normal() as f32,
            rng.normal() as f32,
        ];
    }
    let mut p = FitParams {
        lr_dc: 0.05,
        lr_rest: 0.0025,
        background: [0.3; 3],
        mask_alpha: true,
        ..Default::default()
    };
    let (a, ra) = fit_colours(&start, &cams, &targets, 20, &p).unwrap();
    p.cache = CacheMode::Off;
    let (b, rb) = fit_colours(&start, &cams, &targets, 20, &p).unwrap();
    p.cache = CacheMode::Budget(ra.cache_bytes / 2);
    let (c, rc) = fit_colours(&start, &cams, &targets, 20, &p).unwrap();
    assert_eq!(ra.cached_views, 3);
    assert_eq!(rb.cached_views, 0);
    assert!(rc.cached_views >= 1 && rc.cached_views < 3);
    assert_eq!(a, b);
    assert_eq!(a, c);
    assert_eq!(ra.losses, rb.losses);
    assert!(ra.losses[19] < 0.5 * ra.losses[0], "{:?}", ra.losses);
    // Geometry untouched.
    assert_eq!(a.positions, start.positions);
    assert_eq!(a.log_scales, start.log_scales);
    assert_eq!(a.rotations, start.rotations);
    assert_eq!(a.opacity_logits, start.opacity_logits);
    assert_ne!(a.sh_dc, start.sh_dc);
}

#[test]
fn bad_fit_inputs_are_errors() {
    let scene = random_scene(50, 1, 2);
    let cam = front_camera(16, 12, 16.0, 3.0);
    let good = vec![vec![0.5f32; 16 * 12 * 3]];
    let p = FitParams::default();
    let msg = |r: Result<(Scene, FitReport)>| r.err().map(|e| e.to_string()).unwrap_or_default();
    assert!(
        msg(fit_colours(
            &scene,
            std::slice::from_ref(&cam),
            &good,
            0,
            &p
        ))
        .contains("steps")
    );
    assert!(
        msg(fit_colours(&scene, std::slice::from_ref(&cam), &[], 1, &p))
            .contains("0 target images")
    );
    let small = vec![vec![0.5f32; 10]];
    assert!(
        msg(fit_colours(
            &scene,
            std::slice::from_ref(&cam),
            &small,
            1,
            &p
        ))
        .contains("needs 576")
    );
    let mut nan = good.clone();
    nan[0][7] = f32::NAN;
    assert!(
        msg(fit_colours(&scene, std::slice::from_ref(&cam), &nan, 1, &p)).contains("non-finite")
    );
    // Camera looking away from every Gaussian.
    let mut away = cam.clone();
    away.translation[2] = -10.0;
    assert!(msg(fit_colours(&scene, &[away], &good, 1, &p)).contains("no Gaussian"));
}

/// The fit (views in parallel, loss planes in parallel bands, SH gradients in parallel
/// blocks) gives the same bits for any thread count, cached or not, through `step` and
/// through the `step_with` hook.
#[test]
fn fit_is_identical_for_any_thread_count() {
    let truth = random_scene(600, 1, 31);
    let cams: Vec<Camera> = (0..11)
        .map(|i| {
            let mut c = front_camera(70, 50, 60.0, 3.0);
            c.translation[0] = i as f32 * 0.1 - 0.5;
            c.translation[1] = (i % 3) as f32 * 0.1;
            c
        })
        .collect();
    let opts = RenderOptions::default();
    let targets: Vec<Vec<f32>> = cams
        .iter()
        .map(|c| render(&truth, c, &opts).unwrap().rgb)
        .collect();
    let mut start = truth.clone();
    let mut rng = Rng::new(4);
    for v in start.sh_rest.iter_mut() {
        *v = 0.3 * rng.normal() as f32;
    }
    let pool = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    for cache in [CacheMode::On, CacheMode::Budget(150_000)] {
        let p = FitParams {
            lr_dc: 0.05,
            lr_rest: 0.01,
            mask_alpha: true,
            cache,
            ..Default::default()
        };
        let fits: Vec<(Scene, FitReport)> = [1, 2, 5]
            .iter()
            .map(|&n| pool(n).install(|| fit_colours(&start, &cams, &targets, 6, &p).unwrap()))
            .collect();
        for (s, r) in &fits[1..] {
            assert_eq!(*s, fits[0].0);
            assert_eq!(r.losses, fits[0].1.losses);
        }
        // The hook path, with the same loss, gives the same scene.
        let hooked = pool(3).install(|| {
            let mut fit = ColourFit::new(&start, &cams, &targets, &p).unwrap();
            for _ in 0..6 {
                fit.step_with(&mut |v, rgb, alpha| {
                    let (h, w) = (cams[v].height as usize, cams[v].width as usize);
                    let lp = LossParams { ssim_weight: 0.2 };
                    let (l, g) = loss_and_grad(rgb, &targets[v], alpha, h, w, lp);
                    Ok((l as f64, g))
                })
                .unwrap();
            }
            fit.finish()
        });
        assert_eq!(hooked.0, fits[0].0);
    }
}

/// [`ColourFit::step_l2`] (cached views fused, the rest through [`l2`], the views in
/// parallel) moves the scene exactly as the in-order hook path with [`l2`] does, for
/// every cache mode and thread count; its losses agree to rounding (a cached view sums
/// them tile by tile).
#[test]
fn step_l2_is_the_hook_path_with_l2() {
    let scene = random_scene(700, 1, 57);
    let cams = cameras_along(5, front_camera(53, 37, 50.0, 3.0), 0, 0.15, -0.3);
    let mut rng = Rng::new(8);
    let targets: Vec<Vec<f32>> = cams.iter().map(|_| image(&mut rng, 53 * 37 * 3)).collect();
    let pool = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let all: Vec<usize> = (0..cams.len()).collect();
    for cache in [CacheMode::On, CacheMode::Off, CacheMode::Budget(40_000)] {
        let p = FitParams {
            lr_dc: 0.05,
            lr_rest: 0.01,
            cache,
            ..Default::default()
        };
        let hooked = pool(2).install(|| {
            let mut fit = ColourFit::without_targets(&scene, &cams, &p).unwrap();
            let losses: Vec<f64> = (0..4)
                .map(|_| {
                    fit.step_views(&all, &mut |v, rgb, _| Ok(l2(rgb, &targets[v])))
                        .unwrap()
                })
                .collect();
            (fit.scene().clone(), losses)
        });
        for threads in [1, 3] {
            let (s, losses) = pool(threads).install(|| {
                let mut fit = ColourFit::without_targets(&scene, &cams, &p).unwrap();
                let losses: Vec<f64> = (0..4).map(|_| fit.step_l2(&targets).unwrap()).collect();
                (fit.scene().clone(), losses)
            });
            assert_eq!(s, hooked.0, "{cache:?}, {threads} threads");
            assert_ne!(s.sh_dc, scene.sh_dc);
            for (a, b) in losses.iter().zip(&hooked.1) {
                assert!((a - b).abs() <= 1e-12 * b, "{cache:?}: loss {a} vs {b}");
            }
        }
    }
    let mut fit = ColourFit::without_targets(&scene, &cams, &FitParams::default()).unwrap();
    assert!(fit.step_l2(&targets[..4]).is_err());
    let mut short = targets.clone();
    short[2].pop();
    assert!(fit.step_l2(&short).is_err());
}

/// A fit's views as the renderer makes them, bit for bit, in every cache mode: the
/// colours ([`ColourFit::render_view`]) and the coverage ([`ColourFit::alpha_view`], the
/// patch synthesis's set-up reads it instead of rendering again).
#[test]
fn a_fits_views_are_the_renders() {
    let scene = random_scene(900, 2, 61);
    let cams = cameras_along(3, front_camera(41, 29, 45.0, 3.0), 1, 0.2, -0.2);
    let bg = [0.2, 0.4, 0.7];
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for cache in [CacheMode::On, CacheMode::Off, CacheMode::Budget(20_000)] {
        let p = FitParams {
            background: bg,
            cache,
            ..Default::default()
        };
        let fit = ColourFit::without_targets(&scene, &cams, &p).unwrap();
        for (v, cam) in cams.iter().enumerate() {
            let want = render(&scene, cam, &RenderOptions { background: bg }).unwrap();
            assert!(want.alpha.iter().any(|&a| a > 0.5) && want.alpha.iter().any(|&a| a < 0.5));
            assert_eq!(
                bits(&fit.render_view(v)),
                bits(&want.rgb),
                "{cache:?} view {v}"
            );
            assert_eq!(
                bits(&fit.alpha_view(v)),
                bits(&want.alpha),
                "{cache:?} view {v}"
            );
        }
    }
}

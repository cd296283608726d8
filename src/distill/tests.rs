//! The distillation gradient (issue: the paper's gradient reaches the colours with its
//! magnitude): with the L2 colour loss, dL/d(render) is the alpha-weighted image change
//! itself, and the SH-DC gradient is the rasterizer's vector-Jacobian product of it.

use super::*;
use crate::csd::CsdParams;
use crate::optim::FitParams;
use crate::optim::{LossParams, loss_and_grad};
use crate::render::CacheMode;
use crate::render::tests::{front_camera, random_scene};
use crate::render::{RenderOptions, render};
use crate::rng::Rng;
use crate::terms::half_squared_distance;

fn fit_params() -> FitParams {
    FitParams {
        lr_dc: 0.01,
        lr_rest: 0.0,
        ssim_weight: 0.0,
        mask_alpha: false,
        cache: CacheMode::On,
        background: [0.0; 3],
        progress: false,
    }
}

fn render_rgb(scene: &Scene, cam: &Camera) -> Vec<f32> {
    render(scene, cam, &RenderOptions::default()).unwrap().rgb
}

/// The L2 colour step's DC gradient against central differences of the loss through
/// the full rasterizer (f32 renders, f64 loss, h = 1e-2 on coefficients whose colour is
/// 0.1 or more away from the clamp at 0): relative L2 error over the checked
/// coefficients < 1e-2 (the f32 rounding of the loss differences dominates).
#[test]
fn l2_colour_gradient_matches_finite_differences() {
    let mut scene = random_scene(40, 0, 11);
    // Colours around mid-grey, away from the clamp at 0.
    for c in &mut scene.sh_dc {
        for v in c.iter_mut() {
            *v *= 0.3;
        }
    }
    let cams = [front_camera(40, 32, 40.0, 3.0)];
    let x0 = render_rgb(&scene, &cams[0]);
    let mut rng = Rng::new(5);
    let target: Vec<f32> = x0.iter().map(|v| v + 0.1 * rng.normal() as f32).collect();
    let mut fit = ColourFit::without_targets(&scene, &cams, &fit_params()).unwrap();
    let mut loss =
        |_v: usize, rgb: &[f32], _a: Option<&[f32]>| Ok(half_squared_distance(rgb, &target));
    let (_, g) = fit.gradient_views(&[0], &mut loss).unwrap();
    let l = |s: &Scene| half_squared_distance(&render_rgb(s, &cams[0]), &target).0;
    let h = 1e-2f32;
    let (mut num, mut den, mut checked) = (0.0f64, 0.0f64, 0);
    for i in 0..scene.len() {
        for ch in 0..3 {
            let raw = 0.5 + 0.2821 * scene.sh_dc[i][ch];
            if raw < 0.1 {
                continue;
            }
            let mut p = scene.clone();
            p.sh_dc[i][ch] += h;
            let mut m = scene.clone();
            m.sh_dc[i][ch] -= h;
            let fd = (l(&p) - l(&m)) / (2.0 * h as f64);
            num += (fd - g[i * 3 + ch] as f64).powi(2);
            den += fd * fd;
            checked += 1;
        }
    }
    assert!(checked > 60, "only {checked} coefficients checked");
    assert!(den > 0.0, "the loss does not depend on the colours");
    let rel = (num / den).sqrt();
    assert!(
        rel < 1e-2,
        "relative error {rel} over {checked} coefficients"
    );
}

/// A plane of small non-overlapping Gaussians, mirror-symmetric about the image's
/// vertical centre line, seen head-on.
fn mirrored_plane() -> (Scene, Camera) {
    let mut s = Scene::default();
    let n = 6;
    for iy in 0..n {
        for ix in 0..n {
            for sign in [-1.0f32, 1.0] {
                let x = sign * (0.15 + 0.2 * ix as f32);
                let y = -0.55 + 0.2 * iy as f32;
                s.positions.push([x, y, 0.0]);
                s.log_scales.push([(0.03f32).ln(); 3]);
                s.rotations.push([1.0, 0.0, 0.0, 0.0]);
                s.opacity_logits.push(2.0);
                s.sh_dc.push([0.0, 0.2, -0.3]);
            }
        }
    }
    (s, front_camera(96, 64, 60.0, 3.0))
}

/// With the L2 loss, an image change twice as large on the right half of a view moves
/// the Gaussians there twice as far in one plain gradient step as their mirror images
/// on the left (each pair's ratio within 1e-3 of 2). Under L1 the two halves move
/// equally (the change's size is lost), which this test also shows.
#[test]
fn twice_the_change_moves_twice_as_far() {
    let (scene, cam) = mirrored_plane();
    let cams = [cam];
    let (h, w) = (64usize, 96usize);
    let out = render(&scene, &cams[0], &RenderOptions::default()).unwrap();
    // Target = render + alpha * Delta, Delta = 0.05 left, 0.10 right (colours stay in
    // [0, 1], so nothing is clipped).
    let mut target = out.rgb.clone();
    for y in 0..h {
        for x in 0..w {
            let d = if x < w / 2 { 0.05 } else { 0.10 };
            for c in 0..3 {
                target[(y * w + x) * 3 + c] += out.alpha[y * w + x] * d;
            }
        }
    }
    let step = |kind: ColourLoss| -> Vec<f32> {
        let mut fit = ColourFit::without_targets(&scene, &cams, &fit_params()).unwrap();
        let mut loss = |_v: usize, rgb: &[f32], _a: Option<&[f32]>| match kind {
            ColourLoss::L2 => Ok(half_squared_distance(rgb, &target)),
            ColourLoss::L1 => {
                let lp = LossParams { ssim_weight: 0.0 };
                let (l, g) = loss_and_grad(rgb, &target, None, h, w, lp);
                Ok((l as f64, g))
            }
        };
        // One plain gradient step of size 1: the move is -gradient.
        fit.gradient_views(&[0], &mut loss).unwrap().1
    };
    let g2 = step(ColourLoss::L2);
    let g1 = step(ColourLoss::L1);
    let mut pairs = 0;
    for i in (0..scene.len()).step_by(2) {
        // Gaussian i is on the left (x < 0), i + 1 its mirror image on the right.
        assert!(scene.positions[i][0] < 0.0 && scene.positions[i + 1][0] > 0.0);
        for ch in 0..3 {
            let (l, r) = (g2[i * 3 + ch], g2[(i + 1) * 3 + ch]);
            assert!(
                l < 0.0,
                "Gaussian {i} channel {ch}: the step must raise the colour"
            );
            let ratio = r / l;
            assert!(
                (ratio - 2.0).abs() < 1e-3,
                "Gaussian {i} channel {ch}: right/left move {ratio}, expected 2"
            );
            let ratio1 = g1[(i + 1) * 3 + ch] / g1[i * 3 + ch];
            assert!(
                (ratio1 - 1.0).abs() < 1e-3,
                "L1 moves both halves alike, got {ratio1}"
            );
        }
        pairs += 1;
    }
    assert_eq!(pairs, 36);
}

#[test]
fn keep_chroma_takes_luma_from_one_and_chroma_from_the_other() {
    let c = [0.9, 0.1, 0.2];
    let src = [0.2, 0.5, 0.3];
    let out = keep_chroma(c, src);
    let luma = |v: [f32; 3]| 0.299 * v[0] + 0.587 * v[1] + 0.114 * v[2];
    assert!((luma(out) - luma(c)).abs() < 1e-6);
    for k in 0..3 {
        assert!(((out[k] - luma(out)) - (src[k] - luma(src))).abs() < 1e-6);
    }
    assert_eq!(keep_chroma(src, src), src);
}

/// 32x32 front cameras 3 units away, shifted along x by each of `xs`.
fn cameras_along_x(xs: &[f32]) -> Vec<Camera> {
    xs.iter()
        .map(|&x| {
            let mut c = front_camera(32, 32, 40.0, 3.0);
            c.translation[0] = x;
            c
        })
        .collect()
}

/// A prior that counts its noise predictions (the closed-form Gaussian prior inside).
struct Counting {
    inner: crate::prior::gaussian::GaussianPrior,
    predictions: usize,
}

impl Prior for Counting {
    fn info(&self) -> &crate::prior::PriorInfo {
        self.inner.info()
    }
    fn encode(&mut self, x: ndarray::ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        self.inner.encode(x)
    }
    fn decode(&mut self, z: ndarray::ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        self.inner.decode(z)
    }
    fn predict_eps(
        &mut self,
        z_t: ndarray::ArrayView4<'_, f32>,
        t: usize,
        conds: &[crate::prior::Cond],
        control: Option<ndarray::ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        self.predictions += 1;
        self.inner.predict_eps(z_t, t, conds, control)
    }
}

/// csd at guidance 0 asks nothing of the prior: `distill` then skips the prior's calls
/// (no prediction made) and gives the same colours bit for bit, and the same reports
/// but for the agreement measure, as the whole iteration with its zero gradient, while
/// the texture term moves the colours (so the comparison is not of two unchanged scenes).
#[test]
fn guidance_zero_skips_the_prior_and_gives_the_same_bits() {
    use crate::imageio::Image;
    use crate::scheduler::SchedulerConfig;
    use crate::vgg::{Layer, Vgg16};
    use terms::texture::{Statistic, TextureLoss, TextureTerm};

    let scene = random_scene(300, 0, 21);
    let cams = cameras_along_x(&[-0.3, -0.1, 0.1, 0.3]);
    let src = SourceViews::render(&scene, &cams, [0.0; 3]).unwrap();
    let mut rng = Rng::new(8);
    let style = Image {
        width: 24,
        height: 24,
        data: (0..24 * 24 * 3).map(|_| rng.uniform() as f32).collect(),
    };
    let params = Config {
        views: 2,
        lr_dc: 0.05,
        csd: CsdParams {
            guidance: 0.0,
            ..CsdParams::default()
        },
        ..Config::default()
    };
    assert!(!params.asks_the_prior());
    let run = |skip: bool| {
        let inner = crate::prior::gaussian::GaussianPrior::with_default_text(Some(
            style.to_chw().insert_axis(Axis(0)).view(),
        ))
        .unwrap();
        let mut prior = Counting {
            inner,
            predictions: 0,
        };
        let set = TimestepSet::new(&SchedulerConfig::stable_diffusion(), 20, 980, 50).unwrap();
        let gram = Statistic::new(TextureLoss::Gram, vec![Layer::Relu1_2, Layer::Relu2_2]);
        let term = TextureTerm::new(Vgg16::random(5, 8), &style, &[gram], 1).unwrap();
        let mut d = Distiller::new(&scene, &cams, &src, &mut prior, set, params.clone(), 0)
            .unwrap()
            .with_texture(term);
        let reports: Vec<IterReport> = (0..4)
            .map(|_| {
                if skip {
                    d.iterate_without_prior()
                } else {
                    d.iterate_with_prior()
                }
                .unwrap()
            })
            .collect();
        let (scene, last) = (d.scene().clone(), d.last().cloned().unwrap());
        (scene, reports, last, prior.predictions)
    };
    let (full, full_reports, full_last, full_calls) = run(false);
    let (fast, fast_reports, fast_last, fast_calls) = run(true);
    assert!(full_calls > 0, "the whole iteration asks the prior");
    assert_eq!(fast_calls, 0, "guidance 0 must not call the prior");
    assert!(
        full.sh_dc != scene.sh_dc,
        "the texture term must move the colours for this comparison to mean anything"
    );
    assert_eq!(fast.sh_dc, full.sh_dc, "the same colours, bit for bit");
    for (f, mut g) in fast_reports.into_iter().zip(full_reports) {
        (g.hf_agree_revisit, g.hf_agree_adjacent) = (None, None);
        assert_eq!(f, g);
    }
    assert_eq!(fast_last.targets, full_last.targets);
    assert!(fast_last.latents.is_none() && full_last.latents.is_some());
}

/// A view term of the registry (`tv`, total variation) reaches the colour step through
/// the configuration alone: with `terms = { tv = 1 }` (no prior term) the loop asks the
/// prior nothing, and the colours move so that the renders' total variation falls.
#[test]
fn a_view_term_from_the_registry_moves_the_colours() {
    use crate::scheduler::SchedulerConfig;
    use crate::terms::ViewTerm;
    use crate::terms::tv::TotalVariation;

    let scene = random_scene(300, 0, 5);
    let cams = cameras_along_x(&[-0.2, 0.2]);
    let src = SourceViews::render(&scene, &cams, [0.0; 3]).unwrap();
    let params = Config {
        views: 2,
        lr_dc: 0.05,
        terms: crate::terms::Terms::parse("tv=1").unwrap(),
        ..Config::default()
    };
    assert!(!params.asks_the_prior());
    let mut prior = Counting {
        inner: crate::prior::gaussian::GaussianPrior::with_default_text(None).unwrap(),
        predictions: 0,
    };
    let set = TimestepSet::new(&SchedulerConfig::stable_diffusion(), 20, 980, 50).unwrap();
    let tv = |d: &Distiller<'_>| -> f64 {
        (0..cams.len())
            .map(|v| {
                TotalVariation
                    .view(&d.render_view(v), &src.alpha[v], 32, 32)
                    .0
            })
            .sum()
    };
    let mut d = Distiller::new(&scene, &cams, &src, &mut prior, set, params, 0).unwrap();
    let before = tv(&d);
    for _ in 0..5 {
        d.iterate_without_prior().unwrap();
    }
    let after = tv(&d);
    assert!(after < 0.9 * before, "total variation {before} -> {after}");
    drop(d);
    assert_eq!(prior.predictions, 0);
}

/// Source views rendered from cameras: one per camera at the cameras' size; no camera,
/// or cameras of two sizes, are refused with a message naming the problem.
#[test]
fn source_views_render_every_camera_and_refuse_mixed_sizes() {
    let scene = random_scene(50, 0, 4);
    let cams = [
        front_camera(16, 12, 20.0, 3.0),
        front_camera(16, 12, 24.0, 3.0),
    ];
    let src = SourceViews::render(&scene, &cams, [0.0; 3]).unwrap();
    assert_eq!((src.width, src.height, src.rgb.len()), (16, 12, 2));
    assert_eq!(src.rgb[1], render_rgb(&scene, &cams[1]));
    assert_eq!((src.alpha[0].len(), src.depth[0].len()), (16 * 12, 16 * 12));
    let e = SourceViews::render(&scene, &[], [0.0; 3])
        .unwrap_err()
        .to_string();
    assert!(e.contains("no camera"), "{e}");
    let mixed = [cams[0].clone(), front_camera(8, 12, 20.0, 3.0)];
    let e = SourceViews::render(&scene, &mixed, [0.0; 3])
        .unwrap_err()
        .to_string();
    assert!(e.contains("8x12") && e.contains("16x12"), "{e}");
}

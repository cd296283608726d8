//! Texture through the whole loop (issue 21): a plane of many small Gaussians, distilled
//! with the stylizer prior and the low-layer texture term after an image of vertical
//! stripes, shows the stripes in every view (a peak of the luminance spectrum across
//! the image at the stripes' frequency, absent before), and they are the same stripes
//! seen from each view (adjacent renders agree after depth reprojection).

use fantasystyle::Camera;
use fantasystyle::Scene;
use fantasystyle::camera::load_cameras;
use fantasystyle::distill::{ColourLoss, Config, Distiller, SourceViews};
use fantasystyle::imageio::Image;
use fantasystyle::maths::warp::{surface_depth, warp_into};
use fantasystyle::prior::{self, PriorOptions};
use fantasystyle::rng::Rng;
use fantasystyle::scene::colour::Bands;
use fantasystyle::terms::texture::{Statistic, TextureLoss, TextureTerm};
use fantasystyle::vgg::{Layer, Vgg16};

/// Side of the renders; stripes of the style: period in pixels.
const SIZE: usize = 64;
const PERIOD: usize = 8;

/// A 48 x 48 grid of small Gaussians on the plane z = 0 (|x|, |y| <= 1), grey with a
/// little random jitter (so the texture has something to grow from).
fn plane() -> Scene {
    let mut rng = Rng::new(3);
    let mut s = Scene::default();
    let n = 48;
    for iy in 0..n {
        for ix in 0..n {
            let x = -1.0 + 2.0 * (ix as f32 + 0.5) / n as f32;
            let y = -1.0 + 2.0 * (iy as f32 + 0.5) / n as f32;
            s.positions.push([x, y, 0.0]);
            s.log_scales.push([(0.025f32).ln(); 3]);
            s.rotations.push([1.0, 0.0, 0.0, 0.0]);
            s.opacity_logits.push(4.0);
            let g = 0.5 + 0.05 * rng.normal() as f32;
            s.sh_dc.push([(g - 0.5) / 0.282_094_8; 3]);
        }
    }
    s
}

/// Four views of a 45-view orbit (8 degrees apart) around the plane, from its
/// -z side, 3 units away, filling most of the frame.
fn cameras(scene: &Scene) -> Vec<Camera> {
    let mut c = load_cameras(
        "orbit:45,elev=0,radius=3,fov=40",
        &scene.bounds(),
        SIZE as u32,
        SIZE as u32,
    )
    .unwrap();
    // Views 1..=4 (8 to 32 degrees). View 0 looks at the plane exactly head-on, where
    // the depth reprojection of metrics::warp disagrees with the renders (even the
    // source views' jitter correlates only 0.6 from view 0 to view 1, 0.98 between
    // views 1 and 2): a known gap of the warp, not of the texture.
    c.drain(1..5).collect()
}

/// Vertical stripes, `PERIOD` px, warm light / dark blue, 128 x 128.
fn stripes() -> Image {
    let mut data = Vec::with_capacity(128 * 128 * 3);
    for _y in 0..128 {
        for x in 0..128 {
            let c = if (x / (PERIOD / 2)).is_multiple_of(2) {
                [0.95, 0.8, 0.3]
            } else {
                [0.1, 0.15, 0.45]
            };
            data.extend_from_slice(&c);
        }
    }
    Image {
        width: 128,
        height: 128,
        data,
    }
}

fn luma(rgb: &[f32], p: usize) -> f64 {
    (0.299 * rgb[p * 3] + 0.587 * rgb[p * 3 + 1] + 0.114 * rgb[p * 3 + 2]) as f64
}

/// Power of the luminance along image rows in the central 32 x 32 crop (each row's mean
/// removed), averaged over rows: bins 1..=16 cycles per 32 px.
fn row_spectrum(rgb: &[f32]) -> Vec<f64> {
    let (n, off) = (32usize, (SIZE - 32) / 2);
    let mut power = vec![0.0f64; n / 2 + 1];
    for y in off..off + n {
        let row: Vec<f64> = (off..off + n).map(|x| luma(rgb, y * SIZE + x)).collect();
        let mean = row.iter().sum::<f64>() / n as f64;
        for (k, pk) in power.iter_mut().enumerate().skip(1) {
            let (mut re, mut im) = (0.0, 0.0);
            for (x, v) in row.iter().enumerate() {
                let a = -2.0 * std::f64::consts::PI * (k * x) as f64 / n as f64;
                re += (v - mean) * a.cos();
                im += (v - mean) * a.sin();
            }
            *pk += re * re + im * im;
        }
    }
    power
}

/// (peak bin, peak power / mean power of the other bins 1..=16).
fn peak(power: &[f64]) -> (usize, f64) {
    let (k, &p) = power
        .iter()
        .enumerate()
        .skip(1)
        .max_by(|a, b| a.1.total_cmp(b.1))
        .unwrap();
    let rest: Vec<f64> = (1..power.len())
        .filter(|&i| i != k)
        .map(|i| power[i])
        .collect();
    (k, p / (rest.iter().sum::<f64>() / rest.len() as f64))
}

#[test]
fn a_plane_styled_with_stripes_shows_them_in_every_view() {
    stripes_case(&[Statistic::new(
        TextureLoss::Gram,
        vec![Layer::Relu1_2, Layer::Relu2_2],
    )]);
}

/// The same with the NNFM statistic over the relu3 block (the sample DAG's texture term).
#[test]
fn with_the_nnfm_term_too() {
    stripes_case(&[Statistic::new(
        TextureLoss::Nnfm,
        TextureLoss::Nnfm.default_layers(),
    )]);
}

/// The weight-free patch prior alone (priors/patch, its style scale set to the stripes'
/// 128 px so that they keep their period on screen), with every VGG term off: the
/// paper's CSD term is the only term.
#[test]
fn with_the_patch_prior_alone() {
    let tmp = tempfile::tempdir().unwrap();
    let model = crate::patch_prior::patch_model(tmp.path(), &[("style_size", 128.into())]);
    stripes_with(&model, None);
}

/// Distill a plane of small Gaussians after a stripe style with the texture term `parts`;
/// every view then shows the stripes at their period, and neighbouring views agree.
fn stripes_case(parts: &[Statistic]) {
    let (Some(stylizer), Some(vgg_dir)) = (
        crate::harness::model("stylizer"),
        crate::harness::model_file("lpips/vgg16", "conv0_weight.npy")
            .map(|f| f.parent().unwrap().to_path_buf()),
    ) else {
        return;
    };
    let term = TextureTerm::new(Vgg16::load(&vgg_dir).unwrap(), &stripes(), parts, 1).unwrap();
    stripes_with(&stylizer, Some(term));
}

/// Distill the plane after the stripes with the prior at `model` (and `term`, if any).
fn stripes_with(model: &std::path::Path, term: Option<TextureTerm>) {
    let stylizer = model;
    let scene = plane();
    let cams = cameras(&scene);
    let src = SourceViews::render(&scene, &cams, [0.0; 3]).unwrap();
    let expected = 32 / PERIOD;
    for (v, rgb) in src.rgb.iter().enumerate() {
        let (k, ratio) = peak(&row_spectrum(rgb));
        assert!(
            !(k == expected && ratio > 4.0),
            "view {v} shows stripes before distillation (bin {k}, ratio {ratio:.1})"
        );
    }
    let style = stripes();
    let mut p = prior::open(
        stylizer,
        &PriorOptions {
            style_image: Some(style.to_chw().insert_axis(ndarray::Axis(0))),
            ..Default::default()
        },
    )
    .unwrap();
    let set = prior::model_timesteps(stylizer).unwrap().1;
    let params = Config {
        views: 2,
        lr_dc: 0.05,
        colour_loss: ColourLoss::L2,
        ..Config::default()
    };
    let mut d = Distiller::new(&scene, &cams, &src, p.as_mut(), set, params, 0).unwrap();
    if let Some(term) = term {
        d = d.with_texture(term);
    }
    for _ in 0..60 {
        d.iterate().unwrap();
    }
    let renders: Vec<Vec<f32>> = (0..cams.len()).map(|v| d.render_view(v)).collect();
    assert_stripes(&cams, &src, &renders);
}

/// The patch prior's deterministic end alone (`finish = "patches"`, no iteration): the
/// plane's colours synthesised from the stripes' patches show the stripes in every view,
/// the same stripes from each view, with the geometry bit for bit the input's and the same
/// bytes on a second run.
#[test]
fn with_the_patch_synthesis_alone() {
    use fantasystyle::ends::patches::{SynthesisParams, regions::RegionStyle, synthesize};
    let scene = plane();
    let cams = cameras(&scene);
    let src = SourceViews::render(&scene, &cams, [0.0; 3]).unwrap();
    let p = SynthesisParams {
        levels: vec![2, 1],
        rounds: 3,
        ..SynthesisParams::default()
    };
    let run = || {
        synthesize(
            &scene,
            &cams,
            &[RegionStyle::one(&stripes())],
            [0.0; 3],
            128,
            &p,
            None,
            None,
            Bands::Keep,
        )
        .unwrap()
    };
    let (out, reports) = run();
    eprintln!("{}", serde_json::to_string(&reports).unwrap());
    assert_eq!(out.positions, scene.positions);
    assert_eq!(out.log_scales, scene.log_scales);
    assert_eq!(out.rotations, scene.rotations);
    assert_eq!(out.opacity_logits, scene.opacity_logits);
    let renders: Vec<Vec<f32>> = fantasystyle::render::render_all(&out, &cams, [0.0; 3])
        .unwrap()
        .into_iter()
        .map(|r| r.rgb)
        .collect();
    assert_stripes(&cams, &src, &renders);
    let bits = |s: &Scene| {
        s.sh_dc
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(
        bits(&run().0),
        bits(&out),
        "a second run gave other colours"
    );
}

/// Every view of `renders` shows the stripes at their period, and neighbouring views agree.
fn assert_stripes(cams: &[Camera], src: &SourceViews, renders: &[Vec<f32>]) {
    let expected = 32 / PERIOD;
    for (v, rgb) in renders.iter().enumerate() {
        let (k, ratio) = peak(&row_spectrum(rgb));
        eprintln!(
            "view {v}: spectrum peak at {k} cycles / 32 px (expected {expected}), {ratio:.1}x the other bins"
        );
        assert!(
            k.abs_diff(expected) <= 1 && ratio > 4.0,
            "view {v}: no stripes at {expected} cycles / 32 px (peak at {k}, {ratio:.1}x the rest)"
        );
    }
    // The same stripes from each view: each view warped into the next (8 degrees apart)
    // agrees with that view's render (luminance correlation over the valid pixels).
    for v in 1..cams.len() {
        let (corr, n) = warped_correlation(cams, src, renders, v - 1, v);
        eprintln!(
            "view {} -> view {v}: luminance correlation {corr:.3} over {n} px",
            v - 1
        );
        assert!(n > SIZE * SIZE / 3, "view {v}: only {n} valid pixels");
        assert!(
            corr > 0.8,
            "view {} warped into view {v} correlates {corr:.3}",
            v - 1
        );
    }
}

/// Correlation of view `a`'s render warped into view `b` (depth reprojection with the
/// source views' depth) with view `b`'s render, and the number of valid pixels.
fn warped_correlation(
    cams: &[Camera],
    src: &SourceViews,
    renders: &[Vec<f32>],
    a: usize,
    b: usize,
) -> (f64, usize) {
    let za = surface_depth(&src.depth[a], &src.alpha[a]);
    let zb = surface_depth(&src.depth[b], &src.alpha[b]);
    let img = Image {
        width: SIZE,
        height: SIZE,
        data: renders[a].clone(),
    };
    let w = warp_into(&cams[b], &zb, &cams[a], &za, &img);
    let idx: Vec<usize> = (0..SIZE * SIZE).filter(|&p| w.mask[p] > 0.5).collect();
    let x: Vec<f64> = idx.iter().map(|&p| luma(&w.image.data, p)).collect();
    let y: Vec<f64> = idx.iter().map(|&p| luma(&renders[b], p)).collect();
    (correlation(&x, &y), idx.len())
}

fn correlation(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        sab += (x - ma) * (y - mb);
        saa += (x - ma) * (x - ma);
        sbb += (y - mb) * (y - mb);
    }
    sab / (saa * sbb).sqrt().max(1e-12)
}

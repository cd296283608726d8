//! The structure guide of the deterministic end (`synthesis.control`, issue 47): a
//! shaded sphere styled with two-tone stripes takes the stripes' dark tone where its
//! shading is dark when guided, and not when unguided; the geometry stays bit for bit;
//! a second run gives the same bytes; the guidance scale 0 keeps the scene.

use fantasystyle::Scene;
use fantasystyle::camera::load_cameras;
use fantasystyle::distill::synthesis::{SynthesisParams, synthesize};
use fantasystyle::imageio::Image;

/// Side of the renders.
const SIZE: usize = 64;

/// A sphere of radius 1 of 6,000 small Gaussians (a Fibonacci lattice), grey albedo
/// under a light from +x (Lambert, 0.08 ambient): bright on one side, dark on the other.
fn shaded_sphere() -> Scene {
    let n = 6000;
    let mut s = Scene::default();
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    for i in 0..n {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
        let r = (1.0 - y * y).sqrt();
        let th = golden * i as f32;
        let p = [r * th.cos(), y, r * th.sin()];
        s.positions.push(p);
        s.log_scales.push([(0.035f32).ln(); 3]);
        s.rotations.push([1.0, 0.0, 0.0, 0.0]);
        s.opacity_logits.push(5.0);
        let shade = 0.08 + 0.84 * p[0].max(0.0);
        s.sh_dc.push([(shade - 0.5) / 0.282_094_8; 3]);
    }
    s
}

/// Horizontal two-tone stripes, 6 px, cream and dark blue, 96 x 96.
fn stripes() -> Image {
    let data = (0..96 * 96)
        .flat_map(|i| {
            if (i / 96 / 3) % 2 == 0 {
                [0.95, 0.9, 0.75]
            } else {
                [0.08, 0.1, 0.3]
            }
        })
        .collect();
    Image {
        width: 96,
        height: 96,
        data,
    }
}

fn luma(rgb: &[f32]) -> Vec<f64> {
    rgb.chunks(3)
        .map(|p| 0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64)
        .collect()
}

/// Pearson correlation of `a` and `b` over the pixels where `keep` holds.
fn correlation(a: &[f64], b: &[f64], keep: &[bool]) -> f64 {
    let pairs: Vec<(f64, f64)> = (0..a.len())
        .filter(|&i| keep[i])
        .map(|i| (a[i], b[i]))
        .collect();
    let n = pairs.len() as f64;
    let (ma, mb) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
    let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
    let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

/// The mean over the views of the correlation between the source's luma and the
/// result's luma box-blurred over the stripes' period (so that the stripes themselves
/// do not count, only where their dark tone goes), over the object's pixels.
fn shading_kept(scene: &Scene, out: &Scene, cams: &[fantasystyle::Camera]) -> f64 {
    let render = |s: &Scene| fantasystyle::render::render_all(s, cams, [0.0; 3]).unwrap();
    let (src, res) = (render(scene), render(out));
    let mut sum = 0.0;
    for (a, b) in src.iter().zip(&res) {
        let keep: Vec<bool> = a.alpha.iter().map(|&x| x > 0.9).collect();
        let lb = box_blur(&luma(&b.rgb), 3);
        sum += correlation(&luma(&a.rgb), &lb, &keep);
    }
    sum / src.len() as f64
}

fn box_blur(v: &[f64], r: isize) -> Vec<f64> {
    let n = SIZE as isize;
    (0..n * n)
        .map(|i| {
            let (y, x) = (i / n, i % n);
            let (mut s, mut c) = (0.0, 0.0);
            for yy in (y - r).max(0)..(y + r + 1).min(n) {
                for xx in (x - r).max(0)..(x + r + 1).min(n) {
                    s += v[(yy * n + xx) as usize];
                    c += 1.0;
                }
            }
            s / c
        })
        .collect()
}

#[test]
fn a_guided_sphere_takes_the_dark_stripes_where_it_is_dark() {
    let scene = shaded_sphere();
    let cams = load_cameras(
        "orbit:6,elev=10,radius=3.2,fov=45",
        &scene.bounds(),
        SIZE as u32,
        SIZE as u32,
    )
    .unwrap();
    let run = |control: f32, guidance: f32| {
        let p = SynthesisParams {
            levels: vec![2, 1],
            control,
            guidance,
            ..SynthesisParams::default()
        };
        synthesize(&scene, &cams, &stripes(), [0.0; 3], 96, &p, None, None)
            .unwrap()
            .0
    };
    let guided = run(1.0, 1.0);
    let unguided = run(0.0, 1.0);
    let (g, u) = (
        shading_kept(&scene, &guided, &cams),
        shading_kept(&scene, &unguided, &cams),
    );
    eprintln!("shading kept: guided {g:.3}, unguided {u:.3}");
    assert!(
        g > 0.8,
        "guided: the dark tone does not follow the shading ({g:.3})"
    );
    assert!(g > u + 0.2, "the guide changed little: {g:.3} vs {u:.3}");
    assert_eq!(guided.positions, scene.positions);
    assert_eq!(guided.log_scales, scene.log_scales);
    assert_eq!(guided.rotations, scene.rotations);
    assert_eq!(guided.opacity_logits, scene.opacity_logits);
    let bits = |s: &Scene| {
        s.sh_dc
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&run(1.0, 1.0)), bits(&guided), "a second run differs");
    // The guidance scale 0 moves every patch to the scene's own: the colours stay near.
    let kept = run(1.0, 0.0);
    let change = |s: &Scene| {
        let d: f64 = s
            .sh_dc
            .iter()
            .zip(&scene.sh_dc)
            .flat_map(|(a, b)| (0..3).map(move |c| ((a[c] - b[c]) as f64).powi(2)))
            .sum();
        (d / scene.len() as f64).sqrt()
    };
    eprintln!(
        "RMS SH DC change: guidance 0 {:.4}, 1 {:.4}",
        change(&kept),
        change(&guided)
    );
    assert!(change(&kept) < 0.2 * change(&guided));
}

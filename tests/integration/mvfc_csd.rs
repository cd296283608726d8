//! CSD with the stylizer prior (issue 5; real Magenta weights from
//! scripts/setup/20_stylizer.py): a few rounds move views toward the style, the
//! stylizer's eps is the x0 parameterisation, and its lanes give the same bits as one
//! session; and the csd-step stage: its targets with the stylizer, its bad-input errors.

use crate::harness::repo_root;
use crate::mvfc::{csd_inputs, filter_args, model_dir, step_args, write_latents};
use fantasystyle::artifacts::{read_latents, read_targets};
use fantasystyle::camera::path::ViewPath;
use fantasystyle::csd::{self, CsdParams, Mode, StepInputs};
use fantasystyle::distill::step::Draws;
use fantasystyle::prior::Prior;
use fantasystyle::prior::stylizer::StylizerPrior;
use fantasystyle::rng::Rng;
use fantasystyle::stages::{csd_step, mvfc_filter};
use ndarray::Array4;

/// The style image: the sample's `data-sample/style.png` when present (scene engineer's
/// generator), else a synthetic colourful swirl of the same kind.
fn style_image(size: usize) -> Array4<f32> {
    let p = repo_root().join("data-sample/style.png");
    if let Ok(img) = image::open(&p) {
        let img = img
            .resize_exact(
                size as u32,
                size as u32,
                image::imageops::FilterType::Triangle,
            )
            .to_rgb32f();
        return Array4::from_shape_fn((1, 3, size, size), |(_, c, y, x)| {
            img.get_pixel(x as u32, y as u32)[c]
        });
    }
    Array4::from_shape_fn((1, 3, size, size), |(_, c, y, x)| {
        let (u, v) = (x as f32 / size as f32, y as f32 / size as f32);
        let a = (12.0 * u + 5.0 * (6.0 * v).sin()).sin();
        let b = (9.0 * v + 4.0 * (7.0 * u).cos()).cos();
        let col = [[0.95, 0.55, 0.1], [0.1, 0.3, 0.85], [0.1, 0.7, 0.6]];
        let k = if a > 0.3 {
            0
        } else if b > 0.0 {
            1
        } else {
            2
        };
        col[k][c]
    })
}

/// Synthetic "views": a shaded grey-brown ball on a pale gradient, shifting per view.
fn content_views(n: usize, size: usize) -> Array4<f32> {
    Array4::from_shape_fn((n, 3, size, size), |(v, c, y, x)| {
        let (u, w) = (x as f32 / size as f32, y as f32 / size as f32);
        let cx = 0.4 + 0.05 * v as f32;
        let r2 = (u - cx).powi(2) + (w - 0.55).powi(2);
        if r2 < 0.09 {
            let shade = 1.0 - r2 / 0.09 * 0.6;
            [0.55, 0.45, 0.4][c] * shade
        } else {
            0.75 + 0.15 * w - 0.05 * c as f32
        }
    })
}

/// Distance of an image batch's colour statistics to the style's: per-channel mean and
/// standard deviation (colour moments) plus the 3x3 RGB Gram matrix (mean of x x^T).
fn style_distance(imgs: &Array4<f32>, style: &Array4<f32>) -> (f64, f64) {
    let stats = |a: &Array4<f32>| {
        let n = (a.len() / 3) as f64;
        let ch = |c: usize| a.slice(ndarray::s![.., c, .., ..]).mapv(|v| v as f64);
        let chans: Vec<_> = (0..3).map(ch).collect();
        let mean: Vec<f64> = chans.iter().map(|x| x.sum() / n).collect();
        let sd: Vec<f64> = chans
            .iter()
            .zip(&mean)
            .map(|(x, m)| (x.mapv(|v| (v - m).powi(2)).sum() / n).sqrt())
            .collect();
        let mut gram = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                gram[i][j] = (&chans[i] * &chans[j]).sum() / n;
            }
        }
        (mean, sd, gram)
    };
    let (m1, s1, g1) = stats(imgs);
    let (m2, s2, g2) = stats(style);
    let moments: f64 = (0..3)
        .map(|c| (m1[c] - m2[c]).abs() + (s1[c] - s2[c]).abs())
        .sum();
    let gram: f64 = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (g1[i][j] - g2[i][j]).powi(2))
        .sum::<f64>()
        .sqrt();
    (moments, gram)
}

fn stylizer(style: &Array4<f32>) -> Option<StylizerPrior> {
    let dir = crate::harness::model("stylizer")?;
    Some(StylizerPrior::open(&dir, Some(style.view()), 2).unwrap())
}

/// A few CSD rounds with the stylizer prior move the views' colour statistics toward
/// the style image: colour-moment and RGB-Gram distances both fall by at least 20%, and
/// the images stay finite in [0, 1].
#[test]
fn stylizer_csd_moves_views_toward_the_style() {
    let style = style_image(256);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let views = content_views(2, 128);
    let (m0, g0) = style_distance(&views, &style);
    let mut z0 = prior.encode(views.view()).unwrap();
    let params = CsdParams::default();
    for round in 0..3u64 {
        let t = [300, 200, 100][round as usize];
        let eps = Array4::from_shape_vec(
            z0.raw_dim(),
            Rng::derive(5, &format!("eps/{round}")).normals_f32(z0.len()),
        )
        .unwrap();
        let z_tgt = sched.add_noise(z0.view(), eps.view(), t).unwrap();
        let z_src = sched.add_noise(views.view(), eps.view(), t).unwrap();
        let (z1, _) = csd::step(
            &mut prior,
            &sched,
            StepInputs {
                z0: z0.view(),
                z_tgt: z_tgt.view(),
                z_src: z_src.view(),
                eps: eps.view(),
                z0_src: None,
                t,
                control: None,
            },
            &params,
        )
        .unwrap();
        z0 = z1.mapv(|v| v.clamp(0.0, 1.0));
    }
    let (m1, g1) = style_distance(&z0, &style);
    eprintln!("colour moments {m0:.4} -> {m1:.4}, RGB Gram {g0:.4} -> {g1:.4}");
    assert!(z0.iter().all(|v| v.is_finite()));
    assert!(m1 < 0.8 * m0, "colour-moment distance {m0} -> {m1}");
    assert!(g1 < 0.8 * g0, "Gram distance {g0} -> {g1}");
}

// csd-step against numpy's targets: csd_golden::csd_step_stage_matches_numpy_targets.

/// csd-step with the stylizer model through `prior::open`: the targets move toward the
/// style's colour statistics.
#[test]
fn csd_step_stage_with_stylizer() {
    let Some(model) = model_dir("stylizer") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let views = content_views(2, 64);
    let style = style_image(128);
    let sp = csd_inputs(d.path(), &model, &views, &style);
    let mut a = step_args(d.path(), &model, &sp, Mode::Csd);
    a.config.sets.push("csd.lr=0.1".into());
    csd_step::run(a.clone()).unwrap();
    let rgb = read_targets(&d.path().join("targets")).unwrap().rgb;
    let tgt = rgb.permuted_axes([0, 3, 1, 2]).to_owned();
    let (m0, _) = style_distance(&views, &style);
    let (m1, _) = style_distance(&tgt, &style);
    assert!(m1 < m0, "colour moments {m0} -> {m1}");
}

/// Bad input to csd-step: missing style image, mismatched latents, inputs of another
/// iteration; clear errors and no output.
#[test]
fn csd_step_stage_rejects_bad_input() {
    let Some(model) = model_dir("gaussian-prior") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let views = content_views(2, 32);
    let sp = csd_inputs(d.path(), &model, &views, &style_image(32));
    let err = |a: &csd_step::Args| {
        let e = csd_step::run(a.clone()).unwrap_err();
        assert!(!a.out.exists());
        (e.exit_code(), e.to_string())
    };
    let mut a = step_args(d.path(), &model, &sp, Mode::Csd);
    a.prior.style = d.path().join("nope.png");
    let (code, e) = err(&a);
    assert!(
        code == 2 && e.contains("nope.png") && e.contains("not found"),
        "{e}"
    );

    std::fs::write(d.path().join("bad.png"), b"not a png").unwrap();
    a.prior.style = d.path().join("bad.png");
    let (code, e) = err(&a);
    assert!(code == 2 && e.contains("bad.png"), "{e}");

    // Latents of another shape than the noised ones.
    write_latents(
        &d.path().join("lat2"),
        &Array4::zeros((2, 4, 4, 2)),
        serde_json::json!({}),
    );
    let mut b = step_args(d.path(), &model, &sp, Mode::Csd);
    b.latents = d.path().join("lat2");
    let (code, e) = err(&b);
    assert!(code == 2 && e.contains("shape"), "{e}");

    // Noised latents of a recorded iteration, latents of none.
    let z = read_latents(&d.path().join("lat")).unwrap();
    let w = Draws::new(
        0,
        4,
        ViewPath {
            len: 2,
            closed: false,
        },
        2,
    )
    .window()
    .clone();
    let mut c = filter_args(d.path(), &model);
    write_latents(
        &d.path().join("lat_it"),
        &z,
        serde_json::json!({ "iteration": w }),
    );
    (c.latents, c.source_latents) = (d.path().join("lat_it"), d.path().join("lat"));
    (c.iteration, c.out) = (None, d.path().join("noised_it"));
    mvfc_filter::run(c).unwrap();
    let mut e2 = step_args(d.path(), &model, &sp, Mode::Csd);
    e2.noised = d.path().join("noised_it");
    let (code, e) = err(&e2);
    assert!(
        code == 2 && e.contains("another iteration") && e.contains("lat"),
        "{e}"
    );
}

/// The stylizer's eps under Null inverts to its clean estimate (eps = (z - sqrt(ab) x0) /
/// sqrt(1-ab)); Content equals Null (both the identity: unstyled); Prompt (the image
/// redrawn with its own style) and PromptStyle (with the style image's) differ from it
/// and from each other.
#[test]
fn stylizer_eps_is_the_x0_parameterisation() {
    let style = style_image(64);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let x = content_views(1, 48);
    let eps = Array4::from_shape_vec(x.raw_dim(), Rng::new(4).normals_f32(x.len())).unwrap();
    let t = 200;
    let z = sched.add_noise(x.view(), eps.view(), t).unwrap();
    let conds = [
        fantasystyle::prior::Cond::Null,
        fantasystyle::prior::Cond::Prompt,
        fantasystyle::prior::Cond::PromptStyle,
        fantasystyle::prior::Cond::Content,
    ];
    let e = prior.predict_eps(z.view(), t, &conds, None).unwrap();
    let x0 = sched.x0_from_eps(z.view(), e[0].view(), t).unwrap();
    let xh = prior
        .clean_estimate(z.index_axis(ndarray::Axis(0), 0), t)
        .unwrap();
    let err = x0
        .index_axis(ndarray::Axis(0), 0)
        .iter()
        .zip(xh.iter())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(err < 1e-4, "{err}");
    assert_eq!(e[0], e[3]);
    let diff = |a: &Array4<f32>, b: &Array4<f32>| {
        a.iter()
            .zip(b.iter())
            .map(|(p, q)| (p - q).abs())
            .fold(0.0f32, f32::max)
    };
    assert!(diff(&e[1], &e[0]) > 1e-2 && diff(&e[2], &e[0]) > 1e-2);
    assert!(diff(&e[2], &e[1]) > 1e-2);
    // The clean estimate is closer to the clean image than z / sqrt(ab) is.
    let ab = sched.alpha_bar(t).unwrap() as f32;
    let naive: f32 = z
        .iter()
        .zip(x.iter())
        .map(|(a, b)| (a / ab.sqrt() - b).powi(2))
        .sum();
    let est: f32 = xh.iter().zip(x.iter()).map(|(a, b)| (a - b).powi(2)).sum();
    assert!(est < 0.2 * naive, "{est} vs {naive}");
}

/// `predict_eps` stylizes the views of a call side by side (one transfer session per
/// worker, intra-op threads split between them): the same bits on pools of 1, 2 and 3
/// threads, and the same as stylizing view after view with one session of the default
/// thread count (eps from the clean estimate redrawn by `stylize`).
#[test]
fn lanes_give_the_same_bits_as_one_session() {
    use fantasystyle::prior::Cond;
    let style = style_image(64);
    let Some(mut prior) = stylizer(&style) else {
        return;
    };
    let sched = prior.schedule().clone();
    let x = content_views(3, 48);
    let eps = Array4::from_shape_vec(x.raw_dim(), Rng::new(9).normals_f32(x.len())).unwrap();
    let t = 150;
    let z = sched.add_noise(x.view(), eps.view(), t).unwrap();
    let conds = [Cond::PromptStyle, Cond::Prompt];
    let on = |threads: usize, prior: &mut StylizerPrior| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| prior.predict_eps(z.view(), t, &conds, Some(x.view())))
            .unwrap()
    };
    let one = on(1, &mut prior);
    assert_eq!(on(2, &mut prior), one);
    assert_eq!(on(3, &mut prior), one);
    // View after view on the prior's own session (2 intra-op threads).
    let s_style = prior
        .style_vector(style.index_axis(ndarray::Axis(0), 0))
        .unwrap();
    for b in 0..3 {
        let zb = z.index_axis(ndarray::Axis(0), b);
        let xh = prior.clean_estimate(zb, t).unwrap();
        let s_own = prior
            .style_vector(x.index_axis(ndarray::Axis(0), b))
            .unwrap();
        for (k, s) in [(0, &s_style), (1, &s_own)] {
            let x0 = prior.stylize(xh.view(), s).unwrap();
            let e = sched.eps_from_x0(zb, x0.view(), t).unwrap();
            assert_eq!(
                one[k].index_axis(ndarray::Axis(0), b),
                e,
                "view {b}, cond {k}"
            );
        }
    }
}

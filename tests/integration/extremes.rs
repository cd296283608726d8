//! The distillation loop at its extremes (issue 22), each a test: guidance 0 and 1e6,
//! the CSD step (`--lr`) and the colour step (`--lr-dc`) 0 and 1e3, views the object
//! does not cover, Gaussians of zero scale and of opacity 0 and 1, and a prior that
//! returns NaN. Finite colours, or an error naming the iteration; never a checkpoint
//! written from a non-finite state (`src/distill/guard.rs`).
//!
//! The prior is a test double (no model needed): a pixel-space prior shaped like the
//! default one (identity "VAE", exact unconditional branches) whose styled prediction is
//! a fixed saturated colour, so every step asks for a large, known change.

use crate::harness::{self, repo_root};
use fantasystyle::csd::CsdParams;
use fantasystyle::distill::{Config, Distiller, SourceViews};
use fantasystyle::prior::{Cond, Prior, PriorInfo};
use fantasystyle::scene::colour::{Bands, outside_base};
use fantasystyle::scheduler::{Schedule, SchedulerConfig, TimestepSet};
use fantasystyle::terms::Terms;
use fantasystyle::{Camera, Scene};
use ndarray::{Array4, ArrayView4};

/// Pixel-space test prior: PromptStyle predicts the clean image `colour`, Prompt the
/// clean estimate z / sqrt(ab) (no restyle); Null and Content are exact in CSD. With
/// `nan_from = Some(k)`, every prediction from its k-th call on is NaN.
struct ColourPrior {
    info: PriorInfo,
    schedule: Schedule,
    colour: [f32; 3],
    calls: usize,
    nan_from: Option<usize>,
}

impl ColourPrior {
    fn new(nan_from: Option<usize>) -> Self {
        let cfg = SchedulerConfig::stable_diffusion();
        ColourPrior {
            info: PriorInfo {
                name: "colour-test-prior".into(),
                latent_channels: 3,
                downsample: 1,
                scheduler: cfg.clone(),
                control: None,
                coinciding_style_content: None,
            },
            schedule: Schedule::new(cfg).unwrap(),
            colour: [0.9, 0.15, 0.05],
            calls: 0,
            nan_from,
        }
    }
}

impl Prior for ColourPrior {
    fn info(&self) -> &PriorInfo {
        &self.info
    }
    fn unconditional_is_identity(&self) -> bool {
        true
    }
    fn encode(&mut self, images: ArrayView4<'_, f32>) -> fantasystyle::Result<Array4<f32>> {
        Ok(images.to_owned())
    }
    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> fantasystyle::Result<Array4<f32>> {
        Ok(latents.to_owned())
    }
    fn predict_eps(
        &mut self,
        z: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        _control: Option<ArrayView4<'_, f32>>,
    ) -> fantasystyle::Result<Vec<Array4<f32>>> {
        self.calls += 1;
        let nan = self.nan_from.is_some_and(|k| self.calls > k);
        let ab = self.schedule.alpha_bar(t)?;
        let (sa, sb) = (ab.sqrt() as f32, (1.0 - ab).sqrt() as f32);
        Ok(conds
            .iter()
            .map(|c| {
                Array4::from_shape_fn(z.raw_dim(), |(b, ch, y, x)| {
                    if nan {
                        return f32::NAN;
                    }
                    let zz = z[[b, ch, y, x]];
                    let x0 = match c {
                        Cond::PromptStyle => self.colour[ch],
                        _ => (zz / sa).clamp(0.0, 1.0),
                    };
                    (zz - sa * x0) / sb
                })
            })
            .collect())
    }
}

fn sample_scene() -> Scene {
    fantasystyle::artifacts::load_scene(&repo_root().join("data-sample/scene.ply")).unwrap()
}

/// Four orbit cameras at 24x24 (those in `away` turned around on the spot, so that the
/// object is behind them and covers no pixel) and the scene's renders from them.
fn setup_away(scene: &Scene, away: &[usize]) -> (Vec<Camera>, SourceViews) {
    let mut cams =
        fantasystyle::camera::load_cameras("orbit:4,elev=30,radius=2.4", &scene.bounds(), 24, 24)
            .unwrap();
    for &v in away {
        // R' = diag(-1, 1, -1) R, t' = diag(-1, 1, -1) t: same centre, facing away.
        let c = &mut cams[v];
        for k in [0, 2] {
            c.rotation[k] = c.rotation[k].map(|x| -x);
            c.translation[k] = -c.translation[k];
        }
    }
    let src = SourceViews::render(scene, &cams, [0.0; 3]).unwrap();
    (cams, src)
}

fn setup(scene: &Scene, away: bool) -> (Vec<Camera>, SourceViews) {
    setup_away(scene, if away { &[0, 1, 2, 3] } else { &[] })
}

fn params(csd: CsdParams, lr_dc: f32) -> Config {
    Config {
        terms: Terms::prior_only(csd.mode),
        views: 2,
        csd,
        lr_dc,
        ..Config::default()
    }
}

/// Run `iters` iterations; the scene after them, or the error.
fn run(
    scene: &Scene,
    cams: &[Camera],
    src: &SourceViews,
    prior: &mut ColourPrior,
    p: Config,
    iters: usize,
) -> Result<Scene, String> {
    let set = TimestepSet::default_for(&SchedulerConfig::stable_diffusion()).unwrap();
    let mut d = Distiller::new(scene, cams, src, prior, set, p, 0).map_err(|e| e.to_string())?;
    for _ in 0..iters {
        d.iterate().map_err(|e| e.to_string())?;
    }
    for v in 0..cams.len() {
        assert!(d.render_view(v).iter().all(|x| x.is_finite()), "view {v}");
    }
    Ok(d.scene().clone())
}

fn bits(s: &Scene) -> Vec<u32> {
    s.sh_dc.iter().flatten().map(|v| v.to_bits()).collect()
}

/// Largest change of a colour (SH DC).
fn moved(a: &Scene, b: &Scene) -> f32 {
    a.sh_dc
        .iter()
        .flatten()
        .zip(b.sh_dc.iter().flatten())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn finite(s: &Scene) -> bool {
    s.sh_dc
        .iter()
        .flatten()
        .chain(&s.sh_rest)
        .all(|v| v.is_finite())
}

/// How far `iters` Adam steps of `lr` can move a parameter, whatever its gradients:
/// step t moves it by lr |m^_t / sqrt(v^_t)| <= lr (1 - b1) / (1 - b1^t)
/// sqrt((1 - b2^t) / (1 - b2)) sqrt(sum_{k<t} (b1^2 / b2)^k) (Cauchy-Schwarz; 1 at
/// t = 1, 1.016 at t = 6), with the 3DGS betas 0.9, 0.999 (eps only lowers it).
fn adam_bound(lr: f32, iters: usize) -> f32 {
    let (b1, b2) = (0.9f64, 0.999f64);
    let step = |t: i32| {
        let s: f64 = (0..t).map(|k| (b1 * b1 / b2).powi(k)).sum();
        (1.0 - b1) / (1.0 - b1.powi(t)) * ((1.0 - b2.powi(t)) / (1.0 - b2)).sqrt() * s.sqrt()
    };
    let total: f64 = (1..=iters as i32).map(step).sum();
    (lr as f64 * total * (1.0 + 1e-6)) as f32
}

/// Guidance 0: no change asked, so the colours do not move at all (bit for bit); guidance
/// 1e6: the targets stay in the displayable range, the colours finite and within
/// Adam's step bound.
#[test]
fn guidance_zero_and_huge() {
    let scene = sample_scene();
    let (cams, src) = setup(&scene, false);
    let g = |beta: f32| {
        let csd = CsdParams {
            guidance: beta,
            ..Default::default()
        };
        run(
            &scene,
            &cams,
            &src,
            &mut ColourPrior::new(None),
            params(csd, 0.05),
            3,
        )
    };
    let s0 = g(0.0).unwrap();
    assert_eq!(bits(&s0), bits(&scene), "guidance 0 moved the colours");
    let s1 = g(1e6).unwrap();
    let m = moved(&scene, &s1);
    assert!(finite(&s1));
    assert!(m > 0.5 * 0.05 && m <= adam_bound(0.05, 3), "moved {m}");
}

/// The CSD step size (`--lr`) 0: no change; 1e3: finite, within Adam's bound.
#[test]
fn csd_step_size_zero_and_huge() {
    let scene = sample_scene();
    let (cams, src) = setup(&scene, false);
    let l = |lr: f32| {
        let csd = CsdParams {
            lr,
            ..Default::default()
        };
        run(
            &scene,
            &cams,
            &src,
            &mut ColourPrior::new(None),
            params(csd, 0.05),
            3,
        )
    };
    assert_eq!(
        bits(&l(0.0).unwrap()),
        bits(&scene),
        "--lr 0 moved the colours"
    );
    let s = l(1e3).unwrap();
    let m = moved(&scene, &s);
    assert!(
        finite(&s) && m > 0.025 && m <= adam_bound(0.05, 3),
        "moved {m}"
    );
}

/// The colour step size (`--lr-dc`) 0: no change; 1e3: the colours jump by about 1e3
/// per step but stay finite (a rendered colour is clamped), and the loop goes on.
#[test]
fn colour_step_size_zero_and_huge() {
    let scene = sample_scene();
    let (cams, src) = setup(&scene, false);
    let l = |lr_dc: f32| {
        run(
            &scene,
            &cams,
            &src,
            &mut ColourPrior::new(None),
            params(CsdParams::default(), lr_dc),
            3,
        )
    };
    assert_eq!(
        bits(&l(0.0).unwrap()),
        bits(&scene),
        "--lr-dc 0 moved the colours"
    );
    // A huge step reaches the base colour's range and stops there: the colour step is
    // projected into [0, 1] (scene::colour), so no step size leaves it.
    let s = l(1e3).unwrap();
    let m = moved(&scene, &s);
    assert!(
        finite(&s) && m > 1.0 && m <= adam_bound(1e3, 3),
        "moved {m}"
    );
    assert_eq!(outside_base(&s), 0, "a base colour left [0, 1]");
}

/// The largest step sizes: the base colours cannot overflow (every step is projected
/// into their range) and Adam's normalised step keeps the bands fitted beside them
/// finite (`sh = "fit"`): the run ends with finite colours, base colours in [0, 1].
#[test]
fn the_largest_colour_steps_stay_finite_and_in_range() {
    let scene = sample_scene();
    let (cams, src) = setup(&scene, false);
    for sh in [Bands::Drop, Bands::Fit] {
        let s = run(
            &scene,
            &cams,
            &src,
            &mut ColourPrior::new(None),
            Config {
                sh,
                ..params(CsdParams::default(), 3e38)
            },
            12,
        )
        .unwrap();
        assert!(
            finite(&s) && s.sh_rest.iter().all(|v| v.is_finite()),
            "{sh:?}"
        );
        assert_eq!(outside_base(&s), 0, "{sh:?}");
    }
}

#[test]
fn views_without_the_object() {
    let scene = sample_scene();
    let (cams, src) = setup_away(&scene, &[1, 2]);
    for v in [1, 2] {
        assert!(
            src.alpha[v].iter().all(|a| *a == 0.0),
            "view {v} sees the object"
        );
    }
    let s = run(
        &scene,
        &cams,
        &src,
        &mut ColourPrior::new(None),
        params(CsdParams::default(), 0.05),
        6,
    )
    .unwrap();
    assert!(finite(&s));
    let m = moved(&scene, &s);
    assert!(m > 0.025 && m <= adam_bound(0.05, 6), "moved {m}");
    let (cams, src) = setup(&scene, true);
    let e = run(
        &scene,
        &cams,
        &src,
        &mut ColourPrior::new(None),
        params(CsdParams::default(), 0.05),
        1,
    )
    .unwrap_err();
    assert!(e.contains("no Gaussian") && e.contains("visible"), "{e}");
}

/// Gaussians of zero scale (log-scale -200: exp underflows to 0) and of opacity 0 and 1
/// (logits -100, +100): the loop runs and the colours stay finite; the zero-opacity
/// Gaussians, invisible, keep their colours.
#[test]
fn degenerate_gaussians() {
    let mut scene = sample_scene();
    let n = scene.len();
    for i in 0..n {
        match i % 4 {
            0 => scene.log_scales[i] = [-200.0; 3],
            1 => scene.opacity_logits[i] = -100.0,
            2 => scene.opacity_logits[i] = 100.0,
            _ => {}
        }
    }
    let (cams, src) = setup(&scene, false);
    let s = run(
        &scene,
        &cams,
        &src,
        &mut ColourPrior::new(None),
        params(CsdParams::default(), 0.05),
        3,
    )
    .unwrap();
    assert!(finite(&s));
    assert!(moved(&scene, &s) > 0.025, "nothing moved");
    for i in (1..n).step_by(4) {
        assert_eq!(s.sh_dc[i], scene.sh_dc[i], "invisible Gaussian {i} changed");
    }
}

/// A prior that returns NaN: an error naming the iteration (0 when it does so from the
/// start, 2 when it starts at its third call), and the colours before it stay finite.
#[test]
fn a_prior_returning_nan_is_an_error_naming_the_iteration() {
    let scene = sample_scene();
    let (cams, src) = setup(&scene, false);
    for (from, it) in [(0, 0), (2, 2)] {
        let e = run(
            &scene,
            &cams,
            &src,
            // One predict_eps call per branch with a non-oracle conditioning: 2 per
            // iteration; NaN from call `from * 2` on, i.e. from iteration `from`.
            &mut ColourPrior::new(Some(from * 2)),
            params(CsdParams::default(), 0.05),
            4,
        )
        .unwrap_err();
        assert!(
            e.contains(&format!("distill iteration {it}:")) && e.contains("not finite"),
            "{e}"
        );
    }
}

/// Through the `distill` binary with the installed default prior, at the largest step
/// size with the bands fitted, from a scene whose bands are near f32's largest value
/// (finite, so read): the base colours cannot overflow (every step is projected into
/// [0, 1]), the renderer clamps the huge colours, so the run ends with a finite
/// checkpoint in range. (Before the projection this overflowed; the checkpoint guard
/// that refuses a non-finite state is `distill::guard`'s unit test.)
#[test]
fn distill_at_the_largest_step_writes_a_finite_checkpoint_in_range() {
    let Some(model) = harness::model("stylizer") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("huge.ply");
    let mut s =
        fantasystyle::scene::read_scene_file(&repo_root().join("data-sample/scene.ply")).unwrap();
    s.sh_rest.iter_mut().for_each(|v| *v = 3e38);
    std::fs::write(&scene, fantasystyle::scene::ply::encode_ply(&s)).unwrap();
    let views = d.path().join("views");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_render-views"))
        .arg("--scene")
        .arg(repo_root().join("data-sample/scene.ply"))
        .args([
            "--cameras",
            "orbit:2",
            "--width",
            "32",
            "--height",
            "32",
            "--out",
        ])
        .arg(&views)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = d.path().join("ckpt");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_distill"))
        .arg("--scene")
        .arg(&scene)
        .arg("--source-views")
        .arg(&views)
        .arg("--model")
        .arg(&model)
        .arg("--style")
        .arg(repo_root().join("data-sample/style.png"))
        .args(["--iters", "6", "--set", "views=2", "--set", "sh=fit"])
        .args(["--set", "lr_dc=3e38", "--threads", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success() && !err.contains("panicked"), "{err}");
    let r = fantasystyle::artifacts::load_scene(&out).unwrap();
    assert!(
        r.sh_dc
            .iter()
            .flatten()
            .chain(&r.sh_rest)
            .all(|v| v.is_finite())
    );
    assert_eq!(outside_base(&r), 0);
}

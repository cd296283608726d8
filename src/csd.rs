//! Controllable stylized distillation (CSD, FantasyStyle Sec. 4, the method) and the score
//! distillation variants the paper compares it with.
//!
//! Inputs: the clean target latents z0 (current renders), the noised target latents
//! z_tgt (MVFC-filtered), the noised source latents z_src (original renders) and the
//! shared noise eps, all `[N, C, h, w]`, at training timestep t with ab = `alphas_cumprod[t]`.
//! e(z, c) is the prior's noise prediction under conditioning c ([`Cond`]); beta is the
//! guidance scale (paper: 7.5).
//!
//! | mode | gradient g (before w(t)) |
//! |---|---|
//! | `csd` (paper eq.) | beta (e(z_tgt, PS) - e(z_tgt, Content)) - beta (e(z_src, P) - e(z_src, Null)) |
//! | `csd-no-neg` | beta (e(z_tgt, PS) - e(z_tgt, Null)) - beta (e(z_src, P) - e(z_src, Null)) |
//! | `sds` (DreamFusion, Poole et al. 2022) | e_cfg(z_tgt) - eps, e_cfg = e(z_tgt, Null) + beta (e(z_tgt, PS) - e(z_tgt, Null)) |
//! | `dds` (Delta Denoising Score, Hertz et al. 2023) | e_cfg(z_tgt; PS) - e_cfg(z_src; P), both guided against Null |
//!
//! (PS = prompt + style tokens, P = prompt, Content = the style image's content tokens.)
//! In `sds`, eps is the noise `mvfc-filter` drew (eps.npy); after MVFC the low frequencies
//! of z_tgt no longer match it exactly, so SDS also sees the filter's change as signal,
//! whereas CSD and DDS only difference predictions and are unaffected by that mismatch.
//! So `csd` - `csd-no-neg` = beta (e(z_tgt, Null) - e(z_tgt, Content)) (the negative
//! content guidance), and `dds` - `csd-no-neg` = e(z_tgt, Null) - e(z_src, Null) (DDS keeps
//! the unconditional predictions that CSD's Phi terms cancel). "Without MVFC" is the
//! configuration's `mvfc.enabled = false` (`distill`, `mvfc-filter`).
//!
//! Weighting w(t) ([`Weighting`]): `1-ab` (DreamFusion's choice, default), `uniform` (1),
//! `sqrt-ab-1-ab` = sqrt(ab) (1 - ab).
//!
//! **Step-size convention.** Like SDS, the gradient is applied to the clean latents
//! directly (the Jacobian of the denoiser is skipped): z0' = z0 - lr * w(t) * g. For an
//! x0-predicting prior, e(z, c1) - e(z, c2) = sqrt(ab/(1-ab)) (x0_c2 - x0_c1), so one step
//! moves z0 by lr * w(t) * beta * sqrt(ab/(1-ab)) times the difference of the guided clean
//! images: with w = 1-ab that factor is lr * beta * sqrt(ab (1-ab)) <= lr * beta / 2.
//!
//! All predictions for one latent batch are one [`Prior::predict_eps`] call (target: two
//! conditionings; source: two), so classifier-free guidance is batched.

use crate::prior::{Cond, Prior, PriorInfo};
use crate::scheduler::Schedule;
use crate::{Error, Result};
use ndarray::{Array4, ArrayView4, Axis, Zip, concatenate, s};
use serde::{Deserialize, Serialize};

/// Which distillation gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Mode {
    /// CSD (the paper's method).
    #[default]
    Csd,
    /// Score distillation sampling: CFG-ed target prediction minus the added noise.
    Sds,
    /// Delta denoising score: CFG-ed target minus CFG-ed source prediction.
    Dds,
    /// CSD without negative (content) guidance: Null instead of Content in the target.
    CsdNoNeg,
}

/// The timestep weighting w(t).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Weighting {
    /// w = 1 - ab.
    #[value(name = "1-ab")]
    OneMinusAlphaBar,
    /// w = 1.
    Uniform,
    /// w = sqrt(ab) (1 - ab).
    #[value(name = "sqrt-ab-1-ab")]
    SqrtAlphaBarOneMinus,
}

crate::params::serde_by_value_name!(Mode, Weighting);

impl Weighting {
    pub fn weight(self, ab: f64) -> f64 {
        match self {
            Weighting::OneMinusAlphaBar => 1.0 - ab,
            Weighting::Uniform => 1.0,
            Weighting::SqrtAlphaBarOneMinus => ab.sqrt() * (1.0 - ab),
        }
    }
}

/// Parameters of one distillation step: the `[csd]` section of the method's
/// configuration ([`crate::config`]; the field docs are its help). The mode is
/// not a key of the section: it is the prior's term of the configuration's `terms`
/// (`csd`, `sds`, `dds` or `csd-no-neg`), set when the configuration is checked.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, clap::Args)]
#[serde(deny_unknown_fields, default)]
pub struct CsdParams {
    /// Distillation gradient (from the configuration's `terms`).
    #[arg(skip)]
    #[serde(skip)]
    pub mode: Mode,
    /// Classifier-free guidance scale beta (paper: 7.5). At 0, csd and csd-no-neg ask
    /// nothing of the prior and `distill` skips its calls (the other terms alone, in a
    /// fraction of the time).
    #[arg(long, default_value_t = 7.5)]
    pub guidance: f32,
    /// Timestep weighting w(t): 1-ab, uniform, or sqrt-ab-1-ab (= sqrt(ab)(1-ab)).
    #[arg(long, value_enum, default_value = "1-ab")]
    pub weighting: Weighting,
    /// Step size on the clean latents: z0' = z0 - lr * w(t) * grad.
    #[arg(long, default_value_t = 0.1)]
    pub lr: f32,
}

impl Default for CsdParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl CsdParams {
    /// How many conditionings (UNet rows per latent) a step of this mode evaluates.
    pub fn conds(&self) -> usize {
        let (t, s) = conds(self.mode);
        t.len() + s.len()
    }

    /// Whether a step's gradient is exactly zero whatever the prior predicts: `csd` and
    /// `csd-no-neg` at guidance 0, where both Phi terms are scaled by beta (`sds` and
    /// `dds` keep an unguided term). `distill` then skips the prior's calls: the texture
    /// term alone, the same bits ([`crate::distill`]).
    pub fn asks_nothing(&self) -> bool {
        matches!(self.mode, Mode::Csd | Mode::CsdNoNeg) && self.guidance == 0.0
    }

    /// Refuse a non-finite guidance scale and a negative or non-finite step size.
    pub fn validate(&self) -> Result<()> {
        if !(self.guidance.is_finite() && self.lr.is_finite() && self.lr >= 0.0) {
            return Err(Error::param(format!(
                "csd.guidance ({}) must be finite and csd.lr ({}) finite and >= 0",
                self.guidance, self.lr
            )));
        }
        Ok(())
    }
}

/// The latents one step works on (all `[N, C, h, w]`).
#[derive(Debug, Clone, Copy)]
pub struct StepInputs<'a> {
    pub z0: ArrayView4<'a, f32>,
    pub z_tgt: ArrayView4<'a, f32>,
    pub z_src: ArrayView4<'a, f32>,
    pub eps: ArrayView4<'a, f32>,
    /// The source's clean latents, when `z_src` is not simply `add_noise(z0_src, eps)`
    /// (MVFC on the source branch): an identity prior's exact source noise is then
    /// `(z_src - sqrt(ab) z0_src) / sqrt(1 - ab)`; without it, `eps`.
    pub z0_src: Option<ArrayView4<'a, f32>>,
    pub t: usize,
    /// Control image for priors with a ControlNet (`[N, 3, H, W]`).
    pub control: Option<ArrayView4<'a, f32>>,
}

/// The conditionings each branch needs: (target, source).
pub fn conds(mode: Mode) -> (Vec<Cond>, Vec<Cond>) {
    match mode {
        Mode::Csd => (
            vec![Cond::PromptStyle, Cond::Content],
            vec![Cond::Prompt, Cond::Null],
        ),
        Mode::CsdNoNeg | Mode::Dds => (
            vec![Cond::PromptStyle, Cond::Null],
            vec![Cond::Prompt, Cond::Null],
        ),
        Mode::Sds => (vec![Cond::PromptStyle, Cond::Null], vec![]),
    }
}

/// Refuse `csd` on a prior whose style and content conditionings coincide
/// ([`crate::prior::PriorInfo::coinciding_style_content`]): there the negative branch
/// eps(z_tgt, Content) equals the style image's own contribution to eps(z_tgt, PS), so
/// the target term keeps only text guidance and the "stylization" silently drops the
/// style image.
pub fn check_mode(mode: Mode, info: &PriorInfo) -> Result<()> {
    if let (Mode::Csd, Some(why)) = (mode, &info.coinciding_style_content) {
        return Err(Error::param(format!(
            "the term csd needs distinct style and content conditionings, and model `{}` has \
             none: {why}. Its negative branch eps(content) would cancel the style image. \
             Use the term csd-no-neg or sds with this model (--terms csd-no-neg=1), or \
             re-export it with scripts/export_models.py --ip-adapter (InstantStyle \
             routing, the default)",
            info.name
        )));
    }
    Ok(())
}

/// The weighted gradient w(t) g (module docs), `[N, C, h, w]`.
pub fn gradient(
    prior: &mut dyn Prior,
    schedule: &Schedule,
    x: StepInputs<'_>,
    p: &CsdParams,
) -> Result<Array4<f32>> {
    check_mode(p.mode, prior.info())?;
    let shape = x.z0.shape();
    for (name, a) in [("z_tgt", x.z_tgt), ("z_src", x.z_src), ("eps", x.eps)] {
        if a.shape() != shape {
            return Err(Error::param(format!(
                "CSD: {name} has shape {:?}, z0 has {:?}",
                a.shape(),
                shape
            )));
        }
    }
    if !p.guidance.is_finite() || !p.lr.is_finite() {
        return Err(Error::param("CSD: guidance and lr must be finite"));
    }
    let ab = schedule.alpha_bar(x.t)?;
    let w = p.weighting.weight(ab) as f32;
    let beta = p.guidance;
    let (ct, cs) = conds(p.mode);
    let (et, es) = if prior.unconditional_is_identity() {
        oracle_predictions(prior, schedule, &x, &ct, &cs)?
    } else {
        let et = crate::timing::phase("target branch", || {
            prior.predict_eps(x.z_tgt, x.t, &ct, x.control)
        })?;
        let es = if cs.is_empty() {
            Vec::new()
        } else {
            crate::timing::phase("source branch", || {
                prior.predict_eps(x.z_src, x.t, &cs, x.control)
            })?
        };
        (et, es)
    };
    for e in et.iter().chain(&es) {
        if e.shape() != shape {
            return Err(Error::Other(format!(
                "prior returned eps of shape {:?} for latents {:?}",
                e.shape(),
                shape
            )));
        }
    }
    let g = match p.mode {
        // beta (t0 - t1) - beta (s0 - s1)
        Mode::Csd | Mode::CsdNoNeg => Zip::from(&et[0])
            .and(&et[1])
            .and(&es[0])
            .and(&es[1])
            .map_collect(|&t0, &t1, &s0, &s1| w * (beta * (t0 - t1) - beta * (s0 - s1))),
        // (t1 + beta (t0 - t1)) - eps
        Mode::Sds => Zip::from(&et[0])
            .and(&et[1])
            .and(x.eps)
            .map_collect(|&t0, &t1, &e| w * (t1 + beta * (t0 - t1) - e)),
        // (t1 + beta (t0 - t1)) - (s1 + beta (s0 - s1))
        Mode::Dds => Zip::from(&et[0])
            .and(&et[1])
            .and(&es[0])
            .and(&es[1])
            .map_collect(|&t0, &t1, &s0, &s1| {
                w * ((t1 + beta * (t0 - t1)) - (s1 + beta * (s0 - s1)))
            }),
    };
    if g.iter().any(|v| !v.is_finite()) {
        return Err(Error::Other(format!(
            "CSD gradient is not finite at t = {} (prior output NaN/inf)",
            x.t
        )));
    }
    Ok(g)
}

/// Per-conditioning predictions of the target and the source branch.
type BranchPredictions = (Vec<Array4<f32>>, Vec<Array4<f32>>);

/// Predictions for a prior whose unconditional branch is the identity
/// ([`Prior::unconditional_is_identity`]): `Null` and `Content` are not asked of the
/// prior but given exactly, as the noise that takes the clean latents to the noisy ones
/// (target: `(z_tgt - sqrt(ab) z0) / sqrt(1 - ab)`, which includes MVFC's change of
/// z_tgt; source: `(z_src - sqrt(ab) z0_src) / sqrt(1 - ab)` when z0_src is given, else
/// `eps`, with which `z_src` was made). The other conditionings go to
/// the prior in one call per branch.
fn oracle_predictions(
    prior: &mut dyn Prior,
    schedule: &Schedule,
    x: &StepInputs<'_>,
    ct: &[Cond],
    cs: &[Cond],
) -> Result<BranchPredictions> {
    let (sa, sb) = schedule.coefficients(x.t)?;
    let (sa, sb) = (sa as f32, sb as f32);
    let content = prior.content_is_identity();
    let oracle = |c: Cond| c == Cond::Null || (content && c == Cond::Content);
    let branch = |prior: &mut dyn Prior,
                  z: ArrayView4<'_, f32>,
                  conds: &[Cond],
                  exact: &dyn Fn() -> Array4<f32>|
     -> Result<Vec<Array4<f32>>> {
        let ask: Vec<Cond> = conds.iter().copied().filter(|c| !oracle(*c)).collect();
        let mut got = if ask.is_empty() {
            Vec::new()
        } else {
            prior.predict_eps(z, x.t, &ask, x.control)?
        }
        .into_iter();
        conds
            .iter()
            .map(|c| {
                if oracle(*c) {
                    Ok(exact())
                } else {
                    got.next()
                        .ok_or_else(|| Error::Other("prior returned too few predictions".into()))
                }
            })
            .collect()
    };
    let ph = crate::timing::span("target branch");
    let exact_tgt = || {
        Zip::from(x.z_tgt)
            .and(x.z0)
            .map_collect(|&z, &z0| (z - sa * z0) / sb)
    };
    let mut et = branch(prior, x.z_tgt, ct, &exact_tgt)?;
    if let Some(k) = ct.iter().position(|c| *c == Cond::Content)
        && let Some((x0, r)) = prior.content_layout(x.z_tgt, x.t, x.control)?
    {
        // The mixture of the exact model and the style's layout model.
        let exact = exact_tgt();
        let r = r
            .broadcast(exact.dim())
            .map(|v| v.to_owned())
            .ok_or_else(|| {
                Error::Other(format!("content responsibility of shape {:?}", r.shape()))
            })?;
        et[k] = Zip::from(&exact)
            .and(&r)
            .and(x.z_tgt)
            .and(&x0)
            .map_collect(|&e, &r, &z, &x0| (1.0 - r) * e + r * (z - sa * x0) / sb);
    }
    drop(ph);
    let ph = crate::timing::span("source branch");
    let es = branch(prior, x.z_src, cs, &|| match x.z0_src {
        Some(z0s) => Zip::from(x.z_src)
            .and(z0s)
            .map_collect(|&z, &z0| (z - sa * z0) / sb),
        None => x.eps.to_owned(),
    })?;
    drop(ph);
    Ok((et, es))
}

/// One step: z0' = z0 - lr * w(t) g. Returns (z0', w g).
pub fn step(
    prior: &mut dyn Prior,
    schedule: &Schedule,
    x: StepInputs<'_>,
    p: &CsdParams,
) -> Result<(Array4<f32>, Array4<f32>)> {
    let g = gradient(prior, schedule, x, p)?;
    let lr = p.lr;
    let z = Zip::from(x.z0).and(&g).map_collect(|&z, &g| z - lr * g);
    Ok((z, g))
}

/// The image change a CSD step asks for, `decode(z1) - decode(z0)` `[N, 3, H, W]` (both
/// decoded in one call), for views of `h` x `w`.
pub fn image_change(
    prior: &mut dyn Prior,
    z1: ArrayView4<'_, f32>,
    z0: ArrayView4<'_, f32>,
    h: usize,
    w: usize,
) -> Result<Array4<f32>> {
    let n = z0.shape()[0];
    let both = concatenate(Axis(0), &[z1, z0]).map_err(|e| Error::Other(e.to_string()))?;
    let dec = prior.decode(both.view())?;
    if dec.shape() != [2 * n, 3, h, w] {
        return Err(Error::Other(format!(
            "decoder returned {:?}, expected [{}, 3, {h}, {w}]",
            dec.shape(),
            2 * n
        )));
    }
    Ok(&dec.slice(s![..n, .., .., ..]) - &dec.slice(s![n.., .., .., ..]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::prior::gaussian::GaussianPrior;
    use crate::rng::Rng;

    fn randn(seed: u64, s: [usize; 4]) -> Array4<f32> {
        Array4::from_shape_vec(s, Rng::new(seed).normals_f32(s.iter().product())).unwrap()
    }

    fn prior() -> GaussianPrior {
        // A colourful synthetic style image: per-channel ramps.
        let style = Array4::from_shape_fn((1, 3, 32, 32), |(_, c, y, x)| {
            ((c + 1) as f32 * 0.2 + 0.02 * y as f32 - 0.01 * x as f32).clamp(0.0, 1.0)
        });
        GaussianPrior::with_default_text(Some(style.view())).unwrap()
    }

    /// e(z, c) by the closed form, in f64, from the conditioning's N(mu, var).
    fn closed(p: &GaussianPrior, z: &Array4<f32>, ab: f64, c: Cond) -> ndarray::Array4<f64> {
        let st = p.cond_stats(c).unwrap();
        ndarray::Array4::from_shape_fn(z.raw_dim(), |(b, ch, y, x)| {
            let (mu, var) = (st.mean[ch] as f64, st.var[ch] as f64);
            (1.0 - ab).sqrt() * (z[[b, ch, y, x]] as f64 - ab.sqrt() * mu) / (ab * var + 1.0 - ab)
        })
    }

    struct Case {
        z0: Array4<f32>,
        zt: Array4<f32>,
        zs: Array4<f32>,
        eps: Array4<f32>,
    }

    fn case() -> Case {
        let s = [2, 4, 6, 5];
        Case {
            z0: randn(1, s),
            zt: randn(2, s),
            zs: randn(3, s),
            eps: randn(4, s),
        }
    }

    fn inputs(c: &Case, t: usize) -> StepInputs<'_> {
        StepInputs {
            z0: c.z0.view(),
            z_tgt: c.zt.view(),
            z_src: c.zs.view(),
            eps: c.eps.view(),
            z0_src: None,
            t,
            control: None,
        }
    }

    fn max_err(a: &Array4<f32>, b: &ndarray::Array4<f64>) -> f64 {
        a.iter()
            .zip(b.iter())
            .map(|(x, y)| (*x as f64 - y).abs())
            .fold(0.0, f64::max)
    }

    /// One CSD step equals the closed-form gradient: |error| < 1e-5 (f32 arithmetic on
    /// O(10) values), for every weighting and across t.
    #[test]
    fn csd_step_equals_closed_form() {
        let mut p = prior();
        let sched = p.schedule().clone();
        let c = case();
        for t in [20usize, 500, 980] {
            for weighting in [
                Weighting::OneMinusAlphaBar,
                Weighting::Uniform,
                Weighting::SqrtAlphaBarOneMinus,
            ] {
                let par = CsdParams {
                    weighting,
                    lr: 0.3,
                    ..Default::default()
                };
                let (z1, g) = step(&mut p, &sched, inputs(&c, t), &par).unwrap();
                let ab = sched.alpha_bar(t).unwrap();
                let w = weighting.weight(ab);
                let b = par.guidance as f64;
                let (tps, tco) = (
                    closed(&p, &c.zt, ab, Cond::PromptStyle),
                    closed(&p, &c.zt, ab, Cond::Content),
                );
                let (sp, sn) = (
                    closed(&p, &c.zs, ab, Cond::Prompt),
                    closed(&p, &c.zs, ab, Cond::Null),
                );
                let want = (&tps - &tco - &sp + &sn) * (w * b);
                let e = max_err(&g, &want);
                assert!(e < 1e-5, "t {t} {weighting:?}: gradient error {e}");
                let z_want = c.z0.mapv(|v| v as f64) - &want * 0.3;
                let e = max_err(&z1, &z_want);
                assert!(e < 1e-5, "t {t}: step error {e}");
                assert!(want.iter().any(|v| v.abs() > 1e-3), "trivial gradient");
            }
        }
    }

    /// Each mode's difference from `csd` is what the module-doc formulas say.
    #[test]
    fn mode_differences_match_formulas() {
        let mut p = prior();
        let sched = p.schedule().clone();
        let c = case();
        let t = 400;
        let ab = sched.alpha_bar(t).unwrap();
        let w = 1.0 - ab;
        let b = 7.5;
        let g = |p: &mut GaussianPrior, mode| {
            let par = CsdParams {
                mode,
                ..Default::default()
            };
            gradient(p, &sched, inputs(&c, t), &par).unwrap()
        };
        let csd = g(&mut p, Mode::Csd);
        let noneg = g(&mut p, Mode::CsdNoNeg);
        let dds = g(&mut p, Mode::Dds);
        let sds = g(&mut p, Mode::Sds);
        let tn = closed(&p, &c.zt, ab, Cond::Null);
        let tc = closed(&p, &c.zt, ab, Cond::Content);
        let tps = closed(&p, &c.zt, ab, Cond::PromptStyle);
        let sn = closed(&p, &c.zs, ab, Cond::Null);
        let f64a = |a: &Array4<f32>| a.mapv(|v| v as f64);
        // csd - csd-no-neg = w beta (e_t(Null) - e_t(Content))
        let d = f64a(&csd) - f64a(&noneg);
        let want = (&tn - &tc) * (w * b);
        assert!(max_err(&d.mapv(|v| v as f32), &want) < 1e-5);
        assert!(want.iter().any(|v| v.abs() > 1e-3));
        // dds - csd-no-neg = w (e_t(Null) - e_s(Null))
        let d = f64a(&dds) - f64a(&noneg);
        let want = (&tn - &sn) * w;
        assert!(max_err(&d.mapv(|v| v as f32), &want) < 1e-5);
        // sds = w (e_t(Null) + beta (e_t(PS) - e_t(Null)) - eps)
        let want = (&tn + &((&tps - &tn) * b) - &f64a(&c.eps)) * w;
        assert!(max_err(&sds, &want) < 1e-5);
    }

    #[test]
    fn bad_inputs_are_clear_errors() {
        let mut p = prior();
        let sched = p.schedule().clone();
        let c = case();
        let other = randn(9, [2, 4, 6, 6]);
        let mut x = inputs(&c, 100);
        x.z_src = other.view();
        let e = gradient(&mut p, &sched, x, &CsdParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("z_src") && e.contains("shape"), "{e}");
        let e = gradient(&mut p, &sched, inputs(&c, 5000), &CsdParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("5000"), "{e}");
    }
}

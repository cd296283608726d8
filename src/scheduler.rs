//! DDIM noise schedule (Song et al. 2021) as the diffusers library configures it.
//!
//! * `alphas_cumprod` (written ab_t) from the model's beta schedule:
//!   ab_t = prod_{s<=t} (1 - beta_s), betas linear or linear in sqrt (Stable Diffusion's
//!   "scaled_linear"); computed in f64.
//! * Forward noising (DDPM eq. 4): z_t = sqrt(ab_t) z0 + sqrt(1 - ab_t) eps ([`Schedule::add_noise`]).
//! * Conversions between the three parameterisations of a network output
//!   (Salimans & Ho 2022 for v): x0 = (z_t - sqrt(1-ab) eps) / sqrt(ab),
//!   eps = (z_t - sqrt(ab) x0) / sqrt(1-ab), v = sqrt(ab) eps - sqrt(1-ab) x0,
//!   eps = sqrt(1-ab) z_t + sqrt(ab) v, x0 = sqrt(ab) z_t - sqrt(1-ab) v.
//! * The fixed discrete timestep set the method samples t from (FantasyStyle Sec. 4:
//!   "t drawn from a fixed discrete DDIM set"): [`TimestepSet`].
//!
//! Numerical stability: coefficients are computed in f64 and applied per element in f64;
//! [`SchedulerConfig::validate`] refuses schedules whose ab_{T-1} underflows (< 1e-10)
//! or whose betas leave (0, 1), so that every division above is by a number >= 1e-5 and
//! results are finite at t = 0, 1 and T-1 (see the tests).

use crate::rng::Rng;
use crate::{Error, Result};
use ndarray::{Array, ArrayView, Dimension, Zip};
use serde::{Deserialize, Serialize};

/// How betas are spaced between `beta_start` and `beta_end`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BetaSchedule {
    Linear,
    /// Linear in sqrt(beta) (Stable Diffusion's "scaled_linear").
    ScaledLinear,
}

/// What the network predicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PredictionType {
    Epsilon,
    VPrediction,
}

/// A model's training noise schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SchedulerConfig {
    pub num_train_timesteps: usize,
    pub beta_start: f64,
    pub beta_end: f64,
    pub beta_schedule: BetaSchedule,
    pub prediction_type: PredictionType,
}

/// Most training timesteps a schedule may have (diffusion models use 1000).
pub const MAX_TRAIN_TIMESTEPS: usize = 100_000;

impl SchedulerConfig {
    /// Stable Diffusion 1.x / 2.x / XL: 1000 steps, scaled-linear 0.00085..0.012.
    pub fn stable_diffusion() -> Self {
        SchedulerConfig {
            num_train_timesteps: 1000,
            beta_start: 0.00085,
            beta_end: 0.012,
            beta_schedule: BetaSchedule::ScaledLinear,
            prediction_type: PredictionType::Epsilon,
        }
    }

    /// `alphas_cumprod[t]` for t in 0..num_train_timesteps, in f64.
    pub fn alphas_cumprod(&self) -> Vec<f64> {
        let n = self.num_train_timesteps;
        let mut ab = Vec::with_capacity(n);
        let mut acc = 1.0f64;
        for i in 0..n {
            let f = if n > 1 {
                i as f64 / (n - 1) as f64
            } else {
                0.0
            };
            let beta = match self.beta_schedule {
                BetaSchedule::Linear => self.beta_start + f * (self.beta_end - self.beta_start),
                BetaSchedule::ScaledLinear => {
                    let s = self.beta_start.sqrt()
                        + f * (self.beta_end.sqrt() - self.beta_start.sqrt());
                    s * s
                }
            };
            acc *= 1.0 - beta;
            ab.push(acc);
        }
        ab
    }

    /// Check that the schedule is usable: at least 2 steps, 0 < beta < 1, and
    /// ab_{T-1} >= 1e-10 (so that x0 can be recovered from z_t at every t).
    pub fn validate(&self) -> Result<()> {
        if self.num_train_timesteps < 2 {
            return Err(Error::param(format!(
                "scheduler: num_train_timesteps is {}, need at least 2",
                self.num_train_timesteps
            )));
        }
        // Before the table is built: a manifest claiming 4e9 steps must not allocate
        // 32 GB (found by fuzzing model.json; real models train with 1000).
        if self.num_train_timesteps > MAX_TRAIN_TIMESTEPS {
            return Err(Error::param(format!(
                "scheduler: num_train_timesteps is {}, at most {MAX_TRAIN_TIMESTEPS}",
                self.num_train_timesteps
            )));
        }
        for (name, b) in [("beta_start", self.beta_start), ("beta_end", self.beta_end)] {
            if !(b > 0.0 && b < 1.0) {
                return Err(Error::param(format!(
                    "scheduler: {name} is {b}, must lie in (0, 1)"
                )));
            }
        }
        let last = *self.alphas_cumprod().last().expect("n >= 2");
        if last < 1e-10 {
            return Err(Error::param(format!(
                "scheduler: alphas_cumprod at t = T-1 is {last:e} (< 1e-10): x0 cannot be \
                 recovered stably; lower beta_end or the number of timesteps"
            )));
        }
        Ok(())
    }
}

/// A validated schedule with its `alphas_cumprod` table: noising and conversions.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    pub config: SchedulerConfig,
    ab: Vec<f64>,
}

impl Schedule {
    pub fn new(config: SchedulerConfig) -> Result<Self> {
        config.validate()?;
        let ab = config.alphas_cumprod();
        Ok(Schedule { config, ab })
    }

    /// Number of training timesteps T (valid t are 0..T).
    pub fn num_train_timesteps(&self) -> usize {
        self.ab.len()
    }

    /// The whole ab table.
    pub fn alphas_cumprod(&self) -> &[f64] {
        &self.ab
    }

    /// ab_t, or an error naming the valid range.
    pub fn alpha_bar(&self, t: usize) -> Result<f64> {
        self.ab.get(t).copied().ok_or_else(|| {
            Error::param(format!(
                "timestep {t} is outside the schedule's range 0..{}",
                self.ab.len()
            ))
        })
    }

    /// (sqrt(ab_t), sqrt(1 - ab_t)).
    pub fn coefficients(&self, t: usize) -> Result<(f64, f64)> {
        let ab = self.alpha_bar(t)?;
        Ok((ab.sqrt(), (1.0 - ab).sqrt()))
    }

    /// z_t = sqrt(ab) z0 + sqrt(1-ab) eps.
    pub fn add_noise<D: Dimension>(
        &self,
        z0: ArrayView<'_, f32, D>,
        eps: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(z0, eps, a, s, "add_noise: z0 and eps")
    }

    /// x0 = (z_t - sqrt(1-ab) eps) / sqrt(ab).
    pub fn x0_from_eps<D: Dimension>(
        &self,
        z_t: ArrayView<'_, f32, D>,
        eps: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(z_t, eps, 1.0 / a, -s / a, "x0_from_eps: z_t and eps")
    }

    /// eps = (z_t - sqrt(ab) x0) / sqrt(1-ab).
    pub fn eps_from_x0<D: Dimension>(
        &self,
        z_t: ArrayView<'_, f32, D>,
        x0: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(z_t, x0, 1.0 / s, -a / s, "eps_from_x0: z_t and x0")
    }

    /// v = sqrt(ab) eps - sqrt(1-ab) x0.
    pub fn v_from_x0_eps<D: Dimension>(
        &self,
        x0: ArrayView<'_, f32, D>,
        eps: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(x0, eps, -s, a, "v_from_x0_eps: x0 and eps")
    }

    /// eps = sqrt(1-ab) z_t + sqrt(ab) v.
    pub fn eps_from_v<D: Dimension>(
        &self,
        z_t: ArrayView<'_, f32, D>,
        v: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(z_t, v, s, a, "eps_from_v: z_t and v")
    }

    /// x0 = sqrt(ab) z_t - sqrt(1-ab) v.
    pub fn x0_from_v<D: Dimension>(
        &self,
        z_t: ArrayView<'_, f32, D>,
        v: ArrayView<'_, f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        let (a, s) = self.coefficients(t)?;
        combine(z_t, v, a, -s, "x0_from_v: z_t and v")
    }

    /// Turn a network output of this schedule's prediction type into eps.
    pub fn to_eps<D: Dimension>(
        &self,
        z_t: ArrayView<'_, f32, D>,
        output: Array<f32, D>,
        t: usize,
    ) -> Result<Array<f32, D>> {
        match self.config.prediction_type {
            PredictionType::Epsilon => Ok(output),
            PredictionType::VPrediction => self.eps_from_v(z_t, output.view(), t),
        }
    }
}

/// ca * a + cb * b elementwise, evaluated in f64.
fn combine<D: Dimension>(
    a: ArrayView<'_, f32, D>,
    b: ArrayView<'_, f32, D>,
    ca: f64,
    cb: f64,
    what: &str,
) -> Result<Array<f32, D>> {
    if a.shape() != b.shape() {
        return Err(Error::param(format!(
            "{what} have different shapes {:?} and {:?}",
            a.shape(),
            b.shape()
        )));
    }
    Ok(Zip::from(&a)
        .and(&b)
        .map_collect(|&x, &y| (ca * x as f64 + cb * y as f64) as f32))
}

/// The fixed discrete set of timesteps the method samples from: `count` integers spaced
/// evenly (rounded) from `t_min` to `t_max` inclusive, ascending, no duplicates.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct TimestepSet {
    steps: Vec<usize>,
}

impl TimestepSet {
    /// `count` timesteps from `t_min` to `t_max` (inclusive) of a schedule with
    /// `cfg.num_train_timesteps` steps.
    pub fn new(cfg: &SchedulerConfig, t_min: usize, t_max: usize, count: usize) -> Result<Self> {
        let n = cfg.num_train_timesteps;
        if count == 0 {
            return Err(Error::param("timestep set: count must be at least 1"));
        }
        if t_min > t_max || t_max >= n {
            return Err(Error::param(format!(
                "timestep set: need 0 <= t_min <= t_max < {n}, got t_min {t_min}, t_max {t_max}"
            )));
        }
        if count > t_max - t_min + 1 {
            return Err(Error::param(format!(
                "timestep set: {count} distinct timesteps do not fit in [{t_min}, {t_max}]"
            )));
        }
        let steps = if count == 1 {
            vec![(t_min + t_max) / 2]
        } else {
            (0..count)
                .map(|i| {
                    let f = i as f64 / (count - 1) as f64;
                    (t_min as f64 + f * (t_max - t_min) as f64).round() as usize
                })
                .collect()
        };
        Ok(TimestepSet { steps })
    }

    /// The default set: 50 steps over [0.02 T, 0.98 T] (the usual score-distillation
    /// range, avoiding both ends where the guidance signal vanishes or is pure noise).
    pub fn default_for(cfg: &SchedulerConfig) -> Result<Self> {
        let n = cfg.num_train_timesteps;
        let lo = ((n as f64) * 0.02).round() as usize;
        let hi = (((n as f64) * 0.98).round() as usize).min(n - 1);
        Self::new(cfg, lo, hi, 50.min(hi - lo + 1))
    }

    /// A set given as `MIN:MAX:COUNT` (e.g. `20:300:25`) for a schedule `cfg`.
    pub fn parse(spec: &str, cfg: &SchedulerConfig) -> Result<Self> {
        let nums: Option<Vec<usize>> = spec.split(':').map(|p| p.trim().parse().ok()).collect();
        match nums.as_deref() {
            Some([a, b, c]) => Self::new(cfg, *a, *b, *c),
            _ => Err(Error::param(format!(
                "--timesteps `{spec}`: expected MIN:MAX:COUNT, e.g. 20:300:25"
            ))),
        }
    }

    /// The timesteps, ascending.
    pub fn steps(&self) -> &[usize] {
        &self.steps
    }

    pub fn contains(&self, t: usize) -> bool {
        self.steps.binary_search(&t).is_ok()
    }

    /// Error unless `t` is in the set (names the set's range).
    pub fn check(&self, t: usize) -> Result<()> {
        if self.contains(t) {
            Ok(())
        } else {
            Err(Error::param(format!(
                "timestep {t} is not in the DDIM set ({} steps from {} to {})",
                self.steps.len(),
                self.steps[0],
                self.steps[self.steps.len() - 1]
            )))
        }
    }

    /// Draw one timestep uniformly from the set.
    pub fn sample(&self, rng: &mut Rng) -> usize {
        let i = ((rng.uniform() * self.steps.len() as f64) as usize).min(self.steps.len() - 1);
        self.steps[i]
    }
}

/// How an iteration's timestep is drawn from the model's set.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum TimestepSchedule {
    /// Uniformly from the whole set, every iteration (the paper).
    Random,
    /// Coarse to fine: at iteration i of `total` the draw is uniform over the smallest
    /// timesteps of the set up to t_max(i), which falls linearly from the set's largest
    /// to its smallest (threestudio's annealed maximum step; DreamTime's monotone
    /// schedule in its stochastic form).
    Anneal { total: u64 },
}

impl TimestepSchedule {
    /// The timestep of iteration `it`.
    pub fn draw(&self, set: &TimestepSet, it: u64, rng: &mut Rng) -> usize {
        match *self {
            TimestepSchedule::Random => set.sample(rng),
            TimestepSchedule::Anneal { total } => {
                let steps = set.steps();
                let f = (it as f64 / total.max(1) as f64).min(1.0);
                let top = ((1.0 - f) * (steps.len() - 1) as f64).round() as usize;
                let i = ((rng.uniform() * (top + 1) as f64) as usize).min(top);
                steps[i]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::{Array1, Array4};

    fn sched() -> Schedule {
        Schedule::new(SchedulerConfig::stable_diffusion()).unwrap()
    }

    /// Fuzzing regression: a model.json claiming 4e9 training timesteps made
    /// `validate` build a 32 GB alphas table; now refused before any table is built.
    #[test]
    fn absurd_timestep_counts_are_refused_before_allocating() {
        let cfg = SchedulerConfig {
            num_train_timesteps: 4_000_000_000,
            ..SchedulerConfig::stable_diffusion()
        };
        let e = Schedule::new(cfg).unwrap_err().to_string();
        assert!(e.contains("4000000000") && e.contains("at most"), "{e}");
    }

    fn randn(n: usize, seed: u64) -> Array1<f32> {
        Array1::from(Rng::new(seed).normals_f32(n))
    }

    #[test]
    fn alphas_match_diffusers_reference_values() {
        // Reference: diffusers DDIMScheduler(beta_schedule="scaled_linear",
        // beta_start=0.00085, beta_end=0.012).alphas_cumprod, computed independently in
        // numpy: betas = linspace(sqrt(.00085), sqrt(.012), 1000)**2; cumprod(1 - betas).
        let ab = SchedulerConfig::stable_diffusion().alphas_cumprod();
        assert!((ab[0] - 0.99915).abs() < 1e-12);
        assert!((ab[999] - 0.004_660_098_5).abs() < 1e-9, "{}", ab[999]);
        assert!((ab[499] - 0.277_669_650).abs() < 1e-8, "{}", ab[499]);
        assert!(ab.windows(2).all(|w| w[1] < w[0]));
    }

    #[test]
    fn round_trip_recovers_x0_across_t() {
        let s = sched();
        let z0 = randn(4096, 1);
        let eps = randn(4096, 2);
        for t in [0usize, 1, 10, 100, 250, 500, 750, 900, 998, 999] {
            let zt = s.add_noise(z0.view(), eps.view(), t).unwrap();
            let x0 = s.x0_from_eps(zt.view(), eps.view(), t).unwrap();
            let e2 = s.eps_from_x0(zt.view(), z0.view(), t).unwrap();
            let v = s.v_from_x0_eps(z0.view(), eps.view(), t).unwrap();
            let e3 = s.eps_from_v(zt.view(), v.view(), t).unwrap();
            let x3 = s.x0_from_v(zt.view(), v.view(), t).unwrap();
            // x0 = (z - s eps)/a amplifies the f32 rounding of z_t by 1/a (15x at T-1).
            let ab = s.alpha_bar(t).unwrap();
            let tol_x0 = 4e-6 / ab.sqrt() as f32;
            let tol_eps = 4e-6 / (1.0 - ab).sqrt() as f32;
            let md = |a: &Array1<f32>, b: &Array1<f32>| {
                a.iter()
                    .zip(b.iter())
                    .map(|(x, y)| (x - y).abs())
                    .fold(0f32, f32::max)
            };
            assert!(zt.iter().all(|x| x.is_finite()), "t={t}");
            assert!(md(&x0, &z0) < tol_x0, "x0 t={t}: {}", md(&x0, &z0));
            assert!(md(&x3, &z0) < tol_x0, "x0(v) t={t}: {}", md(&x3, &z0));
            assert!(md(&e2, &eps) < tol_eps, "eps t={t}: {}", md(&e2, &eps));
            assert!(md(&e3, &eps) < 4e-5, "eps(v) t={t}: {}", md(&e3, &eps));
        }
    }

    #[test]
    fn extremes_are_finite_for_large_inputs() {
        // t = 1 (1-ab tiny: eps_from_x0 divides by 0.04) and t = T-1 (ab tiny: x0_from_eps
        // divides by 0.068), with latents far outside the usual range.
        for cfg in [
            SchedulerConfig::stable_diffusion(),
            SchedulerConfig {
                beta_schedule: BetaSchedule::Linear,
                beta_start: 1e-4,
                beta_end: 0.02,
                ..SchedulerConfig::stable_diffusion()
            },
        ] {
            let s = Schedule::new(cfg).unwrap();
            let big = Array4::from_elem((1, 4, 2, 2), 1e4f32);
            for t in [1usize, s.num_train_timesteps() - 1] {
                for out in [
                    s.add_noise(big.view(), big.view(), t).unwrap(),
                    s.x0_from_eps(big.view(), big.view(), t).unwrap(),
                    s.eps_from_x0(big.view(), big.view(), t).unwrap(),
                    s.eps_from_v(big.view(), big.view(), t).unwrap(),
                ] {
                    assert!(out.iter().all(|x| x.is_finite()), "t={t}");
                }
            }
        }
    }

    #[test]
    fn bad_schedules_and_timesteps_are_errors() {
        let s = sched();
        let a = Array1::<f32>::zeros(3);
        let b = Array1::<f32>::zeros(4);
        assert!(s.add_noise(a.view(), a.view(), 1000).is_err());
        let e = s.add_noise(a.view(), b.view(), 3).unwrap_err().to_string();
        assert!(e.contains("different shapes"), "{e}");
        let mut cfg = SchedulerConfig::stable_diffusion();
        cfg.beta_end = 0.5;
        let e = Schedule::new(cfg).unwrap_err().to_string();
        assert!(e.contains("cannot be recovered"), "{e}");
        cfg = SchedulerConfig::stable_diffusion();
        cfg.beta_start = 0.0;
        assert!(Schedule::new(cfg).is_err());
    }

    #[test]
    fn timestep_set_is_even_and_deterministic() {
        let cfg = SchedulerConfig::stable_diffusion();
        let set = TimestepSet::new(&cfg, 20, 980, 49).unwrap();
        assert_eq!(set.steps().len(), 49);
        assert_eq!(set.steps()[0], 20);
        assert_eq!(set.steps()[48], 980);
        assert!(set.steps().windows(2).all(|w| w[1] - w[0] == 20));
        assert!(set.contains(40) && !set.contains(41));
        assert!(set.check(41).unwrap_err().to_string().contains("not in"));
        // Sampling covers the whole set.
        let mut rng = Rng::new(3);
        let mut seen = std::collections::HashSet::new();
        for _ in 0..5000 {
            seen.insert(set.sample(&mut rng));
        }
        assert_eq!(seen.len(), 49);
        let d = TimestepSet::default_for(&cfg).unwrap();
        assert_eq!(d.steps().len(), 50);
        assert_eq!((d.steps()[0], d.steps()[49]), (20, 980));
        assert!(TimestepSet::new(&cfg, 0, 999, 1001).is_err());
        assert!(TimestepSet::new(&cfg, 10, 1000, 5).is_err());
        assert!(TimestepSet::new(&cfg, 0, 10, 0).is_err());
    }
}

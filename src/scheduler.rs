//! DDIM noise schedule (Song et al. 2021) as the diffusers library configures it.
//!
//! `alphas_cumprod` (written ab) from the model's beta schedule; forward noising
//! z_t = sqrt(ab_t) z0 + sqrt(1 - ab_t) eps; conversions between eps, x0 and v
//! predictions; the fixed discrete timestep set the method samples t from.

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

    /// alphas_cumprod[t] for t in 0..num_train_timesteps, in f64.
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
}

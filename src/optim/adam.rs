//! Adam (Kingma & Ba 2015) with beta1 = 0.9, beta2 = 0.999 and eps = 1e-15 as in 3DGS,
//! optionally scaling each Gaussian's step by a weight, and its saved state (moments
//! and step count) for checkpoints.

use crate::{Error, Result, Scene};
use rayon::prelude::*;

/// The moments and step count of one [`Adam`].
#[derive(Debug, Clone, PartialEq)]
pub struct AdamState {
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub t: i32,
}

/// The state of a [`ColourFit`](super::ColourFit)'s optimizers (f_dc, f_rest).
#[derive(Debug, Clone, PartialEq)]
pub struct OptimizerState {
    pub dc: AdamState,
    pub rest: AdamState,
}

impl OptimizerState {
    /// The state of a fit of `scene` that has not stepped yet (zero moments).
    pub fn zeros(scene: &Scene) -> OptimizerState {
        let z = |len: usize| AdamState {
            m: vec![0.0; len],
            v: vec![0.0; len],
            t: 0,
        };
        OptimizerState {
            dc: z(scene.len() * 3),
            rest: z(scene.len() * 3 * scene.rest_per_channel()),
        }
    }
}

/// Adam state for one parameter vector.
#[derive(Debug, Clone)]
pub struct Adam {
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    m: Vec<f32>,
    v: Vec<f32>,
    t: i32,
}

impl Adam {
    /// 3DGS settings: beta (0.9, 0.999), eps 1e-15.
    pub fn new(n: usize, lr: f32) -> Adam {
        Adam {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// The moments and step count.
    pub fn state(&self) -> AdamState {
        AdamState {
            m: self.m.clone(),
            v: self.v.clone(),
            t: self.t,
        }
    }

    /// Replace the moments and step count; `what` names the parameters in errors.
    pub fn set_state(&mut self, s: AdamState, what: &str) -> Result<()> {
        if s.m.len() != self.m.len() || s.v.len() != self.v.len() {
            return Err(Error::param(format!(
                "{what}: optimizer state holds {} / {} moments, the scene needs {}",
                s.m.len(),
                s.v.len(),
                self.m.len()
            )));
        }
        if s.t < 0 || s.m.iter().chain(&s.v).any(|x| !x.is_finite()) || s.v.iter().any(|x| *x < 0.0)
        {
            return Err(Error::param(format!(
                "{what}: optimizer state is not valid (negative step or second moment, or not finite)"
            )));
        }
        self.m = s.m;
        self.v = s.v;
        self.t = s.t;
        Ok(())
    }

    /// One update of `params` with gradient `grad`.
    pub fn step(&mut self, params: &mut [f32], grad: &[f32]) {
        self.step_weighted(params, grad, None);
    }

    /// One update of `params` with gradient `grad`, each parameter's step scaled by the
    /// weight of its group (`weights`: one weight per `params.len() / weights.len()`
    /// consecutive parameters, a Gaussian's): weight 0 leaves the parameter's bits as
    /// they are, weight 1 (or no weights) is the plain Adam step. The moments follow the
    /// gradient either way.
    pub fn step_weighted(&mut self, params: &mut [f32], grad: &[f32], weights: Option<&[f32]>) {
        self.t += 1;
        let bc1 = 1.0 - self.beta1.powi(self.t);
        let bc2 = 1.0 - self.beta2.powi(self.t);
        let (b1, b2, lr, eps) = (self.beta1, self.beta2, self.lr, self.eps);
        let per = weights.map_or(1, |w| (params.len() / w.len().max(1)).max(1));
        params
            .par_iter_mut()
            .zip(grad.par_iter())
            .zip(self.m.par_iter_mut().zip(self.v.par_iter_mut()))
            .enumerate()
            .for_each(|(i, ((p, &g), (m, v)))| {
                *m = b1 * *m + (1.0 - b1) * g;
                *v = b2 * *v + (1.0 - b2) * g * g;
                let mh = *m / bc1;
                let vh = *v / bc2;
                let w = weights.map_or(1.0, |w| w[i / per]);
                if w == 1.0 {
                    *p -= lr * mh / (vh.sqrt() + eps);
                } else if w != 0.0 {
                    *p -= w * (lr * mh / (vh.sqrt() + eps));
                }
            });
    }
}

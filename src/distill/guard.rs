//! Guards of the distillation loop (issue 22): a loop that has gone non-finite stops
//! with an error naming the iteration, and nothing is written from such a state.
//!
//! * [`Distiller::iterate`] runs one iteration and refuses it, naming the iteration,
//!   when it fails (e.g. a prior returned NaN: CSD's gradient check) or leaves a
//!   colour or an optimizer moment that is not finite (e.g. a step size so large that
//!   the colours overflow f32);
//! * [`checkpoint`] is the last check before a checkpoint is written.
//!
//! Extreme but finite settings (guidance 1e6, step sizes 0 or 1e3, views the object
//! does not cover, Gaussians of zero scale or opacity 0 or 1) are not errors: the loop
//! keeps the colours finite (targets are limited to the displayable range), which
//! `tests/integration/extremes.rs` checks.

use super::{Distiller, IterReport};
use crate::optim::OptimizerState;
use crate::{Error, Result, Scene};

impl Distiller<'_> {
    /// One iteration (see the module docs of [`crate::distill`]); an error names the
    /// iteration, and an iteration that leaves a non-finite colour or optimizer moment is
    /// an error.
    pub fn iterate(&mut self) -> Result<IterReport> {
        let it = self.iteration;
        let report = self.iterate_unguarded().map_err(|e| at_iteration(it, e))?;
        checkpoint(self.scene(), &self.optimizer_state()).map_err(|e| at_iteration(it, e))?;
        if !report.loss.is_finite() {
            return Err(at_iteration(
                it,
                Error::Other(format!("the colour loss is {}", report.loss)),
            ));
        }
        Ok(report)
    }
}

/// `e` with "distill iteration IT: " in front, keeping its kind (and so its exit code).
pub fn at_iteration(it: u64, e: Error) -> Error {
    let say = |m: String| format!("distill iteration {it}: {m}");
    match e {
        Error::Input { path, reason } => Error::Input {
            path,
            reason: say(reason),
        },
        Error::Param(m) => Error::Param(say(m)),
        Error::Missing(m) => Error::Missing(say(m)),
        Error::Onnx(m) => Error::Onnx(say(m)),
        Error::Other(m) => Error::Other(say(m)),
        other => Error::Other(say(other.to_string())),
    }
}

/// Refuse a state that is not finite: every colour (SH DC and rest) and every Adam
/// moment. Called before a checkpoint is written and after each iteration.
pub fn checkpoint(scene: &Scene, state: &OptimizerState) -> Result<()> {
    if let Some(i) = scene
        .sh_dc
        .iter()
        .position(|c| c.iter().any(|v| !v.is_finite()))
    {
        return Err(Error::Other(format!(
            "the colour (SH DC) of Gaussian {i} is {:?}: the state is not finite, and no \
             checkpoint is written from it (lower lr_dc, csd.lr or csd.guidance)",
            scene.sh_dc[i]
        )));
    }
    if let Some(j) = scene.sh_rest.iter().position(|v| !v.is_finite()) {
        return Err(Error::Other(format!(
            "SH coefficient {j} (f_rest) is {}: the state is not finite, and no checkpoint \
             is written from it",
            scene.sh_rest[j]
        )));
    }
    for (name, a) in [("f_dc", &state.dc), ("f_rest", &state.rest)] {
        if a.m.iter().chain(&a.v).any(|v| !v.is_finite()) {
            return Err(Error::Other(format!(
                "the optimizer's {name} moments are not finite, and no checkpoint is \
                 written from them"
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::AdamState;

    #[test]
    fn checkpoint_refuses_non_finite_state_naming_it() {
        let s = Scene {
            positions: vec![[0.0; 3]; 2],
            log_scales: vec![[-3.0; 3]; 2],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 2],
            opacity_logits: vec![0.0; 2],
            sh_degree: 0,
            sh_dc: vec![[0.1; 3]; 2],
            sh_rest: Vec::new(),
        };
        let st = |v: f32| OptimizerState {
            dc: AdamState {
                m: vec![0.0, v],
                v: vec![0.0; 2],
                t: 1,
            },
            rest: AdamState {
                m: Vec::new(),
                v: Vec::new(),
                t: 0,
            },
        };
        checkpoint(&s, &st(1.0)).unwrap();
        let e = checkpoint(&s, &st(f32::NAN)).unwrap_err().to_string();
        assert!(e.contains("f_dc moments"), "{e}");
        let mut bad = s.clone();
        bad.sh_dc[1][2] = f32::INFINITY;
        let e = checkpoint(&bad, &st(1.0)).unwrap_err().to_string();
        assert!(
            e.contains("Gaussian 1") && e.contains("no checkpoint"),
            "{e}"
        );
        let e = at_iteration(7, Error::param("x")).to_string();
        assert_eq!(e, "invalid parameter: distill iteration 7: x");
    }
}

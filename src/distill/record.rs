//! What the loop records, in memory and on disk: the progress of a run (a checkpoint's
//! contents), every iteration's report and the last iteration's tensors; the checkpoint
//! I/O beside it ([`super::checkpoint`]) writes and reads them. The stage chain's iteration
//! window and target statistics are the chain's artifacts' ([`crate::artifacts::chain`]).

use crate::Scene;
pub use crate::artifacts::chain::{IterationWindow, TargetStats};
use ndarray::Array4;
use std::path::PathBuf;

/// What one iteration did, for logs, checkpoints and tests.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IterReport {
    pub iteration: u64,
    pub views: Vec<usize>,
    pub timestep: usize,
    /// Mean colour loss over the window before the update.
    pub loss: f64,
    /// Mean texture loss over the window before the update (0 without the term).
    pub texture_loss: f64,
    /// RMS of the image change the prior asked for, over covered pixels.
    pub delta_rms: f64,
    /// Fraction of covered target pixels clipped (<= 0.02 or >= 0.98 in every channel).
    pub clipped: f64,
    /// Cosine of the high-pass change with the same views' previous visit ([`super::agreement`];
    /// None when no view of the window was visited before).
    pub hf_agree_revisit: Option<f64>,
    /// Cosine of the high-pass change between the window's neighbouring views after depth
    /// reprojection ([`super::agreement`]; None for a one-view window or no overlap).
    pub hf_agree_adjacent: Option<f64>,
}

impl IterReport {
    /// The report of an iteration from its window, timestep, targets and colour step
    /// (`(loss, texture_loss)`), with no agreement measured.
    pub fn new(
        w: &IterationWindow,
        timestep: usize,
        stats: TargetStats,
        (loss, texture_loss): (f64, f64),
    ) -> Self {
        IterReport {
            iteration: w.iteration,
            views: w.window.views.clone(),
            timestep,
            loss,
            texture_loss,
            delta_rms: stats.delta_rms,
            clipped: stats.clipped,
            hf_agree_revisit: None,
            hf_agree_adjacent: None,
        }
    }
}

/// The last iteration's tensors, written into checkpoints for inspection.
#[derive(Debug, Clone)]
pub struct LastIteration {
    pub report: IterReport,
    /// The latents of both branches (None when the prior was not called:
    /// [`crate::csd::CsdParams::asks_nothing`]).
    pub latents: Option<LastLatents>,
    /// `[N, H, W, 3]`.
    pub targets: Array4<f32>,
    /// What the prior says of itself ([`crate::prior::Prior::describe`]), if anything.
    pub prior: Option<serde_json::Value>,
}

/// The last iteration's latents, `[N, C, h, w]` each.
#[derive(Debug, Clone)]
pub struct LastLatents {
    pub z0: Array4<f32>,
    pub z_tgt: Array4<f32>,
    pub z_src: Array4<f32>,
}

/// Where a run of the loop starts: a scene and the progress made on it (iterations done,
/// the optimizer state, the history and the agreement state of a checkpoint; none for a
/// plain scene: iteration 0). Read by [`super::checkpoint::read_progress`] and
/// [`super::checkpoint::load_progress`].
#[derive(Debug, Clone)]
pub struct Progress {
    pub scene: Scene,
    /// Iterations done.
    pub iteration: u64,
    /// The optimizer state (`None`: zero, nothing done yet).
    pub state: Option<crate::optim::OptimizerState>,
    /// Per-iteration reports so far.
    pub history: Vec<serde_json::Value>,
    /// Each view's previous high-pass change (`hf_prev.npy`, shape and values): the
    /// agreement measurement's state, which only `distill` keeps.
    pub hf_prev: Option<(Vec<usize>, Vec<f32>)>,
    /// The checkpoint it was read from (None for a plain scene).
    pub from: Option<PathBuf>,
}

impl Progress {
    /// A scene at iteration 0.
    pub fn fresh(scene: Scene) -> Progress {
        Progress {
            scene,
            iteration: 0,
            state: None,
            history: Vec::new(),
            hf_prev: None,
            from: None,
        }
    }

    /// The optimizer state (zero where none was saved).
    pub fn state(&self) -> crate::optim::OptimizerState {
        self.state
            .clone()
            .unwrap_or_else(|| crate::optim::OptimizerState::zeros(&self.scene))
    }
}

//! A distill checkpoint: a `scene` artifact that also holds the loop's optimizer state
//! (Adam's moments of the SH colours, `adam_dc.npy`, `adam_rest.npy`), its iteration and
//! step counts (`state.json`), every iteration's report (`history.json`), the agreement
//! measurement's state (`hf_prev.npy`) and the last iteration's tensors for `pipeline
//! inspect`. Every draw of the loop depends only on (seed, iteration), so a run resumed
//! from a checkpoint gives the same bytes as one that never stopped. A scene artifact
//! without `state.json` (no iteration has run) resumes at iteration 0.

use super::record::{IterReport, LastIteration, Progress};
use crate::artifacts::{read_scene, write_array};
use crate::scene::{self, Scene};
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use std::path::Path;

/// A distillation checkpoint: a `scene` artifact that also holds the optimizer state
/// and the iteration count (written by `distill`), so that a run resumes bit for bit.
#[derive(Debug)]
pub struct Checkpoint {
    pub art: Artifact,
    pub scene: Scene,
    /// Iterations done.
    pub iteration: u64,
    pub state: crate::optim::OptimizerState,
    /// Per-iteration reports of every iteration so far (`history.json`).
    pub history: Vec<serde_json::Value>,
    /// Each view's previous high-pass change, shape and values (`hf_prev.npy`, from
    /// [`crate::metrics::agreement`]; absent before the first iteration).
    pub hf_prev: Option<(Vec<usize>, Vec<f32>)>,
}

/// Files of a checkpoint beside `scene.ply`.
pub const CHECKPOINT_STATE: &str = "state.json";
pub const CHECKPOINT_ADAM_DC: &str = "adam_dc.npy";
pub const CHECKPOINT_ADAM_REST: &str = "adam_rest.npy";
pub const CHECKPOINT_HISTORY: &str = "history.json";
pub const CHECKPOINT_HF_PREV: &str = "hf_prev.npy";

/// Read a checkpoint written by `distill` (a scene artifact with `state.json`,
/// `adam_dc.npy` `[2, 3 G]` and `adam_rest.npy` `[2, 3 G K]` holding Adam's first and
/// second moments, and `history.json`).
pub fn read_checkpoint(dir: &Path) -> Result<Checkpoint> {
    let art = Artifact::open(dir, ArtifactKind::Scene)?;
    if !art.path(CHECKPOINT_STATE).is_file() {
        return Err(Error::input(
            dir,
            "scene artifact holds no optimizer state (state.json): not a distill checkpoint",
        ));
    }
    let scene = scene::ply::read_ply(&art.path("scene.ply"))?;
    #[derive(serde::Deserialize)]
    struct State {
        iteration: u64,
        adam_dc_step: i32,
        adam_rest_step: i32,
    }
    let st: State = art.read_json(CHECKPOINT_STATE)?;
    let adam = |name: &str, len: usize, t: i32| -> Result<crate::optim::AdamState> {
        let a = art.read_f32(name)?;
        if a.shape != [2, len] {
            return Err(Error::input(
                art.path(name),
                format!(
                    "expected shape [2, {len}] for this scene, found {:?}",
                    a.shape
                ),
            ));
        }
        let mut d = a.data;
        let v = d.split_off(len);
        Ok(crate::optim::AdamState { m: d, v, t })
    };
    let n = scene.len();
    let state = crate::optim::OptimizerState {
        dc: adam(CHECKPOINT_ADAM_DC, n * 3, st.adam_dc_step)?,
        rest: adam(
            CHECKPOINT_ADAM_REST,
            n * 3 * scene.rest_per_channel(),
            st.adam_rest_step,
        )?,
    };
    let history = if art.path(CHECKPOINT_HISTORY).is_file() {
        art.read_json(CHECKPOINT_HISTORY)?
    } else {
        Vec::new()
    };
    let hf_prev = if art.path(CHECKPOINT_HF_PREV).is_file() {
        let a = art.read_f32(CHECKPOINT_HF_PREV)?;
        Some((a.shape, a.data))
    } else {
        None
    };
    Ok(Checkpoint {
        art,
        scene,
        iteration: st.iteration,
        state,
        history,
        hf_prev,
    })
}

/// The per-iteration reports (`history.json`) of a distill checkpoint, without reading
/// its scene or optimizer state.
pub fn read_history(dir: &Path) -> Result<Vec<serde_json::Value>> {
    let art = Artifact::open(dir, ArtifactKind::Scene)?;
    if !art.path(CHECKPOINT_HISTORY).is_file() {
        return Err(Error::input(
            dir,
            "scene artifact holds no history.json: not a distill checkpoint",
        ));
    }
    Ok(art.read_json(CHECKPOINT_HISTORY)?)
}

/// The progress of a run from a checkpoint ([`read_checkpoint`]), or from a scene
/// artifact without optimizer state at iteration 0.
pub fn read_progress(dir: &Path) -> Result<Progress> {
    if !dir.join(CHECKPOINT_STATE).is_file() {
        // A scene artifact with no optimizer state (`distill --iters 0` from a scene: no
        // iteration has run) resumes at iteration 0.
        let mut p = Progress::fresh(read_scene(dir)?);
        p.from = Some(dir.to_path_buf());
        return Ok(p);
    }
    let c = read_checkpoint(dir)?;
    Ok(Progress {
        scene: c.scene,
        iteration: c.iteration,
        state: Some(c.state),
        history: c.history,
        hf_prev: c.hf_prev,
        from: Some(dir.to_path_buf()),
    })
}

/// A checkpoint's progress if `path` is one (a scene artifact with `state.json`), else
/// any scene ([`load_scene`]) at iteration 0.
pub fn load_progress(path: &Path) -> Result<Progress> {
    if crate::artifacts::is_artifact(path) && path.join(CHECKPOINT_STATE).is_file() {
        read_progress(path)
    } else {
        Ok(Progress::fresh(crate::artifacts::load_scene(path)?))
    }
}

/// What a checkpoint holds beside its scene files.
#[derive(Debug, Clone, Copy)]
pub struct CheckpointParts<'a> {
    pub scene: &'a Scene,
    pub state: &'a crate::optim::OptimizerState,
    /// Iterations done.
    pub iteration: u64,
    /// Every iteration's report so far, in order.
    pub history: &'a [serde_json::Value],
    /// The agreement measurement's state (`hf_prev.npy`: shape, values), if any.
    pub hf_prev: Option<(&'a [usize], &'a [f32])>,
    /// The last iteration's tensors (for inspection), if this process ran one.
    pub last: Option<&'a LastIteration>,
}

/// Write a checkpoint's optimizer state (`adam_dc.npy`, `adam_rest.npy`, `state.json`),
/// `history.json`, `hf_prev.npy` (if any), the last iteration's tensors if one ran
/// (`last_targets.npy` `[N, H, W, 3]`; when the prior was called also `last_z0.npy`,
/// `last_z_tgt.npy`, `last_z_src.npy` `[N, C, h, w]`) and the manifest's meta into `out`,
/// a scene artifact whose scene files (`scene.ply`, at least) the caller writes: what
/// [`read_checkpoint`] reads.
pub fn write_checkpoint(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    c: &CheckpointParts<'_>,
) -> Result<()> {
    let st = c.state;
    let pair = |x: &crate::optim::AdamState| [x.m.clone(), x.v.clone()].concat();
    out.write_tensor(CHECKPOINT_ADAM_DC, &[2, st.dc.m.len()], &pair(&st.dc))?;
    out.write_tensor(CHECKPOINT_ADAM_REST, &[2, st.rest.m.len()], &pair(&st.rest))?;
    out.write_json(
        CHECKPOINT_STATE,
        &serde_json::json!({
            "iteration": c.iteration,
            "adam_dc_step": st.dc.t,
            "adam_rest_step": st.rest.t,
        }),
    )?;
    out.write_json(CHECKPOINT_HISTORY, &c.history)?;
    if let Some((shape, data)) = c.hf_prev {
        out.write_tensor(CHECKPOINT_HF_PREV, shape, data)?;
    }
    if let Some(l) = c.last {
        if let Some(z) = &l.latents {
            for (name, x) in [
                ("last_z0.npy", &z.z0),
                ("last_z_tgt.npy", &z.z_tgt),
                ("last_z_src.npy", &z.z_src),
            ] {
                write_array(out, name, x)?;
            }
        }
        write_array(out, "last_targets.npy", &l.targets)?;
    }
    let mut meta = serde_json::json!({
        "iteration": c.iteration,
        "gaussians": c.scene.len(),
        "sh_degree": c.scene.sh_degree,
        "last": c.last.map(|l| &l.report),
    });
    if let Some(p) = c.last.and_then(|l| l.prior.as_ref()) {
        meta["prior"] = p.clone();
    }
    out.set_meta(meta);
    Ok(())
}

/// Append the reports of iterations to a checkpoint's history.
pub fn extend_history(history: &mut Vec<serde_json::Value>, reports: &[IterReport]) -> Result<()> {
    for r in reports {
        history.push(serde_json::to_value(r).map_err(|e| Error::Other(e.to_string()))?);
    }
    Ok(())
}

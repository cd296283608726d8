//! Typed readers of the artifacts the stages exchange, on top of `fantasystyle_schemas`
//! (which opens an artifact, checks its manifest, kind and file hashes, and reads `.npy`).
//! The one place that knows what each artifact holds: stages, metrics and tests read
//! artifacts through these functions, and every shape is checked here, with errors that
//! name the file.
//!
//! | artifact (kind) | written by | reader |
//! |---|---|---|
//! | `views` | render-views | [`read_views`]: rgb `[N,H,W,3]`, depth and alpha `[N,H,W]`, [`Views::cameras`]; [`read_view_images`]: rgb only |
//! | `latents` | encode-latents | [`read_latents`]: `[N,C,h,w]` |
//! | `noised-latents` | mvfc-filter | [`read_noised_latents`]: z_src, z_tgt, eps `[N,C,h,w]`, eps' `[C,h,w]`, t |
//! | `targets` (or `views`) | csd-step | [`read_targets`]: rgb `[N,H,W,3]` |
//! | `scene` | update-gaussians, stylize-baseline, `pipeline wrap` | [`read_scene`] |
//! | `scene` with optimizer state (a checkpoint) | distill, update-gaussians (one iteration) | [`read_checkpoint`], [`load_progress`]; written by [`write_checkpoint`] |
//! | `selection` | select | [`read_selection`]: a weight per Gaussian `[N]` in [0, 1]; written by [`write_selection`] |
//! | `eval-reference` | evaluate --reference-only | [`read_eval_reference_for`]: pool3 features `[M,2048]`, style Grams `[C,C]` f64, `reference.json`; written by [`write_eval_reference`] |
//!
//! Artifacts of one iteration of the stage chain (`render-views --window` ->
//! `encode-latents` -> `mvfc-filter` -> `csd-step`) record the iteration and its window
//! in `meta.iteration` ([`iteration_of`]).
//!
//! Stage inputs that may be an artifact or a plain file: [`load_scene`] (a `.ply`, a
//! `.splat`, a `.spz` or a scene artifact) and [`load_cameras`] (an `orbit:` spec, a camera file or
//! directory, or any artifact holding a `cameras.json`).

use crate::camera::{self, Camera};
use crate::distill::SourceViews;
use crate::distill::record::{IterReport, IterationWindow, LastIteration, Progress, TargetStats};
use crate::geometry::Bounds;
use crate::metrics::views::ViewSet;
use crate::scene::{self, Scene};
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use ndarray::{Array3, Array4, Axis};
use std::path::{Path, PathBuf};

/// True when `dir` is an artifact directory (holds a manifest).
pub fn is_artifact(dir: &Path) -> bool {
    dir.is_dir() && dir.join(fantasystyle_schemas::MANIFEST_FILE).is_file()
}

/// Read tensor `name` of `art` as `[N, C, h, w]`.
fn read4(art: &Artifact, name: &str) -> Result<Array4<f32>> {
    let t = art.read_f32(name)?;
    let [n, c, h, w] = t.shape[..] else {
        return Err(Error::input(
            art.path(name),
            format!("expected shape [N, C, h, w], found {:?}", t.shape),
        ));
    };
    Array4::from_shape_vec((n, c, h, w), t.data)
        .map_err(|e| Error::input(art.path(name), e.to_string()))
}

/// Read tensor `name` of `art` as RGB images `[N, H, W, 3]`, `N, H, W >= 1`.
fn read_rgb(art: &Artifact, name: &str) -> Result<Array4<f32>> {
    let t = art.read_f32(name)?;
    let [n, h, w, 3] = t.shape[..] else {
        return Err(Error::input(
            art.path(name),
            format!("expected shape [N, H, W, 3], found {:?}", t.shape),
        ));
    };
    if n == 0 || h == 0 || w == 0 {
        return Err(Error::input(
            art.path(name),
            format!("empty image set, shape {:?}", t.shape),
        ));
    }
    Ok(Array4::from_shape_vec((n, h, w, 3), t.data).expect("shape checked"))
}

/// A `views` artifact's tensors, shape-checked against each other.
#[derive(Debug)]
pub struct Views {
    pub art: Artifact,
    /// `[N, H, W, 3]` in [0, 1].
    pub rgb: Array4<f32>,
    /// Expected depth `sum_i w_i z_i` (not divided by alpha), `[N, H, W]`.
    pub depth: Array3<f32>,
    /// Accumulated opacity, `[N, H, W]`.
    pub alpha: Array3<f32>,
}

impl Views {
    /// The views as the loop's source views (render-views of the original scene). The
    /// loop composites over black, render-views' default background (the views' own
    /// `--background` is not read).
    pub fn source_views(&self) -> SourceViews {
        let (n, h, w) = self.dim();
        let plane = |x: &Array3<f32>, i: usize| -> Vec<f32> {
            x.index_axis(Axis(0), i).iter().copied().collect()
        };
        SourceViews {
            width: w,
            height: h,
            rgb: (0..n)
                .map(|i| self.rgb.index_axis(Axis(0), i).iter().copied().collect())
                .collect(),
            alpha: (0..n).map(|i| plane(&self.alpha, i)).collect(),
            depth: (0..n).map(|i| plane(&self.depth, i)).collect(),
            background: [0.0; 3],
        }
    }

    /// `(N, H, W)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        let (n, h, w, _) = self.rgb.dim();
        (n, h, w)
    }

    /// The views' cameras (`cameras.json`, INRIA format), at the views' size.
    pub fn cameras(&self) -> Result<Vec<Camera>> {
        camera::inria::read_inria(&self.art.path("cameras.json"))
    }

    /// The views' cameras, refused unless there is one per view.
    pub fn cameras_per_view(&self) -> Result<Vec<Camera>> {
        let cameras = self.cameras()?;
        let n = self.dim().0;
        if cameras.len() != n {
            return Err(Error::input(
                self.art.path("cameras.json"),
                format!("{} cameras for {n} views", cameras.len()),
            ));
        }
        Ok(cameras)
    }
}

/// Open a `views` artifact and read only its images, `rgb.npy` `[N, H, W, 3]`
/// (N, H, W >= 1); for stages that need neither depth nor alpha.
pub fn read_view_images(dir: &Path) -> Result<(Artifact, Array4<f32>)> {
    let art = Artifact::open(dir, ArtifactKind::Views)?;
    let rgb = read_rgb(&art, "rgb.npy")?;
    Ok((art, rgb))
}

/// Open a `views` artifact and read `rgb.npy` `[N, H, W, 3]` (N, H, W >= 1) and
/// `depth.npy`, `alpha.npy` `[N, H, W]`.
pub fn read_views(dir: &Path) -> Result<Views> {
    let (art, rgb) = read_view_images(dir)?;
    let (n, h, w, _) = rgb.dim();
    let plane = |name: &str| -> Result<Array3<f32>> {
        let t = art.read_f32(name)?;
        if t.shape != [n, h, w] {
            return Err(Error::input(
                art.path(name),
                format!(
                    "expected shape [{n}, {h}, {w}] to match rgb.npy, got {:?}",
                    t.shape
                ),
            ));
        }
        Ok(Array3::from_shape_vec((n, h, w), t.data).expect("shape checked"))
    };
    let depth = plane("depth.npy")?;
    let alpha = plane("alpha.npy")?;
    Ok(Views {
        art,
        rgb,
        depth,
        alpha,
    })
}

/// A `views` artifact as the evaluation holds it ([`ViewSet`], validated).
pub fn read_view_set(dir: &Path) -> Result<ViewSet> {
    if !dir.is_dir() {
        return Err(Error::input(dir, "views artifact directory not found"));
    }
    let views = read_views(dir)?;
    let cameras = views.cameras()?;
    let Views {
        rgb, depth, alpha, ..
    } = views;
    ViewSet::new(dir, rgb, depth, alpha, cameras)
}

/// Read a `latents` artifact's `latents.npy` as `[N, C, h, w]` (non-empty).
pub fn read_latents(dir: &Path) -> Result<Array4<f32>> {
    Ok(open_latents(dir)?.z)
}

/// A `latents` artifact (encode-latents' output).
#[derive(Debug)]
pub struct Latents {
    pub art: Artifact,
    /// `[N, C, h, w]`, non-empty.
    pub z: Array4<f32>,
    /// The iteration of the stage chain the encoded views belong to ([`iteration_of`]).
    pub iteration: Option<IterationWindow>,
}

/// Open a `latents` artifact: `latents.npy` `[N, C, h, w]` (non-empty) and
/// `meta.iteration`.
pub fn open_latents(dir: &Path) -> Result<Latents> {
    let art = Artifact::open(dir, ArtifactKind::Latents)?;
    let z = read4(&art, "latents.npy")?;
    if z.is_empty() {
        return Err(Error::input(
            art.path("latents.npy"),
            format!("empty latents {:?}", z.shape()),
        ));
    }
    let iteration = iteration_of(&art)?;
    Ok(Latents { art, z, iteration })
}

/// The rows of `z` (`[N, ...]` over every camera of `w`'s path, read from `file`) of
/// the window of `w`, in window order.
pub fn window_rows(z: &Array4<f32>, w: &IterationWindow, file: &Path) -> Result<Array4<f32>> {
    if z.shape()[0] != w.path.len {
        return Err(Error::input(
            file,
            format!(
                "{} views, but the iteration's path has {} cameras",
                z.shape()[0],
                w.path.len
            ),
        ));
    }
    Ok(z.select(ndarray::Axis(0), &w.window.views))
}

/// A `noised-latents` artifact (mvfc-filter's output).
#[derive(Debug)]
pub struct NoisedLatents {
    pub art: Artifact,
    /// add_noise(z0_src, eps, t), `[N, C, h, w]`.
    pub z_src: Array4<f32>,
    /// MVFC(add_noise(z0_tgt, eps, t), eps'), `[N, C, h, w]`.
    pub z_tgt: Array4<f32>,
    /// The noise shared by source and target, `[N, C, h, w]`.
    pub eps: Array4<f32>,
    /// The MVFC noise eps' shared by the views, `[C, h, w]`.
    pub eps_shared: Array3<f32>,
    /// The timestep t (`meta.timestep`).
    pub timestep: usize,
    /// The iteration of the stage chain ([`iteration_of`]).
    pub iteration: Option<IterationWindow>,
}

/// Open a `noised-latents` artifact: `z_src.npy`, `z_tgt.npy`, `eps.npy` of one shape
/// `[N, C, h, w]`, `eps_shared.npy` `[C, h, w]`, and `meta.timestep`.
pub fn read_noised_latents(dir: &Path) -> Result<NoisedLatents> {
    let art = Artifact::open(dir, ArtifactKind::NoisedLatents)?;
    let z_src = read4(&art, "z_src.npy")?;
    let z_tgt = read4(&art, "z_tgt.npy")?;
    let eps = read4(&art, "eps.npy")?;
    for (name, x) in [("z_tgt.npy", &z_tgt), ("eps.npy", &eps)] {
        if x.shape() != z_src.shape() {
            return Err(Error::input(
                art.path(name),
                format!(
                    "shape {:?} differs from z_src.npy's {:?}",
                    x.shape(),
                    z_src.shape()
                ),
            ));
        }
    }
    let (_, c, h, w) = z_src.dim();
    let es = art.read_f32("eps_shared.npy")?;
    if es.shape != [c, h, w] {
        return Err(Error::input(
            art.path("eps_shared.npy"),
            format!("expected shape [{c}, {h}, {w}], found {:?}", es.shape),
        ));
    }
    let eps_shared = Array3::from_shape_vec((c, h, w), es.data).expect("shape checked");
    let timestep = art.manifest.meta["timestep"].as_u64().ok_or_else(|| {
        Error::input(
            art.path("manifest.json"),
            "meta.timestep is missing or not a non-negative integer",
        )
    })? as usize;
    let iteration = iteration_of(&art)?;
    Ok(NoisedLatents {
        art,
        z_src,
        z_tgt,
        eps,
        eps_shared,
        timestep,
        iteration,
    })
}

/// Target images for the colour fit: a `targets` artifact (csd-step) or a `views`
/// artifact, whose `rgb.npy` is `[N, H, W, 3]`.
#[derive(Debug)]
pub struct Targets {
    pub art: Artifact,
    /// `[N, H, W, 3]`.
    pub rgb: Array4<f32>,
    /// For the targets of one iteration of the stage chain (csd-step): the iteration, its
    /// timestep (`meta.timestep`) and what the targets asked for (`meta.stats`).
    pub step: Option<(IterationWindow, usize, TargetStats)>,
}

/// Open a `targets` (or `views`) artifact and read its `rgb.npy` `[N, H, W, 3]`.
pub fn read_targets(dir: &Path) -> Result<Targets> {
    let art = Artifact::open_any(dir)?;
    let kind = art.manifest.kind;
    if kind != ArtifactKind::Targets && kind != ArtifactKind::Views {
        return Err(Error::input(
            dir,
            format!("expected a `targets` or `views` artifact, found `{kind}`"),
        ));
    }
    let rgb = read_rgb(&art, "rgb.npy")?;
    let step = match iteration_of(&art)? {
        None => None,
        Some(w) => {
            let meta = &art.manifest.meta;
            let bad =
                |what: String| Error::input(art.path(fantasystyle_schemas::MANIFEST_FILE), what);
            let t = meta["timestep"]
                .as_u64()
                .ok_or_else(|| bad("meta.timestep is missing or not an integer".into()))?;
            let stats: TargetStats = serde_json::from_value(meta["stats"].clone())
                .map_err(|e| bad(format!("meta.stats: {e}")))?;
            if rgb.dim().0 != w.window.views.len() {
                return Err(bad(format!(
                    "{} target images for a window of {} views",
                    rgb.dim().0,
                    w.window.views.len()
                )));
            }
            Some((w, t as usize, stats))
        }
    };
    Ok(Targets { art, rgb, step })
}

/// Read a `scene` artifact's `scene.ply` (manifest and hashes checked first).
pub fn read_scene(dir: &Path) -> Result<Scene> {
    let a = Artifact::open(dir, ArtifactKind::Scene)?;
    scene::ply::read_ply(&a.path("scene.ply"))
}

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
    /// [`crate::distill::agreement`]; absent before the first iteration).
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

/// The `loss.json` of a `stylize-baseline` artifact (a scene artifact).
pub fn read_baseline_log(dir: &Path) -> Result<serde_json::Value> {
    let art = Artifact::open(dir, ArtifactKind::Scene)?;
    if !art.path("loss.json").is_file() {
        return Err(Error::input(
            dir,
            "scene artifact holds no loss.json: not written by stylize-baseline",
        ));
    }
    Ok(art.read_json("loss.json")?)
}

/// The Inception pool3 feature files of an `eval-reference` artifact, in the order of
/// [`crate::metrics::reference::Reference`]'s fields.
const REFERENCE_POOL3: [&str; 4] = [
    "views_pool3.npy",
    "crops_pool3.npy",
    "object_squares_pool3.npy",
    "style_squares_pool3.npy",
];
/// Its scores.
const REFERENCE_SCORES: &str = "reference.json";

fn style_gram_file(tap: usize) -> String {
    format!("style_gram_{tap}.npy")
}

/// The weights file of a `selection` artifact.
pub const SELECTION_WEIGHTS: &str = "weights.npy";

/// Read the `selection` artifact `dir`: one weight per Gaussian, each in [0, 1] (errors
/// name the file).
pub fn read_selection(dir: &Path) -> Result<crate::selection::Selection> {
    let art = Artifact::open(dir, ArtifactKind::Selection)?;
    let t = art.read_f32(SELECTION_WEIGHTS)?;
    let path = art.path(SELECTION_WEIGHTS);
    if t.shape.len() != 1 {
        return Err(Error::input(
            path,
            format!("expected shape [N], found {:?}", t.shape),
        ));
    }
    crate::selection::Selection::new(t.data, &path)
}

/// Write `sel` into `out` (a `selection` artifact): the weights, and in `meta` the
/// number of Gaussians, how many are selected and `meta`'s own fields.
pub fn write_selection(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    sel: &crate::selection::Selection,
    meta: serde_json::Value,
) -> Result<()> {
    out.write_tensor(SELECTION_WEIGHTS, &[sel.len()], &sel.weights)?;
    let mut m = serde_json::json!({"gaussians": sel.len(), "selected": sel.selected()});
    if let (Some(m), serde_json::Value::Object(extra)) = (m.as_object_mut(), meta) {
        m.extend(extra);
    }
    out.set_meta(m);
    Ok(())
}

/// Write an evaluation reference into `out` (an `eval-reference` artifact): what
/// [`read_eval_reference_for`] reads.
pub fn write_eval_reference(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    r: &crate::metrics::reference::Reference,
) -> Result<()> {
    let sets = [
        &r.views_pool3,
        &r.crops_pool3,
        &r.object_squares_pool3,
        &r.style_squares_pool3,
    ];
    for (name, rows) in REFERENCE_POOL3.iter().zip(sets) {
        out.write_tensor(
            name,
            &[rows.len(), crate::metrics::nets::POOL3],
            &rows.concat(),
        )?;
    }
    for (tap, g) in r.style_grams.iter().enumerate() {
        let c = g.len().isqrt();
        out.write_tensor(&style_gram_file(tap), &[c, c], g)?;
    }
    out.write_json(REFERENCE_SCORES, &r.scores)?;
    out.set_meta(serde_json::json!({"style_gram_taps": r.style_grams.len()}));
    Ok(())
}

/// Read the `eval-reference` artifact `dir` (see [`crate::metrics::reference`]) for an
/// evaluation of `original` against `style` with the LPIPS backbone `lpips_net`: refused,
/// naming `dir` and what differs, when it was made from other files (their blake3 in its
/// manifest) or with another backbone. The caller checks the evaluation's settings
/// ([`crate::metrics::reference::Reference::check`]).
pub fn read_eval_reference_for(
    dir: &Path,
    original: &Path,
    style: &Path,
    lpips_net: &str,
) -> Result<crate::metrics::reference::Reference> {
    let (art, r) = read_eval_reference(dir)?;
    for (role, path) in [("original", original), ("style", style)] {
        let here = fantasystyle_schemas::hash_path(path)?;
        let made_from = art.manifest.inputs.iter().find(|i| i.role == role);
        if made_from.map(|i| &i.blake3) != Some(&here) {
            return Err(Error::input(
                dir,
                format!(
                    "this reference was made from another {role} ({}), not {}: make it again \
                     with `evaluate --reference-only`",
                    made_from.map_or("none recorded", |i| i.path.as_str()),
                    path.display()
                ),
            ));
        }
    }
    if art.manifest.producer.params.get("lpips_net") != Some(&serde_json::json!(lpips_net)) {
        return Err(Error::input(
            dir,
            format!(
                "this reference was made with another --lpips-net (this evaluation: {lpips_net})"
            ),
        ));
    }
    Ok(r)
}

/// Read an `eval-reference` artifact (see [`crate::metrics::reference`]).
fn read_eval_reference(dir: &Path) -> Result<(Artifact, crate::metrics::reference::Reference)> {
    let art = Artifact::open(dir, ArtifactKind::EvalReference)?;
    let mut sets = Vec::new();
    for name in REFERENCE_POOL3 {
        let a = art.read_tensor::<f32>(name)?;
        if a.shape.len() != 2 || a.shape[1] != crate::metrics::nets::POOL3 {
            return Err(Error::input(
                art.path(name),
                format!(
                    "shape {:?}, expected [M, {}]",
                    a.shape,
                    crate::metrics::nets::POOL3
                ),
            ));
        }
        sets.push(
            a.data
                .chunks(crate::metrics::nets::POOL3)
                .map(<[f32]>::to_vec)
                .collect(),
        );
    }
    let taps = art.manifest.meta["style_gram_taps"]
        .as_u64()
        .ok_or_else(|| Error::input(dir.join("manifest.json"), "meta.style_gram_taps missing"))?
        as usize;
    let mut style_grams = Vec::with_capacity(taps);
    for tap in 0..taps {
        let name = style_gram_file(tap);
        let a = art.read_tensor::<f64>(&name)?;
        if a.shape.len() != 2 || a.shape[0] != a.shape[1] {
            return Err(Error::input(
                art.path(&name),
                format!("shape {:?}, expected [C, C]", a.shape),
            ));
        }
        style_grams.push(a.data);
    }
    let scores = art.read_json(REFERENCE_SCORES)?;
    let [
        views_pool3,
        crops_pool3,
        object_squares_pool3,
        style_squares_pool3,
    ]: [Vec<Vec<f32>>; 4] = sets.try_into().expect("four sets");
    Ok((
        art,
        crate::metrics::reference::Reference {
            scores,
            views_pool3,
            crops_pool3,
            object_squares_pool3,
            style_squares_pool3,
            style_grams,
        },
    ))
}

/// The progress of a run from a checkpoint ([`read_checkpoint`]).
pub fn read_progress(dir: &Path) -> Result<Progress> {
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
    if is_artifact(path) && path.join(CHECKPOINT_STATE).is_file() {
        read_progress(path)
    } else {
        Ok(Progress::fresh(load_scene(path)?))
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

/// The iteration that stage inputs `(path, recorded)` record: they must all record the
/// same one, or none (then: one window of an open path of all `n` views, iteration 0 of
/// seed 0).
pub fn agreed_iteration(
    inputs: &[(&Path, Option<&IterationWindow>)],
    n: usize,
) -> Result<IterationWindow> {
    let Some(w) = inputs.iter().find_map(|(_, w)| *w) else {
        return Ok(IterationWindow::whole_open_path(n, 0, 0));
    };
    if let Some((p, _)) = inputs.iter().find(|(_, o)| *o != Some(w)) {
        return Err(Error::input(
            p,
            format!(
                "records another iteration than the other inputs (or none); expected \
                 iteration {} of seed {}, views {:?}",
                w.iteration, w.seed, w.window.views
            ),
        ));
    }
    Ok(w.clone())
}

/// Append the reports of iterations to a checkpoint's history.
pub fn extend_history(history: &mut Vec<serde_json::Value>, reports: &[IterReport]) -> Result<()> {
    for r in reports {
        history.push(serde_json::to_value(r).map_err(|e| Error::Other(e.to_string()))?);
    }
    Ok(())
}

/// Write an array as the `.npy` tensor `name` of `out` (in standard layout).
pub fn write_array<D: ndarray::Dimension>(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    name: &str,
    x: &ndarray::Array<f32, D>,
) -> Result<()> {
    let data = x.as_standard_layout();
    out.write_tensor(name, x.shape(), data.as_slice().expect("standard layout"))?;
    Ok(())
}

/// The iteration an artifact of the stage chain belongs to (`meta.iteration`, written by
/// `render-views --window` and carried along), or `None` for an artifact outside the
/// chain.
pub fn iteration_of(art: &Artifact) -> Result<Option<IterationWindow>> {
    match art.manifest.meta.get("iteration") {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(v) => serde_json::from_value(v.clone()).map(Some).map_err(|e| {
            Error::input(
                art.path(fantasystyle_schemas::MANIFEST_FILE),
                format!("meta.iteration: {e}"),
            )
        }),
    }
}

/// A stage's scene input: a scene artifact directory ([`read_scene`]), else a `.ply`, a
/// `.splat`, a `.spz` or a directory holding `scene.ply` ([`scene::read_scene_file`]).
pub fn load_scene(path: &Path) -> Result<Scene> {
    if is_artifact(path) {
        read_scene(path)
    } else {
        scene::read_scene_file(path)
    }
}

/// The `cameras.json` of any artifact that has one (views, targets, latents), at the
/// artifact's image size; also returns the file (for messages).
pub fn read_cameras(dir: &Path) -> Result<(Vec<Camera>, PathBuf)> {
    let a = Artifact::open_any(dir)?;
    let p = a.path("cameras.json");
    if !p.is_file() {
        return Err(Error::input(
            dir,
            format!(
                "artifact of kind `{}` holds no cameras.json",
                a.manifest.kind
            ),
        ));
    }
    Ok((camera::inria::read_inria(&p)?, p))
}

/// A stage's camera input for images of `width` x `height`: an artifact directory's
/// `cameras.json` ([`read_cameras`], rescaled like a camera file), else what
/// [`camera::load_cameras`] reads (`orbit:` specs around `bounds`, camera files and
/// directories).
pub fn load_cameras(spec: &str, bounds: &Bounds, width: u32, height: u32) -> Result<Vec<Camera>> {
    let path = Path::new(spec);
    if !spec.starts_with("orbit:") && is_artifact(path) {
        camera::check_size(width, height)?;
        let (cams, src) = read_cameras(path)?;
        return camera::fit_cameras(cams, &src, width, height);
    }
    camera::load_cameras(spec, bounds, width, height)
}

/// The scene at `path` for the evaluation report's 3D viewer, and the scene itself: a scene artifact or
/// directory with a `scene.spz`, or a `.spz` file, is embedded as it is (after reading it
/// back with [`scene::spz::parse_spz`]); any other scene ([`load_scene`]) is encoded as `.spz`.
pub fn read_viewer_scene(
    label: &str,
    path: &Path,
) -> Result<(crate::metrics::viewer::ViewerScene, Scene)> {
    let spz_file = if path.is_dir() {
        Some(path.join("scene.spz")).filter(|p| p.is_file())
    } else {
        let ext = path.extension().map(|e| e.to_ascii_lowercase());
        (ext.as_deref() == Some("spz".as_ref())).then(|| path.to_path_buf())
    };
    let (spz_bytes, scene, source) = match spz_file {
        Some(f) => {
            let b = std::fs::read(&f).map_err(|e| Error::io(&f, e))?;
            let s = scene::spz::parse_spz(&f, &b)?;
            (b, s, f.display().to_string())
        }
        None => {
            let s = load_scene(path)?;
            let b = scene::spz::encode_spz(path, &s)?;
            (b, s, format!("{} (as .spz)", path.display()))
        }
    };
    Ok((
        crate::metrics::viewer::ViewerScene {
            label: label.into(),
            source,
            gaussians: scene.len(),
            spz: spz_bytes,
        },
        scene,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fantasystyle_schemas::{ArtifactWriter, Producer};

    fn write(
        dir: &Path,
        kind: ArtifactKind,
        tensors: &[(&str, &[usize])],
        meta: serde_json::Value,
    ) {
        let mut w =
            ArtifactWriter::create(dir, kind, Producer::new("test", "0", serde_json::json!({})))
                .unwrap();
        for (name, shape) in tensors {
            let n = shape.iter().product::<usize>();
            let data: Vec<f32> = (0..n).map(|i| i as f32 * 0.01).collect();
            w.write_tensor(name, shape, &data).unwrap();
        }
        if kind == ArtifactKind::Views {
            w.write_bytes("cameras.json", b"[]").unwrap();
        }
        w.set_meta(meta);
        w.commit().unwrap();
    }

    #[test]
    fn readers_check_shapes_and_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        let v = d.path().join("views");
        let planes: &[(&str, &[usize])] = &[
            ("rgb.npy", &[2, 4, 6, 3]),
            ("depth.npy", &[2, 4, 6]),
            ("alpha.npy", &[2, 4, 5]),
        ];
        write(&v, ArtifactKind::Views, planes, serde_json::json!({}));
        let e = read_views(&v).unwrap_err().to_string();
        assert!(e.contains("alpha.npy") && e.contains("[2, 4, 6]"), "{e}");
        // A views artifact is a valid targets input; latents are not.
        let good: &[(&str, &[usize])] = &[
            ("rgb.npy", &[2, 4, 6, 3]),
            ("depth.npy", &[2, 4, 6]),
            ("alpha.npy", &[2, 4, 6]),
        ];
        let v2 = d.path().join("views2");
        write(&v2, ArtifactKind::Views, good, serde_json::json!({}));
        let views = read_views(&v2).unwrap();
        assert_eq!(views.dim(), (2, 4, 6));
        assert_eq!(views.rgb[[1, 3, 5, 2]], (2 * 4 * 6 * 3 - 1) as f32 * 0.01);
        assert_eq!(read_targets(&v2).unwrap().rgb, views.rgb);
        let l = d.path().join("lat");
        write(
            &l,
            ArtifactKind::Latents,
            &[("latents.npy", &[2, 4, 1, 2])],
            serde_json::json!({}),
        );
        assert_eq!(read_latents(&l).unwrap().dim(), (2, 4, 1, 2));
        let e = read_targets(&l).unwrap_err().to_string();
        assert!(e.contains("`targets` or `views`"), "{e}");
        // Noised latents: one shape for the three tensors, and a timestep.
        let z: &[usize] = &[2, 4, 1, 2];
        let n = d.path().join("noised");
        let parts: &[(&str, &[usize])] = &[
            ("z_src.npy", z),
            ("z_tgt.npy", z),
            ("eps.npy", &[2, 4, 2, 1]),
            ("eps_shared.npy", &[4, 1, 2]),
        ];
        write(
            &n,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({"timestep": 7}),
        );
        let e = read_noised_latents(&n).unwrap_err().to_string();
        assert!(e.contains("eps.npy") && e.contains("z_src.npy"), "{e}");
        let parts: &[(&str, &[usize])] = &[
            ("z_src.npy", z),
            ("z_tgt.npy", z),
            ("eps.npy", z),
            ("eps_shared.npy", &[4, 1, 2]),
        ];
        let n2 = d.path().join("noised2");
        write(
            &n2,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({}),
        );
        let e = read_noised_latents(&n2).unwrap_err().to_string();
        assert!(e.contains("meta.timestep"), "{e}");
        let n3 = d.path().join("noised3");
        write(
            &n3,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({"timestep": 7}),
        );
        let nl = read_noised_latents(&n3).unwrap();
        assert_eq!((nl.timestep, nl.eps_shared.dim()), (7, (4, 1, 2)));
    }

    #[test]
    fn viewer_scene_embeds_spz_files_as_written() {
        let d = tempfile::tempdir().unwrap();
        let s = crate::sample::sample_scene(0);
        let spz_path = d.path().join("s.spz");
        scene::spz::write_spz(&spz_path, &s).unwrap();
        let (v, back) = read_viewer_scene("original", &spz_path).unwrap();
        assert_eq!(v.spz, std::fs::read(&spz_path).unwrap());
        assert_eq!(back.len(), s.len());
        let ply = d.path().join("s.ply");
        crate::scene::ply::write_ply(&ply, &s).unwrap();
        let (v, _) = read_viewer_scene("stylized", &ply).unwrap();
        assert!(v.source.ends_with("(as .spz)"));
        assert_eq!(scene::spz::parse_spz(&ply, &v.spz).unwrap().len(), s.len());
        let bad = d.path().join("bad.spz");
        std::fs::write(&bad, b"nope").unwrap();
        assert!(
            read_viewer_scene("x", &bad)
                .unwrap_err()
                .to_string()
                .contains("bad.spz")
        );
    }
}

//! The stage chain's artifacts (`render-views --window` -> `encode-latents` ->
//! `mvfc-filter` -> `csd-step` -> `update-gaussians`): the latents, the noised latents and
//! the targets of one iteration, and the iteration's identity every one of them records
//! in `meta.iteration` ([`IterationWindow`]), so that each stage replays the same draws
//! (FantasyStyle Sec. 4, one iteration as five stages).

use super::{read_rgb, read4};
use crate::camera::path::{ViewPath, Window};
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use ndarray::{Array3, Array4};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Which iteration an artifact of the chain belongs to, and its window: recorded by
/// `render-views --window` and carried along in `meta.iteration` of every artifact of the
/// iteration, so that later stages replay the same draws.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IterationWindow {
    /// Seed of the run.
    pub seed: u64,
    /// Iterations done before this one (the iteration's index, from 0).
    pub iteration: u64,
    /// The camera path the window lies on.
    pub path: ViewPath,
    /// The window's views (camera indices in path order) and whether it is circular.
    pub window: Window,
}

impl IterationWindow {
    /// Iteration `iteration` of `seed` on an open path of `n` views whose window is the
    /// whole path (what the draws give for it): the iteration of artifacts outside the
    /// stage chain, which record none.
    pub fn whole_open_path(n: usize, seed: u64, iteration: u64) -> IterationWindow {
        IterationWindow {
            seed,
            iteration,
            path: ViewPath {
                len: n,
                closed: false,
            },
            window: Window {
                views: (0..n).collect(),
                circular: false,
            },
        }
    }
}

/// What the targets asked for, over covered pixels (alpha > 0.5).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetStats {
    /// RMS of the image change Delta.
    pub delta_rms: f64,
    /// Fraction of covered target colours clipped (<= 0.02 or >= 0.98 in every channel).
    pub clipped: f64,
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

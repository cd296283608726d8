//! `render-views`: render a scene from a set of cameras into a `views` artifact.
//!
//! Output (schema `views` v1): `rgb.npy` `[N,H,W,3]` f32 composited over the background
//! and clamped to `[0,1]` (3DGS colours `max(0, SH + 0.5)` have no upper bound; INRIA clamps
//! the same way when it saves renders), `depth.npy` `[N,H,W]` (expected depth, not divided by alpha), `alpha.npy`
//! `[N,H,W]`, `cameras.json` (INRIA format, at W x H), and `view_000.png`.. previews.
//! The manifest records the scene and cameras as inputs (hashes) and the parameters.
//!
//! With `--window N` it renders one iteration's window for the stage chain instead: the
//! N adjacent views of the `--cameras` path that `distill`'s iteration draws from
//! (`--seed`, the iteration count of the `--scene` checkpoint; [`crate::distill::step::Draws`]),
//! with the colour fit's renderer as `distill` renders them
//! ([`crate::distill::step::render_window`]: `rgb.npy` NOT clamped, colours have no upper
//! bound), `cameras.json` of those views, and the iteration in `meta.iteration`.

use super::{Background, SceneInput, Threads};
use crate::camera::inria;
use crate::camera::path::ViewPath;
use crate::distill::Progress;
use crate::distill::checkpoint::load_progress;
use crate::distill::step::{Draws, render_window};
use crate::optim::{ColourFit, FitParams};
use crate::render::{RenderOptions, render};
use crate::{Camera, Error, Result, Scene};
use fantasystyle_schemas::{ArtifactKind, Producer, TensorStream};
use std::path::PathBuf;

/// Render a splat scene from a set of cameras into a views artifact (rgb, depth and
/// alpha as .npy, INRIA cameras.json, PNG previews).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "render-views", version)]
pub struct Args {
    #[command(flatten)]
    pub input: SceneInput,
    /// Image width in pixels (> 0).
    #[arg(long)]
    pub width: u32,
    /// Image height in pixels (> 0).
    #[arg(long)]
    pub height: u32,
    /// Output artifact directory (written atomically; replaces an existing artifact).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub background: Background,
    #[command(flatten)]
    pub threads: Threads,
    /// Render only the window of this many adjacent views that distill's iteration draws
    /// (from --seed and the iteration count of the --scene checkpoint; a plain scene is
    /// iteration 0), as distill renders them (rgb not clamped); for the stage chain.
    #[arg(long)]
    pub window: Option<usize>,
    /// Seed of the run whose window --window draws.
    #[arg(long, default_value_t = 0, requires = "window")]
    pub seed: u64,
}

/// Render every camera into `w` as it goes: views are rendered a window at a time on
/// all cores ([`crate::parallel::ordered`]) and each is appended to the streams of
/// `rgb.npy`, `depth.npy` and `alpha.npy` (and its PNG preview written) in view order
/// while the next window renders, so at most two windows of views are held (not all of
/// them) and the bytes are the same for any thread count. A progress bar counts views.
/// `colours`: the rgb of every view as the colour fit renders it (not clamped), which
/// replaces the renderer's clamped rgb (`--window`).
fn write_views(
    w: &mut fantasystyle_schemas::ArtifactWriter,
    [rgb, depth, alpha]: [&mut TensorStream<f32>; 3],
    scene: &Scene,
    cams: &[Camera],
    opts: &RenderOptions,
    colours: Option<&[Vec<f32>]>,
) -> Result<()> {
    let bar = indicatif::ProgressBar::new(cams.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} views {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message("render-views");
    let window = crate::parallel::window_for(rayon::current_num_threads());
    crate::parallel::ordered(
        cams.len(),
        window,
        |i| {
            let mut v = render(scene, &cams[i], opts)?;
            let (wd, h) = (cams[i].width as usize, cams[i].height as usize);
            if v.width != wd || v.height != h {
                return Err(Error::Other(format!(
                    "renderer returned {}x{} for a {wd}x{h} camera",
                    v.width, v.height
                )));
            }
            if let Some(c) = colours {
                v.rgb = c[i].clone();
            }
            let png = crate::imageio::encode_png_rgb(&v.rgb, wd, h)?;
            if colours.is_none() {
                v.rgb.iter_mut().for_each(|x| *x = x.clamp(0.0, 1.0));
            }
            Ok((v, png))
        },
        |i, (v, png)| {
            rgb.append(&v.rgb)?;
            depth.append(&v.depth)?;
            alpha.append(&v.alpha)?;
            w.write_bytes(&format!("view_{i:03}.png"), &png)?;
            bar.inc(1);
            Ok(())
        },
    )?;
    bar.finish_and_clear();
    Ok(())
}

/// The stage: load, render, write the artifact.
pub fn run(a: Args) -> Result<()> {
    if a.width == 0 || a.height == 0 || a.window == Some(0) {
        return Err(Error::param(format!(
            "image size {}x{}, window {:?}: --width, --height and --window must be positive",
            a.width, a.height, a.window
        )));
    }
    let start = match a.window {
        Some(_) => crate::timing::load(|| load_progress(&a.input.scene))?,
        None => Progress::fresh(a.input.load_scene()?),
    };
    let scene = &start.scene;
    let cams = a.input.load_cameras(scene, a.width, a.height)?;
    // The iteration's window (--window) of the cameras' path, or every camera.
    let window = a.window.map(|size| {
        let d = Draws::new(a.seed, start.iteration, ViewPath::of(&cams), size);
        d.window().clone()
    });
    let cams: Vec<Camera> = match &window {
        Some(w) => w.window.views.iter().map(|&v| cams[v].clone()).collect(),
        None => cams,
    };
    let mut params = serde_json::json!({
        "cameras": a.input.cameras, "width": a.width, "height": a.height,
        "background": a.background.rgb,
    });
    if window.is_some() {
        params["window"] = a.window.into();
        params["seed"] = a.seed.into();
    }
    let producer = Producer::new("render-views", crate::VERSION, params);
    let mut w = super::create_artifact(&a.out, ArtifactKind::Views, producer)?;
    a.input.add_inputs(&mut w)?;
    tracing::info!(
        "rendering {} Gaussians, {} views at {}x{}",
        scene.len(),
        cams.len(),
        a.width,
        a.height
    );
    let opts = RenderOptions {
        background: a.background.rgb,
    };
    // The window's colours as distill's colour fit renders them (not clamped).
    let colours = match &window {
        Some(_) => {
            let fit = FitParams {
                background: a.background.rgb,
                ..FitParams::default()
            };
            Some(a.threads.install(|| -> Result<_> {
                let fit = ColourFit::without_targets(scene, &cams, &fit)?;
                Ok(render_window(&fit, &(0..cams.len()).collect::<Vec<_>>()))
            })??)
        }
        None => None,
    };
    let (n, h, wd) = (cams.len(), a.height as usize, a.width as usize);
    // The tensors, then cameras.json, then the previews (the manifest's file order).
    let mut rgb = w.stream_tensor::<f32>("rgb.npy", &[n, h, wd, 3])?;
    let mut depth = w.stream_tensor::<f32>("depth.npy", &[n, h, wd])?;
    let mut alpha = w.stream_tensor::<f32>("alpha.npy", &[n, h, wd])?;
    w.write_json("cameras.json", &inria::to_inria(&cams))?;
    let streams = [&mut rgb, &mut depth, &mut alpha];
    a.threads
        .install(|| write_views(&mut w, streams, scene, &cams, &opts, colours.as_deref()))??;
    w.finish_stream(rgb)?;
    w.finish_stream(depth)?;
    w.finish_stream(alpha)?;
    let mut meta = serde_json::json!({
        "views": n, "width": wd, "height": h, "background": a.background.rgb,
        "camera_names": cams.iter().map(|c| c.name.clone()).collect::<Vec<_>>(),
    });
    if let Some(win) = &window {
        meta["iteration"] = serde_json::to_value(win).map_err(|e| Error::Other(e.to_string()))?;
    }
    w.set_meta(meta);
    crate::timing::io(|| w.commit())?;
    tracing::info!("wrote {}", a.out.display());
    Ok(())
}

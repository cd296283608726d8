//! The stages: one module per stage binary, and the plumbing every binary shares.
//!
//! Every stage has the same shape:
//! * `src/stages/X.rs` owns `Args` (clap derive; its doc comments are the `--help`) and
//!   `pub fn run(args: Args) -> Result<T>`, which does the stage's work through the
//!   library (`T` is what tests want to see: a report, the metrics, or `()`);
//! * the binary `stages/X.rs` is one line, `run_main(X::run)`: parse the flags, set up
//!   logging, run, print the error chain and map it to an exit code ([`run_main`]).
//!
//! Flags several stages share are clap groups flattened into their `Args`:
//! [`SceneInput`] (`--scene`, `--cameras`), [`Background`] (`--background`) and
//! [`Threads`] (`--threads`), [`DeviceArg`] (`--device`), [`PriorArgs`] (`--model`,
//! `--style`, `--prompt`, `--strength`, `--motif-scale` and the device flags of `distill`
//! and `csd-step`), [`MvfcArgs`] (`--no-mvfc`, `--mvfc-source`, `--gamma`, ... of
//! `distill` and `mvfc-filter`), [`TimestepArgs`] (`--timesteps`, `--anneal-iters` of
//! `distill` and `mvfc-filter`), [`ColourArgs`] (`--colour-loss`), [`SplitArgs`]
//! (`--split-px` of `distill` and `stylize-baseline`) and [`TextureArgs`]
//! (`--texture-weight`, ... of `distill` and `update-gaussians`);
//! a stage's own numerics parameters are the library's
//! parameter structs flattened the same way (`csd::CsdParams`, `mvfc::MvfcParams`).
//! A stage never imports another stage: what two stages need lives in the library
//! (artifact readers in [`crate::artifacts`], model lookup in [`crate::models`], phase
//! timing for the DAG runner in [`crate::timing`]).

use crate::artifacts::{load_cameras, load_scene};
use crate::{Camera, Error, Result, Scene};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub mod csd_step;
pub mod distill;
pub mod encode_latents;
pub mod evaluate;
pub mod make_sample;
pub mod mvfc_filter;
pub mod render_views;
pub mod stylize_baseline;
pub mod sweep;
pub mod update_gaussians;

/// Initialise tracing (RUST_LOG, default `info`) to stderr.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}

/// A stage binary's `main`: parse the flags into `A` (clap prints help or a usage error
/// and exits 2 itself), set up logging, call `run`, print the error chain and map it to
/// an exit code (see [`crate::error`]); report phase timing when the runner asks.
pub fn run_main<A: clap::Parser, T>(run: fn(A) -> Result<T>) -> ExitCode {
    let args = A::parse();
    init_logging();
    let start = std::time::Instant::now();
    match run(args) {
        Ok(_) => {
            crate::timing::write_if_requested(start.elapsed());
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            let mut src = std::error::Error::source(&e);
            while let Some(s) = src {
                eprintln!("  caused by: {s}");
                src = s.source();
            }
            ExitCode::from(e.exit_code())
        }
    }
}

/// `--scene` and `--cameras`: the scene and the views of it a stage works on.
#[derive(clap::Args, Debug, Clone)]
pub struct SceneInput {
    /// Scene: an INRIA .ply, a .splat, a .spz, or a scene artifact directory (its scene.ply).
    #[arg(long)]
    pub scene: PathBuf,
    /// Cameras: `orbit:N[,elev=DEG][,radius=R][,fov=DEG]` (around the scene's bounds), an
    /// INRIA cameras.json, a COLMAP sparse/0 directory, a nerfstudio transforms.json, or a
    /// views/targets artifact directory. Intrinsics read from files are rescaled to the
    /// image size the stage works at.
    #[arg(long)]
    pub cameras: String,
}

impl SceneInput {
    /// Load the scene (counted as loading time).
    pub fn load_scene(&self) -> Result<Scene> {
        crate::timing::load(|| load_scene(&self.scene))
    }

    /// The cameras for `scene` at `width` x `height`.
    pub fn load_cameras(&self, scene: &Scene, width: u32, height: u32) -> Result<Vec<Camera>> {
        load_cameras(&self.cameras, &scene.bounds(), width, height)
    }

    /// Record both as inputs of the artifact being written.
    pub fn add_inputs(&self, w: &mut fantasystyle_schemas::ArtifactWriter) -> Result<()> {
        w.add_input("scene", &self.scene)?;
        add_cameras_input(w, &self.cameras)
    }
}

/// `--background`: the colour behind the Gaussians.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct Background {
    /// Background colour R,G,B in [0, 1] the Gaussians are composited over (to fit targets,
    /// use the one they were rendered with).
    #[arg(long = "background", value_name = "R,G,B", default_value = "0,0,0", value_parser = parse_rgb)]
    pub rgb: [f32; 3],
}

/// `--threads`.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct Threads {
    /// Worker threads: the rasterizer's and the numerics' pool, or onnxruntime's intra-op
    /// threads (0 = all cores).
    #[arg(long = "threads", value_name = "THREADS", default_value_t = 0)]
    pub n: usize,
}

impl Threads {
    /// `n` threads.
    pub fn new(n: usize) -> Threads {
        Threads { n }
    }

    /// Run `f` on a pool of this many threads ([`with_threads`]).
    pub fn install<T: Send>(self, f: impl FnOnce() -> T + Send) -> Result<T> {
        with_threads(self.n, f)
    }
}

/// `--device`: where a model's ONNX graphs run.
#[derive(clap::Args, Debug, Clone, Copy, Default)]
pub struct DeviceArg {
    /// Execution provider of the model's graphs: cpu, cuda, cuda:N, tensorrt or
    /// tensorrt:N (GPU N; needs onnxruntime's GPU build, see README "Running on a GPU").
    #[arg(long = "device", value_name = "DEVICE", default_value = "cpu")]
    pub device: crate::runtime::Device,
}

/// `--model`, `--style`, `--prompt`, `--strength`, `--device`, `--unet-batch`: the prior a
/// distilling stage (`distill`, `csd-step`) opens, and how.
#[derive(clap::Args, Debug, Clone)]
pub struct PriorArgs {
    /// Model directory with model.json (e.g. vendor/models/stylizer,
    /// vendor/models/gaussian-prior, an export of scripts/export_models.py).
    #[arg(long)]
    pub model: PathBuf,
    /// Style image (PNG or JPEG, shorter side >= 64 px).
    #[arg(long)]
    pub style: PathBuf,
    /// The prompt P: any text for a model with a text encoder (else one of its exported
    /// prompts); empty or absent: the model's first exported prompt. Ignored by the
    /// stylizer.
    #[arg(long)]
    pub prompt: Option<String>,
    /// Style strength in [0, 1]: 0 leaves the scene unchanged, 1 is the full style.
    #[arg(long, default_value_t = 1.0)]
    pub strength: f32,
    /// Motif scale of the stylizer prior: the render is enlarged this many times before
    /// the network and reduced after, so strokes and motifs come out this much smaller
    /// on the object (1 = as the network draws them at the render's size).
    #[arg(long, default_value_t = 1.0)]
    pub motif_scale: f32,
    #[command(flatten)]
    pub device: DeviceArg,
    /// Most UNet rows per call (rows = views x conditionings; 0 = automatic: all, unless
    /// the first level's attention scores would pass 2^31 floats, as SD 1.5 at 64x64
    /// latents with more than 4 rows).
    #[arg(long, default_value_t = 0)]
    pub unet_batch: usize,
}

impl PriorArgs {
    /// Check the flags and read the style image (before anything slow).
    pub fn load_style(&self) -> Result<crate::imageio::Image> {
        if !(0.0..=1.0).contains(&self.strength) {
            return Err(Error::param(format!(
                "--strength must be in [0, 1], got {}",
                self.strength
            )));
        }
        crate::imageio::load_style(&self.style, crate::imageio::MIN_STYLE_SIDE)
    }

    /// Open the prior with the style image `style` and `threads` intra-op threads
    /// (counted as loading time).
    pub fn open(
        &self,
        style: &crate::imageio::Image,
        threads: Threads,
    ) -> Result<Box<dyn crate::prior::Prior>> {
        let opts = crate::prior::PriorOptions {
            style_image: Some(style.to_chw().insert_axis(ndarray::Axis(0))),
            prompt: self.prompt.clone().filter(|p| !p.is_empty()),
            threads: threads.n,
            strength: Some(self.strength),
            motif_scale: Some(self.motif_scale),
            device: self.device.device,
            unet_batch: self.unet_batch,
            ..Default::default()
        };
        crate::timing::load(|| crate::prior::open(&self.model, &opts))
    }

    /// The model's `model.json` (the model directory's, or `--model` itself if a file).
    pub fn manifest_path(&self) -> PathBuf {
        model_manifest(&self.model)
    }

    /// Record the style image and the model's manifest as inputs of an artifact.
    pub fn add_inputs(&self, w: &mut fantasystyle_schemas::ArtifactWriter) -> Result<()> {
        w.add_input("style", &self.style)?;
        w.add_input("model", &self.manifest_path())?;
        Ok(())
    }

    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "strength": self.strength, "prompt": self.prompt, "motif_scale": self.motif_scale,
            "device": self.device.device.to_string(), "unet_batch": self.unet_batch,
        })
    }
}

/// `--no-mvfc`, `--mvfc-source` and MVFC's parameters: how the loop (`distill`,
/// `mvfc-filter`) filters the noisy latents of the two branches.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct MvfcArgs {
    /// Skip MVFC (the paper's "w/o MVFC" ablation).
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub no_mvfc: bool,
    /// Filter the source branch with MVFC too (false: the target only, as in the paper,
    /// which moves the scene even when the style is its own look).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, num_args = 0..=1, default_missing_value = "true")]
    pub mvfc_source: bool,
    #[command(flatten)]
    pub params: crate::mvfc::MvfcParams,
}

impl MvfcArgs {
    /// The filter (`None`: without MVFC), checked.
    pub fn filter(&self) -> Result<Option<crate::mvfc::MvfcParams>> {
        self.params.validate()?;
        Ok((!self.no_mvfc).then_some(self.params))
    }

    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "mvfc": !self.no_mvfc, "mvfc_source": self.mvfc_source, "gamma": self.params.gamma,
            "d_s": self.params.d_s, "d_t": self.params.d_t,
        })
    }
}

/// `--timesteps`, `--anneal-iters`: the set an iteration's timestep is drawn from and
/// how (`distill`, `mvfc-filter`).
#[derive(clap::Args, Debug, Clone)]
pub struct TimestepArgs {
    /// Timestep set MIN:MAX:COUNT (default: the model's own set).
    #[arg(long)]
    pub timesteps: Option<String>,
    /// Anneal the timestep from coarse to fine over this many iterations in total (the
    /// whole run, all chunks: t_max falls linearly to the set's smallest); 0 = draw
    /// uniformly from the whole set every iteration.
    #[arg(long, default_value_t = 0)]
    pub anneal_iters: u64,
}

impl TimestepArgs {
    /// The set: `--timesteps` for the model's noise schedule `cfg`, else `model_set`.
    pub fn set(
        &self,
        cfg: &crate::scheduler::SchedulerConfig,
        model_set: crate::scheduler::TimestepSet,
    ) -> Result<crate::scheduler::TimestepSet> {
        match &self.timesteps {
            Some(spec) => crate::scheduler::TimestepSet::parse(spec, cfg),
            None => Ok(model_set),
        }
    }

    /// How the timestep is drawn.
    pub fn schedule(&self) -> crate::distill::TimestepSchedule {
        if self.anneal_iters > 0 {
            crate::distill::TimestepSchedule::Anneal {
                total: self.anneal_iters,
            }
        } else {
            crate::distill::TimestepSchedule::Random
        }
    }

    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({ "timesteps": self.timesteps, "anneal_iters": self.anneal_iters })
    }
}

/// `--colour-loss`: the colour step's loss against the targets (`distill`,
/// `update-gaussians` on one iteration's targets).
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct ColourArgs {
    /// The colour step's loss: l2 passes the prior's change with its magnitude (the
    /// paper's gradient), l1 only its sign.
    #[arg(long, value_enum, default_value = "l2")]
    pub colour_loss: crate::distill::ColourLoss,
}

impl ColourArgs {
    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({ "colour_loss": self.colour_loss })
    }
}

/// `--split-px`: split the scene's long Gaussians before stylizing it
/// ([`crate::distill::split`]; `distill`, `stylize-baseline`).
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct SplitArgs {
    /// Before stylizing, split every Gaussian longer than this many render pixels at the
    /// object (2 sigma along its longest axis; one pixel is the style projection's: the
    /// object centre's depth over the focal length, median over the cameras) in two along
    /// that axis, for up to 8 rounds and 16x the Gaussians, the longest first
    /// (`src/scene/split.rs`; not part of FantasyStyle):
    /// with the geometry frozen, a colour changes only as finely as the Gaussians that
    /// carry it. Each pair keeps its parent's mean and covariance, so the renders stay
    /// close; the result has more Gaussians. 0: off. In `distill`, only with --scene (a
    /// resumed checkpoint is split already).
    #[arg(long, default_value_t = 0.0)]
    pub split_px: f64,
}

/// Rounds of `--split-px`: one Gaussian becomes at most 2^8 (the rounds stop earlier
/// once none is above the length; each shortens the axis it splits by 0.7).
pub const SPLIT_ROUNDS: usize = 8;

/// `--split-px` makes at most this many times the scene's Gaussians (the longest split
/// first once a round would pass it): a length far below the scene's Gaussians, or a
/// scene of floaters, cannot exhaust the memory. 2 px gives 2.6x on the plant, 4x on
/// fish_10k, 8.7x on the sample; 1.5 px on the sample would give 32.6x.
pub const SPLIT_MAX_GROWTH: usize = 16;

impl SplitArgs {
    /// Whether a split was asked for; an error for a negative or non-finite length.
    pub fn wanted(&self) -> Result<bool> {
        if !(self.split_px.is_finite() && self.split_px >= 0.0) {
            return Err(Error::param("--split-px must be finite and >= 0 (0: off)"));
        }
        Ok(self.split_px > 0.0)
    }

    /// `scene` split for `cameras` (named by `cameras_from` in errors).
    pub fn split(&self, scene: &Scene, cameras: &[Camera], cameras_from: &Path) -> Result<Scene> {
        let _ph = crate::timing::span("split");
        let at = crate::distill::projection::Placement::of(scene, cameras)
            .map_err(|e| Error::input(cameras_from, e.to_string()))?;
        let max_extent = self.split_px * at.world_per_pixel;
        let cap = scene.len().saturating_mul(SPLIT_MAX_GROWTH);
        let (scene, report) =
            crate::distill::split::split_large(scene, max_extent, SPLIT_ROUNDS, cap);
        tracing::info!(
            "split to {} px ({max_extent:.3e} world units): {report}",
            self.split_px
        );
        Ok(scene)
    }
}

/// `--texture-weight`, `--texture-loss`, `--texture-loss-weights`, `--texture-layers`,
/// `--texture-style-size`, `--texture-views`, `--texture-downsample`, `--texture-vgg`:
/// the texture term of the colour step ([`crate::distill::texture`]; `distill`,
/// `update-gaussians` on one iteration's targets).
#[derive(clap::Args, Debug, Clone)]
pub struct TextureArgs {
    /// Weight of the texture term in the colour step (by default the masked VGG16 Gram
    /// loss at relu1_2 and relu2_2 of the object crop against the style image; see
    /// --texture-loss; not part of FantasyStyle, see src/distill/texture.rs); 0 = off,
    /// the paper's method alone.
    #[arg(long, default_value_t = 1.0)]
    pub texture_weight: f32,
    /// The style image is resized so its shorter side is this many pixels for the
    /// texture term (sets the motif scale against the render's pixels).
    #[arg(long, default_value_t = 256)]
    pub texture_style_size: usize,
    /// The texture term sees the object crop and the style box-averaged this many times
    /// smaller (motif scale on screen kept; D^2 times cheaper; periods under 2D pixels
    /// are left to the prior). 1 = full resolution.
    #[arg(long, default_value_t = 1)]
    pub texture_downsample: usize,
    /// The statistics the texture term matches (their losses add): `gram` (masked Gram
    /// matrices: which features occur, how often) and/or `nnfm` (ARF's nearest-neighbour
    /// feature matching over one VGG block: local arrangements, e.g. a brick's corner).
    #[arg(long, value_enum, value_delimiter = ',', default_value = "gram")]
    pub texture_loss: Vec<crate::distill::texture::TextureLoss>,
    /// Weight of each `--texture-loss` within the term, in the same order (default 1
    /// each; e.g. `--texture-loss nnfm,gram --texture-loss-weights 1,0.1`: the Gram
    /// gradient is otherwise much the larger and decides the picture).
    #[arg(long, value_delimiter = ',')]
    pub texture_loss_weights: Vec<f32>,
    /// VGG16 layers the texture term matches, with one `--texture-loss` (receptive
    /// fields: relu1_2 5 px, relu2_2 14 px, relu3_3 40 px; a deeper layer sees larger
    /// motifs and costs more); default relu1_2,relu2_2 for gram, relu3_1,relu3_2,relu3_3
    /// for nnfm (one block).
    #[arg(long, value_delimiter = ',')]
    pub texture_layers: Vec<crate::vgg::Layer>,
    /// The texture term on this many of each iteration's views (rotating; scaled so the
    /// gradient is the same in expectation); 0 = every view. 1 looks the same as every
    /// view at about 0.7x the CPU (BENCHMARKS.md "Texture").
    #[arg(long, default_value_t = 1)]
    pub texture_views: usize,
    /// VGG16 weights for the texture term (default: lpips/vgg16 in the models directory).
    #[arg(long)]
    pub texture_vgg: Option<PathBuf>,
}

impl TextureArgs {
    /// The texture term against the style image at `style` (VGG from `--texture-vgg` or
    /// the models directory; the style at `--texture-style-size`); `None` at weight 0.
    /// `loaded`: the image at `style` when the caller has read it already (`distill`
    /// reads it for the prior), so it is not read twice. The VGG runs on onnxruntime with
    /// `threads` intra-op threads.
    pub fn term(
        &self,
        style: Option<&Path>,
        loaded: Option<&crate::imageio::Image>,
        threads: Threads,
    ) -> Result<Option<crate::distill::texture::TextureTerm>> {
        use crate::vgg::Vgg16;
        if self.texture_weight == 0.0 {
            return Ok(None);
        }
        let Some(style) = style else {
            return Err(Error::param(format!(
                "the texture term (--texture-weight {}) needs the style image (--style); \
                 --texture-weight 0 is the paper's method alone",
                self.texture_weight
            )));
        };
        let parts = self.parts()?;
        let dir = match &self.texture_vgg {
            Some(p) => p.clone(),
            None => crate::models::model_path("lpips/vgg16")?,
        };
        let vgg = crate::timing::load(|| fast_vgg(Vgg16::load(&dir)?, threads))?;
        let img = match loaded {
            Some(img) => crate::vgg::prepare_style(img, self.texture_style_size, style)?,
            None => crate::vgg::prepare_style(
                &crate::imageio::read_rgb(style)?,
                self.texture_style_size,
                style,
            )?,
        };
        let mut term = crate::distill::texture::TextureTerm::new(
            vgg,
            &img,
            &parts,
            self.texture_weight,
            self.texture_downsample,
        )?;
        term.views = self.texture_views;
        Ok(Some(term))
    }

    /// Each `--texture-loss` with its layers (`--texture-layers`, only with one loss, or
    /// the loss's default layers) and its weight (`--texture-loss-weights`, default 1).
    pub fn parts(&self) -> Result<Vec<crate::distill::texture::Statistic>> {
        if !self.texture_loss_weights.is_empty()
            && self.texture_loss_weights.len() != self.texture_loss.len()
        {
            return Err(Error::param(format!(
                "--texture-loss-weights gives {} weights for {} --texture-loss values; give \
                 one per loss, in the same order",
                self.texture_loss_weights.len(),
                self.texture_loss.len()
            )));
        }
        if !self.texture_layers.is_empty() && self.texture_loss.len() != 1 {
            return Err(Error::param(format!(
                "--texture-layers goes with one --texture-loss, got {} losses; each loss \
                 then uses its default layers",
                self.texture_loss.len()
            )));
        }
        Ok(self
            .texture_loss
            .iter()
            .enumerate()
            .map(|(i, &loss)| {
                let layers = if self.texture_layers.is_empty() {
                    loss.default_layers()
                } else {
                    self.texture_layers.clone()
                };
                crate::distill::texture::Statistic {
                    loss,
                    layers,
                    weight: self.texture_loss_weights.get(i).copied().unwrap_or(1.0),
                }
            })
            .collect())
    }

    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "texture_weight": self.texture_weight,
            "texture_loss": self.texture_loss,
            "texture_loss_weights": self.texture_loss_weights,
            "texture_style_size": self.texture_style_size,
            "texture_downsample": self.texture_downsample,
            "texture_views": self.texture_views,
            "texture_layers": self.texture_layers.iter().map(|l| l.name()).collect::<Vec<_>>(),
        })
    }
}

/// Merge the fields of JSON objects into one (later ones win), for producer parameters.
pub fn merge_params(parts: &[serde_json::Value]) -> serde_json::Value {
    let mut out = serde_json::Map::new();
    for p in parts {
        if let serde_json::Value::Object(m) = p {
            out.extend(m.clone());
        }
    }
    serde_json::Value::Object(out)
}

/// A model's `model.json`: `model` itself if it is a file, else `model/model.json`.
pub fn model_manifest(model: &Path) -> PathBuf {
    if model.is_file() {
        model.to_path_buf()
    } else {
        model.join("model.json")
    }
}

/// `vgg` on onnxruntime with `threads` ([`crate::vgg::Vgg16::on_onnxruntime`]), or, when
/// the onnxruntime library is not installed, on the Rust engine (the same passes, about
/// 1.7x slower) with a warning.
pub fn fast_vgg(vgg: crate::vgg::Vgg16, threads: Threads) -> Result<crate::vgg::Vgg16> {
    match crate::runtime::environment() {
        Ok(_) => vgg.on_onnxruntime(threads.n),
        Err(Error::Missing(why)) => {
            tracing::warn!("VGG16 runs on its slower Rust engine: {why}");
            Ok(vgg)
        }
        Err(e) => Err(e),
    }
}

/// Run `f` on a rayon pool of `threads` threads (0 = all cores).
pub fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> Result<T> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::Other(format!("cannot start {threads} threads: {e}")))?;
    Ok(pool.install(f))
}

/// Start an artifact at `out`, turning a failure (e.g. `--out` below a regular file, a
/// read-only directory) into an I/O error that names `out`. An existing artifact at
/// `out` is replaced on commit; a non-empty directory that is not an artifact is refused
/// by `ArtifactWriter::create` and reported here as a parameter error.
pub fn create_artifact(
    out: &Path,
    kind: fantasystyle_schemas::ArtifactKind,
    producer: fantasystyle_schemas::Producer,
) -> Result<fantasystyle_schemas::ArtifactWriter> {
    fantasystyle_schemas::ArtifactWriter::create(out, kind, producer).map_err(|e| {
        let kind = match &e {
            fantasystyle_schemas::SchemaError::Io { source, .. } => source.kind(),
            // A non-artifact directory that must not be replaced: a parameter error.
            fantasystyle_schemas::SchemaError::Invalid { .. } => {
                return Error::param(format!("--out {}: {e}", out.display()));
            }
            _ => std::io::ErrorKind::Other,
        };
        Error::io(
            out,
            std::io::Error::new(kind, format!("cannot create the output artifact: {e}")),
        )
    })
}

/// Record the `--cameras` spec as an input: a camera file or directory by its hash, a
/// generated `orbit:` spec by the hash of its text.
pub fn add_cameras_input(w: &mut fantasystyle_schemas::ArtifactWriter, spec: &str) -> Result<()> {
    if spec.starts_with("orbit:") {
        w.add_input_hash(
            "cameras",
            spec,
            blake3::hash(spec.as_bytes()).to_hex().to_string(),
        );
    } else {
        w.add_input("cameras", Path::new(spec))?;
    }
    Ok(())
}

/// Parse `R,G,B` (each in [0, 1]) for `--background`.
pub fn parse_rgb(s: &str) -> std::result::Result<[f32; 3], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("`{s}` is not R,G,B"))?;
    match v.as_slice() {
        [r, g, b] if v.iter().all(|x| (0.0..=1.0).contains(x)) => Ok([*r, *g, *b]),
        _ => Err(format!(
            "`{s}`: expected three values in [0, 1], e.g. 1,1,1"
        )),
    }
}

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
//! [`SceneInput`] (`--scene`, `--cameras`), [`Background`] (`--background`),
//! [`Threads`] (`--threads`), [`DeviceArg`] (`--device`), [`PriorArgs`] (`--model`,
//! `--style`, `--prompt` and the device of `distill` and `csd-step`) and [`ConfigArgs`]
//! (`--preset`, `--config`, `--set`: the method's configuration,
//! [`crate::config`], which every stage of the method reads: one type, one
//! default per key).
//! A stage never imports another stage: what two stages need lives in the library
//! (artifact readers in [`crate::artifacts`], model lookup in [`crate::models`], phase
//! timing for the DAG runner in [`crate::timing`]).

use crate::artifacts::load_scene;
use crate::camera::load_cameras;
use crate::{Camera, Error, Result, Scene};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub mod csd_step;
pub mod distill;
pub mod encode_latents;
pub mod evaluate;
mod evaluate_reference;
pub mod make_sample;
pub mod mvfc_filter;
pub mod preview;
pub mod render_views;
pub mod select;
pub mod split;
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

/// `--preset`, `--config`, `--set`: the method's configuration
/// ([`crate::config`]), read by every stage of the method (`distill`, `split`,
/// and the stage chain's `mvfc-filter`, `csd-step`, `update-gaussians`); the keys and
/// their defaults are in `distill --help`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct ConfigArgs {
    /// Start from a preset: `default` (the sample DAG's: the patch prior's deterministic
    /// end guided by the scene's structure, `finish = "patches"`, `synthesis.control = 1`),
    /// `paper` (FantasyStyle alone: the CSD term, no start, no finish, no split: the
    /// defaults), `arf` (ARF's recipe on the loop: NNFM and a light Gram term, the
    /// projected start, the colour finish, a 2 px split), `motifs` (the default with the
    /// style's motifs laid out at their scale first, for smooth objects) or `shaded` (the
    /// default nearly unguided, the style's own layout with the object's shading and fine
    /// lines laid over it). The files are presets/NAME.toml.
    #[arg(long, value_name = "NAME")]
    pub preset: Option<String>,
    /// A configuration file (TOML, the keys listed below; a file may name its base with
    /// `preset = "NAME"`), or an inline table `{ key = value, ... }` (what a DAG passes for
    /// a params table); over the preset, in order.
    #[arg(long, value_name = "FILE|TABLE")]
    pub config: Vec<String>,
    /// One key, `KEY=VALUE` (a section's key dotted: `csd.guidance=0`, `terms.gram=0.2`);
    /// after the files, in order.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
}

impl ConfigArgs {
    /// The configuration's layers, in order.
    pub fn layers(&self) -> Vec<crate::config::Source> {
        use crate::config::Source;
        let mut l: Vec<Source> = self.preset.iter().cloned().map(Source::Preset).collect();
        l.extend(self.config.iter().cloned().map(Source::Config));
        l.extend(self.sets.iter().cloned().map(Source::Set));
        l
    }

    /// The configuration, checked.
    pub fn load(&self) -> Result<crate::config::Config> {
        crate::config::Config::layered(&self.layers())
    }
}

/// `--model`, `--style`, `--prompt`, `--device`: the prior a distilling stage (`distill`,
/// `csd-step`) opens, and where.
#[derive(clap::Args, Debug, Clone)]
pub struct PriorArgs {
    /// Model directory with model.json (e.g. priors/patch, vendor/models/stylizer,
    /// vendor/models/gaussian-prior, an export of scripts/export_models.py), read by the
    /// loop (iterations that call the prior); absent or empty: the configuration's
    /// `prior`, which a preset names (`patch`; the `arf` preset's `stylizer`).
    #[arg(long, value_parser = path_or_empty)]
    pub model: Option<PathBuf>,
    /// Style image (PNG or JPEG, shorter side >= 64 px).
    #[arg(long)]
    pub style: PathBuf,
    /// The prompt P: any text for a model with a text encoder (else one of its exported
    /// prompts); empty or absent: the model's first exported prompt. Ignored by the
    /// stylizer.
    #[arg(long)]
    pub prompt: Option<String>,
    #[command(flatten)]
    pub device: DeviceArg,
}

/// A path argument that may be empty (`--model ""`: a DAG's optional input left empty).
fn path_or_empty(s: &str) -> std::result::Result<PathBuf, std::convert::Infallible> {
    Ok(PathBuf::from(s))
}

impl PriorArgs {
    /// The model directory the loop calls: `--model` when given and not empty, else
    /// the configuration's `prior` ([`crate::models::prior_dir`]).
    pub fn model(&self, config: &crate::config::Config) -> Result<PathBuf> {
        match self.model.as_deref().filter(|m| !m.as_os_str().is_empty()) {
            Some(m) => Ok(m.to_path_buf()),
            None => crate::models::prior_dir(&config.prior),
        }
    }

    /// Read the style image (before anything slow).
    pub fn load_style(&self) -> Result<crate::imageio::Image> {
        crate::imageio::load_style(&self.style, crate::imageio::MIN_STYLE_SIDE)
    }

    /// Open the prior with the style image `style`, the configuration's strength, motif
    /// scale and UNet batch, and `threads` intra-op threads (counted as loading time).
    pub fn open(
        &self,
        style: &crate::imageio::Image,
        config: &crate::config::Config,
        threads: Threads,
    ) -> Result<Box<dyn crate::prior::Prior>> {
        let opts = crate::prior::PriorOptions {
            style_image: Some(style.to_chw().insert_axis(ndarray::Axis(0))),
            prompt: self.prompt.clone().filter(|p| !p.is_empty()),
            threads: threads.n,
            strength: Some(config.strength),
            motif_scale: Some(config.motif_scale),
            device: self.device.device,
            unet_batch: config.unet_batch,
            ..Default::default()
        };
        let model = self.model(config)?;
        crate::timing::load(|| crate::prior::open(&model, &opts))
    }

    /// Record the style image and, when the prior was called (`called`: [`Self::model`])
    /// or `--model` was given, the model's manifest as inputs of an artifact.
    pub fn add_inputs(
        &self,
        w: &mut fantasystyle_schemas::ArtifactWriter,
        config: &crate::config::Config,
        called: bool,
    ) -> Result<()> {
        w.add_input("style", &self.style)?;
        let given = self.model.as_ref().filter(|m| !m.as_os_str().is_empty());
        if called || given.is_some() {
            w.add_input("model", &model_manifest(&self.model(config)?))?;
        }
        Ok(())
    }

    /// The flags as producer parameters.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "prompt": self.prompt, "device": self.device.device.to_string(),
        })
    }
}

/// The timestep set of a run: the configuration's `timesteps` for the model's noise
/// schedule `cfg`, else the model's own `model_set`.
pub fn timestep_set(
    config: &crate::config::Config,
    cfg: &crate::scheduler::SchedulerConfig,
    model_set: crate::scheduler::TimestepSet,
) -> Result<crate::scheduler::TimestepSet> {
    match &config.timesteps {
        Some(spec) => crate::scheduler::TimestepSet::parse(spec, cfg),
        None => Ok(model_set),
    }
}

/// The configuration's VGG texture terms (`nnfm`, `gram`) against the style image at
/// `style` (VGG from `texture.vgg` or the models directory; the style at
/// `texture.style_size`); `None` without a VGG term. `loaded`: the image at `style` when
/// the caller has read it already (`distill` reads it for the prior), so it is not read
/// twice. The VGG runs on onnxruntime with `threads` intra-op threads.
pub fn texture_term(
    config: &crate::config::Config,
    style: &Path,
    loaded: Option<&crate::imageio::Image>,
    threads: Threads,
) -> Result<Option<crate::terms::texture::TextureTerm>> {
    use crate::vgg::Vgg16;
    let p = &config.texture;
    let parts = config.terms.statistics(&p.layers)?;
    if parts.is_empty() {
        return Ok(None);
    }
    let dir = match &p.vgg {
        Some(d) => d.clone(),
        None => crate::models::model_path("lpips/vgg16")?,
    };
    let vgg = crate::timing::load(|| fast_vgg(Vgg16::load(&dir)?, threads))?;
    let img = match loaded {
        Some(img) => crate::vgg::prepare_style(img, p.style_size, style)?,
        None => crate::vgg::prepare_style(&crate::imageio::read_rgb(style)?, p.style_size, style)?,
    };
    let mut term = crate::terms::texture::TextureTerm::new(vgg, &img, &parts, p.downsample)?;
    term.views = p.views;
    Ok(Some(term))
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

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Args;

    /// `--preset`'s help names every preset of the registry ([`crate::config::PRESETS`]: a
    /// new preset is one file and one line there, and `distill --help` is where a user looks
    /// for it).
    #[test]
    fn the_preset_help_names_every_preset() {
        let mut cmd = ConfigArgs::augment_args(clap::Command::new("distill"));
        let help = cmd.render_long_help().to_string();
        let names = crate::config::PRESETS.map(|(n, _)| n);
        for n in names {
            assert!(
                help.contains(&format!("`{n}`")),
                "`{n}` missing from:\n{help}"
            );
        }
    }
}

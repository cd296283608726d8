//! The model manifest: `model.json` in a model directory, describing the ONNX graphs of
//! a 2D prior and how to feed them.
//!
//! Parsing is strict (serde `deny_unknown_fields`; the `family` must be one of
//! [`super::families::FAMILIES`]); [`ModelManifest::load`] then checks the format and the
//! scheduler, and hands the rest to the family's own validation (for the ONNX diffusion
//! families, [`super::families::diffusion`]: positive sizes, scaling factor, and that
//! every referenced file exists). Checking the graphs' inputs and outputs against the manifest
//! happens when sessions are created (`prior::onnx`), so that a wrong name or shape is
//! reported with the graph and the input it concerns.
//!
//! Conventions of the graph contract (what `scripts/export_models.py` produces):
//! * VAE encoder: image `[B,3,H,W]` in [-1,1] -> posterior mean `[B,C,H/f,W/f]`
//!   (unscaled; an output with 2C channels is read as diffusers' mean+logvar moments and
//!   its first C channels taken). The prior multiplies by `vae_scaling_factor`.
//! * VAE decoder: unscaled latents `[B,C,h,w]` -> image `[B,3,fh,fw]` in [-1,1].
//! * UNet: `sample` `[B,C,h,w]`, `timestep` (int64 or float32, rank 0 or 1),
//!   `encoder_hidden_states` `[B,L,D]`, optional SDXL `text_embeds` `[B,P]` and
//!   `time_ids` `[B,6]`, optional IP-Adapter `image_tokens` `[B,N,D']` with optional
//!   per-row, per-layer image scales `image_scale` `[B,K]` (see [`ImageConditioning`]),
//!   optional ControlNet residuals; output eps (or v) `[B,C,h,w]`.
//! * Text encoder (optional, [`TextEncoderGraph`]): int64 token ids `[B,L]` per
//!   tokenizer -> hidden states `[B,L,D]` (+ pooled `[B,P]` for SDXL); without it only
//!   the prompts pre-embedded as `.npy` are available.
//! * Every floating-point input and output is float32, also for `precision: fp16`
//!   models (which keep fp16 weights inside and cast at the graph boundary).
//!
//! The `stylizer` family is the 2D style-transfer prior of the MVFC/CSD stages: its
//! manifest fields live in [`ModelManifest::stylizer`] (free-form JSON, parsed by that
//! prior), as the `patch` family's live in [`ModelManifest::patch`];
//! [`crate::prior::open`] dispatches on the family through [`super::families`].

use crate::scheduler::{Schedule, SchedulerConfig, TimestepSet};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::ControlKind;
pub use super::families::Family;

/// The manifest file's name inside a model directory.
pub const MODEL_FILE: &str = "model.json";
/// The manifest format this build reads.
pub const MODEL_FORMAT: &str = "fantasystyle-model/1";

/// Precision of the weights inside the graphs (their I/O is float32 either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    #[default]
    Fp32,
    Fp16,
}

/// A graph with one input and one output (VAE encoder or decoder).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimpleGraph {
    pub file: String,
    pub input: String,
    pub output: String,
}

/// The UNet's input and output names. Optional inputs the graph does not have are
/// omitted.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UnetGraph {
    pub file: String,
    pub sample: String,
    pub timestep: String,
    pub encoder_hidden_states: String,
    pub output: String,
    /// SDXL pooled text embedding input (`text_embeds`).
    #[serde(default)]
    pub text_embeds: Option<String>,
    /// SDXL micro-conditioning input (`time_ids`: original size, crop, target size).
    #[serde(default)]
    pub time_ids: Option<String>,
    /// IP-Adapter image-prompt token input.
    #[serde(default)]
    pub image_tokens: Option<String>,
    /// Per-row, per-layer IP-Adapter scale input `[B, K]` (K = the layers of
    /// [`ImageConditioning::layers`]).
    #[serde(default)]
    pub image_scale: Option<String>,
    /// ControlNet down-block residual inputs, in the ControlNet's output order.
    #[serde(default)]
    pub down_residuals: Vec<String>,
    /// ControlNet mid-block residual input.
    #[serde(default)]
    pub mid_residual: Option<String>,
}

/// A ControlNet: same conditioning inputs as the UNet plus the control image; its
/// outputs feed the UNet's residual inputs one to one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControlNetGraph {
    pub file: String,
    pub sample: String,
    pub timestep: String,
    pub encoder_hidden_states: String,
    /// The control image input `[B,3,H,W]` in `[0,1]`.
    pub cond: String,
    #[serde(default)]
    pub text_embeds: Option<String>,
    #[serde(default)]
    pub time_ids: Option<String>,
    pub down_outputs: Vec<String>,
    pub mid_output: String,
    /// Which control image it wants.
    pub control: ControlKind,
    /// conditioning scale multiplying every residual.
    #[serde(default = "one")]
    pub scale: f32,
}

fn one() -> f32 {
    1.0
}

/// The image-prompt encoder (IP-Adapter-Instruct style): the style image in, two token
/// sets out (style and content).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageEncoderGraph {
    pub file: String,
    pub input: String,
    /// The input is `[1, 3, size, size]`; the style image is resized (shorter side =
    /// size, bilinear) and centre-cropped.
    pub size: usize,
    /// Per-channel normalisation: (x - mean) / std with x in [0, 1].
    pub mean: [f32; 3],
    pub std: [f32; 3],
    pub style_output: String,
    pub content_output: String,
    /// Tokens meaning "no image" (`.npy` `[1,N,D']`); all zeros when absent.
    #[serde(default)]
    pub uncond_tokens: Option<String>,
}

/// Which scheme separates the style image's style from its content.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ConditioningScheme {
    /// Plain IP-Adapter: the same tokens at the same scale for style and content, so
    /// the two conditionings coincide (CSD's negative branch would cancel the style).
    Shared,
    /// InstantStyle: the tokens enter only the style-carrying attention layers for the
    /// style conditioning and only the layout-carrying ones for the content
    /// conditioning (Wang et al. 2024, "InstantStyle", Sec. 3).
    InstantstyleBlocks,
}

/// How the image tokens are routed through the UNet's IP-Adapter layers: one scale per
/// layer for each image conditioning (fed as the UNet's `image_scale` row; the
/// conditionings without the style image feed zeros).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageConditioning {
    pub scheme: ConditioningScheme,
    /// The IP-Adapter attention layers, in the order of the scale vectors.
    pub layers: Vec<String>,
    /// Scales of the style conditioning (PromptStyle).
    pub style: Vec<f32>,
    /// Scales of the content conditioning (Content).
    pub content: Vec<f32>,
    /// The diffusers `set_ip_adapter_scale` dictionaries the vectors were made from
    /// (informational).
    #[serde(default)]
    pub style_blocks: Option<serde_json::Value>,
    #[serde(default)]
    pub content_blocks: Option<serde_json::Value>,
}

/// One tokenizer feeding one input of the text encoder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TokenizerInput {
    /// The text encoder's input fed with this tokenizer's ids (int64 `[B, max_length]`).
    pub input: String,
    /// Hugging Face `tokenizer.json`, relative to the model directory.
    pub tokenizer: String,
    /// Sequence length: ids are truncated (keeping the start and end marks) and padded
    /// to it (77 for CLIP).
    pub max_length: usize,
    /// The padding id (CLIP: the end mark; SDXL's second tokenizer: `!`, id 0).
    pub pad_id: u32,
}

/// The text encoder graph: token ids in, the UNet's text conditioning out.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextEncoderGraph {
    pub file: String,
    pub tokenizers: Vec<TokenizerInput>,
    /// Hidden states `[B, L, D]` (the UNet's `encoder_hidden_states`).
    pub hidden_output: String,
    /// Pooled embedding `[B, P]` (SDXL's `text_embeds`).
    #[serde(default)]
    pub pooled_output: Option<String>,
}

/// A text embedding stored as `.npy`: hidden states `[1,L,D]` and, for SDXL, the pooled
/// embedding `[1,P]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextEmbedding {
    pub file: String,
    #[serde(default)]
    pub pooled: Option<String>,
}

/// A prompt whose embedding was computed at export time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PromptEmbedding {
    pub text: String,
    pub file: String,
    #[serde(default)]
    pub pooled: Option<String>,
}

/// The text conditioning: pre-embedded prompts, and optionally the text encoder that
/// embeds any prompt at run time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextConfig {
    /// The unconditional branch (SD 1.x: the empty prompt embedded; SDXL: zeros, as
    /// diffusers' `force_zeros_for_empty_prompt`).
    pub null: TextEmbedding,
    /// Exported prompts; the first is the default.
    pub prompts: Vec<PromptEmbedding>,
    /// The text encoder, for prompts not exported.
    #[serde(default)]
    pub encoder: Option<TextEncoderGraph>,
}

/// `model.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelManifest {
    pub format: String,
    pub family: Family,
    pub name: String,
    /// Latent channels C (4 for SD 1.x/2.x/XL).
    #[serde(default)]
    pub latent_channels: usize,
    /// 0.18215 for SD 1.x/2.x, 0.13025 for SDXL.
    #[serde(default)]
    pub vae_scaling_factor: f32,
    /// Image pixels per latent pixel (8 for SD VAEs).
    #[serde(default)]
    pub downsample: usize,
    #[serde(default)]
    pub precision: Precision,
    /// Precision of the VAE's weights when it differs from `precision` (fp16 exports
    /// keep a VAE that overflows in fp16, such as SDXL's, in fp32).
    #[serde(default)]
    pub vae_precision: Option<Precision>,
    pub scheduler: SchedulerConfig,
    #[serde(default)]
    pub vae_encoder: Option<SimpleGraph>,
    #[serde(default)]
    pub vae_decoder: Option<SimpleGraph>,
    #[serde(default)]
    pub unet: Option<UnetGraph>,
    #[serde(default)]
    pub controlnet: Option<ControlNetGraph>,
    #[serde(default)]
    pub image_encoder: Option<ImageEncoderGraph>,
    /// Routing of the image tokens for the style and content conditionings.
    #[serde(default)]
    pub image_conditioning: Option<ImageConditioning>,
    #[serde(default)]
    pub text: Option<TextConfig>,
    /// Fields of the `stylizer` family, parsed by the stylizer prior.
    #[serde(default)]
    pub stylizer: Option<serde_json::Value>,
    /// Fields of the `patch` family ([`crate::prior::patch::PatchConfig`]).
    #[serde(default)]
    pub patch: Option<serde_json::Value>,
}

/// A manifest with its directory, validated.
#[derive(Debug, Clone)]
pub struct ModelDir {
    pub dir: PathBuf,
    pub manifest_path: PathBuf,
    pub manifest: ModelManifest,
}

impl ModelDir {
    /// Path of a file named in the manifest.
    pub fn file(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// An error about this manifest.
    pub fn err(&self, reason: impl Into<String>) -> Error {
        Error::input(&self.manifest_path, reason)
    }
}

impl ModelManifest {
    /// Read and validate `dir/model.json` (or `dir` itself if it is the manifest file).
    pub fn load(dir: &Path) -> Result<ModelDir> {
        let (dir, mpath) = if dir.is_file() {
            let parent = dir.parent().unwrap_or(Path::new(".")).to_path_buf();
            (parent, dir.to_path_buf())
        } else {
            (dir.to_path_buf(), dir.join(MODEL_FILE))
        };
        if !dir.is_dir() {
            return Err(Error::input(&dir, "model directory does not exist"));
        }
        let text = std::fs::read_to_string(&mpath).map_err(|e| {
            if e.kind() == std::io::ErrorKind::NotFound {
                Error::input(
                    &mpath,
                    "model manifest not found (a model directory holds model.json)",
                )
            } else {
                Error::io(&mpath, e)
            }
        })?;
        let manifest: ModelManifest = serde_json::from_str(&text)
            .map_err(|e| Error::input(&mpath, format!("invalid model manifest: {e}")))?;
        let md = ModelDir {
            dir,
            manifest_path: mpath,
            manifest,
        };
        md.manifest.validate(&md)?;
        Ok(md)
    }

    fn validate(&self, md: &ModelDir) -> Result<()> {
        if self.format != MODEL_FORMAT {
            return Err(md.err(format!(
                "format is `{}`, this build reads `{MODEL_FORMAT}`",
                self.format
            )));
        }
        self.scheduler
            .validate()
            .map_err(|e| md.err(format!("scheduler: {e}")))?;
        // The family's own checks ([`super::families`]).
        (self.family.kind().validate)(md)
    }
}

/// An error naming `what` unless `file` (relative to the model directory) exists.
pub(crate) fn check_file(md: &ModelDir, what: &str, file: &str) -> Result<()> {
    let p = md.file(file);
    if !p.is_file() {
        return Err(md.err(format!("{what}: file {} does not exist", p.display())));
    }
    Ok(())
}

/// `count` timesteps spaced evenly over `[t_min, t_max]` (a stylizer manifest's
/// `stylizer.timesteps`, a patch manifest's `patch.timesteps`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimestepRange {
    pub t_min: usize,
    pub t_max: usize,
    pub count: usize,
}

/// The model's noise schedule and the fixed DDIM timestep set the method draws t from:
/// the family's own range if its manifest gives one (`stylizer.timesteps`,
/// `patch.timesteps`; [`super::families::FamilyKind::timesteps`]), else
/// [`TimestepSet::default_for`] its scheduler (50 steps over [0.02 T, 0.98 T]). `model`
/// is a model directory or its `model.json`; the manifest is read and validated by
/// [`ModelManifest::load`].
pub fn model_timesteps(model: &Path) -> Result<(Schedule, TimestepSet)> {
    let md = ModelManifest::load(model)?;
    let m = &md.manifest;
    let bad = |e: Error| md.err(e.to_string());
    let schedule = Schedule::new(m.scheduler.clone()).map_err(bad)?;
    let range = (m.family.kind().timesteps)(&md)?;
    let set = match range {
        Some(r) => TimestepSet::new(&m.scheduler, r.t_min, r.t_max, r.count),
        None => TimestepSet::default_for(&m.scheduler),
    }
    .map_err(bad)?;
    Ok((schedule, set))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, v: &serde_json::Value) {
        std::fs::write(dir.join(MODEL_FILE), serde_json::to_string(v).unwrap()).unwrap();
    }

    fn minimal(dir: &Path) -> serde_json::Value {
        for f in ["e.onnx", "d.onnx", "u.onnx", "n.npy", "p.npy"] {
            std::fs::write(dir.join(f), b"x").unwrap();
        }
        serde_json::json!({
            "format": MODEL_FORMAT, "family": "sd15", "name": "t",
            "latent_channels": 4, "vae_scaling_factor": 0.18215, "downsample": 8,
            "scheduler": SchedulerConfig::stable_diffusion(),
            "vae_encoder": {"file": "e.onnx", "input": "sample", "output": "latent"},
            "vae_decoder": {"file": "d.onnx", "input": "latent_sample", "output": "sample"},
            "unet": {"file": "u.onnx", "sample": "sample", "timestep": "timestep",
                     "encoder_hidden_states": "ehs", "output": "out_sample"},
            "text": {"null": {"file": "n.npy"}, "prompts": [{"text": "a", "file": "p.npy"}]}
        })
    }

    #[test]
    fn minimal_manifest_loads_and_errors_name_the_problem() {
        let d = tempfile::tempdir().unwrap();
        let v = minimal(d.path());
        write(d.path(), &v);
        let md = ModelManifest::load(d.path()).unwrap();
        assert_eq!(md.manifest.family, Family::named("sd15").unwrap());

        let check = |v: serde_json::Value, needle: &str| {
            write(d.path(), &v);
            let e = ModelManifest::load(d.path()).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("model.json"), "{e}");
        };
        let mut bad = v.clone();
        bad["unet"]["extra"] = serde_json::json!(1);
        check(bad, "unknown field `extra`");
        let mut bad = v.clone();
        bad["unet"].as_object_mut().unwrap().remove("file");
        check(bad, "missing field `file`");
        let mut bad = v.clone();
        bad.as_object_mut().unwrap().remove("unet");
        check(bad, "graph `unet` is missing");
        let mut bad = v.clone();
        bad["vae_decoder"]["file"] = "nope.onnx".into();
        check(bad, "nope.onnx does not exist");
        let mut bad = v.clone();
        bad["vae_scaling_factor"] = 0.13025.into();
        check(bad, "does not match family");
        let mut bad = v.clone();
        bad["family"] = "sd3".into();
        check(bad, "unknown variant `sd3`");
        let mut bad = v.clone();
        bad["unet"]["text_embeds"] = "text_embeds".into();
        check(bad, "needs a `pooled` file");
        let mut bad = v.clone();
        bad["scheduler"]["beta_end"] = 0.9.into();
        check(bad, "scheduler");
        std::fs::remove_file(d.path().join(MODEL_FILE)).unwrap();
        let e = ModelManifest::load(d.path()).unwrap_err().to_string();
        assert!(e.contains("not found"), "{e}");
    }

    #[test]
    fn image_conditioning_and_text_encoder_are_checked() {
        let d = tempfile::tempdir().unwrap();
        let mut v = minimal(d.path());
        for f in ["i.onnx", "t.onnx", "tok.json"] {
            std::fs::write(d.path().join(f), b"x").unwrap();
        }
        v["image_encoder"] = serde_json::json!({
            "file": "i.onnx", "input": "image", "size": 224, "mean": [0.5, 0.5, 0.5],
            "std": [0.5, 0.5, 0.5], "style_output": "tokens", "content_output": "tokens"});
        v["unet"]["image_tokens"] = "image_tokens".into();
        v["unet"]["image_scale"] = "ip_scale".into();
        v["image_conditioning"] = serde_json::json!({
            "scheme": "instantstyle-blocks", "layers": ["a", "b"],
            "style": [0.0, 1.0], "content": [1.0, 0.0]});
        v["text"]["encoder"] = serde_json::json!({
            "file": "t.onnx", "hidden_output": "hidden_states",
            "tokenizers": [{"input": "input_ids", "tokenizer": "tok.json",
                            "max_length": 77, "pad_id": 49407}]});
        write(d.path(), &v);
        let md = ModelManifest::load(d.path()).unwrap();
        let ic = md.manifest.image_conditioning.unwrap();
        assert_eq!(ic.scheme, ConditioningScheme::InstantstyleBlocks);
        let check = |v: serde_json::Value, needle: &str| {
            write(d.path(), &v);
            let e = ModelManifest::load(d.path()).unwrap_err().to_string();
            assert!(e.contains(needle) && e.contains("model.json"), "{e}");
        };
        let mut bad = v.clone();
        bad["image_conditioning"]["content"] = serde_json::json!([1.0]);
        check(bad, "2 layers, 2 style and 1 content scales");
        let mut bad = v.clone();
        bad["unet"].as_object_mut().unwrap().remove("image_scale");
        check(bad, "give both or neither");
        let mut bad = v.clone();
        bad["image_conditioning"]["scheme"] = "instruct".into();
        check(bad, "unknown variant `instruct`");
        let mut bad = v.clone();
        bad["text"]["encoder"]["tokenizers"][0]["tokenizer"] = "none.json".into();
        check(bad, "none.json does not exist");
        let mut bad = v.clone();
        bad["text"]["encoder"]["pooled_output"] = "pooled".into();
        check(bad, "names a pooled_output");
        let mut bad = v.clone();
        bad["text"]["encoder"]["tokenizers"][0]["max_length"] = 1.into();
        check(bad, "max_length 1");
    }

    #[test]
    fn stylizer_family_keeps_its_own_fields() {
        let d = tempfile::tempdir().unwrap();
        write(
            d.path(),
            &serde_json::json!({
                "format": MODEL_FORMAT, "family": "stylizer", "name": "magenta",
                "scheduler": SchedulerConfig::stable_diffusion(),
                "stylizer": {"file": "x.onnx"}
            }),
        );
        let md = ModelManifest::load(d.path()).unwrap();
        assert_eq!(md.manifest.stylizer.unwrap()["file"], "x.onnx");
    }
}

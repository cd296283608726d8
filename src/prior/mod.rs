//! The prior interface: everything the method asks of a 2D model.
//!
//! FantasyStyle (Sec. 4, CSD) needs, from a diffusion model: a VAE (encode renders to
//! latents z0, decode back), and noise predictions eps(z_t, t, c) under several
//! conditionings c, batched so that classifier-free guidance costs one call.
//! The families of [`families::FAMILIES`] (the `family` of a model directory's
//! `model.json`) implement [`Prior`]:
//!
//! * `sd15`, `sd21`, `sdxl`, `custom` ([`families::diffusion`]): real diffusion graphs
//!   (SD 1.5 / SDXL UNet, optional ControlNet and IP-Adapter image encoder) described by
//!   a model manifest, run by [`onnx`];
//! * `gaussian` ([`families::gaussian`]): the closed-form optimal denoiser for
//!   Gaussian-distributed latents (exact; shipped as tiny ONNX graphs with the real I/O
//!   contract, for tests);
//! * `stylizer` ([`families::stylizer`]): a feed-forward 2D style-transfer network used
//!   as an x0-predictor in pixel space (real weights, the CPU demo);
//! * `patch` ([`families::patch`]): the weight-free patch prior, whose clean-image model
//!   is the style image's patches ([`patch`]).
//!
//! [`open`] opens the prior of a model directory through its manifest's family.
//! Submodules: [`families`] (the registry), [`gaussian`] (closed form in Rust),
//! [`manifest`] (the model directory's `model.json`), [`onnx`] (the ONNX-backed
//! diffusion prior), [`stylizer`] (the 2D stylizer), [`patch`] (the patch prior),
//! [`session`] (ONNX sessions and their I/O checks, shared by both), [`preprocess`]
//! (image-encoder crops, ControlNet control images, shape checks), [`text`] (prompt
//! embeddings), [`cost`] (what a prior's calls cost).

pub mod cost;
pub mod families;
pub mod gaussian;
pub mod manifest;
pub mod onnx;
pub mod patch;
pub mod preprocess;
pub mod session;
pub mod stylizer;
pub mod text;

pub use manifest::model_timesteps;
pub use onnx::OnnxPrior;
pub use preprocess::control_image;

use crate::Result;
use crate::runtime::{Device, Optimization, SessionConfig};
use crate::scheduler::SchedulerConfig;
use manifest::ModelManifest;
use ndarray::{Array4, ArrayView4};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// How to open a prior.
#[derive(Debug, Clone, Default)]
pub struct PriorOptions {
    /// The style image `[1, 3, H, W]` in [0, 1], for the image-prompt encoder (needed by
    /// `Cond::PromptStyle` and `Cond::Content`).
    pub style_image: Option<Array4<f32>>,
    /// The prompt P: an exported prompt's text (the manifest's `text.prompts`, embedded
    /// at export time), or any text when the model has a text encoder; `None` = the
    /// first exported prompt.
    pub prompt: Option<String>,
    /// Intra-op threads per session (0 = onnxruntime's default).
    pub threads: usize,
    /// Graph optimisation level.
    pub optimization: Optimization,
    /// Largest VAE batch per call (0 = the whole batch at once).
    pub vae_batch: usize,
    /// Most UNet (and ControlNet) rows per call, rows = conditionings x latents (0 =
    /// automatic: as many as keep the first level's attention scores within 2^31 floats,
    /// see [`onnx::auto_unet_rows`]; all at once at SD's usual sizes up to 32x32 latents).
    pub unet_batch: usize,
    /// Execution provider of every session.
    pub device: Device,
    /// Style strength in [0, 1] (`None` = 1): how far the style conditioning moves from
    /// the content's own style. The stylizer interpolates style vectors
    /// (`(1 - strength) s(content) + strength s(style)`).
    pub strength: Option<f32>,
    /// Motif scale of a pixel-space stylizer (`None` = 1): the image is enlarged by this
    /// factor before the network sees it and reduced after, so the network's strokes and
    /// motifs, whose size in network pixels is fixed, come out this many times smaller on
    /// the object (StylizedGS's scale control). Diffusion priors ignore it.
    pub motif_scale: Option<f32>,
}

impl PriorOptions {
    /// How this prior's sessions are created.
    pub fn session_config(&self) -> SessionConfig {
        SessionConfig {
            threads: self.threads,
            optimization: self.optimization,
            device: self.device,
        }
    }
}

/// Open the prior in `model_dir` (a directory with `model.json`) through its manifest's
/// family ([`families::FamilyKind::open`]).
pub fn open(model_dir: &Path, opts: &PriorOptions) -> Result<Box<dyn Prior>> {
    let md = ModelManifest::load(model_dir)?;
    (md.manifest.family.kind().open)(md, opts)
}

/// Which control image a ControlNet wants; both can be made from our renders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ControlKind {
    /// Rendered depth, normalised per view to [0, 1] (near = 1, as MiDaS-style depth
    /// ControlNets expect), replicated to 3 channels.
    Depth,
    /// An edge map of the rendered RGB (Sobel gradient magnitude of the luminance, an
    /// approximation of the Canny maps edge ControlNets are trained on), 3 channels.
    Edges,
    /// The original render itself, RGB: the 2D stylizer takes the content's own style
    /// from it (a tile-ControlNet would take it too).
    Source,
    /// The original render as [`ControlKind::Source`] plus its coverage alpha as a fourth
    /// channel (`[B, 4, H, W]`): the patch prior's source model and structure guide, and
    /// which pixels are the object.
    SourceAlpha,
}

/// The conditioning sets of the paper's guidance terms (Sec. 4, CSD):
/// Phi_tgt = beta (eps(z, t, [P, style]) - eps(z, t, content)),
/// Phi_src = beta (eps(z, t, P) - eps(z, t, null)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Cond {
    /// Unconditional: empty prompt, no image tokens.
    Null,
    /// The text prompt P alone.
    Prompt,
    /// The prompt plus the style image's style tokens (positive branch of the target).
    PromptStyle,
    /// The style image's content tokens (negative branch of the target).
    Content,
}

/// Static facts about a prior.
#[derive(Debug, Clone, PartialEq)]
pub struct PriorInfo {
    /// Human-readable name, e.g. `sd15`, `gaussian`, `magenta-stylizer`.
    pub name: String,
    /// Latent channels C (4 for SD; 3 for a pixel-space prior).
    pub latent_channels: usize,
    /// Image pixels per latent pixel (8 for SD VAEs, 1 in pixel space).
    pub downsample: usize,
    /// The noise schedule the model was trained with.
    pub scheduler: SchedulerConfig,
    /// The control image `predict_eps` wants (`None`: the prior has no ControlNet and
    /// ignores `control`).
    pub control: Option<ControlKind>,
    /// `Some(why)` when the style conditioning (PromptStyle) and the content conditioning
    /// (Content) carry the same image information, so that CSD's target term
    /// beta (eps([P, style]) - eps(content)) would cancel the style image (plain
    /// IP-Adapter); [`crate::csd::check_mode`] then refuses `csd`.
    pub coinciding_style_content: Option<String>,
}

/// A 2D prior. Images are `[B, 3, H, W]` in [0, 1]; latents are `[B, C, H/f, W/f]`
/// already multiplied by the VAE scaling factor.
pub trait Prior: Send {
    fn info(&self) -> &PriorInfo;

    /// Encode images to latents (the VAE posterior mean times the scaling factor).
    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>>;

    /// Decode latents to images (not clamped).
    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>>;

    /// Noise predictions for `z_t` at training timestep `t`, one array per entry of
    /// `conds`, computed in a single batched call where the backend allows.
    /// `control` is the ControlNet's control image `[B, 3, H, W]` (e.g. rendered depth),
    /// ignored by priors without a ControlNet.
    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>>;

    /// True when the prior has no generative model of unstyled images, so its `Null` and
    /// `Content` predictions are the identity on the clean image (a feed-forward
    /// stylizer): CSD then uses the exact noise for those branches instead of asking the
    /// prior (see [`crate::csd`]).
    fn unconditional_is_identity(&self) -> bool {
        false
    }

    /// What the prior is made of, for a checkpoint's manifest (`pipeline inspect`): e.g.
    /// the patch prior's banks and its patch size per timestep. `None` (the default):
    /// nothing beyond the model directory.
    fn describe(&self) -> Option<serde_json::Value> {
        None
    }

    /// True when the `Content` prediction is the identity too (by default whenever the
    /// unconditional one is; a prior with a real content model returns false).
    fn content_is_identity(&self) -> bool {
        self.unconditional_is_identity()
    }

    /// For a prior whose `Content` model is a mixture of the identity (the exact
    /// unconditional model, [`Prior::content_is_identity`] true) and a model of the style
    /// image's layout: the layout model's clean estimate `[B, C, h, w]` and its
    /// responsibility `[B, 1, h, w]` in [0, 1] at `z_t`; CSD then takes
    /// eps(Content) = (1 - r) eps_exact + r eps_layout. `None` (the default): the
    /// identity alone.
    fn content_layout(
        &mut self,
        _z_t: ArrayView4<'_, f32>,
        _t: usize,
        _control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Option<(Array4<f32>, Array4<f32>)>> {
        Ok(None)
    }
}

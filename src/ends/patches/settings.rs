//! The settings of the patch synthesis ([`super::synthesize`]): the `[synthesis]` section
//! of the method's configuration, each key's meaning in its doc comment (`distill --help`).

use crate::{Error, Result};

/// The settings of the patch synthesis (the `[synthesis]` section of the method's
/// configuration; `finish = "patches"` runs it).
#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthesisParams {
    /// Levels, coarsest first: render pixels per synthesis pixel (a patch covers
    /// patch x level render pixels: 7 x 8 = 56 px places motifs of that size).
    #[arg(long, value_delimiter = ',', default_value = "8,4,2,1")]
    pub levels: Vec<usize>,
    /// Patch side in synthesis pixels (odd).
    #[arg(long, default_value_t = 7)]
    pub patch: usize,
    /// Step of the grid of the object's patches (synthesis pixels).
    #[arg(long, default_value_t = 2)]
    pub stride: usize,
    /// Step of the grid the style's patches are taken on at the finest level (coarser
    /// levels take every pixel).
    #[arg(long, default_value_t = 2)]
    pub style_stride: usize,
    /// E/M rounds per level.
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// Colour-fit steps per round (Adam, every view).
    #[arg(long, default_value_t = 8)]
    pub steps: usize,
    /// Adam learning rate of the SH DC colours in the fit.
    #[arg(long, default_value_t = 0.05)]
    pub lr: f32,
    /// Balance of the style's patch use, in [0, 1]: the exponent of the cells' marginal
    /// in the coupling of the object's patches to the style's cells (0: each patch its
    /// nearest; 1: every cell used in proportion to its share of the style).
    #[arg(long, default_value_t = 1.0)]
    pub balance: f32,
    /// PCA dimensions of the search.
    #[arg(long, default_value_t = 24)]
    pub pca_dims: usize,
    /// The structure guide's weight (ControlNet's role): how much the frozen source
    /// render's luminance, remapped to the style's, counts beside the colours in the
    /// match and the coupling (0: unguided; 1: a pixel's guide weighs like its three
    /// colour channels). See `guide.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub control: f32,
    /// The structure guide's share of the control: its weight in the match is `sqrt(3
    /// guide_weight control)`, where the edge guide and the detail layer follow `control`
    /// alone; below 1 the object's shading asks less of the style's layout while the edge
    /// guide and the layer keep its lines (1: the guide at the control's weight; the
    /// default preset sets 0.25; 0: the guide off, the edge guide and the layer alone).
    /// See `guide.rs`.
    #[arg(long, default_value_t = 1.0)]
    pub guide_weight: f32,
    /// The structure guide's scale: its luma blurred with this standard deviation (in
    /// synthesis pixels, at every level, the style's and the object's alike) before the
    /// match, so that it asks for the object's shading at the motif's scale and leaves the
    /// style free to draw its outlines inside (0: the pixel's own luma). See `guide.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub guide_blur: f32,
    /// The detail layer's weight: the source's fine luminance (its remapped luma minus
    /// that luma blurred by `detail_blur` render pixels) laid over the synthesised
    /// texture, which is matched without it (0: none; 1: the detail at the style's
    /// contrast). See `detail.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub detail: f32,
    /// The detail layer's scale: the standard deviation (render pixels) of the blur whose
    /// residue is the detail; also the scale below which the views' consensus leaves each
    /// view its own texture (`consensus`).
    #[arg(long, default_value_t = 4.0)]
    pub detail_blur: f32,
    /// The detail layer's line weight: its most gain where the object's fine structure
    /// is fainter than the style's own edges, and 1 / it the least where it is stronger
    /// (the strongest tenth of each matched; 1: the detail at the style's global
    /// contrast). See `detail.rs`.
    #[arg(long, default_value_t = 1.0)]
    pub line_weight: f32,
    /// The detail layer's ink: the object's strongest edges (the strongest tenth of its
    /// fine detail, and a pixel or two around them) raised until they are this many times
    /// the style's typical edge (the 75th percentile of its band-pass), never lowered, so
    /// a busy style's texture does not drown the object's creases and contours (0: off).
    /// See `detail.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub ink: f32,
    /// The detail layer's shading band: when above `detail_blur`, the layer also holds
    /// the source's shading between the two scales (its luma blurred by `detail_blur`
    /// minus that luma blurred by this many render pixels), at the style's contrast and
    /// without the line weight's gain, so a weak guide can leave the style's layout free
    /// and still show the object's volume (0: none). See `detail.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub shade_blur: f32,
    /// The edge guide's weight: at the object's strongest edges its band pass (its
    /// remapped luma less its blur of 2 synthesis pixels, raised to the style's edge
    /// strength) is matched beside the colours against the style's own band pass, so the
    /// style's own edges are chosen there; elsewhere the texture stays free (0: off; the
    /// default preset's 2 goes with a lighter detail layer, `detail = 0.75`). Its weight
    /// follows `control` (`sqrt(3 edges control)`). See `edges.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub edges: f32,
    /// The views' consensus: each round of the finest level, each view's texture target
    /// at a surface point becomes the mix of every view's target there, weighted by how
    /// face-on each view sees it to this power (0: off, each view its own; 8, the
    /// default preset's: mostly the most face-on views), so the views agree before the
    /// fit instead of being averaged by it; each view keeps its own band finer than
    /// `detail_blur`. See `consensus.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub consensus: f32,
    /// The `layout` start's cells across the object's largest extent (the motif scale it
    /// seeds; read by that start only). See src/ends/layout.rs.
    #[arg(long, default_value_t = 6.0)]
    pub motifs_across: f32,
    /// The motif scale from the object's size on screen: the style sized so that this
    /// many of its motif periods fit across the object's typical part (0: the style at
    /// `texture.style_size`). See src/ends/patches/scale.rs.
    #[arg(long, default_value_t = 0.0)]
    pub motifs_per_part: f32,
    /// The guidance scale at t -> 0: how far each patch moves from the scene's own
    /// (the source branch) toward its style patch (the style branch): 1 takes the style
    /// patch, 0 keeps the scene.
    #[arg(long, default_value_t = 1.0)]
    pub guidance: f32,
    /// The negative scale at t -> 0: the cost, in mean match distances, of a style patch
    /// that continues the piece a neighbouring patch copied (the content branch's
    /// prediction, the style image's own layout); higher copies smaller pieces. See
    /// `negative.rs`.
    #[arg(long, default_value_t = 0.0)]
    pub negative: f32,
}

impl Default for SynthesisParams {
    fn default() -> Self {
        crate::params::defaults()
    }
}

impl SynthesisParams {
    /// Checked ranges.
    pub fn validate(&self) -> Result<()> {
        if self.patch.is_multiple_of(2) || self.patch < 3 {
            return Err(Error::param("synthesis.patch must be odd and >= 3"));
        }
        if self.levels.is_empty() || self.levels.iter().any(|&s| s == 0 || s > 32) {
            return Err(Error::param("synthesis.levels: 1 to 32 each, at least one"));
        }
        if self.stride == 0 || self.style_stride == 0 || self.pca_dims == 0 {
            return Err(Error::param(
                "synthesis.stride, style_stride and pca_dims must be >= 1",
            ));
        }
        if !(self.lr.is_finite() && self.lr >= 0.0) {
            return Err(Error::param("synthesis.lr must be finite and >= 0"));
        }
        if !(0.0..=1.0).contains(&self.balance) {
            return Err(Error::param("synthesis.balance must lie in [0, 1]"));
        }
        if !(self.control.is_finite() && (0.0..=100.0).contains(&self.control)) {
            return Err(Error::param("synthesis.control must lie in [0, 100]"));
        }
        if !(self.guide_weight.is_finite() && (0.0..=100.0).contains(&self.guide_weight)) {
            return Err(Error::param("synthesis.guide_weight must lie in [0, 100]"));
        }
        if !(self.motifs_across.is_finite() && (1.0..=1000.0).contains(&self.motifs_across)) {
            return Err(Error::param(
                "synthesis.motifs_across must lie in [1, 1000]",
            ));
        }
        if !(self.motifs_per_part.is_finite() && (0.0..=100.0).contains(&self.motifs_per_part)) {
            return Err(Error::param(
                "synthesis.motifs_per_part must lie in [0, 100]",
            ));
        }
        if !(self.guidance.is_finite() && (0.0..=2.0).contains(&self.guidance)) {
            return Err(Error::param("synthesis.guidance must lie in [0, 2]"));
        }
        if !(self.consensus.is_finite() && (0.0..=64.0).contains(&self.consensus)) {
            return Err(Error::param("synthesis.consensus must lie in [0, 64]"));
        }
        if !(self.guide_blur.is_finite() && (0.0..=64.0).contains(&self.guide_blur)) {
            return Err(Error::param("synthesis.guide_blur must lie in [0, 64]"));
        }
        if !(self.detail.is_finite() && (0.0..=10.0).contains(&self.detail)) {
            return Err(Error::param("synthesis.detail must lie in [0, 10]"));
        }
        if !(self.line_weight.is_finite() && (1.0..=10.0).contains(&self.line_weight)) {
            return Err(Error::param("synthesis.line_weight must lie in [1, 10]"));
        }
        if !(self.edges.is_finite() && (0.0..=100.0).contains(&self.edges)) {
            return Err(Error::param("synthesis.edges must lie in [0, 100]"));
        }
        if !(self.ink.is_finite() && (0.0..=10.0).contains(&self.ink)) {
            return Err(Error::param("synthesis.ink must lie in [0, 10]"));
        }
        if !(self.detail_blur.is_finite() && (0.25..=64.0).contains(&self.detail_blur)) {
            return Err(Error::param("synthesis.detail_blur must lie in [0.25, 64]"));
        }
        if !(self.shade_blur == 0.0
            || (self.shade_blur.is_finite()
                && self.shade_blur > self.detail_blur
                && self.shade_blur <= 64.0))
        {
            return Err(Error::param(
                "synthesis.shade_blur must be 0 or lie in (synthesis.detail_blur, 64]",
            ));
        }
        if !(self.negative.is_finite() && (0.0..=100.0).contains(&self.negative)) {
            return Err(Error::param("synthesis.negative must lie in [0, 100]"));
        }
        Ok(())
    }
}

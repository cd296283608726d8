//! fantasystyle: restyle a trained 3D Gaussian Splatting scene after a style image by
//! distilling a 2D prior into the scene's colours (FantasyStyle, AAAI 2026).
//!
//! One module per concept; the stage binaries in `stages/` are one line each over
//! [`stages`]. Where to look:
//!
//! | module | what |
//! |---|---|
//! | [`scene`] | Gaussian scenes: INRIA `.ply`, `.splat`, Niantic's `.spz` |
//! | [`camera`] | cameras: INRIA `cameras.json`, COLMAP, nerfstudio, artifacts' `cameras.json`, generated orbits around [`geometry::Bounds`]; view paths |
//! | [`geometry`] | unit vectors, quaternions, look-at frames, bounds (on `glam`) |
//! | [`imageio`] | the one image type ([`imageio::Image`], HWC RGB f32), its resizer, PNG/JPEG files |
//! | [`render`] | CPU EWA rasterizer: forward, colour backward, frozen-geometry cache; the source views; what the prior sees (fill) |
//! | [`maths`] | general maths shared by the method, the baselines and the metrics: eigendecomposition, Gram matrices, depth reprojection |
//! | [`optim`] | L1 + D-SSIM loss, Adam over SH colours |
//! | [`selection`] | which Gaussians may change: shapes, masks lifted from views, their combinations |
//! | [`regions`] | several styles in one run: regions of (selection, style or blend, strength), read and checked |
//! | [`runtime`] | the one onnxruntime environment per process |
//! | [`models`] | where installed models are found (`$FANTASYSTYLE_MODELS`, `vendor/models`) |
//! | [`prior`] | the prior interface and its families: ONNX diffusion, Gaussian closed form, 2D stylizer, the patch prior |
//! | [`scheduler`] | DDIM: alphas, the discrete timestep set, noising, eps/x0/v, the timestep draw |
//! | [`mvfc`] | multi-view frequency consistency (paper Sec. 4, MVFC) |
//! | [`csd`] | controllable stylized distillation (paper Sec. 4, CSD) |
//! | [`vgg`] | VGG16 forward and backward in Rust (the texture terms' and baselines' features) |
//! | [`terms`] | the colour step's loss terms: the prior's (CSD, SDS, ...), NNFM and Gram texture terms |
//! | [`transfer`] | the style put on a scene without a prior: colour transfer, triplanar projection |
//! | [`config`] | the method's configuration: one type, its presets and layers |
//! | [`distill`] | the paper's loop (FantasyStyle Sec. 4): one iteration's steps, the run, its records and checkpoints |
//! | [`ends`] | how a run starts and ends (a registry): the patch prior's deterministic end with its parts, colour transfer, projection; the split |
//! | [`baselines`] | Gram, NNFM and per-view refit baselines |
//! | [`metrics`] | LPIPS, FID/KID, ArtFID, view consistency, structure, Gram distance, agreement, the evaluation and its report |
//! | [`artifacts`] | typed readers of the stages' artifacts (on `fantasystyle_schemas`) |
//! | [`stages`] | one module per stage binary (`Args` + `run`), shared CLI plumbing |
//! | [`sample`] | the deterministic sample of `data-sample/` (`make-sample`) |
//! | [`sweep`] | the speed-accuracy sweep driver and its table |
//! | [`timing`] | phase timing the stages report to the DAG runner |
//! | [`params`] | parameter structs declared once (clap: docs and defaults; serde: files) |
//! | [`parallel`], [`rng`], [`error`] | thread pools; seeded random streams; the typed error and its exit codes |

pub mod artifacts;
pub mod baselines;
pub mod camera;
pub mod config;
pub mod csd;
pub mod distill;
pub mod ends;
pub mod error;
pub mod geometry;
pub mod imageio;
pub mod maths;
pub mod metrics;
pub mod models;
pub mod mvfc;
pub mod optim;
pub mod parallel;
pub mod params;
pub mod prior;
pub mod regions;
pub mod render;
pub mod rng;
pub mod runtime;
pub mod sample;
pub mod scene;
pub mod scheduler;
pub mod selection;
pub mod stages;
pub mod sweep;
pub mod terms;
pub mod timing;
pub mod transfer;
pub mod vgg;

pub use camera::Camera;
pub use error::{Error, Result};
pub use scene::Scene;

/// Version of this crate, recorded in every artifact's producer.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

//! fantasystyle: restyle a trained 3D Gaussian Splatting scene after a style image by
//! distilling a 2D prior into the scene's colours (FantasyStyle, AAAI 2026).
//!
//! One module per concept; the stage binaries in `stages/` are thin wrappers over
//! [`stages`]. Where to look:
//!
//! | module | what |
//! |---|---|
//! | [`scene`] | Gaussian scenes: INRIA `.ply`, `.splat`, the generated sample |
//! | [`camera`] | cameras: INRIA `cameras.json`, COLMAP, nerfstudio, generated orbits |
//! | [`render`] | CPU EWA rasterizer: forward, colour backward, frozen-geometry cache |
//! | [`optim`] | L1 + D-SSIM loss, Adam over SH colours |
//! | [`runtime`] | the one onnxruntime environment per process |
//! | [`prior`] | the prior interface: ONNX diffusion, Gaussian closed form, 2D stylizer |
//! | [`scheduler`] | DDIM: alphas, the discrete timestep set, noising, eps/x0/v |
//! | [`mvfc`] | multi-view frequency consistency (paper Sec. 3.2) |
//! | [`csd`] | controllable stylized distillation (paper Sec. 3.3) |
//! | [`metrics`] | LPIPS, FID/KID, ArtFID, view consistency, Gram distance |
//! | [`stages`] | one function per stage binary, shared CLI plumbing |

pub mod baselines;
pub mod camera;
pub mod csd;
pub mod error;
pub mod imageio;
pub mod metrics;
pub mod mvfc;
pub mod optim;
pub mod parallel;
pub mod prior;
pub mod render;
pub mod rng;
pub mod runtime;
pub mod scene;
pub mod scheduler;
pub mod stages;
pub mod vgg;

pub use camera::Camera;
pub use error::{Error, Result};
pub use scene::Scene;

/// Version of this crate, recorded in every artifact's producer.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

//! General maths that the method, the baselines and the metrics share, kept apart from
//! all three so that none imports another for it.
//!
//! | module | what |
//! |---|---|
//! | [`blur`] | the separable Gaussian blur of a plane (clamp, mirror or zero outside; f32 or f64) and of every plane of `[C, H, W]` |
//! | [`linalg`] | symmetric eigendecomposition (cyclic Jacobi, f64), PSD square roots, small dense products |
//! | [`expf`] | `f32::exp` of many values at once, bit for bit the platform's `expf` (glibc's FMA build's operations on four lanes) |
//! | [`gram`] | the Gram matrix of a feature map (Gatys et al. 2016, Eq. 3) |
//! | [`sinkhorn`] | log-sum-exp, max-shifted softmax weights, the entropic coupling by log-domain Sinkhorn iterations (Cuturi 2013; Schmitzer 2019) |
//! | [`sinkhorn_scaling`] | the synthesis's balance: dense log-unit Sinkhorn rounds at one temperature in the scaling form with absorption (Schmitzer 2019) |
//! | [`kid`] | KID's polynomial kernel and unbiased MMD² estimate (Bińkowski et al. 2018) |
//! | [`warp`] | depth reprojection of one rendered view into another, with an occlusion test |

pub mod blur;
pub mod expf;
pub mod gram;
pub mod kid;
pub mod linalg;
pub mod sinkhorn;
pub mod sinkhorn_scaling;
pub mod warp;

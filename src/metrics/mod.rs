//! Evaluation metrics for stylized 3DGS scenes, as reported by FantasyStyle (AAAI 2026,
//! its experiments: ArtFID, FID, short- and long-range view consistency).
//!
//! | module | what |
//! |---|---|
//! | [`nets`] | the ONNX metric networks (LPIPS AlexNet/VGG16 backbones, FID Inception-v3) |
//! | [`lpips`] | LPIPS distance from tapped features, optionally masked |
//! | [`linalg`] | symmetric eigendecomposition (cyclic Jacobi, f64) and PSD square roots |
//! | [`fid`] | Fréchet distance, KID (polynomial-kernel unbiased MMD²), ArtFID |
//! | [`warp`] | depth reprojection of one view into another with occlusion test |
//! | [`consistency`] | short/long-range consistency: LPIPS and RMSE after warping |
//! | [`gram`] | Gram-matrix style distance on VGG16 features |
//! | [`views`] | `views` artifacts as the evaluation holds them, cross-checked |
//! | [`evaluate`] | the whole evaluation: every metric above on two view sets and a style |
//! | [`report`] | the self-contained `report.html` of an evaluation |

pub mod consistency;
pub mod evaluate;
pub mod fid;
pub mod gram;
pub mod linalg;
pub mod lpips;
pub mod nets;
pub mod report;
pub mod views;
pub mod warp;

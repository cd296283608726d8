//! Evaluation metrics for stylized 3DGS scenes, as reported by FantasyStyle (AAAI 2026,
//! its experiments: ArtFID, FID, short- and long-range view consistency). The general
//! maths they use (eigendecomposition, Gram matrices, depth reprojection) is in
//! [`crate::maths`].
//!
//! | module | what |
//! |---|---|
//! | [`nets`] | the ONNX metric networks (LPIPS AlexNet/VGG16 backbones, FID Inception-v3) |
//! | [`lpips`] | LPIPS distance from tapped features, optionally masked |
//! | [`fid`] | Fréchet distance, KID (polynomial-kernel unbiased MMD²), ArtFID |
//! | [`consistency`] | short/long-range consistency: LPIPS and RMSE after warping |
//! | [`gram`] | Gram-matrix style distance on VGG16 features (the Gram matrix itself: [`crate::maths::gram`]) |
//! | [`spectrum`] | radially averaged luminance power spectrum (the motif scale) |
//! | [`texture`] | measures that see texture: per-layer object Gram, KID interval, spectrum, object colour |
//! | [`leakage`] | content leakage: the object's large-scale structure that the scene does not explain |
//! | [`structure`] | structure kept: correlation of the source's and stylized views' band-passed luminance |
//! | [`interior`] | inside the object (mask eroded 8 px): interior structure, edge recall, motif contrast, style texture |
//! | [`views`] | `views` artifacts as the evaluation holds them, cross-checked |
//! | [`reference`](mod@reference) | the half of an evaluation that depends only on the original views and the style |
//! | [`regions`] | a run's regions on the views (outlines, styles, strengths) and each region's Gram distance to every style |
//! | [`evaluate`] | the whole evaluation: every metric above on two view sets and a style |
//! | [`html`] | HTML pieces of the reports: tables, inline SVG plots, embedded images, the page |
//! | [`report`] | the self-contained `report.html` of an evaluation |
//! | [`viewer`] | the report's interactive side-by-side 3D viewer (Spark, embedded `.spz`) |

pub mod agreement;
pub mod consistency;
pub mod evaluate;
pub mod fid;
pub mod gram;
pub mod html;
pub mod interior;
pub mod leakage;
pub mod lpips;
pub mod nets;
pub mod reference;
pub mod regions;
pub mod report;
pub mod spectrum;
pub mod structure;
pub mod texture;
pub mod viewer;
pub mod views;

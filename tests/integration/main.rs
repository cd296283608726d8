//! The integration test binary: one binary, one harness (`harness`), one module per area.

// The 80-line rule (clippy::too_many_lines) is for the library and the runner; a test or
// benchmark reads as one scenario from set-up to check.
#![allow(clippy::too_many_lines)]
mod baselines;
mod chain;
mod consistency;
mod csd_golden;
mod diffusion;
mod distill;
mod distill_starts;
mod evaluate;
mod evaluate_reference;
mod extremes;
mod formats;
mod fuzz;
mod fuzz_cameras;
mod fuzz_npy_manifests;
mod fuzz_scenes;
mod harness;
mod interior;
mod mvfc;
mod mvfc_csd;
mod own_scene;
mod patch_prior;
mod presets;
mod regions;
mod render;
mod runtime;
mod scene;
mod scene_bad_input;
mod scene_cameras;
mod selection;
mod snakemake_sample;
mod spz;
mod structure;
mod structure_guide;
mod texture;
mod viewer;
mod warp;

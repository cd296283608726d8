//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod baselines;
mod csd_golden;
mod diffusion;
mod distill;
mod evaluate;
mod extremes;
mod fuzz;
mod harness;
mod mvfc;
mod own_scene;
mod render;
mod runtime;
mod scene;
mod snakemake_sample;
mod spz;
mod texture;
mod viewer;

//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod baselines;
mod chain;
mod diffusion;
mod distill;
mod evaluate;
mod harness;
mod mvfc;
mod own_scene;
mod render;
mod runtime;
mod scene;
mod snakemake_sample;

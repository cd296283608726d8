//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod baselines;
mod harness;
mod mvfc;
mod render;
mod runtime;
mod scene;

//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod harness;
mod render;
mod mvfc;
mod runtime;
mod scene;

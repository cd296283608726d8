//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod evaluate;
mod harness;
mod mvfc;
mod render;
mod runtime;
mod scene;

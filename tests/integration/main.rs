//! The integration test binary: one binary, one harness (`harness`), one module per area.
mod evaluate;
mod harness;
mod render;
mod scene;

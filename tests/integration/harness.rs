//! Small helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The repository root.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `../shared/data/scenes/NAME` if present; `None` (and a message) if not.
pub fn shared_scene(name: &str) -> Option<PathBuf> {
    let p = repo_root().join("../shared/data/scenes").join(name);
    if p.is_file() {
        Some(p)
    } else {
        eprintln!("SKIPPED: shared scene {} is absent", p.display());
        None
    }
}

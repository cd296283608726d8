//! Small helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The repository root.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The shared scene `NAME`, looked up in `$FANTASYSTYLE_SHARED/data/scenes/`, then
/// `../shared/data/scenes/` beside the repository, then `/work/shared/data/scenes/` (for
/// worktrees outside the main checkout); `None` (and a SKIPPED message) if absent.
pub fn shared_scene(name: &str) -> Option<PathBuf> {
    let mut roots = Vec::new();
    if let Ok(s) = std::env::var("FANTASYSTYLE_SHARED") {
        roots.push(PathBuf::from(s));
    }
    roots.push(repo_root().join("../shared"));
    roots.push(PathBuf::from("/work/shared"));
    for r in &roots {
        let p = r.join("data/scenes").join(name);
        if p.is_file() {
            return Some(p);
        }
    }
    eprintln!("SKIPPED: shared scene {name} is absent (looked in {roots:?})");
    None
}

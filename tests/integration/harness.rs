//! Small helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The repository root.
pub fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The runner binary `pipeline` (another package of the workspace, so Cargo gives it no
/// `CARGO_BIN_EXE_` here): beside the stage binaries, built by `cargo test --workspace`.
pub fn pipeline_bin() -> PathBuf {
    let p = std::path::Path::new(env!("CARGO_BIN_EXE_render-views"))
        .parent()
        .unwrap()
        .join("pipeline");
    assert!(
        p.is_file(),
        "{} is missing: build every binary first (cargo build --workspace --bins)",
        p.display()
    );
    p
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

/// The installed model directory `rel` under the models directory (`stylizer`,
/// `lpips/vgg16`, ...): under CI (`CI` set) its absence fails the test, naming it;
/// elsewhere the test prints SKIPPED and gets `None`.
pub fn installed_model(rel: &str) -> Option<PathBuf> {
    let dir = fantasystyle::models::model_path(rel).ok();
    if let Some(d) = dir.as_ref().filter(|d| d.is_dir()) {
        return Some(d.clone());
    }
    assert!(
        std::env::var("CI").is_err(),
        "the model {rel} is missing under CI ({dir:?}); scripts/setup.sh installs it"
    );
    eprintln!("SKIPPED: the model {rel} is not installed ({dir:?})");
    None
}

/// Write a `views` artifact at `dir` from `[n, h, w, 3]` RGB, `[n, h, w]` depth and
/// alpha, and the bytes of its `cameras.json`.
pub fn write_views(
    dir: &std::path::Path,
    [n, h, w]: [usize; 3],
    rgb: &[f32],
    depth: &[f32],
    alpha: &[f32],
    cameras_json: &[u8],
) {
    use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
    let mut wr = ArtifactWriter::create(
        dir,
        ArtifactKind::Views,
        Producer::new("test", "0", serde_json::json!({})),
    )
    .unwrap();
    wr.write_tensor("rgb.npy", &[n, h, w, 3], rgb).unwrap();
    wr.write_tensor("depth.npy", &[n, h, w], depth).unwrap();
    wr.write_tensor("alpha.npy", &[n, h, w], alpha).unwrap();
    wr.write_bytes("cameras.json", cameras_json).unwrap();
    wr.commit().unwrap();
}

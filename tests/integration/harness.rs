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

/// Whether this is a CI run (`CI` set, and not to `""`, `0` or `false`): there, set-up
/// has installed everything, and a test that needs something set-up installs must fail
/// when it is missing, not skip.
pub fn ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"))
}

/// The one rule for "this test needs something set-up installs" (a model, onnxruntime,
/// Chromium, a shared scene): `true` when `present`; otherwise under CI ([`ci`]) the test
/// fails with a message naming `what` is missing (a broken set-up must not pass as a
/// green run), and elsewhere it prints `SKIPPED: ...` and gets `false`, to return early.
///
/// Only opt-in tests that need a user's own export, and cases that cannot run at all
/// here (as root), skip without it, and say so in their message.
pub fn need(what: impl std::fmt::Display, present: bool) -> bool {
    if present {
        return true;
    }
    assert!(
        !ci(),
        "missing under CI: {what} (scripts/setup.sh installs it; this test does not skip \
         under CI)"
    );
    eprintln!("SKIPPED: missing {what} (run scripts/setup.sh)");
    false
}

/// The installed model `name` (a directory with `model.json` under the models
/// directory, [`fantasystyle::models`]: `$FANTASYSTYLE_MODELS` or `vendor/models`), or
/// `None` after [`need`].
pub fn model(name: &str) -> Option<PathBuf> {
    model_file(name, "model.json").map(|f| f.parent().unwrap().to_path_buf())
}

/// `rel` (a file) inside the installed model directory `name`, or `None` after [`need`].
pub fn model_file(name: &str, rel: &str) -> Option<PathBuf> {
    match fantasystyle::models::model_path(name) {
        Ok(d) => {
            let f = d.join(rel);
            need(format_args!("model file {}", f.display()), f.is_file()).then_some(f)
        }
        Err(e) => {
            need(format_args!("the models directory ({e})"), false);
            None
        }
    }
}

/// Whether the onnxruntime shared library is found ([`need`]).
pub fn onnxruntime() -> bool {
    match fantasystyle::runtime::library_path() {
        Ok(_) => true,
        Err(e) => need(format_args!("onnxruntime ({e})"), false),
    }
}

/// The shared scene `NAME`, looked up in `$FANTASYSTYLE_SHARED/data/scenes/`, then
/// `../shared/data/scenes/` beside the repository, then `/work/shared/data/scenes/` (for
/// worktrees outside the main checkout); `None` after [`need`] if absent.
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
    need(
        format_args!("shared scene {name} (looked in {roots:?}; set FANTASYSTYLE_SHARED)"),
        false,
    );
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

/// The set-up's Python (`vendor/venv/bin/python`, with numpy), or `None` after [`need`]:
/// the independent references some tests compute on the machine that runs them.
pub fn python() -> Option<PathBuf> {
    let p = repo_root().join("vendor/venv/bin/python");
    need("vendor/venv/bin/python (numpy)", p.is_file()).then_some(p)
}

/// A stage binary of this package by name, as a command.
pub fn bin(name: &str) -> std::process::Command {
    std::process::Command::new(match name {
        "distill" => env!("CARGO_BIN_EXE_distill"),
        "render-views" => env!("CARGO_BIN_EXE_render-views"),
        "select" => env!("CARGO_BIN_EXE_select"),
        "split" => env!("CARGO_BIN_EXE_split"),
        "evaluate" => env!("CARGO_BIN_EXE_evaluate"),
        _ => unreachable!("no binary `{name}` in the harness"),
    })
}

/// Run `c`, which must succeed (its stderr in the failure).
pub fn ok(c: &mut std::process::Command) -> std::process::Output {
    let out = c.output().unwrap();
    assert!(
        out.status.success(),
        "{c:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// The sample scene rendered by `render-views` into a views artifact at `out`: `n` orbit
/// cameras, `side` x `side` pixels.
pub fn render_sample(out: &std::path::Path, n: usize, side: usize) {
    use clap::Parser;
    use fantasystyle::stages::render_views;
    let scene = repo_root().join("data-sample/scene.ply");
    let (cams, side) = (format!("orbit:{n}"), side.to_string());
    render_views::run(render_views::Args::parse_from([
        "rv".as_ref(),
        "--scene".as_ref(),
        scene.as_os_str(),
        "--cameras".as_ref(),
        cams.as_ref(),
        "--width".as_ref(),
        side.as_ref(),
        "--height".as_ref(),
        side.as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]))
    .unwrap();
}

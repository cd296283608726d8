//! Fixtures of every artifact kind at every schema version this build reads. They are
//! checked into `schemas/fixtures/v{N}/{kind}/` and must keep loading: a change that
//! breaks one is a change to the on-disk contract and needs a new schema version plus a
//! reader for the old one.

use super::*;
use crate::{ArtifactKind, MANIFEST_FILE, Manifest, Producer, Result};
use std::fs;
use std::path::{Path, PathBuf};

fn fixture_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// Small, fully deterministic content for each kind (version 1).
fn write_v1(kind: ArtifactKind, dir: &Path) -> Result<Manifest> {
    let params = serde_json::json!({"fixture": true, "kind": kind.as_str()});
    let mut w = ArtifactWriter::create(dir, kind, Producer::new("fixture", "0.1.0", params))?;
    let ramp = |n: usize| (0..n).map(|i| i as f32 / n as f32).collect::<Vec<f32>>();
    let cams = serde_json::json!([{"id": 0, "img_name": "orbit_000", "width": 4, "height": 2,
        "position": [0.0, 0.0, -3.0], "rotation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        "fx": 4.0, "fy": 4.0}]);
    match kind {
        ArtifactKind::Views => {
            w.write_tensor("rgb.npy", &[1, 2, 4, 3], &ramp(24))?;
            w.write_tensor("depth.npy", &[1, 2, 4], &ramp(8))?;
            w.write_tensor("alpha.npy", &[1, 2, 4], &[1.0f32; 8])?;
            w.write_json("cameras.json", &cams)?;
        }
        ArtifactKind::Latents => w.write_tensor("latents.npy", &[1, 4, 1, 2], &ramp(8))?,
        ArtifactKind::NoisedLatents => {
            w.write_tensor("z_src.npy", &[1, 4, 1, 2], &ramp(8))?;
            w.write_tensor("z_tgt.npy", &[1, 4, 1, 2], &ramp(8))?;
            w.write_tensor("eps.npy", &[1, 4, 1, 2], &ramp(8))?;
            w.set_meta(serde_json::json!({"timestep": 501}));
        }
        ArtifactKind::Targets => {
            w.write_tensor("rgb.npy", &[1, 2, 4, 3], &ramp(24))?;
            w.write_json("cameras.json", &cams)?;
        }
        ArtifactKind::Scene => w.write_bytes(
            "scene.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 0\nend_header\n",
        )?,
        ArtifactKind::Evaluation => {
            w.write_json("metrics.json", &serde_json::json!({"lpips": 0.25}))?
        }
        ArtifactKind::EvalReference => {
            w.write_json(
                "reference.json",
                &serde_json::json!({"gram_original": [0.5]}),
            )?;
            w.write_tensor("views_pool3.npy", &[1, 2], &ramp(2))?;
        }
        ArtifactKind::EvalSource => {
            w.write_json(
                "source.json",
                &serde_json::json!({"settings": {"views": 1}}),
            )?;
            w.write_tensor("views_pool3.npy", &[1, 2], &ramp(2))?;
        }
        ArtifactKind::EvalStyle => {
            w.write_json("style.json", &serde_json::json!({"settings": {"views": 1}}))?;
            w.write_tensor("crops_pool3.npy", &[1, 2], &ramp(2))?;
        }
        ArtifactKind::Selection => {
            w.write_tensor("weights.npy", &[4], &[0.0, 1.0, 0.5, 1.0])?;
            w.set_meta(serde_json::json!({"selected": 3, "gaussians": 4}));
        }
    }
    w.commit()
}

/// Regenerate the fixtures of the current version:
/// `cargo test -p fantasystyle-schemas -- --ignored regenerate_fixtures`.
#[test]
#[ignore]
fn regenerate_fixtures() {
    for kind in ArtifactKind::ALL {
        let dir = fixture_root()
            .join(format!("v{}", kind.current_version()))
            .join(kind.as_str());
        write_v1(kind, &dir).unwrap();
    }
}

#[test]
fn every_kind_has_a_fixture_for_every_readable_version_and_it_loads() {
    for kind in ArtifactKind::ALL {
        for v in kind.readable_versions() {
            let dir = fixture_root().join(format!("v{v}")).join(kind.as_str());
            let a = Artifact::open(&dir, kind)
                .unwrap_or_else(|e| panic!("fixture {}: {e}", dir.display()));
            assert_eq!(a.manifest.schema_version, *v);
            for f in &a.manifest.files {
                if f.dtype == Some(crate::DType::F32) {
                    let t = a.read_f32(&f.name).unwrap();
                    assert_eq!(Some(&t.shape), f.shape.as_ref());
                }
            }
        }
    }
}

#[test]
fn fixtures_match_what_this_build_writes() {
    // The current version's fixture must be byte-identical to a fresh write: if this
    // fails, the writer changed the format without bumping the schema version.
    let d = tempfile::tempdir().unwrap();
    for kind in ArtifactKind::ALL {
        let fresh = d.path().join(kind.as_str());
        write_v1(kind, &fresh).unwrap();
        let fixture = fixture_root()
            .join(format!("v{}", kind.current_version()))
            .join(kind.as_str());
        for f in fs::read_dir(&fixture).unwrap() {
            let name = f.unwrap().file_name();
            assert_eq!(
                fs::read(fresh.join(&name)).unwrap(),
                fs::read(fixture.join(&name)).unwrap(),
                "{kind}/{}",
                name.to_string_lossy()
            );
        }
    }
}

#[test]
fn a_future_version_is_refused_with_a_clear_message() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("lat");
    write_v1(ArtifactKind::Latents, &dir).unwrap();
    let m = dir.join(MANIFEST_FILE);
    let text = fs::read_to_string(&m)
        .unwrap()
        .replace("\"schema_version\": 1", "\"schema_version\": 99");
    fs::write(&m, text).unwrap();
    let e = Artifact::open(&dir, ArtifactKind::Latents)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("schema version 99") && e.contains("manifest.json"),
        "{e}"
    );
}

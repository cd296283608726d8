//! Fuzzing the `.npy` reader (whole and streamed), the artifact manifest and
//! `model.json` (the machinery is in `fuzz`).

use crate::fuzz::{apply, apply_lines, edit, fuzz, guarded, json_case, line_edit, names_file, tmp};
use fantasystyle_schemas::NpyReader;
use fantasystyle_schemas::npy::{decode_npy, encode_npy};
use proptest::prelude::*;
use std::path::Path;

fn npy_seeds() -> Vec<Vec<u8>> {
    vec![
        encode_npy::<f32>(
            &[2, 3, 4],
            &(0..24).map(|i| i as f32 * 0.5).collect::<Vec<_>>(),
        ),
        encode_npy::<f32>(&[5], &[1.0, -2.0, 3.5, 0.0, 1e-3]),
        encode_npy::<f32>(&[0, 7], &[]),
        encode_npy::<f64>(&[2, 2], &[1.0, 2.0, 3.0, 4.0]),
        encode_npy::<u8>(&[4], &[1, 2, 3, 255]),
    ]
}

#[test]
fn fuzz_npy() {
    let strategy = (
        prop::sample::select(npy_seeds()),
        prop::collection::vec(line_edit(), 0..2),
        prop::collection::vec(edit(), 0..4),
    );
    let d = tmp();
    let p = d.path().join("fuzz.npy");
    fuzz("npy", 3000, strategy, |(mut b, lines, edits)| {
        // Line edits touch the header dict's words ("'shape': (2, 3, 4)").
        apply_lines(&mut b, &lines, Some(1));
        apply(&mut b, &edits);
        let len = b.len();
        let bb = b.clone();
        let r = guarded(len, move || {
            decode_npy::<f32>(Path::new("fuzz.npy"), &bb).map_err(fantasystyle::Error::from)
        })?;
        names_file(&r, "fuzz.npy")?;
        if let Ok(a) = &r
            && a.data.len() != a.shape.iter().product::<usize>()
        {
            return Err(format!("{} values for shape {:?}", a.data.len(), a.shape));
        }
        // The streaming reader, item by item.
        std::fs::write(&p, &b).unwrap();
        let pp = p.clone();
        let r = guarded(len, move || -> fantasystyle::Result<usize> {
            let mut rd = NpyReader::<f32>::open(&pp)?;
            let mut out = Vec::new();
            let mut n = 0;
            while rd.remaining() > 0 {
                rd.read_items(1, &mut out)?;
                n += out.len();
            }
            Ok(n)
        })?;
        names_file(&r, "fuzz.npy")
    });
}

/// A valid views artifact's directory and its manifest.json as JSON.
fn views_artifact(dir: &Path) -> serde_json::Value {
    let (n, h, w) = (2, 4, 3);
    crate::harness::write_views(
        dir,
        [n, h, w],
        &vec![0.5; n * h * w * 3],
        &vec![2.0; n * h * w],
        &vec![1.0; n * h * w],
        b"[]",
    );
    serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap()
}

#[test]
fn fuzz_artifact_manifest() {
    let d = tmp();
    let art = d.path().join("views");
    let seed = views_artifact(&art);
    fantasystyle::artifacts::read_views(&art).expect("the seed is valid");
    fuzz("manifest.json", 2000, json_case(vec![seed]), |(b, _)| {
        std::fs::write(art.join("manifest.json"), &b).unwrap();
        let a = art.clone();
        let r = guarded(b.len(), move || {
            fantasystyle_schemas::Artifact::open_any(&a).map_err(fantasystyle::Error::from)
        })?;
        names_file(&r, "views")?;
        let a = art.clone();
        let r = guarded(b.len(), move || {
            fantasystyle::artifacts::read_views(&a).map(|_| ())
        })?;
        names_file(&r, "views")
    });
}

#[test]
fn fuzz_model_json() {
    let sched = serde_json::json!({
        "num_train_timesteps": 1000, "beta_start": 0.00085, "beta_end": 0.012,
        "beta_schedule": "scaled_linear", "prediction_type": "epsilon"
    });
    let seeds = vec![
        serde_json::json!({
            "format": "fantasystyle-model/1", "family": "sd15", "name": "t",
            "latent_channels": 4, "vae_scaling_factor": 0.18215, "downsample": 8,
            "scheduler": sched,
            "vae_encoder": {"file": "e.onnx", "input": "sample", "output": "latent"},
            "vae_decoder": {"file": "d.onnx", "input": "latent_sample", "output": "sample"},
            "unet": {"file": "u.onnx", "sample": "sample", "timestep": "timestep",
                     "encoder_hidden_states": "ehs", "output": "out_sample"},
            "text": {"null": {"file": "n.npy"}, "prompts": [{"text": "a", "file": "p.npy"}]}
        }),
        serde_json::json!({
            "format": "fantasystyle-model/1", "family": "stylizer", "name": "s",
            "latent_channels": 3, "downsample": 1, "scheduler": sched,
            "stylizer": {
                "timesteps": {"t_min": 20, "t_max": 300, "count": 25},
                "style_predict": {"file": "p.onnx", "input": "i", "output": "o", "size": 256},
                "transform": {"file": "t.onnx", "content_input": "c", "style_input": "s",
                              "output": "o", "size": 384, "dynamic": true},
                "style_dim": 100
            }
        }),
    ];
    let d = tmp();
    for f in [
        "e.onnx", "d.onnx", "u.onnx", "n.npy", "p.npy", "p.onnx", "t.onnx",
    ] {
        std::fs::write(d.path().join(f), b"x").unwrap();
    }
    for s in &seeds {
        std::fs::write(d.path().join("model.json"), s.to_string()).unwrap();
        fantasystyle::prior::model_timesteps(d.path()).expect("the seeds are valid");
    }
    fuzz("model.json", 2000, json_case(seeds), |(b, _)| {
        std::fs::write(d.path().join("model.json"), &b).unwrap();
        let dir = d.path().to_path_buf();
        let r = guarded(b.len(), move || {
            fantasystyle::prior::manifest::ModelManifest::load(&dir).map(|_| ())
        })?;
        names_file(&r, "model.json")?;
        let dir = d.path().to_path_buf();
        let r = guarded(b.len(), move || {
            fantasystyle::prior::model_timesteps(&dir).map(|(_, set)| set.steps().len())
        })?;
        names_file(&r, "model.json")
    });
}

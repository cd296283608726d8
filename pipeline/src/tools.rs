//! Small artifact tools run as DAG stages by the `pipeline` binary itself.
//!
//! * [`wrap`]: put plain files into an artifact of a given kind (e.g. a source
//!   `scene.ply` into a `scene` artifact, the round-0 scene of the sample DAG).
//! * [`test_stage`]: a deterministic fake stage for the runner's own tests; it writes
//!   a `latents` artifact slowly, in steps, and can be told to abort at a step
//!   (`PIPELINE_TEST_ABORT=<substring of --out>:<step>`), like a stage killed mid-write.

use crate::error::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind, ArtifactWriter, Producer, SchemaError};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Copy `files` (by base name) into a new artifact of `kind` at `out`.
pub fn wrap(kind: &str, files: &[PathBuf], out: &Path) -> Result<()> {
    let kind: ArtifactKind = serde_json::from_value(serde_json::Value::String(kind.into()))
        .map_err(|_| {
            let all: Vec<&str> = ArtifactKind::ALL.iter().map(|k| k.as_str()).collect();
            Error::Usage(format!(
                "unknown artifact kind `{kind}` (one of {})",
                all.join(", ")
            ))
        })?;
    let names: Vec<String> = files
        .iter()
        .map(|f| f.to_string_lossy().into_owned())
        .collect();
    let producer = Producer::new(
        "pipeline-wrap",
        env!("CARGO_PKG_VERSION"),
        serde_json::json!({ "kind": kind.as_str(), "files": names }),
    );
    let mut w = ArtifactWriter::create(out, kind, producer)?;
    for f in files {
        let name = f
            .file_name()
            .ok_or_else(|| Error::Usage(format!("{}: not a file name", f.display())))?
            .to_string_lossy()
            .into_owned();
        let bytes = std::fs::read(f).map_err(|e| Error::io(f, e))?;
        w.add_input(&name, f)?;
        w.write_bytes(&name, &bytes)?;
    }
    w.commit()?;
    Ok(())
}

/// Arguments of the fake stage.
#[derive(Debug, Clone)]
pub struct TestStage {
    pub out: PathBuf,
    pub inputs: Vec<PathBuf>,
    pub seed: u64,
    pub value: f64,
    pub steps: usize,
    pub sleep_ms: u64,
    pub fail: bool,
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Run the fake stage: `latents.npy` `[1,2,4,4]` is half the sum of the inputs' latents,
/// plus `value`, plus uniform noise from (seed, index); one `part{k}.npy` is written per
/// step, with a sleep before each step.
pub fn test_stage(a: &TestStage) -> Result<(), SchemaError> {
    let t0 = Instant::now();
    let abort_step = std::env::var("PIPELINE_TEST_ABORT").ok().and_then(|v| {
        let (sub, step) = v.rsplit_once(':')?;
        let step: usize = step.parse().ok()?;
        a.out.to_string_lossy().contains(sub).then_some(step)
    });
    const N: usize = 32;
    let mut data = vec![0f32; N];
    for p in &a.inputs {
        let art = Artifact::open(p, ArtifactKind::Latents)?;
        let x = art.read_f32("latents.npy")?;
        for (d, v) in data.iter_mut().zip(&x.data) {
            *d += 0.5 * v;
        }
    }
    for (k, d) in data.iter_mut().enumerate() {
        let u = (splitmix(a.seed.wrapping_mul(1_000_003) ^ k as u64) >> 40) as f32
            / (1u64 << 24) as f32;
        *d += a.value as f32 + u;
    }
    let producer = Producer::new(
        "test-stage",
        env!("CARGO_PKG_VERSION"),
        serde_json::json!({"seed": a.seed, "value": a.value, "steps": a.steps}),
    );
    let mut w = ArtifactWriter::create(&a.out, ArtifactKind::Latents, producer)?;
    for p in &a.inputs {
        w.add_input("input", p)?;
    }
    let mut compute = Duration::ZERO;
    for k in 0..a.steps {
        // The sleep stands in for a stage's compute.
        let c = Instant::now();
        std::thread::sleep(Duration::from_millis(a.sleep_ms));
        compute += c.elapsed();
        if abort_step == Some(k) {
            eprintln!("test-stage: aborting at step {k} as PIPELINE_TEST_ABORT asks");
            std::process::abort();
        }
        let part: Vec<f32> = data.iter().map(|v| v * (k + 1) as f32).collect();
        w.write_tensor(&format!("part{k}.npy"), &[N], &part)?;
        eprintln!("test-stage: step {k} written");
    }
    if a.fail {
        return Err(SchemaError::Invalid {
            path: a.out.clone(),
            reason: "failing as --fail asks".into(),
        });
    }
    if abort_step == Some(a.steps) {
        std::process::abort();
    }
    w.write_tensor("latents.npy", &[1, 2, 4, 4], &data)?;
    w.commit()?;
    if let Some(p) = std::env::var_os(crate::run::TIMING_ENV) {
        let (total, c) = (t0.elapsed().as_secs_f64(), compute.as_secs_f64());
        let _ = std::fs::write(
            p,
            serde_json::json!({"compute_s": c, "io_s": total - c}).to_string(),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_makes_an_artifact_and_rejects_bad_kind() {
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("scene.ply");
        std::fs::write(&f, b"ply\n").unwrap();
        wrap("scene", std::slice::from_ref(&f), &d.path().join("s")).unwrap();
        let a = Artifact::open(&d.path().join("s"), ArtifactKind::Scene).unwrap();
        assert_eq!(std::fs::read(a.path("scene.ply")).unwrap(), b"ply\n");
        let e = wrap("nope", &[f], &d.path().join("t"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown artifact kind `nope`"), "{e}");
        // Missing required file for the kind.
        let g = d.path().join("x.txt");
        std::fs::write(&g, b"x").unwrap();
        let e = wrap("scene", &[g], &d.path().join("u"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("scene.ply"), "{e}");
    }
}

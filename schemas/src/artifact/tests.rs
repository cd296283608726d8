//! Writing, streaming, committing, opening and tampering with artifacts.

use super::*;
use crate::{ArtifactKind, MANIFEST_FILE, Producer};
use std::fs;

fn producer() -> Producer {
    Producer::new("test", "0.1.0", serde_json::json!({"b": 1, "a": [1, 2]}))
}

#[test]
fn write_open_read() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("lat");
    let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
    w.write_tensor("latents.npy", &[1, 2, 2, 2], &[0.5f32; 8])
        .unwrap();
    w.set_meta(serde_json::json!({"t": 3}));
    w.commit().unwrap();
    let a = Artifact::open(&t, ArtifactKind::Latents).unwrap();
    assert_eq!(a.read_f32("latents.npy").unwrap().shape, vec![1, 2, 2, 2]);
    assert_eq!(a.manifest.meta["t"], 3);
    // Only the artifact remains: no staging directories.
    assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
    let e = Artifact::open(&t, ArtifactKind::Views)
        .unwrap_err()
        .to_string();
    assert!(e.contains("expected an artifact of kind `views`"), "{e}");
}

#[test]
fn tamper_is_detected() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("lat");
    let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
    w.write_tensor("latents.npy", &[2], &[1f32, 2.]).unwrap();
    w.commit().unwrap();
    crate::npy::write_npy(&t.join("latents.npy"), &[2], &[1f32, 3.]).unwrap();
    let e = Artifact::open(&t, ArtifactKind::Latents)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("hash mismatch") && e.contains("latents.npy"),
        "{e}"
    );
}

#[test]
fn dropped_writer_leaves_old_artifact_and_no_temp() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("lat");
    let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
    w.write_tensor("latents.npy", &[1], &[1f32]).unwrap();
    w.commit().unwrap();
    let before = fs::read(t.join(MANIFEST_FILE)).unwrap();
    {
        let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
        w.write_tensor("latents.npy", &[1], &[9f32]).unwrap();
        // dropped without commit (a failing stage)
    }
    assert_eq!(fs::read(t.join(MANIFEST_FILE)).unwrap(), before);
    assert_eq!(fs::read_dir(d.path()).unwrap().count(), 1);
}

#[test]
fn a_non_artifact_directory_is_never_replaced() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("user");
    fs::create_dir(&t).unwrap();
    fs::write(t.join("precious.txt"), b"x").unwrap();
    let e = ArtifactWriter::create(&t, ArtifactKind::Latents, producer())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("refusing to replace") && e.contains("user"),
        "{e}"
    );
    assert!(t.join("precious.txt").is_file());
    // An empty directory is fine (e.g. created by a DAG runner).
    let empty = d.path().join("empty");
    fs::create_dir(&empty).unwrap();
    let mut w = ArtifactWriter::create(&empty, ArtifactKind::Latents, producer()).unwrap();
    w.write_tensor("latents.npy", &[1], &[1f32]).unwrap();
    w.commit().unwrap();
}

#[test]
fn missing_required_file_refused_at_commit() {
    let d = tempfile::tempdir().unwrap();
    let w = ArtifactWriter::create(&d.path().join("v"), ArtifactKind::Views, producer()).unwrap();
    let e = w.commit().unwrap_err().to_string();
    assert!(e.contains("rgb.npy"), "{e}");
}

#[test]
fn streamed_tensor_equals_written_tensor() {
    let d = tempfile::tempdir().unwrap();
    // Larger than the 1 MiB threshold of the parallel hash.
    let data: Vec<f32> = (0..3 * 300_000).map(|i| (i as f32).sin()).collect();
    let whole = d.path().join("whole");
    let mut w = ArtifactWriter::create(&whole, ArtifactKind::Latents, producer()).unwrap();
    w.write_tensor("latents.npy", &[3, 300_000], &data).unwrap();
    let a = w.commit().unwrap();
    let streamed = d.path().join("streamed");
    let mut w = ArtifactWriter::create(&streamed, ArtifactKind::Latents, producer()).unwrap();
    let mut s = w
        .stream_tensor::<f32>("latents.npy", &[3, 300_000])
        .unwrap();
    // Files written while the stream is open are listed after it.
    w.write_bytes("notes.txt", b"x").unwrap();
    for piece in data.chunks(400_000) {
        s.append(piece).unwrap();
    }
    assert_eq!(s.remaining(), 0);
    assert!(
        s.append(&[1.0])
            .unwrap_err()
            .to_string()
            .contains("1 more elements")
    );
    w.finish_stream(s).unwrap();
    let b = w.commit().unwrap();
    assert_eq!(a.files[..], b.files[..1]);
    assert_eq!(b.files[1].name, "notes.txt");
    assert_eq!(
        fs::read(whole.join("latents.npy")).unwrap(),
        fs::read(streamed.join("latents.npy")).unwrap()
    );
    assert_eq!(
        a.files[0].blake3,
        hash_file(&streamed.join("latents.npy")).unwrap()
    );
    let art = Artifact::open(&streamed, ArtifactKind::Latents).unwrap();
    let mut r = art.tensor_reader::<f32>("latents.npy").unwrap();
    let mut v = Vec::new();
    r.read_items(3, &mut v).unwrap();
    assert_eq!(v, data);
}

#[test]
fn unfinished_or_short_streams_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let t = d.path().join("lat");
    let mut w = ArtifactWriter::create(&t, ArtifactKind::Latents, producer()).unwrap();
    let mut s = w.stream_tensor::<f32>("latents.npy", &[2, 2]).unwrap();
    // The name is reserved while streaming.
    assert!(w.write_tensor("latents.npy", &[1], &[0f32]).is_err());
    s.append(&[1.0, 2.0, 3.0]).unwrap();
    let e = w.finish_stream(s).unwrap_err().to_string();
    assert!(
        e.contains("1 elements short") && e.contains("latents.npy"),
        "{e}"
    );
    let e = w.commit().unwrap_err().to_string();
    assert!(
        e.contains("not finished") && e.contains("latents.npy"),
        "{e}"
    );
    // Nothing was put in place, no staging directory is left.
    assert!(!t.exists());
    assert_eq!(fs::read_dir(d.path()).unwrap().count(), 0);
}

#[test]
fn params_hash_is_key_order_independent() {
    let a = Producer::new("s", "1", serde_json::json!({"x": 1, "y": 2}));
    let b = Producer::new("s", "1", serde_json::json!({"y": 2, "x": 1}));
    assert_eq!(a.params_hash, b.params_hash);
}

//! The evaluation reference through `evaluate`: whole (`--reference-only`) and in two parts
//! (`--reference-only source`, `--reference-only style`), read back by `--reference`;
//! the same metrics.json as computing everything, and foreign or incomplete references
//! refused with an error naming the artifact.

use super::evaluate::{H, W, cameras, opts, ready, restyle, style_png, write_views};
use fantasystyle::imageio::Image;
use fantasystyle::stages::evaluate::{Args, ReferencePart, run};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Seven original views under `p`, their restyled copies and a style image: the views
/// directories and the image's path.
fn seven_views(p: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let cams = cameras(7);
    let orig = write_views(&p.join("orig"), &cams, &|_, i| i);
    let styl = write_views(&p.join("styl"), &cams, &|_, i| {
        Image::from_fn(i.width, i.height, |x, y| restyle(i.px(x, y)))
    });
    (orig, styl, style_png(p))
}

/// `--reference-only`, then `--reference`: the same metrics.json, bit for bit, as one
/// evaluation that computes everything; a reference made from another style, another
/// original, with another seed or LPIPS net, or not a reference at all, is refused
/// (exit 2, the error names the reference, nothing written).
#[test]
fn a_reference_gives_the_same_metrics_and_a_foreign_one_is_refused() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let (orig, styl, style) = seven_views(p);
    let full = p.join("full");
    run(opts(&orig, &styl, &style, &full)).unwrap().unwrap();
    let reference = p.join("ref");
    let made = run(Args {
        stylized: None,
        reference_only: Some(ReferencePart::All),
        ..opts(&orig, &styl, &style, &reference)
    })
    .unwrap();
    assert!(made.is_none(), "--reference-only evaluates nothing");
    let via = p.join("via");
    run(Args {
        reference: vec![reference.clone()],
        ..opts(&orig, &styl, &style, &via)
    })
    .unwrap()
    .unwrap();
    assert!(
        metrics_json(&full) == metrics_json(&via),
        "metrics.json differs with the reference"
    );
    let manifest = std::fs::read_to_string(via.join("manifest.json")).unwrap();
    assert!(
        manifest.contains("\"reference\""),
        "the reference is recorded as an input"
    );

    let other_style = p.join("other.png");
    std::fs::write(
        &other_style,
        Image::from_fn(64, 64, |x, _| [(x % 7) as f32 / 7.0, 0.2, 0.9]).to_png(),
    )
    .unwrap();
    let out = p.join("eval");
    let (o, s, r) = (
        orig.to_str().unwrap(),
        styl.to_str().unwrap(),
        reference.to_str().unwrap(),
    );
    let (st, os) = (style.to_str().unwrap(), other_style.to_str().unwrap());
    let cases: [(&[&str], &str); 6] = [
        (
            &[
                "--original",
                o,
                "--stylized",
                s,
                "--style",
                os,
                "--reference",
                r,
            ],
            "another style",
        ),
        (
            &[
                "--original",
                s,
                "--stylized",
                s,
                "--style",
                st,
                "--reference",
                r,
            ],
            "another original",
        ),
        (
            &[
                "--original",
                o,
                "--stylized",
                s,
                "--style",
                st,
                "--reference",
                r,
                "--seed",
                "3",
            ],
            "seed 0 vs 3",
        ),
        (
            &[
                "--original",
                o,
                "--stylized",
                s,
                "--style",
                st,
                "--reference",
                r,
                "--lpips-net",
                "vgg16",
            ],
            "another --lpips-net",
        ),
        (
            &[
                "--original",
                o,
                "--stylized",
                s,
                "--style",
                st,
                "--reference",
                o,
            ],
            "eval-reference",
        ),
        (
            &[
                "--original",
                o,
                "--stylized",
                s,
                "--style",
                st,
                "--reference-only",
            ],
            "cannot be used with",
        ),
    ];
    for (args, want) in cases {
        let run = Command::new(env!("CARGO_BIN_EXE_evaluate"))
            .args(args)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{want}: {err}");
        assert!(err.contains(want), "expected `{want}` in: {err}");
        if want != "cannot be used with" {
            assert!(
                err.contains(if want == "eval-reference" { o } else { r }),
                "names the reference: {err}"
            );
        }
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "nothing written on bad input");
    }
}

/// `--reference-only source` and `--reference-only style` (the style part from the
/// cameras' count and the size, as the sample DAG makes it), then `--reference SOURCE
/// --reference STYLE` (in either order): the same metrics.json, bit for bit, as with the
/// whole reference. A part alone, a part of the wrong kind, two of a kind, a style part
/// made for other views, or a missing directory: exit 2, an error naming the artifact,
/// no panic, nothing written.
#[test]
fn the_reference_parts_give_the_whole_references_metrics() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let (orig, styl, style) = seven_views(p);
    let whole = p.join("whole");
    run(Args {
        stylized: None,
        reference_only: Some(ReferencePart::All),
        ..opts(&orig, &styl, &style, &whole)
    })
    .unwrap();
    let via_whole = p.join("via-whole");
    run(Args {
        reference: vec![whole.clone()],
        ..opts(&orig, &styl, &style, &via_whole)
    })
    .unwrap()
    .unwrap();

    let source = p.join("source");
    run(Args {
        stylized: None,
        style: None,
        reference_only: Some(ReferencePart::Source),
        ..opts(&orig, &styl, &style, &source)
    })
    .unwrap();
    let cams_file = orig.join("cameras.json");
    let style_part = p.join("style-part");
    let (o, sp) = (orig.to_str().unwrap(), style_part.to_str().unwrap());
    let made = Command::new(env!("CARGO_BIN_EXE_evaluate"))
        .args(["--reference-only", "style", "--style"])
        .arg(&style)
        .arg("--cameras")
        .arg(&cams_file)
        .args(["--width", &W.to_string(), "--height", &H.to_string()])
        .args(["--threads", "2", "--out", sp])
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    for (i, refs) in [
        vec![source.clone(), style_part.clone()],
        vec![style_part.clone(), source.clone()],
    ]
    .into_iter()
    .enumerate()
    {
        let via = p.join(format!("via-parts-{i}"));
        run(Args {
            reference: refs,
            ..opts(&orig, &styl, &style, &via)
        })
        .unwrap()
        .unwrap();
        assert!(
            metrics_json(&via_whole) == metrics_json(&via),
            "metrics.json differs with the two parts ({i})"
        );
    }

    // A style part made for 3 views: refused beside the 7 views' source part.
    let three = p.join("style-3");
    run(Args {
        stylized: None,
        original: None,
        cameras: Some("orbit:3".into()),
        width: Some(W as usize),
        height: Some(H as usize),
        reference_only: Some(ReferencePart::Style),
        ..opts(&orig, &styl, &style, &three)
    })
    .unwrap();
    let (s, w, t, missing) = (
        source.to_str().unwrap(),
        whole.to_str().unwrap(),
        three.to_str().unwrap(),
        p.join("nowhere"),
    );
    let st = style.to_str().unwrap();
    let out = p.join("eval");
    let cases: [(&[&str], &str, &str); 7] = [
        (&["--reference", s], "needs its eval-style part", s),
        (&["--reference", sp], "needs its eval-source part", sp),
        (&["--reference", s, "--reference", o], "kind `views`", o),
        (
            &["--reference", s, "--reference", s],
            "a second eval-source",
            s,
        ),
        (&["--reference", w, "--reference", sp], "read alone", w),
        (&["--reference", s, "--reference", t], "views 3 vs 7", t),
        (
            &["--reference", s, "--reference", missing.to_str().unwrap()],
            "does not exist",
            missing.to_str().unwrap(),
        ),
    ];
    for (refs, want, names) in cases {
        let run = Command::new(env!("CARGO_BIN_EXE_evaluate"))
            .args(["--original", o, "--stylized"])
            .arg(&styl)
            .args(["--style", st])
            .args(refs)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{want}: {err}");
        assert!(err.contains(want), "expected `{want}` in: {err}");
        assert!(err.contains(names), "names {names}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "nothing written on bad input");
    }
}

/// `--inception false` (the sample DAG's default): the Inception measures (FID and KID
/// of style and content, ArtFID, the object KIDs) are null with a note saying why, and
/// every other measure is the same bit for bit as with them on; its reference parts
/// give the same metrics as computing it whole; a reference made with Inception is
/// refused by an evaluation without, naming the setting.
#[test]
fn the_inception_measures_off_change_no_other_measure() {
    if !ready() {
        return;
    }
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    let (orig, styl, style) = seven_views(p);
    let (on, off) = (p.join("on"), p.join("off"));
    run(opts(&orig, &styl, &style, &on)).unwrap().unwrap();
    let no_inception = |out: &Path| Args {
        inception: false,
        ..opts(&orig, &styl, &style, out)
    };
    run(no_inception(&off)).unwrap().unwrap();
    let json = |d: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("metrics.json")).unwrap()).unwrap()
    };
    let (mut a, mut b) = (json(&on), json(&off));
    for key in ["fid_style", "kid_style", "fid_content", "kid_content"] {
        assert!(
            a[key]["value"].is_number(),
            "{key} computed with Inception on"
        );
        assert!(b[key]["value"].is_null(), "{key} not computed with it off");
        let note = b[key]["note"].as_str().unwrap();
        assert!(note.contains("--inception false"), "{key}: {note}");
    }
    for key in ["kid_style", "kid_object", "kid_object_original"] {
        assert!(a["texture"][key]["value"].is_number(), "texture.{key} on");
        assert!(b["texture"][key]["value"].is_null(), "texture.{key} off");
    }
    assert!(a["artfid"].is_number() && b["artfid"].is_null());
    // The report's metrics table says they are off in one row, instead of rows of n/a.
    let report = |d: &Path| std::fs::read_to_string(d.join("report.html")).unwrap();
    let (ron, roff) = (report(&on), report(&off));
    assert!(ron.contains("ArtFID ↓") && ron.contains("FID_style ↓"));
    assert!(!roff.contains("ArtFID ↓") && !roff.contains("FID_style ↓"));
    assert!(
        roff.contains("--set eval.inception=true"),
        "the report says how to add them"
    );
    for m in [&mut a, &mut b] {
        let o = m.as_object_mut().unwrap();
        for key in [
            "fid_style",
            "kid_style",
            "fid_content",
            "kid_content",
            "artfid",
            "warnings",
        ] {
            o.remove(key);
        }
        let t = o["texture"].as_object_mut().unwrap();
        for key in ["kid_style", "kid_object", "kid_object_original"] {
            t.remove(key);
        }
    }
    assert_eq!(a, b, "the other measures are the same with Inception off");
    assert!(
        !json(&off)["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("FID")),
        "no FID warning when FID is not computed"
    );

    // Its parts: the same metrics.json as computing it whole.
    let (source, style_part, via) = (p.join("source"), p.join("style-part"), p.join("via"));
    run(Args {
        stylized: None,
        style: None,
        reference_only: Some(ReferencePart::Source),
        ..no_inception(&source)
    })
    .unwrap();
    run(Args {
        stylized: None,
        reference_only: Some(ReferencePart::Style),
        ..no_inception(&style_part)
    })
    .unwrap();
    run(Args {
        reference: vec![source.clone(), style_part],
        ..no_inception(&via)
    })
    .unwrap()
    .unwrap();
    assert!(
        metrics_json(&via) == metrics_json(&off),
        "metrics.json differs through the parts"
    );

    // A whole reference made with Inception, read by an evaluation without it: refused.
    let whole = p.join("whole");
    run(Args {
        stylized: None,
        reference_only: Some(ReferencePart::All),
        ..opts(&orig, &styl, &style, &whole)
    })
    .unwrap();
    let out = p.join("refused");
    let err = run(Args {
        reference: vec![whole.clone()],
        ..no_inception(&out)
    })
    .unwrap_err()
    .to_string();
    assert!(err.contains("inception true vs false"), "{err}");
    assert!(err.contains(whole.to_str().unwrap()), "{err}");
    assert!(!out.exists(), "nothing written on a refused reference");
}

/// The bytes of `metrics.json` in evaluation directory `d`.
fn metrics_json(d: &Path) -> Vec<u8> {
    std::fs::read(d.join("metrics.json")).unwrap()
}

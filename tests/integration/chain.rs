//! The stage chain is `distill`'s iteration (issue 18): K iterations through
//! `render-views --window` -> `encode-latents --fill` -> `mvfc-filter` -> `csd-step` ->
//! `update-gaussians`, from the same checkpoint, give the same bytes as `distill --iters K`
//! (scene, optimizer state, history) and, iteration by iteration, the same latents, noised
//! latents and targets as `distill --iters 1` chunks (their `last_*` tensors). With the
//! stylizer prior on a window that is part of a closed path (MVFC's mirror extension) and
//! with the tiny SD fixture (VAE, UNet, depth ControlNet) on a whole closed path (the
//! circular filter). The stages run in this process, their flags parsed as the binaries
//! parse them.

use crate::harness::repo_root;
use clap::Parser;
use fantasystyle::stages::update_gaussians;
use fantasystyle::stages::{csd_step, distill, encode_latents, mvfc_filter, render_views};
use std::path::{Path, PathBuf};

/// Parse `args` as stage `A`'s flags and run it.
fn stage<A: Parser, T>(run: fn(A) -> fantasystyle::Result<T>, name: &str, args: &[String]) -> T {
    let a = A::try_parse_from(std::iter::once(name.to_string()).chain(args.iter().cloned()))
        .unwrap_or_else(|e| panic!("{name} {args:?}: {e}"));
    run(a).unwrap_or_else(|e| panic!("{name} {args:?}: {e}"))
}

fn s(xs: &[&dyn AsRef<std::ffi::OsStr>]) -> Vec<String> {
    xs.iter()
        .map(|x| x.as_ref().to_string_lossy().into_owned())
        .collect()
}

/// The bits of a `.npy` tensor (so that -0 and 0 differ, and NaN equals itself).
fn bits(p: &Path) -> (Vec<usize>, Vec<u32>) {
    let t =
        fantasystyle_schemas::read_npy_f32(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    (t.shape, t.data.iter().map(|v| v.to_bits()).collect())
}

fn same_npy(a: &Path, b: &Path) {
    let (x, y) = (bits(a), bits(b));
    assert_eq!(x.0, y.0, "{} vs {}: shapes", a.display(), b.display());
    let first = x.1.iter().zip(&y.1).position(|(p, q)| p != q);
    assert!(
        first.is_none(),
        "{} vs {}: first difference at {first:?}",
        a.display(),
        b.display()
    );
}

fn same_bytes(a: &Path, b: &Path) {
    let (x, y) = (std::fs::read(a).unwrap(), std::fs::read(b).unwrap());
    let first = x.iter().zip(&y).position(|(p, q)| p != q);
    assert!(
        x == y,
        "{} vs {}: {} vs {} bytes, first difference at {first:?}",
        a.display(),
        b.display(),
        x.len(),
        y.len()
    );
}

/// The run's settings.
struct Case<'a> {
    model: PathBuf,
    /// Flags of the prior and the step shared by distill and csd-step.
    prior: &'a [&'a str],
    cameras: &'a str,
    size: u32,
    window: usize,
    iters: usize,
}

/// Run the chain and distill from the same start in `d` and compare them.
fn chain_equals_distill(d: &Path, c: &Case<'_>) {
    let scene = repo_root().join("data-sample/scene.ply");
    let style = repo_root().join("data-sample/style.png");
    let (size, window) = (c.size.to_string(), c.window.to_string());
    let src = d.join("source/views");
    let src_lat = d.join("source/latents");
    let model = &c.model;
    stage(
        render_views::run,
        "render-views",
        &s(&[
            &"--scene",
            &scene,
            &"--cameras",
            &c.cameras,
            &"--width",
            &size,
            &"--height",
            &size,
            &"--out",
            &src,
        ]),
    );
    stage(
        encode_latents::run,
        "encode-latents",
        &s(&[
            &"--views",
            &src,
            &"--model",
            model,
            &"--fill",
            &"--batch",
            &window,
            &"--threads",
            &"2",
            &"--out",
            &src_lat,
        ]),
    );
    let prior: Vec<String> = s(&[&"--model", model, &"--style", &style])
        .into_iter()
        .chain(c.prior.iter().map(|x| x.to_string()))
        .collect();
    let distill = |from: &str, dir: &Path, iters: usize, out: &Path| {
        let mut a = s(&[
            &from,
            &dir,
            &"--source-views",
            &src,
            &"--iters",
            &iters.to_string(),
        ]);
        a.extend(s(&[
            &"--views-per-iter",
            &window,
            &"--lr-dc",
            &"0.05",
            &"--seed",
            &"7",
        ]));
        a.extend(prior.iter().cloned());
        a.extend(s(&[&"--threads", &"2", &"--out", &out]));
        stage(distill::run, "distill", &a);
    };
    let k = |i: usize| d.join(format!("k{i}"));
    distill("--scene", &scene, 0, &k(0));
    // distill: all iterations in one process, and one per process (their last_* tensors).
    distill("--resume", &k(0), c.iters, &d.join("distill"));
    let one = |i: usize| {
        if i == 0 {
            k(0)
        } else {
            d.join(format!("d{i}"))
        }
    };
    for i in 1..=c.iters {
        distill("--resume", &one(i - 1), 1, &one(i));
    }
    // The chain.
    for i in 1..=c.iters {
        let it = d.join(format!("i{i}"));
        let (views, lat, noised, targets) = (
            it.join("views"),
            it.join("latents"),
            it.join("noised"),
            it.join("targets"),
        );
        stage(
            render_views::run,
            "render-views",
            &s(&[
                &"--scene",
                &k(i - 1),
                &"--cameras",
                &src,
                &"--width",
                &size,
                &"--height",
                &size,
                &"--window",
                &window,
                &"--seed",
                &"7",
                &"--out",
                &views,
            ]),
        );
        stage(
            encode_latents::run,
            "encode-latents",
            &s(&[
                &"--views",
                &views,
                &"--model",
                model,
                &"--fill",
                &"--alpha-from",
                &src,
                &"--batch",
                &"0",
                &"--threads",
                &"2",
                &"--out",
                &lat,
            ]),
        );
        stage(
            mvfc_filter::run,
            "mvfc-filter",
            &s(&[
                &"--latents",
                &lat,
                &"--source-latents",
                &src_lat,
                &"--model",
                model,
                &"--out",
                &noised,
            ]),
        );
        let mut a = s(&[
            &"--noised",
            &noised,
            &"--latents",
            &lat,
            &"--views",
            &views,
            &"--source-views",
            &src,
            &"--source-latents",
            &src_lat,
            &"--threads",
            &"2",
            &"--out",
            &targets,
        ]);
        a.extend(prior.iter().cloned());
        stage(csd_step::run, "csd-step", &a);
        stage(
            update_gaussians::run,
            "update-gaussians",
            &s(&[
                &"--scene",
                &k(i - 1),
                &"--cameras",
                &src,
                &"--targets",
                &targets,
                &"--lr-dc",
                &"0.05",
                &"--lr-rest",
                &"0",
                &"--ssim-weight",
                &"0",
                &"--out",
                &k(i),
            ]),
        );
        // This iteration: the same latents, noised latents and targets as distill's.
        let last = one(i);
        same_npy(&lat.join("latents.npy"), &last.join("last_z0.npy"));
        same_npy(&noised.join("z_tgt.npy"), &last.join("last_z_tgt.npy"));
        same_npy(&noised.join("z_src.npy"), &last.join("last_z_src.npy"));
        same_npy(&targets.join("rgb.npy"), &last.join("last_targets.npy"));
        for f in [
            "scene.ply",
            "adam_dc.npy",
            "adam_rest.npy",
            "state.json",
            "history.json",
        ] {
            same_bytes(&k(i).join(f), &last.join(f));
        }
    }
    // K iterations: the same scene, optimizer state and history as distill --iters K.
    for f in [
        "scene.ply",
        "adam_dc.npy",
        "adam_rest.npy",
        "state.json",
        "history.json",
    ] {
        same_bytes(&k(c.iters).join(f), &d.join("distill").join(f));
    }
    // And the colours moved: the comparison is not between two unchanged scenes.
    assert_ne!(
        std::fs::read(k(0).join("scene.ply")).unwrap(),
        std::fs::read(k(c.iters).join("scene.ply")).unwrap()
    );
}

/// The stylizer prior; windows of 3 of 4 views of an orbit (the mirror-extended filter).
#[test]
fn chain_is_distill_with_the_stylizer() {
    let Some(model) = crate::distill::stylizer_dir() else {
        return;
    };
    let t = tempfile::tempdir().unwrap();
    let case = Case {
        model,
        prior: &[],
        cameras: "orbit:4,elev=30,radius=2.4",
        size: 64,
        window: 3,
        iters: 3,
    };
    chain_equals_distill(t.path(), &case);
}

/// The tiny SD fixture (VAE, UNet through its depth ControlNet, a run-time prompt);
/// windows that are the whole closed path of 3 views (the circular filter).
#[test]
fn chain_is_distill_with_the_tiny_sd_fixture() {
    let Some(model) = crate::diffusion::tiny_sd15() else {
        return;
    };
    let t = tempfile::tempdir().unwrap();
    let case = Case {
        model,
        prior: &[
            "--prompt",
            "an ink drawing of a stone bridge",
            "--guidance",
            "3",
        ],
        cameras: "orbit:3,elev=30,radius=2.4",
        size: 64,
        window: 3,
        iters: 3,
    };
    chain_equals_distill(t.path(), &case);
}

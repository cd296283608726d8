//! The stage chain is `distill`'s iteration (issue 18): K iterations through
//! `render-views --window` -> `encode-latents --fill` -> `mvfc-filter` -> `csd-step` ->
//! `update-gaussians`, from the same checkpoint, give the same bytes as `distill --iters K`
//! (scene, optimizer state, history) and, iteration by iteration, the same latents, noised
//! latents and targets as `distill --iters 1` chunks (their `last_*` tensors). With the
//! stylizer prior on a window that is part of a closed path (MVFC's mirror extension) and
//! with the tiny SD fixture (VAE, UNet, depth ControlNet) on a whole closed path (the
//! circular filter). The stages run in this process, their flags parsed as the binaries
//! parse them.

use crate::distill::same_files;
use crate::harness::repo_root;
use clap::Parser;
use fantasystyle::stages::update_gaussians;
use fantasystyle::stages::{csd_step, distill, encode_latents, mvfc_filter, render_views};
use std::path::{Path, PathBuf};

/// Run stage `A` with the flags of `cmd` (its name, then flags separated by white space:
/// the paths of these tests have none) followed by `extra`, parsed as its binary parses
/// them.
fn stage<A: Parser, T>(run: fn(A) -> fantasystyle::Result<T>, cmd: &str, extra: &[String]) {
    let args = cmd
        .split_whitespace()
        .map(String::from)
        .chain(extra.iter().cloned());
    let a = A::try_parse_from(args).unwrap_or_else(|e| panic!("{cmd} {extra:?}: {e}"));
    if let Err(e) = run(a) {
        panic!("{cmd} {extra:?}: {e}");
    }
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

/// The run's settings.
struct Case<'a> {
    model: PathBuf,
    /// Flags of the prior and the step shared by distill and csd-step.
    prior: &'a [&'a str],
    cameras: &'a str,
    /// Views per iteration.
    window: usize,
}

/// Image size (64x64: 8x8 SD latents) and iterations.
const SIZE: u32 = 64;
const ITERS: usize = 3;

/// Run the chain and distill from the same start in `d` and compare them.
fn chain_equals_distill(d: &Path, c: &Case<'_>) {
    let (d, m, n) = (d.display(), c.model.display(), c.window);
    let root = repo_root();
    let (scene, style) = (
        root.join("data-sample/scene.ply"),
        root.join("data-sample/style.png"),
    );
    let (scene, style) = (scene.display(), style.display());
    let size = format!("--width {SIZE} --height {SIZE}");
    let (src, src_lat) = (format!("{d}/source/views"), format!("{d}/source/latents"));
    let cams = c.cameras;
    stage(
        render_views::run,
        &format!("render-views --scene {scene} --cameras {cams} {size} --out {src}"),
        &[],
    );
    stage(
        encode_latents::run,
        &format!("el --views {src} --model {m} --fill --batch {n} --threads 2 --out {src_lat}"),
        &[],
    );
    let mut prior: Vec<String> = vec!["--style".into(), style.to_string()];
    prior.extend(c.prior.iter().map(|x| x.to_string()));
    let distill = |from: &str, iters: usize, out: &str| {
        let flags = format!("--views-per-iter {n} --lr-dc 0.05 --seed 7 --threads 2");
        let cmd = format!("distill {from} --source-views {src} --model {m} --iters {iters}");
        stage(distill::run, &format!("{cmd} {flags} --out {out}"), &prior);
    };
    distill(&format!("--scene {scene}"), 0, &format!("{d}/k0"));
    // distill: all iterations in one process, and one per process (their last_* tensors).
    distill(&format!("--resume {d}/k0"), ITERS, &format!("{d}/distill"));
    let one = |i: usize| match i {
        0 => format!("{d}/k0"),
        _ => format!("{d}/d{i}"),
    };
    for i in 1..=ITERS {
        distill(&format!("--resume {}", one(i - 1)), 1, &one(i));
    }
    // The chain.
    for i in 1..=ITERS {
        let (k0, k1, it) = (
            format!("{d}/k{}", i - 1),
            format!("{d}/k{i}"),
            format!("{d}/i{i}"),
        );
        let (views, lat) = (format!("{it}/views"), format!("{it}/latents"));
        let (noised, targets) = (format!("{it}/noised"), format!("{it}/targets"));
        stage(
            render_views::run,
            &format!("rv --scene {k0} --cameras {src} {size} --window {n} --seed 7 --out {views}"),
            &[],
        );
        let fill = format!("--fill --alpha-from {src} --batch 0 --threads 2");
        stage(
            encode_latents::run,
            &format!("el --views {views} --model {m} {fill} --out {lat}"),
            &[],
        );
        let from = format!("--latents {lat} --source-latents {src_lat} --model {m}");
        stage(mvfc_filter::run, &format!("mf {from} --out {noised}"), &[]);
        let inputs = format!("--noised {noised} --latents {lat} --views {views}");
        let source = format!("--source-views {src} --source-latents {src_lat}");
        stage(
            csd_step::run,
            &format!("cs {inputs} {source} --model {m} --threads 2 --out {targets}"),
            &prior,
        );
        let step = "--lr-dc 0.05 --lr-rest 0 --ssim-weight 0";
        let from = format!("--scene {k0} --cameras {src} --targets {targets}");
        stage(
            update_gaussians::run,
            &format!("ug {from} {step} --out {k1}"),
            &[],
        );
        // This iteration: the same latents, noised latents and targets as distill's, and
        // the same checkpoint.
        let last = PathBuf::from(one(i));
        let it = PathBuf::from(it);
        same_npy(&it.join("latents/latents.npy"), &last.join("last_z0.npy"));
        same_npy(&it.join("noised/z_tgt.npy"), &last.join("last_z_tgt.npy"));
        same_npy(&it.join("noised/z_src.npy"), &last.join("last_z_src.npy"));
        same_npy(&it.join("targets/rgb.npy"), &last.join("last_targets.npy"));
        same_files(Path::new(&k1), &last);
    }
    // K iterations: the same scene, optimizer state and history as distill --iters K.
    let kk = PathBuf::from(format!("{d}/k{ITERS}"));
    same_files(&kk, &PathBuf::from(format!("{d}/distill")));
    // And the colours moved: the comparison is not between two unchanged scenes.
    assert_ne!(
        std::fs::read(format!("{d}/k0/scene.ply")).unwrap(),
        std::fs::read(kk.join("scene.ply")).unwrap()
    );
}

/// The stylizer prior; windows of 3 of 4 views of an orbit (the mirror-extended filter).
#[test]
fn chain_is_distill_with_the_stylizer() {
    if let Some(model) = crate::distill::stylizer_dir() {
        let case = Case {
            model,
            prior: &[],
            cameras: "orbit:4,elev=30,radius=2.4",
            window: 3,
        };
        chain_equals_distill(tempfile::tempdir().unwrap().path(), &case);
    }
}

/// The tiny SD fixture (VAE, UNet through its depth ControlNet, a run-time prompt);
/// windows that are the whole closed path of 3 views (the circular filter).
#[test]
fn chain_is_distill_with_the_tiny_sd_fixture() {
    if let Some(model) = crate::diffusion::tiny_sd15() {
        let prompt = [
            "--prompt",
            "an ink drawing of a stone bridge",
            "--guidance",
            "3",
        ];
        let case = Case {
            model,
            prior: &prompt,
            cameras: "orbit:3,elev=30,radius=2.4",
            window: 3,
        };
        chain_equals_distill(tempfile::tempdir().unwrap().path(), &case);
    }
}

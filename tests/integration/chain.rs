//! The stage chain is `distill`'s iteration (issue 18): K iterations through
//! `render-views --window` -> `encode-latents --fill` -> `mvfc-filter` -> `csd-step` ->
//! `update-gaussians`, from the same checkpoint, give the same bytes as `distill --iters K`
//! (scene.ply, optimizer state, state.json; the history's every field but distill's
//! agreement measurement, which only distill makes) and, iteration by iteration, the same
//! latents, noised latents and targets as `distill --iters 1` chunks (their `last_*`
//! tensors), bit for bit (no tolerance). With a texture term beside the CSD term in both
//! cases (every stage reads the same configuration); the stylizer prior on a window that is part of a closed path (MVFC's mirror
//! extension), the L2 colour loss, a motif scale of 2 and an annealed timestep; the tiny
//! SD fixture (VAE, UNet, depth ControlNet) on a whole closed path (the circular filter)
//! with the L1 colour loss. The stages run in this process, their flags parsed as the
//! binaries parse them.

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

/// Files of two checkpoints that must be the same bytes.
const SAME_FILES: [&str; 4] = ["scene.ply", "adam_dc.npy", "adam_rest.npy", "state.json"];

/// Fields of distill's history the chain does not have (its agreement measurement).
const DISTILL_ONLY: [&str; 2] = ["hf_agree_revisit", "hf_agree_adjacent"];

/// Checkpoint `chain` (update-gaussians) is checkpoint `distill`: the same bytes of
/// [`SAME_FILES`], the same history but for [`DISTILL_ONLY`] (null in the chain's).
fn same_checkpoint(chain: &Path, distill: &Path) {
    crate::distill::same_bytes(chain, distill, &SAME_FILES);
    let history = |d: &Path, drop: bool| -> Vec<serde_json::Value> {
        let s = std::fs::read_to_string(d.join("history.json")).unwrap();
        let mut h: Vec<serde_json::Value> = serde_json::from_str(&s).unwrap();
        for r in &mut h {
            let r = r.as_object_mut().unwrap();
            for k in DISTILL_ONLY {
                let v = r
                    .remove(k)
                    .unwrap_or_else(|| panic!("{}: no {k}", d.display()));
                assert!(!drop || v.is_null(), "the chain measured {k}");
            }
        }
        h
    };
    assert_eq!(history(chain, true), history(distill, false));
}

/// The run's settings.
struct Case<'a> {
    model: PathBuf,
    /// Flags of the prior shared by distill and csd-step (the prompt).
    prior: &'a [&'a str],
    /// The method's configuration (`--set KEY=VALUE`, each a pair of words), over the
    /// one every case shares ([`SHARED`]); every stage of the method gets it.
    config: &'a [&'a str],
    cameras: &'a str,
    /// Views per iteration.
    window: usize,
}

/// The configuration every case shares: the CSD term with a Gram texture term, lr_dc
/// 0.05, seed 7.
const SHARED: [&str; 6] = [
    "--set",
    "terms=csd=1,gram=1",
    "--set",
    "lr_dc=0.05",
    "--set",
    "seed=7",
];

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
    let owned = |xs: &[&str]| -> Vec<String> { xs.iter().map(|x| x.to_string()).collect() };
    let mut prior: Vec<String> = vec!["--style".into(), style.to_string()];
    prior.extend(owned(c.prior));
    let mut config = owned(&SHARED);
    config.extend(["--set".to_string(), format!("views={n}")]);
    config.extend(owned(c.config));
    let with_prior = [prior.clone(), config.clone()].concat();
    let distill = |from: &str, iters: usize, out: &str| {
        let cmd = format!("distill {from} --source-views {src} --model {m} --iters {iters}");
        stage(
            distill::run,
            &format!("{cmd} --threads 2 --out {out}"),
            &with_prior,
        );
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
        stage(
            mvfc_filter::run,
            &format!("mf {from} --out {noised}"),
            &config,
        );
        let inputs = format!("--noised {noised} --latents {lat} --views {views}");
        let source = format!("--source-views {src} --source-latents {src_lat}");
        stage(
            csd_step::run,
            &format!("cs {inputs} {source} --model {m} --threads 2 --out {targets}"),
            &with_prior,
        );
        let from = format!("--scene {k0} --cameras {src} --targets {targets}");
        let texture = format!("--style {style} --source-views {src}");
        stage(
            update_gaussians::run,
            &format!("ug {from} {texture} --out {k1}"),
            &config,
        );
        // This iteration: the same latents, noised latents and targets as distill's, and
        // the same checkpoint.
        let last = PathBuf::from(one(i));
        let it = PathBuf::from(it);
        same_npy(&it.join("latents/latents.npy"), &last.join("last_z0.npy"));
        same_npy(&it.join("noised/z_tgt.npy"), &last.join("last_z_tgt.npy"));
        same_npy(&it.join("noised/z_src.npy"), &last.join("last_z_src.npy"));
        same_npy(&it.join("targets/rgb.npy"), &last.join("last_targets.npy"));
        same_checkpoint(Path::new(&k1), &last);
    }
    // K iterations: the same scene, optimizer state and history as distill --iters K.
    let kk = PathBuf::from(format!("{d}/k{ITERS}"));
    let all = PathBuf::from(format!("{d}/distill"));
    same_checkpoint(&kk, &all);
    // The texture term was on: distill reports its loss, and the chain the same.
    let h: Vec<serde_json::Value> =
        serde_json::from_slice(&std::fs::read(all.join("history.json")).unwrap()).unwrap();
    assert!(
        h.iter().all(|r| r["texture_loss"].as_f64().unwrap() > 0.0),
        "{h:?}"
    );
    // And the colours moved: the comparison is not between two unchanged scenes.
    assert_ne!(
        std::fs::read(format!("{d}/k0/scene.ply")).unwrap(),
        std::fs::read(kk.join("scene.ply")).unwrap()
    );
}

/// The stylizer prior; windows of 3 of 4 views of an orbit (the mirror-extended filter),
/// motif scale 2, the timestep annealed over 4 iterations, L2 (the default).
#[test]
fn chain_is_distill_with_the_stylizer() {
    if let Some(model) = crate::distill::stylizer_dir() {
        let case = Case {
            model,
            prior: &[],
            config: &["--set", "motif_scale=2", "--set", "anneal_iters=4"],
            cameras: "orbit:4,elev=30,radius=2.4",
            window: 3,
        };
        chain_equals_distill(tempfile::tempdir().unwrap().path(), &case);
    }
}

/// The tiny SD fixture (VAE, UNet through its depth ControlNet, a run-time prompt);
/// windows that are the whole closed path of 3 views (the circular filter); the L1
/// colour loss.
#[test]
fn chain_is_distill_with_the_tiny_sd_fixture() {
    if let Some(model) = crate::diffusion::tiny_sd15() {
        let case = Case {
            model,
            prior: &["--prompt", "an ink drawing of a stone bridge"],
            config: &["--set", "csd.guidance=3", "--set", "colour_loss=l1"],
            cameras: "orbit:3,elev=30,radius=2.4",
            window: 3,
        };
        chain_equals_distill(tempfile::tempdir().unwrap().path(), &case);
    }
}

/// The weight-free patch prior (priors/patch: its source-and-coverage control image, its
/// banks rebuilt by each stage process); windows of 2 of 4 views.
#[test]
fn chain_is_distill_with_the_patch_prior() {
    let case = Case {
        model: crate::patch_prior::patch_dir(),
        prior: &[],
        config: &[],
        cameras: "orbit:4,elev=30,radius=2.4",
        window: 2,
    };
    chain_equals_distill(tempfile::tempdir().unwrap().path(), &case);
}

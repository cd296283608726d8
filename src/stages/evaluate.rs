//! `evaluate`: compare a stylized views artifact with the original one and the style image,
//! and write an `evaluation` artifact (`metrics.json`, `report.html`). With
//! `--reference-only` it writes instead the `eval-reference` artifact of the original
//! views and the style ([`crate::metrics::reference`]), which `--reference` then reuses;
//! `--reference-only source` and `--reference-only style` write its two parts
//! (`eval-source`: the original views' alone; `eval-style`: the style image's alone), which
//! `--reference SOURCE --reference STYLE` reads together ([`crate::artifacts::eval`]).
//!
//! The metrics are [`crate::metrics::evaluate`] (FantasyStyle's experiments: LPIPS_content,
//! FID/KID, ArtFID, short/long-range consistency, Gram distance), the page
//! [`crate::metrics::report::evaluation_report`]; the metric networks come from the
//! models directory ([`crate::models`]).

use super::Threads;
use crate::artifacts::{ReferenceFor, read_view_set};
use crate::imageio::Image;
use crate::metrics::evaluate::{Metrics, evaluate};
use crate::metrics::html::fmt_opt;
use crate::metrics::nets::LpipsNet;
use crate::metrics::reference::EvalParams;
use crate::metrics::reference::Reference;
use crate::metrics::report::{ReportExtras, ReportPaths, evaluation_report};
use crate::metrics::views::{Preview, ViewSet};
use crate::sweep::Sweep;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, Producer};
use std::path::{Path, PathBuf};

/// Measure a stylized view set against the original views and the style image: LPIPS,
/// FID/KID (style and content), ArtFID, short/long-range view consistency, Gram distance.
/// Writes an evaluation artifact (metrics.json, report.html).
#[derive(clap::Parser, Debug, Clone)]
#[command(name = "evaluate", version)]
pub struct Args {
    /// Views artifact of the original (unstylized) scene.
    #[arg(long, required_unless_present = "cameras")]
    pub original: Option<PathBuf>,
    /// Views artifact of the stylized scene, rendered from the same cameras.
    #[arg(long, required_unless_present = "reference_only")]
    pub stylized: Option<PathBuf>,
    /// The style image (PNG or JPEG); not taken by `--reference-only source`.
    #[arg(long)]
    pub style: Option<PathBuf>,
    /// Output evaluation artifact directory (written atomically).
    #[arg(long)]
    pub out: PathBuf,
    /// Write only the part of the evaluation that depends on --original and --style to
    /// --out, for --reference to reuse: `all` (the default; an `eval-reference` artifact:
    /// their Inception features, the Gram matrices, the original's own scores), `source`
    /// (an `eval-source` artifact: what depends on --original alone) or `style` (an
    /// `eval-style` artifact: what depends on --style alone, given the views' count and
    /// size by --original or by --cameras, --width and --height).
    #[arg(long, value_enum, value_name = "PART", num_args = 0..=1, default_missing_value = "all",
          conflicts_with_all = ["stylized", "reference", "sweep", "original_scene", "history", "preview"])]
    pub reference_only: Option<ReferencePart>,
    /// An `eval-reference` artifact (`--reference-only`), or, given twice, an `eval-source`
    /// and an `eval-style` artifact (`--reference-only source`, `--reference-only
    /// style`), made from the same --original, --style and options: their part is read
    /// instead of computed (about 120 of the 152 Inception passes of an 8-view
    /// evaluation). The metrics are the same bit for bit.
    #[arg(long)]
    pub reference: Vec<PathBuf>,
    /// `--reference-only style` without --original: the cameras the views are rendered
    /// from (as render-views' --cameras; only their count is read).
    #[arg(long, requires_all = ["reference_only", "width", "height"], conflicts_with = "original")]
    pub cameras: Option<String>,
    /// With --cameras: the views' width and height, pixels.
    #[arg(long, requires = "cameras")]
    pub width: Option<usize>,
    #[arg(long, requires = "cameras")]
    pub height: Option<usize>,
    /// LPIPS backbone for LPIPS_content and the consistency metrics.
    #[arg(long, value_enum, default_value = "alex")]
    pub lpips_net: LpipsNet,
    /// View offset of the short-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 1)]
    pub short_range: usize,
    /// View offset of the long-range consistency pairs (i, i+k).
    #[arg(long, default_value_t = 5)]
    pub long_range: usize,
    /// Seed of the style-image crops used by FID_style and of the object KID's squares.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Squares (32 px, inside the object) per view for the KID of the object's surface
    /// against the style's; 0 skips that measure (its Inception passes, about 80 ms each,
    /// are most of its cost).
    #[arg(long, default_value_t = crate::metrics::texture::PATCHES_PER_VIEW)]
    pub object_squares: usize,
    /// The style's shorter side in render pixels the stylization laid it at (the end's
    /// `texture.style_size`): motif contrast and style texture compare the object's
    /// band-pass contrast with the style's at this size.
    #[arg(long, default_value_t = crate::metrics::interior::STYLE_SHORTER_SIDE)]
    pub style_size: usize,
    /// Compute the Inception measures: FID and KID against the style crops and the
    /// original views, ArtFID, and the object KID. `false` skips them and Inception
    /// itself, most of an evaluation's time; the other measures are the same bit for bit.
    /// The sample DAG's default is `false` (its params.toml `eval.inception`): at 8 to 16
    /// views FID is biased and KID noisy, so they are for the quality benchmarks.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub inception: bool,
    #[command(flatten)]
    pub threads: Threads,
    /// A sweep.json (from the `sweep` stage) to include as the speed-accuracy section.
    #[arg(long)]
    pub sweep: Option<PathBuf>,
    /// The original scene (.ply, .splat, .spz or a scene artifact): with
    /// --stylized-scene, the report gets an interactive 3D viewer of the two side by side.
    #[arg(long, requires = "stylized_scene")]
    pub original_scene: Option<PathBuf>,
    /// The stylized scene (a scene artifact with scene.spz is embedded as written).
    #[arg(long, requires = "original_scene")]
    pub stylized_scene: Option<PathBuf>,
    /// A distill checkpoint whose history.json's agreement of the prior's high-frequency
    /// change (across visits, between neighbouring views) the report draws per iteration.
    /// Without it, the --stylized-scene's history when it is a checkpoint (a loop ran);
    /// none when no loop ran.
    #[arg(long)]
    pub history: Option<PathBuf>,
    /// A views artifact of the prior's 2D stylization of some of the --original views
    /// (the `preview` stage's; its manifest's producer params name them as "views"): the
    /// report's opening pictures show it beside the original and stylized views.
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// A `stylize-baseline --method refit` artifact: its per-view stylizations' agreement
    /// between neighbouring views is drawn as the ceiling (needs --history).
    #[arg(long, requires = "history")]
    pub refit_baseline: Option<PathBuf>,
}

pub use crate::metrics::reference::ReferencePart;

impl Args {
    /// What `--reference-only` reads of these flags.
    fn reference_request(&self) -> super::evaluate_reference::Request {
        super::evaluate_reference::Request {
            original: self.original.clone(),
            style: self.style.clone(),
            cameras: self.cameras.clone(),
            width: self.width,
            height: self.height,
            out: self.out.clone(),
        }
    }
}

/// The stage: read the views and the style, evaluate (or compute the reference only,
/// then `None`), write the artifact.
pub fn run(a: Args) -> Result<Option<Metrics>> {
    let p = eval_params(&a);
    p.validate()?;
    if let Some(part) = a.reference_only {
        return super::evaluate_reference::run(&a.reference_request(), part, &p).map(|()| None);
    }
    let (original, stylized, style_path) = evaluation_inputs(&a)?;
    let orig = crate::timing::load(|| read_view_set(original))?;
    let styl = crate::timing::load(|| read_view_set(stylized))?;
    orig.check_same_views(&styl)?;
    let style = Image::load(style_path)?;
    let reference = (!a.reference.is_empty())
        .then(|| {
            let dirs = ReferenceFor {
                dirs: &a.reference,
                original,
                style: style_path,
                lpips_net: p.lpips_net.name(),
            };
            crate::timing::load(|| reference_for(dirs, &orig, &p))
        })
        .transpose()?;
    let sweep = a.sweep.as_deref().map(Sweep::load).transpose()?;
    let viewer = match (&a.original_scene, &a.stylized_scene) {
        (Some(o), Some(s)) => Some(crate::timing::load(|| viewer_inputs(o, s, &orig))?),
        _ => None,
    };
    let history = history_of(&a)
        .as_deref()
        .map(crate::distill::checkpoint::read_history)
        .transpose()?;
    let ceiling = refit_ceiling(&a)?;
    let preview = a
        .preview
        .as_deref()
        .map(|d| crate::timing::load(|| read_preview(d, &orig)))
        .transpose()?;
    let models = crate::models::metric_models()?;
    let regions = regions_of(&a, &orig, &styl, &models, p.threads)?;
    // Start the artifact now so an unusable --out fails before the slow part.
    let mut wr = super::create_artifact(
        &a.out,
        ArtifactKind::Evaluation,
        Producer::new("evaluate", crate::VERSION, p.to_json()),
    )?;
    let ev = evaluate(
        &models,
        &orig,
        &styl,
        &style,
        &p,
        reference.as_ref().map(|(_, r)| r),
    )?;
    let paths = ReportPaths {
        original,
        stylized,
        style: style_path,
    };
    let ph = crate::timing::span("report");
    let sweep_html = sweep.as_ref().map(Sweep::html);
    let regions_html = regions.as_ref().map(|r| r.html(&orig, &styl));
    let agreement_html = history
        .as_deref()
        .map(|h| crate::metrics::report::agreement_html(h, ceiling, 20));
    let extras = ReportExtras {
        sweep_html: sweep_html.as_deref(),
        viewer_html: viewer.as_deref(),
        agreement_html: agreement_html.as_deref(),
        preview: preview.as_ref(),
        regions_html: regions_html.as_deref(),
    };
    let html = evaluation_report(paths, &ev, &orig, &styl, &style, &extras);
    drop(ph);

    add_inputs(&mut wr, &a)?;
    wr.write_json("metrics.json", &ev.metrics)?;
    if let Some(r) = &regions {
        wr.write_json("regions.json", r)?;
    }
    wr.write_bytes("report.html", html.as_bytes())?;
    crate::timing::io(|| wr.commit())?;
    log_metrics(&ev.metrics, &a.out);
    Ok(Some(ev.metrics))
}

/// An evaluation's `--original`, `--stylized` and `--style` (clap requires them without
/// `--reference-only`; `--cameras` is only for the style part).
fn evaluation_inputs(a: &Args) -> Result<(&Path, &Path, &Path)> {
    if a.cameras.is_some() {
        return Err(Error::param(
            "--cameras, --width and --height are only for `--reference-only style`",
        ));
    }
    match (&a.original, &a.stylized, &a.style) {
        (Some(o), Some(s), Some(st)) => Ok((o, s, st)),
        _ => Err(Error::param(
            "an evaluation needs --original, --stylized and --style",
        )),
    }
}

/// The regions of `--stylized-scene` measured on the views (none without regions).
fn regions_of(
    a: &Args,
    orig: &ViewSet,
    styl: &ViewSet,
    models: &Path,
    threads: usize,
) -> Result<Option<crate::metrics::regions::Regions>> {
    let (Some(o), Some(s)) = (&a.original_scene, &a.stylized_scene) else {
        return Ok(None);
    };
    let Some(rec) = crate::artifacts::read_regions(s)? else {
        return Ok(None);
    };
    let scene = crate::timing::load(|| crate::artifacts::load_scene(o))?;
    crate::metrics::regions::measure(&rec, &scene, orig, styl, models, threads).map(Some)
}

/// The evaluation's parameters from the command line.
fn eval_params(a: &Args) -> EvalParams {
    EvalParams {
        lpips_net: a.lpips_net,
        short_range: a.short_range,
        long_range: a.long_range,
        seed: a.seed,
        object_squares: a.object_squares,
        inception: a.inception,
        threads: a.threads.n,
        style_size: a.style_size,
    }
}

/// The headline metrics, logged.
fn log_metrics(m: &Metrics, out: &std::path::Path) {
    tracing::info!(
        "evaluate: LPIPS_content {} structure kept {} interior structure {} edge recall {} \
         motif contrast {} style texture {} FID_style {} ArtFID {} short-range LPIPS {} -> {}",
        fmt_opt(m.lpips_content, 4),
        fmt_opt(m.structure_kept, 3),
        fmt_opt(m.interior.interior_structure, 3),
        fmt_opt(m.interior.edge_recall, 3),
        fmt_opt(m.interior.motif_contrast, 3),
        fmt_opt(m.interior.style_texture, 3),
        fmt_opt(m.fid_style.value, 2),
        fmt_opt(m.artfid, 2),
        fmt_opt(m.short_range.lpips_mean, 4),
        out.display()
    );
}

/// The agreement ceiling of `--refit-baseline`: its stylizations' and the original
/// renders' own high-frequency agreement between neighbouring views.
fn refit_ceiling(a: &Args) -> Result<Option<(f64, Option<f64>)>> {
    let Some(dir) = &a.refit_baseline else {
        return Ok(None);
    };
    let log = crate::artifacts::read_baseline_log(dir)?;
    match log["hf_agree_adjacent"].as_f64() {
        Some(c) => Ok(Some((c, log["hf_agree_adjacent_original"].as_f64()))),
        None => Err(Error::input(
            dir.join("loss.json"),
            "no hf_agree_adjacent: not a refit baseline (stylize-baseline \
             --method refit) of this version",
        )),
    }
}

/// Record the evaluation's inputs (the reference artifacts read among them).
fn add_inputs(wr: &mut fantasystyle_schemas::ArtifactWriter, a: &Args) -> Result<()> {
    for (role, path) in [
        ("original", &a.original),
        ("stylized", &a.stylized),
        ("style", &a.style),
    ] {
        if let Some(path) = path {
            wr.add_input(role, path)?;
        }
    }
    for dir in &a.reference {
        wr.add_input("reference", dir)?;
    }
    if let (Some(o), Some(s)) = (&a.original_scene, &a.stylized_scene) {
        wr.add_input("original-scene", o)?;
        wr.add_input("stylized-scene", s)?;
    }
    if let Some(h) = &a.history {
        wr.add_input("history", h)?;
    }
    if let Some(r) = &a.refit_baseline {
        wr.add_input("refit-baseline", r)?;
    }
    if let Some(p) = &a.preview {
        wr.add_input("preview", p)?;
    }
    Ok(())
}

/// `--preview DIR`: its views, matched to the evaluation views its manifest's producer
/// params name (`"views": [indices]`; without them, every view in order) and checked
/// against them ([`Preview::new`]).
fn read_preview(dir: &Path, orig: &ViewSet) -> Result<Preview> {
    let views = read_view_set(dir)?;
    let art = fantasystyle_schemas::Artifact::open_unverified(dir)?;
    let named = &art.manifest.producer.params["views"];
    let indices = if named.is_null() {
        None
    } else {
        let ix: Option<Vec<usize>> = named.as_array().and_then(|v| {
            v.iter()
                .map(|x| x.as_u64().and_then(|x| usize::try_from(x).ok()))
                .collect()
        });
        Some(ix.ok_or_else(|| {
            Error::input(
                dir.join("manifest.json"),
                format!("producer params \"views\" is not a list of view indices: {named}"),
            )
        })?)
    };
    Preview::new(views, indices, orig)
}

/// `--reference DIR...`, read ([`crate::artifacts::read_references`]) and checked to be
/// made from this evaluation's original views, style image and options.
fn reference_for(
    dirs: ReferenceFor<'_>,
    orig: &ViewSet,
    p: &EvalParams,
) -> Result<(PathBuf, Reference)> {
    let (dir, r) = crate::artifacts::read_references(dirs)?;
    r.check(&dir, orig, p)?;
    Ok((dir, r))
}

/// The report's 3D viewer section for the two scenes, starting at the first original
/// view ([`crate::metrics::viewer`]); with a note instead when the viewer library is not
/// installed. The background is the one the original views were rendered over.
fn viewer_inputs(original: &Path, stylized: &Path, orig: &ViewSet) -> Result<String> {
    use crate::metrics::viewer::{self, ViewerCamera};
    let (o, scene) = crate::artifacts::read_viewer_scene("original", original)?;
    let (s, _) = crate::artifacts::read_viewer_scene("stylized", stylized)?;
    let cam = ViewerCamera::from_views(&orig.cameras, &scene);
    let background = fantasystyle_schemas::Artifact::open_unverified(&orig.dir)
        .ok()
        .and_then(|a| {
            serde_json::from_value::<[f32; 3]>(a.manifest.meta["background"].clone()).ok()
        })
        .unwrap_or([0.0; 3]);
    let bundle = match viewer::bundle_path() {
        Some(p) => Some(viewer::load_bundle(&p)?),
        None => {
            tracing::warn!(
                "evaluate: the viewer library is not installed (scripts/setup/50_viewer.sh); \
                 the report says so instead of showing the 3D viewer"
            );
            None
        }
    };
    Ok(viewer::section_html(
        bundle.as_deref(),
        &[o, s],
        &cam,
        background,
    ))
}

/// Where the loop's history comes from: `--history`, else the stylized scene when it is a
/// checkpoint that holds one (no loop ran: none).
fn history_of(a: &Args) -> Option<PathBuf> {
    let holds = |d: &&PathBuf| {
        crate::artifacts::is_artifact(d)
            && d.join(crate::distill::checkpoint::CHECKPOINT_HISTORY)
                .is_file()
    };
    a.history
        .clone()
        .or_else(|| a.stylized_scene.as_ref().filter(holds).cloned())
}

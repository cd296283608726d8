//! `evaluate --reference-only [all|source|style]`: the part of an evaluation that does
//! not depend on the stylized views, written for `--reference` to reuse
//! ([`crate::metrics::reference`]): `all` the whole `eval-reference` artifact, `source`
//! the `eval-source` part (the original views alone), `style` the `eval-style` part (the
//! style image alone, for the views' count and size, which `--original` or `--cameras`,
//! `--width` and `--height` give). The networks load as the phase `models` (one child
//! per network), counted as load time.

use crate::artifacts::read_view_set;
use crate::imageio::Image;
use crate::metrics::nets::{LpipsNet, Nets};
use crate::metrics::reference::ReferencePart;
use crate::metrics::reference::{
    EvalParams, Reference, Settings, SourceReference, StyleReference, StyleSettings,
};
use crate::metrics::views::ViewSet;
use crate::models::metric_models;
use crate::{Error, Result};
use fantasystyle_schemas::{ArtifactKind, ArtifactWriter, Producer};
use std::path::Path;
use std::path::PathBuf;

/// What `evaluate --reference-only` was given (the stage's flags of the same names).
#[derive(Debug, Clone)]
pub(super) struct Request {
    pub original: Option<PathBuf>,
    pub style: Option<PathBuf>,
    pub cameras: Option<String>,
    pub width: Option<usize>,
    pub height: Option<usize>,
    pub out: PathBuf,
}

/// Write the `part` of the reference `a` asks for to `--out`.
pub(super) fn run(a: &Request, part: ReferencePart, p: &EvalParams) -> Result<()> {
    if part != ReferencePart::Style && a.cameras.is_some() {
        return Err(Error::param(
            "--cameras, --width and --height are only for `--reference-only style` (the other \
             parts read the views from --original)",
        ));
    }
    match part {
        ReferencePart::All => {
            let (original, style) = (need_original(a)?, need_style(a, part)?);
            let orig = crate::timing::load(|| read_view_set(original))?;
            let style_image = crate::timing::load(|| Image::load(style))?;
            let mut wr = create(a, ArtifactKind::EvalReference, p.to_json())?;
            let mut nets = load_nets(p.lpips_net, p)?;
            let r = Reference::compute(&mut nets, &orig, &style_image, p)?;
            wr.add_input("original", original)?;
            wr.add_input("style", style)?;
            crate::artifacts::write_eval_reference(&mut wr, &r)?;
            commit(wr, a, "reference", orig.n)
        }
        ReferencePart::Source => {
            if a.style.is_some() {
                return Err(Error::param(
                    "`--reference-only source` does not take --style: the source part does not \
                     depend on it (`--reference-only style` makes the style's part)",
                ));
            }
            let original = need_original(a)?;
            let orig = crate::timing::load(|| read_view_set(original))?;
            let mut params = p.to_json();
            params["part"] = "source".into();
            let mut wr = create(a, ArtifactKind::EvalSource, params)?;
            let mut nets = load_nets(p.lpips_net, p)?;
            let r = SourceReference::compute(&mut nets, &orig, p)?;
            wr.add_input("original", original)?;
            crate::artifacts::write_eval_source(&mut wr, &r)?;
            commit(wr, a, "source part", orig.n)
        }
        ReferencePart::Style => run_style(a, p),
    }
}

/// `--reference-only style`.
fn run_style(a: &Request, p: &EvalParams) -> Result<()> {
    let style = need_style(a, ReferencePart::Style)?;
    let settings = style_settings(a, p)?;
    let style_image = crate::timing::load(|| Image::load(style))?;
    let mut wr = create(
        a,
        ArtifactKind::EvalStyle,
        serde_json::json!({"part": "style", "settings": &settings}),
    )?;
    // VGG16 and Inception only: VGG16 as the LPIPS backbone loads no AlexNet.
    let mut nets = load_nets(LpipsNet::Vgg16, p)?;
    let views = settings.views;
    let r = StyleReference::compute(&mut nets, &style_image, settings)?;
    wr.add_input("style", style)?;
    match (&a.original, &a.cameras) {
        (Some(o), _) => wr.add_input("original", o)?,
        (None, Some(c)) => super::add_cameras_input(&mut wr, c)?,
        (None, None) => {}
    }
    crate::artifacts::write_eval_style(&mut wr, &r)?;
    commit(wr, a, "style part", views)
}

/// What the style part is made for: the views' count and size from `--original`, or
/// from `--cameras` (their count), `--width` and `--height`.
fn style_settings(a: &Request, p: &EvalParams) -> Result<StyleSettings> {
    let s = |views, width, height| {
        StyleSettings::of(&Settings {
            views,
            width,
            height,
            short_range: p.short_range,
            long_range: p.long_range,
            seed: p.seed,
            object_squares: p.object_squares,
            inception: p.inception,
        })
    };
    match (&a.original, &a.cameras, a.width, a.height) {
        (Some(o), ..) => {
            let v: ViewSet = crate::timing::load(|| read_view_set(o))?;
            Ok(s(v.n, v.width, v.height))
        }
        (None, Some(c), Some(w), Some(h)) if w > 0 && h > 0 => {
            Ok(s(crate::camera::count_cameras(c)?, w, h))
        }
        _ => Err(Error::param(
            "`--reference-only style` needs the views' count and size: --original VIEWS, or \
             --cameras SPEC --width W --height H (both at least 1)",
        )),
    }
}

fn need_original(a: &Request) -> Result<&Path> {
    a.original
        .as_deref()
        .ok_or_else(|| Error::param("this part of the reference needs --original"))
}

fn need_style(a: &Request, part: ReferencePart) -> Result<&Path> {
    a.style.as_deref().ok_or_else(|| {
        Error::param(format!(
            "`--reference-only {}` needs --style",
            if part == ReferencePart::All {
                "all"
            } else {
                "style"
            }
        ))
    })
}

/// Start the artifact now, so that an unusable --out fails before the slow part.
fn create(a: &Request, kind: ArtifactKind, params: serde_json::Value) -> Result<ArtifactWriter> {
    super::create_artifact(
        &a.out,
        kind,
        Producer::new("evaluate", crate::VERSION, params),
    )
}

/// The metric networks (the models directory's; Inception as `p` says), timed as the
/// phase `models`.
fn load_nets(net: LpipsNet, p: &EvalParams) -> Result<Nets> {
    let models = metric_models()?;
    crate::timing::load(|| {
        crate::timing::phase("models", || {
            Nets::load(&models, net, p.inception, p.threads)
        })
    })
}

fn commit(wr: ArtifactWriter, a: &Request, what: &str, views: usize) -> Result<()> {
    crate::timing::io(|| wr.commit())?;
    tracing::info!("evaluate: {what} for {views} views -> {}", a.out.display());
    Ok(())
}

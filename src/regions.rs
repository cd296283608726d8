//! Regions: several styles in one run (issue 54; docs/selection.md, "Regions"). A region
//! is a selection of the scene's Gaussians, a style (one image, or a blend of weighted
//! images, `a.png:0.7,b.png:0.3`) and a strength (how far its pixels move toward the
//! style, the guidance scale's factor). The patch end synthesises every region in one
//! pass ([`crate::ends::patches::regions`]): the renders, the queries and the colour fit
//! are shared; each region has its own style bank, search and balance.
//!
//! Written as `[[regions]]` entries of a TOML file (`distill --regions FILE`, paths
//! relative to the file) or as `--region SELECTION[=STYLE][@STRENGTH]` flags (paths as
//! typed). A selection is a `selection` artifact (written by `select`), a source of
//! [`crate::selection::SOURCES`] (`box:...`, `ellipsoid:...`, `half-space:...`,
//! `masks:DIR`), or `rest`: every Gaussian the other regions leave.
//!
//! Where weights overlap past 1 they are normalised (each region's weight over their
//! sum) and the run says how many Gaussians; a Gaussian in no region keeps its bytes
//! (its weight in the combined selection is 0).

use crate::imageio::Image;
use crate::selection::{Context, Selection};
use crate::{Error, Result, Scene};
use std::path::{Path, PathBuf};

/// One region as written.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// Its name in messages and the report (default `region N`, from 1).
    #[serde(default)]
    pub name: Option<String>,
    /// Its Gaussians: a selection artifact, a selection source `KIND:SPEC`, or `rest`.
    pub selection: String,
    /// Its style: an image, or weighted images `a.png:0.7,b.png:0.3` (default: the run's
    /// `--style`).
    #[serde(default)]
    pub style: Option<String>,
    /// How far its pixels move toward its style, in [0, 1] (1: all the way).
    #[serde(default = "full")]
    pub strength: f32,
}

fn full() -> f32 {
    1.0
}

/// A regions file: `[[regions]]` entries.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RegionsFile {
    regions: Vec<RegionSpec>,
}

impl RegionSpec {
    /// A `--region` flag: `SELECTION[=STYLE][@STRENGTH]`.
    pub fn parse(s: &str) -> std::result::Result<RegionSpec, String> {
        let (rest, strength) = match s.rsplit_once('@') {
            Some((a, b)) => (
                a,
                b.trim()
                    .parse::<f32>()
                    .map_err(|_| format!("`{s}`: the strength after `@` is not a number"))?,
            ),
            None => (s, 1.0),
        };
        let (selection, style) = match rest.split_once('=') {
            Some((a, b)) => (a, Some(b.to_string())),
            None => (rest, None),
        };
        if selection.trim().is_empty() {
            return Err(format!("`{s}`: no selection before `=`"));
        }
        Ok(RegionSpec {
            name: None,
            selection: selection.to_string(),
            style,
            strength,
        })
    }

    /// The `[[regions]]` of file `path`, their paths taken from the file's directory.
    pub fn read_file(path: &Path) -> Result<Vec<RegionSpec>> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let file: RegionsFile =
            toml::from_str(&text).map_err(|e| Error::input(path, format!("regions: {e}")))?;
        let dir = path.parent().unwrap_or(Path::new(""));
        Ok(file
            .regions
            .into_iter()
            .map(|mut r| {
                r.selection = relative_selection(&r.selection, dir);
                r.style = r.style.map(|s| relative_blend(&s, dir));
                r
            })
            .collect())
    }
}

/// A selection spec of a file at `dir`: a path (or a `masks:` directory) taken from it.
fn relative_selection(s: &str, dir: &Path) -> String {
    if s == REST {
        return s.to_string();
    }
    match s.split_once(':') {
        Some(("masks", d)) => format!("masks:{}", dir.join(d).display()),
        Some((kind, _)) if crate::selection::SOURCES.iter().any(|k| k.name == kind) => {
            s.to_string()
        }
        _ => dir.join(s).display().to_string(),
    }
}

/// A blend of a file at `dir`: each image's path taken from it.
fn relative_blend(s: &str, dir: &Path) -> String {
    s.split(',')
        .map(|part| match split_weight(part) {
            (p, Some(w)) => format!("{}:{w}", dir.join(p).display()),
            (p, None) => dir.join(p).display().to_string(),
        })
        .collect::<Vec<_>>()
        .join(",")
}

/// `path:weight` -> (path, weight); a part whose tail after the last `:` is not a
/// number is a path alone.
fn split_weight(part: &str) -> (&str, Option<f32>) {
    match part.rsplit_once(':') {
        Some((p, w)) => match w.trim().parse::<f32>() {
            Ok(w) => (p.trim(), Some(w)),
            Err(_) => (part.trim(), None),
        },
        None => (part.trim(), None),
    }
}

/// The selection spec of the Gaussians no other region has.
pub const REST: &str = "rest";

/// A blend's images and weights as written: `a.png:0.7,b.png:0.3` (a path alone weighs
/// 1). Checked: no negative or non-finite weight, not all zero, no image twice; the
/// weights normalised to sum 1. A part of weight 0 stays (its image is read and the
/// report measures the result against it) but adds nothing to the synthesis.
pub fn parse_blend(s: &str) -> std::result::Result<Vec<(PathBuf, f32)>, String> {
    let mut parts: Vec<(PathBuf, f32)> = Vec::new();
    for part in s.split(',') {
        let (path, w) = split_weight(part);
        let w = w.unwrap_or(1.0);
        if path.is_empty() {
            return Err(format!("`{s}`: an empty image path"));
        }
        if !(w.is_finite() && w >= 0.0) {
            return Err(format!(
                "`{s}`: weight {w} of {path} is negative or not finite"
            ));
        }
        if parts.iter().any(|(p, _)| p == Path::new(path)) {
            return Err(format!("`{s}`: {path} is named twice"));
        }
        parts.push((PathBuf::from(path), w));
    }
    let sum: f32 = parts.iter().map(|p| p.1).sum();
    if sum <= 0.0 {
        return Err(format!("`{s}`: every weight is 0"));
    }
    Ok(parts.into_iter().map(|(p, w)| (p, w / sum)).collect())
}

/// One region, loaded.
#[derive(Debug, Clone)]
pub struct Region {
    pub name: String,
    /// The selection as written.
    pub selection: String,
    /// Its weight per Gaussian (after the overlaps' normalisation).
    pub weights: Vec<f32>,
    /// Its style: each image's path, the image and its weight (summing to 1).
    pub styles: Vec<(PathBuf, Image, f32)>,
    pub strength: f32,
}

/// The regions of a run and what they select together.
#[derive(Debug, Clone)]
pub struct Regions {
    pub list: Vec<Region>,
    /// Each Gaussian's weight over all regions (at most 1): the colour fit's selection.
    pub combined: Selection,
    /// Gaussians whose weights summed past 1 (normalised).
    pub overlapping: usize,
}

/// The `specs` loaded for `scene`: their selections made (`ctx`: the cameras masks were
/// drawn on), their styles read (`default_style` where a region names none), checked
/// (module docs). Every error names the region.
pub fn load(
    specs: &[RegionSpec],
    scene: &Scene,
    default_style: &Path,
    ctx: &Context,
) -> Result<Regions> {
    if specs.is_empty() {
        return Err(Error::param("regions: none given"));
    }
    let names: Vec<String> = specs
        .iter()
        .enumerate()
        .map(|(i, s)| {
            s.name
                .clone()
                .unwrap_or_else(|| format!("region {}", i + 1))
        })
        .collect();
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            return Err(Error::param(format!(
                "regions: two regions are named `{n}`"
            )));
        }
    }
    if specs.iter().filter(|s| s.selection == REST).count() > 1 {
        return Err(Error::param("regions: `rest` is given twice"));
    }
    let n = scene.len();
    let mut list = specs
        .iter()
        .zip(names)
        .map(|(spec, name)| load_one(spec, name, scene, default_style, ctx))
        .collect::<Result<Vec<_>>>()?;
    let overlapping = normalise(&mut list, n);
    for r in &list {
        if r.weights.iter().all(|&w| w <= 0.0) {
            return Err(Error::param(format!(
                "region `{}`: selects no Gaussian ({})",
                r.name, r.selection
            )));
        }
    }
    let combined = (0..n)
        .map(|i| list.iter().map(|r| r.weights[i]).sum::<f32>().min(1.0))
        .collect();
    if overlapping > 0 {
        tracing::warn!(
            "regions: {overlapping} Gaussians are in regions whose weights sum past 1: each region's weight divided by the sum"
        );
    }
    Ok(Regions {
        list,
        combined: Selection { weights: combined },
        overlapping,
    })
}

/// One region of `spec`, named `name`: its strength checked, its selection made (`rest`:
/// none yet, [`normalise`] fills it), its styles read. Errors name the region.
fn load_one(
    spec: &RegionSpec,
    name: String,
    scene: &Scene,
    default_style: &Path,
    ctx: &Context,
) -> Result<Region> {
    let err = |e: Error| match e {
        Error::Param(m) => Error::param(format!("region `{name}`: {m}")),
        Error::Input { path, reason } => Error::input(path, format!("region `{name}`: {reason}")),
        other => Error::param(format!("region `{name}`: {other}")),
    };
    if !(spec.strength.is_finite() && (0.0..=1.0).contains(&spec.strength)) {
        return Err(err(Error::param(format!(
            "strength {} is outside [0, 1]",
            spec.strength
        ))));
    }
    let weights = if spec.selection == REST {
        Vec::new()
    } else {
        select(&spec.selection, scene, ctx).map_err(err)?.weights
    };
    let blend = match &spec.style {
        Some(s) => parse_blend(s).map_err(|e| err(Error::param(e)))?,
        None => vec![(default_style.to_path_buf(), 1.0)],
    };
    let styles = blend
        .into_iter()
        .map(|(p, w)| {
            crate::imageio::load_style(&p, crate::imageio::MIN_STYLE_SIDE)
                .map(|img| (p, img, w))
                .map_err(err)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Region {
        name,
        selection: spec.selection.clone(),
        weights,
        styles,
        strength: spec.strength,
    })
}

/// The regions' weights where they sum past 1 divided by the sum, then `rest` given
/// what is left, over a scene of `n` Gaussians; how many Gaussians were normalised.
fn normalise(list: &mut [Region], n: usize) -> usize {
    let mut overlapping = 0;
    let mut sum = vec![0.0f32; n];
    for r in list.iter().filter(|r| r.selection != REST) {
        for (s, w) in sum.iter_mut().zip(&r.weights) {
            *s += w;
        }
    }
    for (i, &s) in sum.iter().enumerate() {
        if s > 1.0 {
            overlapping += 1;
            for r in list.iter_mut().filter(|r| r.selection != REST) {
                r.weights[i] /= s;
            }
        }
    }
    for r in list.iter_mut().filter(|r| r.selection == REST) {
        r.weights = sum.iter().map(|&s| 1.0 - s.min(1.0)).collect();
    }
    overlapping
}

/// The selection `spec` of `scene`: a selection artifact directory or a source.
fn select(spec: &str, scene: &Scene, ctx: &Context) -> Result<Selection> {
    let dir = Path::new(spec);
    let sel = if dir.is_dir() {
        crate::artifacts::read_selection(dir)?
    } else {
        crate::selection::parse_source(spec)?.make(scene, ctx)?
    };
    if sel.len() != scene.len() {
        return Err(Error::input(
            dir,
            format!(
                "selection of {} Gaussians, but the scene has {}",
                sel.len(),
                scene.len()
            ),
        ));
    }
    Ok(sel)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_region_flag_reads_selection_style_and_strength() {
        let r = RegionSpec::parse("runs/sphere=a.png:0.7,b.png:0.3@0.5").unwrap();
        assert_eq!(r.selection, "runs/sphere");
        assert_eq!(r.style.as_deref(), Some("a.png:0.7,b.png:0.3"));
        assert_eq!(r.strength, 0.5);
        let r = RegionSpec::parse("rest").unwrap();
        assert_eq!(
            (r.selection.as_str(), r.style, r.strength),
            ("rest", None, 1.0)
        );
        assert!(RegionSpec::parse("=a.png").is_err());
        assert!(RegionSpec::parse("rest@lots").is_err());
    }

    #[test]
    fn a_blend_is_checked_and_normalised() {
        let b = parse_blend("a.png:3,b.png:1").unwrap();
        assert_eq!(b, vec![("a.png".into(), 0.75), ("b.png".into(), 0.25)]);
        assert_eq!(parse_blend("a.png").unwrap(), vec![("a.png".into(), 1.0)]);
        assert_eq!(
            parse_blend("a.png:1,b.png:0").unwrap(),
            vec![("a.png".into(), 1.0), ("b.png".into(), 0.0)]
        );
        for bad in [
            "a.png:-1,b.png:1",
            "a.png:0,b.png:0",
            "a.png:1,a.png:2",
            ",b.png",
        ] {
            assert!(parse_blend(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_file_takes_its_paths_from_its_directory() {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("regions.toml");
        std::fs::write(
            &f,
            "[[regions]]\nselection = \"runs/sphere\"\nstyle = \"a.png:0.5,b.png:0.5\"\n\
             [[regions]]\nselection = \"box:0,0,0,1,1,1\"\nstrength = 0.5\n\
             [[regions]]\nname = \"ground\"\nselection = \"rest\"\n",
        )
        .unwrap();
        let r = RegionSpec::read_file(&f).unwrap();
        let d = dir.path().display();
        assert_eq!(r[0].selection, format!("{d}/runs/sphere"));
        assert_eq!(
            r[0].style.as_deref(),
            Some(format!("{d}/a.png:0.5,{d}/b.png:0.5").as_str())
        );
        assert_eq!(r[1].selection, "box:0,0,0,1,1,1");
        assert_eq!(
            (r[2].selection.as_str(), r[2].name.as_deref()),
            ("rest", Some("ground"))
        );
        std::fs::write(&f, "[[regions]]\nselection = \"rest\"\ncolour = 1\n").unwrap();
        let e = RegionSpec::read_file(&f).unwrap_err().to_string();
        assert!(e.contains("regions.toml") && e.contains("colour"), "{e}");
    }

    #[test]
    fn overlaps_are_normalised_and_rest_is_what_is_left() {
        let scene = crate::sample::sample_scene(1);
        let (w, h, style) = crate::sample::style_image(1);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.png");
        crate::imageio::write_png_rgb(&path, &style, w, h).unwrap();
        let spec = |sel: &str, name: &str| RegionSpec {
            name: Some(name.into()),
            selection: sel.into(),
            style: None,
            strength: 1.0,
        };
        let b = scene.bounds();
        let (lo, hi) = (b.min, b.max);
        let mid = (lo + hi) * 0.5;
        let left = format!("box:{},{},{},{},{},{}", lo.x, lo.y, lo.z, mid.x, hi.y, hi.z);
        let all = format!("box:{},{},{},{},{},{}", lo.x, lo.y, lo.z, hi.x, hi.y, hi.z);
        let ctx = Context::default();
        let r = load(&[spec(&left, "a"), spec(&all, "b")], &scene, &path, &ctx).unwrap();
        assert!(r.overlapping > 0);
        assert!(r.combined.weights.iter().all(|&w| w == 1.0));
        let i = r.list[0].weights.iter().position(|&w| w > 0.0).unwrap();
        assert_eq!((r.list[0].weights[i], r.list[1].weights[i]), (0.5, 0.5));
        let r = load(&[spec(&left, "a"), spec(REST, "b")], &scene, &path, &ctx).unwrap();
        assert_eq!(r.overlapping, 0);
        for i in 0..scene.len() {
            assert_eq!(r.list[0].weights[i] + r.list[1].weights[i], 1.0);
        }
        let e = load(&[spec(&all, "a"), spec(REST, "b")], &scene, &path, &ctx).unwrap_err();
        assert!(
            e.to_string().contains("region `b`: selects no Gaussian"),
            "{e}"
        );
        let e = load(&[spec(&all, "a"), spec(&all, "a")], &scene, &path, &ctx).unwrap_err();
        assert!(e.to_string().contains("two regions are named `a`"), "{e}");
        let missing = RegionSpec {
            style: Some("nowhere.png".into()),
            ..spec(&all, "c")
        };
        let e = load(&[missing], &scene, &path, &ctx)
            .unwrap_err()
            .to_string();
        assert!(e.contains("region `c`") && e.contains("nowhere.png"), "{e}");
    }
}

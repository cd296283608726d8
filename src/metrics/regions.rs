//! The regions of a run in the evaluation (issue 54; docs/selection.md, "Regions"):
//! where each region lies on the views (its Gaussians' weights rendered as their share
//! of each pixel, [`crate::render::shares`]; a pixel is the region's whose share is
//! largest and at least half the pixel's coverage), its style and strength, and its own
//! style measure: the object Gram distance ([`super::texture::ObjectGram`], VGG16 relu1_2
//! and relu2_2, each view's features weighted by the region's share of its pixels) of the
//! stylized and of the original views to every style of the run. A region styled as
//! asked is nearer its own style than the others, and nearer than the original was.

use super::html::{esc, figure, fmt_opt, table};
use super::nets::{LpipsModel, LpipsNet};
use super::reference::GRAM_MAX_SIDE;
use super::texture::ObjectGram;
use super::views::ViewSet;
use crate::artifacts::regions::RegionsRecord;
use crate::imageio::Image;
use crate::{Result, Scene};
use std::path::{Path, PathBuf};

/// The regions' outline colours, in order (cycled).
const COLOURS: [[f32; 3]; 6] = [
    [1.0, 0.9, 0.0],
    [0.0, 0.9, 1.0],
    [1.0, 0.2, 0.8],
    [0.3, 1.0, 0.2],
    [1.0, 0.5, 0.0],
    [0.6, 0.4, 1.0],
];

/// Views drawn with the regions' outlines.
const DRAWN: usize = 4;

/// One region's measures: its Gram distance (relu1_2 + relu2_2, mean over the views it
/// covers) to each style of the run, stylized and original.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RegionMeasure {
    pub name: String,
    pub selection: String,
    pub selected: usize,
    pub strength: f32,
    pub styles: Vec<(PathBuf, f32)>,
    /// Per style of [`Regions::styles`]: (stylized, original).
    pub gram: Vec<(Option<f64>, Option<f64>)>,
}

/// The regions measured on the views, with what the report draws.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Regions {
    /// Every style image of the run, once, in the order the regions name them.
    pub styles: Vec<PathBuf>,
    pub regions: Vec<RegionMeasure>,
    /// Gaussians in regions whose weights summed past 1 (normalised by the run).
    pub overlapping: usize,
    /// The region owning each pixel of each view (`[view][H W]`, `None`: no region).
    #[serde(skip)]
    owner: Vec<Vec<Option<u8>>>,
    #[serde(skip)]
    images: Vec<Image>,
}

/// The `record`'s regions of `scene` (the original; its geometry is the stylized one's)
/// on the views `orig` and `styl` (`models`: the metric networks).
pub fn measure(
    record: &RegionsRecord,
    scene: &Scene,
    orig: &ViewSet,
    styl: &ViewSet,
    models: &Path,
    threads: usize,
) -> Result<Regions> {
    let _ph = crate::timing::span("regions");
    let (w, h) = (orig.width, orig.height);
    let (shares, owner) = shares_and_owners(record, scene, orig)?;
    let styles = style_paths(record);
    let images: Vec<Image> = styles
        .iter()
        .map(|p| Image::load(p))
        .collect::<Result<_>>()?;
    let mut vgg = crate::timing::phase("models load", || {
        LpipsModel::load(models, LpipsNet::Vgg16, threads)
    })?;
    let mut style_grams = Vec::with_capacity(images.len());
    for img in &images {
        let f = vgg.features(&[&img.fit_within(GRAM_MAX_SIDE)])?;
        style_grams.push(super::gram::grams(&f[0]));
    }
    // grams[region][style], fed view by view.
    let mut grams: Vec<Vec<ObjectGram>> = record
        .regions
        .iter()
        .map(|_| style_grams.iter().map(|g| ObjectGram::new(g)).collect())
        .collect();
    for v in 0..orig.n {
        let fs = vgg.features(&[&styl.images[v]])?;
        let fo = vgg.features(&[&orig.images[v]])?;
        for (r, per_style) in grams.iter_mut().enumerate() {
            for g in per_style.iter_mut() {
                let s = g.view_distances(&fs[0], &shares[r][v], w, h);
                let o = g.view_distances(&fo[0], &shares[r][v], w, h);
                g.push(&s, &o);
            }
        }
    }
    let regions = record
        .regions
        .iter()
        .zip(grams)
        .map(|(r, per_style)| RegionMeasure {
            name: r.name.clone(),
            selection: r.selection.clone(),
            selected: r.selected,
            strength: r.strength,
            styles: r.styles.clone(),
            gram: per_style
                .into_iter()
                .map(|g| {
                    let l = g.finish();
                    let add = |a: Option<f64>, b: Option<f64>| a.zip(b).map(|(a, b)| a + b);
                    (
                        add(l[0].stylized, l[1].stylized),
                        add(l[0].original, l[1].original),
                    )
                })
                .collect(),
        })
        .collect();
    Ok(Regions {
        styles,
        regions,
        overlapping: record.overlapping,
        owner,
        images,
    })
}

/// Each region's share of every view's pixels (`[region][view][H W]`) and each pixel's
/// owner (module docs).
#[allow(clippy::type_complexity)]
fn shares_and_owners(
    record: &RegionsRecord,
    scene: &Scene,
    orig: &ViewSet,
) -> Result<(Vec<Vec<Vec<f32>>>, Vec<Vec<Option<u8>>>)> {
    let (w, h) = (orig.width, orig.height);
    let weights: Vec<&[f32]> = record.weights.iter().map(|w| &w[..]).collect();
    let mut shares = vec![Vec::with_capacity(orig.n); weights.len()];
    let mut owner = Vec::with_capacity(orig.n);
    for (v, cam) in orig.cameras.iter().enumerate() {
        let s = crate::render::shares::shares(scene, cam, &weights)?;
        let alpha = orig.geometry(v).1;
        owner.push(
            (0..w * h)
                .map(|i| {
                    let (r, best) = s.iter().enumerate().fold((0, 0.0f32), |b, (r, x)| {
                        if x[i] > b.1 { (r, x[i]) } else { b }
                    });
                    (best > 0.0 && best >= 0.5 * alpha[i]).then_some(r as u8)
                })
                .collect(),
        );
        for (r, x) in s.into_iter().enumerate() {
            shares[r].push(x);
        }
    }
    Ok((shares, owner))
}

/// Every style image of the run, once, in the order the regions name them.
fn style_paths(record: &RegionsRecord) -> Vec<PathBuf> {
    let mut styles: Vec<PathBuf> = Vec::new();
    for r in &record.regions {
        for (p, _) in &r.styles {
            if !styles.contains(p) {
                styles.push(p.clone());
            }
        }
    }
    styles
}

/// `img` with the outlines of the regions `owner` says own its pixels (a pixel whose
/// right or lower neighbour has another owner takes its region's colour).
fn outlined(img: &Image, owner: &[Option<u8>]) -> Image {
    let (w, h) = (img.width, img.height);
    let mut out = img.clone();
    for y in 0..h {
        for x in 0..w {
            let o = owner[y * w + x];
            let edge = (x + 1 < w && owner[y * w + x + 1] != o)
                || (y + 1 < h && owner[(y + 1) * w + x] != o)
                || (x > 0 && owner[y * w + x - 1] != o)
                || (y > 0 && owner[(y - 1) * w + x] != o);
            if let (true, Some(r)) = (edge, o) {
                let c = COLOURS[usize::from(r) % COLOURS.len()];
                out.data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&c);
            }
        }
    }
    out
}

impl Regions {
    /// The report's section: the views with the regions' outlines (original and
    /// stylized), each region's colour, selection, style thumbnails, strength, and its
    /// Gram distances to every style.
    pub fn html(&self, orig: &ViewSet, styl: &ViewSet) -> String {
        let mut s = self.outlines_html(orig, styl);
        s.push_str(&self.legend_html());
        s.push_str(&self.grams_html());
        if self.overlapping > 0 {
            s.push_str(&format!(
                "<p class=\"note\">{} Gaussians were in regions whose weights summed past 1: each \
                 region's weight was divided by the sum.</p>",
                self.overlapping
            ));
        }
        s
    }

    /// The views with the regions' outlines.
    fn outlines_html(&self, orig: &ViewSet, styl: &ViewSet) -> String {
        let n = orig.n;
        let views: Vec<usize> = (0..DRAWN.min(n)).map(|k| k * n / DRAWN.min(n)).collect();
        let mut s = String::from(
            "<p>Each region's outline in its colour (a pixel is the region's whose Gaussians give \
             it the largest share of its light, at least half its coverage).</p><div>",
        );
        for &v in &views {
            let o = outlined(&orig.images[v], &self.owner[v]);
            s.push_str(&figure(&o, 192, &format!("original {v}")));
            let st = outlined(&styl.images[v], &self.owner[v]);
            s.push_str(&figure(&st, 192, &format!("stylized {v}")));
        }
        s.push_str("</div>");
        s
    }

    /// Each region's colour, selection, Gaussians, style thumbnails and strength.
    fn legend_html(&self) -> String {
        let swatch = |r: usize| {
            let c = COLOURS[r % COLOURS.len()].map(|x| (x * 255.0) as u8);
            format!(
                "<span style=\"display:inline-block;width:1em;height:1em;background:rgb({},{},{})\"></span>",
                c[0], c[1], c[2]
            )
        };
        let rows: Vec<Vec<String>> = self
            .regions
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let thumbs: String = r
                    .styles
                    .iter()
                    .map(|(p, wt)| {
                        let k = self.styles.iter().position(|q| q == p).unwrap_or(0);
                        figure(&self.images[k], 72, &format!("{} x {wt:.2}", file_name(p)))
                    })
                    .collect();
                vec![
                    format!("{} {}", swatch(i), esc(&r.name)),
                    format!("<code>{}</code>", esc(&r.selection)),
                    r.selected.to_string(),
                    thumbs,
                    format!("{}", r.strength),
                ]
            })
            .collect();
        table(
            &["region", "selection", "Gaussians", "style", "strength"],
            &rows,
        )
    }

    /// Each region's Gram distance to every style.
    fn grams_html(&self) -> String {
        let mut header = vec!["region".to_string()];
        header.extend(
            self.styles
                .iter()
                .map(|p| format!("to {}: stylized (original)", file_name(p))),
        );
        let rows: Vec<Vec<String>> = self
            .regions
            .iter()
            .map(|r| {
                let mut row = vec![esc(&r.name)];
                row.extend(
                    r.gram
                        .iter()
                        .map(|(a, b)| format!("{} ({})", fmt_opt(*a, 4), fmt_opt(*b, 4))),
                );
                row
            })
            .collect();
        let hdr: Vec<&str> = header.iter().map(String::as_str).collect();
        format!(
            "<p>Each region's Gram distance (VGG16 relu1_2 + relu2_2, over the region's pixels) to \
             every style of the run: a region styled as asked is nearest its own style.</p>{}",
            table(&hdr, &rows)
        )
    }
}

/// A path's file name, for captions.
fn file_name(p: &Path) -> String {
    p.file_name()
        .map_or(String::new(), |f| f.to_string_lossy().into_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_outline_is_drawn_where_the_owner_changes() {
        let img = Image::from_fn(4, 1, |_, _| [0.0; 3]);
        let owner = [Some(0), Some(0), Some(1), None];
        let out = outlined(&img, &owner);
        let px = |x: usize| [0, 1, 2].map(|c| out.data[x * 3 + c]);
        assert_eq!(px(0), [0.0; 3], "inside region 0");
        assert_eq!(px(1), COLOURS[0]);
        assert_eq!(px(2), COLOURS[1]);
        assert_eq!(px(3), [0.0; 3], "no region");
    }
}

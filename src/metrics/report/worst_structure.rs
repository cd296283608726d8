//! The view that keeps the least structure ([`crate::metrics::structure`]): original,
//! stylized, and both band-passed luminances, cropped to the object.

use super::opening::object_box;
use crate::imageio::Image;
use crate::metrics::evaluate::Metrics;
use crate::metrics::html::{esc, figure, fmt_opt};
use crate::metrics::structure;
use crate::metrics::views::ViewSet;

/// The band-passed luminance `d` ([`structure::band_pass`]) as a grey image: 0.5 + d / (6
/// sd), with sd its standard deviation over the object pixels `inside`.
fn band_pass_image(d: &[f64], inside: &[bool], w: usize, h: usize) -> Image {
    let v: Vec<f64> = d
        .iter()
        .zip(inside)
        .filter(|p| *p.1)
        .map(|p| *p.0)
        .collect();
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n)
        .sqrt()
        .max(1e-12);
    Image::from_fn(w, h, |x, y| {
        [(0.5 + d[y * w + x] / (6.0 * sd)).clamp(0.0, 1.0) as f32; 3]
    })
}

/// The view with the lowest structure kept: original, stylized, and both band-passed
/// luminances, cropped to the object.
pub(super) fn worst_structure_html(m: &Metrics, orig: &ViewSet, styl: &ViewSet) -> String {
    let Some(i) = structure::worst_view(&m.structure_kept_per_view) else {
        return format!(
            "<p class=\"note\">No view has a value. {}</p>",
            esc(structure::NOTE)
        );
    };
    let (w, h) = (orig.width, orig.height);
    let inside = structure::object_pixels(orig.geometry(i).1);
    let (bo, bs) = (
        structure::band_pass(&orig.images[i]),
        structure::band_pass(&styl.images[i]),
    );
    let (x0, y0, cw, ch) = object_box(orig, &[i]);
    let crop = |img: &Image| img.crop(x0, y0, cw, ch);
    let mut s = format!(
        "<p>View {i} keeps the least structure: <b>{}</b> (mean over views {}). Below: the \
         original and stylized view, and their band-passed luminance (difference of Gaussians, \
         sigma 1 px minus 4 px; each scaled by its own spread over the object, grey = 0), \
         cropped to the object.</p>",
        fmt_opt(m.structure_kept_per_view[i], 3),
        fmt_opt(m.structure_kept, 3)
    );
    s.push_str(&figure(
        &crop(&orig.images[i]),
        256,
        &format!("original {i}"),
    ));
    s.push_str(&figure(
        &crop(&styl.images[i]),
        256,
        &format!("stylized {i}"),
    ));
    s.push_str(&figure(
        &crop(&band_pass_image(&bo, &inside, w, h)),
        256,
        "band-pass, original",
    ));
    s.push_str(&figure(
        &crop(&band_pass_image(&bs, &inside, w, h)),
        256,
        "band-pass, stylized",
    ));
    s
}

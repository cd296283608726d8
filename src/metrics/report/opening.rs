//! The report's opening pictures: the style image beside the original and stylized
//! views (and a preview's), a few views spread over the set, cropped to the object.

use super::list;
use crate::imageio::Image;
use crate::metrics::html::{esc, img_tag};
use crate::metrics::views::{Preview, ViewSet};

/// Longest side of the opening pictures, px. Small enough to keep the 3D viewer below
/// them high on the page: in headless Chromium with SwiftShader (the viewer test), an
/// orbit of panes whose top lies below about 490 px never finishes drawing.
pub const STRIP_SIDE: usize = 112;
/// Most views the opening pictures show.
pub const STRIP_VIEWS: usize = 4;
/// The label of the preview's row in the opening pictures.
pub const PREVIEW_LABEL: &str = "preview (the prior's 2D stylization)";

/// The views the opening pictures show: up to [`STRIP_VIEWS`], spread evenly over the
/// preview's views when there is a preview (so that each has all rows), else over all
/// `n`.
pub fn strip_views(n: usize, preview: Option<&Preview>) -> Vec<usize> {
    let c: Vec<usize> = match preview {
        Some(p) => {
            let mut v = p.indices.clone();
            v.sort_unstable();
            v.dedup();
            v
        }
        None => (0..n).collect(),
    };
    if c.len() <= STRIP_VIEWS {
        return c;
    }
    (0..STRIP_VIEWS)
        .map(|k| c[k * c.len() / STRIP_VIEWS])
        .collect()
}

/// The box `(x0, y0, w, h)` around the object (source alpha > 0.05) in any of views
/// `views`, padded by 8 px; the whole frame when no pixel is.
pub fn object_box(orig: &ViewSet, views: &[usize]) -> (usize, usize, usize, usize) {
    let (w, h) = (orig.width, orig.height);
    let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
    for &v in views {
        for (p, a) in orig.geometry(v).1.iter().enumerate() {
            if *a > 0.05 {
                let (x, y) = (p % w, p / w);
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            }
        }
    }
    if x1 == 0 {
        return (0, 0, w, h);
    }
    let (x0, y0) = (x0.saturating_sub(8), y0.saturating_sub(8));
    let (x1, y1) = ((x1 + 8).min(w), (y1 + 8).min(h));
    (x0, y0, x1 - x0, y1 - y0)
}

/// The report's opening: the style image beside the original and stylized views (and
/// the preview's, labelled [`PREVIEW_LABEL`]) of [`strip_views`], cropped to the object.
pub(super) fn opening_pictures(
    orig: &ViewSet,
    styl: &ViewSet,
    style: &Image,
    preview: Option<&Preview>,
) -> String {
    let views = strip_views(orig.n, preview);
    let (x0, y0, w, h) = object_box(orig, &views);
    let mut rows: Vec<(&str, Vec<Option<&Image>>)> = vec![
        (
            "original",
            views.iter().map(|&v| Some(&orig.images[v])).collect(),
        ),
        (
            "stylized",
            views.iter().map(|&v| Some(&styl.images[v])).collect(),
        ),
    ];
    if let Some(p) = preview {
        rows.push((
            PREVIEW_LABEL,
            views.iter().map(|&v| p.image_of(v)).collect(),
        ));
    }
    let mut s = format!(
        "<div id=\"pictures\"><table title=\"views {} of {}, cropped to the object ({w}x{h} px at \
         ({x0}, {y0})); every view, whole, is further below\"><tr><th>style</th><th class=\"note\">\
         cropped</th>",
        list(&views),
        orig.n
    );
    for v in &views {
        s.push_str(&format!("<th>view {v} of {}</th>", orig.n));
    }
    s.push_str("</tr>");
    for (r, (label, imgs)) in rows.iter().enumerate() {
        s.push_str("<tr>");
        if r == 0 {
            s.push_str(&format!(
                "<td rowspan=\"{}\">{}</td>",
                rows.len(),
                img_tag(style, STRIP_SIDE, "style")
            ));
        }
        s.push_str(&format!("<th>{}</th>", esc(label)));
        for (v, img) in views.iter().zip(imgs) {
            s.push_str(&match img {
                Some(i) => format!(
                    "<td>{}</td>",
                    img_tag(&i.crop(x0, y0, w, h), STRIP_SIDE, &format!("{label} {v}"))
                ),
                None => "<td>-</td>".into(),
            });
        }
        s.push_str("</tr>");
    }
    s.push_str("</table></div>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    use std::path::Path;

    /// `n` views of 40x30 whose alpha is 1 inside `boxes[i]` = (x0, y0, x1, y1).
    fn views_with_objects(boxes: &[(usize, usize, usize, usize)]) -> ViewSet {
        let (n, w, h) = (boxes.len(), 40, 30);
        let cams = (0..n)
            .map(|i| {
                let e = [i as f64, -3.0, 1.0];
                crate::maths::warp::look_at(&format!("v{i}"), e, [0.0; 3], w as u32, h as u32, 30.0)
            })
            .collect();
        let alpha = ndarray::Array3::from_shape_fn((n, h, w), |(i, y, x)| {
            let (x0, y0, x1, y1) = boxes[i];
            f32::from(u8::from((x0..x1).contains(&x) && (y0..y1).contains(&y)))
        });
        let rgb = ndarray::Array4::zeros((n, h, w, 3));
        let depth = ndarray::Array3::zeros((n, h, w));
        ViewSet::new(Path::new("v"), rgb, depth, alpha, cams).unwrap()
    }

    #[test]
    fn the_opening_pictures_spread_over_the_views_or_the_preview() {
        assert_eq!(strip_views(3, None), vec![0, 1, 2]);
        assert_eq!(strip_views(8, None), vec![0, 2, 4, 6]);
        assert_eq!(strip_views(7, None), vec![0, 1, 3, 5]);
        let orig = views_with_objects(&[(0, 0, 1, 1); 8]);
        // The preview's views, sorted, each once: 1, 2, 3, 5, 6, 7.
        let mut p = Preview {
            views: orig,
            indices: vec![7, 1, 5, 3, 1, 6, 2],
        };
        assert_eq!(strip_views(8, Some(&p)), vec![1, 2, 5, 6]);
        p.indices = vec![6, 2];
        assert_eq!(strip_views(8, Some(&p)), vec![2, 6]);
    }

    #[test]
    fn the_object_box_covers_every_shown_view_padded() {
        let v = views_with_objects(&[(12, 10, 20, 14), (15, 4, 30, 12), (0, 0, 0, 0)]);
        assert_eq!(object_box(&v, &[0]), (4, 2, 24, 20));
        // The union of views 0 and 1, padded by 8 px, clamped to the 40x30 frame.
        assert_eq!(object_box(&v, &[0, 1]), (4, 0, 34, 22));
        // No object: the whole frame.
        assert_eq!(object_box(&v, &[2]), (0, 0, 40, 30));
    }
}

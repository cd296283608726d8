//! HTML pieces of the self-contained reports (the evaluation's `report.html`, the
//! texture section, the sweep's page): escaping, number formatting, tables, inline SVG
//! plots, embedded base64 PNG images and the page around them. No external resources,
//! so a page opens anywhere (and in the headless-Chromium test).

use crate::imageio::Image;
use std::fmt::Write;

/// Escape text for HTML.
pub fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Format an optional metric value (`digits` decimals; scientific below 1e-3).
pub fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() && x != 0.0 && x.abs() < 1e-3 => format!("{x:.2e}"),
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "n/a".into(),
    }
}

/// One line of a line plot.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub colour: &'static str,
    /// (x, y); `None` y values leave a gap.
    pub points: Vec<(f64, Option<f64>)>,
    /// Draw markers only (a scatter plot).
    pub markers_only: bool,
    /// Optional text beside each point (same length as `points`, or empty).
    pub names: Vec<String>,
}

/// An SVG line/scatter plot with axes, ticks and a legend.
pub fn svg_plot(title: &str, xlabel: &str, ylabel: &str, series: &[Series]) -> String {
    let (w, h) = (520.0, 260.0);
    let (l, r) = (60.0, 130.0);
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| {
            s.points
                .iter()
                .filter_map(|(x, y)| y.filter(|v| v.is_finite()).map(|y| (*x, y)))
        })
        .collect();
    let mut svg = String::new();
    let _ = write!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" aria-label="{}"><rect width="100%" height="100%" fill="white"/><text x="{}" y="18" font-size="13" text-anchor="middle" font-family="sans-serif">{}</text>"#,
        esc(title),
        (l + w - r) / 2.0,
        esc(title)
    );
    if pts.is_empty() {
        let _ = write!(
            svg,
            r#"<text x="{}" y="{}" font-size="12" text-anchor="middle" font-family="sans-serif">no data</text></svg>"#,
            w / 2.0,
            h / 2.0
        );
        return svg;
    }
    let f = Frame::around(&pts, series.iter().any(|s| s.markers_only));
    f.axes(&mut svg, &pts, xlabel, ylabel);
    for (si, s) in series.iter().enumerate() {
        f.series(&mut svg, si, s);
    }
    svg.push_str("</svg>");
    svg
}

/// A plot's drawing area and data ranges.
struct Frame {
    /// Size, margins (left, right, top, bottom).
    w: f64,
    h: f64,
    l: f64,
    r: f64,
    t: f64,
    b: f64,
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
}

impl Frame {
    /// The ranges around points `pts`: y from zero when zero is near the data (else
    /// padded), x padded for markers.
    fn around(pts: &[(f64, f64)], markers: bool) -> Frame {
        let (mut x0, mut x1) = pts
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let (mut y0, mut y1) = pts
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
        // Start the y axis at zero when zero is near the data; otherwise pad the range.
        if y0 >= 0.0 && y0 < 0.5 * y1 {
            y0 = 0.0;
        } else {
            y0 -= 0.05 * (y1 - y0).max(1e-12);
        }
        if x1 - x0 < 1e-12 {
            x0 -= 0.5;
            x1 += 0.5;
        } else if markers {
            let pad = 0.04 * (x1 - x0);
            x0 -= pad;
            x1 += pad;
        }
        if y1 - y0 < 1e-12 {
            y1 = y0 + 1.0;
        }
        y1 += 0.05 * (y1 - y0);
        Frame {
            w: 520.0,
            h: 260.0,
            l: 60.0,
            r: 130.0,
            t: 28.0,
            b: 40.0,
            x0,
            x1,
            y0,
            y1,
        }
    }

    fn px(&self, x: f64) -> f64 {
        self.l + (x - self.x0) / (self.x1 - self.x0) * (self.w - self.l - self.r)
    }

    fn py(&self, y: f64) -> f64 {
        self.h - self.b - (y - self.y0) / (self.y1 - self.y0) * (self.h - self.t - self.b)
    }

    /// The axes, their ticks (every integer when the x values are a few integers: view
    /// indices) and labels.
    fn axes(&self, svg: &mut String, pts: &[(f64, f64)], xlabel: &str, ylabel: &str) {
        let Frame {
            w, h, l, r, t, b, ..
        } = *self;
        let (x0, x1, y0, y1) = (self.x0, self.x1, self.y0, self.y1);
        let _ = write!(
            svg,
            r#"<line x1="{l}" y1="{}" x2="{}" y2="{}" stroke="black"/><line x1="{l}" y1="{t}" x2="{l}" y2="{}" stroke="black"/>"#,
            h - b,
            w - r,
            h - b,
            h - b
        );
        for k in 0..=4 {
            let yv = y0 + (y1 - y0) * k as f64 / 4.0;
            let _ = write!(
                svg,
                r##"<text x="{}" y="{}" font-size="10" text-anchor="end" font-family="sans-serif">{}</text><line x1="{l}" y1="{}" x2="{}" y2="{}" stroke="#ddd"/>"##,
                l - 4.0,
                self.py(yv) + 3.0,
                tick(yv, y1 - y0),
                self.py(yv),
                w - r,
                self.py(yv),
            );
        }
        let integral = pts.iter().all(|p| p.0.fract() == 0.0) && x1 - x0 <= 12.0;
        let xticks: Vec<f64> = if integral {
            (x0.ceil() as i64..=x1.floor() as i64)
                .map(|v| v as f64)
                .collect()
        } else {
            (0..=4).map(|k| x0 + (x1 - x0) * k as f64 / 4.0).collect()
        };
        for xv in xticks {
            let _ = write!(
                svg,
                r#"<text x="{}" y="{}" font-size="10" text-anchor="middle" font-family="sans-serif">{}</text>"#,
                self.px(xv),
                h - b + 14.0,
                tick(xv, x1 - x0)
            );
        }
        let _ = write!(
            svg,
            r#"<text x="{}" y="{}" font-size="11" text-anchor="middle" font-family="sans-serif">{}</text><text x="14" y="{}" font-size="11" text-anchor="middle" font-family="sans-serif" transform="rotate(-90 14 {})">{}</text>"#,
            (l + w - r) / 2.0,
            h - 6.0,
            esc(xlabel),
            (t + h - b) / 2.0,
            (t + h - b) / 2.0,
            esc(ylabel)
        );
    }

    /// Series `s` (the `si`-th): its markers, names, line and legend entry.
    fn series(&self, svg: &mut String, si: usize, s: &Series) {
        let mut path = String::new();
        let mut pen_up = true;
        for (k, (x, y)) in s.points.iter().enumerate() {
            let Some(y) = y.filter(|v| v.is_finite()) else {
                pen_up = true;
                continue;
            };
            let (cx, cy) = (self.px(*x), self.py(y));
            let _ = write!(path, "{}{cx:.1},{cy:.1} ", if pen_up { "M" } else { "L" });
            pen_up = false;
            let _ = write!(
                svg,
                r#"<circle cx="{cx:.1}" cy="{cy:.1}" r="3" fill="{}"/>"#,
                s.colour
            );
            if let Some(name) = s.names.get(k) {
                let _ = write!(
                    svg,
                    r#"<text x="{:.1}" y="{:.1}" font-size="9" font-family="sans-serif">{}</text>"#,
                    cx + 4.0,
                    cy - 4.0,
                    esc(name)
                );
            }
        }
        if !s.markers_only && !path.is_empty() {
            let _ = write!(
                svg,
                r#"<path d="{}" fill="none" stroke="{}" stroke-width="1.5"/>"#,
                path.trim(),
                s.colour
            );
        }
        let ly = self.t + 14.0 + 16.0 * si as f64;
        let (w, r) = (self.w, self.r);
        let _ = write!(
            svg,
            r#"<rect x="{}" y="{}" width="10" height="10" fill="{}"/><text x="{}" y="{}" font-size="11" font-family="sans-serif">{}</text>"#,
            w - r + 8.0,
            ly - 9.0,
            s.colour,
            w - r + 22.0,
            ly,
            esc(&s.label)
        );
    }
}

/// Tick label with enough decimals for a axis spanning `span`.
fn tick(v: f64, span: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    if span < 1e-3 {
        return format!("{v:.1e}");
    }
    let digits = (2.0 - (span / 4.0).log10().floor()).clamp(0.0, 6.0) as usize;
    let digits = if v.fract() == 0.0 && span >= 4.0 {
        0
    } else {
        digits.saturating_sub(1)
    };
    format!("{v:.digits$}")
}

/// An `<img>` tag with the image embedded, fitted to `max_side` pixels; small images
/// are shown enlarged (at least 160 px wide, pixelated) so they stay readable.
pub fn img_tag(img: &Image, max_side: usize, alt: &str) -> String {
    let small = img.fit_within(max_side);
    let scale = (160.0 / small.width as f64)
        .max(1.0)
        .min(max_side as f64 / small.width.max(small.height) as f64)
        .max(1.0);
    format!(
        r#"<img class="shot" src="{}" width="{}" height="{}" alt="{}"{}>"#,
        png_data_uri(&small),
        (small.width as f64 * scale).round(),
        (small.height as f64 * scale).round(),
        esc(alt),
        if scale > 1.0 {
            r#" style="image-rendering: pixelated""#
        } else {
            ""
        }
    )
}

/// A grey-scale image of a mask (white = 1).
pub fn mask_image(mask: &[f32], width: usize, height: usize) -> Image {
    Image::from_fn(width, height, |x, y| [mask[y * width + x]; 3])
}

/// `|a - b|` (mean over channels), amplified `gain` times, as an image; black outside `mask`.
pub fn diff_image(a: &Image, b: &Image, mask: &[f32], gain: f32) -> Image {
    Image::from_fn(a.width, a.height, |x, y| {
        let p = y * a.width + x;
        if mask[p] <= 0.0 {
            return [0.0; 3];
        }
        let (pa, pb) = (a.px(x, y), b.px(x, y));
        let d = (0..3).map(|c| (pa[c] - pb[c]).abs()).sum::<f32>() / 3.0 * gain;
        [d; 3]
    })
}

/// HTML document builder: `section`s of raw HTML inside a page with a small stylesheet.
#[derive(Debug, Default)]
pub struct Page {
    title: String,
    body: String,
}

impl Page {
    pub fn new(title: &str) -> Page {
        Page {
            title: title.into(),
            body: String::new(),
        }
    }

    pub fn section(&mut self, heading: &str, html: &str) {
        let _ = write!(
            self.body,
            "<section><h2>{}</h2>\n{html}\n</section>\n",
            esc(heading)
        );
    }

    pub fn raw(&mut self, html: &str) {
        self.body.push_str(html);
    }

    pub fn finish(self) -> String {
        format!(
            r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{t}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; color: #222; max-width: 1400px; }}
table {{ border-collapse: collapse; margin: 0.5em 0; }}
td, th {{ border: 1px solid #bbb; padding: 3px 8px; text-align: left; vertical-align: top; }}
th {{ background: #f0f0f0; }}
.warn {{ background: #fff3cd; border: 1px solid #e0c060; padding: 0.5em 1em; }}
.note {{ color: #555; font-size: 0.9em; }}
figure {{ display: inline-block; margin: 4px; text-align: center; }}
figcaption {{ font-size: 0.8em; }}
img.shot {{ image-rendering: auto; border: 1px solid #ccc; }}
</style></head><body>
<h1>{t}</h1>
{b}</body></html>
"#,
            t = esc(&self.title),
            b = self.body
        )
    }
}

/// `<figure>` with an embedded image and a caption.
pub fn figure(img: &Image, max_side: usize, caption: &str) -> String {
    format!(
        "<figure>{}<figcaption>{}</figcaption></figure>",
        img_tag(img, max_side, caption),
        esc(caption)
    )
}

/// A table from a header row and body rows (cells are raw HTML).
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = String::from("<table><tr>");
    for h in header {
        let _ = write!(s, "<th>{}</th>", esc(h));
    }
    s.push_str("</tr>");
    for r in rows {
        s.push_str("<tr>");
        for c in r {
            let _ = write!(s, "<td>{c}</td>");
        }
        s.push_str("</tr>");
    }
    s.push_str("</table>");
    s
}

// ---------------------------------------------------------------------------------
// The evaluation report.

/// Standard base64 (RFC 4648, with padding), for embedding PNGs in HTML.
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for ch in bytes.chunks(3) {
        let b = [ch[0], *ch.get(1).unwrap_or(&0), *ch.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        s.push(T[(n >> 18) as usize & 63] as char);
        s.push(T[(n >> 12) as usize & 63] as char);
        s.push(if ch.len() > 1 {
            T[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        s.push(if ch.len() > 2 {
            T[n as usize & 63] as char
        } else {
            '='
        });
    }
    s
}

/// `data:image/png;base64,...` URI of an image.
pub fn png_data_uri(img: &Image) -> String {
    format!("data:image/png;base64,{}", base64(&img.to_png()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn plot_and_page_are_well_formed() {
        let s = svg_plot(
            "t<1>",
            "x",
            "y",
            &[Series {
                label: "a".into(),
                colour: "red",
                points: vec![(0.0, Some(1.0)), (1.0, None), (2.0, Some(3.0))],
                markers_only: false,
                names: vec![],
            }],
        );
        assert!(s.starts_with("<svg") && s.ends_with("</svg>"));
        assert!(s.contains("t&lt;1&gt;"));
        assert_eq!(s.matches("<circle").count(), 2);
        let empty = svg_plot("e", "x", "y", &[]);
        assert!(empty.contains("no data"));
        let mut p = Page::new("R");
        p.section("S", &table(&["a"], &[vec!["1".into()]]));
        p.raw(&figure(&Image::filled(3, 2, [0.5; 3]), 64, "img"));
        let html = p.finish();
        assert!(html.contains("data:image/png;base64,") && html.contains("<td>1</td>"));
    }
}

//! The agreement of the prior's high-frequency change across visits of a view and
//! between neighbouring views, over a distill run's iterations, read from its
//! `history.json`.

use crate::metrics::html::{Series, esc, fmt_opt, svg_plot, table};

/// The refit baseline's ceiling `(c, own)` of the adjacent agreement as a line over the
/// history's iterations and two rows (the stylizations' and the original renders' own).
fn add_ceiling(
    history: &[serde_json::Value],
    (c, own): (f64, Option<f64>),
    series: &mut Vec<Series>,
    rows: &mut Vec<Vec<String>>,
) {
    let xs = history_series(history, "iteration");
    let (a, b) = (
        xs.first().map_or(0.0, |p| p.0),
        xs.last().map_or(1.0, |p| p.0),
    );
    series.push(Series {
        label: "refit ceiling".into(),
        colour: "#31a354",
        points: vec![(a, Some(c)), (b, Some(c))],
        markers_only: false,
        names: vec![],
    });
    rows.push(vec![
        "adjacent, refit baseline's 2D stylizations (ceiling)".into(),
        fmt_opt(Some(c), 3),
        fmt_opt(Some(c), 3),
        "-".into(),
    ]);
    rows.push(vec![
        "adjacent, the original renders' own high pass (what the warp allows)".into(),
        fmt_opt(own, 3),
        fmt_opt(own, 3),
        "-".into(),
    ]);
}

/// Keys of a distill checkpoint's `history.json` records that [`agreement_html`] draws.
pub const HF_AGREE_KEYS: [(&str, &str); 2] = [
    ("hf_agree_revisit", "revisit"),
    ("hf_agree_adjacent", "adjacent"),
];

/// `(iteration, value)` of one key over a distill history (`None` where the record has
/// no number for it).
pub fn history_series(history: &[serde_json::Value], key: &str) -> Vec<(f64, Option<f64>)> {
    history
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let x = r["iteration"].as_f64().unwrap_or(i as f64);
            (x, r[key].as_f64())
        })
        .collect()
}

/// Mean of the values present among `points[range]` (`None` when none is).
pub fn mean_present(points: &[(f64, Option<f64>)]) -> Option<f64> {
    let v: Vec<f64> = points.iter().filter_map(|p| p.1).collect();
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

/// The agreement of the prior's high-frequency change across visits of a view and
/// between neighbouring views ([`crate::metrics::agreement`]) over a distill run's
/// iterations: every iteration's value, a running mean over `window` iterations, the
/// first and last `window` iterations' means, and when given the refit baseline's
/// per-view 2D stylizations as the ceiling of the adjacent measure, with the same measure
/// on the original renders' own high pass (what the warp allows).
pub fn agreement_html(
    history: &[serde_json::Value],
    refit_ceiling: Option<(f64, Option<f64>)>,
    window: usize,
) -> String {
    let window = window.max(1);
    let colours = [("#9ecae1", "#08519c"), ("#fdae6b", "#d94801")];
    let mut series = Vec::new();
    let mut rows = Vec::new();
    for ((key, name), (light, dark)) in HF_AGREE_KEYS.iter().zip(colours) {
        let pts = history_series(history, key);
        let running: Vec<(f64, Option<f64>)> = (0..pts.len())
            .map(|i| {
                (
                    pts[i].0,
                    mean_present(&pts[i.saturating_sub(window - 1)..=i]),
                )
            })
            .collect();
        let k = window.min(pts.len());
        rows.push(vec![
            esc(name),
            fmt_opt(mean_present(&pts[..k]), 3),
            fmt_opt(mean_present(&pts[pts.len() - k..]), 3),
            pts.iter().filter(|p| p.1.is_some()).count().to_string(),
        ]);
        series.push(Series {
            label: (*name).into(),
            colour: light,
            points: pts,
            markers_only: true,
            names: vec![],
        });
        series.push(Series {
            label: format!("{name}, mean {window}"),
            colour: dark,
            points: running,
            markers_only: false,
            names: vec![],
        });
    }
    if let Some(ceiling) = refit_ceiling {
        add_ceiling(history, ceiling, &mut series, &mut rows);
    }
    let mut h = String::from(
        "<p class=\"note\">Cosine similarity of the prior's high-pass image change (the change \
         minus its Gaussian blur, sigma 2 px, over covered pixels): <b>revisit</b> against the \
         same view's previous visit, <b>adjacent</b> between neighbouring views of the window \
         after depth reprojection (occluded pixels masked). 1: the strokes land in the same \
         place; about 0: independent strokes, which the colour fit averages away.</p>",
    );
    h.push_str(&svg_plot(
        "high-frequency change agreement",
        "iteration",
        "cosine",
        &series,
    ));
    h.push_str(&table(
        &[
            "measure",
            &format!("first {window} iterations"),
            &format!("last {window} iterations"),
            "iterations with a value",
        ],
        &rows,
    ));
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agreement_section_reads_the_history() {
        let hist: Vec<serde_json::Value> = (0..30)
            .map(|i| {
                serde_json::json!({
                    "iteration": i + 100,
                    "hf_agree_revisit": if i < 3 { None } else { Some(0.1) },
                    "hf_agree_adjacent": if i < 20 { 0.2 } else { 0.4 },
                })
            })
            .collect();
        let adj = history_series(&hist, "hf_agree_adjacent");
        assert_eq!(adj[0], (100.0, Some(0.2)));
        assert!((mean_present(&adj[..20]).unwrap() - 0.2).abs() < 1e-12);
        assert_eq!(
            mean_present(&history_series(&hist, "hf_agree_revisit")[..3]),
            None
        );
        let h = agreement_html(&hist, Some((0.5, Some(0.7))), 20);
        assert!(h.contains("<svg") && h.contains("refit ceiling"));
        // first 20: adjacent 0.2; last 20: 10 x 0.2 and 10 x 0.4.
        assert!(h.contains("<td>0.200</td><td>0.300</td>"), "{h}");
        assert!(h.contains("<td>revisit</td><td>0.100</td><td>0.100</td><td>27</td>"));
    }
}

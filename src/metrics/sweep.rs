//! The speed-accuracy trade: a sweep runs the stylization at several settings
//! (resolution, views per MVFC group, rounds, timestep range), recording each point's wall
//! time and its `evaluate` metrics; this module turns the recorded points into the table
//! (markdown for `BENCHMARKS.md`, HTML for the report) and the wall-time-vs-metric plots,
//! so a user can pick a point.
//!
//! `sweep.json` (written by the sweep driver, `scripts/sweep.sh`) is
//! `{"points": [SweepPoint, ...]}`.

use super::report::{Series, esc, fmt_opt, svg_plot, table};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// One sweep point: its settings, wall time and metrics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepPoint {
    pub name: String,
    /// Setting name -> value (e.g. `width`, `group`, `rounds`, `t_range`).
    pub settings: BTreeMap<String, serde_json::Value>,
    /// Wall time of the stylization (not the evaluation), seconds.
    pub wall_s: f64,
    /// Metric name -> value, from the point's `metrics.json` summary.
    pub metrics: BTreeMap<String, Option<f64>>,
}

/// The file the sweep driver writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Sweep {
    pub points: Vec<SweepPoint>,
}

impl Sweep {
    pub fn load(path: &Path) -> Result<Sweep> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let s: Sweep = serde_json::from_str(&text)
            .map_err(|e| Error::input(path, format!("invalid sweep file: {e}")))?;
        if s.points.is_empty() {
            return Err(Error::input(path, "sweep has no points"));
        }
        Ok(s)
    }

    fn setting_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .points
            .iter()
            .flat_map(|p| p.settings.keys().cloned())
            .collect();
        v.sort();
        v.dedup();
        v
    }

    fn metric_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .points
            .iter()
            .flat_map(|p| p.metrics.keys().cloned())
            .collect();
        v.sort();
        v.dedup();
        v
    }

    fn rows(&self) -> (Vec<String>, Vec<Vec<String>>) {
        let (sn, mn) = (self.setting_names(), self.metric_names());
        let mut header = vec!["point".to_string()];
        header.extend(sn.iter().cloned());
        header.push("wall s".into());
        header.extend(mn.iter().cloned());
        let rows = self
            .points
            .iter()
            .map(|p| {
                let mut r = vec![p.name.clone()];
                r.extend(
                    sn.iter()
                        .map(|k| p.settings.get(k).map_or("".into(), value_text)),
                );
                r.push(format!("{:.1}", p.wall_s));
                r.extend(
                    mn.iter()
                        .map(|k| fmt_opt(p.metrics.get(k).copied().flatten(), 4)),
                );
                r
            })
            .collect();
        (header, rows)
    }

    /// A markdown table (for `BENCHMARKS.md`).
    pub fn markdown(&self) -> String {
        let (header, rows) = self.rows();
        let mut s = format!(
            "| {} |\n|{}\n",
            header.join(" | "),
            "---|".repeat(header.len())
        );
        for r in rows {
            s.push_str(&format!("| {} |\n", r.join(" | ")));
        }
        s
    }

    /// The report section: the table and one wall-time-vs-metric plot per metric.
    pub fn html(&self) -> String {
        let (header, rows) = self.rows();
        let h: Vec<&str> = header.iter().map(|s| s.as_str()).collect();
        let rows: Vec<Vec<String>> = rows
            .into_iter()
            .map(|r| r.into_iter().map(|c| esc(&c)).collect())
            .collect();
        let mut s = table(&h, &rows);
        for m in self.metric_names() {
            let pts = self
                .points
                .iter()
                .map(|p| (p.wall_s, p.metrics.get(&m).copied().flatten()))
                .collect();
            s.push_str(&svg_plot(
                &format!("{m} vs wall time (lower-left is better)"),
                "wall time, s",
                &m,
                &[Series {
                    label: m.clone(),
                    colour: "#1f77b4",
                    points: pts,
                    markers_only: true,
                }],
            ));
        }
        s
    }
}

fn value_text(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_and_plot() {
        let p = |name: &str, w: i64, t: f64, a: Option<f64>| SweepPoint {
            name: name.into(),
            settings: [("width".to_string(), serde_json::json!(w))].into(),
            wall_s: t,
            metrics: [("artfid".to_string(), a)].into(),
        };
        let s = Sweep {
            points: vec![p("a", 64, 1.0, Some(20.0)), p("b", 128, 3.5, None)],
        };
        let md = s.markdown();
        assert!(
            md.starts_with("| point | width | wall s | artfid |"),
            "{md}"
        );
        assert!(md.contains("| b | 128 | 3.5 | n/a |"), "{md}");
        let html = s.html();
        assert!(html.contains("<svg") && html.contains("artfid vs wall time"));
        let d = tempfile::tempdir().unwrap();
        let f = d.path().join("s.json");
        std::fs::write(&f, serde_json::to_string(&s).unwrap()).unwrap();
        assert_eq!(Sweep::load(&f).unwrap(), s);
        std::fs::write(&f, "{\"points\": []}").unwrap();
        assert!(
            Sweep::load(&f)
                .unwrap_err()
                .to_string()
                .contains("no points")
        );
    }
}

//! The speed-accuracy trade: a sweep runs the stylization at several settings
//! (resolution, views per MVFC group, rounds, timestep range), recording each point's wall
//! time and its `evaluate` metrics; this module turns the recorded points into the table
//! (markdown for `BENCHMARKS.md`, HTML for the report) and the wall-time-vs-metric plots,
//! so a user can pick a point.
//!
//! The driver ([`run_sweep`], binary `sweep`) reads a sweep spec (TOML, see
//! [`SweepSpec`]; example `data-sample/sweep.toml`), and for each point writes a copy of
//! the DAG (its `[vars]` paths made absolute) and of its params file with the point's
//! overrides into `OUT/<point>/`, runs `pipeline run` up to the timed target (the
//! stylization), records its wall time, runs the evaluation target, and reads the point's
//! `metrics.json`. It writes `OUT/sweep.json`, `OUT/sweep.md` (the table) and
//! `OUT/sweep.html` (table and plots); `evaluate --sweep OUT/sweep.json` also embeds them
//! in an evaluation report.

use crate::metrics::html::{Page, Series, esc, figure, fmt_opt, svg_plot, table};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One sweep point: its settings, wall time and metrics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepPoint {
    pub name: String,
    /// Setting name -> value (e.g. `width`, `group`, `rounds`, `t_range`).
    pub settings: BTreeMap<String, serde_json::Value>,
    /// Wall time of the stylization (not the evaluation), seconds.
    pub wall_s: f64,
    /// Metric name -> value, from the point's `metrics.json` summary (and, for a run
    /// of regions, each style's Gram distance from the first region's `regions.json`:
    /// `gram_to_STEM`).
    pub metrics: BTreeMap<String, Option<f64>>,
    /// One stylized view of the point (the spec's `view`), shown in the report's strip.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<PathBuf>,
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
        let mut s = String::new();
        let strip: Vec<String> = self
            .points
            .iter()
            .filter_map(|p| {
                let img = crate::imageio::Image::load(p.view.as_deref()?).ok()?;
                let set: Vec<String> = p
                    .settings
                    .iter()
                    .map(|(k, v)| format!("--set {k}={}", value_text(v)))
                    .collect();
                let measures: Vec<String> = [
                    "edge_recall",
                    "motif_contrast",
                    "style_texture",
                    "interior_structure",
                ]
                .iter()
                .filter_map(|k| Some(format!("{k} {:.3}", p.metrics.get(*k).copied()??)))
                .collect();
                let caption = format!("{}: {} ({})", p.name, set.join(" "), measures.join(", "));
                Some(figure(&img, 160, &caption))
            })
            .collect();
        if !strip.is_empty() {
            s.push_str(&format!("<div>{}</div>", strip.concat()));
        }
        s.push_str(&table(&h, &rows));
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
                    names: self.points.iter().map(|p| p.name.clone()).collect(),
                }],
            ));
        }
        s
    }
}

/// A sweep specification (TOML).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SweepSpec {
    /// The DAG to run, relative to the spec file.
    pub dag: PathBuf,
    /// Stage (or base name) whose upstream is the timed stylization.
    #[serde(default = "default_time_target")]
    pub time_target: String,
    /// Stage that writes the evaluation.
    #[serde(default = "default_eval_target")]
    pub eval_target: String,
    /// The evaluation's `metrics.json`, relative to the DAG directory.
    #[serde(default = "default_metrics")]
    pub metrics: PathBuf,
    /// A stylized view of each point, relative to the point's directory, shown in the
    /// report's strip of the points.
    #[serde(default = "default_view")]
    pub view: PathBuf,
    /// The points.
    pub point: Vec<PointSpec>,
}

fn default_time_target() -> String {
    "final-views".into()
}
fn default_eval_target() -> String {
    "evaluate".into()
}
fn default_metrics() -> PathBuf {
    "runs/eval/metrics.json".into()
}
fn default_view() -> PathBuf {
    "runs/final-views/view_000.png".into()
}

/// One point: a name and params-file overrides (dotted keys, e.g. `"render.width"`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PointSpec {
    pub name: String,
    #[serde(default)]
    pub params: BTreeMap<String, toml::Value>,
}

impl SweepSpec {
    pub fn load(path: &Path) -> Result<SweepSpec> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let mut s: SweepSpec = toml::from_str(&text)
            .map_err(|e| Error::input(path, format!("invalid sweep spec: {e}")))?;
        if s.point.is_empty() {
            return Err(Error::input(path, "sweep spec has no [[point]]"));
        }
        let mut names: Vec<&str> = s.point.iter().map(|p| p.name.as_str()).collect();
        names.sort();
        if names.windows(2).any(|w| w[0] == w[1])
            || names.iter().any(|n| n.is_empty() || n.contains('/'))
        {
            return Err(Error::input(
                path,
                "point names must be unique, non-empty and contain no `/`",
            ));
        }
        let base = path.parent().unwrap_or(Path::new("."));
        s.dag = base.join(&s.dag);
        Ok(s)
    }
}

/// Set a dotted key in a TOML table, creating intermediate tables.
pub fn set_dotted(t: &mut toml::Table, key: &str, v: toml::Value) -> Result<()> {
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().unwrap_or_default();
    let mut cur = t;
    for p in parts {
        let e = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        cur = e.as_table_mut().ok_or_else(|| {
            Error::param(format!(
                "sweep: `{key}`: `{p}` is not a table in the params file"
            ))
        })?;
    }
    cur.insert(last.to_string(), v);
    Ok(())
}

/// Write the point's DAG copy (vars that name existing files made absolute) and params file.
fn prepare_point(spec: &SweepSpec, point: &PointSpec, dir: &Path) -> Result<PathBuf> {
    let dag_dir = spec.dag.parent().unwrap_or(Path::new(".")).to_path_buf();
    let text = std::fs::read_to_string(&spec.dag).map_err(|e| Error::io(&spec.dag, e))?;
    let mut dag: toml::Table =
        toml::from_str(&text).map_err(|e| Error::input(&spec.dag, format!("invalid DAG: {e}")))?;
    if let Some(toml::Value::Table(vars)) = dag.get_mut("vars") {
        let keys: Vec<String> = vars.keys().cloned().collect();
        for k in keys {
            if let Some(toml::Value::String(v)) = vars.get(&k) {
                let p = dag_dir.join(v);
                if p.exists() {
                    let abs = std::fs::canonicalize(&p).map_err(|e| Error::io(&p, e))?;
                    vars.insert(k, toml::Value::String(abs.display().to_string()));
                }
            }
        }
    }
    let mut params = match dag.get("params").and_then(|v| v.as_str()) {
        Some(pf) => {
            let p = dag_dir.join(pf);
            let t = std::fs::read_to_string(&p).map_err(|e| Error::io(&p, e))?;
            toml::from_str::<toml::Table>(&t)
                .map_err(|e| Error::input(&p, format!("invalid params file: {e}")))?
        }
        None => toml::Table::new(),
    };
    for (k, v) in &point.params {
        set_dotted(&mut params, k, v.clone())?;
    }
    dag.insert("params".into(), toml::Value::String("params.toml".into()));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let ser = |t: &toml::Table, p: &Path| -> Result<()> {
        let s = toml::to_string(t).map_err(|e| Error::Other(format!("{}: {e}", p.display())))?;
        fantasystyle_schemas::atomic_write(p, s.as_bytes()).map_err(Error::from)
    };
    ser(&params, &dir.join("params.toml"))?;
    let dag_path = dir.join(spec.dag.file_name().unwrap_or("dag.toml".as_ref()));
    ser(&dag, &dag_path)?;
    Ok(dag_path)
}

/// The `pipeline` binary: beside this executable, else on PATH.
fn pipeline_bin() -> PathBuf {
    std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(|d| d.join("pipeline")))
        .filter(|p| p.is_file())
        .unwrap_or_else(|| PathBuf::from("pipeline"))
}

fn pipeline_run(dag: &Path, target: &str) -> Result<()> {
    let st = std::process::Command::new(pipeline_bin())
        .args(["run", "--dag"])
        .arg(dag)
        .arg(target)
        .status()
        .map_err(|e| Error::Other(format!("cannot run `pipeline`: {e}")))?;
    if !st.success() {
        return Err(Error::Other(format!(
            "`pipeline run --dag {} {target}` failed ({st})",
            dag.display()
        )));
    }
    Ok(())
}

/// The summary metrics of a `metrics.json` (evaluate's output) that the sweep tabulates.
pub fn summary(metrics: &serde_json::Value) -> BTreeMap<String, Option<f64>> {
    let get = |p: &[&str]| {
        let mut v = metrics;
        for k in p {
            v = &v[*k];
        }
        v.as_f64()
    };
    [
        ("artfid", get(&["artfid"])),
        ("fid_style", get(&["fid_style", "value"])),
        ("kid_style", get(&["kid_style", "value"])),
        ("lpips_content", get(&["lpips_content"])),
        ("short_lpips", get(&["short_range", "lpips_mean"])),
        ("long_lpips", get(&["long_range", "lpips_mean"])),
        ("long_excess", get(&["long_range", "excess_lpips_mean"])),
        ("short_rmse", get(&["short_range", "rmse_mean"])),
        ("gram_style", get(&["gram_style"])),
        ("structure_kept", get(&["structure_kept"])),
        ("interior_structure", get(&["interior_structure"])),
        ("edge_recall", get(&["edge_recall"])),
        ("motif_contrast", get(&["motif_contrast"])),
        ("style_texture", get(&["style_texture"])),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect()
}

/// For a run of regions (`regions.json` at `path`, [`crate::metrics::regions`]): the
/// first region's Gram distance to each style of the run, `gram_to_STEM` (none without
/// the file).
fn region_grams(path: &Path) -> BTreeMap<String, Option<f64>> {
    let Some(v) = std::fs::read(path)
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
    else {
        return BTreeMap::new();
    };
    let styles = v["styles"].as_array().cloned().unwrap_or_default();
    styles
        .iter()
        .enumerate()
        .map(|(k, s)| {
            let stem = Path::new(s.as_str().unwrap_or_default())
                .file_stem()
                .map_or(String::new(), |f| f.to_string_lossy().into_owned());
            (
                format!("gram_to_{stem}"),
                v["regions"][0]["gram"][k][0].as_f64(),
            )
        })
        .collect()
}

/// Run every point; failed points are recorded with `wall_s = NaN` and no metrics.
pub fn run_sweep(spec: &SweepSpec, out: &Path) -> Result<Sweep> {
    let mut points = Vec::new();
    for p in &spec.point {
        let dir = out.join(&p.name);
        let dag = prepare_point(spec, p, &dir)?;
        tracing::info!("sweep: point `{}` in {}", p.name, dir.display());
        let t0 = Instant::now();
        let ran = pipeline_run(&dag, &spec.time_target);
        let wall = t0.elapsed().as_secs_f64();
        let metrics = match ran.and_then(|_| pipeline_run(&dag, &spec.eval_target)) {
            Ok(()) => {
                let mp = dir.join(&spec.metrics);
                let t = std::fs::read_to_string(&mp).map_err(|e| Error::io(&mp, e))?;
                let v: serde_json::Value = serde_json::from_str(&t)
                    .map_err(|e| Error::input(&mp, format!("invalid metrics.json: {e}")))?;
                let mut m = summary(&v);
                m.extend(region_grams(&mp.with_file_name("regions.json")));
                m
            }
            Err(e) => {
                tracing::warn!("sweep: point `{}` failed: {e}", p.name);
                BTreeMap::new()
            }
        };
        let settings = p
            .params
            .iter()
            .map(|(k, v)| {
                (
                    k.clone(),
                    serde_json::to_value(v).unwrap_or(serde_json::Value::Null),
                )
            })
            .collect();
        let view = dir.join(&spec.view);
        points.push(SweepPoint {
            name: p.name.clone(),
            settings,
            wall_s: if metrics.is_empty() { f64::NAN } else { wall },
            metrics,
            view: view.is_file().then_some(view),
        });
    }
    let sweep = Sweep { points };
    write_outputs(&sweep, out)?;
    Ok(sweep)
}

/// Write `sweep.json`, `sweep.md` and `sweep.html` into `out`.
pub fn write_outputs(sweep: &Sweep, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    fantasystyle_schemas::atomic_write_json(&out.join("sweep.json"), sweep)?;
    fantasystyle_schemas::atomic_write(&out.join("sweep.md"), sweep.markdown().as_bytes())?;
    let mut page = Page::new("fantasystyle speed-accuracy sweep");
    page.section("Points", &sweep.html());
    fantasystyle_schemas::atomic_write(&out.join("sweep.html"), page.finish().as_bytes())?;
    Ok(())
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
            view: None,
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
        assert!(!html.contains("<figure>"), "no view, no strip");
        let d = tempfile::tempdir().unwrap();
        // A point's view joins the strip.
        let view = d.path().join("v.png");
        crate::imageio::write_png_rgb(&view, &[0.5; 12], 2, 2).unwrap();
        let mut with = s.clone();
        with.points[0].view = Some(view);
        assert_eq!(with.html().matches("<figure>").count(), 1);
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

    #[test]
    fn summary_and_strip_show_style_texture_beside_motif_contrast() {
        let m = summary(&serde_json::json!({
            "edge_recall": 0.9, "motif_contrast": 0.6, "style_texture": 0.25,
            "interior_structure": 0.8
        }));
        assert_eq!(m["motif_contrast"], Some(0.6));
        assert_eq!(m["style_texture"], Some(0.25));
        let d = tempfile::tempdir().unwrap();
        let view = d.path().join("v.png");
        crate::imageio::write_png_rgb(&view, &[0.5; 12], 2, 2).unwrap();
        let s = Sweep {
            points: vec![SweepPoint {
                name: "c1".into(),
                settings: [("synthesis.control".to_string(), serde_json::json!(1))].into(),
                wall_s: 1.0,
                metrics: m,
                view: Some(view),
            }],
        };
        let html = s.html();
        assert!(
            html.contains("motif_contrast 0.600, style_texture 0.250, interior_structure"),
            "{html}"
        );
        assert!(s.markdown().contains("| style_texture |"));
    }

    #[test]
    fn spec_points_are_prepared_with_overrides_and_absolute_vars() {
        let d = tempfile::tempdir().unwrap();
        let w = |n: &str, t: &str| std::fs::write(d.path().join(n), t).unwrap();
        w("scene.ply", "x");
        w(
            "dag.toml",
            "params = \"p.toml\"\n[vars]\nscene = \"scene.ply\"\nother = \"not-a-file\"\n[stages.a]\ncmd = \"true\"\n",
        );
        w("p.toml", "rounds = 4\n[render]\nwidth = 256\n");
        w(
            "sweep.toml",
            "dag = \"dag.toml\"\n[[point]]\nname = \"small\"\n[point.params]\n\"render.width\" = 64\n\"mvfc.group\" = 2\n",
        );
        let spec = SweepSpec::load(&d.path().join("sweep.toml")).unwrap();
        let dag = prepare_point(&spec, &spec.point[0], &d.path().join("out/small")).unwrap();
        let dag: toml::Table = toml::from_str(&std::fs::read_to_string(dag).unwrap()).unwrap();
        let scene = dag["vars"]["scene"].as_str().unwrap();
        assert!(Path::new(scene).is_absolute() && scene.ends_with("scene.ply"));
        assert_eq!(dag["vars"]["other"].as_str(), Some("not-a-file"));
        assert_eq!(dag["params"].as_str(), Some("params.toml"));
        let p: toml::Table = toml::from_str(
            &std::fs::read_to_string(d.path().join("out/small/params.toml")).unwrap(),
        )
        .unwrap();
        assert_eq!(p["render"]["width"].as_integer(), Some(64));
        assert_eq!(p["rounds"].as_integer(), Some(4));
        assert_eq!(p["mvfc"]["group"].as_integer(), Some(2));
        // bad specs
        w("bad.toml", "dag = \"dag.toml\"\npoint = []\n");
        let e = SweepSpec::load(&d.path().join("bad.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no [[point]]"), "{e}");
        w(
            "bad2.toml",
            "dag = \"dag.toml\"\nbogus = 1\n[[point]]\nname = \"a\"\n",
        );
        assert!(SweepSpec::load(&d.path().join("bad2.toml")).is_err());
        w(
            "bad3.toml",
            "dag = \"dag.toml\"\n[[point]]\nname = \"a\"\n[[point]]\nname = \"a\"\n",
        );
        assert!(
            SweepSpec::load(&d.path().join("bad3.toml"))
                .unwrap_err()
                .to_string()
                .contains("unique")
        );
    }
}

//! Phase 1 of loading a DAG: the TOML text into raw stages (unknown keys rejected,
//! spans kept for line numbers), the params file into dotted keys, and `[vars]` into
//! strings. Nothing is substituted or expanded here.

use super::Diag;
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use toml::Spanned;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawDag {
    #[serde(default)]
    pub params: Option<Spanned<String>>,
    #[serde(default)]
    pub vars: BTreeMap<String, Spanned<toml::Value>>,
    #[serde(default)]
    pub stages: BTreeMap<String, Spanned<RawStage>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawStage {
    pub cmd: Spanned<String>,
    #[serde(default)]
    pub desc: Option<String>,
    #[serde(default)]
    pub deps: Vec<Spanned<String>>,
    #[serde(default)]
    pub outs: Vec<Spanned<String>>,
    #[serde(default)]
    pub params: Vec<Spanned<String>>,
    #[serde(default)]
    pub foreach: Option<Spanned<toml::Value>>,
}

/// Maps byte offsets to 1-based line numbers.
pub(super) struct Lines(Vec<usize>);
impl Lines {
    pub fn new(text: &str) -> Self {
        let mut v = vec![0];
        v.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        Lines(v)
    }
    pub fn line(&self, offset: usize) -> usize {
        self.0.partition_point(|&s| s <= offset)
    }
}

/// A parsed DAG file: the raw stages and the values `${...}` can refer to.
pub(super) struct Parsed {
    pub raw: RawDag,
    pub lines: Lines,
    /// The params file's values, flattened to dotted keys (tables included).
    pub params: BTreeMap<String, serde_json::Value>,
    /// `[vars]` as strings.
    pub vars: HashMap<String, String>,
    /// The params file's scalar values as strings (what `${key}` substitutes).
    pub params_text: HashMap<String, String>,
}

/// Parse DAG text (`dir`: where the params file is looked up). A TOML error stops
/// here; problems with the params file or `[vars]` go into `diags` and parsing goes on,
/// so that one run reports every problem.
pub(super) fn parse(text: &str, dir: &Path, diags: &mut Vec<Diag>) -> Result<Parsed, Diag> {
    let lines = Lines::new(text);
    let raw: RawDag = toml::from_str(text).map_err(|e| Diag {
        line: e.span().map(|s| lines.line(s.start)),
        msg: e.message().trim().to_string(),
    })?;

    let mut params = BTreeMap::new();
    if let Some(p) = &raw.params {
        let line = Some(lines.line(p.span().start));
        let path = dir.join(p.get_ref());
        match std::fs::read_to_string(&path) {
            Err(e) => diags.push(Diag {
                line,
                msg: format!("cannot read params file {}: {e}", path.display()),
            }),
            Ok(t) => match t.parse::<toml::Table>() {
                Err(e) => diags.push(Diag {
                    line,
                    msg: format!(
                        "params file {}: {}",
                        path.display(),
                        e.to_string().replace('\n', " ")
                    ),
                }),
                Ok(table) => flatten("", &toml::Value::Table(table), &mut params),
            },
        }
    }

    let mut vars: HashMap<String, String> = HashMap::new();
    for (k, v) in &raw.vars {
        let line = Some(lines.line(v.span().start));
        if k == "item" || k == "prev" {
            diags.push(Diag {
                line,
                msg: format!("variable `{k}` is reserved for foreach stages"),
            });
        } else if params.contains_key(k) {
            diags.push(Diag {
                line,
                msg: format!("variable `{k}` is also a key of the params file"),
            });
        } else {
            match scalar(v.get_ref()) {
                Some(s) => {
                    vars.insert(k.clone(), s);
                }
                None => diags.push(Diag {
                    line,
                    msg: format!("variable `{k}` must be a string or a number"),
                }),
            }
        }
    }
    let params_text = params
        .iter()
        .filter_map(|(k, v)| json_scalar(v).map(|s| (k.clone(), s)))
        .collect();
    Ok(Parsed {
        raw,
        lines,
        params,
        vars,
        params_text,
    })
}

fn scalar(v: &toml::Value) -> Option<String> {
    match v {
        toml::Value::String(s) => Some(s.clone()),
        toml::Value::Integer(i) => Some(i.to_string()),
        toml::Value::Float(f) => Some(f.to_string()),
        toml::Value::Boolean(b) => Some(b.to_string()),
        _ => None,
    }
}

pub(super) fn json_scalar(v: &serde_json::Value) -> Option<String> {
    match v {
        serde_json::Value::String(s) => Some(s.clone()),
        serde_json::Value::Number(n) => Some(n.to_string()),
        serde_json::Value::Bool(b) => Some(b.to_string()),
        _ => None,
    }
}

fn flatten(prefix: &str, v: &toml::Value, out: &mut BTreeMap<String, serde_json::Value>) {
    if !prefix.is_empty() {
        out.insert(
            prefix.to_string(),
            serde_json::to_value(v).unwrap_or(serde_json::Value::Null),
        );
    }
    if let toml::Value::Table(t) = v {
        for (k, x) in t {
            let key = if prefix.is_empty() {
                k.clone()
            } else {
                format!("{prefix}.{k}")
            };
            flatten(&key, x, out);
        }
    }
}

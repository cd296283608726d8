//! Phase 1 of loading a DAG: the TOML text into raw stages (unknown keys rejected,
//! spans kept for line numbers), the params file into dotted keys, and `[vars]` into
//! strings; then `--set NAME=VALUE` overrides replace `[vars]` and params values.
//! Nothing is substituted or expanded here.

use super::Diag;
use super::Set;
use super::locate::Places;
use crate::error::{Error, Result};
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
    /// What a successful run leaves for the user, by name (`scene = "runs/final/scene.ply"`).
    #[serde(default)]
    pub result: BTreeMap<String, Spanned<String>>,
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
    /// The stage exists only when this condition holds (`"${distill.chunks} > 0"`).
    #[serde(default)]
    pub when: Option<Spanned<String>>,
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
    /// The params file as read (before flattening), `--set` overrides applied.
    pub params_table: toml::Table,
    /// The params file's values, flattened to dotted keys (tables included).
    pub params: BTreeMap<String, serde_json::Value>,
    /// `[vars]` as strings.
    pub vars: HashMap<String, String>,
    /// What `${key}` substitutes for a params key: a scalar as its text, a table as an
    /// inline TOML table (`{ a = 1, b = "x" }`, keys sorted), so that a stage can be given
    /// a whole table as one argument (and tracks every key in it).
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
    let mut params_table = toml::Table::new();
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
                Ok(table) => {
                    flatten("", &toml::Value::Table(table.clone()), &mut params);
                    params_table = table;
                }
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
    let params_text = params_text(&params, &params_table);
    Ok(Parsed {
        raw,
        lines,
        params_table,
        params,
        vars,
        params_text,
    })
}

fn params_text(
    params: &BTreeMap<String, serde_json::Value>,
    table: &toml::Table,
) -> HashMap<String, String> {
    params
        .iter()
        .filter_map(|(k, v)| match v {
            serde_json::Value::Object(_) => table_at(table, k).map(|t| (k.clone(), inline(t))),
            _ => json_scalar(v).map(|s| (k.clone(), s)),
        })
        .collect()
}

/// The table at dotted key `key` of `t`.
fn table_at<'a>(t: &'a toml::Table, key: &str) -> Option<&'a toml::Table> {
    key.split('.').try_fold(t, |t, k| t.get(k)?.as_table())
}

/// `t` as an inline TOML table, keys sorted: `{ a = 1, b = { c = "x" } }` (`{}` when
/// empty).
pub(super) fn inline(t: &toml::Table) -> String {
    fn key(k: &str) -> String {
        let bare = !k.is_empty()
            && k.chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if bare {
            k.to_string()
        } else {
            toml::Value::String(k.to_string()).to_string()
        }
    }
    fn value(v: &toml::Value) -> String {
        match v {
            toml::Value::Table(t) => inline(t),
            toml::Value::Array(a) => {
                format!("[{}]", a.iter().map(value).collect::<Vec<_>>().join(", "))
            }
            other => other.to_string(),
        }
    }
    let mut keys: Vec<&String> = t.keys().collect();
    keys.sort();
    if keys.is_empty() {
        return "{}".into();
    }
    let parts: Vec<String> = keys
        .into_iter()
        .map(|k| format!("{} = {}", key(k), value(&t[k])))
        .collect();
    format!("{{ {} }}", parts.join(", "))
}

/// Whether some stage's command substitutes the params table `key` whole (`${key}`):
/// a key `--set` adds to such a table reaches that stage, which checks it.
fn passed_whole(p: &Parsed, key: &str) -> bool {
    let word = format!("${{{key}}}");
    p.params.get(key).is_some_and(|v| v.is_object())
        && p.raw
            .stages
            .values()
            .any(|s| s.get_ref().cmd.get_ref().contains(&word))
}

/// The value of a `--set` that adds a key to a table passed whole: a TOML literal
/// (number, boolean, string in quotes, array, inline table) as written, else the text as
/// a string.
fn literal(value: &str) -> toml::Value {
    format!("v = {value}")
        .parse::<toml::Table>()
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(value.to_string()))
}

/// Apply `--set NAME=VALUE` overrides: a `[vars]` name takes the value; a params key
/// (dotted) takes the value converted to the type it has in the params file. A value
/// naming an existing path relative to the current directory is rewritten as seen
/// from the work directory. Returns the names of the `[vars]` that were set.
pub(super) fn apply_sets(
    p: &mut Parsed,
    sets: &[Set],
    places: &Places,
    file: &Path,
) -> Result<Vec<String>> {
    let mut set_vars = Vec::new();
    for s in sets {
        let value = places.from_cwd(&s.value).unwrap_or_else(|| s.value.clone());
        if p.raw.vars.contains_key(&s.name) {
            p.vars.insert(s.name.clone(), value);
            set_vars.push(s.name.clone());
            continue;
        }
        let in_whole_table = s
            .name
            .match_indices('.')
            .any(|(i, _)| passed_whole(p, &s.name[..i]));
        let new = if !p.params.contains_key(&s.name) && in_whole_table {
            // A new key of a table a stage takes whole: that stage checks it.
            literal(&value)
        } else {
            typed_set(p, s, value, file)?
        };
        set_in_table(&mut p.params_table, &s.name, new);
        p.params.clear();
        flatten(
            "",
            &toml::Value::Table(p.params_table.clone()),
            &mut p.params,
        );
    }
    p.params_text = params_text(&p.params, &p.params_table);
    Ok(set_vars)
}

/// The new value of params key `s.name`, of the type it has in the params file; an
/// unknown key, a table or list, or a value of the wrong type is a usage error.
fn typed_set(p: &Parsed, s: &Set, value: String, file: &Path) -> Result<toml::Value> {
    let Some(old) = p.params.get(&s.name) else {
        return Err(unknown_set(p, s, file));
    };
    let bad = |what: &str| {
        Error::Usage(format!(
            "--set {s}: params key `{}` is {what}, and `{}` is not one",
            s.name, s.value
        ))
    };
    Ok(match old {
        serde_json::Value::Object(_) | serde_json::Value::Array(_) => {
            return Err(Error::Usage(format!(
                "--set {s}: params key `{}` is a {}; set one of its values by its dotted key",
                s.name,
                if old.is_object() { "table" } else { "list" }
            )));
        }
        serde_json::Value::Bool(_) => {
            toml::Value::Boolean(s.value.parse().map_err(|_| bad("a boolean"))?)
        }
        serde_json::Value::Number(n) if n.is_i64() || n.is_u64() => {
            toml::Value::Integer(s.value.parse().map_err(|_| bad("an integer"))?)
        }
        serde_json::Value::Number(_) => {
            let f: f64 = s.value.parse().map_err(|_| bad("a number"))?;
            if !f.is_finite() {
                return Err(bad("a finite number"));
            }
            toml::Value::Float(f)
        }
        _ => toml::Value::String(value),
    })
}

/// The error of a `--set` of a name that is neither a `[vars]` name nor a params key
/// (listing both).
fn unknown_set(p: &Parsed, s: &Set, file: &Path) -> Error {
    let mut vars: Vec<&str> = p.raw.vars.keys().map(String::as_str).collect();
    vars.sort();
    let keys: Vec<&str> = p
        .params
        .iter()
        .filter(|(_, v)| !v.is_object())
        .map(|(k, _)| k.as_str())
        .collect();
    let list = |v: &[&str]| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.join(", ")
        }
    };
    Error::Usage(format!(
        "--set {s}: `{}` is neither a [vars] name nor a params key of {} (vars: {}; params keys: {})",
        s.name,
        file.display(),
        list(&vars),
        list(&keys),
    ))
}

/// Set dotted key `dotted` of `t` to `v`, making the tables on the way that are missing.
fn set_in_table(t: &mut toml::Table, dotted: &str, v: toml::Value) {
    match dotted.split_once('.') {
        Some((head, rest)) if t.get(head).is_none_or(|x| x.is_table()) => {
            let inner = t
                .entry(head.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            if let toml::Value::Table(inner) = inner {
                set_in_table(inner, rest, v);
            }
        }
        _ => {
            t.insert(dotted.to_string(), v);
        }
    }
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

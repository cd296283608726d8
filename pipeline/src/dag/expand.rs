//! Phase 2 of loading a DAG: `foreach` expansion and `${...}` substitution. Each raw
//! stage becomes one [`Stage`] (or one per `foreach` item, named `NAME@ITEM`) with its
//! `cmd` (split into arguments first, then substituted per argument: [`super::words`]),
//! `deps` and `outs` substituted and its tracked params collected; problems go into the
//! diagnostics with their lines.

use super::inside;
use super::locate::{Places, is_value_dep, replace_arg};
use super::parse::{Lines, Parsed, RawStage};
use super::{Diag, Stage, normalize, words};
use std::collections::{BTreeSet, HashMap};
use toml::Spanned;

/// Why `${...}` substitution failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SubstError {
    #[error("unterminated `${{` in `{0}`")]
    Unterminated(String),
    #[error("undefined variable `${{{0}}}`")]
    Undefined(String),
}

/// Why a `foreach` value cannot be expanded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ForeachError {
    #[error("the list is empty")]
    Empty,
    #[error("items must be strings or integers, found {0}")]
    ItemType(&'static str),
    #[error("item `{0}` may only use letters, digits, `-`, `_` and `.`")]
    Label(String),
    #[error("item `{0}` appears twice")]
    Twice(String),
    #[error("unknown key `{0}` in a range (expected `from`, `to`, `prefix`)")]
    RangeKey(String),
    #[error(
        "a matrix is a table of lists, e.g. {{ matrix = {{ scene = [\"a\", \"b\"], style = [\"x\"] }} }}; `{0}` is not a non-empty list"
    )]
    Matrix(String),
    #[error("a range needs `{0}`")]
    MissingBound(&'static str),
    #[error(transparent)]
    Subst(#[from] SubstError),
    #[error("`{key}` = \"{raw}\" is `{value}`, not an integer")]
    NotInteger {
        key: &'static str,
        raw: String,
        value: String,
    },
    #[error("`{key}` must be an integer or a \"${{var}}\", found {found}")]
    BoundType {
        key: &'static str,
        found: &'static str,
    },
    #[error("`prefix` must be a string of letters/digits")]
    Prefix,
    #[error("range is empty (from = {from}, to = {to})")]
    EmptyRange { from: i64, to: i64 },
    #[error("range {from}..={to} is too long")]
    TooLong { from: i64, to: i64 },
    #[error("the matrix makes {0} combinations; at most {MAX_INSTANCES} instances per stage")]
    MatrixTooLarge(u128),
    #[error("expected a list of items or a range table {{ from, to, prefix }}, found {0}")]
    Shape(&'static str),
}

/// An expanded stage with the lines of its deps and outs (for later diagnostics).
pub(super) struct Expanded {
    pub stage: Stage,
    pub dep_lines: Vec<usize>,
    pub out_lines: Vec<usize>,
    /// Per dep: written without `${...}` (a literal path in the DAG file).
    pub dep_literal: Vec<bool>,
}

/// Whether some stage writes `p` (or a directory holding it).
pub(super) fn produced(p: &str, stages: &[Expanded]) -> bool {
    stages
        .iter()
        .any(|e| e.stage.outs.iter().any(|o| o == p || inside(p, o)))
}

/// Literal deps of the DAG file that name existing paths relative to the DAG's
/// directory (and that no stage produces), and a relative executable as the command's
/// program, rewritten as seen from the work directory, in `deps` and in the command's
/// arguments (an argument equal to the dep, or `NAME=` followed by it).
pub(super) fn relocate_literals(stages: &mut [Expanded], places: &Places) {
    if !places.moved() {
        return;
    }
    let mut todo: Vec<(usize, usize, String)> = Vec::new();
    for (i, e) in stages.iter().enumerate() {
        for (k, d) in e.stage.deps.iter().enumerate() {
            if e.dep_literal[k]
                && !is_value_dep(d)
                && !produced(d, stages)
                && let Some(r) = places.from_dag(d)
            {
                todo.push((i, k, r));
            }
        }
    }
    for (i, k, r) in todo {
        let s = &mut stages[i].stage;
        let d = std::mem::replace(&mut s.deps[k], r.clone());
        for a in s.argv.iter_mut() {
            if let Some(new) = replace_arg(a, &d, &r) {
                *a = new;
            }
        }
    }
    for e in stages.iter_mut() {
        let s = &mut e.stage;
        let Some(first) = s.argv.first_mut() else {
            continue;
        };
        if first.contains('/')
            && !first.contains('=')
            && let Some(r) = places.from_dag(first)
        {
            *first = r;
        }
    }
}

/// A `[result]` entry after substitution: (name, path, line).
pub(super) type ResultEntry = (String, String, usize);

/// Substitute the `[result]` table (vars and params only).
pub(super) fn expand_result(p: &Parsed, diags: &mut Vec<Diag>) -> Vec<ResultEntry> {
    let mut out = Vec::new();
    for (name, v) in &p.raw.result {
        let line = p.lines.line(v.span().start);
        let look = |n: &str| p.vars.get(n).or_else(|| p.params_text.get(n)).cloned();
        match substitute(v.get_ref(), look) {
            Ok(s) => out.push((name.clone(), normalize(&s), line)),
            Err(e) => diags.push(Diag {
                line: Some(line),
                msg: format!("result `{name}`: {e}"),
            }),
        }
    }
    out
}

/// Expand every stage: `foreach` into instances, `${...}` substituted in each one's
/// command (word by word), deps and outs, its tracked params collected; problems go into
/// `diags` and the stage is left out.
pub(super) fn expand(text: &str, p: &Parsed, diags: &mut Vec<Diag>) -> Vec<Expanded> {
    let lines = &p.lines;
    let mut raw_stages: Vec<_> = p.raw.stages.iter().collect();
    raw_stages.sort_by_key(|(_, s)| s.span().start);
    let mut stages = Vec::new();
    for (base, rs) in raw_stages {
        let line = stage_line(text, lines, base, rs.span().start);
        if base.is_empty()
            || !base
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        {
            diags.push(Diag {
                line: Some(line),
                msg: format!("stage name `{base}` may only use letters, digits, `-` and `_`"),
            });
            continue;
        }
        let st = rs.get_ref();
        let items = match &st.foreach {
            None => vec![None],
            Some(f) => match foreach_items(f.get_ref(), &p.vars, &p.params_text) {
                Ok(items) => items.into_iter().map(Some).collect(),
                Err(m) => {
                    diags.push(Diag {
                        line: Some(lines.line(f.span().start)),
                        msg: format!("stage `{base}`: bad foreach: {m}"),
                    });
                    continue;
                }
            },
        };
        for item in items {
            let at = Instance {
                p,
                base,
                st,
                line,
                item: item.as_ref(),
            };
            if !at.present(diags) {
                continue;
            }
            if let Some(e) = at.expand(diags) {
                stages.push(e);
            }
        }
    }
    stages
}

/// One instance of a stage (its `foreach` item, if any), being expanded.
struct Instance<'a> {
    p: &'a Parsed,
    base: &'a str,
    st: &'a RawStage,
    /// Line of the stage's definition.
    line: usize,
    item: Option<&'a Item>,
}

impl Instance<'_> {
    /// `NAME` or `NAME@ITEM`.
    fn name(&self) -> String {
        match self.item {
            Some(it) => format!("{}@{}", self.base, it.label),
            None => self.base.to_string(),
        }
    }

    /// Whether the stage's `when` holds (no `when`: it does); a bad condition goes
    /// into `diags` and leaves the stage out.
    fn present(&self, diags: &mut Vec<Diag>) -> bool {
        let Some(w) = &self.st.when else {
            return true;
        };
        let line = self.p.lines.line(w.span().start);
        let mut tracked = BTreeSet::new();
        let Some(text) = self.sub(w.get_ref(), line, "when", &mut tracked, diags) else {
            return false;
        };
        match super::when::holds(&text) {
            Ok(b) => b,
            Err(m) => {
                diags.push(Diag {
                    line: Some(line),
                    msg: format!("stage `{}`: when `{text}`: {m}", self.name()),
                });
                false
            }
        }
    }

    /// The value of `${n}`: the item's, a `[vars]` value or a params value (whose key is
    /// then tracked).
    fn look(&self, n: &str, tracked: &mut BTreeSet<String>) -> Option<String> {
        if let Some(it) = self.item {
            if n == "item" {
                return Some(it.value.clone());
            }
            if n == "prev" {
                return it.prev.clone();
            }
            if let Some(f) = n.strip_prefix("item.") {
                return it
                    .fields
                    .iter()
                    .find(|(k, _)| k == f)
                    .map(|(_, v)| v.clone());
            }
        }
        if let Some(v) = self.p.vars.get(n) {
            return Some(v.clone());
        }
        let v = self.p.params_text.get(n)?;
        tracked.insert(n.to_string());
        Some(v.clone())
    }

    /// `text` substituted (`what` and `line` name it in a problem).
    fn sub(
        &self,
        text: &str,
        line: usize,
        what: &str,
        tracked: &mut BTreeSet<String>,
        diags: &mut Vec<Diag>,
    ) -> Option<String> {
        match substitute(text, |n| self.look(n, tracked)) {
            Ok(v) => Some(v),
            Err(e) => {
                let hint = if e == SubstError::Undefined("prev".into()) && self.item.is_some() {
                    " (the first item of a foreach list has no previous item)"
                } else {
                    ""
                };
                diags.push(Diag {
                    line: Some(line),
                    msg: format!("stage `{}`: {what}: {e}{hint}", self.name()),
                });
                None
            }
        }
    }

    /// The command split into words once, then each word substituted, so that a value
    /// stays one argument (`words`).
    fn argv(&self, tracked: &mut BTreeSet<String>, diags: &mut Vec<Diag>) -> Option<Vec<String>> {
        let cmd_line = self.p.lines.line(self.st.cmd.span().start);
        match words::split(self.st.cmd.get_ref())
            .and_then(|w| words::check_shell_script(&w).map(|()| w))
        {
            Ok(ws) => ws
                .iter()
                .map(|w| self.sub(w, cmd_line, "cmd", tracked, diags))
                .collect::<Vec<_>>()
                .into_iter()
                .collect(),
            Err(m) => {
                diags.push(Diag {
                    line: Some(cmd_line),
                    msg: format!("stage `{}`: cmd: {m}", self.name()),
                });
                None
            }
        }
    }

    /// The paths of `list` (deps or outs, `what`) substituted.
    fn paths(
        &self,
        list: &[Spanned<String>],
        what: &str,
        tracked: &mut BTreeSet<String>,
        diags: &mut Vec<Diag>,
    ) -> Option<Vec<String>> {
        let lines = &self.p.lines;
        list.iter()
            .map(|d| {
                self.sub(
                    d.get_ref(),
                    lines.line(d.span().start),
                    what,
                    tracked,
                    diags,
                )
            })
            .collect::<Vec<_>>()
            .into_iter()
            .collect()
    }

    /// The stage's listed `params` keys, added to `tracked` (each must be in the params
    /// file).
    fn listed_params(&self, tracked: &mut BTreeSet<String>, diags: &mut Vec<Diag>) {
        let p = self.p;
        for k in &self.st.params {
            if p.params.contains_key(k.get_ref()) {
                tracked.insert(k.get_ref().clone());
            } else {
                diags.push(Diag {
                    line: Some(p.lines.line(k.span().start)),
                    msg: format!(
                        "stage `{}`: params key `{}` is not in the params file{}",
                        self.name(),
                        k.get_ref(),
                        if p.raw.params.is_none() {
                            " (no `params = \"...\"` file is given)"
                        } else {
                            ""
                        }
                    ),
                });
            }
        }
    }

    /// The expanded stage, or `None` after a problem (in `diags`).
    fn expand(&self, diags: &mut Vec<Diag>) -> Option<Expanded> {
        let mut tracked: BTreeSet<String> = BTreeSet::new();
        let argv = self.argv(&mut tracked, diags);
        let deps = self.paths(&self.st.deps, "deps", &mut tracked, diags);
        let outs = self.paths(&self.st.outs, "outs", &mut tracked, diags);
        self.listed_params(&mut tracked, diags);
        let (argv, deps, outs) = (argv?, deps?, outs?);
        let lines = &self.p.lines;
        let st = self.st;
        // A dep that substitutes to nothing is no dep (an optional input left empty, e.g.
        // the sample DAG's `model`, whose stages then use the preset's prior).
        let kept: Vec<usize> = (0..deps.len()).filter(|&k| !deps[k].is_empty()).collect();
        let deps: Vec<String> = kept.iter().map(|&k| deps[k].clone()).collect();
        let st_deps: Vec<&Spanned<String>> = kept.iter().map(|&k| &st.deps[k]).collect();
        Some(Expanded {
            stage: Stage {
                name: self.name(),
                base: self.base.to_string(),
                desc: st.desc.clone(),
                argv,
                deps: deps
                    .iter()
                    .map(|d| {
                        if is_value_dep(d) {
                            d.clone()
                        } else {
                            normalize(d)
                        }
                    })
                    .collect(),
                outs: outs.iter().map(|d| normalize(d)).collect(),
                params: tracked.into_iter().collect(),
                line: self.line,
                upstream: Vec::new(),
            },
            dep_lines: st_deps.iter().map(|d| lines.line(d.span().start)).collect(),
            out_lines: st.outs.iter().map(|d| lines.line(d.span().start)).collect(),
            dep_literal: st_deps
                .iter()
                .map(|d| !d.get_ref().contains("${"))
                .collect(),
        })
    }
}

/// The line of `[stages.NAME]` if the stage is written as a header table, else the
/// line of the span start.
fn stage_line(text: &str, lines: &Lines, name: &str, span_start: usize) -> usize {
    for pat in [format!("[stages.{name}]"), format!("[stages.\"{name}\"]")] {
        if let Some(i) = text.find(&pat) {
            return lines.line(i);
        }
    }
    lines.line(span_start)
}

struct Item {
    label: String,
    value: String,
    prev: Option<String>,
    /// A matrix item's values by axis (`${item.scene}`); empty otherwise.
    fields: Vec<(String, String)>,
}

/// Most instances one `foreach` stage may expand to (a range or a matrix).
pub const MAX_INSTANCES: usize = 10_000;

/// `{ matrix = { axis = [labels], ... } }`: one item per combination, axes in key
/// order, labelled `a.b` (the values joined by `.`), `${item.axis}` each value.
fn matrix_items(m: &toml::Value) -> Result<Vec<Item>, ForeachError> {
    let toml::Value::Table(t) = m else {
        return Err(ForeachError::Matrix("matrix".into()));
    };
    if t.is_empty() {
        return Err(ForeachError::Matrix("matrix".into()));
    }
    // The number of combinations, before building any (it grows as a product).
    let total = t.values().fold(1u128, |acc, v| {
        acc.saturating_mul(v.as_array().map_or(1, |a| a.len().max(1)) as u128)
    });
    if total > MAX_INSTANCES as u128 {
        return Err(ForeachError::MatrixTooLarge(total));
    }
    let mut combos: Vec<Vec<(String, String)>> = vec![Vec::new()];
    for (axis, v) in t {
        let toml::Value::Array(a) = v else {
            return Err(ForeachError::Matrix(axis.clone()));
        };
        if a.is_empty() {
            return Err(ForeachError::Matrix(axis.clone()));
        }
        let mut labels: Vec<String> = Vec::new();
        for x in a {
            let s = label_of(x)?;
            if labels.contains(&s) {
                return Err(ForeachError::Twice(s));
            }
            labels.push(s);
        }
        combos = combos
            .into_iter()
            .flat_map(|c| {
                labels.iter().map(move |l| {
                    let mut c = c.clone();
                    c.push((axis.clone(), l.clone()));
                    c
                })
            })
            .collect();
    }
    Ok(combos
        .into_iter()
        .map(|fields| {
            let label = fields
                .iter()
                .map(|(_, v)| v.as_str())
                .collect::<Vec<_>>()
                .join(".");
            Item {
                label: label.clone(),
                value: label,
                prev: None,
                fields,
            }
        })
        .collect())
}

fn ok_label(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
}

fn foreach_items(
    v: &toml::Value,
    vars: &HashMap<String, String>,
    params: &HashMap<String, String>,
) -> Result<Vec<Item>, ForeachError> {
    match v {
        toml::Value::Array(a) => list_items(a),
        toml::Value::Table(t) if t.contains_key("matrix") => {
            if let Some(k) = t.keys().find(|k| *k != "matrix") {
                return Err(ForeachError::RangeKey(k.clone()));
            }
            matrix_items(&t["matrix"])
        }
        toml::Value::Table(t) => range_items(t, vars, params),
        other => Err(ForeachError::Shape(other.type_str())),
    }
}

/// A list item as a label: a string or an integer, of the characters a label may have.
fn label_of(x: &toml::Value) -> Result<String, ForeachError> {
    let s = match x {
        toml::Value::String(s) => s.clone(),
        toml::Value::Integer(i) => i.to_string(),
        other => return Err(ForeachError::ItemType(other.type_str())),
    };
    if !ok_label(&s) {
        return Err(ForeachError::Label(s));
    }
    Ok(s)
}

/// A list `["a", "b"]`: one item each, `${prev}` the one before.
fn list_items(a: &[toml::Value]) -> Result<Vec<Item>, ForeachError> {
    if a.is_empty() {
        return Err(ForeachError::Empty);
    }
    let mut items: Vec<Item> = Vec::new();
    for x in a {
        let s = label_of(x)?;
        if items.iter().any(|i| i.value == s) {
            return Err(ForeachError::Twice(s));
        }
        let prev = items.last().map(|i| i.value.clone());
        items.push(Item {
            label: s.clone(),
            value: s,
            prev,
            fields: Vec::new(),
        });
    }
    Ok(items)
}

/// A range `{ from = A, to = B, prefix = "r" }` (bounds may be `${var}`).
fn range_items(
    t: &toml::Table,
    vars: &HashMap<String, String>,
    params: &HashMap<String, String>,
) -> Result<Vec<Item>, ForeachError> {
    for k in t.keys() {
        if !["from", "to", "prefix"].contains(&k.as_str()) {
            return Err(ForeachError::RangeKey(k.clone()));
        }
    }
    let int = |key: &'static str| -> Result<i64, ForeachError> {
        match t.get(key) {
            None => Err(ForeachError::MissingBound(key)),
            Some(toml::Value::Integer(i)) => Ok(*i),
            Some(toml::Value::String(s)) => {
                let r = substitute(s, |n| vars.get(n).or_else(|| params.get(n)).cloned())?;
                r.trim()
                    .parse::<i64>()
                    .map_err(|_| ForeachError::NotInteger {
                        key,
                        raw: s.clone(),
                        value: r,
                    })
            }
            Some(o) => Err(ForeachError::BoundType {
                key,
                found: o.type_str(),
            }),
        }
    };
    let (from, to) = (int("from")?, int("to")?);
    let prefix = match t.get("prefix") {
        None => String::new(),
        Some(toml::Value::String(s)) if s.is_empty() || ok_label(s) => s.clone(),
        Some(_) => return Err(ForeachError::Prefix),
    };
    // `to = from - 1` is a count of zero (e.g. `distill.chunks = 0`): no instance.
    if to < from.saturating_sub(1) {
        return Err(ForeachError::EmptyRange { from, to });
    }
    if to
        .checked_sub(from)
        .is_none_or(|n| n >= MAX_INSTANCES as i64)
    {
        return Err(ForeachError::TooLong { from, to });
    }
    Ok((from..=to)
        .map(|n| Item {
            label: format!("{prefix}{n}"),
            value: n.to_string(),
            prev: n.checked_sub(1).map(|p| p.to_string()),
            fields: Vec::new(),
        })
        .collect())
}

/// Replace `${name}` using `look`; `$${` is a literal `${`.
pub fn substitute(
    s: &str,
    mut look: impl FnMut(&str) -> Option<String>,
) -> Result<String, SubstError> {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find('$') {
        out.push_str(&rest[..i]);
        let tail = &rest[i..];
        if let Some(after) = tail.strip_prefix("$${") {
            out.push_str("${");
            rest = after;
        } else if let Some(body) = tail.strip_prefix("${") {
            let end = body
                .find('}')
                .ok_or_else(|| SubstError::Unterminated(s.to_string()))?;
            let name = body[..end].trim();
            match look(name) {
                Some(v) => out.push_str(&v),
                None => return Err(SubstError::Undefined(name.to_string())),
            }
            rest = &body[end + 1..];
        } else {
            out.push('$');
            rest = &tail[1..];
        }
    }
    out.push_str(rest);
    Ok(out)
}

//! The DAG file: parsing, variable substitution, `foreach` expansion and validation.
//!
//! Format (TOML, close to DVC's `dvc.yaml` with Snakemake-style wildcards):
//!
//! ```toml
//! params = "params.toml"        # optional: a TOML file of tunable values
//! [vars]                        # strings or numbers, substituted as ${name}
//! model = "../vendor/models/stylizer"
//! [stages.render]
//! desc = "render the views"     # optional
//! cmd = "render-views --scene ${scene} --width ${render.width} --out runs/views"
//! deps = ["scene.ply"]          # files or directories read (another stage's outs or existing paths)
//! outs = ["runs/views"]         # files or directories written
//! params = ["render"]           # params-file keys (dotted; a table name tracks the whole table)
//! [stages.step]
//! foreach = { from = 1, to = "${rounds}", prefix = "r" }   # or a list: ["a", "b"]
//! cmd = "step --in runs/r${prev} --out runs/r${item}"
//! ```
//!
//! Substitution: `${name}` in `cmd`, `deps` and `outs` is replaced by a `[vars]` value,
//! a params-file value (dotted key, e.g. `${csd.guidance}`; such a reference also adds
//! the key to the stage's tracked params), or, inside a `foreach` stage, `${item}`
//! and `${prev}`. `$${` writes a literal `${`. Anything else after `${` is an error.
//!
//! `foreach` expands a stage into one stage per item, named `NAME@ITEM`:
//! * a list of strings or integers: `${item}` is the item, `${prev}` the previous item
//!   (undefined for the first one);
//! * a range `{ from = A, to = B, prefix = "r" }` (inclusive, `to` may be a `${var}`):
//!   items are the integers A..=B, instances are named `NAME@{prefix}{n}`, `${item}` is
//!   `n` and `${prev}` is `n-1` (so the first round can read a round-0 output).
//!
//! Validation runs before anything else and reports every problem with its line:
//! unknown keys, undefined variables, bad `foreach`, two stages writing one output
//! (or one inside the other), a dep that no stage produces and that does not exist,
//! and cycles (named stage by stage).

use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// One problem found in a DAG file.
#[derive(Debug, Clone, PartialEq)]
pub struct Diag {
    /// 1-based line in the DAG file, when known.
    pub line: Option<usize>,
    pub msg: String,
}

/// Every problem found in a DAG file (or in its params file).
#[derive(Debug)]
pub struct DagError {
    pub file: PathBuf,
    pub diags: Vec<Diag>,
}

impl fmt::Display for DagError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.diags.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            match d.line {
                Some(l) => write!(f, "{}:{l}: {}", self.file.display(), d.msg)?,
                None => write!(f, "{}: {}", self.file.display(), d.msg)?,
            }
        }
        Ok(())
    }
}
impl std::error::Error for DagError {}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDag {
    #[serde(default)]
    params: Option<Spanned<String>>,
    #[serde(default)]
    vars: BTreeMap<String, Spanned<toml::Value>>,
    #[serde(default)]
    stages: BTreeMap<String, Spanned<RawStage>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStage {
    cmd: Spanned<String>,
    #[serde(default)]
    desc: Option<String>,
    #[serde(default)]
    deps: Vec<Spanned<String>>,
    #[serde(default)]
    outs: Vec<Spanned<String>>,
    #[serde(default)]
    params: Vec<Spanned<String>>,
    #[serde(default)]
    foreach: Option<Spanned<toml::Value>>,
}

/// A stage after `foreach` expansion and substitution.
#[derive(Debug, Clone)]
pub struct Stage {
    /// `NAME` or `NAME@ITEM`.
    pub name: String,
    /// The `[stages.NAME]` key.
    pub base: String,
    pub desc: Option<String>,
    pub cmd: String,
    /// Normalised paths relative to the DAG directory (or absolute).
    pub deps: Vec<String>,
    pub outs: Vec<String>,
    /// Tracked params-file keys (listed or referenced in `${...}`), sorted.
    pub params: Vec<String>,
    /// Line of the stage's definition.
    pub line: usize,
    /// Indices of the stages producing this stage's deps.
    pub upstream: Vec<usize>,
}

/// A loaded and validated DAG.
#[derive(Debug, Clone)]
pub struct Dag {
    /// The DAG file.
    pub file: PathBuf,
    /// Its directory: commands run here, relative paths resolve here.
    pub dir: PathBuf,
    /// Stages in a topological order (ties broken by file order).
    pub stages: Vec<Stage>,
    /// The params file's values, flattened to dotted keys (tables included).
    pub params: BTreeMap<String, serde_json::Value>,
}

impl Dag {
    /// Index of stage `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.stages.iter().position(|s| s.name == name)
    }

    /// Absolute-or-DAG-relative path of a dep or out.
    pub fn path(&self, p: &str) -> PathBuf {
        self.dir.join(p)
    }

    /// Lock file path: `<dir>/<stem>.lock`.
    pub fn lock_path(&self) -> PathBuf {
        let stem = self
            .file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "dag".into());
        self.dir.join(format!("{stem}.lock"))
    }

    /// The `.pipeline` state directory next to the DAG.
    pub fn state_dir(&self) -> PathBuf {
        self.dir.join(".pipeline")
    }

    /// The stages selected by `targets` (stage names, or base names selecting every
    /// instance) plus everything upstream of them; all stages when `targets` is empty.
    /// Returned in topological order.
    pub fn select(&self, targets: &[String]) -> Result<Vec<usize>, String> {
        if targets.is_empty() {
            return Ok((0..self.stages.len()).collect());
        }
        let mut want = vec![false; self.stages.len()];
        let mut stack = Vec::new();
        for t in targets {
            let hits: Vec<usize> = (0..self.stages.len())
                .filter(|&i| self.stages[i].name == *t || self.stages[i].base == *t)
                .collect();
            if hits.is_empty() {
                return Err(format!("no stage named `{t}` in {}", self.file.display()));
            }
            stack.extend(hits);
        }
        while let Some(i) = stack.pop() {
            if !want[i] {
                want[i] = true;
                stack.extend(self.stages[i].upstream.iter().copied());
            }
        }
        Ok((0..self.stages.len()).filter(|&i| want[i]).collect())
    }

    /// Indices of every stage downstream of `i` (not including `i`).
    pub fn downstream(&self, i: usize) -> Vec<usize> {
        let mut hit = vec![false; self.stages.len()];
        hit[i] = true;
        // Topological order: one forward sweep suffices.
        for j in i + 1..self.stages.len() {
            if self.stages[j].upstream.iter().any(|&u| hit[u]) {
                hit[j] = true;
            }
        }
        hit[i] = false;
        (0..self.stages.len()).filter(|&j| hit[j]).collect()
    }
}

/// Maps byte offsets to 1-based line numbers.
struct Lines(Vec<usize>);
impl Lines {
    fn new(text: &str) -> Self {
        let mut v = vec![0];
        v.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        Lines(v)
    }
    fn line(&self, offset: usize) -> usize {
        self.0.partition_point(|&s| s <= offset)
    }
}

/// Load, expand and validate a DAG file.
pub fn load(file: &Path) -> Result<Dag, DagError> {
    let err = |line: Option<usize>, msg: String| DagError {
        file: file.to_path_buf(),
        diags: vec![Diag { line, msg }],
    };
    let text = std::fs::read_to_string(file).map_err(|e| err(None, format!("cannot read: {e}")))?;
    let dir = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
    parse(&text, file, &dir)
}

/// Parse DAG text; `file` names it in messages, `dir` is where relative paths resolve.
pub fn parse(text: &str, file: &Path, dir: &Path) -> Result<Dag, DagError> {
    let lines = Lines::new(text);
    let fail = |diags: Vec<Diag>| DagError {
        file: file.to_path_buf(),
        diags,
    };
    let raw: RawDag = toml::from_str(text).map_err(|e| {
        fail(vec![Diag {
            line: e.span().map(|s| lines.line(s.start)),
            msg: e.message().trim().to_string(),
        }])
    })?;
    let mut diags = Vec::new();

    // Params file.
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

    // Variables.
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
    let params_text: HashMap<String, String> = params
        .iter()
        .filter_map(|(k, v)| json_scalar(v).map(|s| (k.clone(), s)))
        .collect();

    // Expansion, in file order.
    let mut raw_stages: Vec<(&String, &Spanned<RawStage>)> = raw.stages.iter().collect();
    raw_stages.sort_by_key(|(_, s)| s.span().start);
    let mut stages = Vec::new();
    for (base, rs) in raw_stages {
        let line = stage_line(text, &lines, base, rs.span().start);
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
            Some(f) => match foreach_items(f.get_ref(), &vars, &params_text) {
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
            let name = match &item {
                Some(it) => format!("{base}@{}", it.label),
                None => base.clone(),
            };
            let mut tracked: BTreeSet<String> = BTreeSet::new();
            let mut sub = |s: &Spanned<String>, what: &str, diags: &mut Vec<Diag>| {
                let look = |n: &str| -> Option<String> {
                    if let Some(it) = &item {
                        if n == "item" {
                            return Some(it.value.clone());
                        }
                        if n == "prev" {
                            return it.prev.clone();
                        }
                    }
                    if let Some(v) = vars.get(n) {
                        return Some(v.clone());
                    }
                    let v = params_text.get(n)?;
                    tracked.insert(n.to_string());
                    Some(v.clone())
                };
                match substitute(s.get_ref(), look) {
                    Ok(v) => Some(v),
                    Err(m) => {
                        let hint = if m.contains("`${prev}`") && item.is_some() {
                            " (the first item of a foreach list has no previous item)"
                        } else {
                            ""
                        };
                        diags.push(Diag {
                            line: Some(lines.line(s.span().start)),
                            msg: format!("stage `{name}`: {what}: {m}{hint}"),
                        });
                        None
                    }
                }
            };
            let cmd = sub(&st.cmd, "cmd", &mut diags);
            let deps: Vec<_> = st.deps.iter().map(|d| sub(d, "deps", &mut diags)).collect();
            let outs: Vec<_> = st.outs.iter().map(|d| sub(d, "outs", &mut diags)).collect();
            for p in &st.params {
                if params.contains_key(p.get_ref()) {
                    tracked.insert(p.get_ref().clone());
                } else {
                    diags.push(Diag {
                        line: Some(lines.line(p.span().start)),
                        msg: format!(
                            "stage `{name}`: params key `{}` is not in the params file{}",
                            p.get_ref(),
                            if raw.params.is_none() {
                                " (no `params = \"...\"` file is given)"
                            } else {
                                ""
                            }
                        ),
                    });
                }
            }
            let (Some(cmd), Some(deps), Some(outs)) = (
                cmd,
                deps.into_iter().collect::<Option<Vec<_>>>(),
                outs.into_iter().collect::<Option<Vec<_>>>(),
            ) else {
                continue;
            };
            let dep_lines: Vec<usize> =
                st.deps.iter().map(|d| lines.line(d.span().start)).collect();
            let out_lines: Vec<usize> =
                st.outs.iter().map(|d| lines.line(d.span().start)).collect();
            stages.push((
                Stage {
                    name,
                    base: base.clone(),
                    desc: st.desc.clone(),
                    cmd,
                    deps: deps.iter().map(|d| normalize(d)).collect(),
                    outs: outs.iter().map(|d| normalize(d)).collect(),
                    params: tracked.into_iter().collect(),
                    line,
                    upstream: Vec::new(),
                },
                dep_lines,
                out_lines,
            ));
        }
    }
    if !diags.is_empty() {
        return Err(fail(diags));
    }

    // Outputs the runner may delete after a failure must stay inside the DAG
    // directory and away from the DAG's own files.
    let params_file = raw.params.as_ref().map(|p| normalize(p.get_ref()));
    let dag_name = file
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let lock_name = format!(
        "{}.lock",
        file.file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    for (s, _, ol) in &stages {
        for (o, &l) in s.outs.iter().zip(ol) {
            let own = |f: &str| o == f || inside(f, o);
            if o == "." || o == ".." || o.starts_with("../") || o.starts_with('/') {
                diags.push(Diag {
                    line: Some(l),
                    msg: format!(
                        "output `{o}` of stage `{}` must be a path inside the DAG's directory",
                        s.name
                    ),
                });
            } else if own(&dag_name)
                || own(&lock_name)
                || own(".pipeline")
                || inside(o, ".pipeline")
                || params_file.as_deref().is_some_and(own)
            {
                diags.push(Diag {
                    line: Some(l),
                    msg: format!(
                        "output `{o}` of stage `{}` would overwrite the DAG, its params or its state",
                        s.name
                    ),
                });
            }
        }
    }

    // Duplicate (or nested) outputs.
    let mut outs: Vec<(&str, usize, usize)> = Vec::new(); // (path, stage, line)
    for (i, (s, _, ol)) in stages.iter().enumerate() {
        for (o, &l) in s.outs.iter().zip(ol) {
            for &(p, j, lj) in &outs {
                if p == o || inside(o, p) || inside(p, o) {
                    let how = if p == o { "also" } else { "overlappingly" };
                    diags.push(Diag {
                        line: Some(l),
                        msg: format!(
                            "output `{o}` of stage `{}` is {how} written by stage `{}` (`{p}`, line {lj})",
                            s.name, stages[j].0.name
                        ),
                    });
                }
            }
            outs.push((o, i, l));
        }
    }
    // Producers.
    let n = stages.len();
    let mut upstream = vec![Vec::new(); n];
    for (i, (s, dl, _)) in stages.iter().enumerate() {
        for (d, &l) in s.deps.iter().zip(dl) {
            let producers: Vec<usize> = outs
                .iter()
                .filter(|(p, _, _)| *p == d || inside(d, p))
                .map(|&(_, j, _)| j)
                .collect();
            if producers.is_empty() {
                if !dir.join(d).exists() {
                    diags.push(Diag {
                        line: Some(l),
                        msg: format!(
                            "dep `{d}` of stage `{}` does not exist and no stage produces it (missing producer)",
                            s.name
                        ),
                    });
                }
            } else {
                for j in producers {
                    if !upstream[i].contains(&j) {
                        upstream[i].push(j);
                    }
                }
            }
        }
    }
    if !diags.is_empty() {
        return Err(fail(diags));
    }
    // Cycles, then a topological order (Kahn, ties by file order).
    if let Some(cycle) = find_cycle(&upstream) {
        let names: Vec<&str> = cycle.iter().map(|&i| stages[i].0.name.as_str()).collect();
        let first = cycle[0];
        return Err(fail(vec![Diag {
            line: Some(stages[first].0.line),
            msg: format!("dependency cycle: {}", names.join(" -> ")),
        }]));
    }
    let order = topo_order(&upstream);
    let mut pos = vec![0; n];
    for (k, &i) in order.iter().enumerate() {
        pos[i] = k;
    }
    let mut ordered: Vec<Stage> = order
        .iter()
        .map(|&i| {
            let mut s = stages[i].0.clone();
            s.upstream = upstream[i].iter().map(|&u| pos[u]).collect();
            s.upstream.sort();
            s
        })
        .collect();
    ordered.shrink_to_fit();
    Ok(Dag {
        file: file.to_path_buf(),
        dir: dir.to_path_buf(),
        stages: ordered,
        params,
    })
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
}

fn foreach_items(
    v: &toml::Value,
    vars: &HashMap<String, String>,
    params: &HashMap<String, String>,
) -> Result<Vec<Item>, String> {
    let ok_label = |s: &str| {
        !s.is_empty()
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
    };
    match v {
        toml::Value::Array(a) => {
            if a.is_empty() {
                return Err("the list is empty".into());
            }
            let mut items: Vec<Item> = Vec::new();
            for x in a {
                let s = match x {
                    toml::Value::String(s) => s.clone(),
                    toml::Value::Integer(i) => i.to_string(),
                    other => {
                        return Err(format!(
                            "items must be strings or integers, found {}",
                            other.type_str()
                        ));
                    }
                };
                if !ok_label(&s) {
                    return Err(format!(
                        "item `{s}` may only use letters, digits, `-`, `_` and `.`"
                    ));
                }
                if items.iter().any(|i| i.value == s) {
                    return Err(format!("item `{s}` appears twice"));
                }
                let prev = items.last().map(|i| i.value.clone());
                items.push(Item {
                    label: s.clone(),
                    value: s,
                    prev,
                });
            }
            Ok(items)
        }
        toml::Value::Table(t) => {
            for k in t.keys() {
                if !["from", "to", "prefix"].contains(&k.as_str()) {
                    return Err(format!(
                        "unknown key `{k}` in a range (expected `from`, `to`, `prefix`)"
                    ));
                }
            }
            let int = |key: &str| -> Result<i64, String> {
                match t.get(key) {
                    None => Err(format!("a range needs `{key}`")),
                    Some(toml::Value::Integer(i)) => Ok(*i),
                    Some(toml::Value::String(s)) => {
                        let r = substitute(s, |n| vars.get(n).or_else(|| params.get(n)).cloned())?;
                        r.trim()
                            .parse::<i64>()
                            .map_err(|_| format!("`{key}` = \"{s}\" is `{r}`, not an integer"))
                    }
                    Some(o) => Err(format!(
                        "`{key}` must be an integer or a \"${{var}}\", found {}",
                        o.type_str()
                    )),
                }
            };
            let (from, to) = (int("from")?, int("to")?);
            let prefix = match t.get("prefix") {
                None => String::new(),
                Some(toml::Value::String(s)) if s.is_empty() || ok_label(s) => s.clone(),
                Some(_) => return Err("`prefix` must be a string of letters/digits".into()),
            };
            if to < from {
                return Err(format!("range is empty (from = {from}, to = {to})"));
            }
            if to - from >= 10_000 {
                return Err(format!("range {from}..={to} is too long"));
            }
            Ok((from..=to)
                .map(|n| Item {
                    label: format!("{prefix}{n}"),
                    value: n.to_string(),
                    prev: Some((n - 1).to_string()),
                })
                .collect())
        }
        other => Err(format!(
            "expected a list of items or a range table {{ from, to, prefix }}, found {}",
            other.type_str()
        )),
    }
}

/// Replace `${name}` using `look`; `$${` is a literal `${`.
pub fn substitute(s: &str, mut look: impl FnMut(&str) -> Option<String>) -> Result<String, String> {
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
                .ok_or_else(|| format!("unterminated `${{` in `{s}`"))?;
            let name = body[..end].trim();
            match look(name) {
                Some(v) => out.push_str(&v),
                None => return Err(format!("undefined variable `${{{name}}}`")),
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

fn scalar(v: &toml::Value) -> Option<String> {
    match v {
        toml::Value::String(s) => Some(s.clone()),
        toml::Value::Integer(i) => Some(i.to_string()),
        toml::Value::Float(f) => Some(f.to_string()),
        toml::Value::Boolean(b) => Some(b.to_string()),
        _ => None,
    }
}

fn json_scalar(v: &serde_json::Value) -> Option<String> {
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

/// Lexically normalise a relative path: drop `.`, fold `a/..`, drop trailing `/`.
pub fn normalize(p: &str) -> String {
    let abs = p.starts_with('/');
    let mut parts: Vec<&str> = Vec::new();
    for c in p.split('/') {
        match c {
            "" | "." => {}
            ".." if parts.last().is_some_and(|l| *l != "..") => {
                parts.pop();
            }
            c => parts.push(c),
        }
    }
    let j = parts.join("/");
    if abs {
        format!("/{j}")
    } else if j.is_empty() {
        ".".into()
    } else {
        j
    }
}

/// Whether `p` lies strictly inside directory `dir`.
pub fn inside(p: &str, dir: &str) -> bool {
    p.len() > dir.len() && p.starts_with(dir) && p.as_bytes()[dir.len()] == b'/'
}

/// A cycle in `upstream` (stage -> its producers), as stage indices in dependency
/// order `a -> b -> ... -> a` (each depends on the next's output... reversed so that
/// the message reads producer first).
fn find_cycle(upstream: &[Vec<usize>]) -> Option<Vec<usize>> {
    // 0 = unvisited, 1 = on stack, 2 = done
    let n = upstream.len();
    let mut state = vec![0u8; n];
    let mut stack: Vec<(usize, usize)> = Vec::new();
    for root in 0..n {
        if state[root] != 0 {
            continue;
        }
        stack.push((root, 0));
        state[root] = 1;
        while let Some(&mut (v, ref mut k)) = stack.last_mut() {
            if *k < upstream[v].len() {
                let u = upstream[v][*k];
                *k += 1;
                match state[u] {
                    0 => {
                        state[u] = 1;
                        stack.push((u, 0));
                    }
                    1 => {
                        let at = stack.iter().position(|&(x, _)| x == u).unwrap_or(0);
                        // stack[at..] goes consumer -> producer; print producer -> consumer.
                        let mut c: Vec<usize> = stack[at..].iter().map(|&(x, _)| x).collect();
                        c.reverse();
                        c.push(c[0]);
                        return Some(c);
                    }
                    _ => {}
                }
            } else {
                state[v] = 2;
                stack.pop();
            }
        }
    }
    None
}

fn topo_order(upstream: &[Vec<usize>]) -> Vec<usize> {
    let n = upstream.len();
    let mut done = vec![false; n];
    let mut order = Vec::with_capacity(n);
    while order.len() < n {
        let next = (0..n)
            .find(|&i| !done[i] && upstream[i].iter().all(|&u| done[u]))
            .expect("acyclic graph always has a ready stage");
        done[next] = true;
        order.push(next);
    }
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn try_parse(text: &str) -> Result<Dag, DagError> {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("in.txt"), "x").unwrap();
        std::fs::write(
            d.path().join("params.toml"),
            "seed = 3\n[csd]\nguidance = 7.5\nmode = \"csd\"\n",
        )
        .unwrap();
        parse(text, Path::new("dag.toml"), d.path())
    }

    fn err(text: &str) -> String {
        try_parse(text).unwrap_err().to_string()
    }

    #[test]
    fn expands_foreach_range_with_prev_and_orders_topologically() {
        let dag = try_parse(
            r#"
params = "params.toml"
[vars]
rounds = 3
[stages.step]
foreach = { from = 1, to = "${rounds}", prefix = "r" }
cmd = "step --in runs/r${prev} --out runs/r${item} --g ${csd.guidance}"
deps = ["runs/r${prev}"]
outs = ["runs/r${item}"]
[stages.init]
cmd = "init --seed ${seed}"
deps = ["./in.txt"]
outs = ["runs/r0/"]
"#,
        )
        .unwrap();
        let names: Vec<_> = dag.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["init", "step@r1", "step@r2", "step@r3"]);
        assert_eq!(dag.stages[2].cmd, "step --in runs/r1 --out runs/r2 --g 7.5");
        assert_eq!(dag.stages[2].params, ["csd.guidance"]);
        assert_eq!(dag.stages[0].params, ["seed"]);
        assert_eq!(dag.stages[0].deps, ["in.txt"]);
        assert_eq!(dag.stages[0].outs, ["runs/r0"]);
        assert_eq!(dag.stages[3].upstream, [2]);
        assert_eq!(dag.downstream(1), [2, 3]);
        assert_eq!(dag.select(&["step@r2".into()]).unwrap(), [0, 1, 2]);
        assert!(dag.select(&["nope".into()]).is_err());
    }

    #[test]
    fn foreach_list_and_literal_dollar() {
        let dag = try_parse(
            r#"
[stages.a]
foreach = ["x", "y"]
cmd = "echo $${HOME} $$ ${item} ${prev}"
outs = ["o/${item}"]
"#,
        );
        let e = dag.unwrap_err().to_string();
        assert!(
            e.contains("dag.toml:4: stage `a@x`: cmd: undefined variable `${prev}`")
                && e.contains("no previous item"),
            "{e}"
        );
        let dag = try_parse(
            "[stages.a]\nforeach = [\"x\", \"y\"]\ncmd = \"echo $${HOME} $$ ${item}\"\nouts = [\"o/${item}\"]\n",
        )
        .unwrap();
        assert_eq!(dag.stages[1].name, "a@y");
        assert_eq!(dag.stages[1].cmd, "echo ${HOME} $$ y");
    }

    #[test]
    fn cycle_is_named_with_its_line() {
        let e = err(r#"
[stages.a]
cmd = "a"
deps = ["b.out"]
outs = ["a.out"]

[stages.b]
cmd = "b"
deps = ["a.out"]
outs = ["b.out"]
"#);
        assert!(
            e.contains("dependency cycle:") && e.contains("a -> b -> a")
                || e.contains("b -> a -> b"),
            "{e}"
        );
        assert!(
            e.starts_with("dag.toml:2: ") || e.starts_with("dag.toml:7: "),
            "{e}"
        );
    }

    #[test]
    fn self_cycle_through_nested_output() {
        let e = err("[stages.a]\ncmd = \"a\"\ndeps = [\"o/x\"]\nouts = [\"o\"]\n");
        assert_eq!(e, "dag.toml:1: dependency cycle: a -> a");
    }

    #[test]
    fn missing_producer_reports_the_dep_line() {
        let e = err(
            "[stages.a]\ncmd = \"a\"\ndeps = [\n  \"in.txt\",\n  \"nowhere.npy\",\n]\nouts = [\"o\"]\n",
        );
        assert_eq!(
            e,
            "dag.toml:5: dep `nowhere.npy` of stage `a` does not exist and no stage produces it (missing producer)"
        );
    }

    #[test]
    fn duplicate_output_names_both_stages() {
        let e = err(
            "[stages.a]\ncmd = \"a\"\nouts = [\"o\"]\n[stages.b]\ncmd = \"b\"\nouts = [\"./o\"]\n",
        );
        assert_eq!(
            e,
            "dag.toml:6: output `o` of stage `b` is also written by stage `a` (`o`, line 3)"
        );
        let e = err(
            "[stages.a]\ncmd = \"a\"\nouts = [\"o\"]\n[stages.b]\ncmd = \"b\"\nouts = [\"o/x\"]\n",
        );
        assert!(e.contains("overlappingly written by stage `a`"), "{e}");
    }

    #[test]
    fn unknown_keys_are_rejected_with_line() {
        let e = err("[stages.a]\ncmd = \"a\"\noutz = [\"o\"]\n");
        assert!(e.starts_with("dag.toml:3: unknown field `outz`"), "{e}");
        let e = err("stagez = 1\n");
        assert!(e.starts_with("dag.toml:1: unknown field `stagez`"), "{e}");
        let e = err("[stages.a]\noutz = 1\n");
        assert!(e.contains("unknown field `outz`"), "{e}");
    }

    #[test]
    fn undefined_variable_reports_line() {
        let e = err("[vars]\nx = 1\n[stages.a]\ncmd = \"a ${x}\"\nouts = [\"o/${y}\"]\n");
        assert_eq!(e, "dag.toml:5: stage `a`: outs: undefined variable `${y}`");
        let e = err("[stages.a]\ncmd = \"a ${x\"\n");
        assert!(
            e.contains("dag.toml:2: stage `a`: cmd: unterminated"),
            "{e}"
        );
    }

    #[test]
    fn bad_foreach_cases() {
        let cases = [
            ("foreach = []", "the list is empty"),
            (
                "foreach = [1.5]",
                "items must be strings or integers, found float",
            ),
            ("foreach = [\"a\", \"a\"]", "item `a` appears twice"),
            ("foreach = [\"a b\"]", "may only use letters"),
            (
                "foreach = { from = 3, to = 1 }",
                "range is empty (from = 3, to = 1)",
            ),
            ("foreach = { from = 1, upto = 2 }", "unknown key `upto`"),
            ("foreach = { from = 1 }", "a range needs `to`"),
            (
                "foreach = { from = 1, to = \"${nope}\" }",
                "undefined variable `${nope}`",
            ),
            ("foreach = 3", "expected a list of items or a range table"),
        ];
        for (f, want) in cases {
            let e = err(&format!(
                "[stages.a]\ncmd = \"a\"\n{f}\nouts = [\"o${{item}}\"]\n"
            ));
            assert!(
                e.starts_with("dag.toml:3: stage `a`: bad foreach: ") && e.contains(want),
                "{f}: {e}"
            );
        }
    }

    #[test]
    fn params_keys_must_exist() {
        let e = err("params = \"params.toml\"\n[stages.a]\ncmd = \"a\"\nparams = [\"csd.nope\"]\n");
        assert_eq!(
            e,
            "dag.toml:4: stage `a`: params key `csd.nope` is not in the params file"
        );
        let dag =
            try_parse("params = \"params.toml\"\n[stages.a]\ncmd = \"a\"\nparams = [\"csd\"]\n")
                .unwrap();
        assert_eq!(dag.stages[0].params, ["csd"]);
        assert_eq!(dag.params["csd"]["mode"], "csd");
        let e = err("params = \"nope.toml\"\n");
        assert!(e.starts_with("dag.toml:1: cannot read params file"), "{e}");
    }

    #[test]
    fn outputs_must_stay_inside_and_off_the_dags_files() {
        for (o, want) in [
            ("..", "must be a path inside the DAG's directory"),
            ("/tmp/x", "must be a path inside the DAG's directory"),
            ("a/../..", "must be a path inside the DAG's directory"),
            ("./", "must be a path inside the DAG's directory"),
            (
                "params.toml",
                "would overwrite the DAG, its params or its state",
            ),
            (
                ".pipeline/logs",
                "would overwrite the DAG, its params or its state",
            ),
        ] {
            let e = err(&format!(
                "params = \"params.toml\"\n[stages.a]\ncmd = \"a\"\nouts = [\"{o}\"]\n"
            ));
            assert!(
                e.starts_with("dag.toml:4: output") && e.contains(want),
                "{o}: {e}"
            );
        }
    }

    #[test]
    fn normalize_paths() {
        assert_eq!(normalize("./a//b/"), "a/b");
        assert_eq!(normalize("a/../b"), "b");
        assert_eq!(normalize("../x"), "../x");
        assert_eq!(normalize("/abs/./p"), "/abs/p");
        assert!(inside("a/b", "a") && !inside("ab", "a") && !inside("a", "a"));
    }
}

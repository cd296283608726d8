//! The DAG file: parsing, variable substitution, `foreach` expansion, validation and
//! the graph, one phase per module: `parse` (TOML, params file, `[vars]`) ->
//! `expand` (`foreach`, `${...}`) -> `validate` (outputs, producers) -> `graph`
//! (cycles, topological order). `load` runs them in that order.
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
//! deps = ["scene.ply"]          # files or directories read (another stage's outs or existing paths; one that substitutes to "" is none)
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
//! and `${prev}`. A params *table* (`${distill.loop}`) becomes one argument, the table
//! as inline TOML (`{ a = 1, b = { c = "x" } }`, keys sorted), and the stage tracks the
//! table whole: a stage that takes its configuration as a table reruns when, and only
//! when, a key in that table changes. `$${` writes a literal `${`. Anything else after `${` is an error.
//! `cmd` is split into arguments first (shell quoting rules) and substituted per
//! argument; stages run without a shell, so a value is always one argument (or part of
//! the one word it is written in), never shell code ([`words`]).
//!
//! `foreach` expands a stage into one stage per item, named `NAME@ITEM`:
//! * a list of strings or integers: `${item}` is the item, `${prev}` the previous item
//!   (undefined for the first one);
//! * a range `{ from = A, to = B, prefix = "r" }` (inclusive, `to` may be a `${var}`):
//!   items are the integers A..=B, instances are named `NAME@{prefix}{n}`, `${item}` is
//!   `n` and `${prev}` is `n-1` (so the first round can read a round-0 output);
//! * a matrix `{ matrix = { scene = ["bob", "fish"], style = ["wave", "ink"] } }`: one
//!   instance per combination (axes in key order), named `NAME@bob.wave`, with
//!   `${item.scene}` and `${item.style}` the values (`${item}` is `bob.wave`; no
//!   `${prev}`). Every scene in every style, in one file.
//!
//! `when` (optional) keeps a stage only where its condition holds after substitution
//! (`when = "${distill.chunks} > 0"`; [`when`]): a stage whose condition fails is no
//! stage, so two stages may write the same output when at most one of them exists.
//!
//! `[result]` (optional) names what a successful run leaves for the user, e.g.
//! `scene = "runs/final/scene.ply"`; `pipeline run` prints these paths at its end.
//!
//! Deps are paths (files or directories), or values written `scheme:rest` such as
//! `orbit:16` (a generated camera spec), which are hashed by their text.
//!
//! The work directory (`--workdir`, default the DAG's directory) holds every output,
//! the lock and `.pipeline/`; commands run there. `--set NAME=VALUE` overrides a
//! `[vars]` value or a params value (dotted key); it may also add a key to a table that
//! a stage takes whole (the value read as a TOML literal, else as a string): the stage
//! that reads the table checks its keys. How paths from the DAG file and from
//! `--set` are resolved is described in `locate`.
//!
//! Validation runs before anything else and reports every problem with its line:
//! unknown keys, undefined variables, bad `foreach`, two stages writing one output
//! (or one inside the other), a dep that no stage produces and that does not exist,
//! and cycles (named stage by stage).

mod expand;
#[cfg(test)]
mod fuzz;
mod graph;
mod locate;
mod parse;
mod validate;
mod when;
pub mod words;

pub use locate::{Places, absolute, is_value_dep, lexical, relative};

pub use expand::{ForeachError, SubstError, substitute};

use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

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

/// A stage after `foreach` expansion and substitution.
#[derive(Debug, Clone)]
pub struct Stage {
    /// `NAME` or `NAME@ITEM`.
    pub name: String,
    /// The `[stages.NAME]` key.
    pub base: String,
    pub desc: Option<String>,
    /// The command's arguments after substitution (program first); run without a shell
    /// ([`words`]).
    pub argv: Vec<String>,
    /// Normalised paths relative to the work directory (or absolute), or values
    /// (`orbit:16`, see [`is_value_dep`]).
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
    /// Its directory (absolute): the params file and the DAG's own relative paths
    /// are found here.
    pub dir: PathBuf,
    /// The work directory (absolute): commands run here; outputs, the lock and
    /// `.pipeline/` go here. The DAG's directory unless `--workdir` says otherwise.
    pub workdir: PathBuf,
    /// Stages in a topological order (ties broken by file order).
    pub stages: Vec<Stage>,
    /// The params file's values (`--set` applied), flattened to dotted keys (tables
    /// included).
    pub params: BTreeMap<String, serde_json::Value>,
    /// The `[result]` table: (name, path relative to the work directory).
    pub result: Vec<(String, String)>,
    /// The `--set` overrides it was loaded with.
    pub sets: Vec<Set>,
}

/// A `--set NAME=VALUE` override.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Set {
    pub name: String,
    pub value: String,
}

impl std::str::FromStr for Set {
    type Err = Error;
    fn from_str(s: &str) -> Result<Set> {
        match s.split_once('=') {
            Some((n, v)) if !n.trim().is_empty() => Ok(Set {
                name: n.trim().to_string(),
                value: v.to_string(),
            }),
            _ => Err(Error::Usage(format!(
                "--set `{s}`: expected NAME=VALUE (a [vars] name or a dotted params key, e.g. --set scene=captures/cat.splat)"
            ))),
        }
    }
}

impl fmt::Display for Set {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}={}", self.name, self.value)
    }
}

/// How to load a DAG: the work directory and `--set` overrides.
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// `--workdir` (relative to the current directory); `None`: the DAG's directory.
    pub workdir: Option<PathBuf>,
    pub sets: Vec<Set>,
}

impl Stage {
    /// The command as one shell-quoted line ([`words::join`]): what the lock records and
    /// the logs, `status` and the Snakemake export show.
    pub fn cmd(&self) -> String {
        words::join(&self.argv)
    }
}

impl Dag {
    /// Index of stage `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.stages.iter().position(|s| s.name == name)
    }

    /// Path of a dep or out (relative ones are in the work directory).
    pub fn path(&self, p: &str) -> PathBuf {
        lexical(&self.workdir.join(p))
    }

    /// Lock file path: `<workdir>/<stem>.lock`.
    pub fn lock_path(&self) -> PathBuf {
        let stem = self
            .file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "dag".into());
        self.workdir.join(format!("{stem}.lock"))
    }

    /// The `.pipeline` state directory (logs, timing, run.pid) in the work directory.
    pub fn state_dir(&self) -> PathBuf {
        self.workdir.join(".pipeline")
    }

    /// The stages selected by `targets` (stage names, or base names selecting every
    /// instance) plus everything upstream of them; all stages when `targets` is empty.
    /// Returned in topological order.
    pub fn select(&self, targets: &[String]) -> Result<Vec<usize>> {
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
                return Err(Error::NoSuchStage {
                    name: t.clone(),
                    file: self.file.clone(),
                });
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

/// Load, expand and validate a DAG file (work directory: the DAG's, no overrides).
pub fn load(file: &Path) -> Result<Dag> {
    load_with(file, &LoadOptions::default())
}

/// Load, expand and validate a DAG file with a work directory and `--set` overrides.
pub fn load_with(file: &Path, opts: &LoadOptions) -> Result<Dag> {
    let text = std::fs::read_to_string(file).map_err(|e| DagError {
        file: file.to_path_buf(),
        diags: vec![Diag {
            line: None,
            msg: format!("cannot read: {e}"),
        }],
    })?;
    let dir = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let dir = absolute(&dir);
    let places = Places {
        workdir: opts
            .workdir
            .as_deref()
            .map_or_else(|| dir.clone(), absolute),
        cwd: absolute(Path::new(".")),
        dir,
    };
    parse_with(&text, file, &places, &opts.sets)
}

/// Parse DAG text; `file` names it in messages, `dir` is where relative paths resolve
/// (and the work directory).
pub fn parse(text: &str, file: &Path, dir: &Path) -> Result<Dag> {
    let places = Places {
        dir: dir.to_path_buf(),
        workdir: dir.to_path_buf(),
        cwd: absolute(Path::new(".")),
    };
    parse_with(text, file, &places, &[])
}

/// Parse DAG text with the given directories and overrides: parse, apply `--set`,
/// expand, relocate the DAG's own paths for the work directory, validate, order.
pub fn parse_with(text: &str, file: &Path, places: &Places, sets: &[Set]) -> Result<Dag> {
    let fail = |diags: Vec<Diag>| DagError {
        file: file.to_path_buf(),
        diags,
    };
    let mut diags = Vec::new();
    let mut parsed = parse::parse(text, &places.dir, &mut diags).map_err(|d| fail(vec![d]))?;
    let set_vars = parse::apply_sets(&mut parsed, sets, places, file)?;
    let mut stages = expand::expand(text, &parsed, &mut diags);
    if !diags.is_empty() {
        return Err(fail(diags).into());
    }
    if places.moved() {
        // [vars] values naming the DAG's own files, as seen from the work directory;
        // then expand again with them.
        let mut moved = false;
        for (k, v) in parsed.vars.iter_mut() {
            if set_vars.contains(k) || expand::produced(&normalize(v), &stages) {
                continue;
            }
            if let Some(r) = places.from_dag(v) {
                *v = r;
                moved = true;
            }
        }
        if moved {
            stages = expand::expand(text, &parsed, &mut diags);
        }
        expand::relocate_literals(&mut stages, places);
    }
    let result = expand::expand_result(&parsed, &mut diags);
    diags.extend(validate::check_result(&result, &stages));
    if !diags.is_empty() {
        return Err(fail(diags).into());
    }
    let set_values: Vec<(String, String)> = set_vars
        .iter()
        .filter_map(|k| parsed.vars.get(k).map(|v| (k.clone(), v.clone())))
        .collect();
    let cx = validate::Context {
        file,
        places,
        params_file: parsed.raw.params.as_ref().map(|p| p.get_ref().as_str()),
        set_values: &set_values,
    };
    let upstream = validate::validate(&cx, &stages).map_err(fail)?;
    let stages = graph::order(stages, &upstream).map_err(|d| fail(vec![d]))?;
    Ok(Dag {
        file: file.to_path_buf(),
        dir: places.dir.clone(),
        workdir: places.workdir.clone(),
        stages,
        params: parsed.params,
        result: result.into_iter().map(|(n, p, _)| (n, p)).collect(),
        sets: sets.to_vec(),
    })
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

#[cfg(test)]
mod tests;

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
mod tests {
    use super::*;

    fn try_parse(text: &str) -> Result<Dag> {
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
        assert_eq!(
            dag.stages[2].cmd(),
            "step --in runs/r1 --out runs/r2 --g 7.5"
        );
        assert_eq!(dag.stages[2].params, ["csd.guidance"]);
        assert_eq!(dag.stages[0].params, ["seed"]);
        assert_eq!(dag.stages[0].deps, ["in.txt"]);
        assert_eq!(dag.stages[0].outs, ["runs/r0"]);
        assert_eq!(dag.stages[3].upstream, [2]);
        assert_eq!(dag.downstream(1), [2, 3]);
        assert_eq!(dag.select(&["step@r2".into()]).unwrap(), [0, 1, 2]);
        assert!(dag.select(&["nope".into()]).is_err());
    }

    /// A range of zero instances (`to = from - 1`, e.g. zero chunks) expands to no
    /// stage, and a stage reading `r${rounds}` then reads the init's `r0`.
    #[test]
    fn a_range_of_zero_instances_is_no_stage() {
        let dag = try_parse(
            r#"
[vars]
rounds = 0
[stages.step]
foreach = { from = 1, to = "${rounds}", prefix = "r" }
cmd = "step --in runs/r${prev} --out runs/r${item}"
deps = ["runs/r${prev}"]
outs = ["runs/r${item}"]
[stages.init]
cmd = "init"
deps = ["./in.txt"]
outs = ["runs/r0/"]
[stages.last]
cmd = "last --in runs/r${rounds}"
deps = ["runs/r${rounds}"]
outs = ["runs/last"]
"#,
        )
        .unwrap();
        let names: Vec<_> = dag.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["init", "last"]);
        assert_eq!(dag.stages[1].upstream, [0]);
    }

    /// A params table passed whole (`${m.loop}`) is one argument, an inline TOML table,
    /// and the stage tracks the table: a `--set` of a key in it (even a new one, for the
    /// stage to check) changes that stage's command and tracked value and no other
    /// stage's; a new key elsewhere is refused.
    #[test]
    fn a_table_passed_whole_reruns_exactly_its_stages() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(
            d.path().join("params.toml"),
            "[m]\npreset = \"arf\"\n[m.start]\n[m.loop]\nviews = 4\n[m.finish]\n",
        )
        .unwrap();
        let text = r#"
params = "params.toml"
[stages.init]
cmd = "run --preset ${m.preset} --config ${m.start} --out o/c0"
outs = ["o/c0"]
[stages.chunk]
cmd = "run --resume o/c0 --preset ${m.preset} --config ${m.loop} --out o/c1"
deps = ["o/c0"]
outs = ["o/c1"]
[stages.final]
cmd = "run --resume o/c1 --preset ${m.preset} --config ${m.finish} --out o/f"
deps = ["o/c1"]
outs = ["o/f"]
"#;
        let places = Places {
            dir: d.path().to_path_buf(),
            workdir: d.path().to_path_buf(),
            cwd: absolute(Path::new(".")),
        };
        let load = |sets: &[&str]| {
            let sets: Vec<Set> = sets.iter().map(|s| s.parse().unwrap()).collect();
            parse_with(text, Path::new("dag.toml"), &places, &sets)
        };
        // What each stage's rerun depends on: its command and its tracked values.
        let seen = |dag: &Dag| -> Vec<(String, Vec<serde_json::Value>)> {
            dag.stages
                .iter()
                .map(|s| {
                    (
                        s.cmd(),
                        s.params.iter().map(|k| dag.params[k].clone()).collect(),
                    )
                })
                .collect()
        };
        let base = load(&[]).unwrap();
        assert_eq!(base.stages[1].argv[6], "{ views = 4 }");
        assert_eq!(base.stages[0].argv[4], "{}");
        assert_eq!(base.stages[1].params, ["m.loop", "m.preset"]);
        let changed = |sets: &[&str]| -> Vec<String> {
            let (a, b) = (seen(&base), seen(&load(sets).unwrap()));
            let dag = load(sets).unwrap();
            (0..a.len())
                .filter(|&i| a[i] != b[i])
                .map(|i| dag.stages[i].name.clone())
                .collect()
        };
        assert_eq!(changed(&["m.finish.finish=none"]), ["final"]);
        assert_eq!(changed(&["m.loop.csd.guidance=0"]), ["chunk"]);
        assert_eq!(changed(&["m.loop.views=2"]), ["chunk"]);
        assert_eq!(changed(&["m.start.start=colour"]), ["init"]);
        assert_eq!(changed(&["m.preset=paper"]), ["init", "chunk", "final"]);
        let dag = load(&["m.loop.csd.guidance=0", "m.loop.terms.gram=0.5"]).unwrap();
        assert_eq!(
            dag.stages[1].argv[6],
            "{ csd = { guidance = 0 }, terms = { gram = 0.5 }, views = 4 }"
        );
        let dag = load(&["m.finish.finish=colour"]).unwrap();
        assert_eq!(dag.stages[2].argv[6], r#"{ finish = "colour" }"#);
        // A new key in a table no stage takes whole is a mistake, as before.
        let e = load(&["m.nope=1"]).unwrap_err().to_string();
        assert!(e.contains("m.nope"), "{e}");
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
        assert_eq!(dag.stages[1].argv, ["echo", "${HOME}", "$$", "y"]);
    }

    #[test]
    fn foreach_matrix_is_every_combination() {
        let dag = try_parse(
            r#"
[stages.src]
foreach = ["bob", "fish"]
cmd = "src ${item}"
outs = ["runs/${item}/src"]
[stages.sty]
foreach = { matrix = { style = ["wave", "ink"], scene = ["bob", "fish"] } }
cmd = "sty --in runs/${item.scene}/src --style ${item.style} --out runs/${item.scene}/${item.style}"
deps = ["runs/${item.scene}/src"]
outs = ["runs/${item.scene}/${item.style}"]
"#,
        )
        .unwrap();
        let names: Vec<_> = dag.stages.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "src@bob",
                "src@fish",
                "sty@bob.wave",
                "sty@bob.ink",
                "sty@fish.wave",
                "sty@fish.ink"
            ]
        );
        let s = &dag.stages[dag.index("sty@fish.ink").unwrap()];
        assert_eq!(
            s.cmd(),
            "sty --in runs/fish/src --style ink --out runs/fish/ink"
        );
        assert_eq!(s.upstream, [1]);
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
            (
                "foreach = { matrix = { s = [] } }",
                "`s` is not a non-empty list",
            ),
            (
                "foreach = { matrix = { s = [\"a\"] }, x = 1 }",
                "unknown key `x`",
            ),
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

    /// Values are arguments: whatever a `[vars]` value, a params value or a `--set`
    /// holds, it is one argument of the command (or part of the one word it is written
    /// in), and the lock's command line quotes it so that a shell would read it back the
    /// same.
    #[test]
    fn values_are_single_arguments() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("p.toml"), "[x]\nname = \"a b\"\n").unwrap();
        let text = "params = \"p.toml\"\n[vars]\nprompt = \"\"\nscene = \"s.ply\"\n[stages.a]\n\
                    cmd = \"prog --prompt '${prompt}' --scene ${scene} --name=${x.name} --n x${x.name}y\"\n\
                    outs = [\"o\"]\n";
        let places = Places {
            dir: d.path().to_path_buf(),
            workdir: d.path().to_path_buf(),
            cwd: d.path().to_path_buf(),
        };
        let nasty = [
            "it's; touch pwned; echo '",
            "my captures/cat's $HOME `id` $(id) \"q\" ünïcødé.splat",
            "a\nb\tc\\d",
            "",
            "--flag",
            "*",
        ];
        for v in nasty {
            let sets = [
                Set {
                    name: "prompt".into(),
                    value: v.into(),
                },
                Set {
                    name: "scene".into(),
                    value: v.into(),
                },
                Set {
                    name: "x.name".into(),
                    value: v.into(),
                },
            ];
            let dag = parse_with(text, Path::new("dag.toml"), &places, &sets).unwrap();
            let s = &dag.stages[0];
            let want = [
                "prog".to_string(),
                "--prompt".into(),
                v.into(),
                "--scene".into(),
                v.into(),
                format!("--name={v}"),
                "--n".into(),
                format!("x{v}y"),
            ];
            assert_eq!(s.argv, want, "{v:?}");
            assert_eq!(shlex::split(&s.cmd()).unwrap(), want, "{v:?}");
            // The tracked params key is still tracked.
            assert_eq!(s.params, ["x.name"]);
        }
    }

    /// The sample DAG: the prompt reaches `distill` as one argument, and the scene path
    /// as one, whatever they hold.
    #[test]
    fn sample_dag_passes_prompt_and_scene_as_single_arguments() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data-sample/stylize.toml");
        let prompt = "it's; touch pwned; echo '";
        let scene = "/tmp/my captures/cat's `x` $y.splat";
        let dag = load_with(
            &file,
            &LoadOptions {
                workdir: None,
                sets: vec![
                    format!("prompt={prompt}").parse().unwrap(),
                    format!("scene={scene}").parse().unwrap(),
                ],
            },
        );
        // The scene does not exist: the DAG names it as a missing dep, which is the
        // only complaint.
        let e = dag.unwrap_err().to_string();
        assert!(
            e.contains("cat's `x` $y.splat") && !e.contains("cmd"),
            "{e}"
        );
        let dag = load_with(
            &file,
            &LoadOptions {
                workdir: None,
                // The default runs no loop: one chunk, so that a stage takes the prompt.
                sets: vec![
                    format!("prompt={prompt}").parse().unwrap(),
                    "distill.chunks=1".parse().unwrap(),
                ],
            },
        )
        .unwrap();
        let s = &dag.stages[dag.index("distill@c1").unwrap()];
        let i = s.argv.iter().position(|a| a == "--prompt").unwrap();
        assert_eq!(s.argv[i + 1], prompt);
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

//! `pipeline export --snakemake`: the same DAG as a Snakefile, so that Snakemake (and
//! its cluster and cloud executors) can run it. The stage binaries stay the unit of
//! work: one rule per expanded stage, whose shell command is the stage's arguments,
//! each shell-quoted ([`crate::dag::words::join`]), so that the shell Snakemake starts
//! hands the program exactly the arguments `pipeline run` gives it (a value with spaces,
//! quotes, `$` or backticks stays one argument and is never run as code), in the work
//! directory (`workdir:`) with the `pipeline` executable's directory first on PATH.
//!
//! Mapping (see the README, "Many scenes and styles: Snakemake"):
//! * inputs: the stage's path deps; a dep inside another stage's output directory is
//!   given as that directory (what Snakemake can match); value deps (`orbit:16`) are
//!   no files and go into `params`;
//! * outputs: artifact (and other) directories as `directory()`, declared files as
//!   files;
//! * `params`: the substituted command and the values of every tracked params key,
//!   so that Snakemake's `params` rerun trigger reruns what a changed value touches
//!   (each as a function returning the text: Snakemake reads braces in a params
//!   string as wildcards);
//! * `threads`: the command's `--threads N` (`0`, all cores: `workflow.cores`), else 1;
//! * before the command, the staging leftovers of a killed stage (`.NAME.partial-*`,
//!   `.NAME.old-*`, `.NAME.tmp-*`) are removed, as `pipeline run` does.
//!
//! Refused, with the reason: a stage without outputs (Snakemake runs a rule only to
//! make its outputs), a file path (dep or output) with a brace (Snakemake reads braces
//! in file names as wildcards, and doubling them does not escape them there), and a
//! stage whose output is not known to be a file or a directory (an output that does not exist yet and whose name does not say:
//! a name with an extension is taken as a file, one without as a directory).

use crate::dag::{Dag, Stage, inside, is_value_dep};
use crate::error::{Error, Result};
use std::collections::{BTreeMap, HashSet};
use std::fmt::Write;
use std::path::Path;

/// Python string literal (JSON's escapes are valid Python).
fn py(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// Snakemake formats shell commands with `{...}`: literal braces are doubled.
fn shell_escape_braces(s: &str) -> String {
    s.replace('{', "{{").replace('}', "}}")
}

/// A rule name (a Python identifier) for stage `name`, unique among `taken`.
fn rule_name(name: &str, taken: &mut HashSet<String>) -> String {
    let mut r: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if r.starts_with(|c: char| c.is_ascii_digit()) {
        r.insert(0, '_');
    }
    let base = r.clone();
    let mut k = 2;
    while !taken.insert(r.clone()) {
        r = format!("{base}_{k}");
        k += 1;
    }
    r
}

/// The threads a command asks for: `--threads N` / `--threads=N`.
fn threads(argv: &[String]) -> Option<usize> {
    for (i, w) in argv.iter().enumerate() {
        if w == "--threads" {
            return argv.get(i + 1).and_then(|n| n.parse().ok());
        }
        if let Some(n) = w.strip_prefix("--threads=") {
            return n.parse().ok();
        }
    }
    None
}

/// Whether output `o` is a directory: as it is on disk, else by its name (no
/// extension: a directory).
fn is_dir_output(dag: &Dag, o: &str) -> bool {
    let p = dag.path(o);
    if p.exists() {
        return p.is_dir();
    }
    Path::new(o).extension().is_none()
}

/// The Snakefile for `dag`. `bin_dir` is put first on PATH (the directory of the
/// `pipeline` executable, where the stage binaries are).
pub fn snakefile(dag: &Dag, bin_dir: &Path) -> Result<String> {
    check_exportable(dag)?;
    let mut taken = HashSet::from(["all".to_string()]);
    let names: Vec<String> = dag
        .stages
        .iter()
        .map(|s| rule_name(&s.name, &mut taken))
        .collect();
    let mut out = header(dag, bin_dir);
    for (i, s) in dag.stages.iter().enumerate() {
        rule(&mut out, dag, s, &names[i]);
    }
    Ok(out)
}

/// Refuse what Snakemake cannot run as the DAG does: a stage without outputs, a path
/// with a brace, an output that is neither a file nor a directory.
fn check_exportable(dag: &Dag) -> Result<()> {
    let mut problems = Vec::new();
    for s in &dag.stages {
        if s.outs.is_empty() {
            problems.push(format!(
                "stage `{}` (line {}) has no outputs: Snakemake runs a rule only to make its outputs; declare what it writes in `outs`",
                s.name, s.line
            ));
        }
        for f in s
            .outs
            .iter()
            .chain(s.deps.iter().filter(|d| !is_value_dep(d)))
        {
            if f.contains(['{', '}']) {
                problems.push(format!(
                    "path `{f}` of stage `{}` has a brace, which Snakemake reads as a wildcard \
                     in a file name (doubling does not escape it there); rename it, or use \
                     `pipeline run`",
                    s.name
                ));
            }
        }
        for o in &s.outs {
            let p = dag.path(o);
            if p.exists() && !p.is_dir() && !p.is_file() {
                problems.push(format!(
                    "output `{o}` of stage `{}` is neither a file nor a directory",
                    s.name
                ));
            }
        }
    }
    if problems.is_empty() {
        return Ok(());
    }
    Err(Error::Export(format!(
        "{}: cannot be exported to Snakemake:\n  {}",
        dag.file.display(),
        problems.join("\n  ")
    )))
}

/// The Snakefile's head: where it came from, the work directory, the PATH prefix, and
/// `rule all` (every output of every stage).
fn header(dag: &Dag, bin_dir: &Path) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# Generated by `pipeline export --snakemake` from {} -- do not edit; export again.",
        // Escaped: a name or value with a newline must not end the comment.
        py(&dag.file.to_string_lossy())
    );
    if !dag.sets.is_empty() {
        let sets: Vec<String> = dag
            .sets
            .iter()
            .map(|s| format!("--set {}", py(&s.to_string())))
            .collect();
        let _ = writeln!(out, "# Overrides: {}", sets.join(" "));
    }
    let _ = writeln!(
        out,
        "# Run: snakemake -s THIS_FILE --cores 2 (add --rerun-incomplete after a kill)."
    );
    let _ = writeln!(
        out,
        "# One rule per stage; commands run in the work directory.\n"
    );
    let _ = writeln!(out, "workdir: {}", py(&dag.workdir.to_string_lossy()));
    let path_prefix = format!(
        "export PATH={}:\"$PATH\"; ",
        sh_quote(&bin_dir.to_string_lossy())
    );
    let _ = writeln!(out, "shell.prefix({})\n", py(&path_prefix));
    let _ = writeln!(out, "rule all:\n    default_target: True\n    input:");
    for s in &dag.stages {
        for o in &s.outs {
            let _ = writeln!(out, "        {},", py(o));
        }
    }
    out.push('\n');
    out
}

/// Stage `s`'s rule `name`: inputs, outputs, tracked values, threads, log, shell.
fn rule(out: &mut String, dag: &Dag, s: &Stage, name: &str) {
    let _ = writeln!(out, "# stage {}", s.name);
    let _ = writeln!(out, "rule {name}:");
    let (inputs, values) = inputs(dag, s);
    if !inputs.is_empty() {
        let _ = writeln!(out, "    input:");
        for p in &inputs {
            let _ = writeln!(out, "        {},", py(p));
        }
    }
    let _ = writeln!(out, "    output:");
    for o in &s.outs {
        if is_dir_output(dag, o) {
            let _ = writeln!(out, "        directory({}),", py(o));
        } else {
            let _ = writeln!(out, "        {},", py(o));
        }
    }
    // As functions: Snakemake would read braces in a params string as wildcards.
    let _ = writeln!(out, "    params:");
    for (k, v) in &tracked_values(dag, s, &values) {
        let _ = writeln!(out, "        {k}=lambda wildcards: {},", py(v));
    }
    let _ = match threads(&s.argv) {
        Some(0) => writeln!(out, "    threads: workflow.cores"),
        Some(n) => writeln!(out, "    threads: {n}"),
        None => writeln!(out, "    threads: 1"),
    };
    let _ = writeln!(
        out,
        "    log: {}",
        py(&format!(".pipeline/snakemake-logs/{}.log", s.name))
    );
    // Snakemake formats the command: `{log:q}` is the rule's log; braces of the
    // stage's own text are doubled. Every argument is quoted for the shell.
    let cmd = format!(
        "{}( {} ) > {{log:q}} 2>&1",
        shell_escape_braces(&clean_staging(s)),
        shell_escape_braces(&s.cmd())
    );
    let _ = writeln!(out, "    shell:\n        {}\n", py(&cmd));
}

/// Stage `s`'s file inputs (a dep inside another stage's output is that output:
/// Snakemake matches inputs to outputs by path) and its value deps.
fn inputs(dag: &Dag, s: &Stage) -> (Vec<String>, Vec<String>) {
    let mut inputs: Vec<String> = Vec::new();
    let mut values: Vec<String> = Vec::new();
    for d in &s.deps {
        if is_value_dep(d) {
            values.push(d.clone());
            continue;
        }
        let producer_out = s
            .upstream
            .iter()
            .flat_map(|&u| dag.stages[u].outs.iter())
            .find(|o| *o == d || inside(d, o));
        let p = producer_out.cloned().unwrap_or_else(|| d.clone());
        if !inputs.contains(&p) {
            inputs.push(p);
        }
    }
    (inputs, values)
}

/// The values a rule tracks: the command, the params keys, the value deps.
fn tracked_values(dag: &Dag, s: &Stage, values: &[String]) -> BTreeMap<String, String> {
    let mut params: BTreeMap<String, String> = BTreeMap::new();
    params.insert("cmd".into(), s.cmd());
    for k in &s.params {
        let v = dag.params.get(k).cloned().unwrap_or_default();
        let key = format!(
            "p_{}",
            k.chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect::<String>()
        );
        params.insert(key, fantasystyle_schemas::manifest::canonical_json(&v));
    }
    for (k, v) in values.iter().enumerate() {
        params.insert(format!("value_{k}"), v.clone());
    }
    params
}

/// The shell that removes stage `s`'s staging leftovers before it runs.
fn clean_staging(s: &Stage) -> String {
    let mut pre = String::new();
    for o in &s.outs {
        let p = Path::new(o);
        let parent = p
            .parent()
            .map(|x| x.to_string_lossy().into_owned())
            .filter(|x| !x.is_empty())
            .unwrap_or_else(|| ".".into());
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        for t in ["partial", "old", "tmp"] {
            let _ = write!(
                pre,
                "rm -rf {}/.{}.{t}-*; ",
                sh_quote(&parent),
                sh_glob_quote(&name)
            );
        }
    }
    pre
}

/// Single-quote for sh.
fn sh_quote(s: &str) -> String {
    if !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "/._-+:@".contains(c))
    {
        return s.to_string();
    }
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// A name used in a glob: quoted except for the glob itself (names here are safe
/// characters or get quoted whole).
fn sh_glob_quote(s: &str) -> String {
    sh_quote(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_threads_and_escapes() {
        let mut t = HashSet::from(["all".to_string()]);
        assert_eq!(rule_name("csd-step@r1", &mut t), "csd_step_r1");
        assert_eq!(rule_name("csd-step.r1", &mut t), "csd_step_r1_2");
        assert_eq!(rule_name("all", &mut t), "all_2");
        assert_eq!(rule_name("3d", &mut t), "_3d");
        let v = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert_eq!(threads(&v(&["x", "--threads", "0", "--out", "y"])), Some(0));
        assert_eq!(threads(&v(&["x", "--threads=4"])), Some(4));
        assert_eq!(threads(&v(&["x"])), None);
        assert_eq!(shell_escape_braces("echo ${HOME}"), "echo ${{HOME}}");
        assert_eq!(py("a\"b\\c"), "\"a\\\"b\\\\c\"");
        assert_eq!(sh_quote("/a/b c"), "'/a/b c'");
    }
}

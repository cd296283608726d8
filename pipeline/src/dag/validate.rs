//! Phase 3 of loading a DAG: checks on the expanded stages, each problem with its
//! line: outputs must stay inside the work directory and off the DAG's own files (the
//! runner deletes outputs after a failure), no two stages may write one output (or one
//! inside the other), every dep must be another stage's output, an existing path or a
//! value (`orbit:16`), and every `[result]` entry must lie in some stage's output. The
//! producers found here are the graph's edges.

use super::expand::{Expanded, ResultEntry};
use super::locate::{Places, is_value_dep, lexical, relative};
use super::{Diag, inside, normalize};
use std::path::Path;

/// What validation needs to know besides the stages.
pub(super) struct Context<'a> {
    /// The DAG file (its name and lock name are protected).
    pub file: &'a Path,
    /// The directories: relative deps and outputs are looked up in the work directory.
    pub places: &'a Places,
    /// The params file as written in the DAG, if any.
    pub params_file: Option<&'a str>,
    /// `--set` values (as substituted) by the name they set, to explain missing deps.
    pub set_values: &'a [(String, String)],
}

/// Validate and return, per stage, the indices of the stages producing its deps.
pub(super) fn validate(cx: &Context, stages: &[Expanded]) -> Result<Vec<Vec<usize>>, Vec<Diag>> {
    let mut diags = Vec::new();
    check_output_locations(cx, stages, &mut diags);

    // Duplicate (or nested) outputs.
    let mut outs: Vec<(&str, usize, usize)> = Vec::new(); // (path, stage, line)
    for (i, e) in stages.iter().enumerate() {
        let s = &e.stage;
        for (o, &l) in s.outs.iter().zip(&e.out_lines) {
            for &(p, j, lj) in &outs {
                if p == o || inside(o, p) || inside(p, o) {
                    let how = if p == o { "also" } else { "overlappingly" };
                    diags.push(Diag {
                        line: Some(l),
                        msg: format!(
                            "output `{o}` of stage `{}` is {how} written by stage `{}` (`{p}`, line {lj})",
                            s.name, stages[j].stage.name
                        ),
                    });
                }
            }
            outs.push((o, i, l));
        }
    }

    // Producers.
    let mut upstream = vec![Vec::new(); stages.len()];
    for (i, e) in stages.iter().enumerate() {
        let s = &e.stage;
        for (d, &l) in s.deps.iter().zip(&e.dep_lines) {
            let producers: Vec<usize> = outs
                .iter()
                .filter(|(p, _, _)| *p == d || inside(d, p))
                .map(|&(_, j, _)| j)
                .collect();
            if producers.is_empty() {
                if !is_value_dep(d) && !lexical(&cx.places.workdir.join(d)).exists() {
                    let from_set = cx.set_values.iter().find(|(_, v)| normalize(v) == *d);
                    let msg = match from_set {
                        Some((name, v)) => format!(
                            "dep `{v}` of stage `{}` (from --set {name}={v}) does not exist (a relative --set path is taken from the current directory)",
                            s.name
                        ),
                        None => format!(
                            "dep `{d}` of stage `{}` does not exist and no stage produces it (missing producer)",
                            s.name
                        ),
                    };
                    diags.push(Diag { line: Some(l), msg });
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
    if diags.is_empty() {
        Ok(upstream)
    } else {
        Err(diags)
    }
}

/// Each `[result]` entry must lie in (or be) some stage's output.
pub(super) fn check_result(result: &[ResultEntry], stages: &[Expanded]) -> Vec<Diag> {
    result
        .iter()
        .filter(|(_, p, _)| {
            !stages
                .iter()
                .any(|e| e.stage.outs.iter().any(|o| o == p || inside(p, o)))
        })
        .map(|(name, p, line)| Diag {
            line: Some(*line),
            msg: format!("result `{name}` = `{p}` is not inside any stage's output"),
        })
        .collect()
}

/// Outputs the runner may delete after a failure must stay inside the work directory
/// and away from the DAG's own files.
fn check_output_locations(cx: &Context, stages: &[Expanded], diags: &mut Vec<Diag>) {
    let places = cx.places;
    // The DAG's own files as seen from the work directory.
    let seen = |name: &str| {
        if places.moved() {
            relative(&lexical(&places.dir.join(name)), &places.workdir)
        } else {
            normalize(name)
        }
    };
    let params_file = cx.params_file.map(seen);
    let dag_name = cx
        .file
        .file_name()
        .map(|n| seen(&n.to_string_lossy()))
        .unwrap_or_default();
    let where_ = if places.moved() {
        "the work directory (--workdir)"
    } else {
        "the DAG's directory"
    };
    let lock_name = format!(
        "{}.lock",
        cx.file
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    );
    for e in stages {
        let s = &e.stage;
        for (o, &l) in s.outs.iter().zip(&e.out_lines) {
            let own = |f: &str| o == f || inside(f, o);
            if o == "." || o == ".." || o.starts_with("../") || o.starts_with('/') {
                diags.push(Diag {
                    line: Some(l),
                    msg: format!(
                        "output `{o}` of stage `{}` must be a path inside {where_}",
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
}

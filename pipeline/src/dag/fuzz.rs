//! Property-based fuzzing of the DAG loader (issue 22), with `proptest`: structured
//! mutations of the repository's own DAG files and their params files (bytes inserted,
//! deleted, flipped, duplicated; lines dropped, doubled, swapped; words replaced by
//! interesting tokens: huge ranges, `${` fragments, quotes, shell syntax), and arbitrary
//! `--set` values. Loading must give a DAG or a `DagError`/usage error, never panic,
//! and a value must always be exactly one argument of the command. Case counts are
//! printed to stderr (past the test harness's capture).

use super::*;
use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use std::io::Write;

fn runner(name: &str, cases: u32) -> TestRunner {
    let cases = std::env::var("FANTASYSTYLE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(cases);
    let mut seed = [7u8; 32];
    seed[..name.len().min(32)].copy_from_slice(&name.as_bytes()[..name.len().min(32)]);
    TestRunner::new_with_rng(
        Config {
            cases,
            failure_persistence: None,
            max_shrink_iters: 400,
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &seed),
    )
}

fn report(name: &str, count: u32, started: std::time::Instant) {
    let _ = writeln!(
        std::io::stderr(),
        "fuzz {name}: {count} cases (incl. shrinking) in {:.1} s",
        started.elapsed().as_secs_f64()
    );
}

const TOKENS: &[&str] = &[
    "${",
    "}",
    "$${",
    "${item}",
    "${prev}",
    "${nope}",
    "${render.width}",
    "'",
    "\"",
    "\\",
    "&&",
    "|",
    ";",
    ">",
    "`",
    "$(",
    "#",
    "9223372036854775807",
    "-9223372036854775808",
    "4000000000",
    "-1",
    "0",
    "1e309",
    "nan",
    "[",
    "]",
    "{",
    "=",
    "[stages.x]",
    "foreach = { from = -9223372036854775808, to = 9223372036854775807 }",
    "foreach = { matrix = { a = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10], b = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10], c = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10], d = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10], e = [1, 2, 3, 4, 5] } }",
    "deps = [\"runs\"]",
    "outs = [\".\"]",
    "outs = [\"/\"]",
    "outs = [\"../x\"]",
    "\n",
    "é",
];

#[derive(Debug, Clone)]
enum Edit {
    Flip(Index, u8),
    Delete(Index, usize),
    Insert(Index, &'static str),
    Duplicate(Index, usize),
    DropLine(Index),
    DoubleLine(Index),
    SwapLines(Index, Index),
}

fn edit() -> impl Strategy<Value = Edit> {
    let tok = prop::sample::select(TOKENS);
    prop_oneof![
        2 => (any::<Index>(), 0u8..7).prop_map(|(i, b)| Edit::Flip(i, b)),
        2 => (any::<Index>(), 1usize..40).prop_map(|(i, n)| Edit::Delete(i, n)),
        4 => (any::<Index>(), tok).prop_map(|(i, t)| Edit::Insert(i, t)),
        1 => (any::<Index>(), 1usize..200).prop_map(|(i, n)| Edit::Duplicate(i, n)),
        1 => any::<Index>().prop_map(Edit::DropLine),
        1 => any::<Index>().prop_map(Edit::DoubleLine),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Edit::SwapLines(a, b)),
    ]
}

/// Apply edits to text, keeping it valid UTF-8 (bit flips stay inside ASCII).
fn apply(text: &str, edits: &[Edit]) -> String {
    let mut b: Vec<u8> = text.as_bytes().to_vec();
    for e in edits {
        let n = b.len().max(1);
        match e {
            Edit::Flip(i, bit) => {
                let k = i.index(n);
                if k < b.len() && b[k].is_ascii() {
                    b[k] ^= 1 << bit;
                }
            }
            Edit::Delete(i, len) => {
                let k = i.index(n).min(b.len());
                let end = (k + len).min(b.len());
                b.drain(k..end);
            }
            Edit::Insert(i, t) => {
                let k = i.index(b.len() + 1);
                b.splice(k..k, t.bytes());
            }
            Edit::Duplicate(i, len) => {
                let k = i.index(n).min(b.len());
                let end = (k + len).min(b.len());
                let span = b[k..end].to_vec();
                b.splice(end..end, span);
            }
            Edit::DropLine(i) | Edit::DoubleLine(i) | Edit::SwapLines(i, _) => {
                let text = String::from_utf8_lossy(&b).into_owned();
                let mut lines: Vec<&str> = text.split('\n').collect();
                let k = i.index(lines.len());
                match e {
                    Edit::DropLine(_) => {
                        lines.remove(k);
                    }
                    Edit::DoubleLine(_) => lines.insert(k, lines[k]),
                    Edit::SwapLines(_, j) => {
                        let j = j.index(lines.len());
                        lines.swap(k, j);
                    }
                    _ => {}
                }
                b = lines.join("\n").into_bytes();
            }
        }
    }
    String::from_utf8_lossy(&b).into_owned()
}

/// The repository's DAGs (with their params files), made self-contained in `dir`: the
/// model path points inside it and every literal dep exists.
fn seeds(dir: &Path) -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut out = Vec::new();
    for (dag, params) in [
        ("data-sample/stylize.toml", "data-sample/params.toml"),
        ("data-sample/baseline-gram.toml", "data-sample/params.toml"),
        ("data-sample/baseline-nnfm.toml", "data-sample/params.toml"),
        ("data-sample/baseline-refit.toml", "data-sample/params.toml"),
    ] {
        let Ok(text) = std::fs::read_to_string(root.join(dag)) else {
            continue;
        };
        let p = std::fs::read_to_string(root.join(params)).unwrap_or_default();
        out.push((text.replace("../", ""), p));
    }
    for f in ["scene.ply", "cameras.json", "style.png", "in.txt"] {
        std::fs::write(dir.join(f), "x").unwrap();
    }
    for d in [
        "vendor/models/stylizer",
        "vendor/models/lpips/vgg16",
        "priors/patch",
    ] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    out
}

/// Mutated DAG files and params files load to a DAG or to an error naming the DAG,
/// never a panic; every loaded stage has a program and only normalised outputs.
#[test]
fn fuzz_dag_files() {
    let d = tempfile::tempdir().unwrap();
    let seeds = seeds(d.path());
    assert!(seeds.len() >= 3, "the repository's DAG files");
    let places = Places {
        dir: d.path().to_path_buf(),
        workdir: d.path().to_path_buf(),
        cwd: d.path().to_path_buf(),
    };
    for (dag, params) in &seeds {
        std::fs::write(d.path().join("params.toml"), params).unwrap();
        parse_with(dag, Path::new("dag.toml"), &places, &[])
            .unwrap_or_else(|e| panic!("a seed DAG does not load: {e}"));
    }
    let strategy = (
        prop::sample::select(seeds),
        prop::collection::vec(edit(), 0..5),
        prop::collection::vec(edit(), 0..2),
    );
    let started = std::time::Instant::now();
    let count = std::cell::Cell::new(0);
    let r = runner("dag", 1500).run(&strategy, |((dag, params), e1, e2)| {
        count.set(count.get() + 1);
        let dag = apply(&dag, &e1);
        std::fs::write(d.path().join("params.toml"), apply(&params, &e2)).unwrap();
        match parse_with(&dag, Path::new("dag.toml"), &places, &[]) {
            Err(e) => {
                let m = e.to_string();
                if !m.contains("dag.toml") && !m.contains("params.toml") {
                    return Err(TestCaseError::fail(format!("error names no file: {m}")));
                }
            }
            Ok(dag) => {
                for s in &dag.stages {
                    if s.argv.is_empty() {
                        return Err(TestCaseError::fail(format!("{}: no program", s.name)));
                    }
                    if shlex::split(&s.cmd()).as_ref() != Some(&s.argv) {
                        return Err(TestCaseError::fail(format!("{}: cmd() != argv", s.name)));
                    }
                }
            }
        }
        Ok(())
    });
    report("dag", count.get(), started);
    r.unwrap();
}

/// Any `--set` value (any text, shell syntax, quotes, `${`, newlines, non-ASCII) is
/// exactly one argument, or exactly the part of the word it is written in; a params
/// key takes it only when it has the key's type; the command line quotes it back.
#[test]
fn fuzz_set_values_stay_single_arguments() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(
        d.path().join("p.toml"),
        "n = 3\nf = 0.5\nb = true\n[t]\ns = \"x\"\n",
    )
    .unwrap();
    let text = "params = \"p.toml\"\n[vars]\nv = \"\"\n[stages.a]\n\
                cmd = \"prog --v ${v} x${v}y --s=${t.s} ${n} ${f} ${b}\"\nouts = [\"o\"]\n";
    let places = Places {
        dir: d.path().to_path_buf(),
        workdir: d.path().to_path_buf(),
        cwd: d.path().to_path_buf(),
    };
    let value = prop_oneof![
        any::<String>(),
        "[ -~]{0,40}",
        prop::collection::vec(prop::sample::select(TOKENS), 0..6).prop_map(|t| t.concat()),
    ]
    .prop_filter("no NUL (not a command-line argument)", |s| {
        !s.contains('\0')
    });
    let key = prop::sample::select(vec!["v", "t.s", "n", "f", "b"]);
    let started = std::time::Instant::now();
    let count = std::cell::Cell::new(0);
    let r = runner("set", 3000).run(&(key, value), |(key, value)| {
        count.set(count.get() + 1);
        let set = Set {
            name: key.to_string(),
            value: value.clone(),
        };
        match parse_with(
            text,
            Path::new("dag.toml"),
            &places,
            std::slice::from_ref(&set),
        ) {
            Err(e) => {
                // Only a typed params key may refuse a value, and must say so.
                let m = e.to_string();
                if !["n", "f", "b"].contains(&key) || !m.contains("--set") {
                    return Err(TestCaseError::fail(format!("{key}={value:?}: {m}")));
                }
            }
            Ok(dag) => {
                let argv = &dag.stages[0].argv;
                // A value naming an existing path is rewritten for the work directory
                // (`locate`); any other value must arrive as it is.
                let is_path = !value.is_empty() && d.path().join(&value).exists();
                let (v, s) = match key {
                    "v" => (value.as_str(), "x"),
                    "t.s" => ("", value.as_str()),
                    _ => ("", "x"),
                };
                let want = [
                    "prog".to_string(),
                    "--v".into(),
                    v.into(),
                    format!("x{v}y"),
                    format!("--s={s}"),
                ];
                if (!is_path && argv[..5] != want) || argv.len() != 8 {
                    return Err(TestCaseError::fail(format!("{key}={value:?}: {argv:?}")));
                }
                if shlex::split(&dag.stages[0].cmd()).as_ref() != Some(argv) {
                    return Err(TestCaseError::fail(format!("{key}={value:?}: quoting")));
                }
            }
        }
        Ok(())
    });
    report("--set", count.get(), started);
    r.unwrap();
}

/// Regressions found by fuzzing: a range from i64::MIN (its `to - from` and the first
/// item's `prev` overflowed), and a matrix whose combinations multiply past any memory.
#[test]
fn extreme_foreach_ranges_and_matrices_are_errors_not_panics() {
    let d = tempfile::tempdir().unwrap();
    let p = |t: &str| parse(t, Path::new("dag.toml"), d.path());
    let e = p("[stages.a]\nforeach = { from = -9223372036854775808, to = 9223372036854775807 }\ncmd = \"a ${item}\"\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("too long"), "{e}");
    let dag = p("[stages.a]\nforeach = { from = -9223372036854775808, to = -9223372036854775808 }\ncmd = \"a ${item}\"\nouts = [\"o\"]\n")
        .unwrap();
    assert_eq!(dag.stages[0].argv[1], "-9223372036854775808");
    let axis = (1..=20)
        .map(|i| i.to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let m = format!(
        "[stages.a]\nforeach = {{ matrix = {{ a = [{axis}], b = [{axis}], c = [{axis}], d = [{axis}] }} }}\ncmd = \"a\"\nouts = [\"o/${{item}}\"]\n"
    );
    let e = p(&m).unwrap_err().to_string();
    assert!(e.contains("160000 combinations"), "{e}");
}

//! The DAG file's tests: parsing, `foreach`, `when`, substitution, validation.
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

/// `when` keeps a stage only where its condition holds: with zero rounds the loop's
/// stages are gone and the end reads the input; with two, the end resumes the last round
/// (the two `last` stages write the same output, one at a time); a bad condition is
/// named with its line.
#[test]
fn a_stage_exists_only_when_its_condition_holds() {
    let dag = |rounds: u32| {
        format!(
            r#"
[vars]
rounds = {rounds}
[stages.init]
when = "${{rounds}} > 0"
cmd = "init"
deps = ["./in.txt"]
outs = ["runs/r0"]
[stages.step]
foreach = {{ from = 1, to = "${{rounds}}", prefix = "r" }}
cmd = "step --in runs/r${{prev}} --out runs/r${{item}}"
deps = ["runs/r${{prev}}"]
outs = ["runs/r${{item}}"]
[stages.last]
when = "${{rounds}} == 0"
cmd = "last --scene in.txt"
deps = ["./in.txt"]
outs = ["runs/last"]
[stages.last-after-rounds]
when = "${{rounds}}"
cmd = "last --resume runs/r${{rounds}}"
deps = ["runs/r${{rounds}}"]
outs = ["runs/last"]
"#
        )
    };
    let names = |d: &Dag| d.stages.iter().map(|s| s.name.clone()).collect::<Vec<_>>();
    assert_eq!(names(&try_parse(&dag(0)).unwrap()), ["last"]);
    assert_eq!(
        names(&try_parse(&dag(2)).unwrap()),
        ["init", "step@r1", "step@r2", "last-after-rounds"]
    );
    let bad = err("[stages.a]\nwhen = \"x > 1\"\ncmd = \"a\"\nouts = [\"o\"]\n");
    assert!(
        bad.contains("dag.toml:2:") && bad.contains("compares numbers"),
        "{bad}"
    );
    let undefined = err("[stages.a]\nwhen = \"${nope}\"\ncmd = \"a\"\nouts = [\"o\"]\n");
    assert!(undefined.contains("nope"), "{undefined}");
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
        e.contains("dependency cycle:") && e.contains("a -> b -> a") || e.contains("b -> a -> b"),
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
    let e =
        err("[stages.a]\ncmd = \"a\"\nouts = [\"o\"]\n[stages.b]\ncmd = \"b\"\nouts = [\"./o\"]\n");
    assert_eq!(
        e,
        "dag.toml:6: output `o` of stage `b` is also written by stage `a` (`o`, line 3)"
    );
    let e =
        err("[stages.a]\ncmd = \"a\"\nouts = [\"o\"]\n[stages.b]\ncmd = \"b\"\nouts = [\"o/x\"]\n");
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
    let dag = try_parse("params = \"params.toml\"\n[stages.a]\ncmd = \"a\"\nparams = [\"csd\"]\n")
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

/// A dep that substitutes to nothing (an optional input left empty) is no dep; the
/// command still gets the empty argument, and a set value brings the dep back.
#[test]
fn a_dep_that_substitutes_to_nothing_is_no_dep() {
    let text = r#"
[vars]
model = ""
[stages.step]
cmd = "step --model ${model} --out runs/a"
deps = ["${model}", "./in.txt"]
outs = ["runs/a"]
"#;
    let dag = try_parse(text).unwrap();
    assert_eq!(dag.stages[0].deps, ["in.txt"]);
    assert_eq!(
        dag.stages[0].argv,
        ["step", "--model", "", "--out", "runs/a"]
    );
    let dag = try_parse(&text.replace("model = \"\"", "model = \"./in.txt\"")).unwrap();
    assert_eq!(dag.stages[0].deps, ["in.txt", "in.txt"]);
}

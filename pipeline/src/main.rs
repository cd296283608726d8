//! `pipeline`: run, explain and inspect a DAG of fantasystyle stages.
//! Exit codes: 0 ok, 1 a stage failed, 2 a DAG or usage error.
use clap::{Args, Parser, Subcommand};
use fantasystyle_pipeline::{Error, dag, inspect, run, show, tools};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// DAG runner for fantasystyle stages: resumes what failed, says what is stale and why,
/// and looks inside artifacts.
#[derive(Parser, Debug)]
#[command(version)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

/// Which DAG, where its outputs go, and overrides of its values.
#[derive(Args, Debug)]
struct DagArgs {
    /// The DAG file (TOML).
    #[arg(long)]
    dag: PathBuf,
    /// Work directory: commands run here and every output, the lock, logs and the pid
    /// file go here (default: the DAG's directory).
    #[arg(long, short = 'w')]
    workdir: Option<PathBuf>,
    /// Override a value of the DAG's vars table or of its params (dotted key): NAME=VALUE. A value that
    /// names an existing path is taken relative to the current directory. Repeatable.
    #[arg(long = "set", short = 's', value_name = "NAME=VALUE")]
    sets: Vec<String>,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run the stale stages of a DAG (and of TARGETS' upstream only, when given).
    Run {
        #[command(flatten)]
        dag: DagArgs,
        /// Stage names (`csd-step@r3`) or base names (`csd-step`, every round).
        targets: Vec<String>,
        /// Run the selected stages even when up to date.
        #[arg(long)]
        force: bool,
        /// Say what would run and why, run nothing.
        #[arg(long)]
        dry_run: bool,
        /// After a failure, keep running stages that do not depend on it.
        #[arg(long)]
        keep_going: bool,
        /// Stages run at once (independent stages only; 0 = one per core).
        #[arg(long, default_value_t = 1)]
        jobs: usize,
    },
    /// Say for each stage whether it is up to date, or stale and why.
    Status {
        #[command(flatten)]
        dag: DagArgs,
    },
    /// Print the graph: stages in run order, or Graphviz DOT with --dot.
    Dag {
        #[command(flatten)]
        dag: DagArgs,
        #[arg(long)]
        dot: bool,
    },
    /// Write the DAG as a Snakefile (one rule per stage, the same commands), to run it
    /// with Snakemake and its cluster or cloud executors.
    Export {
        #[command(flatten)]
        dag: DagArgs,
        /// Export for Snakemake (the one format so far).
        #[arg(long, required = true)]
        snakemake: bool,
        /// Where to write the Snakefile (written atomically).
        #[arg(long)]
        out: PathBuf,
    },
    /// Wall time per stage against the compute time stages reported.
    Report {
        #[command(flatten)]
        dag: DagArgs,
    },
    /// Show an artifact's manifest and tensor statistics (or a lone .npy's).
    Inspect {
        /// An artifact directory or a .npy file (relative to --workdir when given).
        path: PathBuf,
        /// The work directory a relative PATH is in (as given to `pipeline run`).
        #[arg(long, short = 'w')]
        workdir: Option<PathBuf>,
        /// Draw a tensor into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// How to draw latents (N, C, h, w).
        #[arg(long, value_enum, default_value_t = inspect::LatentMode::Grid)]
        mode: inspect::LatentMode,
        /// Which tensor to draw (default: latents, z_tgt, rgb, else the first).
        #[arg(long)]
        tensor: Option<String>,
    },
    /// Put plain files into a new artifact of the given kind (written atomically).
    Wrap {
        /// Artifact kind: views, latents, noised-latents, targets, scene, evaluation.
        #[arg(long)]
        kind: String,
        #[arg(long)]
        out: PathBuf,
        files: Vec<PathBuf>,
    },
    /// A slow deterministic fake stage for the runner's tests.
    #[command(hide = true)]
    TestStage {
        #[arg(long)]
        out: PathBuf,
        #[arg(long)]
        input: Vec<PathBuf>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        #[arg(long, default_value_t = 0.0)]
        value: f64,
        #[arg(long, default_value_t = 3)]
        steps: usize,
        #[arg(long, default_value_t = 0)]
        sleep_ms: u64,
        #[arg(long)]
        fail: bool,
    },
}

fn load(a: &DagArgs) -> Result<dag::Dag, ExitCode> {
    let sets = a
        .sets
        .iter()
        .map(|s| s.parse::<dag::Set>())
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| fail(2, e))?;
    let opts = dag::LoadOptions {
        workdir: a.workdir.clone(),
        sets,
    };
    dag::load_with(&a.dag, &opts).map_err(|e| match e {
        // DAG problems read `file:line: problem`.
        Error::Dag(d) => {
            eprintln!("{d}");
            ExitCode::from(2)
        }
        e => fail(2, e),
    })
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(2)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match real_main(cli) {
        Ok(c) | Err(c) => c,
    }
}

fn fail(code: u8, msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("pipeline: {msg}");
    ExitCode::from(code)
}

/// `pipeline export --snakemake`: the Snakefile at `out`.
fn export(d: &dag::Dag, out: &Path) -> Result<ExitCode, ExitCode> {
    let bin_dir = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(|p| p.to_path_buf()))
        .unwrap_or_else(|| PathBuf::from("."));
    let text = fantasystyle_pipeline::export::snakefile(d, &bin_dir).map_err(|e| fail(2, e))?;
    fantasystyle_schemas::atomic_write(out, text.as_bytes()).map_err(|e| fail(2, e))?;
    println!(
        "wrote {} ({} rules); run: snakemake -s {} --cores 2",
        out.display(),
        d.stages.len() + 1,
        out.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// `pipeline inspect`: the artifact's manifest and tensors, and one tensor drawn to
/// `png` if asked.
fn inspect_cmd(
    path: &Path,
    png: Option<&Path>,
    mode: inspect::LatentMode,
    tensor: Option<&str>,
) -> Result<ExitCode, ExitCode> {
    let (text, tensors) = inspect::inspect(path).map_err(|e| fail(2, e))?;
    print!("{text}");
    if let Some(out) = png {
        let p = inspect::pick(&tensors, tensor).map_err(|e| fail(2, e))?;
        let t = inspect::read_any(&p).map_err(|e| fail(2, e))?;
        let img = inspect::draw(&t, mode).map_err(|e| fail(2, format!("{}: {e}", p.display())))?;
        inspect::save_png(&img, out).map_err(|e| fail(2, e))?;
        println!(
            "wrote {} ({}x{}) from {}",
            out.display(),
            img.width(),
            img.height(),
            p.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// The hidden `test-stage` command (a stage for the runner's tests).
fn test_stage(a: tools::TestStage) -> ExitCode {
    match tools::test_stage(&a) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => fail(1, e),
    }
}

/// Print `shown`'s text (`status`, `report`), or fail with its error.
fn print_or_fail(shown: fantasystyle_pipeline::Result<String>) -> ExitCode {
    match shown {
        Ok(t) => {
            print!("{t}");
            ExitCode::SUCCESS
        }
        Err(e) => fail(2, e),
    }
}

fn real_main(cli: Cli) -> Result<ExitCode, ExitCode> {
    Ok(match cli.cmd {
        Cmd::Run {
            dag,
            targets,
            force,
            dry_run,
            keep_going,
            jobs,
        } => {
            let opts = run::RunOptions {
                targets,
                force,
                dry_run,
                keep_going,
                jobs,
            };
            match run::run(&load(&dag)?, &opts) {
                Err(e) => fail(2, e),
                Ok(s) if !s.failed.is_empty() => ExitCode::from(1),
                Ok(_) => ExitCode::SUCCESS,
            }
        }
        Cmd::Status { dag } => print_or_fail(show::status(&load(&dag)?)),
        Cmd::Dag { dag, dot } => {
            let d = load(&dag)?;
            print!("{}", if dot { show::dot(&d) } else { show::text(&d) });
            ExitCode::SUCCESS
        }
        Cmd::Export {
            dag,
            snakemake: _,
            out,
        } => export(&load(&dag)?, &out)?,
        Cmd::Report { dag } => print_or_fail(show::report(&load(&dag)?)),
        Cmd::Inspect {
            path,
            workdir,
            png,
            mode,
            tensor,
        } => {
            let path = match workdir {
                Some(w) if path.is_relative() => w.join(path),
                _ => path,
            };
            inspect_cmd(&path, png.as_deref(), mode, tensor.as_deref())?
        }
        Cmd::Wrap { kind, out, files } => match tools::wrap(&kind, &files, &out) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => fail(2, e),
        },
        Cmd::TestStage {
            out,
            input,
            seed,
            value,
            steps,
            sleep_ms,
            fail: f,
        } => test_stage(tools::TestStage {
            out,
            inputs: input,
            seed,
            value,
            steps,
            sleep_ms,
            fail: f,
        }),
    })
}

//! Running a DAG: stale stages in topological order, independent ones in parallel.
//!
//! Each stage runs its command's arguments directly, without a shell (values are
//! arguments, never shell code: [`crate::dag::words`]), in the work directory
//! (`--workdir`, default the DAG's directory), with the `pipeline` executable's own
//! directory first on PATH (so sibling stage binaries are found; the program is
//! resolved on that PATH, the same executable whose hash the lock records), its stdout
//! and stderr going to `.pipeline/logs/NAME.log` in the work directory. At the end of a
//! successful run the DAG's `[result]` paths are printed.
//!
//! Resume semantics (what makes an interrupted run safe to restart):
//! * A stage counts as done only when the lock records it `ok`, which the runner writes
//!   (atomically) only after the stage exited 0 and every declared output exists; the
//!   output hashes go into the lock at that moment.
//! * Stages write artifacts into a temporary sibling and rename it into place
//!   (`ArtifactWriter`), so an output path holds either the previous complete artifact
//!   or the new one. If a stage or the runner is killed, the next run removes the
//!   staging leftovers (`.NAME.partial-*`, `.NAME.old-*`, `.NAME.tmp-*`) before running
//!   the stage again.
//! * When a stage fails (non-zero exit, killed by a signal, or a declared output
//!   missing), the runner records it `failed`, removes the staging leftovers and removes
//!   every output that is not a complete artifact (plain files and directories without a
//!   valid manifest, which may be half-written); complete artifacts are kept (they were
//!   written atomically, by this or an earlier run) but are not trusted: the stage is
//!   stale until it succeeds. Stages downstream of a failure do not run.
//! * If the runner is killed, the lock still holds the state before the interrupted
//!   stage; that stage's recorded hashes no longer match (or it was never recorded), so
//!   it reruns. Outputs are compared by content, so a half-done stage is never mistaken
//!   for a done one.

use crate::dag::Dag;
use crate::error::{Error, Result};
use crate::lock::{Entry, Lock, RunRecord, Status, now_unix};
use crate::state::{Fingerprint, Hasher, Reason, reasons, stage_path_env};
use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Options of `pipeline run`.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    pub targets: Vec<String>,
    pub force: bool,
    pub dry_run: bool,
    pub keep_going: bool,
    pub jobs: usize,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    pub ran: Vec<String>,
    pub up_to_date: Vec<String>,
    pub failed: Vec<String>,
    /// Not run because an upstream stage failed (or the run stopped).
    pub blocked: Vec<String>,
}

/// For each selected stage (topological order), the reasons it is stale, with
/// [`Reason::Upstream`] added where an upstream stage is stale.
pub fn plan(
    dag: &Dag,
    selected: &[usize],
    lock: &Lock,
    hasher: &mut Hasher,
    force: bool,
) -> Vec<(usize, Vec<Reason>)> {
    let mut stale = vec![false; dag.stages.len()];
    let mut out = Vec::new();
    for &i in selected {
        let s = &dag.stages[i];
        let mut r = if force {
            vec![Reason::Forced]
        } else {
            let fp = hasher.fingerprint(dag, s);
            reasons(dag, s, &fp, lock.stages.get(&s.name))
        };
        let up: Vec<Reason> = s
            .upstream
            .iter()
            .filter(|&&u| stale[u])
            .map(|&u| Reason::Upstream(dag.stages[u].name.clone()))
            .collect();
        if !up.is_empty() {
            // Deps an upstream stage will (re)write are not worth listing.
            r.retain(|x| !matches!(x, Reason::MissingDep(_) | Reason::ChangedDep(_)));
            r.extend(up);
        }
        stale[i] = !r.is_empty();
        out.push((i, r));
    }
    out
}

/// Prevents two runners on one DAG: `.pipeline/run.pid`, taken over when its process
/// is gone (a killed runner).
struct RunGuard(PathBuf);
impl RunGuard {
    fn take(state: &Path) -> Result<RunGuard> {
        use std::io::ErrorKind;
        std::fs::create_dir_all(state).map_err(|e| Error::io(state, e))?;
        let p = state.join("run.pid");
        for _ in 0..3 {
            // create_new: of two runners starting at once, exactly one gets the file.
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&p)
            {
                Ok(mut f) => {
                    let _ = write!(f, "{}", std::process::id());
                    return Ok(RunGuard(p));
                }
                Err(e) if e.kind() == ErrorKind::AlreadyExists => {
                    let pid = std::fs::read_to_string(&p).unwrap_or_default();
                    let pid = pid.trim();
                    if !pid.is_empty() && Path::new("/proc").join(pid).exists() {
                        return Err(Error::Busy {
                            pid: pid.to_string(),
                            path: p,
                        });
                    }
                    // A killed runner's file: take it over.
                    let _ = std::fs::remove_file(&p);
                }
                Err(e) => return Err(Error::io(p, e)),
            }
        }
        Err(Error::io(
            p,
            std::io::Error::other("could not take the run lock"),
        ))
    }
}
impl Drop for RunGuard {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Remove staging leftovers of output `out` (see the module docs).
pub fn clean_staging(dag: &Dag, out: &str) {
    let p = dag.path(out);
    let (Some(parent), Some(name)) = (p.parent(), p.file_name()) else {
        return;
    };
    let name = name.to_string_lossy();
    let Ok(rd) = std::fs::read_dir(parent) else {
        return;
    };
    for e in rd.flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if ["partial", "old", "tmp"]
            .iter()
            .any(|t| n.starts_with(&format!(".{name}.{t}-")))
        {
            let q = e.path();
            let _ = if q.is_dir() {
                std::fs::remove_dir_all(&q)
            } else {
                std::fs::remove_file(&q)
            };
        }
    }
}

/// After a failure: remove leftovers and every output that is not a complete artifact.
fn clean_failed(dag: &Dag, outs: &[String]) {
    for o in outs {
        clean_staging(dag, o);
        let p = dag.path(o);
        if p.is_dir() {
            if fantasystyle_schemas::Artifact::open_any(&p).is_err() {
                let _ = std::fs::remove_dir_all(&p);
            }
        } else if p.exists() {
            let _ = std::fs::remove_file(&p);
        }
    }
}

struct Outcome {
    exit: Option<i32>,
    signal: Option<i32>,
    error: Option<String>,
    duration: f64,
}

#[derive(Clone, Copy, PartialEq)]
enum St {
    Pending,
    Running,
    Done,
    Failed,
    Blocked,
}

/// Run the DAG. Stage failures are reported in the summary; DAG-level problems are
/// errors.
pub fn run(dag: &Dag, opts: &RunOptions) -> Result<Summary> {
    let t0 = Instant::now();
    let selected = dag.select(&opts.targets)?;
    let lock = Lock::read(&dag.lock_path())?;
    if opts.dry_run {
        let mut hasher = Hasher::new(stage_path_env());
        return Ok(dry_run(dag, &selected, &lock, &mut hasher, opts.force));
    }
    std::fs::create_dir_all(&dag.workdir).map_err(|e| Error::io(&dag.workdir, e))?;
    let _guard = RunGuard::take(&dag.state_dir())?;
    let mut r = Runner::new(dag, opts, selected, lock)?;
    r.run()?;
    r.finish(t0)
}

/// `--dry-run`: what would run, and why.
fn dry_run(
    dag: &Dag,
    selected: &[usize],
    lock: &Lock,
    hasher: &mut Hasher,
    force: bool,
) -> Summary {
    let mut summary = Summary::default();
    for (i, r) in plan(dag, selected, lock, hasher, force) {
        let name = &dag.stages[i].name;
        if r.is_empty() {
            println!("up to date  {name}");
            summary.up_to_date.push(name.clone());
        } else {
            println!("would run   {name}: {}", join(&r));
            summary.ran.push(name.clone());
        }
    }
    if summary.ran.is_empty() {
        println!("nothing to run: all {} stages up to date", selected.len());
    }
    summary
}

/// A run in progress: each selected stage's state, the stages running, the lock.
struct Runner<'a> {
    dag: &'a Dag,
    opts: &'a RunOptions,
    selected: Vec<usize>,
    lock: Lock,
    hasher: Hasher,
    path_env: std::ffi::OsString,
    log_dir: PathBuf,
    jobs: usize,
    summary: Summary,
    st: Vec<St>,
    fps: Vec<Option<Fingerprint>>,
    spinners: Vec<Option<ProgressBar>>,
    mp: MultiProgress,
    overall: ProgressBar,
    tx: mpsc::Sender<(usize, Outcome)>,
    rx: mpsc::Receiver<(usize, Outcome)>,
    running: usize,
    stop: bool,
}

impl<'a> Runner<'a> {
    fn new(
        dag: &'a Dag,
        opts: &'a RunOptions,
        selected: Vec<usize>,
        mut lock: Lock,
    ) -> Result<Self> {
        // Forget stages that are no longer in the DAG (e.g. after lowering `rounds`).
        lock.stages.retain(|name, _| dag.index(name).is_some());
        let log_dir = dag.state_dir().join("logs");
        std::fs::create_dir_all(&log_dir).map_err(|e| Error::io(&log_dir, e))?;
        let mp = MultiProgress::with_draw_target(ProgressDrawTarget::stderr());
        let overall = mp.add(ProgressBar::new(selected.len() as u64));
        overall.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} stages {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        let jobs = match opts.jobs {
            0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
            j => j,
        };
        let n = dag.stages.len();
        let mut st = vec![St::Done; n];
        for &i in &selected {
            st[i] = St::Pending;
        }
        let path_env = stage_path_env();
        let (tx, rx) = mpsc::channel::<(usize, Outcome)>();
        Ok(Runner {
            dag,
            opts,
            selected,
            lock,
            hasher: Hasher::new(path_env.clone()),
            path_env,
            log_dir,
            jobs,
            summary: Summary::default(),
            st,
            fps: vec![None; n],
            spinners: vec![None; n],
            mp,
            overall,
            tx,
            rx,
            running: 0,
            stop: false,
        })
    }

    fn say(&self, m: String) {
        self.mp.suspend(|| println!("{m}"));
    }

    /// Launch what is ready, wait for a stage, record it; until nothing runs.
    fn run(&mut self) -> Result<()> {
        loop {
            self.block_below_failures();
            self.launch_ready();
            if self.running == 0 {
                return Ok(());
            }
            let (i, out) = match self.rx.recv_timeout(Duration::from_millis(250)) {
                Ok(x) => x,
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    self.show_log_lines();
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => return Ok(()),
            };
            self.running -= 1;
            self.record(i, out)?;
        }
    }

    /// Block the pending stages below a failure.
    fn block_below_failures(&mut self) {
        for &i in &self.selected {
            if self.st[i] == St::Pending
                && self.dag.stages[i]
                    .upstream
                    .iter()
                    .any(|&u| matches!(self.st[u], St::Failed | St::Blocked))
            {
                self.st[i] = St::Blocked;
                self.summary.blocked.push(self.dag.stages[i].name.clone());
                self.overall.inc(1);
            }
        }
    }

    /// Launch the pending stages whose upstream is done, up to `jobs` running (those up
    /// to date are marked done instead).
    fn launch_ready(&mut self) {
        while !self.stop && self.running < self.jobs {
            let (dag, st) = (self.dag, &self.st);
            let Some(i) = self.selected.iter().copied().find(|&i| {
                st[i] == St::Pending && dag.stages[i].upstream.iter().all(|&u| st[u] == St::Done)
            }) else {
                break;
            };
            let s = &dag.stages[i];
            let fp = self.hasher.fingerprint(dag, s);
            let mut r = reasons(dag, s, &fp, self.lock.stages.get(&s.name));
            if self.opts.force && r.is_empty() {
                r.push(Reason::Forced);
            }
            if r.is_empty() {
                if let Some(e) = self.lock.stages.get_mut(&s.name) {
                    refresh_stamps(dag, s, e);
                }
                self.st[i] = St::Done;
                self.summary.up_to_date.push(s.name.clone());
                self.say(format!("up to date  {}", s.name));
                self.overall.inc(1);
                continue;
            }
            self.launch(i, &r);
            self.fps[i] = Some(fp);
        }
    }

    /// Start stage `i` (stale for `r`) in the background, with a spinner.
    fn launch(&mut self, i: usize, r: &[Reason]) {
        let s = &self.dag.stages[i];
        for o in &s.outs {
            clean_staging(self.dag, o);
        }
        self.say(format!("running     {}: {}", s.name, join(r)));
        let sp = self.mp.add(ProgressBar::new_spinner());
        sp.set_style(
            ProgressStyle::with_template("  {spinner} {elapsed:>4} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        sp.set_message(s.name.clone());
        sp.enable_steady_tick(Duration::from_millis(120));
        self.spinners[i] = Some(sp);
        let log = self.log_dir.join(format!("{}.log", s.name));
        let timing = timing_file(self.dag, &s.name);
        let _ = std::fs::remove_file(&timing);
        let env = vec![
            ("PATH".into(), self.path_env.clone()),
            ("PIPELINE_STAGE".into(), s.name.clone().into()),
            (TIMING_ENV.into(), timing.into_os_string()),
        ];
        spawn_stage(
            i,
            s.name.clone(),
            s.argv.clone(),
            self.dag.workdir.clone(),
            env,
            log,
            self.tx.clone(),
        );
        self.st[i] = St::Running;
        self.running += 1;
    }

    /// Show each running stage's latest log line beside its spinner.
    fn show_log_lines(&self) {
        if self.mp.is_hidden() {
            return;
        }
        for (k, sp) in self.spinners.iter().enumerate() {
            if let Some(sp) = sp {
                let log = self
                    .log_dir
                    .join(format!("{}.log", self.dag.stages[k].name));
                let line = last_line(&log);
                sp.set_message(format!("{}  {line}", self.dag.stages[k].name));
            }
        }
    }

    /// Record the outcome of stage `i` in the lock (written at once) and the summary.
    fn record(&mut self, i: usize, out: Outcome) -> Result<()> {
        let dag = self.dag;
        let s = &dag.stages[i];
        let error = failure(dag, s, &out);
        let log_rel = format!(".pipeline/logs/{}.log", s.name);
        if let Some(e) = &error {
            append_log(
                &dag.workdir.join(&log_rel),
                &format!("pipeline: stage failed: {e}"),
            );
            clean_failed(dag, &s.outs);
        }
        let fp = self.fps[i].take().expect("fingerprint of a launched stage");
        let entry = lock_entry(dag, s, fp, &out, error.is_none(), &log_rel);
        self.lock.stages.insert(s.name.clone(), entry);
        self.lock.write(&dag.lock_path())?;
        if let Some(sp) = self.spinners[i].take() {
            sp.finish_and_clear();
        }
        self.overall.inc(1);
        if let Some(e) = error {
            self.st[i] = St::Failed;
            self.summary.failed.push(s.name.clone());
            self.say(format!(
                "FAILED      {} ({:.1}s): {e}; log: {}",
                s.name,
                out.duration,
                dag.workdir.join(&log_rel).display()
            ));
            if !self.opts.keep_going {
                self.stop = true;
            }
        } else {
            self.st[i] = St::Done;
            self.summary.ran.push(s.name.clone());
            self.say(format!("done        {} ({:.1}s)", s.name, out.duration));
        }
        Ok(())
    }

    /// The run's record in the lock, the summary line and the results.
    fn finish(mut self, t0: Instant) -> Result<Summary> {
        for &i in &self.selected {
            if self.st[i] == St::Pending {
                self.summary.blocked.push(self.dag.stages[i].name.clone());
            }
        }
        self.overall.finish_and_clear();
        let summary = self.summary;
        self.lock.last_run = Some(RunRecord {
            wall_s: t0.elapsed().as_secs_f64(),
            ran: summary.ran.clone(),
            jobs: self.jobs,
            finished_unix: now_unix(),
        });
        self.lock.write(&self.dag.lock_path())?;
        if summary.ran.is_empty() && summary.failed.is_empty() && summary.blocked.is_empty() {
            println!(
                "nothing to run: all {} stages up to date",
                self.selected.len()
            );
        } else {
            println!(
                "ran {}, up to date {}, failed {}, not run {} ({:.1}s)",
                summary.ran.len(),
                summary.up_to_date.len(),
                summary.failed.len(),
                summary.blocked.len(),
                t0.elapsed().as_secs_f64()
            );
        }
        if summary.failed.is_empty() && summary.blocked.is_empty() {
            print!("{}", result_lines(self.dag));
        }
        Ok(summary)
    }
}

/// Why stage `s` failed, if it did: its error, a non-zero exit or a signal, or a declared
/// output it did not write.
fn failure(dag: &Dag, s: &crate::dag::Stage, out: &Outcome) -> Option<String> {
    if out.error.is_some() {
        return out.error.clone();
    }
    if out.exit != Some(0) {
        return Some(match (out.exit, out.signal) {
            (Some(c), _) if c > 128 && c <= 128 + 64 => format!(
                "exited with status {c} (the command was killed by signal {})",
                c - 128
            ),
            (Some(c), _) => format!("exited with status {c}"),
            (None, Some(sig)) => format!("killed by signal {sig}"),
            (None, None) => "killed by a signal".to_string(),
        });
    }
    s.outs
        .iter()
        .find(|o| !dag.path(o).exists())
        .map(|o| format!("exited 0 but did not write its output {o}"))
}

/// The lock's entry for stage `s` after `out` (`ok`: it succeeded; then its outputs'
/// hashes, file stamps and timing are recorded).
fn lock_entry(
    dag: &Dag,
    s: &crate::dag::Stage,
    fp: Fingerprint,
    out: &Outcome,
    ok: bool,
    log_rel: &str,
) -> Entry {
    let outs: BTreeMap<String, String> = if ok {
        s.outs
            .iter()
            .map(|o| (o.clone(), crate::state::hash_or_missing(&dag.path(o))))
            .collect()
    } else {
        BTreeMap::new()
    };
    let files: BTreeMap<_, _> = if ok {
        s.outs
            .iter()
            .map(|o| (o.clone(), crate::state::stamp_files(&dag.path(o))))
            .filter(|(_, f)| !f.is_empty())
            .collect()
    } else {
        BTreeMap::new()
    };
    Entry {
        cmd: fp.cmd,
        binary: fp.binary,
        deps: fp.deps,
        params: fp.params,
        outs,
        status: if ok { Status::Ok } else { Status::Failed },
        duration_s: out.duration,
        exit_code: out.exit,
        finished_unix: now_unix(),
        log: log_rel.to_string(),
        timing: if ok {
            read_timing(&timing_file(dag, &s.name))
        } else {
            BTreeMap::new()
        },
        files,
    }
}

/// The DAG's `[result]` paths that exist, one `result  NAME  PATH` line each, with
/// paths as seen from the current directory.
pub fn result_lines(dag: &Dag) -> String {
    let cwd = crate::dag::absolute(Path::new("."));
    let mut out = String::new();
    for (name, p) in &dag.result {
        let full = dag.path(p);
        if full.exists() {
            let shown = crate::dag::relative(&crate::dag::lexical(&full), &cwd);
            out.push_str(&format!("result  {name:<8} {shown}\n"));
        }
    }
    out
}

/// For an up-to-date stage: bring the lock's file stamps of its artifact outputs up to
/// date, so that a file whose mtime moved but whose bytes did not is hashed once, not
/// at every check (as DVC refreshes its cache state). Files with a moved mtime were
/// just hashed and found equal to the manifest by `reasons`; outputs with no stamps at
/// all (a lock from before stamps existed) are verified by hashing every file first.
fn refresh_stamps(dag: &Dag, s: &crate::dag::Stage, e: &mut Entry) {
    for o in &s.outs {
        let p = dag.path(o);
        let now = crate::state::stamp_files(&p);
        if now.is_empty() {
            continue;
        }
        let ok = match e.files.get(o) {
            Some(old) => *old != now,
            None => fantasystyle_schemas::Artifact::open_any(&p).is_ok(),
        };
        if ok {
            e.files.insert(o.clone(), now);
        }
    }
}

/// Environment variable naming the file where a stage may report its timing.
pub const TIMING_ENV: &str = "PIPELINE_TIMING_FILE";

/// Where stage `name` reports its timing: `.pipeline/timing/NAME.json` (absolute).
pub fn timing_file(dag: &Dag, name: &str) -> PathBuf {
    let d = dag.state_dir().join("timing");
    let _ = std::fs::create_dir_all(&d);
    let d = std::fs::canonicalize(&d).unwrap_or(d);
    d.join(format!("{name}.json"))
}

/// Read a timing report: a JSON object of numbers (non-numbers are ignored).
pub fn read_timing(p: &Path) -> BTreeMap<String, f64> {
    let Ok(t) = std::fs::read_to_string(p) else {
        return BTreeMap::new();
    };
    let Ok(serde_json::Value::Object(m)) = serde_json::from_str::<serde_json::Value>(&t) else {
        return BTreeMap::new();
    };
    m.into_iter()
        .filter_map(|(k, v)| v.as_f64().filter(|x| x.is_finite()).map(|x| (k, x)))
        .collect()
}

fn join(r: &[Reason]) -> String {
    r.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The last non-empty line of a log (from its last 512 bytes), shortened.
fn last_line(p: &Path) -> String {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = std::fs::File::open(p) else {
        return String::new();
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let _ = f.seek(SeekFrom::Start(len.saturating_sub(512)));
    let mut buf = Vec::new();
    let _ = f.read_to_end(&mut buf);
    let text = String::from_utf8_lossy(&buf);
    let line = text
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("");
    line.chars().take(80).collect()
}

fn append_log(p: &Path, line: &str) {
    if let Ok(mut f) = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(p)
    {
        let _ = writeln!(f, "{line}");
    }
}

fn spawn_stage(
    i: usize,
    name: String,
    argv: Vec<String>,
    dir: PathBuf,
    env: Vec<(String, std::ffi::OsString)>,
    log: PathBuf,
    tx: mpsc::Sender<(usize, Outcome)>,
) {
    std::thread::spawn(move || {
        let t = Instant::now();
        let res = (|| -> Result<std::process::ExitStatus> {
            let mut f = std::fs::File::create(&log).map_err(|e| Error::io(&log, e))?;
            writeln!(
                f,
                "# stage {name}\n# cmd: {}\n# cwd: {}",
                crate::dag::words::join(&argv),
                dir.display()
            )
            .map_err(|e| Error::io(&log, e))?;
            let program = argv.first().map_or("", String::as_str);
            let path_env = env
                .iter()
                .find(|(k, _)| k == "PATH")
                .map(|(_, v)| v.clone())
                .unwrap_or_default();
            let Some(exe) = crate::state::resolve(&dir, program, &path_env) else {
                let why = format!(
                    "program `{program}` not found{}",
                    if program.contains('/') {
                        format!(" (looked for {})", dir.join(program).display())
                    } else {
                        " on PATH (the pipeline executable's directory, then $PATH)".into()
                    }
                );
                let _ = writeln!(f, "pipeline: {why}");
                return Err(Error::Usage(why));
            };
            let err = f.try_clone().map_err(|e| Error::io(&log, e))?;
            // No shell: the program and its arguments exactly as substituted.
            let status = Command::new(&exe)
                .args(&argv[1..])
                .current_dir(&dir)
                .envs(env)
                .stdin(Stdio::null())
                .stdout(f)
                .stderr(err)
                .status()
                .map_err(|e| Error::io(&exe, e))?;
            Ok(status)
        })();
        let duration = t.elapsed().as_secs_f64();
        let out = match res {
            Ok(st) => Outcome {
                exit: st.code(),
                signal: std::os::unix::process::ExitStatusExt::signal(&st),
                error: None,
                duration,
            },
            Err(e) => Outcome {
                exit: None,
                signal: None,
                error: Some(e.to_string()),
                duration,
            },
        };
        let _ = tx.send((i, out));
    });
}

//! Property-based fuzzing of every file parser (issue 22), with `proptest` on stable
//! Rust: thousands of structured mutations of valid files -- truncations, bit flips,
//! inserted and deleted spans, duplicated spans, interesting numbers written over
//! counts and sizes (4e9, 2^64 - 1, -1), NaN and infinities in binary fields, header
//! lines dropped, doubled or rewritten, JSON fields removed, duplicated, retyped or set
//! to absurd numbers -- through the PLY (binary and ASCII), `.splat`, `cameras.json`,
//! `transforms.json`, COLMAP (text and binary), `.npy` (whole and streamed), artifact
//! manifest and `model.json` readers. (The DAG TOML and `--set` values are fuzzed in
//! `pipeline/src/dag/fuzz.rs`.)
//!
//! This module is the machinery (the guard, the runner, the mutations); the targets are
//! in `fuzz_scenes` (PLY, `.splat`), `fuzz_cameras` (`cameras.json`, `transforms.json`,
//! COLMAP) and `fuzz_npy_manifests` (`.npy`, artifact manifest, `model.json`).
//!
//! Every case must: return a value or an error that names the file (never panic); make
//! no single allocation larger than 16 MiB + 64 bytes per input byte (a header claiming
//! 4e9 vertices must not reserve them: a tracking global allocator measures it); and
//! finish within 10 s (a case that loops fails by timeout). A returned scene or camera
//! set is valid (finite, normalised). The number of cases and the time of each target
//! are printed (to stderr, past the test harness's capture). `FANTASYSTYLE_FUZZ_CASES=N`
//! runs N cases per target, `FANTASYSTYLE_FUZZ_SEED=S` another deterministic stream.

use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};
use std::io::Write;
use std::time::{Duration, Instant};

/// A global allocator that forwards to the system one and records, on threads that
/// ask for it, the largest single request.
mod alloc {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        static TRACKING: Cell<bool> = const { Cell::new(false) };
        static PEAK: Cell<usize> = const { Cell::new(0) };
    }

    fn note(size: usize) {
        let _ = TRACKING.try_with(|t| {
            if t.get() {
                let _ = PEAK.try_with(|p| p.set(p.get().max(size)));
            }
        });
    }

    pub struct Tracking;

    // The repository's one unsafe block: implementing `GlobalAlloc` is unsafe by
    // definition; every call is forwarded unchanged to `System`.
    #[allow(unsafe_code)]
    unsafe impl GlobalAlloc for Tracking {
        unsafe fn alloc(&self, l: Layout) -> *mut u8 {
            note(l.size());
            unsafe { System.alloc(l) }
        }
        unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
            note(l.size());
            unsafe { System.alloc_zeroed(l) }
        }
        unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
            unsafe { System.dealloc(p, l) }
        }
        unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
            note(new);
            unsafe { System.realloc(p, l, new) }
        }
    }

    #[global_allocator]
    static GLOBAL: Tracking = Tracking;

    /// Run `f` on this thread, returning its value and the largest single allocation
    /// it asked for.
    pub fn track<R>(f: impl FnOnce() -> R) -> (R, usize) {
        PEAK.with(|p| p.set(0));
        TRACKING.with(|t| t.set(true));
        let r = f();
        TRACKING.with(|t| t.set(false));
        (r, PEAK.with(|p| p.get()))
    }
}

const TIMEOUT: Duration = Duration::from_secs(10);

fn allowed(input_len: usize) -> usize {
    (16 << 20) + 64 * input_len
}

/// Run `f` (a parser call on `input_len` bytes) on its own thread: a panic, a timeout
/// or an allocation over [`allowed`] is an error naming what happened.
pub(crate) fn guarded<R: Send + 'static>(
    input_len: usize,
    f: impl FnOnce() -> R + Send + 'static,
) -> Result<R, String> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| alloc::track(f)));
        let _ = tx.send(r);
    });
    match rx.recv_timeout(TIMEOUT) {
        Err(_) => Err(format!("no answer within {TIMEOUT:?} (a loop?)")),
        Ok(Err(p)) => Err(format!(
            "panicked: {}",
            p.downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default()
        )),
        Ok(Ok((_, peak))) if peak > allowed(input_len) => Err(format!(
            "one allocation of {peak} bytes for {input_len} bytes of input (bound {})",
            allowed(input_len)
        )),
        Ok(Ok((r, _))) => Ok(r),
    }
}

/// The guard itself can fail: a large allocation, a panic and a loop are caught.
#[test]
fn guard_sees_allocations_panics_and_loops() {
    let e = guarded(10, || vec![1u8; 40 << 20].len()).unwrap_err();
    assert!(e.contains("one allocation of 41943040 bytes"), "{e}");
    assert_eq!(
        guarded(1 << 20, || vec![1u8; 40 << 20].len()).unwrap(),
        40 << 20
    );
    let e = guarded(10, || -> usize { panic!("boom") }).unwrap_err();
    assert!(e.contains("panicked: boom"), "{e}");
    let started = Instant::now();
    let e = guarded(10, || std::thread::sleep(TIMEOUT + Duration::from_secs(1))).unwrap_err();
    assert!(e.contains("no answer") && started.elapsed() < TIMEOUT + Duration::from_secs(1));
}

fn cases(default: u32) -> u32 {
    std::env::var("FANTASYSTYLE_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Run `cases` cases of `strategy` through `check`; print the count and the time.
pub(crate) fn fuzz<S: Strategy>(
    name: &str,
    n: u32,
    strategy: S,
    check: impl Fn(S::Value) -> Result<(), String>,
) {
    let seed: u64 = std::env::var("FANTASYSTYLE_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(22);
    let mut bytes = [0u8; 32];
    bytes[..8].copy_from_slice(&seed.to_le_bytes());
    bytes[8..8 + name.len().min(24)].copy_from_slice(&name.as_bytes()[..name.len().min(24)]);
    let n = cases(n);
    let mut runner = TestRunner::new_with_rng(
        Config {
            cases: n,
            failure_persistence: None,
            max_shrink_iters: 400,
            ..Config::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &bytes),
    );
    let started = Instant::now();
    ACCEPTED.with(|a| a.set(0));
    let count = std::cell::Cell::new(0u32);
    let result = runner.run(&strategy, |v| {
        count.set(count.get() + 1);
        check(v).map_err(TestCaseError::fail)
    });
    let count = count.get();
    let _ = writeln!(
        std::io::stderr(),
        "fuzz {name}: {count} cases (of {n} planned, incl. shrinking) in {:.1} s; {} parser \
         calls returned a value, the rest a clear error",
        started.elapsed().as_secs_f64(),
        ACCEPTED.with(|a| a.get())
    );
    if let Err(e) = result {
        panic!("fuzz {name}: {e}");
    }
}

// ---------------------------------------------------------------------------------
// Mutations.

/// Byte strings a parser should meet at any position: numbers a count could claim,
/// non-finite and extreme floats (text and little-endian), structure characters.
const DICT: &[&[u8]] = &[
    b"0",
    b"-1",
    b"4000000000",
    b"4294967296",
    b"18446744073709551615",
    b"9223372036854775807",
    b"1e309",
    b"-1e309",
    b"nan",
    b"NaN",
    b"inf",
    b"-inf",
    b"1e-320",
    b"null",
    b"true",
    b"\"\"",
    b"[]",
    b"{}",
    b"[[[[[[[[",
    b"\n",
    b" ",
    b"\t",
    b"\r\n",
    b"\0",
    b"\xff\xfe",
    b",",
    b":",
    b"'",
    b"(",
    b")",
    &[0, 0, 0xc0, 0x7f],
    &[0, 0, 0x80, 0x7f],
    &[0, 0, 0x80, 0xff],
    &[0xff, 0xff, 0x7f, 0x7f],
    &[0, 0, 0, 0],
    &[0xff, 0xff, 0xff, 0xff],
    &[0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff],
    &[0, 0x28, 0x6b, 0xee, 0, 0, 0, 0],
    &[0, 0, 0, 0, 0, 0, 0xf8, 0x7f],
    &[0, 0, 0, 0, 0, 0, 0xf0, 0x7f],
];

/// Numbers a count, a size, a shape entry or an id could claim.
const NUMBERS: &[&[u8]] = &[
    b"0",
    b"1",
    b"-1",
    b"255",
    b"65536",
    b"4000000000",
    b"4294967295",
    b"4294967296",
    b"1152921504606846976",
    b"4611686018427387904",
    b"9223372036854775807",
    b"18446744073709551615",
    b"18446744073709551616",
    b"1e309",
    b"nan",
    b"-0",
    b"1.5",
];

#[derive(Debug, Clone)]
pub(crate) enum Edit {
    /// Replace the k-th run of ASCII digits (a count, a size, a shape entry) by a number.
    Number(Index, &'static [u8]),
    Truncate(Index),
    Flip(Index, u8),
    Set(Index, u8),
    Insert(Index, Vec<u8>),
    Delete(Index, usize),
    Duplicate(Index, usize),
    Overwrite(Index, Vec<u8>),
}

fn token() -> impl Strategy<Value = Vec<u8>> {
    prop_oneof![
        3 => prop::sample::select(DICT).prop_map(|t| t.to_vec()),
        1 => prop::collection::vec(any::<u8>(), 1..12),
    ]
}

pub(crate) fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        4 => (any::<Index>(), prop::sample::select(NUMBERS)).prop_map(|(i, n)| Edit::Number(i, n)),
        1 => any::<Index>().prop_map(Edit::Truncate),
        3 => (any::<Index>(), 0u8..8).prop_map(|(i, b)| Edit::Flip(i, b)),
        2 => (any::<Index>(), any::<u8>()).prop_map(|(i, b)| Edit::Set(i, b)),
        2 => (any::<Index>(), token()).prop_map(|(i, t)| Edit::Insert(i, t)),
        2 => (any::<Index>(), 1usize..64).prop_map(|(i, n)| Edit::Delete(i, n)),
        1 => (any::<Index>(), 1usize..256).prop_map(|(i, n)| Edit::Duplicate(i, n)),
        4 => (any::<Index>(), token()).prop_map(|(i, t)| Edit::Overwrite(i, t)),
    ]
}

pub(crate) fn apply(b: &mut Vec<u8>, edits: &[Edit]) {
    for e in edits {
        if b.is_empty() {
            if let Edit::Insert(_, t) = e {
                b.extend_from_slice(t);
            }
            continue;
        }
        match e {
            Edit::Number(i, n) => {
                let runs = digit_runs(b);
                if !runs.is_empty() {
                    let (start, end) = runs[i.index(runs.len())];
                    b.splice(start..end, n.iter().copied());
                }
            }
            Edit::Truncate(i) => b.truncate(i.index(b.len())),
            Edit::Flip(i, bit) => {
                let k = i.index(b.len());
                b[k] ^= 1 << bit;
            }
            Edit::Set(i, v) => {
                let k = i.index(b.len());
                b[k] = *v;
            }
            Edit::Insert(i, t) => {
                let k = i.index(b.len() + 1);
                b.splice(k..k, t.iter().copied());
            }
            Edit::Delete(i, n) => {
                let k = i.index(b.len());
                let end = (k + n).min(b.len());
                b.drain(k..end);
            }
            Edit::Duplicate(i, n) => {
                let k = i.index(b.len());
                let end = (k + n).min(b.len());
                let span = b[k..end].to_vec();
                b.splice(end..end, span);
            }
            Edit::Overwrite(i, t) => {
                let k = i.index(b.len());
                for (j, v) in t.iter().enumerate() {
                    if k + j < b.len() {
                        b[k + j] = *v;
                    }
                }
            }
        }
    }
}

/// (start, end) of each run of ASCII digits in the first 64 KiB (where the text of a
/// header is).
fn digit_runs(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in b.iter().take(1 << 16).enumerate() {
        match (c.is_ascii_digit(), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((s, i));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, b.len().min(1 << 16)));
    }
    out
}

/// Edits of a text's lines: drop, double, swap, or replace one whitespace-separated
/// word by an interesting token.
#[derive(Debug, Clone)]
pub(crate) enum LineEdit {
    Drop(Index),
    Double(Index),
    Swap(Index, Index),
    Word(Index, Index, Vec<u8>),
}

pub(crate) fn line_edit() -> impl Strategy<Value = LineEdit> {
    prop_oneof![
        1 => any::<Index>().prop_map(LineEdit::Drop),
        1 => any::<Index>().prop_map(LineEdit::Double),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| LineEdit::Swap(a, b)),
        4 => (any::<Index>(), any::<Index>(), token()).prop_map(|(l, w, t)| LineEdit::Word(l, w, t)),
    ]
}

/// Apply line edits to the first `head` lines of `b` (all lines when `head` is None).
pub(crate) fn apply_lines(b: &mut Vec<u8>, edits: &[LineEdit], head: Option<usize>) {
    let text_end = match head {
        Some(k) => b
            .iter()
            .enumerate()
            .filter(|(_, c)| **c == b'\n')
            .nth(k.saturating_sub(1))
            .map(|(i, _)| i + 1)
            .unwrap_or(b.len()),
        None => b.len(),
    };
    let tail = b.split_off(text_end);
    let mut lines: Vec<Vec<u8>> = b.split(|c| *c == b'\n').map(|l| l.to_vec()).collect();
    for e in edits {
        if lines.is_empty() {
            break;
        }
        match e {
            LineEdit::Drop(i) => {
                lines.remove(i.index(lines.len()));
            }
            LineEdit::Double(i) => {
                let k = i.index(lines.len());
                let l = lines[k].clone();
                lines.insert(k, l);
            }
            LineEdit::Swap(a, c) => {
                let (x, y) = (a.index(lines.len()), c.index(lines.len()));
                lines.swap(x, y);
            }
            LineEdit::Word(l, w, t) => {
                let k = l.index(lines.len());
                let words: Vec<&[u8]> = lines[k].split(|c| *c == b' ').collect();
                let j = w.index(words.len());
                let mut out = Vec::new();
                for (m, word) in words.iter().enumerate() {
                    if m > 0 {
                        out.push(b' ');
                    }
                    out.extend_from_slice(if m == j { t } else { word });
                }
                lines[k] = out;
            }
        }
    }
    *b = lines.join(&b'\n');
    b.extend(tail);
}

/// JSON edits on the n-th node (pre-order) of a value.
#[derive(Debug, Clone)]
enum JsonEdit {
    Remove(Index),
    Retype(Index, u8),
    Number(Index, f64),
    Duplicate(Index),
    Nest(Index),
}

fn json_edit() -> impl Strategy<Value = JsonEdit> {
    let numbers = prop::sample::select(vec![
        0.0,
        -1.0,
        0.5,
        -0.0,
        4e9,
        1.8446744073709552e19,
        1e308,
        -1e308,
        5e-324,
        9007199254740993.0,
        1e15,
        3.0,
    ]);
    prop_oneof![
        2 => any::<Index>().prop_map(JsonEdit::Remove),
        2 => (any::<Index>(), 0u8..6).prop_map(|(i, k)| JsonEdit::Retype(i, k)),
        3 => (any::<Index>(), numbers).prop_map(|(i, x)| JsonEdit::Number(i, x)),
        1 => any::<Index>().prop_map(JsonEdit::Duplicate),
        1 => any::<Index>().prop_map(JsonEdit::Nest),
    ]
}

fn count_nodes(v: &serde_json::Value) -> usize {
    1 + match v {
        serde_json::Value::Array(a) => a.iter().map(count_nodes).sum(),
        serde_json::Value::Object(o) => o.values().map(count_nodes).sum(),
        _ => 0,
    }
}

/// Apply `f` to node `target` (pre-order) of `v`; containers may remove or duplicate
/// their children.
fn edit_node(v: &mut serde_json::Value, target: usize, e: &JsonEdit) {
    use serde_json::Value;
    fn walk(v: &mut Value, target: usize, at: &mut usize, e: &JsonEdit) -> bool {
        let me = *at;
        *at += 1;
        if me == target {
            match e {
                JsonEdit::Retype(_, k) => {
                    *v = match k {
                        0 => Value::Null,
                        1 => Value::Bool(true),
                        2 => Value::String("x".into()),
                        3 => Value::Array(vec![]),
                        4 => Value::Object(Default::default()),
                        _ => serde_json::json!(-7),
                    }
                }
                JsonEdit::Number(_, x) => {
                    *v = serde_json::Number::from_f64(*x).map_or(Value::Null, Value::Number)
                }
                JsonEdit::Nest(_) => *v = Value::Array(vec![v.take()]),
                _ => return true, // removal and duplication: the parent does them
            }
            return false;
        }
        let mut act: Option<(usize, bool)> = None;
        match v {
            Value::Array(a) => {
                for (i, c) in a.iter_mut().enumerate() {
                    if walk(c, target, at, e) {
                        act = Some((i, matches!(e, JsonEdit::Duplicate(_))));
                    }
                }
                if let Some((i, dup)) = act {
                    if dup {
                        let c = a[i].clone();
                        a.insert(i, c);
                    } else {
                        a.remove(i);
                    }
                }
            }
            Value::Object(o) => {
                let keys: Vec<String> = o.keys().cloned().collect();
                for k in keys {
                    if walk(o.get_mut(&k).unwrap(), target, at, e) {
                        if matches!(e, JsonEdit::Duplicate(_)) {
                            let c = o[&k].clone();
                            o.insert(format!("{k}_"), c);
                        } else {
                            o.remove(&k);
                        }
                    }
                }
            }
            _ => {}
        }
        false
    }
    let mut at = 0;
    if walk(v, target, &mut at, e) {
        *v = serde_json::Value::Null;
    }
}

/// Mutated JSON text: tree edits, then (sometimes) byte edits, and duplicated keys
/// spliced in as text (serde_json's maps cannot hold them).
pub(crate) fn json_case(seeds: Vec<serde_json::Value>) -> impl Strategy<Value = (Vec<u8>, String)> {
    (
        prop::sample::select(seeds),
        prop::collection::vec(json_edit(), 0..4),
        prop::collection::vec(edit(), 0..3),
        any::<bool>(),
    )
        .prop_map(|(mut v, jedits, edits, dup_key)| {
            for e in &jedits {
                let i = match e {
                    JsonEdit::Remove(i)
                    | JsonEdit::Retype(i, _)
                    | JsonEdit::Number(i, _)
                    | JsonEdit::Duplicate(i)
                    | JsonEdit::Nest(i) => i,
                };
                let n = count_nodes(&v);
                edit_node(&mut v, i.index(n), e);
            }
            let mut text = serde_json::to_string_pretty(&v).unwrap();
            if dup_key && let Some(k) = text.find("\"fx\"").or_else(|| text.find("\"w\"")) {
                text.insert_str(k, "\"fx\": 1e308, ");
            }
            let mut b = text.into_bytes();
            apply(&mut b, &edits);
            let desc = format!("{jedits:?} {edits:?}");
            (b, desc)
        })
}

pub(crate) fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

thread_local! {
    /// Parser calls that returned a value (not an error), for the report.
    static ACCEPTED: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// The error names `name` (the file), or the value is fine.
pub(crate) fn names_file<T>(r: &fantasystyle::Result<T>, name: &str) -> Result<(), String> {
    match r {
        Err(e) if !e.to_string().contains(name) => Err(format!("error does not name {name}: {e}")),
        Err(_) => Ok(()),
        Ok(_) => {
            ACCEPTED.with(|a| a.set(a.get() + 1));
            Ok(())
        }
    }
}

//! Where paths live: the DAG's directory, the work directory (`--workdir`, where
//! commands run and every output, lock, log and pid file goes) and the current
//! directory (where `--set` paths are taken from).
//!
//! The rule (also in the README): stage commands run with the work directory as their
//! current directory, so outputs and stage-produced deps are relative to it. A value
//! that names an existing file or directory is a path, and it is rewritten to the same
//! file as seen from the work directory before it is substituted anywhere:
//! * a `[vars]` value or a literal dep written in the DAG file is relative to the DAG's
//!   directory (only when the work directory is elsewhere, and only when no stage
//!   produces it);
//! * a `--set` value is relative to the current directory.
//!
//! Rewritten paths are relative to the work directory (absolute when the two share
//! nothing but `/`), so a lock stays valid when the whole tree moves. Values that name
//! nothing (numbers, words, `orbit:16` specs) are left as they are.

use std::path::{Component, Path, PathBuf};

/// The three directories paths are resolved against (all absolute).
#[derive(Debug, Clone)]
pub struct Places {
    /// The DAG file's directory.
    pub dir: PathBuf,
    /// Where commands run and outputs go.
    pub workdir: PathBuf,
    /// The current directory (`--set` paths are relative to it).
    pub cwd: PathBuf,
}

impl Places {
    /// Whether the work directory is elsewhere than the DAG's directory.
    pub fn moved(&self) -> bool {
        self.dir != self.workdir
    }

    /// `v`, relative to the DAG's directory, as seen from the work directory, when it
    /// names an existing path and the work directory is elsewhere.
    pub fn from_dag(&self, v: &str) -> Option<String> {
        if !self.moved() {
            return None;
        }
        self.seen_from_workdir(&self.dir, v)
    }

    /// `v`, relative to the current directory, as seen from the work directory, when
    /// it names an existing path.
    pub fn from_cwd(&self, v: &str) -> Option<String> {
        self.seen_from_workdir(&self.cwd, v)
    }

    fn seen_from_workdir(&self, base: &Path, v: &str) -> Option<String> {
        if v.trim().is_empty() || is_value_dep(v) {
            return None;
        }
        let p = Path::new(v);
        if p.is_absolute() {
            return None;
        }
        let abs = lexical(&base.join(p));
        if !abs.exists() {
            return None;
        }
        Some(relative(&abs, &self.workdir))
    }
}

/// The argument `arg` with the path `from` (also written `./from`, or after `NAME=`)
/// replaced by `to`; `None` when it is not that path.
pub(super) fn replace_arg(arg: &str, from: &str, to: &str) -> Option<String> {
    let dotted = format!("./{from}");
    if arg == from || arg == dotted {
        return Some(to.to_string());
    }
    if let Some((head, tail)) = arg.split_once('=')
        && (tail == from || tail == dotted)
    {
        return Some(format!("{head}={to}"));
    }
    None
}

/// A dep that is a value, not a path: `scheme:rest` with a scheme of two or more
/// letters, digits, `+`, `-` or `.` (e.g. `orbit:16,elev=30`). Hashed by its text.
pub fn is_value_dep(d: &str) -> bool {
    let Some((scheme, _)) = d.split_once(':') else {
        return false;
    };
    scheme.len() >= 2
        && scheme.starts_with(|c: char| c.is_ascii_alphabetic())
        && scheme
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
}

/// `p` made absolute against the current directory, `.` and `..` folded lexically,
/// and its longest existing ancestor canonicalised (so that the same directory gets
/// the same name whether it exists yet or not).
pub fn absolute(p: &Path) -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("/"));
    let full = lexical(&cwd.join(p));
    let mut head = full.clone();
    let mut tail = Vec::new();
    loop {
        if let Ok(c) = std::fs::canonicalize(&head) {
            let mut out = c;
            for t in tail.iter().rev() {
                out.push(t);
            }
            return out;
        }
        match (head.file_name().map(|s| s.to_os_string()), head.parent()) {
            (Some(name), Some(parent)) => {
                tail.push(name);
                head = parent.to_path_buf();
            }
            _ => return full,
        }
    }
}

/// Fold `.` and `..` of an absolute path lexically.
pub fn lexical(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// `target` relative to `base` (both absolute and lexical): `../x/y`; the absolute
/// `target` when they share nothing but the root.
pub fn relative(target: &Path, base: &Path) -> String {
    let t: Vec<Component> = target.components().collect();
    let b: Vec<Component> = base.components().collect();
    let common = t.iter().zip(&b).take_while(|(x, y)| x == y).count();
    if common <= 1 {
        return target.to_string_lossy().into_owned();
    }
    let mut parts: Vec<String> = vec!["..".into(); b.len() - common];
    parts.extend(
        t[common..]
            .iter()
            .map(|c| c.as_os_str().to_string_lossy().into_owned()),
    );
    if parts.is_empty() {
        ".".into()
    } else {
        parts.join("/")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_and_value_deps() {
        let r = |t: &str, b: &str| relative(Path::new(t), Path::new(b));
        assert_eq!(r("/a/b/c", "/a/b"), "c");
        assert_eq!(r("/a/d/s.ply", "/a/b/c"), "../../d/s.ply");
        assert_eq!(r("/a/b", "/a/b"), ".");
        assert_eq!(r("/x/s.ply", "/a/b"), "/x/s.ply");
        assert!(is_value_dep("orbit:16") && is_value_dep("orbit:8,elev=30,radius=2.4"));
        assert!(!is_value_dep("runs/a:b") && !is_value_dep("c:x") && !is_value_dep("a.ply"));
        assert_eq!(lexical(Path::new("/a/./b/../c")), PathBuf::from("/a/c"));
        let rep = |a: &str| replace_arg(a, "cameras.json", "../c.json");
        assert_eq!(rep("cameras.json").as_deref(), Some("../c.json"));
        assert_eq!(rep("--d=./cameras.json").as_deref(), Some("--d=../c.json"));
        assert_eq!(rep("cameras.jsonx"), None);
        assert_eq!(rep("my cameras.json"), None);
    }

    #[test]
    fn values_naming_files_are_rewritten_for_the_workdir() {
        let d = tempfile::tempdir().unwrap();
        let root = std::fs::canonicalize(d.path()).unwrap();
        std::fs::create_dir_all(root.join("dag")).unwrap();
        std::fs::write(root.join("dag/scene.ply"), "x").unwrap();
        std::fs::write(root.join("mine.splat"), "x").unwrap();
        let p = Places {
            dir: root.join("dag"),
            workdir: root.join("out/w"),
            cwd: root.clone(),
        };
        assert_eq!(p.from_dag("scene.ply").unwrap(), "../../dag/scene.ply");
        assert_eq!(p.from_dag("./scene.ply").unwrap(), "../../dag/scene.ply");
        assert_eq!(p.from_dag("nope.ply"), None);
        assert_eq!(p.from_dag("3"), None);
        assert_eq!(p.from_cwd("mine.splat").unwrap(), "../../mine.splat");
        assert_eq!(p.from_cwd("orbit:16"), None);
        let same = Places {
            workdir: root.join("dag"),
            ..p
        };
        assert_eq!(same.from_dag("scene.ply"), None);
        assert_eq!(same.from_cwd("mine.splat").unwrap(), "../mine.splat");
    }
}

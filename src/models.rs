//! Finding the installed models: one rule for every stage that defaults a model path
//! (`evaluate`'s metric networks, `stylize-baseline`'s `--vgg` and `--stylizer`, the
//! loop's prior named by the configuration's `prior`: [`prior_dir`]).
//!
//! The models directory is, in order:
//! 1. `$FANTASYSTYLE_MODELS` when set (used as given, even if it does not exist, so a
//!    wrong setting shows up as a missing file under it rather than as a silent fallback);
//! 2. the first `vendor/models` directory in an ancestor of the running executable
//!    (`target/release/evaluate` finds the repository's `vendor/models`);
//! 3. the first `vendor/models` directory in an ancestor of the current directory;
//! 4. `vendor/models` of the source tree the crate was built from.
//!
//! So a stage finds the models whether it is started from the repository root, from
//! another directory, or by the DAG runner, and `FANTASYSTYLE_MODELS` points elsewhere.

use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// Environment variable naming the models directory.
pub const MODELS_ENV: &str = "FANTASYSTYLE_MODELS";

/// The models directory (see the module docs for the search order).
pub fn models_dir() -> Result<PathBuf> {
    resolve(std::env::var_os(MODELS_ENV), &candidates())
}

/// The rule itself: `env` when set and non-empty, else the first existing candidate.
fn resolve(env: Option<std::ffi::OsString>, candidates: &[PathBuf]) -> Result<PathBuf> {
    if let Some(p) = env.filter(|p| !p.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    first_dir(candidates, || {
        format!(
            "the models directory was not found (set {MODELS_ENV}, or run scripts/setup.sh to \
             make vendor/models)"
        )
    })
}

/// The first of `candidates` that is a directory, else a missing-resource error: `what`
/// and the places looked in.
fn first_dir(candidates: &[PathBuf], what: impl FnOnce() -> String) -> Result<PathBuf> {
    candidates
        .iter()
        .find(|p| p.is_dir())
        .cloned()
        .ok_or_else(|| {
            let looked: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
            Error::Missing(format!("{}; looked in: {}", what(), looked.join(", ")))
        })
}

/// `rel` under the models directory, e.g. `model_path("lpips/vgg16")`.
pub fn model_path(rel: impl AsRef<Path>) -> Result<PathBuf> {
    Ok(models_dir()?.join(rel))
}

/// The `vendor/models` directories searched when `$FANTASYSTYLE_MODELS` is not set.
fn candidates() -> Vec<PathBuf> {
    vendor_candidates("models")
}

/// `vendor/SUB` in every ancestor of the running executable, then of the current
/// directory, then of the source tree, in that order (the search of the module docs,
/// also used for other installed assets such as `vendor/viewer`).
pub fn vendor_candidates(sub: &str) -> Vec<PathBuf> {
    ancestors_with(&Path::new("vendor").join(sub))
}

/// `rel` in every ancestor of the running executable, then of the current directory,
/// then the source tree's, in that order, each once.
fn ancestors_with(rel: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    let mut push = |p: PathBuf| {
        if !v.contains(&p) {
            v.push(p);
        }
    };
    if let Ok(exe) = std::env::current_exe() {
        for anc in exe.ancestors().skip(1) {
            push(anc.join(rel));
        }
    }
    if let Ok(cwd) = std::env::current_dir() {
        for anc in cwd.ancestors() {
            push(anc.join(rel));
        }
    }
    push(Path::new(env!("CARGO_MANIFEST_DIR")).join(rel));
    v
}

/// The model directory of the configuration's `prior` (what the loop calls when a stage
/// is given no `--model`): a value that names an existing directory, or holds a path
/// separator, is that path; a bare name is looked up as `priors/NAME` (the priors
/// shipped in the repository, e.g. `patch`) near the executable, the current directory
/// and the source tree, then as `NAME` in the models directory (`stylizer`,
/// `gaussian-prior`: installed by scripts/setup.sh).
pub fn prior_dir(name: &str) -> Result<PathBuf> {
    let as_path = Path::new(name);
    if as_path.is_dir() || name.contains('/') || name.contains(std::path::MAIN_SEPARATOR) {
        return Ok(as_path.to_path_buf());
    }
    let mut looked = ancestors_with(&Path::new("priors").join(name));
    if let Ok(models) = models_dir() {
        looked.push(models.join(name));
    }
    find_prior(name, &looked)
}

/// The first of `candidates` that is a directory, else an error naming `name` and them.
fn find_prior(name: &str, candidates: &[PathBuf]) -> Result<PathBuf> {
    first_dir(candidates, || {
        format!(
            "prior `{name}` (the configuration's `prior`) was not found: give --model DIR, set \
             prior to a model directory, or run scripts/setup.sh (the installed priors)"
        )
    })
}

/// The models directory, with the metric networks in it.
pub fn metric_models() -> Result<PathBuf> {
    let models = models_dir()?;
    if !models.join("metrics").is_dir() {
        return Err(Error::Missing(format!(
            "the metric networks are not installed in {} (run scripts/setup.sh, or set {} \
             to a models directory that has metrics/)",
            models.display(),
            MODELS_ENV
        )));
    }
    Ok(models)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn search_order_starts_near_the_executable_and_ends_at_the_source_tree() {
        let c = candidates();
        let exe = std::env::current_exe().unwrap();
        assert_eq!(c[0], exe.parent().unwrap().join("vendor/models"));
        let cwd = std::env::current_dir().unwrap().join("vendor/models");
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("vendor/models");
        assert!(c.contains(&cwd) && c.contains(&src), "{c:?}");
    }

    #[test]
    fn a_prior_is_a_path_or_a_name_found_in_priors_then_the_models() {
        // The repository's own prior, by name, from the test's current directory.
        let patch = prior_dir("patch").unwrap();
        assert!(patch.ends_with("priors/patch") && patch.join("model.json").is_file());
        // A path is taken as given, even where nothing exists (the stage then names it).
        assert_eq!(prior_dir("x/y").unwrap(), PathBuf::from("x/y"));
        let d = tempfile::tempdir().unwrap();
        let (a, b) = (d.path().join("a"), d.path().join("b"));
        std::fs::create_dir(&b).unwrap();
        assert_eq!(find_prior("b", &[a.clone(), b.clone()]).unwrap(), b);
        let e = find_prior("nope", std::slice::from_ref(&a))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("`nope`") && e.contains(&a.display().to_string()),
            "{e}"
        );
    }

    #[test]
    fn env_wins_then_the_first_existing_candidate() {
        let d = tempfile::tempdir().unwrap();
        let (a, b) = (d.path().join("a"), d.path().join("b"));
        std::fs::create_dir(&b).unwrap();
        let c = [a.clone(), b.clone()];
        assert_eq!(resolve(None, &c).unwrap(), b);
        assert_eq!(resolve(Some("".into()), &c).unwrap(), b);
        // Set: used as given, even where nothing exists.
        assert_eq!(resolve(Some(a.clone().into()), &c).unwrap(), a);
        let e = resolve(None, std::slice::from_ref(&a))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains(MODELS_ENV) && e.contains(&a.display().to_string()),
            "{e}"
        );
    }
}

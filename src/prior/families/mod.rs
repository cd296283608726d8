//! The registry of prior families: what a model directory's `model.json` may name as its
//! `family`, and, for each, how its manifest is checked, which DDIM timesteps the method
//! draws from it and how its prior is opened.
//!
//! Every family is one [`FamilyKind`] line of [`FAMILIES`], its functions in one file
//! here: [`diffusion`] (ONNX diffusion graphs: `sd15`, `sd21`, `sdxl`, `custom`),
//! [`gaussian`] (the closed-form Gaussian denoiser, shipped with the same ONNX contract),
//! [`stylizer`] (a feed-forward 2D stylizer, the CPU demo) and [`patch`] (the weight-free
//! patch prior). A new family is one new file here and one line of [`FAMILIES`]; the
//! manifest's `family` is parsed against the list, and the errors naming the known
//! families come from it.

use super::manifest::{ModelDir, TimestepRange};
use super::{Prior, PriorOptions};
use crate::Result;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub mod diffusion;
pub mod gaussian;
pub mod patch;
pub mod stylizer;
#[cfg(test)]
mod test_only;

/// One family of priors: its name (the `family` of `model.json`) and its functions.
pub struct FamilyKind {
    /// The name `model.json` gives it.
    pub name: &'static str,
    /// Checks what the family needs of the manifest, after the format and the scheduler
    /// (which every family checks the same way).
    pub validate: fn(&ModelDir) -> Result<()>,
    /// The family's own DDIM timestep range, when its manifest gives one (`None`: the
    /// scheduler's default set).
    pub timesteps: fn(&ModelDir) -> Result<Option<TimestepRange>>,
    /// Opens the family's prior from its validated manifest.
    pub open: fn(ModelDir, &PriorOptions) -> Result<Box<dyn Prior>>,
}

impl std::fmt::Debug for FamilyKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FamilyKind")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

/// The registry of families, one line each.
#[rustfmt::skip]
pub const FAMILIES: &[FamilyKind] = &[
    FamilyKind { name: "sd15", validate: |md| diffusion::validate(md, Some(0.18215)), timesteps: diffusion::timesteps, open: diffusion::open },
    FamilyKind { name: "sd21", validate: |md| diffusion::validate(md, Some(0.18215)), timesteps: diffusion::timesteps, open: diffusion::open },
    FamilyKind { name: "sdxl", validate: |md| diffusion::validate(md, Some(0.13025)), timesteps: diffusion::timesteps, open: diffusion::open },
    FamilyKind { name: "custom", validate: |md| diffusion::validate(md, None), timesteps: diffusion::timesteps, open: diffusion::open },
    FamilyKind { name: "gaussian", validate: gaussian::validate, timesteps: gaussian::timesteps, open: gaussian::open },
    FamilyKind { name: "stylizer", validate: stylizer::validate, timesteps: stylizer::timesteps, open: stylizer::open },
    FamilyKind { name: "patch", validate: patch::validate, timesteps: patch::timesteps, open: patch::open },
    #[cfg(test)]
    FamilyKind { name: "test-only", validate: test_only::validate, timesteps: test_only::timesteps, open: test_only::open },
];

/// The names of [`FAMILIES`], in its order (for serde's "expected one of" errors).
static NAMES: [&str; FAMILIES.len()] = {
    let mut names = [""; FAMILIES.len()];
    let mut i = 0;
    while i < FAMILIES.len() {
        names[i] = FAMILIES[i].name;
        i += 1;
    }
    names
};

/// The names of the known families, in the registry's order.
pub fn names() -> &'static [&'static str] {
    &NAMES
}

/// The family a model directory holds: an entry of [`FAMILIES`], written in `model.json`
/// as its name (`"family": "sd15"`).
#[derive(Clone, Copy)]
pub struct Family(&'static FamilyKind);

impl Family {
    /// The family of this name, if [`FAMILIES`] has one.
    pub fn named(name: &str) -> Option<Family> {
        FAMILIES.iter().find(|k| k.name == name).map(Family)
    }

    /// Its entry of [`FAMILIES`].
    pub fn kind(self) -> &'static FamilyKind {
        self.0
    }

    /// Its name in `model.json`.
    pub fn name(self) -> &'static str {
        self.0.name
    }
}

impl PartialEq for Family {
    fn eq(&self, other: &Family) -> bool {
        self.name() == other.name()
    }
}

impl Eq for Family {}

impl std::fmt::Debug for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for Family {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> Deserialize<'de> for Family {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Family, D::Error> {
        let name = String::deserialize(d)?;
        Family::named(&name).ok_or_else(|| serde::de::Error::unknown_variant(&name, names()))
    }
}

/// The `timesteps` of a family's own manifest section `name` (`stylizer`, `patch`), if
/// given.
pub fn section_timesteps(
    md: &ModelDir,
    name: &str,
    section: Option<&serde_json::Value>,
) -> Result<Option<TimestepRange>> {
    let Some(v) = section.and_then(|s| s.get("timesteps")) else {
        return Ok(None);
    };
    serde_json::from_value::<TimestepRange>(v.clone())
        .map(Some)
        .map_err(|e| md.err(format!("{name}.timesteps: {e}")))
}

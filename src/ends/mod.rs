//! How a run starts and how it ends: the configuration's `start` and `finish`, each one
//! name of the registry [`ENDS`]. FantasyStyle starts from the scene as it is and ends
//! with the last iteration (`start = "scene"`, `finish = "none"`); the default ends with
//! the patch prior's deterministic limit; the rest are techniques of ARF's recipe (the
//! `arf` preset), not part of FantasyStyle:
//!
//! | end | role | what | module |
//! |---|---|---|---|
//! | `scene` | start | the scene as it is | here |
//! | `none` | finish | the last iteration's colours | here |
//! | `colour` | start, finish | the object's colour mean and covariance moved onto the style image's, each Gaussian then clamped into the style's colour extent: over the source views (ARF's colour pre-transfer), or over the result's renders (ARF's colour transfer after the optimisation: the loop's palette drift taken back) | [`colour`] |
//! | `projection` | start | the style image texture-mapped onto the object: triplanar projection along each Gaussian's normal, one style pixel per render pixel at the object (`texture.style_size`), shaded by each Gaussian's relative brightness | [`projection`] |
//! | `layout` | start | the object cut into 3D Voronoi cells at the motif scale (`synthesis.motifs_across` across its extent), each one random colour of the style's motifs: the layout the patch end draws its motifs on | [`layout`] |
//! | `patches` | finish | the patch prior's deterministic t -> 0 end: the colours fitted, coarse to fine, to every view's average of its nearest style patches, targets held, patch use balanced (texture optimisation, Kwatra et al. 2005), guided by the scene's structure; settings `[synthesis]`, parts [`patches::PARTS`] | [`patches`] |
//!
//! A new end is one new file here and one line of [`ENDS`] (its name, its roles, its
//! settings section if it has one, its help and its function); the configuration,
//! `--start`/`--finish`, `--set` and `distill --help` take it from there.
//!
//! A start applies to a fresh run (from a scene, iteration 0): a checkpoint has been
//! through it. A chunked run (the sample DAG with a loop) gives the finish to its last
//! stage only. Splitting long Gaussians is a start of another kind, a change of the
//! geometry: its own stage (`split`, [`split`]).

pub mod colour;
pub mod layout;
pub mod patches;
pub mod projection;
pub mod split;
#[cfg(test)]
mod test_grey;

use crate::imageio::Image;
use crate::render::source::SourceViews;
use crate::{Camera, Error, Result, Scene};
use std::path::Path;

/// Where an end may stand.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Before the loop, on a fresh run.
    Start,
    /// After the loop.
    Finish,
}

/// One end: its name in the configuration, where it may stand, the configuration section
/// it reads (if any), a line of help, and what it does.
#[derive(Debug, Clone, Copy)]
pub struct EndKind {
    pub name: &'static str,
    pub roles: &'static [Role],
    pub section: Option<&'static str>,
    pub help: &'static str,
    /// `scene` after this end in `role`.
    pub run: fn(Role, &Scene, &EndInputs<'_>) -> Result<Scene>,
}

const START: &[Role] = &[Role::Start];
const FINISH: &[Role] = &[Role::Finish];
const BOTH: &[Role] = &[Role::Start, Role::Finish];

/// The ends. A new end is one file of this module and one line here.
#[rustfmt::skip]
pub const ENDS: &[EndKind] = &[
    EndKind { name: "scene", roles: START, section: None, help: "the scene as it is (FantasyStyle)", run: as_it_is },
    EndKind { name: "none", roles: FINISH, section: None, help: "the last iteration's colours (FantasyStyle)", run: as_it_is },
    EndKind { name: "colour", roles: BOTH, section: None, help: "the colours moved onto the style's mean and covariance (ARF's colour transfer)", run: colour::run },
    EndKind { name: "projection", roles: START, section: Some("texture"), help: "the style image texture-mapped onto the object (triplanar)", run: projection::run },
    EndKind { name: "layout", roles: START, section: Some("synthesis"), help: "the object cut into 3D cells at the motif scale, each one random colour of the style's motifs (a layout for the patch end to draw on)", run: layout::run },
    EndKind { name: "patches", roles: FINISH, section: Some("synthesis"), help: "the patch prior's deterministic end: the style's patches synthesised onto the colours, coarse to fine", run: patches::run },
    #[cfg(test)]
    EndKind { name: "test-grey", roles: FINISH, section: None, help: "every colour grey (a test-only end)", run: test_grey::run },
];

/// An end chosen for one role (`start` or `finish`): a name of [`ENDS`] that may stand
/// there. In a file and on the command line: its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct End {
    name: &'static str,
    role: Role,
}

/// The configuration's `start`.
pub type Start = End;
/// The configuration's `finish`.
pub type Finish = End;

impl End {
    /// The start that keeps the scene as it is.
    pub const SCENE: End = End {
        name: "scene",
        role: Role::Start,
    };
    /// The finish that keeps the last iteration's colours.
    pub const NONE: End = End {
        name: "none",
        role: Role::Finish,
    };

    /// The end `name` in `role`, or why not (the ends that may stand there).
    pub fn parse(name: &str, role: Role) -> std::result::Result<End, String> {
        match ENDS
            .iter()
            .find(|k| k.name == name && k.roles.contains(&role))
        {
            Some(k) => Ok(End { name: k.name, role }),
            None => Err(format!(
                "`{name}` is not one of {}",
                Self::names(role).join(", ")
            )),
        }
    }

    /// The names of the ends that may stand in `role`.
    pub fn names(role: Role) -> Vec<&'static str> {
        ENDS.iter()
            .filter(|k| k.roles.contains(&role))
            .map(|k| k.name)
            .collect()
    }

    /// A start for clap (`--start`, `--set start=`).
    pub fn start(s: &str) -> std::result::Result<End, String> {
        End::parse(s, Role::Start)
    }

    /// A finish for clap (`--finish`, `--set finish=`).
    pub fn finish(s: &str) -> std::result::Result<End, String> {
        End::parse(s, Role::Finish)
    }

    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Its entry of [`ENDS`].
    pub fn kind(&self) -> &'static EndKind {
        ENDS.iter()
            .find(|k| k.name == self.name)
            .expect("an End is made from the registry")
    }

    /// Whether it keeps the scene as it is (`scene`, `none`).
    pub fn keeps(&self) -> bool {
        matches!(self.name, "scene" | "none")
    }

    /// Every end with its roles and help, for `--help`.
    pub fn help() -> String {
        ENDS.iter()
            .map(|k| {
                let roles: Vec<&str> = k
                    .roles
                    .iter()
                    .map(|r| match r {
                        Role::Start => "start",
                        Role::Finish => "finish",
                    })
                    .collect();
                let section = k.section.map(|s| format!("; [{s}]")).unwrap_or_default();
                format!(
                    "          {} ({}{section}): {}\n",
                    k.name,
                    roles.join(", "),
                    k.help
                )
            })
            .collect()
    }
}

impl std::fmt::Display for End {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

impl serde::Serialize for End {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name)
    }
}

/// Read an end of `role` from a file (serde's `deserialize_with`).
fn read_end<'de, D: serde::Deserializer<'de>>(
    d: D,
    role: Role,
) -> std::result::Result<End, D::Error> {
    let s = <String as serde::Deserialize>::deserialize(d)?;
    End::parse(&s, role).map_err(serde::de::Error::custom)
}

/// `start` from a file.
pub fn read_start<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<End, D::Error> {
    read_end(d, Role::Start)
}

/// `finish` from a file.
pub fn read_finish<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<End, D::Error> {
    read_end(d, Role::Finish)
}

/// What an end needs besides the scene: the cameras (`cameras_from` names them in
/// errors) and their source views, the style image as loaded (`style_path` in errors),
/// the configuration as a table (each end reads its own section by name,
/// [`EndInputs::section`]), the selection, if any, and the regions, if any.
#[derive(Debug, Clone, Copy)]
pub struct EndInputs<'a> {
    pub cameras: &'a [Camera],
    pub cameras_from: &'a Path,
    pub source: &'a SourceViews,
    pub style: &'a Image,
    pub style_path: &'a Path,
    pub settings: &'a toml::Table,
    pub selection: Option<&'a crate::selection::Selection>,
    /// Several regions, each its own style (the `patches` finish alone takes them;
    /// `selection` is then their combined weights).
    pub regions: Option<&'a crate::regions::Regions>,
}

impl EndInputs<'_> {
    /// The configuration's `sh`: whether an end's colour fit moves the bands too.
    pub fn bands(&self) -> Result<crate::scene::colour::Bands> {
        self.section("sh")
    }

    /// Section `name` of the configuration (`[synthesis]`, `[texture]`), read as `T`
    /// (its defaults where the table has none).
    pub fn section<T: serde::de::DeserializeOwned + Default>(&self, name: &str) -> Result<T> {
        match self.settings.get(name) {
            Some(v) => v
                .clone()
                .try_into()
                .map_err(|e| Error::param(format!("[{name}]: {e}"))),
            None => Ok(T::default()),
        }
    }
}

/// `scene` after `end`. An end that changes the scene leaves every base colour it may
/// change (weight above 0) inside [0, 1], the range every output format holds
/// ([`crate::scene::colour`]): a projection here, whatever the end did.
pub fn apply(end: End, scene: &Scene, inputs: &EndInputs<'_>) -> Result<Scene> {
    let mut out = (end.kind().run)(end.role, scene, inputs)?;
    if !end.keeps() {
        let weights = inputs.selection.map(|s| &s.weights[..]);
        let moved = crate::scene::colour::bound_base(&mut out, weights);
        if moved > 0 {
            tracing::info!(
                "{}: {moved} base colours moved into [0, 1]",
                end.kind().name
            );
        }
    }
    Ok(out)
}

/// `scene` and `none`: the scene as it is.
fn as_it_is(_: Role, scene: &Scene, _: &EndInputs<'_>) -> Result<Scene> {
    Ok(scene.clone())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every end parses by name in the roles it has and no other, names the others when
    /// refused, and reads back from its name; `--help` lists them all from the registry.
    #[test]
    fn ends_come_from_the_registry() {
        for k in ENDS {
            for role in [Role::Start, Role::Finish] {
                assert_eq!(End::parse(k.name, role).is_ok(), k.roles.contains(&role));
            }
        }
        let e = End::parse("paint", Role::Start).unwrap_err();
        assert!(e.contains("scene, colour, projection"), "{e}");
        assert!(End::parse("patches", Role::Start).is_err());
        let h = End::help();
        assert!(h.contains("patches (finish; [synthesis])") && h.contains("test-grey"));
        assert!(End::SCENE.keeps() && End::NONE.keeps());
        assert!(!End::finish("patches").unwrap().keeps());
    }
}

//! The method's configuration: one type ([`Config`]) that the command line, the
//! configuration files (presets, a DAG's params tables) and the artifacts' manifests all
//! read and write. Each key is declared once, in the struct that uses it (a field here,
//! or in [`CsdParams`], [`MvfcParams`], [`TextureParams`]): its doc comment is its help,
//! its clap declaration its default ([`crate::params`]). The defaults are FantasyStyle's
//! method (AAAI 2026, Sec. 4): the CSD term through the prior, MVFC on both branches, no
//! start, no finish, no split.
//!
//! A run's configuration is built in layers, each over the one before:
//!
//! 1. the defaults;
//! 2. a preset (`--preset NAME`): a configuration file of the repository's `presets/`
//!    directory, built into the binaries ([`PRESETS`]): `default` (the sample DAG's:
//!    FantasyStyle's loop ended by the patch prior's deterministic limit), `paper`
//!    (FantasyStyle alone), `arf` (ARF's recipe on the loop) and `motifs` (the default
//!    with the style's motifs laid out at their scale first: src/ends/layout.rs);
//! 3. configuration files and inline tables (`--config FILE` or `--config '{ k = v }'`,
//!    in order; a table's `preset = "NAME"` puts that preset under it);
//! 4. single keys (`--set KEY=VALUE`, dotted for a section: `csd.guidance=0`), parsed as
//!    the key's flag would be;
//! 5. the choices a stage takes as flags (`distill --terms`, `--start`, `--finish`).
//!
//! Tables merge key by key, except `terms`, which a layer gives whole (the terms it
//! names, every other at 0). Unknown keys are errors, named with their file.

use crate::csd::CsdParams;
use crate::ends::patches::SynthesisParams;
use crate::ends::{End, Finish, Start};
use crate::mvfc::MvfcParams;
use crate::scene::colour::Bands;
use crate::scheduler::TimestepSchedule;
use crate::terms::texture::TextureParams;
use crate::terms::{ColourLoss, Terms};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The method's configuration (module docs): every parameter of a run with its default.
#[derive(Debug, Clone, PartialEq, clap::Args, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// The colour step's loss, a weighted sum of terms `NAME=WEIGHT,...` of the registry
    /// (src/terms/, listed below): the prior's distillation term `csd` (the paper),
    /// `sds`, `dds` or `csd-no-neg` (at most one), and terms that are not FantasyStyle
    /// (the VGG texture terms `nnfm` and `gram`, `tv`). In a file: a table,
    /// `terms = { csd = 1.0, gram = 0.1 }`.
    #[arg(long, default_value = "csd=1", value_parser = Terms::parse)]
    pub terms: Terms,
    /// How a fresh run starts, an end of the registry (src/ends/): `scene` (as it is),
    /// `colour` (its colours moved onto the style's mean and covariance) or `projection`
    /// (the style image texture-mapped onto the object); the last two are ARF's, not
    /// FantasyStyle.
    #[arg(long, default_value = "scene", value_parser = End::start)]
    #[serde(deserialize_with = "crate::ends::read_start")]
    pub start: Start,
    /// How a run ends, an end of the registry (src/ends/): `none`, `colour` (the
    /// result's colours moved onto the style's mean and covariance, ARF's colour transfer
    /// after the optimisation) or `patches` (the patch prior's deterministic t -> 0 end:
    /// texture optimisation of the colours with the style's patches, coarse to fine,
    /// `[synthesis]`).
    #[arg(long, default_value = "none", value_parser = End::finish)]
    #[serde(deserialize_with = "crate::ends::read_finish")]
    pub finish: Finish,
    /// Read by the `split` stage, not by distill: split every Gaussian longer than this
    /// many render pixels at the object (2 sigma along its longest axis) in two, up to 8
    /// rounds, before the run (geometry changes; not FantasyStyle; src/distill/split.rs).
    /// 0 = off.
    #[arg(long, default_value_t = 0.0)]
    pub split: f64,
    /// The prior the loop's iterations call when a stage is given no `--model` (or an
    /// empty one): a model directory, or the name of one shipped in `priors/` (`patch`:
    /// the weight-free patch prior) or installed in `vendor/models` by scripts/setup.sh
    /// (`stylizer`, `gaussian-prior`); src/models.rs [`crate::models::prior_dir`]. A preset
    /// names the prior it needs (the `arf` preset: `stylizer`).
    #[arg(long, default_value = "patch")]
    pub prior: String,
    /// Adjacent views per iteration (the paper's N).
    #[arg(long, default_value_t = 4)]
    pub views: usize,
    /// Style strength in [0, 1]: 0 leaves the scene unchanged, 1 is the full style (for
    /// the stylizer prior an interpolation of style vectors).
    #[arg(long, default_value_t = 1.0)]
    pub strength: f32,
    /// Keep the scene's own colours (chroma); change luminance (texture, contrast) only.
    #[arg(long, default_value_t = false, action = clap::ArgAction::Set)]
    pub preserve_color: bool,
    /// The input's view-dependent colour bands (SH degree >= 1): `drop` (the stylized
    /// Gaussians lose them, degree 0 without a selection: every output format holds the
    /// result exactly), `keep` (as they were; the base colour is fitted around them) or
    /// `fit` (fitted with the base at lr_dc / 20). Applied on a fresh run
    /// (src/scene/colour.rs).
    #[arg(long, value_enum, default_value = "drop")]
    pub sh: Bands,
    /// Adam learning rate of the SH DC colours (3DGS trains from scratch at 0.0025 over
    /// 30k steps; a few hundred distillation steps need more: docs/method.md "Colour-fit
    /// learning rate").
    #[arg(long, default_value_t = 0.05)]
    pub lr_dc: f32,
    /// How the prior's change reaches the colours: `l2` passes it with its magnitude (the
    /// paper's gradient), `l1` only its sign.
    #[arg(long, value_enum, default_value = "l2")]
    pub colour_loss: ColourLoss,
    /// Give the prior (and the texture terms) the object over a fill of its own colours
    /// rather than the raw render over the background.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub fill: bool,
    /// Seed of every draw (views, timesteps, noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Timestep set MIN:MAX:COUNT (empty: the model's own set).
    #[arg(long)]
    pub timesteps: Option<String>,
    /// Anneal the timestep from coarse to fine over this many iterations in total (the
    /// whole run, all chunks: t_max falls linearly to the set's smallest); 0 = draw
    /// uniformly from the whole set every iteration (the paper).
    #[arg(long, default_value_t = 0)]
    pub anneal_iters: u64,
    /// Motif scale of the stylizer prior: the render is enlarged this many times before
    /// the network and reduced after, so strokes come out this much smaller on the object.
    #[arg(long, default_value_t = 1.0)]
    pub motif_scale: f32,
    /// Most UNet rows per call of a diffusion prior (rows = views x conditionings; 0 =
    /// automatic: all, unless the first level's attention scores would pass 2^31 floats).
    #[arg(long, default_value_t = 0)]
    pub unet_batch: usize,
    /// The distillation step (`[csd]`).
    #[arg(skip)]
    pub csd: CsdParams,
    /// Multi-view frequency consistency (`[mvfc]`).
    #[arg(skip)]
    pub mvfc: MvfcParams,
    /// The VGG texture terms (`[texture]`).
    #[arg(skip)]
    pub texture: TextureParams,
    /// The patch synthesis of `finish = "patches"` (`[synthesis]`).
    #[arg(skip)]
    pub synthesis: SynthesisParams,
}

impl Default for Config {
    fn default() -> Self {
        crate::params::defaults()
    }
}

/// A section of the configuration (`[NAME]` in a file, `NAME.KEY` for `--set`): the keys
/// one part of the method reads, declared once in its parameter struct. This list drives
/// `--help`, `--set` and the range checks; a new section is one field of [`Config`] and
/// one line here (a test holds the two together).
#[derive(Debug, Clone, Copy)]
pub struct Section {
    pub name: &'static str,
    /// Its keys with their defaults and docs ([`crate::params::key_help`]).
    help: fn(&str) -> String,
    /// One `KEY=VALUE` parsed by the key's declaration ([`crate::params::typed_value`]).
    value: fn(&str, &str, &str) -> Result<toml::Value>,
    /// Every key's range checked.
    check: fn(&Config) -> Result<()>,
}

macro_rules! section {
    ($name:ident, $t:ty) => {
        Section {
            name: stringify!($name),
            help: crate::params::key_help::<$t>,
            value: crate::params::typed_value::<$t>,
            check: |c| c.$name.validate(),
        }
    };
}

/// The sections: the distillation step's, MVFC's, the VGG texture terms' and the patch
/// synthesis end's.
pub const SECTIONS: &[Section] = &[
    section!(csd, CsdParams),
    section!(mvfc, MvfcParams),
    section!(texture, TextureParams),
    section!(synthesis, SynthesisParams),
];

/// The presets: `presets/NAME.toml` of the repository, built into the binaries.
pub const PRESETS: [(&str, &str); 5] = [
    ("default", include_str!("../presets/default.toml")),
    ("paper", include_str!("../presets/paper.toml")),
    ("arf", include_str!("../presets/arf.toml")),
    ("motifs", include_str!("../presets/motifs.toml")),
    ("shaded", include_str!("../presets/shaded.toml")),
];

/// Where a layer of the configuration comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum Source {
    /// A preset by name ([`PRESETS`]).
    Preset(String),
    /// A configuration file, or an inline TOML table `{ key = value, ... }`.
    Config(String),
    /// One `KEY=VALUE`.
    Set(String),
}

impl Config {
    /// The configuration of `layers` over the defaults (module docs), checked.
    pub fn layered(layers: &[Source]) -> Result<Config> {
        let mut table = toml::Table::new();
        for layer in layers {
            match layer {
                Source::Preset(name) => merge(&mut table, preset(name)?),
                Source::Config(src) => merge(&mut table, config_table(src)?),
                Source::Set(kv) => set(&mut table, kv)?,
            }
        }
        let c: Config = toml::Value::Table(table)
            .try_into()
            .map_err(|e| Error::param(format!("configuration: {e}")))?;
        c.checked()
    }

    /// Checked (every section's ranges, the terms), with the distillation step's mode
    /// taken from the prior's term.
    pub fn checked(mut self) -> Result<Config> {
        self.terms.validate()?;
        self.csd.mode = self.terms.prior().map_or(self.csd.mode, |(m, _)| m);
        for s in SECTIONS {
            (s.check)(&self)?;
        }
        let positive = |x: f32| x.is_finite() && x >= 0.0;
        if !positive(self.lr_dc) {
            return Err(Error::param("lr_dc must be finite and >= 0"));
        }
        if self.prior.trim().is_empty() {
            return Err(Error::param(
                "prior must name a model directory or an installed prior (patch, stylizer)",
            ));
        }
        if self.views == 0 {
            return Err(Error::param("views must be at least 1"));
        }
        if !(0.0..=1.0).contains(&self.strength) {
            return Err(Error::param(format!(
                "strength must be in [0, 1], got {}",
                self.strength
            )));
        }
        if !(self.split.is_finite() && self.split >= 0.0) {
            return Err(Error::param("split must be finite and >= 0 (0: off)"));
        }
        if self.preserve_color && !(self.start.keeps() && self.finish.keeps()) {
            return Err(Error::param(
                "preserve_color keeps the scene's colours; the colour and projection starts \
                 and the colour finish replace them: choose one",
            ));
        }
        Ok(self)
    }

    /// Whether the prior is asked anything: a prior term whose gradient is not zero
    /// whatever the prior says ([`CsdParams::asks_nothing`]).
    pub fn asks_the_prior(&self) -> bool {
        self.terms.prior().is_some() && !self.csd.asks_nothing()
    }

    /// How an iteration's timestep is drawn.
    pub fn t_schedule(&self) -> TimestepSchedule {
        if self.anneal_iters > 0 {
            TimestepSchedule::Anneal {
                total: self.anneal_iters,
            }
        } else {
            TimestepSchedule::Random
        }
    }

    /// The configuration as a table (what the ends read their sections from,
    /// [`crate::ends::EndInputs::section`]).
    pub fn table(&self) -> toml::Table {
        toml::Table::try_from(self).expect("a configuration serialises")
    }

    /// The configuration as TOML (what a file would hold to reproduce it).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a configuration serialises")
    }

    /// Every key with its default and its doc, for `--help`, then the registries: the
    /// terms, the ends and the patch synthesis's parts.
    pub fn help() -> String {
        let mut s = crate::params::key_help::<Config>("");
        for sec in SECTIONS {
            s += &(sec.help)(&format!("{}.", sec.name));
        }
        s += "\nTerms (`terms`, src/terms/):\n";
        s += &Terms::help();
        s += "\nEnds (`start`, `finish`, src/ends/):\n";
        s += &End::help();
        s += "\nParts of the patch synthesis (src/ends/patches/):\n";
        s += &crate::ends::patches::parts_help();
        s += "\nPrior families (the `family` of --model's model.json, src/prior/families/):\n";
        let families: Vec<&str> = crate::prior::families::FAMILIES
            .iter()
            .map(|f| f.name)
            .collect();
        s += &format!("          {}\n", families.join(", "));
        s
    }
}

/// The table of preset `name`.
fn preset(name: &str) -> Result<toml::Table> {
    let Some((_, text)) = PRESETS.iter().find(|(n, _)| *n == name) else {
        let names: Vec<&str> = PRESETS.iter().map(|(n, _)| *n).collect();
        return Err(Error::param(format!(
            "unknown preset `{name}`; the presets: {}",
            names.join(", ")
        )));
    };
    parse_layer(text, &format!("preset {name}"))
}

/// The table of a `--config` value: an inline table (starting with `{`) or a file.
fn config_table(src: &str) -> Result<toml::Table> {
    if src.trim_start().starts_with('{') {
        let doc: toml::Table = toml::from_str(&format!("config = {src}"))
            .map_err(|e| Error::param(format!("--config {src}: {}", e.message())))?;
        let Some(toml::Value::Table(t)) = doc.get("config").cloned() else {
            return Err(Error::param(format!("--config {src}: not a table")));
        };
        return with_preset(t, &format!("--config {src}"));
    }
    let path = Path::new(src);
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_layer(&text, src)
}

/// A configuration file's text as a table, its keys checked (`what` names it in errors).
fn parse_layer(text: &str, what: &str) -> Result<toml::Table> {
    let t: toml::Table =
        toml::from_str(text).map_err(|e| Error::param(format!("{what}: {}", e.message())))?;
    with_preset(t, what)
}

/// `t` over the preset it names (`preset = "NAME"`), its keys checked against
/// [`Config`] (`what` names it in errors).
fn with_preset(mut t: toml::Table, what: &str) -> Result<toml::Table> {
    let base = match t.remove("preset") {
        Some(toml::Value::String(name)) => preset(&name)?,
        Some(v) => {
            return Err(Error::param(format!(
                "{what}: preset = {v}: expected a preset's name"
            )));
        }
        None => toml::Table::new(),
    };
    let check: std::result::Result<Config, _> = toml::Value::Table(t.clone()).try_into();
    check.map_err(|e| Error::param(format!("{what}: {e}")))?;
    let mut out = base;
    merge(&mut out, t);
    Ok(out)
}

/// `over` merged into `base`: tables key by key, `terms` and every other value replaced.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) if k != "terms" => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Apply `KEY=VALUE` to `table`, the value parsed by the key's own declaration.
fn set(table: &mut toml::Table, kv: &str) -> Result<()> {
    use crate::params::typed_value;
    let Some((key, value)) = kv.split_once('=') else {
        return Err(Error::param(format!(
            "--set {kv}: expected KEY=VALUE (e.g. csd.guidance=0; `distill --help` lists the keys)"
        )));
    };
    let key = key.trim().replace('-', "_");
    let (section, field) = key.split_once('.').unwrap_or(("", &key));
    let v = match (section, SECTIONS.iter().find(|s| s.name == section)) {
        ("", _) => typed_value::<Config>("", field, value)?,
        (_, Some(s)) => (s.value)(&format!("{section}."), field, value)?,
        ("terms", None) => {
            let w: f32 = value
                .trim()
                .parse()
                .map_err(|_| Error::param(format!("--set {kv}: a weight is a number")))?;
            let name = Terms::canonical(field).map_err(Error::param)?;
            let toml::Value::Table(mut terms) = table
                .remove("terms")
                .unwrap_or_else(|| toml::Value::try_from(Config::default().terms).expect("terms"))
            else {
                return Err(Error::param("terms is not a table"));
            };
            terms.insert(name.to_string(), toml::Value::Float(w as f64));
            table.insert("terms".into(), toml::Value::Table(terms));
            return Ok(());
        }
        (_, None) => {
            let names: Vec<&str> = SECTIONS.iter().map(|s| s.name).collect();
            return Err(Error::param(format!(
                "--set {kv}: unknown section `{section}` ({}, terms)",
                names.join(", ")
            )));
        }
    };
    if section.is_empty() {
        table.insert(field.to_string(), v);
    } else {
        let toml::Value::Table(s) = table
            .entry(section.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        else {
            return Err(Error::param(format!("{section} is not a table")));
        };
        s.insert(field.to_string(), v);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::csd::Mode;

    #[test]
    fn the_defaults_are_the_papers_method_and_the_paper_preset_says_so() {
        let d = Config::default();
        assert_eq!(d.terms, Terms::parse("csd=1").unwrap());
        assert_eq!(
            (d.start, d.finish, d.split),
            (Start::SCENE, Finish::NONE, 0.0)
        );
        assert!(d.mvfc.enabled && d.mvfc.source);
        assert_eq!(d.csd, CsdParams::default());
        let paper = Config::layered(&[Source::Preset("paper".into())]).unwrap();
        assert_eq!(paper, Config::default().checked().unwrap());
        // Each preset names the prior its loop calls (src/models.rs `prior_dir`).
        assert_eq!(d.prior, "patch");
        let arf = Config::layered(&[Source::Preset("arf".into())]).unwrap();
        assert_eq!(arf.prior, "stylizer");
        // `motifs` is the default over the layout start, its keys over the default's.
        let m = Config::layered(&[Source::Preset("motifs".into())]).unwrap();
        let default = Config::layered(&[Source::Preset("default".into())]).unwrap();
        assert_eq!(m.start, End::start("layout").unwrap());
        assert_eq!(
            (m.synthesis.levels.clone(), m.synthesis.control),
            (vec![2, 1], 0.6)
        );
        assert_eq!((m.finish, m.synthesis.guide_blur), (default.finish, 2.0));
        // `shaded` is the default's end with the guide nearly off and the shading in the
        // layer, whose weight detail x control stays 1 (the default's before its edge guide).
        let s = Config::layered(&[Source::Preset("shaded".into())]).unwrap();
        assert_eq!((s.start, s.finish), (default.start, default.finish));
        assert_eq!(
            (
                s.synthesis.control,
                s.synthesis.shade_blur,
                s.synthesis.line_weight
            ),
            (0.1, 16.0, 4.0)
        );
        assert!((s.synthesis.detail * s.synthesis.control - 1.0).abs() < 1e-6);
        assert_eq!(default.synthesis.shade_blur, 0.0);
        // Both were measured without the default's edge guide and at the guide's full
        // share, and keep them so.
        assert_eq!((m.synthesis.edges, s.synthesis.edges), (0.0, 0.0));
        assert_eq!(
            (m.synthesis.guide_weight, s.synthesis.guide_weight),
            (1.0, 1.0)
        );
        // What a file holds is what it reads back.
        let back: Config = toml::from_str(&d.to_toml()).unwrap();
        assert_eq!(back, d);
    }

    #[test]
    fn the_default_preset_is_the_paper_ended_by_the_guided_patch_synthesis() {
        let d = Config::layered(&[Source::Preset("default".into())]).unwrap();
        let paper = Config::default().checked().unwrap();
        assert_eq!(d.finish, End::finish("patches").unwrap());
        assert_eq!(d.synthesis.control, 1.0);
        assert_eq!((d.synthesis.guide_blur, d.synthesis.detail), (2.0, 0.75));
        assert_eq!((d.synthesis.lr, d.synthesis.line_weight), (0.1, 2.0));
        assert_eq!((d.synthesis.ink, d.synthesis.consensus), (2.0, 8.0));
        assert_eq!((d.synthesis.edges, d.synthesis.guide_weight), (2.0, 0.25));
        let mut unguided = d.clone();
        unguided.finish = Finish::NONE;
        unguided.synthesis.control = paper.synthesis.control;
        unguided.synthesis.guide_blur = paper.synthesis.guide_blur;
        unguided.synthesis.detail = paper.synthesis.detail;
        unguided.synthesis.lr = paper.synthesis.lr;
        unguided.synthesis.line_weight = paper.synthesis.line_weight;
        unguided.synthesis.ink = paper.synthesis.ink;
        unguided.synthesis.consensus = paper.synthesis.consensus;
        unguided.synthesis.edges = paper.synthesis.edges;
        unguided.synthesis.guide_weight = paper.synthesis.guide_weight;
        assert_eq!(unguided, paper);
        let c = Config::layered(&[
            Source::Preset("default".into()),
            Source::Set("synthesis.levels=4,1".into()),
            Source::Set("synthesis.balance=0.5".into()),
        ])
        .unwrap();
        assert_eq!(
            (c.synthesis.levels.clone(), c.synthesis.balance),
            (vec![4, 1], 0.5)
        );
        let e = Config::layered(&[Source::Set("synthesis.balance=2".into())]).unwrap_err();
        assert!(e.to_string().contains("synthesis.balance"), "{e}");
        let e = Config::layered(&[Source::Set("synthesis.patch=6".into())]).unwrap_err();
        assert!(e.to_string().contains("synthesis.patch"), "{e}");
    }

    #[test]
    fn layers_apply_in_order_and_terms_are_given_whole() {
        let arf = Config::layered(&[Source::Preset("arf".into())]).unwrap();
        assert_eq!(arf.terms.to_string(), "csd=1,nnfm=1,gram=0.1");
        assert_eq!(
            (arf.start, arf.finish, arf.split),
            (
                End::start("projection").unwrap(),
                End::finish("colour").unwrap(),
                2.0
            )
        );
        let c = Config::layered(&[
            Source::Preset("arf".into()),
            Source::Config("{ terms = { sds = 1.0 }, csd = { guidance = 3.0 } }".into()),
            Source::Set("mvfc.gamma=0.5".into()),
            Source::Set("terms.gram=0.2".into()),
        ])
        .unwrap();
        assert_eq!(c.terms.to_string(), "sds=1,gram=0.2");
        assert_eq!(
            (c.csd.mode, c.csd.guidance, c.mvfc.gamma),
            (Mode::Sds, 3.0, 0.5)
        );
        assert_eq!(c.start.name(), "projection");
        let inline = Config::layered(&[Source::Config("{ preset = \"arf\", views = 2 }".into())]);
        assert_eq!(inline.unwrap().start.name(), "projection");
    }

    #[test]
    fn unknown_keys_bad_values_and_contradictions_are_named() {
        let e = |l: Source| Config::layered(&[l]).unwrap_err().to_string();
        assert!(e(Source::Set("guidance=1".into())).contains("`guidance`"));
        assert!(e(Source::Set("csd.guidanc=1".into())).contains("csd.guidanc"));
        assert!(e(Source::Set("start=paint".into())).contains("start=paint"));
        assert!(e(Source::Config("{ view = 2 }".into())).contains("view"));
        assert!(e(Source::Preset("arff".into())).contains("paper, arf"));
        assert!(e(Source::Set("strength=2".into())).contains("strength"));
        assert!(e(Source::Set("prior= ".into())).contains("prior"));
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("c.toml");
        std::fs::write(&p, "[mvfc]\ngama = 1.0\n").unwrap();
        let msg = e(Source::Config(p.display().to_string()));
        assert!(msg.contains("c.toml") && msg.contains("gama"), "{msg}");
        let both = Config::layered(&[
            Source::Preset("arf".into()),
            Source::Set("preserve_color=true".into()),
        ]);
        assert!(both.unwrap_err().to_string().contains("choose one"));
    }

    #[test]
    fn help_lists_every_key_with_its_doc() {
        let h = Config::help();
        for key in [
            "terms",
            "start",
            "finish",
            "csd.guidance",
            "mvfc.gamma",
            "texture.views",
        ] {
            assert!(h.contains(&format!("  {key} ")), "{key}: {h}");
        }
        assert!(h.contains("[default: csd=1]") && h.contains("Adjacent views per iteration"));
        // The registries, each from its list (test-only entries included).
        for entry in [
            "tv: total variation",
            "patches (finish; [synthesis])",
            "test-grey",
        ] {
            assert!(h.contains(entry), "{entry}: {h}");
        }
        for part in crate::ends::patches::PARTS {
            assert!(
                h.contains(&format!("          {}", part.name)),
                "{}",
                part.name
            );
        }
    }

    /// Every table of the configuration is a section of [`SECTIONS`] (or `terms`), and
    /// every section a table: adding a section's field without its line fails here.
    #[test]
    fn the_sections_list_is_the_configurations_tables() {
        let t = toml::Table::try_from(Config::default()).unwrap();
        let mut tables: Vec<&str> = t
            .iter()
            .filter(|(k, v)| v.is_table() && *k != "terms")
            .map(|(k, _)| k.as_str())
            .collect();
        tables.sort_unstable();
        let mut listed: Vec<&str> = SECTIONS.iter().map(|s| s.name).collect();
        listed.sort_unstable();
        assert_eq!(tables, listed);
    }

    /// Each section's ranges are checked from the list: a style of no pixels is refused
    /// by name, like a guide weight below 0.
    #[test]
    fn every_sections_ranges_are_checked() {
        for bad in [
            "texture.style_size=0",
            "synthesis.control=-1",
            "mvfc.gamma=2",
        ] {
            let e = Config::layered(&[Source::Set(bad.into())])
                .unwrap_err()
                .to_string();
            let field = bad.split(['.', '=']).nth(1).unwrap();
            assert!(e.contains(field), "{bad}: {e}");
        }
    }

    /// A test-only end, added as one file and one line of the registry
    /// (src/ends/test_grey.rs), is a finish the configuration takes by name.
    #[test]
    fn a_new_end_is_one_file_and_one_line() {
        let c = Config::layered(&[Source::Set("finish=test-grey".into())]).unwrap();
        assert_eq!(c.finish.name(), "test-grey");
        let e = Config::layered(&[Source::Set("start=test-grey".into())]).unwrap_err();
        assert!(e.to_string().contains("scene, colour, projection"), "{e}");
    }
}

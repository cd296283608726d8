//! The colour step's loss as a weighted list of terms (the shape of threestudio's
//! systems: a loss is a sum of named, weighted terms, each its own module returning its
//! loss and gradient). The configuration's `terms` ([`Terms`], e.g.
//! `csd=1,nnfm=1,gram=0.1`) names them:
//!
//! | term | what | module |
//! |---|---|---|
//! | `csd`, `sds`, `dds`, `csd-no-neg` | the prior's distillation term (FantasyStyle Sec. 4, CSD; at most one): the whole window's views batched through the prior give the targets, and per view the colour loss against them ([`PriorTerm`]; [`crate::csd`], [`crate::distill::step`]) | here |
//! | `nnfm` | ARF's nearest-neighbour feature matching of the object's VGG16 relu3 features to the style's (Zhang et al. 2022, Eq. 1) | [`texture`], [`nnfm`] |
//! | `gram` | Gram matrices of the object's VGG16 relu1_2/relu2_2 features against the style's (Gatys et al. 2016, Eq. 3-5) | [`texture`] |
//! | `tv` | total variation of the object's colours (Johnson et al. 2016's smoothness regulariser), a [`ViewTerm`] | [`tv`] |
//!
//! The registry is [`TERMS`]: a term's name, its role (the prior's, a VGG statistic, or
//! a [`ViewTerm`] of its own) and its help. A new term is one new file here and one line
//! of [`TERMS`]; the configuration, `--terms`, `--set terms.NAME=W` and `distill --help`
//! take it from there.
//!
//! Only the prior's term is FantasyStyle; `nnfm` and `gram` are texture terms added
//! because the CPU stylizer prior cannot carry a style's motifs on its own (the `arf`
//! preset; docs/texture-term.md). The VGG terms share one forward and one backward
//! pass per view ([`texture::TextureTerm`]), so they are one module with a weight per
//! statistic. Per view, the colour step's gradient at the render is the prior term's
//! (zero without one), plus the texture terms', plus the view terms', in that order
//! ([`crate::distill::step::colour_step`]).

pub mod nnfm;
pub mod texture;
pub mod tv;

use crate::csd::Mode;
use crate::{Error, Result};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use texture::{Statistic, TextureLoss};

/// What a term is to the colour step.
#[derive(Debug, Clone, Copy)]
pub enum Role {
    /// The prior's distillation term with its CSD mode (at most one is on): the targets
    /// come from the prior's change, and per view the colour loss against them
    /// ([`PriorTerm`]).
    Prior(Mode),
    /// A VGG texture statistic: the VGG terms share one forward and one backward pass per
    /// view ([`texture::TextureTerm`]).
    Texture(TextureLoss),
    /// A loss of its own on each view's render ([`ViewTerm`]), made by this function.
    View(fn() -> Box<dyn ViewTerm>),
}

/// One term of the colour step's loss: its name in the configuration, its role, and a
/// line of help.
#[derive(Debug, Clone, Copy)]
pub struct TermKind {
    pub name: &'static str,
    pub role: Role,
    pub help: &'static str,
}

/// The terms, in the order their gradients are summed per view (the prior's, the VGG
/// statistics', then the view terms'). A new term is one file of this module and one
/// line here.
#[rustfmt::skip]
pub const TERMS: &[TermKind] = &[
    TermKind { name: "csd", role: Role::Prior(Mode::Csd), help: "the prior's CSD (FantasyStyle Sec. 4)" },
    TermKind { name: "sds", role: Role::Prior(Mode::Sds), help: "the prior's score distillation (DreamFusion)" },
    TermKind { name: "dds", role: Role::Prior(Mode::Dds), help: "the prior's delta denoising score" },
    TermKind { name: "csd-no-neg", role: Role::Prior(Mode::CsdNoNeg), help: "CSD without its negative (content) branch" },
    TermKind { name: "nnfm", role: Role::Texture(TextureLoss::Nnfm), help: "ARF's nearest-neighbour feature matching, VGG16 relu3 (not FantasyStyle)" },
    TermKind { name: "gram", role: Role::Texture(TextureLoss::Gram), help: "Gram matrices of VGG16 relu1_2/relu2_2 (not FantasyStyle)" },
    TermKind { name: "tv", role: Role::View(tv::make), help: "total variation of the object's colours (smoothness; not FantasyStyle)" },
];

/// Most terms [`TERMS`] may hold (the weights are a fixed array, so [`Terms`] is `Copy`).
const MAX_TERMS: usize = 16;
const _: () = assert!(TERMS.len() <= MAX_TERMS);

/// A term of its own on each view's render (a [`Role::View`] term).
pub trait ViewTerm: std::fmt::Debug + Send + Sync {
    /// `(loss, dL/drender)` of render `rgb` `[H, W, 3]`, whose object coverage (the
    /// source views' alpha) is `alpha` `[H, W]`, at weight 1.
    fn view(&self, rgb: &[f32], alpha: &[f32], h: usize, w: usize) -> (f64, Vec<f32>);
}

/// The terms of the colour step's loss and their weights (0 = off), one per entry of
/// [`TERMS`]. At most one of the prior's terms (`csd`, `sds`, `dds`, `csd-no-neg`: the
/// distillation gradient). In a file: a table of the terms that are on,
/// `terms = { csd = 1.0, gram = 0.1 }`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Terms {
    weights: [f32; MAX_TERMS],
}

impl Terms {
    /// Parse `NAME=WEIGHT,...` (a name alone: weight 1), e.g. `csd=1,nnfm=1,gram=0.1`.
    pub fn parse(s: &str) -> std::result::Result<Terms, String> {
        let mut t = Terms::default();
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (name, w) = match part.split_once('=') {
                Some((n, w)) => (n.trim(), w.trim()),
                None => (part, "1"),
            };
            let w: f32 = w
                .parse()
                .map_err(|_| format!("`{part}`: the weight `{w}` is not a number"))?;
            *t.weight_mut(name)? = w;
        }
        Ok(t)
    }

    /// The prior's term `mode` alone, at weight 1.
    pub fn prior_only(mode: Mode) -> Terms {
        let mut t = Terms::default();
        if let Some(i) = TERMS
            .iter()
            .position(|k| matches!(k.role, Role::Prior(m) if m == mode))
        {
            t.weights[i] = 1.0;
        }
        t
    }

    /// The registry's name of term `name` (`csd_no_neg`, as a key may spell it, is
    /// `csd-no-neg`).
    pub fn canonical(name: &str) -> std::result::Result<&'static str, String> {
        let want = name.replace('_', "-");
        match TERMS.iter().find(|k| k.name == want) {
            Some(k) => Ok(k.name),
            None => Err(format!(
                "unknown term `{name}`; the terms: {} (the prior's, one at most: {})",
                TERMS.iter().map(|k| k.name).collect::<Vec<_>>().join(", "),
                TERMS
                    .iter()
                    .filter(|k| matches!(k.role, Role::Prior(_)))
                    .map(|k| k.name)
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
        }
    }

    /// The weight of term `name`, for setting it.
    pub fn weight_mut(&mut self, name: &str) -> std::result::Result<&mut f32, String> {
        let name = Self::canonical(name)?;
        let i = TERMS
            .iter()
            .position(|k| k.name == name)
            .expect("canonical");
        Ok(&mut self.weights[i])
    }

    /// The weight of term `name` (0 for an unknown one).
    pub fn weight(&self, name: &str) -> f32 {
        TERMS
            .iter()
            .position(|k| k.name == name)
            .map_or(0.0, |i| self.weights[i])
    }

    /// Each term of the registry with its weight, in [`TERMS`]' order.
    fn named(&self) -> impl Iterator<Item = (&'static TermKind, f32)> + '_ {
        TERMS.iter().zip(self.weights)
    }

    /// Refuse a negative or non-finite weight and two of the prior's terms.
    pub fn validate(&self) -> Result<()> {
        if let Some((k, w)) = self.named().find(|(_, w)| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::param(format!(
                "terms: the weight of {} must be finite and >= 0, got {w}",
                k.name
            )));
        }
        let prior: Vec<&str> = self
            .named()
            .filter(|(k, w)| matches!(k.role, Role::Prior(_)) && *w > 0.0)
            .map(|(k, _)| k.name)
            .collect();
        if prior.len() > 1 {
            return Err(Error::param(format!(
                "terms: {} are all the prior's distillation term; choose one",
                prior.join(" and ")
            )));
        }
        Ok(())
    }

    /// The prior's term: its distillation gradient and weight (`None`: no prior term).
    pub fn prior(&self) -> Option<(Mode, f32)> {
        self.named().find_map(|(k, w)| match k.role {
            Role::Prior(m) if w > 0.0 => Some((m, w)),
            _ => None,
        })
    }

    /// The VGG texture statistics with a weight, in the order their gradients are summed
    /// (nnfm, then gram), each at its default layers or at `layers` (only with one
    /// statistic).
    pub fn statistics(&self, layers: &[crate::vgg::Layer]) -> Result<Vec<Statistic>> {
        let on: Vec<(TextureLoss, f32)> = self
            .named()
            .filter_map(|(k, w)| match k.role {
                Role::Texture(loss) if w > 0.0 => Some((loss, w)),
                _ => None,
            })
            .collect();
        if !layers.is_empty() && on.len() != 1 {
            return Err(Error::param(format!(
                "texture.layers goes with one VGG term (nnfm or gram), got {}; each then \
                 uses its default layers",
                on.len()
            )));
        }
        Ok(on
            .into_iter()
            .map(|(loss, weight)| Statistic {
                loss,
                layers: if layers.is_empty() {
                    loss.default_layers()
                } else {
                    layers.to_vec()
                },
                weight,
            })
            .collect())
    }

    /// The view terms that are on, made, with their weights.
    pub fn view_terms(&self) -> Vec<(f32, Box<dyn ViewTerm>)> {
        self.named()
            .filter_map(|(k, w)| match k.role {
                Role::View(make) if w > 0.0 => Some((w, make())),
                _ => None,
            })
            .collect()
    }

    /// Every term with its help, for `--help`.
    pub fn help() -> String {
        TERMS
            .iter()
            .map(|k| format!("          {}: {}\n", k.name, k.help))
            .collect()
    }
}

impl Serialize for Terms {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let on: Vec<(&str, f32)> = self
            .named()
            .filter(|(_, w)| *w != 0.0)
            .map(|(k, w)| (k.name, w))
            .collect();
        let mut m = s.serialize_map(Some(on.len()))?;
        for (n, w) in on {
            m.serialize_entry(n, &w)?;
        }
        m.end()
    }
}

impl<'de> Deserialize<'de> for Terms {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let m = <std::collections::BTreeMap<String, f32>>::deserialize(d)?;
        let mut t = Terms::default();
        for (name, w) in m {
            *t.weight_mut(&name).map_err(serde::de::Error::custom)? = w;
        }
        Ok(t)
    }
}

impl std::fmt::Display for Terms {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let on: Vec<String> = self
            .named()
            .filter(|(_, w)| *w != 0.0)
            .map(|(k, w)| format!("{}={w}", k.name))
            .collect();
        if on.is_empty() {
            write!(f, "none")
        } else {
            write!(f, "{}", on.join(","))
        }
    }
}

/// The colour step's loss against the prior's targets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ColourLoss {
    /// L1: each pixel passes only the sign of the change the prior asks for.
    L1,
    /// Half the squared distance: dL/drender = render - target = -a (c' - c), the
    /// alpha-weighted image change itself, so the render's vector-Jacobian product
    /// carries the paper's gradient w(t) (Phi_tgt - Phi_src) with its magnitude (the
    /// MSE-to-a-detached-target form of score distillation).
    L2,
}

crate::params::serde_by_value_name!(ColourLoss);

/// The prior's term per view: the colour loss of a render against its target (which the
/// prior's change made, [`crate::distill::step::targets`]), times the term's weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorTerm {
    pub loss: ColourLoss,
    pub weight: f32,
}

impl PriorTerm {
    /// `(loss, dL/drender)` of render `rgb` `[H, W, 3]` against `target`: L2 (half the
    /// squared distance) or L1 (with no D-SSIM: where the target equals the render its
    /// gradient would be rounding noise, which Adam turns into full-size steps), scaled by
    /// the weight (the weight-1 gradient is the loss's own, bit for bit).
    pub fn view(&self, rgb: &[f32], target: &[f32], h: usize, w: usize) -> (f64, Vec<f32>) {
        let (l, mut g) = match self.loss {
            ColourLoss::L1 => {
                let lp = crate::optim::LossParams { ssim_weight: 0.0 };
                let (l, g) = crate::optim::loss_and_grad(rgb, target, None, h, w, lp);
                (l as f64, g)
            }
            ColourLoss::L2 => half_squared_distance(rgb, target),
        };
        if self.weight != 1.0 {
            g.iter_mut().for_each(|v| *v *= self.weight);
            return (l * self.weight as f64, g);
        }
        (l, g)
    }
}

/// `(sum 0.5 (x - y)^2 / n, (x - y) / n)` over the `n` values of a view: the gradient is
/// the difference itself, scaled like the L1 loss's (1/n per value).
pub fn half_squared_distance(render: &[f32], target: &[f32]) -> (f64, Vec<f32>) {
    let n = render.len().max(1) as f32;
    let mut loss = 0.0f64;
    let g = render
        .iter()
        .zip(target)
        .map(|(x, y)| {
            let d = x - y;
            loss += 0.5 * (d as f64) * (d as f64);
            d / n
        })
        .collect();
    (loss / n as f64, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terms_parse_print_and_refuse_two_prior_terms() {
        let t = Terms::parse("csd=1, nnfm, gram=0.1").unwrap();
        assert_eq!(
            (t.weight("csd"), t.weight("nnfm"), t.weight("gram")),
            (1.0, 1.0, 0.1)
        );
        assert_eq!(t.to_string(), "csd=1,nnfm=1,gram=0.1");
        assert_eq!(t.prior(), Some((Mode::Csd, 1.0)));
        assert_eq!(
            Terms::parse("sds=2").unwrap().prior(),
            Some((Mode::Sds, 2.0))
        );
        assert_eq!(Terms::parse("gram").unwrap().prior(), None);
        assert!(
            Terms::parse("vgg=1")
                .unwrap_err()
                .contains("unknown term `vgg`")
        );
        assert!(Terms::parse("csd=x").unwrap_err().contains("not a number"));
        let two = Terms::parse("csd,sds").unwrap().validate().unwrap_err();
        assert!(two.to_string().contains("csd and sds"), "{two}");
        assert!(Terms::parse("gram=-1").unwrap().validate().is_err());
        let s = Terms::parse("gram=0.1,nnfm=1")
            .unwrap()
            .statistics(&[])
            .unwrap();
        assert_eq!(
            s.iter().map(|s| s.loss).collect::<Vec<_>>(),
            [TextureLoss::Nnfm, TextureLoss::Gram]
        );
        let toml = toml::to_string(&Terms::parse("csd-no-neg=1,gram=0.5").unwrap()).unwrap();
        assert_eq!(
            toml::from_str::<Terms>(&toml).unwrap().weight("csd-no-neg"),
            1.0
        );
        assert!(toml::from_str::<Terms>("vgg = 1.0").is_err());
        assert!(Terms::parse("csd_no_neg").unwrap().prior() == Some((Mode::CsdNoNeg, 1.0)));
        assert!(Terms::help().contains("tv: total variation"));
    }

    /// A view term is made from the registry with its weight, printed in registry
    /// order, and absent when its weight is 0.
    #[test]
    fn view_terms_come_from_the_registry() {
        let t = Terms::parse("tv=0.5,csd").unwrap();
        assert_eq!(t.to_string(), "csd=1,tv=0.5");
        let v = t.view_terms();
        assert_eq!((v.len(), v[0].0), (1, 0.5));
        assert!(Terms::parse("csd").unwrap().view_terms().is_empty());
        let back: Terms = toml::from_str(&toml::to_string(&t).unwrap()).unwrap();
        assert_eq!(back, t);
    }

    #[test]
    fn a_prior_term_of_weight_one_is_the_loss_itself() {
        let (r, t) = (vec![0.5f32, 0.25, 1.0], vec![0.0f32, 0.5, 1.0]);
        let one = PriorTerm {
            loss: ColourLoss::L2,
            weight: 1.0,
        }
        .view(&r, &t, 1, 1);
        assert_eq!(one, half_squared_distance(&r, &t));
        let two = PriorTerm {
            loss: ColourLoss::L2,
            weight: 2.0,
        }
        .view(&r, &t, 1, 1);
        assert_eq!(two.1, one.1.iter().map(|g| 2.0 * g).collect::<Vec<_>>());
    }
}

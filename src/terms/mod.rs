//! The colour step's loss as a weighted list of terms (the shape of threestudio's
//! systems: a loss is a sum of named, weighted terms, each its own module returning its
//! loss and gradient). The configuration's `terms` ([`Terms`], e.g.
//! `csd=1,nnfm=1,gram=0.1`) names them:
//!
//! | term | what | module |
//! |---|---|---|
//! | `csd`, `sds`, `dds`, `csd-no-neg` | the prior's distillation term (FantasyStyle Sec. 4, CSD; at most one): the whole window's views batched through the prior give the targets, and per view the colour loss against them ([`PriorTerm`]; [`crate::csd`], [`super::step`]) | here |
//! | `nnfm` | ARF's nearest-neighbour feature matching of the object's VGG16 relu3 features to the style's (Zhang et al. 2022, Eq. 1) | [`texture`], [`nnfm`] |
//! | `gram` | Gram matrices of the object's VGG16 relu1_2/relu2_2 features against the style's (Gatys et al. 2016, Eq. 3-5) | [`texture`] |
//!
//! Only the prior's term is FantasyStyle; `nnfm` and `gram` are texture terms added
//! because the CPU stylizer prior cannot carry a style's motifs on its own (the `arf`
//! preset; docs/texture-term.md). The VGG terms share one forward and one backward
//! pass per view ([`texture::TextureTerm`]), so they are one module with a weight per
//! statistic. Per view, the colour step's gradient at the render is the prior term's
//! (zero without one) plus the texture terms', in that order ([`super::step::colour_step`]).

pub mod nnfm;
pub mod texture;

use crate::csd::Mode;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use texture::{Statistic, TextureLoss};

/// The terms of the colour step's loss and their weights (0 = off). At most one of the
/// prior's terms (`csd`, `sds`, `dds`, `csd-no-neg`: the distillation gradient).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Terms {
    #[serde(skip_serializing_if = "is_zero")]
    pub csd: f32,
    #[serde(skip_serializing_if = "is_zero")]
    pub sds: f32,
    #[serde(skip_serializing_if = "is_zero")]
    pub dds: f32,
    #[serde(rename = "csd-no-neg", skip_serializing_if = "is_zero")]
    pub csd_no_neg: f32,
    #[serde(skip_serializing_if = "is_zero")]
    pub nnfm: f32,
    #[serde(skip_serializing_if = "is_zero")]
    pub gram: f32,
}

fn is_zero(w: &f32) -> bool {
    *w == 0.0
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
        *match mode {
            Mode::Csd => &mut t.csd,
            Mode::Sds => &mut t.sds,
            Mode::Dds => &mut t.dds,
            Mode::CsdNoNeg => &mut t.csd_no_neg,
        } = 1.0;
        t
    }

    /// The weight of term `name`, for setting it.
    pub fn weight_mut(&mut self, name: &str) -> std::result::Result<&mut f32, String> {
        Ok(match name {
            "csd" => &mut self.csd,
            "sds" => &mut self.sds,
            "dds" => &mut self.dds,
            "csd-no-neg" | "csd_no_neg" => &mut self.csd_no_neg,
            "nnfm" => &mut self.nnfm,
            "gram" => &mut self.gram,
            _ => {
                return Err(format!(
                    "unknown term `{name}`; the terms: csd, sds, dds, csd-no-neg (the prior's, \
                     one at most), nnfm, gram"
                ));
            }
        })
    }

    /// Each term's name (as the configuration spells it) and weight.
    fn named(&self) -> [(&'static str, f32); 6] {
        [
            ("csd", self.csd),
            ("sds", self.sds),
            ("dds", self.dds),
            ("csd-no-neg", self.csd_no_neg),
            ("nnfm", self.nnfm),
            ("gram", self.gram),
        ]
    }

    /// Refuse a negative or non-finite weight and two of the prior's terms.
    pub fn validate(&self) -> Result<()> {
        let all = self.named();
        if let Some((n, w)) = all.iter().find(|(_, w)| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::param(format!(
                "terms: the weight of {n} must be finite and >= 0, got {w}"
            )));
        }
        let prior: Vec<&str> = all[..4]
            .iter()
            .filter(|(_, w)| *w > 0.0)
            .map(|(n, _)| *n)
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
        [
            (Mode::Csd, self.csd),
            (Mode::Sds, self.sds),
            (Mode::Dds, self.dds),
            (Mode::CsdNoNeg, self.csd_no_neg),
        ]
        .into_iter()
        .find(|(_, w)| *w > 0.0)
    }

    /// The VGG texture statistics with a weight, in the order their gradients are summed
    /// (nnfm, then gram), each at its default layers or at `layers` (only with one
    /// statistic).
    pub fn statistics(&self, layers: &[crate::vgg::Layer]) -> Result<Vec<Statistic>> {
        let on: Vec<(TextureLoss, f32)> = [
            (TextureLoss::Nnfm, self.nnfm),
            (TextureLoss::Gram, self.gram),
        ]
        .into_iter()
        .filter(|(_, w)| *w > 0.0)
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
}

impl std::fmt::Display for Terms {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let all = self.named();
        let on: Vec<String> = all
            .iter()
            .filter(|(_, w)| *w != 0.0)
            .map(|(n, w)| format!("{n}={w}"))
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
/// prior's change made, [`super::step::targets`]), times the term's weight.
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
        assert_eq!((t.csd, t.nnfm, t.gram), (1.0, 1.0, 0.1));
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
        assert_eq!(toml::from_str::<Terms>(&toml).unwrap().csd_no_neg, 1.0);
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

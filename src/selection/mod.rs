//! Selections: a weight in [0, 1] per Gaussian of one scene, saying which Gaussians a
//! stylization may change and how much (StylizedGS's region masks, StyleSplat's
//! per-object styles, SuperSplat's box and sphere selections, as one type).
//!
//! The loop honours a selection by scaling each Gaussian's colour update by its weight
//! ([`crate::optim::ColourFit::set_weights`]): a Gaussian of weight 0 keeps every byte of
//! its colours, one of weight 1 moves as without a selection. The prior and the terms
//! still see whole views, so the style meets a region's boundary as it would anyway;
//! only the selected Gaussians follow. Whatever a run's start or finish does to the
//! colours is held to the same rule by [`Selection::blend`].
//!
//! A selection is written as a `selection` artifact (`weights.npy` `[N]`, read and
//! written by [`crate::artifacts::read_selection`] and
//! [`crate::artifacts::write_selection`]).
//!
//! Selections are made from [`SOURCES`] (`KIND:SPEC`, parsed by [`parse_source`]): the
//! shapes of [`shapes`] (box, ellipsoid, half-space around the Gaussians' centres) and
//! masks drawn on views lifted in closed form ([`lift`], FlashSplat, ECCV 2024; the
//! Gaussians the views show only behind other surfaces labelled by [`hidden`]); [`ops`]
//! combines them (union, intersection, complement). A new source is one new file here
//! and one line of [`SOURCES`].

use crate::{Error, Result, Scene};
use std::path::Path;

pub mod hidden;
pub mod lift;
pub mod ops;
pub mod shapes;

/// What every source may need besides its own spec: the cameras masks were drawn on and
/// how masks are lifted.
#[derive(Debug, Clone, Default)]
pub struct Context {
    /// A camera spec (`orbit:N`, a camera file or directory, a views artifact).
    pub cameras: Option<String>,
    pub lift: lift::LiftOptions,
}

/// A selection source, parsed from its spec.
pub trait Make: std::fmt::Debug + Send + Sync {
    /// The selection of `scene`.
    fn make(&self, scene: &Scene, ctx: &Context) -> Result<Selection>;
    /// What it was made from, for the artifact's meta.
    fn describe(&self, ctx: &Context) -> serde_json::Value;
}

impl Make for shapes::Shape {
    fn make(&self, scene: &Scene, _: &Context) -> Result<Selection> {
        Ok(self.select(scene))
    }
    fn describe(&self, _: &Context) -> serde_json::Value {
        self.to_json()
    }
}

/// One kind of source: its name (the `KIND` of `KIND:SPEC`), its spec's syntax, its
/// parser.
pub struct SourceKind {
    pub name: &'static str,
    pub syntax: &'static str,
    pub parse: fn(&str) -> Result<Box<dyn Make>>,
}

fn boxed(s: Result<shapes::Shape>) -> Result<Box<dyn Make>> {
    Ok(Box::new(s?))
}

/// The registry of sources, one line each.
#[rustfmt::skip]
pub const SOURCES: &[SourceKind] = &[
    SourceKind { name: "box", syntax: "MINX,MINY,MINZ,MAXX,MAXY,MAXZ", parse: |s| boxed(shapes::Shape::parse_box(s)) },
    SourceKind { name: "ellipsoid", syntax: "CX,CY,CZ,RX,RY,RZ", parse: |s| boxed(shapes::Shape::parse_ellipsoid(s)) },
    SourceKind { name: "half-space", syntax: "NX,NY,NZ,D (n . p >= d)", parse: |s| boxed(shapes::Shape::parse_half_space(s)) },
    SourceKind { name: "masks", syntax: "DIR (a PNG per camera, named after it; --cameras)", parse: lift::MaskSource::parse },
];

/// Parse `KIND:SPEC` through [`SOURCES`].
pub fn parse_source(s: &str) -> Result<Box<dyn Make>> {
    let (kind, spec) = s.split_once(':').unwrap_or((s, ""));
    match SOURCES.iter().find(|k| k.name == kind) {
        Some(k) => (k.parse)(spec),
        None => {
            let known: Vec<String> = SOURCES
                .iter()
                .map(|k| format!("{}:{}", k.name, k.syntax))
                .collect();
            Err(Error::param(format!(
                "selection source `{s}`: expected one of {}",
                known.join("; ")
            )))
        }
    }
}

/// A weight in [0, 1] per Gaussian of one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// One weight per Gaussian, in the scene's order.
    pub weights: Vec<f32>,
}

impl Selection {
    /// A selection of `weights`, each checked to be finite and in [0, 1] (`from` names
    /// the file in errors).
    pub fn new(weights: Vec<f32>, from: &Path) -> Result<Selection> {
        if let Some((i, w)) = weights
            .iter()
            .enumerate()
            .find(|(_, w)| !(w.is_finite() && (0.0..=1.0).contains(*w)))
        {
            return Err(Error::input(
                from,
                format!("weight {w} of Gaussian {i} is outside [0, 1]"),
            ));
        }
        Ok(Selection { weights })
    }

    /// Every Gaussian of a scene of `n`, fully (weight 1).
    pub fn all(n: usize) -> Selection {
        Selection {
            weights: vec![1.0; n],
        }
    }

    /// Number of Gaussians the selection covers (selected or not).
    pub fn len(&self) -> usize {
        self.weights.len()
    }

    pub fn is_empty(&self) -> bool {
        self.weights.is_empty()
    }

    /// Gaussians with a weight above zero.
    pub fn selected(&self) -> usize {
        self.weights.iter().filter(|&&w| w > 0.0).count()
    }

    /// An error naming `from` unless the selection is of a scene of `n` Gaussians and
    /// selects at least one.
    pub fn check_for(&self, n: usize, from: &Path) -> Result<()> {
        if self.len() != n {
            return Err(Error::input(
                from,
                format!(
                    "selection of {} Gaussians, but the scene has {n} (a selection belongs to \
                     the scene it was made on; make it after any split)",
                    self.len()
                ),
            ));
        }
        if self.selected() == 0 {
            return Err(Error::input(
                from,
                "the selection is empty (every weight is 0)",
            ));
        }
        Ok(())
    }

    /// Axis-aligned bounds of the centres of the selected Gaussians (weight > 0) of
    /// `scene` (empty when none is).
    pub fn bounds(&self, scene: &Scene) -> crate::geometry::Bounds {
        crate::geometry::Bounds::of_points(
            scene
                .positions
                .iter()
                .zip(&self.weights)
                .filter(|(_, w)| **w > 0.0)
                .map(|(p, _)| p),
        )
    }

    /// `updated`'s colours where the weight is 1, `original`'s bit for bit where it is 0,
    /// `original + w (updated - original)` between; the geometry is `updated`'s (which
    /// must be `original`'s: a selection changes colours only).
    pub fn blend(&self, original: &Scene, updated: &Scene) -> Result<Scene> {
        let n = original.len();
        if updated.len() != n || self.len() != n || updated.sh_degree != original.sh_degree {
            return Err(Error::param(format!(
                "selection blend: {} weights, {n} and {} Gaussians (SH degree {} and {})",
                self.len(),
                updated.len(),
                original.sh_degree,
                updated.sh_degree
            )));
        }
        let k = 3 * original.rest_per_channel();
        let mut out = updated.clone();
        for (i, &w) in self.weights.iter().enumerate() {
            if w == 1.0 {
                continue;
            }
            let lerp = |a: f32, b: f32| if w == 0.0 { a } else { a + w * (b - a) };
            for c in 0..3 {
                out.sh_dc[i][c] = lerp(original.sh_dc[i][c], updated.sh_dc[i][c]);
            }
            for j in i * k..(i + 1) * k {
                out.sh_rest[j] = lerp(original.sh_rest[j], updated.sh_rest[j]);
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_outside_the_unit_interval_are_refused_with_the_file() {
        let p = Path::new("sel/weights.npy");
        for bad in [-0.1f32, 1.5, f32::NAN] {
            let e = Selection::new(vec![0.0, bad], p).unwrap_err().to_string();
            assert!(
                e.contains("sel/weights.npy") && e.contains("Gaussian 1"),
                "{e}"
            );
        }
        assert!(Selection::new(vec![0.0, 1.0, 0.25], p).is_ok());
    }

    #[test]
    fn an_empty_or_mismatched_selection_is_an_error() {
        let p = Path::new("s");
        let none = Selection::new(vec![0.0; 3], p).unwrap();
        assert!(
            none.check_for(3, p)
                .unwrap_err()
                .to_string()
                .contains("empty")
        );
        let some = Selection::new(vec![0.0, 1.0, 0.0], p).unwrap();
        assert!(some.check_for(4, p).unwrap_err().to_string().contains("4"));
        assert!(some.check_for(3, p).is_ok());
    }

    #[test]
    fn blend_keeps_weight_zero_bit_for_bit_and_interpolates_between() {
        let a = crate::sample::sample_scene(1);
        let mut b = a.clone();
        for c in b.sh_dc.iter_mut() {
            *c = [c[0] + 0.3, c[1] - 0.2, c[2] + 0.1];
        }
        for r in b.sh_rest.iter_mut() {
            *r += 0.05;
        }
        let n = a.len();
        let w: Vec<f32> = (0..n).map(|i| [0.0, 1.0, 0.5][i % 3]).collect();
        let s = Selection::new(w, Path::new("s")).unwrap();
        let out = s.blend(&a, &b).unwrap();
        let k = 3 * a.rest_per_channel();
        for i in 0..n {
            let (want, from) = match i % 3 {
                0 => (&a, "original"),
                1 => (&b, "updated"),
                _ => {
                    let mid = a.sh_dc[i][0] + 0.5 * (b.sh_dc[i][0] - a.sh_dc[i][0]);
                    assert_eq!(out.sh_dc[i][0].to_bits(), mid.to_bits());
                    continue;
                }
            };
            assert_eq!(
                out.sh_dc[i].map(f32::to_bits),
                want.sh_dc[i].map(f32::to_bits),
                "{from}"
            );
            let r = |s: &Scene| {
                s.sh_rest[i * k..(i + 1) * k]
                    .iter()
                    .map(|x| x.to_bits())
                    .collect::<Vec<_>>()
            };
            assert_eq!(r(&out), r(want), "{from}");
        }
        assert_eq!(out.positions, a.positions);
    }
}

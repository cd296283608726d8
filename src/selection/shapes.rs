//! Shape selections: a box, an ellipsoid or a half-space in scene coordinates (the
//! volumes SuperSplat and other splat editors select with). A Gaussian is selected
//! (weight 1) iff its centre (`Scene::positions`) lies inside, boundary included; every
//! other Gaussian has weight 0. The shapes are axis-aligned in the scene's frame.
//!
//! Syntax (after `box:`, `ellipsoid:`, `half-space:` in [`super::Source::parse`]):
//! * `box:MINX,MINY,MINZ,MAXX,MAXY,MAXZ` (each min <= its max);
//! * `ellipsoid:CX,CY,CZ,RX,RY,RZ` (radii > 0): `sum ((p - c) / r)^2 <= 1`;
//! * `half-space:NX,NY,NZ,D` (n non-zero, not normalised): `n . p >= d`.

use super::Selection;
use crate::{Error, Result, Scene};
use glam::Vec3;

/// A volume in scene coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// Axis-aligned box `[min, max]`.
    Box { min: Vec3, max: Vec3 },
    /// Axis-aligned ellipsoid of centre `centre` and semi-axes `radii`.
    Ellipsoid { centre: Vec3, radii: Vec3 },
    /// `normal . p >= offset`.
    HalfSpace { normal: Vec3, offset: f32 },
}

/// `n` comma-separated finite numbers, or a parameter error naming `what`.
fn numbers(what: &str, spec: &str, n: usize) -> Result<Vec<f32>> {
    let v: Vec<f32> = spec
        .split(',')
        .map(|t| t.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| Error::param(format!("{what}:{spec}: not a list of numbers")))?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(Error::param(format!(
            "{what}:{spec}: expected {n} finite numbers, found {}",
            v.len()
        )));
    }
    Ok(v)
}

impl Shape {
    /// `box:MINX,MINY,MINZ,MAXX,MAXY,MAXZ` (the part after `box:`).
    pub fn parse_box(spec: &str) -> Result<Shape> {
        let v = numbers("box", spec, 6)?;
        let (min, max) = (Vec3::new(v[0], v[1], v[2]), Vec3::new(v[3], v[4], v[5]));
        if min.cmpgt(max).any() {
            return Err(Error::param(format!(
                "box:{spec}: a minimum corner coordinate is above the maximum's"
            )));
        }
        Ok(Shape::Box { min, max })
    }

    /// `ellipsoid:CX,CY,CZ,RX,RY,RZ` (the part after `ellipsoid:`).
    pub fn parse_ellipsoid(spec: &str) -> Result<Shape> {
        let v = numbers("ellipsoid", spec, 6)?;
        let radii = Vec3::new(v[3], v[4], v[5]);
        if radii.cmple(Vec3::ZERO).any() {
            return Err(Error::param(format!(
                "ellipsoid:{spec}: every radius must be > 0"
            )));
        }
        Ok(Shape::Ellipsoid {
            centre: Vec3::new(v[0], v[1], v[2]),
            radii,
        })
    }

    /// `half-space:NX,NY,NZ,D` (the part after `half-space:`).
    pub fn parse_half_space(spec: &str) -> Result<Shape> {
        let v = numbers("half-space", spec, 4)?;
        let normal = Vec3::new(v[0], v[1], v[2]);
        if normal == Vec3::ZERO {
            return Err(Error::param(format!(
                "half-space:{spec}: the normal must not be zero"
            )));
        }
        Ok(Shape::HalfSpace {
            normal,
            offset: v[3],
        })
    }

    /// Whether `p` lies inside (boundary included).
    pub fn contains(&self, p: [f32; 3]) -> bool {
        let p = Vec3::from_array(p);
        match *self {
            Shape::Box { min, max } => p.cmpge(min).all() && p.cmple(max).all(),
            Shape::Ellipsoid { centre, radii } => ((p - centre) / radii).length_squared() <= 1.0,
            Shape::HalfSpace { normal, offset } => normal.dot(p) >= offset,
        }
    }

    /// Weight 1 for the Gaussians of `scene` whose centre lies inside, 0 for the rest.
    pub fn select(&self, scene: &Scene) -> Selection {
        Selection {
            weights: scene
                .positions
                .iter()
                .map(|&p| if self.contains(p) { 1.0 } else { 0.0 })
                .collect(),
        }
    }

    /// The shape as JSON, for the artifact's meta.
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Shape::Box { min, max } => {
                serde_json::json!({"box": {"min": min.to_array(), "max": max.to_array()}})
            }
            Shape::Ellipsoid { centre, radii } => serde_json::json!({
                "ellipsoid": {"centre": centre.to_array(), "radii": radii.to_array()}
            }),
            Shape::HalfSpace { normal, offset } => serde_json::json!({
                "half-space": {"normal": normal.to_array(), "offset": offset}
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_select_the_centres_inside() {
        let scene = crate::sample::sample_scene(0);
        let b = Shape::parse_box("-0.1,-0.5,-0.2,0.6,-0.1,0.4").unwrap();
        let want = scene
            .positions
            .iter()
            .filter(|p| {
                (-0.1..=0.6).contains(&p[0])
                    && (-0.5..=-0.1).contains(&p[1])
                    && (-0.2..=0.4).contains(&p[2])
            })
            .count();
        let s = b.select(&scene);
        assert!(want > 100, "{want}");
        assert_eq!(s.selected(), want);
        // The sphere (centre (-0.42, -0.29, 0.12), radius 0.28) as an ellipsoid a bit larger.
        let e = Shape::parse_ellipsoid("-0.42,-0.29,0.12,0.285,0.285,0.285").unwrap();
        let sphere = crate::sample::sample_parts(0)
            .into_iter()
            .find(|(n, _)| *n == "sphere")
            .unwrap()
            .1;
        let s = e.select(&scene);
        assert!(sphere.clone().all(|i| s.weights[i] == 1.0));
        assert_eq!(s.selected(), sphere.len());
        // Above the ground (-y up): y <= -0.01 is -y >= 0.01.
        let h = Shape::parse_half_space("0,-1,0,0.01")
            .unwrap()
            .select(&scene);
        let above = scene.positions.iter().filter(|p| -p[1] >= 0.01).count();
        assert_eq!(h.selected(), above);
    }

    #[test]
    fn bad_shapes_are_parameter_errors() {
        for (f, spec, says) in [
            (
                Shape::parse_box as fn(&str) -> Result<Shape>,
                "0,0,0,1,1",
                "expected 6",
            ),
            (Shape::parse_box, "0,0,2,1,1,1", "above"),
            (Shape::parse_ellipsoid, "0,0,0,1,0,1", "radius"),
            (Shape::parse_half_space, "0,0,0,1", "normal"),
            (Shape::parse_half_space, "a,b,c,d", "numbers"),
            (Shape::parse_box, "0,0,0,1,1,inf", "finite"),
        ] {
            let e = f(spec).unwrap_err().to_string();
            assert!(e.contains(says), "{spec}: {e}");
        }
    }
}

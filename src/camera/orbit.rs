//! Generated orbit cameras: `orbit:N[,elev=DEG][,radius=R][,fov=DEG]`.
//!
//! N cameras on a circle around the centre `c` of the given bounds (a scene's: of the
//! Gaussian means), all looking at `c`. The scenes this project uses have their up axis along
//! **-y** (the OpenCV/COLMAP habit), so the circle lies in a plane of constant y and
//! "elevation toward up" moves cameras toward -y:
//!
//! `eye_i = c + r (cos(e) sin(a_i), -sin(e), -cos(e) cos(a_i))`, `a_i = 2 pi i / N`,
//!
//! so view 0 sits on the -z side looking toward +z. Image "down" (the camera's +y) is
//! world +y projected onto the image plane. Defaults (the reference case in
//! `../shared/TARGETS.md`): `r = 2.2 x` the largest extent of the bounds (max - min over
//! the axes; 1 if the scene is a single point), `e = 15` degrees, `fov = 50` degrees
//! horizontal (`fx = fy = (W/2) / tan(fov/2)`), principal point at the image centre.

use super::Camera;
use crate::geometry::{Bounds, DVec3, look_at_c2w, rows};
use crate::{Error, Result};

/// A parsed `orbit:` spec.
#[derive(Debug, Clone, PartialEq)]
pub struct OrbitSpec {
    pub n: usize,
    /// Elevation toward the scene's up axis (-y), degrees.
    pub elev_deg: f64,
    /// Distance from the centre; `None` = 2.2 x the largest extent.
    pub radius: Option<f64>,
    /// Horizontal field of view, degrees.
    pub fov_deg: f64,
}

impl OrbitSpec {
    /// Parse the part after `orbit:`.
    pub fn parse(s: &str) -> Result<OrbitSpec> {
        let bad = |r: String| Error::param(format!("camera spec `orbit:{s}`: {r}"));
        let mut parts = s.split(',');
        let n = parts.next().unwrap_or("").trim();
        let n: usize = n
            .parse()
            .map_err(|_| bad(format!("`{n}` is not a number of views")))?;
        if n == 0 || n > 100_000 {
            return Err(bad(format!("{n} views (expected 1..=100000)")));
        }
        let mut o = OrbitSpec {
            n,
            elev_deg: 15.0,
            radius: None,
            fov_deg: 50.0,
        };
        for p in parts {
            let (k, v) = p
                .split_once('=')
                .ok_or_else(|| bad(format!("`{p}` is not KEY=VALUE")))?;
            let v: f64 = v
                .trim()
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| bad(format!("`{v}` is not a finite number")))?;
            match k.trim() {
                "elev" if v.abs() < 90.0 => o.elev_deg = v,
                "radius" if v > 0.0 => o.radius = Some(v),
                "fov" if v > 0.0 && v < 180.0 => o.fov_deg = v,
                "elev" | "radius" | "fov" => {
                    return Err(bad(format!(
                        "{k}={v} out of range (elev in (-90, 90), radius > 0, fov in (0, 180))"
                    )));
                }
                _ => {
                    return Err(bad(format!(
                        "unknown key `{k}` (expected elev, radius or fov)"
                    )));
                }
            }
        }
        Ok(o)
    }
}

/// The orbit cameras around `bounds` at `width` x `height`.
pub fn orbit(o: &OrbitSpec, bounds: &Bounds, width: u32, height: u32) -> Result<Vec<Camera>> {
    if bounds.is_empty() {
        return Err(Error::param("cannot place an orbit around an empty scene"));
    }
    let c = bounds.center();
    let extent = bounds.largest_extent();
    let r = o
        .radius
        .unwrap_or(2.2 * if extent > 0.0 { extent } else { 1.0 });
    let e = o.elev_deg.to_radians();
    let f = 0.5 * width as f64 / (0.5 * o.fov_deg.to_radians()).tan();
    let intr = [f, f, 0.5 * width as f64, 0.5 * height as f64];
    Ok((0..o.n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / o.n as f64;
            let d = DVec3::new(e.cos() * a.sin(), -e.sin(), -e.cos() * a.cos());
            let eye = c + r * d;
            let c2w = look_at_c2w(eye, c, DVec3::Y);
            Camera::from_c2w(
                format!("orbit_{i:03}"),
                width,
                height,
                intr,
                rows(c2w),
                eye.to_array(),
            )
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn bounds() -> Bounds {
        Bounds::of_points(&[[-1.0, -0.5, 0.0], [1.0, 0.5, 0.4]])
    }

    #[test]
    fn parse_specs() {
        let o = OrbitSpec::parse("8,elev=30,radius=2.5,fov=40").unwrap();
        assert_eq!(
            (o.n, o.elev_deg, o.radius, o.fov_deg),
            (8, 30.0, Some(2.5), 40.0)
        );
        assert_eq!(OrbitSpec::parse("3").unwrap().elev_deg, 15.0);
        for bad in [
            "0",
            "x",
            "4,elev=95",
            "4,foo=1",
            "4,radius=-1",
            "4,fov",
            "4,fov=nan",
        ] {
            assert!(OrbitSpec::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn orbit_geometry_matches_the_definition() {
        let cams = orbit(&OrbitSpec::parse("4").unwrap(), &bounds(), 100, 80).unwrap();
        let c = [0.0f32, 0.0, 0.2];
        for (i, cam) in cams.iter().enumerate() {
            cam.validate(Path::new("orbit")).unwrap();
            // Looks at the centre: it projects to the principal point.
            let (uv, z) = cam.project(c);
            assert!(
                (uv[0] - 50.0).abs() < 1e-3 && (uv[1] - 40.0).abs() < 1e-3,
                "{uv:?}"
            );
            // Distance 2.2 x extent (2.0), elevated toward -y by 15 degrees.
            assert!((z - 4.4).abs() < 1e-4);
            let e = cam.center();
            let h = (4.4f32) * 15f32.to_radians().sin();
            assert!((e[1] + h).abs() < 1e-4, "view {i}: {e:?}");
            // A point above the centre (toward -y) appears above it in the image.
            let (up, _) = cam.project([0.0, -0.3, 0.2]);
            assert!(up[1] < 40.0);
            // 50-degree horizontal field of view.
            let f = 50.0 / (25f32.to_radians()).tan();
            assert!((cam.fx - f).abs() < 1e-3 && cam.fx == cam.fy);
        }
        // View 0 on the -z side, view 1 a quarter turn on (+x).
        assert!(cams[0].center()[2] < 0.0 && cams[1].center()[0] > 3.0);
    }
}

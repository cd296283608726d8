//! The camera path and the windows of adjacent views each iteration works on
//! (FantasyStyle Sec. 4: "render N adjacent views"; MVFC's view axis).
//!
//! Cameras are taken in file order as a path. The path is *closed* (an orbit) when its
//! last camera is about as close to its first as consecutive cameras are to each other:
//! `|c_last - c_0| <= 1.5 median_i |c_{i+1} - c_i|` over camera centres (at least three
//! cameras). Windows of a closed path may wrap around its end; windows of an open path
//! never do. A window is also told whether its ends are neighbours (the whole of a
//! closed path): only then may MVFC treat the view axis as circular
//! ([`crate::mvfc::mvfc_path`]).

use crate::Camera;
use crate::rng::Rng;

/// The cameras' order as a path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewPath {
    /// Number of cameras.
    pub len: usize,
    /// Whether the last camera is a neighbour of the first.
    pub closed: bool,
}

/// A run of adjacent views.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    /// Camera indices in path order.
    pub views: Vec<usize>,
    /// Whether the last view is a neighbour of the first (the window is a whole closed
    /// path), so the view axis is circular.
    pub circular: bool,
}

impl ViewPath {
    /// The path of `cameras` in their order (module docs for "closed").
    pub fn of(cameras: &[Camera]) -> ViewPath {
        let n = cameras.len();
        let centres: Vec<glam::DVec3> = cameras
            .iter()
            .map(|c| {
                let p = c.center();
                glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
            })
            .collect();
        let closed = n >= 3 && {
            let mut steps: Vec<f64> = centres.windows(2).map(|w| w[0].distance(w[1])).collect();
            steps.sort_by(f64::total_cmp);
            let median = steps[steps.len() / 2];
            median > 0.0 && centres[n - 1].distance(centres[0]) <= 1.5 * median
        };
        ViewPath { len: n, closed }
    }

    /// The window of `size` views (at most the path's length) starting at `start`.
    pub fn window(&self, start: usize, size: usize) -> Window {
        let size = size.clamp(1, self.len);
        let views = if self.closed {
            (0..size).map(|i| (start + i) % self.len).collect()
        } else {
            let s = start.min(self.len - size);
            (s..s + size).collect()
        };
        Window {
            views,
            circular: self.closed && size == self.len,
        }
    }

    /// A window of `size` views with a uniformly drawn start (every start on a closed
    /// path; every start that fits on an open one).
    pub fn draw(&self, rng: &mut Rng, size: usize) -> Window {
        let size = size.clamp(1, self.len);
        let starts = if self.closed {
            self.len
        } else {
            self.len - size + 1
        };
        let start = ((rng.uniform() * starts as f64) as usize).min(starts - 1);
        self.window(start, size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::load_cameras;

    fn orbit(n: usize) -> Vec<Camera> {
        let b = crate::geometry::Bounds::of_points(&[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]);
        load_cameras(&format!("orbit:{n}"), &b, 32, 32).unwrap()
    }

    #[test]
    fn an_orbit_is_closed_and_half_of_it_is_open() {
        let cams = orbit(12);
        assert!(ViewPath::of(&cams).closed);
        assert!(!ViewPath::of(&cams[..6]).closed);
        assert!(!ViewPath::of(&cams[..2]).closed);
    }

    #[test]
    fn windows_wrap_only_on_closed_paths() {
        let closed = ViewPath {
            len: 8,
            closed: true,
        };
        let open = ViewPath {
            len: 8,
            closed: false,
        };
        assert_eq!(closed.window(6, 4).views, [6, 7, 0, 1]);
        assert!(!closed.window(6, 4).circular);
        assert_eq!(open.window(6, 4).views, [4, 5, 6, 7]);
        assert!(closed.window(3, 8).circular && !open.window(0, 8).circular);
        assert_eq!(open.window(0, 20).views.len(), 8);
        let mut rng = Rng::new(1);
        let mut seen = [false; 8];
        for _ in 0..400 {
            let w = open.draw(&mut rng, 3);
            assert!(w.views.windows(2).all(|p| p[1] == p[0] + 1));
            seen[w.views[0]] = true;
        }
        assert_eq!(seen, [true, true, true, true, true, true, false, false]);
    }
}

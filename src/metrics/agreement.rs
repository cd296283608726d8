//! How much of the prior's *high-frequency* image change agrees across visits and views
//! (issue 21, item 2: "measure why texture is lost before fixing it").
//!
//! The colour step averages what the prior asks for over visits of a view and over the
//! views that see a surface (FantasyStyle Sec. 4: one optimiser over all iterations).
//! Texture (strokes, motifs) survives that averaging only where the asks agree; where they
//! are independent, the average of `k` of them shrinks like `1/sqrt(k)` and only the
//! low-frequency part (the palette) accumulates. This module measures the agreement:
//!
//! * the high-pass change of a view is `h = m (Delta - B(Delta))` with `Delta` the image
//!   change `[3, H, W]`, `m` the covered pixels (alpha > 0.5, [`ALPHA_MIN`]) and `B` a
//!   Gaussian blur of pixel std [`HF_SIGMA`] normalised over the covered pixels
//!   (`B(Delta) = G * (m Delta) / G * m`), so the fill around the object does not leak
//!   into the object's high pass at the silhouette;
//! * agreement is the cosine similarity `sum a b / sqrt(sum a^2 sum b^2)` of two high-pass
//!   changes over the pixels valid in both (1: the same strokes; about 0: independent
//!   ones; it is `None` when either side is all zero there);
//! * *revisit*: a view's high pass against the one of its previous visit (same pixels);
//! * *adjacent*: the high pass of view `j` warped into its path neighbour `i` by depth
//!   reprojection ([`crate::maths::warp`]: the source views' surface depth and the
//!   cameras; occluded, off-screen and uncovered pixels are masked) against `i`'s own.
//!
//! Over a window of views the sums are pooled (the cosine of the concatenated vectors), so
//! views with a larger change weigh more. The bilinear resampling of the warp blurs the
//! warped high pass a little, so even a perfectly consistent texture scores below 1 after
//! a sub-pixel warp: compare with the same measure on the refit baseline's per-view 2D
//! stylizations ([`adjacent_agreement_of_views`]), the ceiling of per-view stylization.

use crate::Camera;
use crate::imageio::Image;
use crate::maths::blur::gaussian_chw;
use crate::maths::warp::{ALPHA_MIN, surface_depth, warp_into};
use ndarray::{Array3, ArrayView3, ArrayView4, Axis, s};

/// Pixel std of the blur whose residual is the "high-frequency" change.
pub const HF_SIGMA: f32 = 2.0;

/// Pooled cosine similarity: running sums of `a b`, `a^2`, `b^2`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Cosine {
    pub dot: f64,
    pub aa: f64,
    pub bb: f64,
}

impl Cosine {
    pub fn add(&mut self, a: f32, b: f32) {
        let (a, b) = (a as f64, b as f64);
        self.dot += a * b;
        self.aa += a * a;
        self.bb += b * b;
    }

    /// Pool another set of sums into this one, when it has something on both sides (a
    /// part with nothing to compare adds nothing, instead of diluting the cosine).
    pub fn merge(&mut self, o: Cosine) {
        if !(o.aa > 0.0 && o.bb > 0.0) {
            return;
        }
        self.dot += o.dot;
        self.aa += o.aa;
        self.bb += o.bb;
    }

    /// The cosine, `None` when either side is zero.
    pub fn value(&self) -> Option<f64> {
        let d = (self.aa * self.bb).sqrt();
        (d > 0.0 && d.is_finite()).then(|| (self.dot / d).clamp(-1.0, 1.0))
    }
}

/// Covered pixels of a view: `alpha > ALPHA_MIN`.
pub fn covered(alpha: &[f32]) -> Vec<f32> {
    alpha
        .iter()
        .map(|&a| if a > ALPHA_MIN { 1.0 } else { 0.0 })
        .collect()
}

/// The high-pass change `m (d - B(d))` of `d` `[3, H, W]` over the mask `m` `[H, W]`
/// (1 covered, 0 not), with `B` the blur normalised over the mask (module docs); zero
/// outside the mask.
pub fn high_pass(d: ArrayView3<'_, f32>, mask: &[f32], sigma: f32) -> Array3<f32> {
    let (c, h, w) = d.dim();
    assert_eq!(
        mask.len(),
        h * w,
        "mask of {} pixels for {h}x{w}",
        mask.len()
    );
    // Channels of m d, then m itself: one blur call.
    let mut x = Array3::<f32>::zeros((c + 1, h, w));
    for k in 0..c {
        for y in 0..h {
            for xx in 0..w {
                x[[k, y, xx]] = mask[y * w + xx] * d[[k, y, xx]];
            }
        }
    }
    for y in 0..h {
        for xx in 0..w {
            x[[c, y, xx]] = mask[y * w + xx];
        }
    }
    let b = gaussian_chw(x.view(), sigma);
    Array3::from_shape_fn((c, h, w), |(k, y, xx)| {
        let m = mask[y * w + xx];
        let wsum = b[[c, y, xx]];
        if m > 0.0 && wsum > 1e-6 {
            d[[k, y, xx]] - b[[k, y, xx]] / wsum
        } else {
            0.0
        }
    })
}

/// Cosine sums of `a` and `b` `[3, H, W]` over the pixels where `mask > 0`.
pub fn cosine_masked(a: ArrayView3<'_, f32>, b: ArrayView3<'_, f32>, mask: &[f32]) -> Cosine {
    let (c, h, w) = a.dim();
    assert_eq!(b.dim(), (c, h, w));
    let mut s = Cosine::default();
    for k in 0..c {
        for y in 0..h {
            for x in 0..w {
                if mask[y * w + x] > 0.0 {
                    s.add(a[[k, y, x]], b[[k, y, x]]);
                }
            }
        }
    }
    s
}

/// Cosine sums of `hp_dst` against `hp_src` warped from `src_cam` into `dst_cam`, over
/// the pixels whose reprojection is valid ([`warp_into`]: surface in both, on screen, not
/// occluded). `*_z` are surface depths ([`surface_depth`]).
pub fn warped_cosine(
    dst_cam: &Camera,
    dst_z: &[f32],
    hp_dst: ArrayView3<'_, f32>,
    src_cam: &Camera,
    src_z: &[f32],
    hp_src: ArrayView3<'_, f32>,
) -> Cosine {
    let warped = warp_into(dst_cam, dst_z, src_cam, src_z, &Image::from_chw(hp_src));
    cosine_masked(hp_dst, warped.image.to_chw().view(), &warped.mask)
}

/// The path neighbours `(i, i + 1)` of `n` views in order, and `(n - 1, 0)` when `closed`
/// (with at least three views).
pub fn adjacent_pairs(n: usize, closed: bool) -> Vec<(usize, usize)> {
    let mut p: Vec<(usize, usize)> = (0..n.saturating_sub(1)).map(|i| (i, i + 1)).collect();
    if closed && n >= 3 {
        p.push((n - 1, 0));
    }
    p
}

/// Agreement of a view set's image changes between path neighbours after reprojection:
/// `changes` `[3, H, W]` per view (e.g. a per-view 2D stylization minus the original),
/// `alpha` and expected `depth` `[H, W]` per view (the `views` artifact's convention),
/// pooled over [`adjacent_pairs`]. The ceiling the distillation's per-iteration
/// adjacent agreement is compared with.
pub fn adjacent_agreement_of_views(
    cameras: &[Camera],
    changes: &[Array3<f32>],
    alpha: &[Vec<f32>],
    depth: &[Vec<f32>],
    closed: bool,
) -> Option<f64> {
    let hp: Vec<Array3<f32>> = changes
        .iter()
        .zip(alpha)
        .map(|(d, a)| high_pass(d.view(), &covered(a), HF_SIGMA))
        .collect();
    let z: Vec<Vec<f32>> = depth
        .iter()
        .zip(alpha)
        .map(|(d, a)| surface_depth(d, a))
        .collect();
    let mut s = Cosine::default();
    for (i, j) in adjacent_pairs(cameras.len(), closed) {
        s.merge(warped_cosine(
            &cameras[i],
            &z[i],
            hp[i].view(),
            &cameras[j],
            &z[j],
            hp[j].view(),
        ));
    }
    s.value()
}

/// The distillation's bookkeeping: the previous visit's high-pass change of every view
/// (zero before the first visit, which [`Cosine::value`] reads as "nothing to compare").
#[derive(Debug, Clone)]
pub struct Tracker {
    cameras: Vec<Camera>,
    /// `[V, 3, H, W]`.
    prev: ndarray::Array4<f32>,
}

/// One iteration's agreements.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Agreement {
    pub revisit: Option<f64>,
    pub adjacent: Option<f64>,
}

impl Tracker {
    pub fn new(cameras: &[Camera], height: usize, width: usize) -> Tracker {
        Tracker {
            cameras: cameras.to_vec(),
            prev: ndarray::Array4::zeros((cameras.len(), 3, height, width)),
        }
    }

    /// The stored high-pass changes `[V, 3, H, W]` (for checkpoints).
    pub fn state(&self) -> &ndarray::Array4<f32> {
        &self.prev
    }

    /// Restore [`Self::state`]; `false` (and nothing changed) when the shape differs.
    pub fn set_state(&mut self, shape: &[usize], data: Vec<f32>) -> bool {
        if shape != self.prev.shape() {
            return false;
        }
        match ndarray::Array4::from_shape_vec(self.prev.raw_dim(), data) {
            Ok(a) => {
                self.prev = a;
                true
            }
            Err(_) => false,
        }
    }

    /// Measure one window: `views` in path order (neighbours adjacent; `circular`: the
    /// last is also a neighbour of the first), `delta` `[N, 3, H, W]` their image
    /// changes, `alpha` / `depth` `[H, W]` of every view (indexed by view). Stores each
    /// view's high pass as its previous visit.
    pub fn measure(
        &mut self,
        views: &[usize],
        circular: bool,
        delta: ArrayView4<'_, f32>,
        alpha: &[Vec<f32>],
        depth: &[Vec<f32>],
    ) -> Agreement {
        let hp: Vec<Array3<f32>> = views
            .iter()
            .enumerate()
            .map(|(i, &v)| high_pass(delta.index_axis(Axis(0), i), &covered(&alpha[v]), HF_SIGMA))
            .collect();
        let mut revisit = Cosine::default();
        for (i, &v) in views.iter().enumerate() {
            let m = covered(&alpha[v]);
            revisit.merge(cosine_masked(
                hp[i].view(),
                self.prev.slice(s![v, .., .., ..]),
                &m,
            ));
        }
        let z: Vec<Vec<f32>> = views
            .iter()
            .map(|&v| surface_depth(&depth[v], &alpha[v]))
            .collect();
        let mut adjacent = Cosine::default();
        for (i, j) in adjacent_pairs(views.len(), circular) {
            adjacent.merge(warped_cosine(
                &self.cameras[views[i]],
                &z[i],
                hp[i].view(),
                &self.cameras[views[j]],
                &z[j],
                hp[j].view(),
            ));
        }
        for (i, &v) in views.iter().enumerate() {
            self.prev.slice_mut(s![v, .., .., ..]).assign(&hp[i]);
        }
        Agreement {
            revisit: revisit.value(),
            adjacent: adjacent.value(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maths::warp::look_at;
    use crate::rng::Rng;

    fn noise(rng: &mut Rng, h: usize, w: usize) -> Array3<f32> {
        Array3::from_shape_vec((3, h, w), rng.normals_f32(3 * h * w)).unwrap()
    }

    #[test]
    fn high_pass_removes_smooth_change_and_keeps_fine_change() {
        let (h, w) = (40, 48);
        let mask = vec![1.0; h * w];
        // A slow ramp is (almost) all low frequency.
        let ramp = Array3::from_shape_fn((3, h, w), |(_, y, x)| 0.01 * (x + y) as f32);
        let hp = high_pass(ramp.view(), &mask, HF_SIGMA);
        let inner = hp.slice(s![.., 8..h - 8, 8..w - 8]);
        assert!(inner.iter().all(|v| v.abs() < 1e-4), "ramp leaks");
        // A 2-pixel checkerboard is (almost) all high frequency.
        let chk = Array3::from_shape_fn((3, h, w), |(_, y, x)| ((x + y) % 2) as f32 - 0.5);
        let hp = high_pass(chk.view(), &mask, HF_SIGMA);
        let c = cosine_masked(hp.view(), chk.view(), &mask).value().unwrap();
        assert!(c > 0.99, "checkerboard cosine {c}");
        // Outside the mask the high pass is zero, and the masked-out region's values do
        // not reach the covered pixels (the normalised blur).
        let mut m = mask.clone();
        for y in 0..h {
            for x in 0..w / 2 {
                m[y * w + x] = 0.0;
            }
        }
        let step = Array3::from_shape_fn((3, h, w), |(_, _, x)| if x < w / 2 { 5.0 } else { 0.0 });
        let hp = high_pass(step.view(), &m, HF_SIGMA);
        assert!(hp.iter().all(|v| v.abs() < 1e-5), "masked step leaks");
    }

    #[test]
    fn identical_change_agrees_one_and_independent_about_zero() {
        let (h, w) = (64, 64);
        let mut rng = Rng::new(3);
        let mask = vec![1.0; h * w];
        let a = high_pass(noise(&mut rng, h, w).view(), &mask, HF_SIGMA);
        let b = high_pass(noise(&mut rng, h, w).view(), &mask, HF_SIGMA);
        let same = cosine_masked(a.view(), a.view(), &mask).value().unwrap();
        assert!((same - 1.0).abs() < 1e-9, "{same}");
        // 12k independent values: std of the cosine about 1/sqrt(12288) = 0.009.
        let ind = cosine_masked(a.view(), b.view(), &mask).value().unwrap();
        assert!(ind.abs() < 0.04, "independent changes agree {ind}");
        let neg = cosine_masked(a.view(), (-&a).view(), &mask)
            .value()
            .unwrap();
        assert!((neg + 1.0).abs() < 1e-9);
        // Nothing to compare: None.
        let z = Array3::zeros((3, h, w));
        assert_eq!(cosine_masked(a.view(), z.view(), &mask).value(), None);
        assert_eq!(
            cosine_masked(a.view(), a.view(), &vec![0.0; h * w]).value(),
            None
        );
    }

    /// Two cameras looking straight down at the plane z = 0, the second moved sideways so
    /// the image shifts by exactly `SHIFT` pixels: the second view's change is the first's
    /// shifted; warped back by depth reprojection it agrees about 1 (the blur's mirrored
    /// image border is the only difference), an independent change about 0.
    #[test]
    fn a_shifted_copy_under_a_known_reprojection_agrees() {
        const SHIFT: usize = 4;
        let (h, w, f, height) = (48usize, 64usize, 50.0, 5.0);
        let s = SHIFT as f64 * height / f;
        let a = look_at(
            "a",
            [0.0, 0.0, height],
            [0.0, 0.0, 0.0],
            w as u32,
            h as u32,
            f,
        );
        let b = look_at("b", [s, 0.0, height], [s, 0.0, 0.0], w as u32, h as u32, f);
        let alpha = vec![vec![1.0f32; h * w]; 2];
        // Expected depth = surface depth x alpha = the height everywhere.
        let depth = vec![vec![height as f32; h * w]; 2];
        let mut rng = Rng::new(9);
        let field = noise(&mut rng, h, w + SHIFT);
        let da = field.slice(s![.., .., 0..w]).to_owned();
        let db = field.slice(s![.., .., SHIFT..w + SHIFT]).to_owned();
        // The geometry is what the test says: b's pixel x sees a's pixel x + SHIFT.
        let wp = warp_into(
            &a,
            &surface_depth(&depth[0], &alpha[0]),
            &b,
            &surface_depth(&depth[1], &alpha[1]),
            &Image::from_chw(db.view()),
        );
        assert_eq!(wp.valid, h * (w - SHIFT));
        let cams = [a, b];
        let c =
            adjacent_agreement_of_views(&cams, &[da.clone(), db], &alpha, &depth, false).unwrap();
        assert!(c > 0.97, "shifted copy agrees only {c}");
        let other = noise(&mut rng, h, w);
        let c0 = adjacent_agreement_of_views(&cams, &[da, other], &alpha, &depth, false).unwrap();
        assert!(c0.abs() < 0.05, "independent changes agree {c0}");
    }

    #[test]
    fn tracker_compares_with_the_previous_visit_only() {
        let (h, w) = (32, 32);
        let cams: Vec<Camera> = (0..3)
            .map(|i| {
                look_at(
                    &format!("c{i}"),
                    [i as f64, 0.0, 5.0],
                    [i as f64, 0.0, 0.0],
                    w as u32,
                    h as u32,
                    40.0,
                )
            })
            .collect();
        let alpha = vec![vec![1.0f32; h * w]; 3];
        let depth = vec![vec![5.0f32; h * w]; 3];
        let mut t = Tracker::new(&cams, h, w);
        let mut rng = Rng::new(1);
        let d0 = noise(&mut rng, h, w);
        let stack = |xs: &[&Array3<f32>]| {
            ndarray::stack(Axis(0), &xs.iter().map(|x| x.view()).collect::<Vec<_>>()).unwrap()
        };
        // First visit of view 0: nothing to compare.
        let r = t.measure(&[0], false, stack(&[&d0]).view(), &alpha, &depth);
        assert_eq!(r.revisit, None);
        assert_eq!(r.adjacent, None, "one view has no neighbour");
        // Second visit with the same change: 1; with the change doubled: still 1.
        let d0x2 = &d0 * 2.0;
        let r = t.measure(&[0], false, stack(&[&d0x2]).view(), &alpha, &depth);
        assert!((r.revisit.unwrap() - 1.0).abs() < 1e-9);
        // Third visit, independent change: about 0; view 1 is new: pooled sums of view 0
        // only.
        let d1 = noise(&mut rng, h, w);
        let d2 = noise(&mut rng, h, w);
        let r = t.measure(&[0, 1], false, stack(&[&d1, &d2]).view(), &alpha, &depth);
        assert!(r.revisit.unwrap().abs() < 0.06, "{:?}", r.revisit);
        assert!(r.adjacent.unwrap().abs() < 0.06, "{:?}", r.adjacent);
        // The state round-trips.
        let st = t.state().clone();
        let mut u = Tracker::new(&cams, h, w);
        assert!(u.set_state(st.shape(), st.iter().copied().collect()));
        assert_eq!(u.state(), t.state());
        assert!(!u.set_state(&[1, 3, h, w], vec![0.0; 3 * h * w]));
    }

    #[test]
    fn adjacent_pairs_close_the_path_only_when_asked() {
        assert_eq!(adjacent_pairs(1, true), vec![]);
        assert_eq!(adjacent_pairs(3, false), vec![(0, 1), (1, 2)]);
        assert_eq!(adjacent_pairs(3, true), vec![(0, 1), (1, 2), (2, 0)]);
        assert_eq!(adjacent_pairs(2, true), vec![(0, 1)]);
    }
}

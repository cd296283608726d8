//! The views' consensus (`synthesis.consensus`; issue 53, seams): every round of the
//! finest level, each view's texture target is reconciled with the other views' before
//! the colour fit.
//!
//! The E-step synthesises each view on its own, so two views that see the same surface
//! point ask for different colours there, and the fit's least-squares compromise between
//! them shows as seams: a thin fin painted one way from its face and another from its
//! edge, outlines of two views averaged into grey. Texture mapping from photographs
//! meets the same problem and answers it by view selection: each surface point takes its
//! colour from the view that sees it best, the most face-on (Waechter, Moehrle and Goesele,
//! "Let there be color!", ECCV 2014). Here the selection is soft: view `d`'s target at a
//! surface pixel becomes
//!
//! `t'_d(x) = sum_s f_s(x)^k t_s(x) / sum_s f_s(x)^k`,
//!
//! over the views `s` that see the same point (`s = d` included; the others through the
//! depth warp of [`crate::maths::warp`], whose 3% occlusion test drops what `s` sees in
//! front of it), `f_s = |n . r|` the facing of the surface to view `s`'s ray (normals from
//! the rendered depth's central differences, as the style projection takes them; the
//! geometry is frozen) and `k = synthesis.consensus`: at 8 a view 30
//! degrees from the normal counts a third of a face-on one, at 60 degrees 1/256. Pixels
//! no other view sees keep their own target; pixels without a surface (coverage <= 0.5)
//! are left.
//!
//! It acts at the finest level only (the last of `synthesis.levels`): the coarse levels
//! lay each view's motifs out under its own structure guide, which puts the style's
//! edges on that view's edges, and the finest level reconciles the colours where the
//! views still disagree. Reconciled at every level, the views' layouts were averaged
//! into one and the edges a single view drew under its guide were lost (a fish's fin
//! outline under op-art's bands: edge recall 0.722 at every level, 0.755 without the
//! consensus; BENCHMARKS.md "The views' consensus").
//!
//! Only the mix's change coarser than the detail layer's scale (`synthesis.detail_blur`,
//! 4 render pixels) is taken: `t'_d = t_d + G * (m_d - t_d)`, `m_d` the mix above and
//! `G *` a Gaussian blur normalised over the surface, so each view keeps its own band
//! finer than that (a brick wall's joints, a mosaic's leading) and the views agree on
//! the colours and layout above it (a fin red from every side). The whole mix averaged
//! the joints of views that drew them a few pixels apart into grey (style texture on the
//! four brick cases 0.47-0.54 against 0.60-0.65 without the consensus; with the band
//! kept 0.59-0.62).
//!
//! It acts on the texture the patches voted (the targets before the detail layer, which
//! comes from the frozen source renders and already agrees between views), so each view's
//! lines stay its own. The geometry is frozen: the surface depths and facings are
//! computed once with the weights' warps, and each round costs `N (N - 1)` warps of the
//! targets. Measured in BENCHMARKS.md
//! "The views' consensus".

use super::guide::blur;
use crate::Camera;
use crate::imageio::Image;
use crate::maths::warp::{surface_depth, warp_into};
use crate::transfer::projection::DepthView;
use rayon::prelude::*;

/// The views' frozen geometry for the consensus: cameras, surface depths and facings.
#[derive(Debug, Clone)]
pub struct Consensus {
    cameras: Vec<Camera>,
    /// Surface depth per view ([`surface_depth`]: NaN where there is none).
    depth: Vec<Vec<f32>>,
    /// `f^k` per view, in all three channels (an image, so it warps like one).
    weight: Vec<Image>,
    /// Per view `d`: each other view `s` that sees some of it, with the pixels of `d`
    /// it sees (the warp's mask, ascending) and `s`'s weight warped there. Frozen like
    /// the geometry, so each round warps only the targets.
    seen: Vec<Seen>,
    /// The scale in render pixels below which each view keeps its own target (the
    /// detail layer's, `synthesis.detail_blur`; 0: the whole mix).
    blur: f32,
    /// Per view, with `blur` > 0: its surface pixels (1, else 0) and their blur, the
    /// normaliser of [`keep_own_band`]; frozen like the geometry.
    surface: Vec<(Vec<f32>, Vec<f32>)>,
}

/// The other views that see some of a view: `(s, [(pixel, weight of s there)])`.
type Seen = Vec<(usize, Vec<(u32, f32)>)>;

impl Consensus {
    /// The consensus of the views of `cameras` (one size each), from their expected
    /// depth and coverage (`[H W]` each, the renderer's), the power `k` and the scale
    /// `blur` (render pixels) below which each view keeps its own target.
    pub fn new(
        cameras: &[Camera],
        (depth, alpha): (&[Vec<f32>], &[Vec<f32>]),
        k: f32,
        blur: f32,
    ) -> Consensus {
        let depth: Vec<Vec<f32>> = (depth.iter().zip(alpha))
            .map(|(d, a)| surface_depth(d, a))
            .collect();
        let weight = (cameras.par_iter().zip(&depth))
            .map(|(c, z)| {
                let mut f = facing(c, z);
                f.data.iter_mut().for_each(|v| *v = v.powf(k));
                f
            })
            .collect::<Vec<Image>>();
        let seen = (0..cameras.len())
            .into_par_iter()
            .map(|d| {
                let (cam, z) = (&cameras[d], &depth[d]);
                (0..cameras.len())
                    .filter(|&s| s != d)
                    .filter_map(|s| {
                        let w = warp_into(cam, z, &cameras[s], &depth[s], &weight[s]);
                        let px: Vec<(u32, f32)> = (w.mask.iter().enumerate())
                            .filter(|&(i, m)| *m > 0.0 && z[i].is_finite())
                            .map(|(i, _)| (i as u32, w.image.data[i * 3]))
                            .collect();
                        (!px.is_empty()).then_some((s, px))
                    })
                    .collect()
            })
            .collect();
        let surface = if blur > 0.0 {
            (cameras.iter().zip(&depth))
                .map(|(c, z)| {
                    let on: Vec<f32> = z
                        .iter()
                        .map(|v| f32::from(u8::from(v.is_finite())))
                        .collect();
                    let sum =
                        super::guide::blur(on.clone(), (c.height as usize, c.width as usize), blur);
                    (on, sum)
                })
                .collect()
        } else {
            Vec::new()
        };
        Consensus {
            cameras: cameras.to_vec(),
            depth,
            weight,
            seen,
            blur,
            surface,
        }
    }

    /// `targets` (`[H, W, 3]` per view, the views of [`Consensus::new`]) reconciled
    /// (module docs).
    pub fn apply(&self, targets: Vec<Vec<f32>>) -> Vec<Vec<f32>> {
        let images: Vec<Image> = (targets.into_iter().zip(&self.cameras))
            .map(|(data, c)| Image {
                width: c.width as usize,
                height: c.height as usize,
                data,
            })
            .collect();
        (0..images.len())
            .into_par_iter()
            .map(|d| self.one(d, &images))
            .collect()
    }

    /// View `d`'s reconciled target.
    fn one(&self, d: usize, images: &[Image]) -> Vec<f32> {
        let (cam, z) = (&self.cameras[d], &self.depth[d]);
        let mut sum = vec![0.0f64; images[d].data.len()];
        let mut total = vec![0.0f64; z.len()];
        let mut add = |i: usize, w: f32, px: &[f32]| {
            let w = f64::from(w);
            total[i] += w;
            for c in 0..3 {
                sum[i * 3 + c] += w * f64::from(px[c]);
            }
        };
        for i in (0..z.len()).filter(|&i| z[i].is_finite()) {
            add(
                i,
                self.weight[d].data[i * 3],
                &images[d].data[i * 3..i * 3 + 3],
            );
        }
        for (s, pixels) in &self.seen[d] {
            let target = warp_into(cam, z, &self.cameras[*s], &self.depth[*s], &images[*s]);
            for &(i, w) in pixels {
                let i = i as usize;
                add(i, w, &target.image.data[i * 3..i * 3 + 3]);
            }
        }
        let mut out = images[d].data.clone();
        for (i, &t) in total.iter().enumerate() {
            if t > 0.0 {
                for c in 0..3 {
                    out[i * 3 + c] = (sum[i * 3 + c] / t) as f32;
                }
            }
        }
        if let Some(surface) = self.surface.get(d) {
            keep_own_band(
                &mut out,
                &images[d].data,
                surface,
                (cam.height as usize, cam.width as usize),
                self.blur,
            );
        }
        out
    }
}

/// `out` (the mix, `[H, W, 3]`) made `own` plus the mix's change blurred by a Gaussian
/// of `sigma` px, normalised over the surface pixels (`on` 1 there, 0 elsewhere, and
/// `weight` its blur): the views' agreement on the layout and colours, each view's own
/// band finer than `sigma` kept.
fn keep_own_band(
    out: &mut [f32],
    own: &[f32],
    (on, weight): &(Vec<f32>, Vec<f32>),
    (h, w): (usize, usize),
    sigma: f32,
) {
    for c in 0..3 {
        let change: Vec<f32> = (0..w * h)
            .map(|i| (out[i * 3 + c] - own[i * 3 + c]) * on[i])
            .collect();
        let change = blur(change, (h, w), sigma);
        for i in (0..w * h).filter(|&i| on[i] > 0.0) {
            out[i * 3 + c] = own[i * 3 + c] + change[i] / weight[i].max(1e-6);
        }
    }
}

/// `|n . r|` per pixel of `cam`'s view (in all three channels): the cosine between the
/// surface normal and the pixel's ray from the rendered surface depth `z`
/// ([`DepthView::pixel_normal`], the style projection's normals); 0 on the frame's
/// border, off the surface and at depth edges.
pub fn facing(cam: &Camera, z: &[f32]) -> Image {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let view = DepthView {
        camera: cam,
        surface: z,
    };
    let mut out = Image::filled(w, h, [0.0; 3]);
    for y in 0..h {
        for x in 0..w {
            if let Some((_, cos)) = view.pixel_normal(x, y) {
                let i = (y * w + x) * 3;
                out.data[i..i + 3].copy_from_slice(&[cos.abs() as f32; 3]);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::maths::warp::{look_at, synthetic};

    /// A camera looking straight down at the ground plane and one at 60 degrees from
    /// its normal, both at the same distance from the point they look at; a long focal
    /// length, so that the side view's neighbouring depths stay within the normals'
    /// depth-edge tolerance (`SEEN_TOL`).
    fn cameras() -> Vec<Camera> {
        let t = 60f64.to_radians();
        vec![
            look_at("top", [0.0, 0.0, 6.0], [0.0; 3], 48, 48, 160.0),
            look_at(
                "side",
                [6.0 * t.sin(), 0.0, 6.0 * t.cos()],
                [0.0; 3],
                48,
                48,
                160.0,
            ),
        ]
    }

    fn geometry(cams: &[Camera]) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
        cams.iter()
            .map(|c| {
                let (_, d, a) = synthetic::render(c, None);
                (d, a)
            })
            .unzip()
    }

    #[test]
    fn facing_is_the_cosine_of_the_view_ray_to_the_normal() {
        let cams = cameras();
        let (depth, alpha) = geometry(&cams);
        for (v, want) in [1.0f64, 0.5].into_iter().enumerate() {
            let f = facing(&cams[v], &surface_depth(&depth[v], &alpha[v]));
            // The pixel at the image centre looks along the camera's axis.
            let i = (24 * 48 + 24) * 3;
            assert!(
                (f64::from(f.data[i]) - want).abs() < 0.03,
                "view {v}: {}",
                f.data[i]
            );
        }
    }

    #[test]
    fn a_grazing_view_takes_the_face_on_views_colour_and_keeps_its_own_elsewhere() {
        let cams = cameras();
        let (depth, alpha) = geometry(&cams);
        let n = 48 * 48 * 3;
        // The face-on view asks for white, the grazing one for black.
        let targets = vec![vec![1.0f32; n], vec![0.0f32; n]];
        let k = 8.0f32;
        let out = Consensus::new(&cams, (&depth, &alpha), k, 0.0).apply(targets.clone());
        // At the grazing view's centre (facing 0.5 against the top view's about 1), the
        // weights are 0.5^8 and about 1: the mix is about 1 / (1 + 0.5^8).
        let centre = (24 * 48 + 24) * 3;
        let want = 1.0 / (1.0 + 0.5f32.powf(k));
        assert!(
            (out[1][centre] - want).abs() < 0.02,
            "{} vs {want}",
            out[1][centre]
        );
        assert!(
            out[0][centre] > 0.99,
            "the face-on view keeps its own: {}",
            out[0][centre]
        );
        // Where the top view does not see the ground the side view sees (the far part of
        // its image), its own target stays.
        let top_z = surface_depth(&depth[0], &alpha[0]);
        let seen = warp_into(
            &cams[1],
            &surface_depth(&depth[1], &alpha[1]),
            &cams[0],
            &top_z,
            &Image::filled(48, 48, [1.0; 3]),
        );
        let unseen = (0..48 * 48).find(|&i| seen.mask[i] == 0.0 && alpha[1][i] > 0.5);
        let i = unseen.expect("the side view sees ground the top view does not");
        assert_eq!(out[1][i * 3], 0.0);
        // k = 0: a plain mean of the views that see the point.
        let mean = Consensus::new(&cams, (&depth, &alpha), 0.0, 0.0).apply(targets.clone());
        assert!((mean[1][centre] - 0.5).abs() < 1e-5, "{}", mean[1][centre]);
    }

    #[test]
    fn with_a_blur_a_view_keeps_its_own_fine_band_and_takes_the_others_level() {
        let cams = cameras();
        let (depth, alpha) = geometry(&cams);
        // The face-on view asks for a flat 0.8; the grazing one for 0.2 with columns
        // alternating +-0.1 (a 2-px band: joints, outlines).
        let mut stripes = vec![0.0f32; 48 * 48 * 3];
        for (i, v) in stripes.iter_mut().enumerate() {
            *v = if (i / 3) % 2 == 0 { 0.3 } else { 0.1 };
        }
        let targets = vec![vec![0.8f32; 48 * 48 * 3], stripes];
        let k = 8.0f32;
        let plain = Consensus::new(&cams, (&depth, &alpha), k, 0.0).apply(targets.clone());
        let kept = Consensus::new(&cams, (&depth, &alpha), k, 2.0).apply(targets.clone());
        let at = |img: &[f32], x: usize| img[(24 * 48 + x) * 3];
        // The plain mix is nearly the face-on view's flat 0.8: the stripes are gone.
        let plain_band = (at(&plain[1], 24) - at(&plain[1], 25)).abs();
        assert!(plain_band < 0.01, "{plain_band}");
        // With the blur the level moves as far (the pair's mean near the plain mix's),
        // and the grazing view keeps its own +-0.1 band.
        let level = 0.5 * (at(&kept[1], 24) + at(&kept[1], 25));
        let plain_level = 0.5 * (at(&plain[1], 24) + at(&plain[1], 25));
        assert!(
            (level - plain_level).abs() < 0.03,
            "{level} vs {plain_level}"
        );
        let band = at(&kept[1], 24) - at(&kept[1], 25);
        assert!((band - 0.2).abs() < 0.03, "{band}");
        // The face-on view, flat and nearly its own in the mix, stays flat.
        let flat = (at(&kept[0], 24) - at(&kept[0], 25)).abs();
        assert!(flat < 0.01, "{flat}");
    }
}

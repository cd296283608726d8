//! One view at one level of the synthesis: its current colour over a fill of itself and
//! its coverage, pooled to the level; its queries (the object's patches on the grid);
//! the vote of the matched style patches (Kwatra et al. 2005's E-step with his robust
//! weights and a Gaussian fall-off, moved from the source branch toward the style branch
//! by the guidance scale), and the full-resolution target it gives.

use super::guide::Moments;
use super::level::StyleLevel;
use super::{Frozen, OBJECT, SynthesisParams};
use crate::prior::patch::bank::patches_at;
use crate::prior::patch::latent::{bilinear, upsample_taps};
use crate::render::fill::fill_background;
use ndarray::{Array2, Array3, Array4, Axis};
use rayon::prelude::*;

/// One view's queries at one level: the object's pixels on the grid, the region owning
/// each ([`super::regions`]), their colour patches `[P, k k 3]` and their patches of each
/// region's channels `[P, k k]` (`channels[region][channel]`).
pub(super) struct Query {
    pub(super) pixels: Vec<[usize; 3]>,
    pub(super) region: Vec<u8>,
    pub(super) colour: Array2<f32>,
    pub(super) channels: Vec<Vec<Array2<f32>>>,
}

/// The votes' Gaussian fall-off from a patch's centre, sigma as a fraction of the patch
/// side (overlapping patches that disagree average to a blur; weighing each by its
/// nearness to the centre keeps the strokes sharper).
const VOTE_SIGMA: f32 = 0.25;

/// One view at one level, what no round changes: its coverage, (when a guidance scale
/// is not 1) its source colour, each region's channels' images, and which region owns
/// each pixel (several regions), pooled; made once per level ([`ViewLevel::new`]).
pub(super) struct ViewLevel {
    /// `[h, w]`.
    alpha: Array2<f32>,
    /// The source branch's colour `[1, 3, h, w]`, when a region's guidance != 1.
    source: Option<Array4<f32>>,
    /// Each region's channels' images `[1, 1, h, w]` ([`super::parts::Channel`]).
    channels: Vec<Vec<Array4<f32>>>,
    /// The region owning each pixel `[h, w]` (none: one region owns all).
    owner: Option<Array2<u8>>,
    /// Each region's guidance scale.
    guidance: Vec<f32>,
    s: usize,
    /// The full-resolution size (H, W).
    full: (usize, usize),
    /// Per region, each channel's share imposed on its queries
    /// ([`super::parts::Channel::imposed`]; `None`: the whole channel).
    imposed: Vec<Vec<Option<Vec<f32>>>>,
}

/// One view in one round: its current colour over a fill of itself, pooled, beside its
/// level's frozen images.
pub(super) struct ViewImage<'a> {
    /// `[1, 3, h, w]`.
    colour: Array4<f32>,
    frozen: &'a ViewLevel,
    /// Per region, each channel's image where its part follows the current colours
    /// ([`super::parts::Channel::imposed`]; `None`: the frozen one).
    current: Vec<Vec<Option<Array4<f32>>>>,
}

/// `[H, W, C]` values pooled over whole `s` x `s` blocks (the patch prior's pooling,
/// [`crate::prior::patch::latent::pool`]'s sums in its order): `[1, C, H / s, W / s]`.
fn pooled(x: &[f32], c: usize, (h, w): (usize, usize), s: usize) -> Array4<f32> {
    let (hl, wl) = (h / s, w / s);
    let inv = 1.0 / (s * s) as f32;
    let mut out = vec![0.0f32; c * hl * wl];
    let mut acc = vec![0.0f32; c];
    for y in 0..hl {
        for xx in 0..wl {
            // Every channel's block sum at once, each in the block's row-major order.
            acc.fill(0.0);
            for dy in 0..s {
                let o = ((y * s + dy) * w + xx * s) * c;
                for px in x[o..o + s * c].chunks_exact(c) {
                    acc.iter_mut().zip(px).for_each(|(a, &v)| *a += v);
                }
            }
            for (ch, &a) in acc.iter().enumerate() {
                out[(ch * hl + y) * wl + xx] = a * inv;
            }
        }
    }
    Array4::from_shape_vec((1, c, hl, wl), out).expect("one value per pooled pixel")
}

impl ViewLevel {
    /// View `v` (of full size `size`) of the frozen views `src` at level `s`.
    pub(super) fn new(
        src: &Frozen,
        v: usize,
        size: (usize, usize),
        s: usize,
        p: &SynthesisParams,
    ) -> Self {
        let (alpha, bg) = (&src.alpha[v][..], src.background);
        let a = pooled(alpha, 1, size, s)
            .index_axis_move(Axis(0), 0)
            .index_axis_move(Axis(0), 0);
        let guidance: Vec<f32> = src.regions.iter().map(|r| r.guidance).collect();
        let source = guidance.iter().any(|&g| g != 1.0).then(|| {
            let filled = fill_background(&src.rgb[v], alpha, bg, size.0, size.1);
            pooled(&filled, 3, size, s)
        });
        let channels: Vec<Vec<Array4<f32>>> = src
            .regions
            .iter()
            .map(|r| {
                r.channels
                    .iter()
                    .zip(&src.parts)
                    .map(|(g, &(_, part))| {
                        let c = pooled(&g[v], 1, size, s);
                        let (_, _, hl, wl) = c.dim();
                        let c = part.at_level(c.into_raw_vec_and_offset().0, (hl, wl), p);
                        Array4::from_shape_vec((1, 1, hl, wl), c).expect("one value per pixel")
                    })
                    .collect()
            })
            .collect();
        let owner = (src.regions.len() > 1).then(|| {
            let shares: Vec<Array4<f32>> = src
                .regions
                .iter()
                .map(|r| pooled(&r.cover[v], 1, size, s))
                .collect();
            let (_, _, hl, wl) = shares[0].dim();
            Array2::from_shape_fn((hl, wl), |(y, x)| {
                owner(shares.iter().map(|c| c[[0, 0, y, x]]))
            })
        });
        let imposed = (channels.iter())
            .map(|r| {
                (r.iter().zip(&src.parts))
                    .map(|(g, &(_, part))| {
                        let (_, _, hl, wl) = g.dim();
                        let (g, a) = (g.as_slice(), a.as_slice());
                        part.imposed(
                            g.expect("standard layout"),
                            a.expect("standard layout"),
                            (hl, wl),
                        )
                    })
                    .collect()
            })
            .collect();
        ViewLevel {
            alpha: a,
            source,
            channels,
            owner,
            guidance,
            s,
            full: size,
            imposed,
        }
    }
}

/// Every view's frozen images at level `s` ([`ViewLevel`]; `sizes` (H, W) per view),
/// made once for the level's rounds; `styles`: each region's style model at the level,
/// to whose channel spread the channels that ask it are narrowed ([`match_moments`];
/// none: the channels as pooled).
pub(super) fn levels(
    src: &Frozen,
    sizes: &[(usize, usize)],
    (s, styles): (usize, &[StyleLevel]),
    p: &SynthesisParams,
) -> Vec<ViewLevel> {
    let mut views: Vec<ViewLevel> = (0..sizes.len())
        .into_par_iter()
        .map(|v| ViewLevel::new(src, v, sizes[v], s, p))
        .collect();
    match_moments(&mut views, src, styles);
    views
}

/// Each channel whose part asks it ([`super::parts::Channel::matched_at_level`]), for
/// each region, its spread over the region's object pixels of every view (coverage
/// above [`OBJECT`], the pixels that make queries) narrowed to the spread of the
/// region's style patches' channel at the level where it is wider, its mean kept
/// ([`super::guide::Moments::toward`]); one map for all the views, so they agree.
fn match_moments(views: &mut [ViewLevel], src: &Frozen, styles: &[StyleLevel]) {
    for (r, style) in styles.iter().enumerate() {
        for (c, &(_, part)) in src.parts.iter().enumerate() {
            if !part.matched_at_level() {
                continue;
            }
            let object = Moments::of(views.iter().flat_map(|f| {
                // The region's pixels (every pixel without regions).
                let owner = f.owner.as_ref().map(|o| o.iter());
                let owned = owner
                    .into_iter()
                    .flatten()
                    .map(move |&x| x as usize == r)
                    .chain(std::iter::repeat(true));
                f.channels[r][c]
                    .iter()
                    .zip(f.alpha.iter())
                    .zip(owned)
                    .map(|((&v, &a), own)| (v, a > OBJECT && own))
            }));
            let to = &style.channel_moments[c];
            tracing::debug!(
                "level {}: {} of region {r} from mean {:.3} spread {:.3} onto the style's {:.3} / {:.3}",
                views.first().map_or(0, |f| f.s),
                src.parts[c].0,
                object.mean,
                object.std,
                to.mean,
                to.std
            );
            let map = object.toward(to);
            views
                .par_iter_mut()
                .for_each(|f| f.channels[r][c].mapv_inplace(&map));
        }
    }
}

impl<'a> ViewImage<'a> {
    /// The view's render `rgb` (`[H, W, 3]`, composited over `src`'s background with
    /// view `v`'s coverage) at its level `frozen`.
    pub(super) fn new(rgb: &[f32], src: &Frozen, v: usize, frozen: &'a ViewLevel) -> Self {
        let size = frozen.full;
        let filled = fill_background(rgb, &src.alpha[v], src.background, size.0, size.1);
        let colour = pooled(&filled, 3, size, frozen.s);
        let current = (frozen.channels.iter().zip(&frozen.imposed))
            .map(|(r, imposed)| {
                (r.iter().zip(imposed).zip(&src.parts))
                    .map(|((g, share), &(_, part))| {
                        let share = share.as_ref()?;
                        let own = part.of_current(colour.index_axis(Axis(0), 0));
                        let g4 = g.as_slice().expect("standard layout");
                        let c = super::parts::follow(g4, share, &own);
                        Some(Array4::from_shape_vec(g.dim(), c).expect("one value per pixel"))
                    })
                    .collect()
            })
            .collect();
        ViewImage {
            colour,
            frozen,
            current,
        }
    }

    /// The object's pixels on the grid of step `stride` and their patches.
    pub(super) fn queries(&self, p: &SynthesisParams) -> Query {
        let (_, _, hl, wl) = self.colour.dim();
        let step = p.stride.max(1);
        let pixels: Vec<[usize; 3]> = (0..hl)
            .step_by(step)
            .flat_map(|y| (0..wl).step_by(step).map(move |x| [0, y, x]))
            .filter(|&[_, y, x]| self.frozen.alpha[[y, x]] > OBJECT)
            .collect();
        let colour = patches_at(self.colour.view(), p.patch, &pixels);
        let channels = (self.frozen.channels.iter().zip(&self.current))
            .map(|(r, now)| {
                (r.iter().zip(now))
                    .map(|(g, now)| patches_at(now.as_ref().unwrap_or(g).view(), p.patch, &pixels))
                    .collect()
            })
            .collect();
        let region = pixels.iter().map(|&[_, y, x]| self.owns(y, x)).collect();
        Query {
            pixels,
            region,
            colour,
            channels,
        }
    }

    /// The region owning pooled pixel (y, x).
    fn owns(&self, y: usize, x: usize) -> u8 {
        self.frozen.owner.as_ref().map_or(0, |o| o[[y, x]])
    }

    /// The view's full-resolution target (`[H, W, 3]`: the render plus its coverage times
    /// the upsampled change of the vote over the pooled colour) from the matches `m` of
    /// its queries `q` (each in its region's level of `levels`).
    pub(super) fn target(
        &self,
        levels: &[StyleLevel],
        q: &Query,
        m: &[(u32, f32)],
        p: &SynthesisParams,
        rgb: &[f32],
        alpha: &[f32],
    ) -> Vec<f32> {
        if q.pixels.is_empty() {
            return rgb.to_vec();
        }
        let (_, _, hl, wl) = self.colour.dim();
        let delta = self.vote(levels, q, m, p);
        // The change upsampled as [`crate::prior::patch::latent::upsample`] makes it, pixel
        // by pixel.
        let full_w = self.frozen.full.1;
        let (ty, tx) = (
            upsample_taps(hl, self.frozen.s),
            upsample_taps(wl, self.frozen.s),
        );
        let delta = delta.as_slice().expect("a standard-layout vote");
        let mut t = rgb.to_vec();
        for (y, &ty) in ty.iter().enumerate() {
            for (x, &tx) in tx.iter().enumerate() {
                let i = y * full_w + x;
                let a = alpha[i];
                for c in 0..3 {
                    let d = &delta[c * hl * wl..(c + 1) * hl * wl];
                    let up = bilinear(|yy, xx| d[yy * wl + xx], ty, tx);
                    t[i * 3 + c] = rgb[i * 3 + c] + a * up;
                }
            }
        }
        t
    }

    /// The average of the matched patches over each object pixel they cover, minus the
    /// pooled colour (`[3, h, w]`; 0 where no patch voted or off the object).
    fn vote(
        &self,
        levels: &[StyleLevel],
        q: &Query,
        m: &[(u32, f32)],
        p: &SynthesisParams,
    ) -> Array3<f32> {
        let k = p.patch;
        let (_, _, hl, wl) = self.colour.dim();
        let mut acc = Array3::<f32>::zeros((3, hl, wl));
        let mut wt = Array2::<f32>::zeros((hl, wl));
        let r = (k / 2) as isize;
        let sigma = VOTE_SIGMA * k as f32;
        // Each region's mean match distance (its own style's scale).
        let mean_d: Vec<f32> = (0..levels.len())
            .map(|r| {
                let mine = || m.iter().zip(&q.region).filter(|x| usize::from(*x.1) == r);
                mine().map(|x| x.0.1).sum::<f32>() / mine().count().max(1) as f32
            })
            .collect();
        for ((&[_, y, x], &(j, d)), &reg) in q.pixels.iter().zip(m).zip(&q.region) {
            let patch = levels[usize::from(reg)].bank.patches.row(j as usize);
            let mean_d = mean_d[usize::from(reg)];
            // Kwatra et al.'s robust weight |d|^(r - 2) with r = 0.8 (d: the match's
            // distance), relative to the mean distance so that it stays bounded.
            let robust = ((d + 0.01 * mean_d + 1e-12) / (mean_d + 1e-12)).powf(-0.6);
            let mut q = 0;
            for dy in -r..=r {
                for dx in -r..=r {
                    let (yy, xx) = (y as isize + dy, x as isize + dx);
                    if yy >= 0 && xx >= 0 && (yy as usize) < hl && (xx as usize) < wl {
                        let (yy, xx) = (yy as usize, xx as usize);
                        let g =
                            robust * (-((dy * dy + dx * dx) as f32) / (2.0 * sigma * sigma)).exp();
                        for c in 0..3 {
                            acc[[c, yy, xx]] += g * patch[q + c];
                        }
                        wt[[yy, xx]] += g;
                    }
                    q += 3;
                }
            }
        }
        let colour = self.colour.index_axis(Axis(0), 0);
        // The guidance scale (the owning region's): from the source's colour toward the
        // style's vote (at 1 the vote itself, bit for bit).
        Array3::from_shape_fn((3, hl, wl), |(c, y, x)| {
            let g = self.frozen.guidance[usize::from(self.owns(y, x))];
            if wt[[y, x]] > 0.0 && self.frozen.alpha[[y, x]] > 0.0 {
                let vote = (acc[[c, y, x]] / wt[[y, x]]).clamp(0.0, 1.0);
                let to = match &self.frozen.source {
                    Some(src) => src[[0, c, y, x]] + g * (vote - src[[0, c, y, x]]),
                    None => vote,
                };
                to - colour[[c, y, x]]
            } else {
                0.0
            }
        })
    }
}

/// The region owning a pixel of shares `shares` ([`super::regions`]: the largest share, the first on a tie, the first where none covers).
fn owner(shares: impl Iterator<Item = f32>) -> u8 {
    let mut best = (0u8, 0.0f32);
    for (r, s) in shares.enumerate() {
        if s > best.1 {
            best = (r as u8, s);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::{owner, pooled};
    use crate::prior::patch::latent::pool;
    use ndarray::Array4;

    /// The pooling straight from the `[H, W, C]` slice is the prior's `pool` of the
    /// same image as an array, bit for bit (odd sizes: the last partial block dropped).
    #[test]
    fn pooled_is_the_priors_pool_bitwise() {
        let mut rng = crate::rng::Rng::new(4);
        for (c, h, w, s) in [(3, 37, 29, 1), (3, 37, 29, 4), (1, 16, 24, 8), (2, 9, 9, 2)] {
            let x: Vec<f32> = rng.normals_f32(h * w * c);
            let (hc, wc) = ((h / s) * s, (w / s) * s);
            let a =
                Array4::from_shape_fn((1, c, hc, wc), |(_, ch, y, xx)| x[(y * w + xx) * c + ch]);
            let want = pool(a.view(), s);
            let got = pooled(&x, c, (h, w), s);
            assert_eq!(got.dim(), want.dim());
            let bits = |a: &Array4<f32>| a.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "c {c}, {h}x{w}, s {s}");
        }
    }

    /// At each level the object's guide takes the style's guide spread there where it is
    /// wider: a disc shaded from dark to bright under a style of fine stripes, whose
    /// blurred guide keeps little spread, is narrowed to the stripes' spread; under a
    /// style of two flat halves (more spread at the level than the disc) it is left as
    /// it was. Its mean stays in both.
    #[test]
    fn each_level_narrows_the_objects_guide_to_the_styles() {
        use super::super::guide::Moments;
        use super::super::level::StyleLevel;
        use super::super::motif::tests::image;
        use super::super::regions::RegionStyle;
        use super::super::{Frozen, OBJECT, SynthesisParams, channels};
        use super::levels;
        let (h, w) = (32usize, 32usize);
        let stripes = image(48, 48, |_, x| [if x % 2 == 0 { 0.2 } else { 0.8 }; 3]);
        let halves = image(48, 48, |_, x| [if x < 24 { 0.05 } else { 0.95 }; 3]);
        let alpha: Vec<f32> = (0..h * w)
            .map(|i| {
                let (y, x) = ((i / w) as f32 - 15.5, (i % w) as f32 - 15.5);
                if y * y + x * x < 144.0 { 1.0 } else { 0.0 }
            })
            .collect();
        let rgb: Vec<f32> = (0..h * w)
            .flat_map(|i| [0.1 + 0.8 * (i % w) as f32 / w as f32; 3])
            .zip(alpha.iter().flat_map(|&a| [a; 3]))
            .map(|(v, a)| v * a)
            .collect();
        let p = SynthesisParams {
            patch: 5,
            pca_dims: 4,
            control: 1.0,
            guide_blur: 2.0,
            detail: 0.0,
            ..SynthesisParams::default()
        };
        for (style, narrowed) in [(&stripes, true), (&halves, false)] {
            let region = [RegionStyle::one(style)];
            let src = Frozen::new(
                vec![rgb.clone()],
                vec![alpha.clone()],
                (&[(h, w)], 48),
                &region,
                Vec::new(),
                [0.0; 3],
                &p,
            );
            let one = [(style, 1.0)];
            let level = StyleLevel::new(
                &one,
                &super::super::motif::masks(&one),
                24,
                &p,
                1,
                &channels(&p),
            )
            .unwrap();
            let to = level.channel_moments[0];
            let object = |views: &[super::ViewLevel]| {
                let f = &views[0];
                Moments::of(
                    f.channels[0][0]
                        .iter()
                        .zip(f.alpha.iter())
                        .map(|(&v, &a)| (v, a > OBJECT)),
                )
            };
            // The level's views before the match: made without the style.
            let before = object(&levels(&src, &[(h, w)], (2, &[]), &p));
            let got = object(&levels(
                &src,
                &[(h, w)],
                (2, std::slice::from_ref(&level)),
                &p,
            ));
            assert!((got.mean - before.mean).abs() < 1e-4, "{got:?} {before:?}");
            if narrowed {
                assert!(before.std > to.std + 0.05, "{before:?} {to:?}");
                assert!((got.std - to.std).abs() < 1e-4, "{got:?} {to:?}");
            } else {
                assert!(before.std < to.std, "{before:?} {to:?}");
                assert!((got.std - before.std).abs() < 1e-6, "{got:?} {before:?}");
            }
        }
    }

    #[test]
    fn a_pixel_belongs_to_the_region_with_the_largest_share() {
        assert_eq!(owner([0.2, 0.5, 0.3].into_iter()), 1);
        assert_eq!(owner([0.4, 0.4].into_iter()), 0, "the first on a tie");
        assert_eq!(
            owner([0.0, 0.0].into_iter()),
            0,
            "the first where none covers"
        );
    }
}

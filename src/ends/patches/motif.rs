//! A style's motif and its background: a style photographed on a plain background (an
//! object on black) has a flat region of one colour touching its border, which is not a
//! motif. [`motif_mask`] finds it (a flood fill from the border through pixels near the
//! border's dominant colour with no local texture), with the same colour's flat pockets
//! inside the object when they are few beside it (the background seen between a plant's
//! leaves); its patches leave the bank and its pixels the style's moments
//! ([`super::guide`]), so its share of the style is not forced onto the object. Every level
//! of the synthesis uses it, guided or not: found once on the style as given and carried
//! to each level's size ([`masks`], [`motif_at`]).
//!
//! **The rim.** Where the motif meets the background its edge pixels are partly covered
//! (anti-aliasing, a soft focus, a render over black): blends of the motif's colour and
//! the background's, a dark halo that is neither. Kept as motif, the halo is a motif
//! the balance hands its share of the object (a bust styled with its own render over
//! black came out darker than the render, its outline's halo laid over it). So the
//! motif's pixels near the background whose colour lies between the background's and
//! the motif's own colour further in are background too ([`drop_rim`]); a real outline
//! of another colour is off that line and stays.

use crate::imageio::Image;
use crate::render::fill::push_pull;

/// Rec. 601 luma weights.
pub const LUMA: [f32; 3] = [0.299, 0.587, 0.114];

/// The luma of `[N, 3]` pixels.
pub fn luma(rgb: &[f32]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|p| LUMA[0] * p[0] + LUMA[1] * p[1] + LUMA[2] * p[2])
        .collect()
}

/// A pixel is the background's colour when within this RGB distance of it.
const BACKGROUND_TOLERANCE: f32 = 0.1;
/// ... and flat when its 5x5 neighbourhood's luma spread is below this.
const BACKGROUND_FLAT: f32 = 0.03;
/// The border must be this much of one flat colour for the style to have a background.
const BACKGROUND_BORDER_SHARE: f32 = 0.75;
/// A border between this share and [`BACKGROUND_BORDER_SHARE`] of one flat colour (an
/// object photographed on a plain background and cropped tight, touching the image's
/// sides) is a background only when the fill from the border leaves at most
/// [`BACKGROUND_INNER_SHARE`] of that colour's flat pixels unreached (a pattern's flat
/// colour also fills closed areas inside the image: op-art's bands, a wall's bricks) and
/// leaves one object (stripes that all reach the border leave several).
const BACKGROUND_TIGHT_SHARE: f32 = 0.5;
/// See [`BACKGROUND_TIGHT_SHARE`].
const BACKGROUND_INNER_SHARE: f32 = 0.1;
/// Parts of the motif smaller than this share of the image are not counted as objects.
const OBJECT_MIN_SHARE: f32 = 0.01;
/// Pixels of the background's colour it grows by beside the motif.
const BACKGROUND_RING: usize = 3;
/// The motif's rim tested as a blend with the background, px ([`drop_rim`]).
const RIM_PX: usize = 3;
/// A rim pixel is a blend when its share of the motif's colour is below this ...
const RIM_BLEND_MAX: f32 = 0.9;
/// ... and its colour off the line from the background's to the motif's by at most this.
const RIM_RESIDUAL: f32 = 0.1;

/// The style's motif pixels (`[h w]`, row-major): every pixel except a flat background, the
/// connected region of pixels near the border's dominant colour with no local texture that
/// touches the border, and that colour's flat pixels out of its reach when they are at most
/// [`BACKGROUND_INNER_SHARE`] of it (module docs). Every pixel when the border is not
/// dominated by one colour (textures, paintings, patterns).
pub fn motif_mask(img: &Image) -> Vec<bool> {
    let (h, w) = (img.height, img.width);
    let px = |y: usize, x: usize| -> [f32; 3] {
        let i = (y * w + x) * 3;
        [img.data[i], img.data[i + 1], img.data[i + 2]]
    };
    let border: Vec<(usize, usize)> = (0..w)
        .flat_map(|x| [(0, x), (h - 1, x)])
        .chain((0..h).flat_map(|y| [(y, 0), (y, w - 1)]))
        .collect();
    // The border's dominant colour: the channel-wise median.
    let mut bg = [0.0f32; 3];
    for (c, b) in bg.iter_mut().enumerate() {
        let mut v: Vec<f32> = border.iter().map(|&(y, x)| px(y, x)[c]).collect();
        v.sort_by(f32::total_cmp);
        *b = v[v.len() / 2];
    }
    let near = |p: [f32; 3]| {
        let d: f32 = (0..3).map(|c| (p[c] - bg[c]).powi(2)).sum();
        d.sqrt() < BACKGROUND_TOLERANCE
    };
    let l = luma(&img.data);
    let flat = local_spread(&l, h, w, 2);
    let candidate = |i: usize| near(px(i / w, i % w)) && flat[i] < BACKGROUND_FLAT;
    let share = border
        .iter()
        .filter(|&&(y, x)| candidate(y * w + x))
        .count() as f32
        / border.len() as f32;
    if share < BACKGROUND_TIGHT_SHARE {
        return vec![true; h * w];
    }
    let seeds: Vec<usize> = border.iter().map(|&(y, x)| y * w + x).collect();
    let mut motif: Vec<bool> = fill(&seeds, (h, w), candidate)
        .iter()
        .map(|&b| !b)
        .collect();
    let reached = motif.iter().filter(|&&m| !m).count();
    let inner: Vec<usize> = (0..h * w).filter(|&i| motif[i] && candidate(i)).collect();
    let pockets = inner.len() as f32 <= BACKGROUND_INNER_SHARE * reached as f32;
    if share < BACKGROUND_BORDER_SHARE && (!pockets || objects(&motif, (h, w)) != 1) {
        return vec![true; h * w];
    }
    if pockets {
        // The background seen through the object (between a plant's leaves): the
        // border's flat colour in closed areas, few beside the fill's.
        for i in inner {
            motif[i] = false;
        }
    }
    // The flatness test misses the background's last pixels beside the motif (their
    // neighbourhood reaches it): the background grows into pixels of its colour there.
    for _ in 0..BACKGROUND_RING {
        let grown: Vec<usize> = (0..h * w)
            .filter(|&i| motif[i] && near(px(i / w, i % w)))
            .filter(|&i| {
                let (y, x) = (i / w, i % w);
                (y > 0 && !motif[i - w])
                    || (y + 1 < h && !motif[i + w])
                    || (x > 0 && !motif[i - 1])
                    || (x + 1 < w && !motif[i + 1])
            })
            .collect();
        for i in grown {
            motif[i] = false;
        }
    }
    drop_rim(img, &mut motif, bg);
    motif
}

/// The motif's anti-aliased rim (module docs): the motif pixels at most [`RIM_PX`]
/// 8-neighbour steps from the background whose colour lies on the line from the
/// background's colour `bg` to the motif's own colour there (the motif's pixels further
/// in, extended outward by push-pull), short of it (a share below [`RIM_BLEND_MAX`]) and
/// off it by at most [`RIM_RESIDUAL`]: a blend of the two, a partly covered pixel, is
/// background. Nothing changes where the motif's colour there is near the background's
/// (nothing to tell a blend by) or no motif pixel lies further in.
fn drop_rim(img: &Image, motif: &mut [bool], bg: [f32; 3]) {
    let (h, w) = (img.height, img.width);
    // Steps from the background (RIM_PX + 1: further).
    let mut steps = vec![RIM_PX + 1; h * w];
    let mut front: Vec<usize> = (0..h * w).filter(|&i| !motif[i]).collect();
    for &i in &front {
        steps[i] = 0;
    }
    for d in 1..=RIM_PX {
        let mut next = Vec::new();
        for i in front {
            let (y, x) = (i / w, i % w);
            let rows = y.saturating_sub(1)..(y + 2).min(h);
            let around = rows
                .flat_map(|yy| (x.saturating_sub(1)..(x + 2).min(w)).map(move |xx| yy * w + xx));
            for j in around {
                if steps[j] > d {
                    steps[j] = d;
                    next.push(j);
                }
            }
        }
        front = next;
    }
    let inner: Vec<f32> = steps
        .iter()
        .map(|&s| f32::from(u8::from(s > RIM_PX)))
        .collect();
    if inner.iter().all(|&v| v == 0.0) {
        return;
    }
    let own = push_pull(&img.data, &inner, h, w);
    for i in (0..h * w).filter(|&i| (1..=RIM_PX).contains(&steps[i])) {
        let v: [f32; 3] = std::array::from_fn(|c| own[i * 3 + c] - bg[c]);
        let u: [f32; 3] = std::array::from_fn(|c| img.data[i * 3 + c] - bg[c]);
        let vv: f32 = v.iter().map(|x| x * x).sum();
        if vv.sqrt() < BACKGROUND_TOLERANCE {
            continue;
        }
        let a = (0..3).map(|c| u[c] * v[c]).sum::<f32>() / vv;
        let off: f32 = (0..3)
            .map(|c| (u[c] - a * v[c]).powi(2))
            .sum::<f32>()
            .sqrt();
        if a < RIM_BLEND_MAX && off <= RIM_RESIDUAL {
            motif[i] = false;
        }
    }
}

/// Each style's motif pixels ([`motif_mask`] of each image as given), found once for
/// all the levels ([`motif_at`]).
pub fn masks(styles: &[(&Image, f32)]) -> Vec<Vec<bool>> {
    styles.iter().map(|(style, _)| motif_mask(style)).collect()
}

/// A style's motif pixels `motif` ([`motif_mask`] of `style` as given) at a level's size
/// `(width, height)`: the mask resized as the image is ([`Image::with_shorter_side`]'s
/// filter), a level's pixel motif only where everything it takes from the style is. So
/// the background is one decision for every level (a tight crop on black whose small
/// levels' borders are mostly the object's would otherwise have no background there, its
/// black a motif), and no level's pixel is a blend of the motif and the background.
pub fn motif_at(style: &Image, motif: &[bool], (width, height): (usize, usize)) -> Vec<bool> {
    if motif.iter().all(|&m| m) {
        return vec![true; width * height];
    }
    let share = Image {
        width: style.width,
        height: style.height,
        data: motif
            .iter()
            .flat_map(|&m| [f32::from(u8::from(m)); 3])
            .collect(),
    };
    share
        .resized(width, height, crate::imageio::Filter::Bilinear)
        .data
        .chunks_exact(3)
        .map(|c| c[0] >= 1.0 - 1e-6)
        .collect()
}

/// `img` with its background (`motif` false) replaced by its motif's colours extended
/// by push-pull ([`crate::render::fill`]): a patch on the motif's edge then holds no
/// background colour.
pub fn fill_background(img: &Image, motif: &[bool]) -> Image {
    let weight: Vec<f32> = motif.iter().map(|&m| f32::from(u8::from(m))).collect();
    Image {
        width: img.width,
        height: img.height,
        data: push_pull(&img.data, &weight, img.height, img.width),
    }
}

/// The pixels (`[h w]`) reached from the `seeds` through 4-neighbours where `pass` holds
/// (a seed where `pass` fails is not taken).
fn fill(seeds: &[usize], (h, w): (usize, usize), pass: impl Fn(usize) -> bool) -> Vec<bool> {
    let mut reached = vec![false; h * w];
    let start = seeds.iter().copied().filter(|&i| pass(i)).collect();
    grow(start, &mut reached, (h, w), pass);
    reached
}

/// The 4-connected parts of `mask` (`[h w]`) of at least [`OBJECT_MIN_SHARE`] of the
/// image.
fn objects(mask: &[bool], (h, w): (usize, usize)) -> usize {
    let mut seen = vec![false; h * w];
    let mut count = 0;
    for start in 0..h * w {
        if mask[start] && !seen[start] {
            let n = grow(vec![start], &mut seen, (h, w), |j| mask[j]);
            count += usize::from(n as f32 >= OBJECT_MIN_SHARE * (h * w) as f32);
        }
    }
    count
}

/// Marks in `seen` the pixels of `stack` and every pixel reached from them through
/// 4-neighbours where `pass` holds, not entering pixels already seen; returns how many
/// it marked.
fn grow(
    mut stack: Vec<usize>,
    seen: &mut [bool],
    (h, w): (usize, usize),
    pass: impl Fn(usize) -> bool,
) -> usize {
    let mut n = 0;
    while let Some(i) = stack.pop() {
        if seen[i] {
            continue;
        }
        seen[i] = true;
        n += 1;
        let (y, x) = (i / w, i % w);
        let next = [
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
        ];
        stack.extend(next.into_iter().flatten().filter(|&j| !seen[j] && pass(j)));
    }
    n
}

/// The range (max - min) of `v` `[h, w]` over each pixel's (2r+1)^2 neighbourhood.
fn local_spread(v: &[f32], h: usize, w: usize, r: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; h * w];
    for y in 0..h {
        for x in 0..w {
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    lo = lo.min(v[yy * w + xx]);
                    hi = hi.max(v[yy * w + xx]);
                }
            }
            out[y * w + x] = hi - lo;
        }
    }
    out
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// An image of `w` x `h` pixels, `f(y, x)` each.
    pub(in crate::ends::patches) fn image(
        w: usize,
        h: usize,
        f: impl Fn(usize, usize) -> [f32; 3],
    ) -> Image {
        let data = (0..h * w).flat_map(|i| f(i / w, i % w)).collect();
        Image {
            width: w,
            height: h,
            data,
        }
    }

    /// A textured disc of radius 20 on black, 64 x 64.
    pub(in crate::ends::patches) fn disc() -> Image {
        image(64, 64, |y, x| {
            let (dy, dx) = (y as f32 - 32.0, x as f32 - 32.0);
            if dy * dy + dx * dx < 400.0 {
                let v = if (x / 3 + y / 3) % 2 == 0 { 0.9 } else { 0.2 };
                [v, 0.5, 0.3]
            } else {
                [0.02, 0.02, 0.02]
            }
        })
    }

    #[test]
    fn an_object_on_black_has_a_background_and_a_texture_has_none() {
        // A textured disc on black: the black outside is background, the disc motif.
        let disc = disc();
        let m = motif_mask(&disc);
        assert!(!m[0] && !m[64 * 64 - 1], "the corners are background");
        assert!(m[32 * 64 + 32], "the centre is motif");
        let kept = m.iter().filter(|&&v| v).count() as f32 / m.len() as f32;
        assert!((0.25..0.45).contains(&kept), "kept {kept}");
        // Black and white stripes touching the border: no background.
        let stripes = image(
            64,
            64,
            |_, x| if (x / 8) % 2 == 0 { [0.0; 3] } else { [1.0; 3] },
        );
        assert!(motif_mask(&stripes).iter().all(|&v| v));
    }

    /// The share of the border of `img` within the tolerance of `colour` and flat.
    fn flat_border_share(img: &Image, colour: f32) -> f32 {
        let (h, w) = (img.height, img.width);
        let flat = local_spread(&luma(&img.data), h, w, 2);
        let border: Vec<usize> = (0..w)
            .flat_map(|x| [x, (h - 1) * w + x])
            .chain((0..h).flat_map(|y| [y * w, y * w + w - 1]))
            .collect();
        let on = |i: usize| {
            let d: f32 = (0..3).map(|c| (img.data[i * 3 + c] - colour).powi(2)).sum();
            d.sqrt() < BACKGROUND_TOLERANCE && flat[i] < BACKGROUND_FLAT
        };
        border.iter().filter(|&&i| on(i)).count() as f32 / border.len() as f32
    }

    /// A textured disc on black cropped to its box, 64 x 64, touching all four sides.
    fn tight_disc() -> Image {
        image(64, 64, |y, x| {
            let (dy, dx) = (y as f32 - 31.5, x as f32 - 31.5);
            if dy * dy + dx * dx < 32.5 * 32.5 {
                [if (x / 3 + y / 3) % 2 == 0 { 0.9 } else { 0.3 }, 0.6, 0.4]
            } else {
                [0.02; 3]
            }
        })
    }

    #[test]
    fn a_tight_crop_on_black_has_a_background_and_rings_have_none() {
        // A textured disc cropped to its box, touching all four sides: the black corners
        // make less than 3/4 of the border, and they are the background.
        let tight = tight_disc();
        let share = flat_border_share(&tight, 0.02);
        assert!(
            (BACKGROUND_TIGHT_SHARE..BACKGROUND_BORDER_SHARE).contains(&share),
            "{share}"
        );
        let m = motif_mask(&tight);
        assert!(
            !m[0] && !m[63] && !m[64 * 63] && !m[64 * 64 - 1],
            "the corners"
        );
        assert!(
            m[32 * 64 + 32] && m[32 * 64] && m[32],
            "the disc, to its sides"
        );
        // Rings, black wider than white, as much of the border: the black also fills
        // rings inside the image, so it is the pattern's colour, not a background.
        let rings = image(64, 64, |y, x| {
            let r = ((y as f32 - 31.5).powi(2) + (x as f32 - 31.5).powi(2)).sqrt();
            if (r as usize) % 16 < 13 {
                [0.02; 3]
            } else {
                [0.95; 3]
            }
        });
        assert!(flat_border_share(&rings, 0.02) >= BACKGROUND_TIGHT_SHARE);
        assert!(motif_mask(&rings).iter().all(|&v| v));
    }

    /// A flat disc of radius 20 on black, 64 x 64, its colour `c`, with a 3 px band inside
    /// its edge of colour `edge(c, coverage)` (coverage falling linearly to the edge).
    fn disc_with_edge(c: [f32; 3], edge: impl Fn([f32; 3], f32) -> [f32; 3]) -> Image {
        image(64, 64, |y, x| {
            let r = ((y as f32 - 32.0).powi(2) + (x as f32 - 32.0).powi(2)).sqrt();
            if r < 17.0 {
                c
            } else if r < 20.0 {
                edge(c, (20.0 - r) / 3.0)
            } else {
                [0.0; 3]
            }
        })
    }

    #[test]
    fn the_motifs_anti_aliased_rim_is_background_and_an_outline_is_not() {
        // The pixels of the band's middle (radius 17.5 to 19.5), and how many are motif.
        let band: Vec<usize> = (0..64 * 64)
            .filter(|&i| {
                let (y, x) = ((i / 64) as f32 - 32.0, (i % 64) as f32 - 32.0);
                (17.5..19.5).contains(&(y * y + x * x).sqrt())
            })
            .collect();
        let kept = |m: &[bool]| band.iter().filter(|&&i| m[i]).count();
        // Blends of the disc's colour and black (a partly covered edge): background.
        let soft = motif_mask(&disc_with_edge([0.7, 0.5, 0.3], |c, a| c.map(|v| v * a)));
        assert!(
            soft[32 * 64 + 32] && soft[32 * 64 + 48],
            "the disc inside its rim"
        );
        assert_eq!(kept(&soft), 0, "the blend is background");
        // A red outline (off the line from black to the disc's colour): motif.
        let outlined = motif_mask(&disc_with_edge([0.2, 0.5, 0.3], |_, _| [0.8, 0.1, 0.1]));
        assert_eq!(kept(&outlined), band.len(), "the outline is motif");
    }

    #[test]
    fn a_level_takes_the_styles_background_at_its_size() {
        // A tight crop on black (its border between 1/2 and 3/4 black at 64 px): at 16 px
        // the flatness test finds too little flat black on the border and, tested there,
        // the black would be a motif; carried from the style, the corners are background.
        let tight = tight_disc();
        let small = tight.with_shorter_side(16);
        assert!(
            motif_mask(&small).iter().all(|&m| m),
            "tested at 16 px: no background"
        );
        let m = motif_at(&tight, &motif_mask(&tight), (16, 16));
        assert!(
            !m[0] && !m[15] && !m[16 * 15] && !m[16 * 16 - 1],
            "the corners"
        );
        assert!(m[8 * 16 + 8] && m[8 * 16] && m[8], "the disc, to its sides");
        // A pixel of the level that takes any background is background: none is a blend.
        let full = motif_mask(&tight);
        let at = motif_at(&tight, &full, (32, 32));
        for (i, &v) in at.iter().enumerate() {
            let (y, x) = (2 * (i / 32), 2 * (i % 32));
            let all = [0, 1, 64, 65].iter().all(|&d| full[y * 64 + x + d]);
            assert_eq!(v, all, "pixel {i}");
        }
        // A style without a background keeps every pixel at every size.
        let stripes = image(64, 64, |_, x| [f32::from(u8::from((x / 8) % 2 == 0)); 3]);
        assert!(
            motif_at(&stripes, &motif_mask(&stripes), (20, 20))
                .iter()
                .all(|&m| m)
        );
    }

    /// A textured disc of radius 24 on black with a black hole of radius `hole` at its
    /// centre, 64 x 64.
    fn holed_disc(hole: f32) -> Image {
        image(64, 64, |y, x| {
            let r = ((y as f32 - 32.0).powi(2) + (x as f32 - 32.0).powi(2)).sqrt();
            if (hole..24.0).contains(&r) {
                [if (x / 3 + y / 3) % 2 == 0 { 0.9 } else { 0.3 }, 0.6, 0.4]
            } else {
                [0.02; 3]
            }
        })
    }

    #[test]
    fn the_background_seen_through_the_object_is_background_when_small() {
        // A hole of radius 5 (about 80 px against the 2300 px of background reached from
        // the border): the background seen through the object, not a motif.
        let m = motif_mask(&holed_disc(5.0));
        assert!(!m[0], "the corner");
        assert!(!m[32 * 64 + 32] && !m[32 * 64 + 35], "the hole");
        assert!(m[32 * 64 + 40] && m[32 * 64 + 12], "the disc around it");
        // A hole of radius 12 (about 450 px, over a tenth of the background): black is
        // also a colour of the object there, and it stays a motif.
        let m = motif_mask(&holed_disc(12.0));
        assert!(!m[0], "the corner");
        assert!(m[32 * 64 + 32], "the large hole");
    }
}

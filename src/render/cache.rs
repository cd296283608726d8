//! The frozen-geometry contribution cache (issue: colour gradients).
//!
//! During stylization only colours change, so every pixel's blending weights
//! `w_pi = alpha_i T_i` and its final transmittance are constants of the view. A
//! [`ViewCache`] stores them once: per tile, a run per contributing splat (its local
//! index) with the records where it blends (tile pixel and the run's index in the tile
//! packed in a `u32`, weight `f32`), in front-to-back order, plus `T_final` per pixel.
//! Colour forward is then the sparse product `C_p = sum_i w_pi c_i + T_p bg` and the
//! backward its transpose, with no projection, sorting or exponentials. The forward
//! reproduces [`super::render`]'s RGB bit for bit (same weights, same summation order).
//!
//! The loops have no branch on a run's length, the cost that dominated them (a run has
//! about 5 records): the forward walks a tile's records in one loop, each naming its
//! run's colour (gathered per tile first); the backward, whose per-run sums do not
//! depend on the order of the runs, takes a tile's runs shortest first.
//!
//! Memory is about 8 bytes per splat-pixel blend + 12 bytes per (tile, splat) run +
//! 4 bytes per pixel ([`ViewCache::bytes`]). [`CacheMode`] chooses between caching
//! every view, none, or as many as fit a byte budget.

use super::backward::merge;
use super::project::TILE;
use super::raster::{HALF, Sink, TP, TileState, composite_tile};
use super::{Frame, project, validate_camera, validate_scene};
use crate::{Camera, Error, Result, Scene};
use rayon::prelude::*;

/// Whether per-view contribution caches are kept across optimisation steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CacheMode {
    /// Cache every view.
    On,
    /// Recompute projection, sorting and compositing for every view at every step.
    Off,
    /// Cache views in order while their total size stays within this many bytes; the
    /// remaining views are recomputed each step. For the cyclic view order of a fit
    /// this static choice is optimal (an LRU would evict each view just before reuse).
    Budget(usize),
}

impl std::str::FromStr for CacheMode {
    type Err = Error;
    /// `on`, `off` or `budget=MB` (megabytes, 10^6 bytes).
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "on" => Ok(CacheMode::On),
            "off" => Ok(CacheMode::Off),
            _ => {
                let mb = s
                    .strip_prefix("budget=")
                    .and_then(|v| v.parse::<f64>().ok())
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| {
                        Error::param(format!(
                            "cache mode {s:?}: expected on, off or budget=MB (MB >= 0)"
                        ))
                    })?;
                Ok(CacheMode::Budget((mb * 1e6) as usize))
            }
        }
    }
}

/// One tile's `(local index, dL/dc)` per run, before [`merge`].
type TileGrads = Vec<(u32, [f32; 3])>;

/// Blending weights of one view (see module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewCache {
    pub width: usize,
    pub height: usize,
    tiles_x: usize,
    /// Scene indices of the splats with at least one blend; runs index into this.
    gaussians: Vec<u32>,
    /// `tile_runs[t]..tile_runs[t+1]`: the runs of tile `t`.
    tile_runs: Vec<u32>,
    run_splat: Vec<u32>,
    /// `run_start[r]..run_start[r+1]`: the records of run `r`.
    run_start: Vec<u32>,
    /// Per record: the tile pixel (low 8 bits) and its run's index within the tile.
    rec: Vec<u32>,
    weight: Vec<f32>,
    /// Per tile, the indices within the tile of its runs, shortest first (the
    /// backward's order).
    by_len: Vec<u32>,
    /// Final transmittance per pixel, row-major.
    t_final: Vec<f32>,
}

#[derive(Default)]
struct TileRecords {
    run_splat: Vec<u32>,
    run_len: Vec<u32>,
    pix: Vec<u8>,
    weight: Vec<f32>,
    t: Vec<f32>,
    /// Records before the current splat's.
    start: usize,
}

impl Sink for TileRecords {
    #[inline(always)]
    fn begin(&mut self, _local: u32, _slot: usize) {
        self.start = self.pix.len();
    }

    #[inline(always)]
    fn half(&mut self, r: usize, h: usize, w: &[f32; HALF]) {
        for (c, &wc) in w.iter().enumerate() {
            if wc != 0.0 {
                self.pix.push((r * TILE + h * HALF + c) as u8);
                self.weight.push(wc);
            }
        }
    }

    #[inline(always)]
    fn end(&mut self, local: u32, _slot: usize, _any: bool) {
        let n = self.pix.len() - self.start;
        if n > 0 {
            self.run_splat.push(local);
            self.run_len.push(n as u32);
        }
    }
}

impl ViewCache {
    /// Project, sort and composite `scene` once for `camera`, keeping the weights.
    pub fn build(scene: &Scene, camera: &Camera) -> Result<ViewCache> {
        validate_camera(camera)?;
        validate_scene(scene)?;
        Ok(Self::from_frame(&project(scene, camera)))
    }

    /// Build from a projected frame.
    pub fn from_frame(frame: &Frame) -> ViewCache {
        let nt = frame.tiles_x * frame.tiles_y;
        let tiles: Vec<TileRecords> = (0..nt)
            .into_par_iter()
            .map_init(TileState::new, |st, t| {
                let mut rec = TileRecords::default();
                composite_tile(frame, t, st, &mut rec);
                rec.t = (0..TP)
                    .map(|p| st.transmittance(p / TILE, p % TILE))
                    .collect();
                rec
            })
            .collect();
        // Compact local indices: splats with at least one record, in splat order.
        let mut used = vec![u32::MAX; frame.splats.ids.len()];
        for tr in &tiles {
            for &s in &tr.run_splat {
                used[s as usize] = 0;
            }
        }
        let mut gaussians = Vec::new();
        for (s, u) in used.iter_mut().enumerate() {
            if *u == 0 {
                *u = gaussians.len() as u32;
                gaussians.push(frame.splats.ids[s]);
            }
        }
        let (w, h) = (frame.width, frame.height);
        let runs: usize = tiles.iter().map(|t| t.run_splat.len()).sum();
        let mut c = ViewCache {
            width: w,
            height: h,
            tiles_x: frame.tiles_x,
            gaussians,
            tile_runs: vec![0],
            run_splat: Vec::new(),
            run_start: vec![0],
            rec: Vec::new(),
            weight: Vec::new(),
            by_len: Vec::with_capacity(runs),
            t_final: vec![1.0; w * h],
        };
        let recs: usize = tiles.iter().map(|t| t.pix.len()).sum();
        c.run_splat.reserve_exact(runs);
        c.run_start.reserve_exact(runs);
        c.rec.reserve_exact(recs);
        c.weight.reserve_exact(recs);
        for (t, tr) in tiles.into_iter().enumerate() {
            // A pixel blends at most ~2,350 splats (alpha >= 1/255 until T < 1e-4), so
            // a tile's records, and its runs, stay far below 2^24.
            assert!(
                tr.run_len.len() < 1 << 24,
                "ViewCache: too many runs in a tile"
            );
            let mut k = 0;
            for (j, (&s, &n)) in tr.run_splat.iter().zip(&tr.run_len).enumerate() {
                c.run_splat.push(used[s as usize]);
                let last = *c.run_start.last().unwrap_or(&0);
                c.run_start.push(last + n);
                let span = k..k + n as usize;
                c.rec
                    .extend(tr.pix[span].iter().map(|&p| u32::from(p) | (j as u32) << 8));
                k += n as usize;
            }
            let mut order: Vec<u32> = (0..tr.run_len.len() as u32).collect();
            order.sort_by_key(|&j| tr.run_len[j as usize]);
            c.by_len.extend(order);
            c.tile_runs.push(c.run_splat.len() as u32);
            c.weight.extend_from_slice(&tr.weight);
            let x0 = (t % c.tiles_x) * TILE;
            let y0 = (t / c.tiles_x) * TILE;
            for r in 0..(h - y0).min(TILE) {
                for col in 0..(w - x0).min(TILE) {
                    c.t_final[(y0 + r) * w + x0 + col] = tr.t[r * TILE + col];
                }
            }
        }
        c
    }

    /// Scene indices of the contributing Gaussians; colours passed to
    /// [`Self::forward`] and gradients from [`Self::backward`] are indexed like this.
    pub fn gaussians(&self) -> &[u32] {
        &self.gaussians
    }

    /// Number of splat-pixel blends stored.
    pub fn blends(&self) -> usize {
        self.weight.len()
    }

    /// Heap bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.gaussians.len()
            + self.tile_runs.len()
            + self.run_splat.len()
            + self.run_start.len()
            + self.rec.len()
            + self.weight.len()
            + self.by_len.len()
            + self.t_final.len())
    }

    /// Alpha `1 - T_final`, `[H, W]`.
    pub fn alpha(&self) -> Vec<f32> {
        self.t_final.iter().map(|t| 1.0 - t).collect()
    }

    fn tiles(&self) -> usize {
        self.tile_runs.len() - 1
    }

    /// RGB `[H, W, 3]` for colours `colours[j]` of `gaussians()[j]` over `background`.
    pub fn forward(&self, colours: &[[f32; 3]], background: [f32; 3]) -> Vec<f32> {
        let mut rgb = vec![0.0f32; self.width * self.height * 3];
        self.forward_into(colours, background, &mut rgb);
        rgb
    }

    /// [`Self::forward`] into `rgb` (`[H, W, 3]`, every value overwritten), so that a
    /// caller rendering many steps reuses one buffer.
    ///
    /// A pixel's three sums are held side by side with a fourth lane (always 0) so that
    /// each record is one 4-wide multiply and add; every channel still adds `w c` (the
    /// product rounded, then the sum) in record order, so the bits are the per-channel
    /// loop's.
    pub fn forward_into(&self, colours: &[[f32; 3]], background: [f32; 3], rgb: &mut [f32]) {
        let w = self.width;
        assert_eq!(rgb.len(), w * self.height * 3, "forward_into: buffer size");
        let tiles_x = self.tiles_x;
        rgb.par_chunks_mut(TILE * w * 3)
            .enumerate()
            .for_each_init(Vec::new, |cr, (ty, out)| {
                let rows = out.len() / (3 * w);
                for tx in 0..tiles_x {
                    let t = ty * tiles_x + tx;
                    let acc = self.tile_sums(t, colours, cr);
                    let x0 = tx * TILE;
                    for r in 0..rows {
                        for col in 0..(w - x0).min(TILE) {
                            let p = r * TILE + col;
                            let o = r * w + x0 + col;
                            let tf = self.t_final[(ty * TILE + r) * w + x0 + col];
                            for ch in 0..3 {
                                out[o * 3 + ch] = acc[p][ch] + tf * background[ch];
                            }
                        }
                    }
                }
            });
    }

    /// Tile `t`'s colour sums `sum_i w_pi c_i` per pixel, a pixel's three channels and
    /// a 0 side by side; `cr` holds the tile's run colours (reused across tiles). The
    /// records are added in their order, so each pixel's sum runs front to back.
    fn tile_sums(&self, t: usize, colours: &[[f32; 3]], cr: &mut Vec<[f32; 4]>) -> [[f32; 4]; TP] {
        let runs = self.tile_runs[t] as usize..self.tile_runs[t + 1] as usize;
        cr.clear();
        cr.extend(runs.clone().map(|r| {
            let [c0, c1, c2] = colours[self.run_splat[r] as usize];
            [c0, c1, c2, 0.0]
        }));
        let recs = self.run_start[runs.start] as usize..self.run_start[runs.end] as usize;
        let mut acc = [[0.0f32; 4]; TP];
        for (&k, &wt) in self.rec[recs.clone()].iter().zip(&self.weight[recs]) {
            let a = &mut acc[(k & 0xff) as usize];
            let c = cr[(k >> 8) as usize];
            for ch in 0..4 {
                a[ch] += wt * c[ch];
            }
        }
        acc
    }

    /// Tile `t`'s `(local, dL/dc)` per run given dL/dC `g` over the tile (the layout of
    /// [`Self::tile_sums`]), the runs shortest first: each run's sum is over its own
    /// records in their order, so the order of the runs changes no bit.
    fn tile_grads(&self, t: usize, g: &[[f32; 4]; TP]) -> TileGrads {
        let runs = self.tile_runs[t] as usize..self.tile_runs[t + 1] as usize;
        let mut out = Vec::with_capacity(runs.len());
        for &j in &self.by_len[runs.clone()] {
            let r = runs.start + j as usize;
            let span = self.run_start[r] as usize..self.run_start[r + 1] as usize;
            let mut s = [0.0f32; 4];
            for (&k, &wt) in self.rec[span.clone()].iter().zip(&self.weight[span]) {
                let gp = &g[(k & 0xff) as usize];
                for ch in 0..4 {
                    s[ch] += wt * gp[ch];
                }
            }
            out.push((self.run_splat[r], [s[0], s[1], s[2]]));
        }
        out
    }

    /// `dL/dc` per entry of `gaussians()` given `dL/dC` as an `[H, W, 3]` image (a
    /// pixel's three gradients side by side, as in [`Self::forward_into`]: each channel's
    /// sum is the per-channel loop's, bit for bit).
    pub fn backward(&self, grad_rgb: &[f32]) -> Vec<[f32; 3]> {
        let per_tile: Vec<TileGrads> = (0..self.tiles())
            .into_par_iter()
            .map(|t| {
                let g = load_tile4(grad_rgb, self.width, self.height, t, self.tiles_x);
                self.tile_grads(t, &g)
            })
            .collect();
        merge(per_tile, self.gaussians.len())
    }

    /// The mean squared error against `target` (`[H, W, 3]`) and its `dL/dc` per entry
    /// of `gaussians()`, forward, loss and backward fused tile by tile (no image is
    /// written): the gradient is [`crate::optim::l2`]'s through [`Self::backward`] bit
    /// for bit, `2 (C - T) / n` with `C` as [`Self::forward_into`] makes it. The loss's
    /// f64 sums run per tile and channel, then over the tiles in order: the same for any
    /// thread count, not `l2`'s row-major sum bit for bit.
    pub fn l2_backward(
        &self,
        colours: &[[f32; 3]],
        background: [f32; 3],
        target: &[f32],
    ) -> (f64, Vec<[f32; 3]>) {
        let (w, h) = (self.width, self.height);
        assert_eq!(target.len(), w * h * 3, "l2_backward: target size");
        let n = target.len().max(1) as f32;
        let bg = [background[0], background[1], background[2], 0.0];
        let per_tile: Vec<(f64, TileGrads)> = (0..self.tiles())
            .into_par_iter()
            .map_init(Vec::new, |cr, t| {
                let acc = self.tile_sums(t, colours, cr);
                // dL/dC in the same layout (lane 3 and pixels outside the image: 0).
                let mut g = [[0.0f32; 4]; TP];
                let mut loss = [0.0f64; 4];
                let (x0, y0) = ((t % self.tiles_x) * TILE, (t / self.tiles_x) * TILE);
                for r in 0..(h - y0).min(TILE) {
                    for col in 0..(w - x0).min(TILE) {
                        let p = r * TILE + col;
                        let o = (y0 + r) * w + x0 + col;
                        let tf = self.t_final[o];
                        let tv = &target[o * 3..o * 3 + 3];
                        let tv = [tv[0], tv[1], tv[2], 0.0];
                        for ch in 0..4 {
                            let d = (acc[p][ch] + tf * bg[ch]) - tv[ch];
                            loss[ch] += f64::from(d * d);
                            g[p][ch] = 2.0 * d / n;
                        }
                    }
                }
                (loss[0] + loss[1] + loss[2], self.tile_grads(t, &g))
            })
            .collect();
        let loss = per_tile.iter().map(|t| t.0).sum::<f64>() / f64::from(n);
        (
            loss,
            merge(
                per_tile.into_iter().map(|t| t.1).collect(),
                self.gaussians.len(),
            ),
        )
    }
}

/// Tile `tile` of an `[H, W, 3]` image, a pixel's three values and a 0 side by side,
/// row-major within the tile (zero outside the image).
fn load_tile4(
    img: &[f32],
    width: usize,
    height: usize,
    tile: usize,
    tiles_x: usize,
) -> Box<[[f32; 4]; TP]> {
    let mut g = Box::new([[0.0f32; 4]; TP]);
    let x0 = (tile % tiles_x) * TILE;
    let y0 = (tile / tiles_x) * TILE;
    for r in 0..(height - y0).min(TILE) {
        for c in 0..(width - x0).min(TILE) {
            let o = ((y0 + r) * width + x0 + c) * 3;
            g[r * TILE + c] = [img[o], img[o + 1], img[o + 2], 0.0];
        }
    }
    g
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::tests::{front_camera, random_scene};

    /// A non-negative random colour per contributing Gaussian of `c`.
    fn random_colours(c: &ViewCache, rng: &mut crate::rng::Rng) -> Vec<[f32; 3]> {
        (0..c.gaussians().len())
            .map(|_| {
                let x = rng.normals_f32(3);
                [x[0].abs(), x[1].abs(), x[2].abs()]
            })
            .collect()
    }

    /// The per-channel loops the 4-wide ones replaced: the same bits, forward and
    /// backward (SH degree 0 and 2, a camera whose width is not a multiple of the tile).
    #[test]
    fn four_wide_sums_are_the_per_channel_loops_bitwise() {
        for deg in [0, 2] {
            let scene = random_scene(3000, deg, 40 + deg as u64);
            let cam = front_camera(90, 60, 80.0, 3.0);
            let c = ViewCache::build(&scene, &cam).unwrap();
            let mut rng = crate::rng::Rng::new(9);
            let colours = random_colours(&c, &mut rng);
            let bg = [0.1, 0.5, 0.9];
            let (w, h) = (c.width, c.height);
            let mut want = vec![0.0f32; w * h * 3];
            let grad = rng.normals_f32(w * h * 3);
            let mut want_g = vec![[0.0f32; 3]; colours.len()];
            for t in 0..c.tiles() {
                let (x0, y0) = ((t % c.tiles_x) * TILE, (t / c.tiles_x) * TILE);
                let mut acc = [[0.0f32; TP]; 3];
                for r in c.tile_runs[t] as usize..c.tile_runs[t + 1] as usize {
                    let (j, mut s) = (c.run_splat[r] as usize, [0.0f32; 3]);
                    for k in c.run_start[r] as usize..c.run_start[r + 1] as usize {
                        let p = (c.rec[k] & 0xff) as usize;
                        let o = ((y0 + p / TILE) * w + x0 + p % TILE) * 3;
                        for ch in 0..3 {
                            acc[ch][p] += c.weight[k] * colours[j][ch];
                            s[ch] += c.weight[k] * grad[o + ch];
                        }
                    }
                    for ch in 0..3 {
                        want_g[j][ch] += s[ch];
                    }
                }
                for p in 0..TP {
                    let (y, x) = (y0 + p / TILE, x0 + p % TILE);
                    if y < h && x < w {
                        for ch in 0..3 {
                            want[(y * w + x) * 3 + ch] = acc[ch][p] + c.t_final[y * w + x] * bg[ch];
                        }
                    }
                }
            }
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&c.forward(&colours, bg)), bits(&want), "degree {deg}");
            let got_g = c.backward(&grad);
            assert_eq!(bits(got_g.as_flattened()), bits(want_g.as_flattened()));
        }
    }

    /// The fused squared error: its gradient is `l2`'s image gradient through
    /// `backward`, bit for bit, and its loss `l2`'s to rounding (a camera whose width and
    /// height are not multiples of the tile, so edge tiles hold pixels outside the image).
    #[test]
    fn l2_backward_is_l2_through_backward() {
        let scene = random_scene(2500, 1, 77);
        let cam = front_camera(45, 38, 60.0, 3.0);
        let c = ViewCache::build(&scene, &cam).unwrap();
        let mut rng = crate::rng::Rng::new(5);
        let colours = random_colours(&c, &mut rng);
        let bg = [0.2, 0.7, 0.4];
        let target: Vec<f32> = rng.normals_f32(45 * 38 * 3);
        let (want_loss, grad) = crate::optim::l2(&c.forward(&colours, bg), &target);
        let want = c.backward(&grad);
        let (loss, got) = c.l2_backward(&colours, bg, &target);
        let bits = |v: &[[f32; 3]]| {
            v.as_flattened()
                .iter()
                .map(|x| x.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&got), bits(&want));
        assert!(want.iter().flatten().any(|&g| g != 0.0));
        assert!(
            (loss - want_loss).abs() <= 1e-12 * want_loss,
            "{loss} vs {want_loss}"
        );
    }
}

//! The frozen-geometry contribution cache (issue: colour gradients).
//!
//! During stylization only colours change, so every pixel's blending weights
//! `w_pi = alpha_i T_i` and its final transmittance are constants of the view. A
//! [`ViewCache`] stores them once: per tile, a run per contributing splat (its local
//! index) with the (tile pixel `u8`, weight `f32`) records where it blends, in
//! front-to-back order, plus `T_final` per pixel. Colour forward is then the sparse
//! product `C_p = sum_i w_pi c_i + T_p bg` and the backward its transpose, with no
//! projection, sorting or exponentials. The forward reproduces [`super::render`]'s RGB
//! bit for bit (same weights, same summation order).
//!
//! Memory is about 5 bytes per splat-pixel blend + 8 bytes per (tile, splat) run +
//! 4 bytes per pixel ([`ViewCache::bytes`]). [`CacheMode`] chooses between caching
//! every view, none, or as many as fit a byte budget.

use super::backward::{load_tile, merge};
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
    pix: Vec<u8>,
    weight: Vec<f32>,
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
        let mut c = ViewCache {
            width: w,
            height: h,
            tiles_x: frame.tiles_x,
            gaussians,
            tile_runs: vec![0],
            run_splat: Vec::new(),
            run_start: vec![0],
            pix: Vec::new(),
            weight: Vec::new(),
            t_final: vec![1.0; w * h],
        };
        let runs: usize = tiles.iter().map(|t| t.run_splat.len()).sum();
        let recs: usize = tiles.iter().map(|t| t.pix.len()).sum();
        c.run_splat.reserve_exact(runs);
        c.run_start.reserve_exact(runs);
        c.pix.reserve_exact(recs);
        c.weight.reserve_exact(recs);
        for (t, tr) in tiles.into_iter().enumerate() {
            for (&s, &n) in tr.run_splat.iter().zip(&tr.run_len) {
                c.run_splat.push(used[s as usize]);
                let last = *c.run_start.last().unwrap_or(&0);
                c.run_start.push(last + n);
            }
            c.tile_runs.push(c.run_splat.len() as u32);
            c.pix.extend_from_slice(&tr.pix);
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
            + self.weight.len()
            + self.t_final.len())
            + self.pix.len()
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
    pub fn forward_into(&self, colours: &[[f32; 3]], background: [f32; 3], rgb: &mut [f32]) {
        let w = self.width;
        assert_eq!(rgb.len(), w * self.height * 3, "forward_into: buffer size");
        let tiles_x = self.tiles_x;
        rgb.par_chunks_mut(TILE * w * 3)
            .enumerate()
            .for_each(|(ty, out)| {
                let rows = out.len() / (3 * w);
                let mut acc = [[0.0f32; TP]; 3];
                for tx in 0..tiles_x {
                    for a in acc.iter_mut() {
                        a.fill(0.0);
                    }
                    let t = ty * tiles_x + tx;
                    for r in self.tile_runs[t] as usize..self.tile_runs[t + 1] as usize {
                        let c = colours[self.run_splat[r] as usize];
                        let span = self.run_start[r] as usize..self.run_start[r + 1] as usize;
                        for (&p, &wt) in self.pix[span.clone()].iter().zip(&self.weight[span]) {
                            let p = p as usize;
                            acc[0][p] += wt * c[0];
                            acc[1][p] += wt * c[1];
                            acc[2][p] += wt * c[2];
                        }
                    }
                    let x0 = tx * TILE;
                    for r in 0..rows {
                        for col in 0..(w - x0).min(TILE) {
                            let p = r * TILE + col;
                            let o = r * w + x0 + col;
                            let tf = self.t_final[(ty * TILE + r) * w + x0 + col];
                            for ch in 0..3 {
                                out[o * 3 + ch] = acc[ch][p] + tf * background[ch];
                            }
                        }
                    }
                }
            });
    }

    /// `dL/dc` per entry of `gaussians()` given `dL/dC` as an `[H, W, 3]` image.
    pub fn backward(&self, grad_rgb: &[f32]) -> Vec<[f32; 3]> {
        let per_tile: Vec<Vec<(u32, [f32; 3])>> = (0..self.tiles())
            .into_par_iter()
            .map(|t| {
                let g = load_tile(grad_rgb, self.width, self.height, t, self.tiles_x);
                let g = [
                    g[0].as_flattened(),
                    g[1].as_flattened(),
                    g[2].as_flattened(),
                ];
                let runs = self.tile_runs[t] as usize..self.tile_runs[t + 1] as usize;
                let mut out = Vec::with_capacity(runs.len());
                for r in runs {
                    let span = self.run_start[r] as usize..self.run_start[r + 1] as usize;
                    let mut s = [0.0f32; 3];
                    for (&p, &wt) in self.pix[span.clone()].iter().zip(&self.weight[span]) {
                        let p = p as usize;
                        s[0] += wt * g[0][p];
                        s[1] += wt * g[1][p];
                        s[2] += wt * g[2][p];
                    }
                    out.push((self.run_splat[r], s));
                }
                out
            })
            .collect();
        merge(per_tile, self.gaussians.len())
    }
}

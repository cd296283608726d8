//! The patch prior's clean estimates per conditioning (the module docs' table,
//! FantasyStyle Sec. 4, CSD eq. 7-9): the style's texture (balanced, optionally guided,
//! coarse to fine: Kwatra et al. 2005; GPNN), the style image's layout as the content
//! model, the source views' own local patch model (Kamb & Ganguli, ICML 2025), over the
//! window of object pixels a call's control image gives.

use super::*;

/// What one call knows about the window: the source views in latent space and which
/// latent pixels are the object.
pub(super) struct Window {
    /// `[B, 3, h, w]`.
    pub(super) source: Option<Array4<f32>>,
    /// Object pixels (b, y, x): every pixel without a coverage channel.
    pub(super) pixels: Vec<[usize; 3]>,
}

impl Window {
    /// The window of a control image (`[B, 4, H, W]`: the source as the prior sees it and
    /// its coverage; `[B, 3, H, W]`: no coverage) for latents of `shape`.
    pub(super) fn of(
        control: Option<ArrayView4<'_, f32>>,
        f: usize,
        shape: (usize, usize, usize, usize),
    ) -> Result<Window> {
        let (b, _, h, w) = shape;
        let all = || -> Vec<[usize; 3]> {
            (0..b * h * w)
                .map(|i| [i / (h * w), (i / w) % h, i % w])
                .collect()
        };
        let Some(c) = control else {
            return Ok(Window {
                source: None,
                pixels: all(),
            });
        };
        let rgb = c.slice(ndarray::s![.., 0..3, .., ..]);
        let source = latent::encode(rgb, f)?;
        if source.dim() != shape {
            return Err(Error::param(format!(
                "patch prior: control latents {:?}, latents {shape:?}",
                source.dim()
            )));
        }
        let pixels = if c.dim().1 >= 4 {
            let alpha = latent::pool(c.slice(ndarray::s![.., 3..4, .., ..]), f);
            all()
                .into_iter()
                .filter(|&[n, y, x]| alpha[[n, 0, y, x]] > OBJECT_ALPHA)
                .collect()
        } else {
            all()
        };
        Ok(Window {
            source: Some(source),
            pixels,
        })
    }

    pub(super) fn source(&self, what: &str) -> Result<&Array4<f32>> {
        self.source.as_ref().ok_or_else(|| {
            Error::param(format!(
                "the patch prior needs the source views (its control image) for {what}"
            ))
        })
    }
}

/// `x0` at `pixels` written into the images `base` `[B, C, h, w]`.
fn scatter(base: &mut Array4<f32>, pixels: &[[usize; 3]], x0: &Array2<f32>) {
    for (i, &[b, y, x]) in pixels.iter().enumerate() {
        for c in 0..x0.ncols() {
            base[[b, c, y, x]] = x0[[i, c]];
        }
    }
}

impl PatchPrior {
    /// The clean estimate `[B, C, h, w]` of `cond` (module docs' table) at the object's
    /// pixels; elsewhere the Null model's.
    pub(super) fn clean(
        &mut self,
        z: ArrayView4<'_, f32>,
        t: usize,
        cond: Cond,
        win: &Window,
    ) -> Result<Array4<f32>> {
        let (sa, sb) = self.schedule.coefficients(t)?;
        let level = Level {
            sa: sa as f32,
            sb: sb as f32,
        };
        let k = self.patch_size(t)?;
        let mut imgs = vec![self.style.view()];
        if let Some(s) = &win.source {
            imgs.extend(s.axis_iter(Axis(0)));
        }
        let mut x0 = PixelGaussian::of(&imgs).denoise(z, sa, sb);
        if win.pixels.is_empty() {
            return Ok(x0);
        }
        let est = match cond {
            Cond::Null => return Ok(x0),
            Cond::Content => self.content(z, k, level, &win.pixels)?,
            Cond::Prompt => match self.style_scale(t) {
                sc if sc > 1 && self.config.coarse_source => self.own_coarse(z, sc, level, win)?,
                _ => self.own(z, k, level, win)?,
            },
            Cond::PromptStyle => match self.style_scale(t) {
                1 => self.styled(z, k, level, win)?,
                sc => self.styled_coarse(z, sc, level, win)?,
            },
        };
        scatter(&mut x0, &win.pixels, &est);
        Ok(x0)
    }

    /// The content model's estimate `[P, C]` at `pixels`: the latents pooled
    /// `content_scale` times (noise std sb / scale), denoised with the pooled style's
    /// patches, upsampled back.
    pub(super) fn content(
        &mut self,
        z: ArrayView4<'_, f32>,
        k: usize,
        level: Level,
        pixels: &[[usize; 3]],
    ) -> Result<Array2<f32>> {
        let s = self.config.content_scale;
        let (zp, coarse) = pooled_grid(z, s)?;
        let (b, c, hs, ws) = zp.dim();
        let x = patches_at(zp.view(), k, &coarse);
        let search = self.config.search(false);
        let lv = Level {
            sa: level.sa,
            sb: level.sb / s as f32,
        };
        let est = denoise::denoise(self.content_bank(k)?, x.view(), lv, search, None);
        let mut img = Array4::<f32>::zeros((b, c, hs, ws));
        scatter(&mut img, &coarse, &est);
        let up = latent::upsample(img.view(), s);
        Ok(Array2::from_shape_fn((pixels.len(), c), |(i, ch)| {
            let [n, y, x] = pixels[i];
            up[[n, ch, y, x]]
        }))
    }

    /// The layout model's clean estimate `[B, C, h, w]` and its responsibility
    /// `[B, 1, h, w]` against the generic model: on latents pooled `content_scale` times
    /// (noise std sb / scale), the posterior probability that a coarse patch comes from
    /// the style's coarse patches (prior `layout_prior`, likelihood (1/M) sum_j
    /// N(x; sa y_j, sb^2 I)) rather than from the moment-matched Gaussian of those patches
    /// ([`bank::PatchGaussian`]), both upsampled back.
    pub(super) fn layout(
        &mut self,
        z: ArrayView4<'_, f32>,
        t: usize,
    ) -> Result<(Array4<f32>, Array4<f32>)> {
        let (sa, sb) = self.schedule.coefficients(t)?;
        let k = self.patch_size(t)?;
        let s = self.config.content_scale;
        let (zp, coarse) = pooled_grid(z, s)?;
        let (b, c, hs, ws) = zp.dim();
        let x = patches_at(zp.view(), k, &coarse);
        let lv = Level {
            sa: sa as f32,
            sb: (sb / s as f64) as f32,
        };
        let search = self.config.search(false);
        let prior_logit = (self.config.layout_prior / (1.0 - self.config.layout_prior)).ln();
        let bank = self.content_bank(k)?;
        let (est, evidence) = denoise::denoise_with_evidence(bank, x.view(), lv, search);
        let gauss = bank::PatchGaussian::of(bank)
            .ok_or_else(|| Error::param("the layout model needs pca_dims > 0"))?;
        let red = bank.reduced.as_ref().expect("PatchGaussian::of checked");
        let coords = red.pca.project(x.view(), lv.sa);
        let d = x.ncols() as f32;
        let norm = bank.len() as f32;
        let mut img = Array4::<f32>::zeros((b, c, hs, ws));
        let mut resp = Array4::<f32>::zeros((b, 1, hs, ws));
        scatter(&mut img, &coarse, &est);
        let mean_dot = red.pca.mean.dot(&red.pca.mean) * lv.sa * lv.sa;
        for (i, &[n, y, xx]) in coarse.iter().enumerate() {
            let xi = x.row(i);
            let dist2 = xi.dot(&xi) - 2.0 * lv.sa * xi.dot(&red.pca.mean) + mean_dot;
            let ll_gen = gauss.log_density(coords.row(i), dist2, lv.sa, lv.sb);
            let two_pi_var = 2.0 * std::f32::consts::PI * lv.sb * lv.sb;
            let ll_bank = evidence[i] - norm.ln() - 0.5 * d * two_pi_var.ln();
            let logit = prior_logit + ll_bank - ll_gen;
            resp[[n, 0, y, xx]] = 1.0 / (1.0 + (-logit).exp());
        }
        Ok((
            latent::upsample(img.view(), s),
            latent::upsample(resp.view(), s),
        ))
    }

    /// The source model's estimate `[P, C]` at the object's pixels: each view's own
    /// patches near the pixel ([`denoise::denoise_local`]).
    pub(super) fn own(
        &self,
        z: ArrayView4<'_, f32>,
        k: usize,
        level: Level,
        win: &Window,
    ) -> Result<Array2<f32>> {
        let src = win.source("the source model (Prompt)")?;
        let r = self.config.source_radius;
        Ok(denoise::denoise_local(
            src.view(),
            z,
            &win.pixels,
            k,
            r,
            level,
        ))
    }

    /// The style model's estimate `[P, C]` at the object's pixels: balanced, guided, and
    /// blended with the source model's below full strength.
    pub(super) fn styled(
        &mut self,
        z: ArrayView4<'_, f32>,
        k: usize,
        level: Level,
        win: &Window,
    ) -> Result<Array2<f32>> {
        let cfg = self.config.clone();
        let x = patches_at(z, k, &win.pixels);
        let guides = if cfg.guide_weight > 0.0 {
            let src = win.source("the structure guide")?;
            let sg: Vec<Array3<f32>> = src.axis_iter(Axis(0)).map(structure).collect();
            let views: Vec<_> = sg.iter().map(|a| a.view()).collect();
            let sg = ndarray::stack(Axis(0), &views).map_err(|e| Error::Other(e.to_string()))?;
            let bank = patches(self.style_guide.view(), k, cfg.style_stride);
            Some((patches_at(sg.view(), k, &win.pixels), bank))
        } else {
            None
        };
        let guide = guides.as_ref().map(|(q, b)| Guide {
            query: q.view(),
            bank: b.view(),
            weight: cfg.guide_weight,
        });
        let bank = self.style_bank(1, k)?;
        let styled = denoise::denoise(bank, x.view(), level, cfg.search(true), guide);
        if self.strength >= 1.0 {
            return Ok(styled);
        }
        let own = self.own(z, k, level, win)?;
        let s = self.strength;
        Ok(styled * s + own * (1.0 - s))
    }
}

impl PatchPrior {
    /// The style model at scale `sc` (module docs, coarse-to-fine): the object's coarse
    /// pixels denoised on latents pooled `sc` times (noise std sb / sc) with the pooled
    /// style's `patch_max` patches, upsampled, plus the finer detail of z_t / sa (whose
    /// noise the source model's coarse estimate passes through the same way, so CSD's
    /// difference cancels it).
    pub(super) fn styled_coarse(
        &mut self,
        z: ArrayView4<'_, f32>,
        sc: usize,
        level: Level,
        win: &Window,
    ) -> Result<Array2<f32>> {
        let k = self.config.patch_max;
        let (zp, coarse, lv) = coarse_queries(z, sc, level, win)?;
        let x = patches_at(zp.view(), k, &coarse);
        let search = self.config.search(true);
        let est = denoise::denoise(self.style_bank(sc, k)?, x.view(), lv, search, None);
        Ok(refine(z, &zp, sc, level, win, &coarse, &est))
    }

    /// The source model at scale `sc`: each pooled source view's own patches near the
    /// coarse pixel, upsampled, plus the finer detail of z_t / sa.
    pub(super) fn own_coarse(
        &self,
        z: ArrayView4<'_, f32>,
        sc: usize,
        level: Level,
        win: &Window,
    ) -> Result<Array2<f32>> {
        let k = self.config.patch_max;
        let src = latent::pool(win.source("the source model (Prompt)")?.view(), sc);
        let (zp, coarse, lv) = coarse_queries(z, sc, level, win)?;
        let r = self.config.source_radius;
        let est = denoise::denoise_local(src.view(), zp.view(), &coarse, k, r, lv);
        Ok(refine(z, &zp, sc, level, win, &coarse, &est))
    }
}

/// The latents pooled `sc` times, the coarse pixels under the object's pixels, and the
/// pooled noise level (sb / sc).
/// The latents pooled `s` times (the content model's scale) and every pixel of the
/// pooled grid, in order.
fn pooled_grid(z: ArrayView4<'_, f32>, s: usize) -> Result<(Array4<f32>, Vec<[usize; 3]>)> {
    let (b, _, h, w) = z.dim();
    if h % s != 0 || w % s != 0 {
        return Err(Error::param(format!(
            "patch prior: latents of {w}x{h} do not divide by content_scale {s}"
        )));
    }
    let zp = latent::pool(z, s);
    let (hs, ws) = (h / s, w / s);
    let coarse = (0..b * hs * ws)
        .map(|i| [i / (hs * ws), (i / ws) % hs, i % ws])
        .collect();
    Ok((zp, coarse))
}

fn coarse_queries(
    z: ArrayView4<'_, f32>,
    sc: usize,
    level: Level,
    win: &Window,
) -> Result<(Array4<f32>, Vec<[usize; 3]>, Level)> {
    let (_, _, h, w) = z.dim();
    if h % sc != 0 || w % sc != 0 {
        return Err(Error::param(format!(
            "patch prior: latents of {w}x{h} do not divide by coarse_scale {sc}"
        )));
    }
    let mut coarse: Vec<[usize; 3]> = win
        .pixels
        .iter()
        .map(|&[n, y, x]| [n, y / sc, x / sc])
        .collect();
    coarse.sort_unstable();
    coarse.dedup();
    let lv = Level {
        sa: level.sa,
        sb: level.sb / sc as f32,
    };
    Ok((latent::pool(z, sc), coarse, lv))
}

/// The fine estimate `[P, C]` at the object's pixels from a coarse one `est` at
/// `coarse`: upsampled (z_t / sa elsewhere), plus the detail of z_t / sa finer than the
/// pooling.
fn refine(
    z: ArrayView4<'_, f32>,
    zp: &Array4<f32>,
    sc: usize,
    level: Level,
    win: &Window,
    coarse: &[[usize; 3]],
    est: &Array2<f32>,
) -> Array2<f32> {
    let mut img = zp.mapv(|v| v / level.sa);
    scatter(&mut img, coarse, est);
    let up = latent::upsample(img.view(), sc);
    let low = latent::upsample(zp.view(), sc);
    Array2::from_shape_fn((win.pixels.len(), 3), |(i, ch)| {
        let [n, y, x] = win.pixels[i];
        up[[n, ch, y, x]] + (z[[n, ch, y, x]] - low[[n, ch, y, x]]) / level.sa
    })
}

//! The Gaussian prior: the exact (closed-form) optimal denoiser when clean latents are
//! Gaussian, with a linear "VAE". Pure Rust; `scripts/setup/10_gaussian_prior.py` ships
//! the same model as ONNX graphs with a real UNet/VAE/image-encoder I/O contract, and the
//! tests check that both agree.
//!
//! **Denoiser.** If x0 ~ N(mu, diag(var)) per latent channel and z_t = sqrt(ab) x0 +
//! sqrt(1-ab) eps, the MMSE noise prediction is
//! E[eps | z_t] = sqrt(1-ab) (z_t - sqrt(ab) mu) / (ab var + 1 - ab).
//!
//! **VAE.** Encoder: image in `[0,1]` -> x = 2 img - 1 -> 8x8 average pool -> latent
//! z_c = SCALING_FACTOR * sum_k `ENC[c][k]` x_k. ENC's columns are orthogonal (norm 2), so
//! the decoder DEC = pinv(ENC) = ENC^T / 4 followed by 8x8 nearest upsampling inverts the
//! encoder exactly on block-constant images.
//!
//! **Conditioning as tokens.** A token is `[w, w mu_1..C, w var_1..C]` (TOKEN_DIM = 1+2C).
//! The denoiser sums all tokens of a conditioning (text tokens and image tokens) and uses
//! mu = sum(w mu)/sum(w), var = sum(w var)/sum(w): a weighted average of the statistics.
//! All-zero tokens (padding, "no image") contribute nothing. The conditionings:
//!
//! | Cond | text tokens | image tokens | resulting N(mu, var) |
//! |---|---|---|---|
//! | Null | null: N(0, 1) | none | N(0, 1) |
//! | Prompt | prompt: [`PROMPT_MEAN`], [`PROMPT_VAR`] | none | the prompt's |
//! | PromptStyle | prompt | style: mean and var of the style image's latents | average of both |
//! | Content | null | content: mean 0, the style latents' var | average of both |
//!
//! The style image is resized and centre-cropped to [`ENCODER_SIZE`]^2
//! ([`super::preprocess::fit_square`]) before encoding, as the ONNX image encoder's
//! input is that size.

use super::preprocess::{check_finite, check_images, fit_square};
use super::{Cond, Prior, PriorInfo};
use crate::scheduler::{Schedule, SchedulerConfig};
use crate::{Error, Result};
use ndarray::{Array2, Array4, ArrayView2, ArrayView4, Axis, s};

/// Latent channels.
pub const CHANNELS: usize = 4;
/// Image pixels per latent pixel.
pub const DOWNSAMPLE: usize = 8;
/// VAE scaling factor (applied after the raw encoder, removed before the raw decoder).
pub const SCALING_FACTOR: f32 = 0.5;
/// Token width: weight, C means, C variances.
pub const TOKEN_DIM: usize = 1 + 2 * CHANNELS;
/// Side of the (square) image the image encoder takes.
pub const ENCODER_SIZE: usize = 64;
/// Raw encoder: latent channel c = sum_k `ENC[c][k]` x_k on pooled images in `[-1, 1]`.
pub const ENC: [[f32; 3]; CHANNELS] = [
    [1.0, 1.0, 1.0],
    [1.0, -1.0, 1.0],
    [1.0, 1.0, -1.0],
    [1.0, -1.0, -1.0],
];
/// Statistics the prompt embedding stands for (written to `prompt.npy` by set-up).
pub const PROMPT_MEAN: [f32; CHANNELS] = [0.2, -0.1, 0.05, 0.0];
/// See [`PROMPT_MEAN`].
pub const PROMPT_VAR: [f32; CHANNELS] = [0.8, 1.1, 0.9, 1.0];

/// Per-channel mean and variance of a Gaussian over latents.
#[derive(Debug, Clone, PartialEq)]
pub struct Stats {
    pub mean: Vec<f32>,
    pub var: Vec<f32>,
}

impl Stats {
    /// N(0, 1) in every channel.
    pub fn standard() -> Self {
        Stats {
            mean: vec![0.0; CHANNELS],
            var: vec![1.0; CHANNELS],
        }
    }

    /// The prompt's statistics.
    pub fn prompt() -> Self {
        Stats {
            mean: PROMPT_MEAN.to_vec(),
            var: PROMPT_VAR.to_vec(),
        }
    }

    /// The token `[1, mean, var]`.
    pub fn token(&self) -> Vec<f32> {
        let mut t = vec![1.0];
        t.extend_from_slice(&self.mean);
        t.extend_from_slice(&self.var);
        t
    }

    /// Weighted average of the statistics encoded by `tokens` `[n, TOKEN_DIM]`.
    pub fn from_tokens(tokens: ArrayView2<'_, f32>) -> Result<Self> {
        if tokens.ncols() != TOKEN_DIM {
            return Err(Error::param(format!(
                "gaussian prior: tokens have width {}, expected {TOKEN_DIM}",
                tokens.ncols()
            )));
        }
        let sum = tokens.sum_axis(Axis(0));
        let w = sum[0];
        if w.abs() < 1e-12 {
            return Err(Error::param(
                "gaussian prior: the conditioning tokens have zero total weight",
            ));
        }
        Ok(Stats {
            mean: (0..CHANNELS).map(|c| sum[1 + c] / w).collect(),
            var: (0..CHANNELS).map(|c| sum[1 + CHANNELS + c] / w).collect(),
        })
    }

    /// Per-channel mean and population variance of latents `[1, C, h, w]` (all of the
    /// batch pooled together).
    pub fn of_latents(latents: ArrayView4<'_, f32>) -> Self {
        let c = latents.dim().1;
        let mut mean = Vec::with_capacity(c);
        let mut var = Vec::with_capacity(c);
        for ci in 0..c {
            let ch = latents.slice(s![.., ci, .., ..]);
            let n = ch.len() as f64;
            let m = ch.iter().map(|&x| x as f64).sum::<f64>() / n;
            let v = ch.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / n;
            mean.push(m as f32);
            var.push(v as f32);
        }
        Stats { mean, var }
    }
}

/// Encode images `[B, 3, H, W]` in [0, 1] to scaled latents `[B, C, H/8, W/8]`.
pub fn vae_encode(images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
    check_images(images, DOWNSAMPLE, "gaussian prior: encode")?;
    let (b, _, h, w) = images.dim();
    let (lh, lw) = (h / DOWNSAMPLE, w / DOWNSAMPLE);
    let area = (DOWNSAMPLE * DOWNSAMPLE) as f32;
    let mut out = Array4::<f32>::zeros((b, CHANNELS, lh, lw));
    for bi in 0..b {
        for y in 0..lh {
            for x in 0..lw {
                let mut px = [0f32; 3];
                for (k, p) in px.iter_mut().enumerate() {
                    let blk = images.slice(s![
                        bi,
                        k,
                        y * DOWNSAMPLE..(y + 1) * DOWNSAMPLE,
                        x * DOWNSAMPLE..(x + 1) * DOWNSAMPLE
                    ]);
                    *p = blk.iter().map(|&v| 2.0 * v - 1.0).sum::<f32>() / area;
                }
                for c in 0..CHANNELS {
                    let raw: f32 = (0..3).map(|k| ENC[c][k] * px[k]).sum();
                    out[[bi, c, y, x]] = SCALING_FACTOR * raw;
                }
            }
        }
    }
    Ok(out)
}

/// Decode scaled latents `[B, C, h, w]` to images `[B, 3, 8h, 8w]` (not clamped).
pub fn vae_decode(latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
    check_latents(latents)?;
    let (b, _, lh, lw) = latents.dim();
    let mut out = Array4::<f32>::zeros((b, 3, lh * DOWNSAMPLE, lw * DOWNSAMPLE));
    for bi in 0..b {
        for y in 0..lh {
            for x in 0..lw {
                for k in 0..3 {
                    // DEC = ENC^T / 4.
                    let raw: f32 = (0..CHANNELS)
                        .map(|c| ENC[c][k] * 0.25 * latents[[bi, c, y, x]] / SCALING_FACTOR)
                        .sum();
                    let v = (raw + 1.0) * 0.5;
                    out.slice_mut(s![
                        bi,
                        k,
                        y * DOWNSAMPLE..(y + 1) * DOWNSAMPLE,
                        x * DOWNSAMPLE..(x + 1) * DOWNSAMPLE
                    ])
                    .fill(v);
                }
            }
        }
    }
    Ok(out)
}

fn check_latents(z: ArrayView4<'_, f32>) -> Result<()> {
    if z.dim().1 != CHANNELS || z.dim().0 == 0 {
        return Err(Error::param(format!(
            "gaussian prior: expected latents [B>=1, {CHANNELS}, h, w], got {:?}",
            z.shape()
        )));
    }
    check_finite(z, "gaussian prior: latents")
}

/// (style token, content token) of a style image `[1, 3, H, W]` in [0, 1]: the image is
/// resized to ENCODER_SIZE^2, encoded, and its latent statistics packed as tokens.
pub fn style_content_tokens(style: ArrayView4<'_, f32>) -> Result<(Vec<f32>, Vec<f32>)> {
    if style.dim().0 != 1 {
        return Err(Error::param(format!(
            "style image: expected one image [1, 3, H, W], got {:?}",
            style.shape()
        )));
    }
    check_images(style, 1, "style image")?;
    let small = fit_square(style, ENCODER_SIZE);
    let st = Stats::of_latents(vae_encode(small.view())?.view());
    let content = Stats {
        mean: vec![0.0; CHANNELS],
        var: st.var.clone(),
    };
    Ok((st.token(), content.token()))
}

/// The closed-form eps for latents `z` `[B, C, h, w]` at ab under N(mean, var).
pub fn closed_form_eps(z: ArrayView4<'_, f32>, alpha_bar: f64, stats: &Stats) -> Array4<f32> {
    let (sa, s1) = (alpha_bar.sqrt(), (1.0 - alpha_bar).sqrt());
    let mut out = z.to_owned();
    for (c, mut ch) in out.axis_iter_mut(Axis(1)).enumerate() {
        let mu = stats.mean[c] as f64;
        let denom = alpha_bar * stats.var[c] as f64 + 1.0 - alpha_bar;
        ch.mapv_inplace(|x| (s1 * (x as f64 - sa * mu) / denom) as f32);
    }
    out
}

type ImageTokens = (Vec<f32>, Vec<f32>);

/// The Gaussian prior in pure Rust.
#[derive(Debug, Clone)]
pub struct GaussianPrior {
    info: PriorInfo,
    schedule: Schedule,
    null_tokens: Array2<f32>,
    prompt_tokens: Array2<f32>,
    /// (style token, content token), when built with a style image.
    image_tokens: Option<ImageTokens>,
}

impl GaussianPrior {
    /// Text tokens `[L, TOKEN_DIM]` for the null and the prompt conditioning, and an
    /// optional style image `[1, 3, H, W]` in [0, 1].
    pub fn new(
        null_tokens: Array2<f32>,
        prompt_tokens: Array2<f32>,
        style_image: Option<ArrayView4<'_, f32>>,
    ) -> Result<Self> {
        Stats::from_tokens(null_tokens.view())?;
        Stats::from_tokens(prompt_tokens.view())?;
        let image_tokens = style_image.map(style_content_tokens).transpose()?;
        let scheduler = SchedulerConfig::stable_diffusion();
        Ok(GaussianPrior {
            info: PriorInfo {
                name: "gaussian".into(),
                latent_channels: CHANNELS,
                downsample: DOWNSAMPLE,
                scheduler: scheduler.clone(),
                control: None,
                coinciding_style_content: None,
            },
            schedule: Schedule::new(scheduler)?,
            null_tokens,
            prompt_tokens,
            image_tokens,
        })
    }

    /// With the default text tokens: null = N(0, 1), prompt = [`Stats::prompt`].
    pub fn with_default_text(style_image: Option<ArrayView4<'_, f32>>) -> Result<Self> {
        let row = |s: Stats| Array2::from_shape_vec((1, TOKEN_DIM), s.token()).expect("width");
        Self::new(row(Stats::standard()), row(Stats::prompt()), style_image)
    }

    /// The tokens of a conditioning (text tokens then image tokens), `[n, TOKEN_DIM]`.
    pub fn cond_tokens(&self, cond: Cond) -> Result<Array2<f32>> {
        let image = |pick: fn(&ImageTokens) -> &Vec<f32>| {
            self.image_tokens.as_ref().map(pick).ok_or_else(|| {
                Error::param(format!(
                    "gaussian prior: conditioning {cond:?} needs a style image, and none was given"
                ))
            })
        };
        let (text, img) = match cond {
            Cond::Null => (&self.null_tokens, None),
            Cond::Prompt => (&self.prompt_tokens, None),
            Cond::PromptStyle => (&self.prompt_tokens, Some(image(|t| &t.0)?)),
            Cond::Content => (&self.null_tokens, Some(image(|t| &t.1)?)),
        };
        let mut rows = text.clone();
        if let Some(tok) = img {
            rows.push_row(ndarray::ArrayView1::from(tok.as_slice()))
                .expect("token width");
        }
        Ok(rows)
    }

    /// The Gaussian N(mu, var) a conditioning stands for.
    pub fn cond_stats(&self, cond: Cond) -> Result<Stats> {
        Stats::from_tokens(self.cond_tokens(cond)?.view())
    }

    pub fn schedule(&self) -> &Schedule {
        &self.schedule
    }
}

impl Prior for GaussianPrior {
    fn info(&self) -> &PriorInfo {
        &self.info
    }

    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        vae_encode(images)
    }

    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        vae_decode(latents)
    }

    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        _control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        check_latents(z_t)?;
        let ab = self.schedule.alpha_bar(t)?;
        conds
            .iter()
            .map(|&c| Ok(closed_form_eps(z_t, ab, &self.cond_stats(c)?)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn rand_images(b: usize, h: usize, w: usize, seed: u64) -> Array4<f32> {
        let mut r = Rng::new(seed);
        Array4::from_shape_fn((b, 3, h, w), |_| r.uniform() as f32)
    }

    #[test]
    fn vae_round_trip_on_block_constant_images() {
        let lat = {
            let mut r = Rng::new(5);
            Array4::from_shape_fn((2, 4, 3, 5), |_| r.normal() as f32 * 0.3)
        };
        // decode(encode(decode(z))) == decode(z); encode(decode(z)) is the projection of
        // z onto ENC's column space (3 of 4 dims), so round-trip through images.
        let img = vae_decode(lat.view()).unwrap();
        assert_eq!(img.dim(), (2, 3, 24, 40));
        let z2 = vae_encode(img.view()).unwrap();
        let img2 = vae_decode(z2.view()).unwrap();
        let d = (&img - &img2).mapv(f32::abs).fold(0f32, |a, &b| a.max(b));
        assert!(d < 1e-5, "{d}");
        let x = rand_images(1, 16, 16, 1);
        let z = vae_encode(x.view()).unwrap();
        let z3 = vae_encode(vae_decode(z.view()).unwrap().view()).unwrap();
        let d = (&z - &z3).mapv(f32::abs).fold(0f32, |a, &b| a.max(b));
        assert!(d < 1e-5, "{d}");
    }

    #[test]
    fn eps_is_the_posterior_mean_of_the_noise_by_monte_carlo() {
        // Sample x0 ~ N(mu, var), eps ~ N(0, 1); regress eps on z_t per channel: the
        // least-squares slope/intercept must match the closed form's affine map.
        let stats = Stats::prompt();
        let ab = 0.4f64;
        let n = 200_000;
        let mut r = Rng::new(9);
        let c = 1;
        let (mu, var) = (stats.mean[c] as f64, stats.var[c] as f64);
        let (mut sz, mut se, mut szz, mut sze) = (0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let x0 = mu + var.sqrt() * r.normal();
            let e = r.normal();
            let z = ab.sqrt() * x0 + (1.0 - ab).sqrt() * e;
            sz += z;
            se += e;
            szz += z * z;
            sze += z * e;
        }
        let nf = n as f64;
        let slope = (sze / nf - sz / nf * se / nf) / (szz / nf - (sz / nf).powi(2));
        let icpt = se / nf - slope * sz / nf;
        let z = Array4::from_shape_vec((1, 4, 1, 2), vec![0., 0., 0., 1., 0., 0., 0., 0.]).unwrap();
        let e = closed_form_eps(z.view(), ab, &stats);
        let cf_icpt = e[[0, c, 0, 0]] as f64;
        let cf_slope = e[[0, c, 0, 1]] as f64 - cf_icpt;
        assert!((slope - cf_slope).abs() < 0.01, "{slope} vs {cf_slope}");
        assert!((icpt - cf_icpt).abs() < 0.01, "{icpt} vs {cf_icpt}");
    }

    #[test]
    fn conditionings_map_to_documented_stats() {
        let style = rand_images(1, 40, 56, 3);
        let mut p = GaussianPrior::with_default_text(Some(style.view())).unwrap();
        assert_eq!(p.cond_stats(Cond::Null).unwrap(), Stats::standard());
        assert_eq!(p.cond_stats(Cond::Prompt).unwrap(), Stats::prompt());
        let small = fit_square(style.view(), ENCODER_SIZE);
        let st = Stats::of_latents(vae_encode(small.view()).unwrap().view());
        let ps = p.cond_stats(Cond::PromptStyle).unwrap();
        let ct = p.cond_stats(Cond::Content).unwrap();
        for c in 0..CHANNELS {
            assert!((ps.mean[c] - 0.5 * (PROMPT_MEAN[c] + st.mean[c])).abs() < 1e-6);
            assert!((ps.var[c] - 0.5 * (PROMPT_VAR[c] + st.var[c])).abs() < 1e-6);
            assert!(ct.mean[c].abs() < 1e-7);
            assert!((ct.var[c] - 0.5 * (1.0 + st.var[c])).abs() < 1e-6);
        }
        let z = rand_images(2, 4, 4, 4)
            .slice(s![.., ..3, .., ..])
            .to_owned();
        assert!(p.predict_eps(z.view(), 10, &[Cond::Null], None).is_err());
        let z = Array4::<f32>::ones((2, 4, 3, 3));
        let out = p
            .predict_eps(z.view(), 999, &[Cond::Null, Cond::PromptStyle], None)
            .unwrap();
        assert_eq!(out.len(), 2);
        assert!(p.predict_eps(z.view(), 1000, &[Cond::Null], None).is_err());
        let mut q = GaussianPrior::with_default_text(None).unwrap();
        let e = q
            .predict_eps(z.view(), 10, &[Cond::Content], None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("style image"), "{e}");
    }
}

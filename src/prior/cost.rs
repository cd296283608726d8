//! What the diffusion path will cost, said before a run starts ("about N minutes on this
//! machine") and corrected once the first evaluation has been timed.
//!
//! FantasyStyle's loop (Sec. 4, CSD) evaluates the UNet, with its ControlNet, on every view
//! under several conditionings per iteration (CSD: four, batched as one call per branch),
//! and runs the VAE on the renders and the targets. On a CPU these graphs are dominated by
//! convolutions and matrix products whose work is, per image, proportional to the number
//! of weights times the number of positions they are applied at; the model here is
//!
//! ```text
//! unet work = (unet bytes + controlnet bytes) x latent pixels x batch rows
//! vae work  = (vae graph bytes) x image pixels x images
//! seconds   = unet work / unet rate + vae work / vae rate
//! ```
//!
//! with the graphs' sizes read from their files (`.onnx` plus ONNX external data). The
//! rates start at nominal per-thread values measured on one CPU core of the project's
//! benchmark machine and scaled as threads^0.7 (SD 1.5's UNet: 8x the threads gave 4.4x
//! the speed); each is replaced by the measured rate as soon as one evaluation of that
//! graph has been timed ([`CostModel::calibrate_unet`], [`CostModel::calibrate_vae`]).
//! Attention grows with the square of the latent pixels, so the linear model
//! underestimates large resolutions a little (BENCHMARKS.md, "Diffusion path"); on a GPU
//! the nominal rates mean nothing and only the calibrated estimate is given.

use super::manifest::{ModelDir, ModelManifest};
use crate::runtime::Device;
use crate::{Error, Result};
use std::path::Path;

/// UNet work units (bytes x latent pixels x rows) per second on one CPU thread: the
/// full-size SD 1.5 UNet + depth ControlNet (random weights, fp32), batch 4, onnxruntime
/// 1.31 with all graph optimisations, measured 1.03e12 at 16x16 latents and 1.45e12 at
/// 32x32 (BENCHMARKS.md, "Diffusion path").
pub const NOMINAL_UNET_RATE: f64 = 1.2e12;
/// VAE work units (bytes x image pixels x images) per second on one CPU thread: SD 1.5's
/// VAE decoder, measured 1.41e12 at both 128x128 and 256x256 (BENCHMARKS.md,
/// "Diffusion path"; the encoder is assumed to run at the same rate).
pub const NOMINAL_VAE_RATE: f64 = 1.4e12;
/// Speed-up from `n` threads is n^THREAD_EXPONENT.
pub const THREAD_EXPONENT: f64 = 0.7;

/// Sizes of the graphs in bytes (file plus external data).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GraphBytes {
    pub unet: u64,
    pub controlnet: u64,
    pub vae_encoder: u64,
    pub vae_decoder: u64,
}

fn graph_bytes(md: &ModelDir, file: &str) -> Result<u64> {
    let p = md.file(file);
    let main = std::fs::metadata(&p).map_err(|e| Error::io(&p, e))?.len();
    let data = md.file(&format!("{file}.data"));
    Ok(main + std::fs::metadata(&data).map(|m| m.len()).unwrap_or(0))
}

impl GraphBytes {
    /// The sizes of a diffusion model's graphs (`None` for a manifest without a UNet,
    /// e.g. the stylizer).
    pub fn of(md: &ModelDir) -> Result<Option<GraphBytes>> {
        let m = &md.manifest;
        let (Some(u), Some(e), Some(d)) = (&m.unet, &m.vae_encoder, &m.vae_decoder) else {
            return Ok(None);
        };
        Ok(Some(GraphBytes {
            unet: graph_bytes(md, &u.file)?,
            controlnet: match &m.controlnet {
                Some(c) => graph_bytes(md, &c.file)?,
                None => 0,
            },
            vae_encoder: graph_bytes(md, &e.file)?,
            vae_decoder: graph_bytes(md, &d.file)?,
        }))
    }
}

/// What a run does.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Plan {
    /// UNet evaluations (calls of [`crate::prior::Prior::predict_eps`]).
    pub evaluations: usize,
    /// Rows per evaluation: views x conditionings.
    pub batch: usize,
    /// Latent size (h, w).
    pub latent: (usize, usize),
    /// Image pixels per latent pixel along each axis (8 for SD VAEs).
    pub downsample: usize,
    /// Images VAE-encoded and decoded over the run.
    pub encodes: usize,
    pub decodes: usize,
}

impl Plan {
    /// `iterations` CSD steps, each one UNet call on `views` views under `conds`
    /// conditionings, at images of `image` (h, w) and latents `downsample` times smaller,
    /// with two decodes (z0' and z0) and `encodes` encodes per view.
    pub fn csd_steps(
        iterations: usize,
        views: usize,
        conds: usize,
        image: (usize, usize),
        downsample: usize,
        encodes: usize,
    ) -> Plan {
        let f = downsample.max(1);
        Plan {
            evaluations: iterations,
            batch: views * conds,
            latent: (image.0 / f, image.1 / f),
            downsample: f,
            encodes: iterations * encodes * views,
            decodes: iterations * 2 * views,
        }
    }
}

/// The cost model of one model on one machine.
#[derive(Debug, Clone, PartialEq)]
pub struct CostModel {
    pub bytes: GraphBytes,
    /// Work units per second.
    pub unet_rate: f64,
    pub vae_rate: f64,
    /// Whether each rate was measured here (else nominal).
    pub unet_measured: bool,
    pub vae_measured: bool,
    /// Whether the nominal rates mean anything on this device (the CPU).
    pub nominal_valid: bool,
}

impl CostModel {
    /// The cost model of the model at `model` (a directory or its `model.json`) with
    /// `threads` intra-op threads on `device`; `None` for a model without a UNet (the
    /// stylizer), whose cost the graphs' size does not predict.
    pub fn for_model(model: &Path, threads: usize, device: Device) -> Result<Option<CostModel>> {
        let md = ModelManifest::load(model)?;
        Ok(GraphBytes::of(&md)?.map(|b| CostModel::new(b, threads, device)))
    }

    /// Nominal rates for `threads` intra-op threads (0 = all cores) on `device`.
    pub fn new(bytes: GraphBytes, threads: usize, device: Device) -> Self {
        let n = if threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            threads
        };
        let speedup = (n as f64).powf(THREAD_EXPONENT);
        CostModel {
            bytes,
            unet_rate: NOMINAL_UNET_RATE * speedup,
            vae_rate: NOMINAL_VAE_RATE * speedup,
            unet_measured: false,
            vae_measured: false,
            nominal_valid: device == Device::Cpu,
        }
    }

    /// Work of one UNet (+ ControlNet) evaluation of `batch` rows at `latent`.
    pub fn unet_work(&self, batch: usize, latent: (usize, usize)) -> f64 {
        (self.bytes.unet + self.bytes.controlnet) as f64 * (latent.0 * latent.1 * batch) as f64
    }

    /// Work of VAE-encoding and -decoding these many images of `pixels` pixels each.
    pub fn vae_work(&self, encodes: usize, decodes: usize, pixels: usize) -> f64 {
        (self.bytes.vae_encoder as f64 * encodes as f64
            + self.bytes.vae_decoder as f64 * decodes as f64)
            * pixels as f64
    }

    /// Seconds the plan takes at the current rates.
    pub fn seconds(&self, p: &Plan) -> f64 {
        let pixels = p.latent.0 * p.latent.1 * p.downsample * p.downsample;
        self.unet_work(p.batch, p.latent) * p.evaluations as f64 / self.unet_rate
            + self.vae_work(p.encodes, p.decodes, pixels) / self.vae_rate
    }

    /// Replace the UNet rate by the one measured: `seconds` for one evaluation of
    /// `batch` rows at `latent`.
    pub fn calibrate_unet(&mut self, batch: usize, latent: (usize, usize), seconds: f64) {
        if seconds > 0.0 {
            self.unet_rate = self.unet_work(batch, latent) / seconds;
            self.unet_measured = true;
        }
    }

    /// Replace the VAE rate by the one measured: `seconds` for encoding `encodes` and
    /// decoding `decodes` images of `pixels` pixels.
    pub fn calibrate_vae(&mut self, encodes: usize, decodes: usize, pixels: usize, seconds: f64) {
        let w = self.vae_work(encodes, decodes, pixels);
        if seconds > 0.0 && w > 0.0 {
            self.vae_rate = w / seconds;
            self.vae_measured = true;
        }
    }

    /// The estimate as a sentence: "about 12 minutes on this machine (from the graphs'
    /// size; corrected after the first evaluation)", or `None` where there is nothing
    /// to say yet (an uncalibrated model on a GPU).
    pub fn describe(&self, p: &Plan) -> Option<String> {
        let calibrated = self.unet_measured;
        if !calibrated && !self.nominal_valid {
            return None;
        }
        let how = if calibrated {
            "measured on the first evaluation"
        } else {
            "from the graphs' size at nominal CPU rates; corrected after the first evaluation"
        };
        Some(format!(
            "{} on this machine ({how})",
            about(self.seconds(p))
        ))
    }
}

/// Log what `plan` will cost (`who`: the stage), before it starts; nothing for a model
/// without a cost model (the stylizer) or without an estimate yet.
pub fn announce(cost: Option<&CostModel>, who: &str, plan: &Plan) {
    if let Some(say) = cost.and_then(|c| c.describe(plan)) {
        tracing::info!(
            "{who}: {} UNet calls of {} rows at {}x{} latents: {say}",
            plan.evaluations,
            plan.batch,
            plan.latent.0,
            plan.latent.1
        );
    }
}

/// "under a second", "about 40 seconds", "about 3 minutes", "about 2.5 hours".
pub fn about(seconds: f64) -> String {
    if !seconds.is_finite() {
        return "an unknown time".into();
    }
    let s = seconds.max(0.0);
    if s < 1.0 {
        "under a second".into()
    } else if s < 1.5 {
        "about 1 second".into()
    } else if s < 90.0 {
        format!("about {} seconds", s.round() as u64)
    } else if s < 90.0 * 60.0 {
        format!("about {} minutes", (s / 60.0).round() as u64)
    } else {
        format!("about {:.1} hours", s / 3600.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> CostModel {
        let bytes = GraphBytes {
            unet: 3_000,
            controlnet: 1_000,
            vae_encoder: 100,
            vae_decoder: 200,
        };
        CostModel::new(bytes, 1, Device::Cpu)
    }

    #[test]
    fn work_is_linear_in_rows_pixels_and_evaluations() {
        let m = model();
        let p = Plan {
            evaluations: 3,
            batch: 8,
            latent: (4, 5),
            downsample: 8,
            encodes: 0,
            decodes: 0,
        };
        let t = m.seconds(&p);
        assert!((t - 3.0 * 4000.0 * 20.0 * 8.0 / NOMINAL_UNET_RATE).abs() < 1e-18);
        let twice = Plan { batch: 16, ..p };
        assert!((m.seconds(&twice) / t - 2.0).abs() < 1e-12);
        let bigger = Plan {
            latent: (8, 10),
            ..p
        };
        assert!((m.seconds(&bigger) / t - 4.0).abs() < 1e-12);
        // More threads, less time; 0 = all cores.
        assert!(CostModel::new(m.bytes, 4, Device::Cpu).seconds(&p) < t);
    }

    #[test]
    fn calibration_reproduces_the_measured_evaluation() {
        let mut m = model();
        let p = Plan {
            evaluations: 10,
            batch: 4,
            latent: (32, 32),
            downsample: 8,
            encodes: 4,
            decodes: 8,
        };
        m.calibrate_unet(4, (32, 32), 2.0);
        m.calibrate_vae(4, 8, 256 * 256, 3.0);
        // Ten evaluations at 2 s plus the VAE work measured at 3 s.
        assert!((m.seconds(&p) - 23.0).abs() < 1e-9);
        assert!(m.describe(&p).unwrap().contains("measured"));
        // On a GPU, nothing is said before calibration.
        let g = CostModel::new(m.bytes, 1, Device::Cuda(0));
        assert_eq!(g.describe(&p), None);
    }

    #[test]
    fn about_rounds_to_a_readable_unit() {
        assert_eq!(about(0.2), "under a second");
        assert_eq!(about(1.2), "about 1 second");
        assert_eq!(about(42.4), "about 42 seconds");
        assert_eq!(about(600.0), "about 10 minutes");
        assert_eq!(about(3.0 * 3600.0), "about 3.0 hours");
    }
}

//! A family that exists only in tests (`test-only`), to show that a new prior family is
//! this one file and one line of [`super::FAMILIES`]: a pixel-space prior (3 latent
//! channels, downsample 1) whose VAE is the identity and whose noise prediction is zero
//! (the exact denoiser of a point mass at the noisy sample's own scaled mean), drawing
//! from a fixed timestep range of its own.

use crate::Result;
use crate::prior::manifest::{ModelDir, TimestepRange};
use crate::prior::{Cond, Prior, PriorInfo, PriorOptions};
use ndarray::{Array4, ArrayView4};

/// Pixel latents only.
pub fn validate(md: &ModelDir) -> Result<()> {
    let m = &md.manifest;
    if m.latent_channels != 3 || m.downsample != 1 {
        return Err(md.err("a test-only prior works on pixels: latent_channels 3, downsample 1"));
    }
    Ok(())
}

/// Its own range: 5 timesteps over [100, 900].
pub fn timesteps(_: &ModelDir) -> Result<Option<TimestepRange>> {
    Ok(Some(TimestepRange {
        t_min: 100,
        t_max: 900,
        count: 5,
    }))
}

/// The identity-VAE, zero-eps prior.
pub fn open(md: ModelDir, _: &PriorOptions) -> Result<Box<dyn Prior>> {
    let m = md.manifest;
    Ok(Box::new(TestOnly {
        info: PriorInfo {
            name: m.name,
            latent_channels: 3,
            downsample: 1,
            scheduler: m.scheduler,
            control: None,
            coinciding_style_content: None,
        },
    }))
}

struct TestOnly {
    info: PriorInfo,
}

impl Prior for TestOnly {
    fn info(&self) -> &PriorInfo {
        &self.info
    }

    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        Ok(images.to_owned())
    }

    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        Ok(latents.to_owned())
    }

    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        _: usize,
        conds: &[Cond],
        _: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        Ok(conds.iter().map(|_| Array4::zeros(z_t.dim())).collect())
    }
}

#[cfg(test)]
mod tests {
    use crate::prior::manifest::{MODEL_FILE, MODEL_FORMAT, ModelManifest};
    use crate::prior::{Cond, PriorOptions, families, model_timesteps, open};
    use crate::scheduler::SchedulerConfig;
    use ndarray::Array4;

    fn manifest(channels: usize) -> serde_json::Value {
        serde_json::json!({
            "format": MODEL_FORMAT, "family": "test-only", "name": "t",
            "latent_channels": channels, "downsample": 1,
            "scheduler": SchedulerConfig::stable_diffusion(),
        })
    }

    #[test]
    fn a_test_only_family_validates_and_opens_through_the_registry() {
        let d = tempfile::tempdir().unwrap();
        let write = |v: serde_json::Value| {
            std::fs::write(d.path().join(MODEL_FILE), v.to_string()).unwrap();
        };
        write(manifest(3));
        let md = ModelManifest::load(d.path()).unwrap();
        assert_eq!(md.manifest.family.name(), "test-only");
        // Its timesteps are its own.
        let (_, set) = model_timesteps(d.path()).unwrap();
        assert_eq!(set.steps().len(), 5);
        // It opens and runs.
        let mut p = open(d.path(), &PriorOptions::default()).unwrap();
        assert_eq!(p.info().name, "t");
        let z = Array4::<f32>::ones((1, 3, 2, 2));
        assert_eq!(p.encode(z.view()).unwrap(), z);
        let eps = p.predict_eps(z.view(), 500, &[Cond::Null, Cond::Prompt], None);
        assert_eq!(eps.unwrap().len(), 2);
        // Its validation runs at load.
        write(manifest(4));
        let e = ModelManifest::load(d.path()).unwrap_err().to_string();
        assert!(e.contains("latent_channels 3"), "{e}");
        // The known families are listed from the registry, this one included.
        let mut bad = manifest(3);
        bad["family"] = "sd3".into();
        write(bad);
        let e = ModelManifest::load(d.path()).unwrap_err().to_string();
        assert!(
            e.contains("unknown variant `sd3`") && e.contains("`test-only`"),
            "{e}"
        );
        assert_eq!(families::names().last(), Some(&"test-only"));
    }
}

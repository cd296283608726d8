//! The metric networks, run with onnxruntime: the LPIPS backbones (AlexNet, VGG16) that
//! output their ReLU features at the five LPIPS taps, plus the LPIPS linear heads, and the
//! FID Inception-v3 (TF 2015, 2048-d pool3).
//!
//! All three graphs are made at set-up without torch (`scripts/setup/30_lpips_weights.py`,
//! `31_metric_nets.py`) under `vendor/models/`; the tests below check them against the
//! independent numpy forward passes of `scripts/reference/metric_nets_ref.py` (step 32).
//! Graph inputs are RGB NCHW in `[0, 1]`; each graph does its own input scaling (LPIPS:
//! `(2x - 1 - shift) / scale`; Inception: TF-legacy bilinear resize to 299x299, then
//! `x * 255/128 - 1` clamped to `[-1, 0.9921875]`).

use crate::imageio::Image;
use crate::vgg::Tensor3;
use crate::{Error, Result};
use fantasystyle_schemas::read_npy_f32;
use ort::session::Session;
use ort::value::Tensor;
use std::path::{Path, PathBuf};

/// Images per onnxruntime call (bounds memory: VGG tap 0 is 64 x H x W floats per image).
const BATCH: usize = 4;
/// Length of an Inception pool3 feature vector.
pub const POOL3: usize = 2048;

/// Which LPIPS backbone.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum LpipsNet {
    Alex,
    Vgg16,
}

impl LpipsNet {
    pub fn name(self) -> &'static str {
        match self {
            LpipsNet::Alex => "alex",
            LpipsNet::Vgg16 => "vgg16",
        }
    }
}

/// The five tapped feature maps of one image.
pub type Features = Vec<Tensor3>;

fn onnx_err(path: &Path) -> impl Fn(ort::Error) -> Error + '_ {
    move |e| Error::Onnx(format!("{}: {e}", path.display()))
}

/// One output tensor of one image: shape (without the batch axis) and data.
type Output = (Vec<usize>, Vec<f32>);

/// Run `session` on `images` (batched), returning each output tensor per image.
fn run_batched(
    session: &mut Session,
    path: &Path,
    images: &[&Image],
    outputs: &[&str],
) -> Result<Vec<Vec<Output>>> {
    let mut per_image = Vec::with_capacity(images.len());
    for chunk in images.chunks(BATCH) {
        if chunk
            .iter()
            .any(|i| (i.width, i.height) != (chunk[0].width, chunk[0].height))
        {
            return Err(Error::param("metric network batch: images differ in size"));
        }
        let (shape, data) = Image::to_nchw(chunk);
        let t = Tensor::from_array((shape, data)).map_err(onnx_err(path))?;
        let out = session
            .run(ort::inputs!["image" => t])
            .map_err(onnx_err(path))?;
        // Each image's part copied once, straight out of onnxruntime's output.
        let first = per_image.len();
        per_image.extend((0..chunk.len()).map(|_| Vec::with_capacity(outputs.len())));
        for name in outputs {
            let v = out
                .get(*name)
                .ok_or_else(|| Error::input(path, format!("graph has no output `{name}`")))?;
            let (s, d) = v.try_extract_tensor::<f32>().map_err(onnx_err(path))?;
            let s: Vec<usize> = s.iter().map(|&x| x as usize).collect();
            if s.first() != Some(&chunk.len()) {
                return Err(Error::input(
                    path,
                    format!("output `{name}` has shape {s:?} for {} images", chunk.len()),
                ));
            }
            let per = d.len() / chunk.len();
            for (b, img) in per_image[first..].iter_mut().enumerate() {
                img.push((s[1..].to_vec(), d[b * per..(b + 1) * per].to_vec()));
            }
        }
    }
    Ok(per_image)
}

/// An LPIPS backbone and its linear heads.
pub struct LpipsModel {
    pub net: LpipsNet,
    session: Session,
    path: PathBuf,
    /// `lin[k][c]`: non-negative weight of channel `c` at tap `k`.
    pub lin: Vec<Vec<f32>>,
}

impl LpipsModel {
    /// Load `metrics/lpips_<net>.onnx` and `lpips/<net>/lin{k}.npy` from `models`.
    pub fn load(models: &Path, net: LpipsNet, threads: usize) -> Result<LpipsModel> {
        let path = models
            .join("metrics")
            .join(format!("lpips_{}.onnx", net.name()));
        if !path.is_file() {
            return Err(Error::Missing(format!(
                "{} not found; run `scripts/setup.sh` (steps 30, 31)",
                path.display()
            )));
        }
        let session = crate::runtime::load_session(&path, threads)?;
        let mut lin = Vec::new();
        for k in 0..5 {
            let p = models
                .join("lpips")
                .join(net.name())
                .join(format!("lin{k}.npy"));
            lin.push(read_npy_f32(&p)?.data);
        }
        Ok(LpipsModel {
            net,
            session,
            path,
            lin,
        })
    }

    /// Tapped features of each image.
    pub fn features(&mut self, images: &[&Image]) -> Result<Vec<Features>> {
        let names = ["feat0", "feat1", "feat2", "feat3", "feat4"];
        let out = run_batched(&mut self.session, &self.path, images, &names)?;
        let mut res = Vec::with_capacity(out.len());
        for taps in out {
            let mut f = Vec::new();
            for (k, (s, d)) in taps.into_iter().enumerate() {
                if s.len() != 3 || s[0] != self.lin[k].len() {
                    return Err(Error::input(
                        &self.path,
                        format!(
                            "tap {k} has shape {s:?}, heads expect {} channels",
                            self.lin[k].len()
                        ),
                    ));
                }
                f.push(Tensor3 {
                    c: s[0],
                    h: s[1],
                    w: s[2],
                    data: d,
                });
            }
            res.push(f);
        }
        Ok(res)
    }
}

/// The FID Inception-v3.
pub struct Inception {
    session: Session,
    path: PathBuf,
}

impl Inception {
    pub fn load(models: &Path, threads: usize) -> Result<Inception> {
        let path = models.join("metrics").join("fid_inception.onnx");
        if !path.is_file() {
            return Err(Error::Missing(format!(
                "{} not found; run `scripts/setup.sh` (step 31)",
                path.display()
            )));
        }
        Ok(Inception {
            session: crate::runtime::load_session(&path, threads)?,
            path,
        })
    }

    /// 2048-d pool3 features of each image.
    pub fn pool3(&mut self, images: &[&Image]) -> Result<Vec<Vec<f32>>> {
        let out = run_batched(&mut self.session, &self.path, images, &["pool3"])?;
        out.into_iter()
            .map(|mut t| {
                let (s, d) = t.remove(0);
                if s != [POOL3] {
                    return Err(Error::input(&self.path, format!("pool3 has shape {s:?}")));
                }
                Ok(d)
            })
            .collect()
    }
}

/// The metric networks an evaluation runs.
pub struct Nets {
    /// LPIPS (the evaluation's backbone) for consistency.
    pub lpips: LpipsModel,
    /// VGG16 LPIPS model for the Gram distances (`None`: `lpips` is VGG16 itself).
    pub vgg: Option<LpipsModel>,
    /// Inception (`None`: the Inception measures are off, [`super::reference::EvalParams`]).
    pub inception: Option<Inception>,
}

impl Nets {
    /// The VGG16 model (its own or the LPIPS one).
    pub fn vgg(&mut self) -> &mut LpipsModel {
        self.vgg.as_mut().unwrap_or(&mut self.lpips)
    }

    /// Load the networks for `net` (Inception only with `inception`) from the models
    /// directory, each timed as a phase named after it ([`crate::timing`]).
    pub fn load(models: &Path, net: LpipsNet, inception: bool, threads: usize) -> Result<Nets> {
        let load = |n: LpipsNet| {
            crate::timing::phase(&format!("lpips {}", n.name()), || {
                LpipsModel::load(models, n, threads)
            })
        };
        let lpips = load(net)?;
        let vgg = (net != LpipsNet::Vgg16)
            .then(|| load(LpipsNet::Vgg16))
            .transpose()?;
        let inception = inception
            .then(|| crate::timing::phase("inception", || Inception::load(models, threads)))
            .transpose()?;
        Ok(Nets {
            lpips,
            vgg,
            inception,
        })
    }

    /// The networks beside LPIPS: VGG16 (unless `net` is VGG16) and Inception (with
    /// `inception`).
    pub fn load_rest(
        models: &Path,
        net: LpipsNet,
        inception: bool,
        threads: usize,
    ) -> Result<(Option<LpipsModel>, Option<Inception>)> {
        let vgg = (net != LpipsNet::Vgg16)
            .then(|| LpipsModel::load(models, LpipsNet::Vgg16, threads))
            .transpose()?;
        let inception = inception
            .then(|| Inception::load(models, threads))
            .transpose()?;
        Ok((vgg, inception))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    //! Each converted network against the numpy reference (set-up step 32).
    //! Tolerance: max |onnx - ref| <= 1e-4 * max |ref| + 1e-6 per output tensor (float32
    //! graph vs float64 reference; the measured errors are printed).
    use super::*;
    use fantasystyle_schemas::read_npy;

    /// The models dir and reference dir, or `None` (test prints SKIPPED) if set-up or
    /// onnxruntime is missing; under CI (`CI` set, not `""`, `0` or `false`) set-up has
    /// installed both, so a missing one fails the test instead of passing it as green.
    pub(crate) fn setup() -> Option<PathBuf> {
        let skip = |what: &str| {
            let ci = std::env::var("CI").is_ok_and(|v| !matches!(v.trim(), "" | "0" | "false"));
            assert!(!ci, "missing under CI: {what} (scripts/setup.sh)");
            eprintln!("SKIPPED: {what} (scripts/setup.sh)");
            None
        };
        if crate::runtime::library_path().is_err() {
            return skip("onnxruntime not installed");
        }
        match crate::models::models_dir() {
            Ok(m) if m.join("metrics/ref/ref.json").is_file() => Some(m),
            _ => skip("metric networks/reference not set up"),
        }
    }

    pub(crate) fn ref_images(m: &Path, name: &str) -> Vec<Image> {
        let a = read_npy_f32(&m.join("metrics/ref").join(name)).unwrap();
        let (n, h, w) = (a.shape[0], a.shape[2], a.shape[3]);
        (0..n)
            .map(|i| {
                Image::from_fn(w, h, |x, y| {
                    let at = |c: usize| a.data[((i * 3 + c) * h + y) * w + x];
                    [at(0), at(1), at(2)]
                })
            })
            .collect()
    }

    fn rel_err(got: &[f32], want: &[f32]) -> (f32, f32) {
        assert_eq!(got.len(), want.len());
        let maxref = want.iter().fold(0.0f32, |m, x| m.max(x.abs()));
        let err = got
            .iter()
            .zip(want)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        (err, maxref)
    }

    fn check_lpips_net(net: LpipsNet) {
        let Some(m) = setup() else { return };
        let imgs = ref_images(&m, "images_lpips.npy");
        let refs: Vec<&Image> = imgs.iter().collect();
        let mut model = LpipsModel::load(&m, net, 2).unwrap();
        let feats = model.features(&refs).unwrap();
        for k in 0..5 {
            let want =
                read_npy_f32(&m.join(format!("metrics/ref/lpips_{}_feat{k}.npy", net.name())))
                    .unwrap();
            let got: Vec<f32> = feats.iter().flat_map(|f| f[k].data.clone()).collect();
            assert_eq!(
                [imgs.len(), feats[0][k].c, feats[0][k].h, feats[0][k].w].to_vec(),
                want.shape
            );
            let (err, maxref) = rel_err(&got, &want.data);
            eprintln!(
                "lpips {} tap {k}: max abs err {err:.3e}, max |ref| {maxref:.3e}",
                net.name()
            );
            assert!(
                err <= 1e-4 * maxref + 1e-6,
                "tap {k}: err {err} (max ref {maxref})"
            );
        }
        // End to end: the LPIPS distance from our features vs the numpy distance.
        let want =
            read_npy::<f64>(&m.join(format!("metrics/ref/lpips_{}_dist.npy", net.name()))).unwrap();
        for (p, (a, b)) in [(0, 1), (0, 2), (1, 2)].into_iter().enumerate() {
            let got = super::super::lpips::distance(&feats[a], &feats[b], &model.lin, None);
            eprintln!(
                "lpips {} pair ({a},{b}): {got:.7} vs ref {:.7}",
                net.name(),
                want.data[p]
            );
            assert!(
                (got - want.data[p]).abs() <= 1e-4 * want.data[p],
                "{got} vs {}",
                want.data[p]
            );
        }
    }

    #[test]
    fn lpips_alex_matches_numpy_reference() {
        check_lpips_net(LpipsNet::Alex);
    }

    #[test]
    fn lpips_vgg16_matches_numpy_reference() {
        check_lpips_net(LpipsNet::Vgg16);
    }

    #[test]
    fn fid_inception_matches_numpy_reference() {
        let Some(m) = setup() else { return };
        let imgs = ref_images(&m, "images_fid.npy");
        let refs: Vec<&Image> = imgs.iter().collect();
        let mut net = Inception::load(&m, 2).unwrap();
        let got: Vec<f32> = net.pool3(&refs).unwrap().concat();
        let want = read_npy_f32(&m.join("metrics/ref/fid_pool3.npy")).unwrap();
        assert_eq!(want.shape, vec![imgs.len(), 2048]);
        let (err, maxref) = rel_err(&got, &want.data);
        eprintln!("inception pool3: max abs err {err:.3e}, max |ref| {maxref:.3e}");
        assert!(err <= 1e-4 * maxref + 1e-6, "err {err} (max ref {maxref})");
    }
}

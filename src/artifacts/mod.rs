//! Typed readers of the artifacts the stages exchange, on top of `fantasystyle_schemas`
//! (which opens an artifact, checks its manifest, kind and file hashes, and reads `.npy`).
//! The one place that knows what each artifact holds: stages, metrics and tests read
//! artifacts through these functions, and every shape is checked here, with errors that
//! name the file. Nothing here knows the loop: a distill checkpoint's optimizer state
//! and history are read and written beside the loop ([`crate::distill::checkpoint`]).
//!
//! | artifact (kind) | written by | reader |
//! |---|---|---|
//! | `views` | render-views | [`read_views`]: rgb `[N,H,W,3]`, depth and alpha `[N,H,W]`, [`Views::cameras`]; [`read_view_images`]: rgb only |
//! | `latents` | encode-latents | [`chain::read_latents`]: `[N,C,h,w]` |
//! | `noised-latents` | mvfc-filter | [`chain::read_noised_latents`]: z_src, z_tgt, eps `[N,C,h,w]`, eps' `[C,h,w]`, t |
//! | `targets` (or `views`) | csd-step | [`chain::read_targets`]: rgb `[N,H,W,3]` |
//! | `scene` | distill, update-gaussians, stylize-baseline, `pipeline wrap` | [`read_scene`] (a checkpoint's state: [`crate::distill::checkpoint`]) |
//! | `scene` with regions | distill --region | [`regions::read_regions`]: each region's weights `[R, N]`, name, selection, styles, strength (`meta.regions`); written by [`regions::write_regions`] |
//! | `selection` | select | [`selection::read_selection`]: a weight per Gaussian `[N]` in [0, 1]; written by [`selection::write_selection`] |
//! | `eval-reference` | evaluate --reference-only | [`eval::read_references`]: pool3 features `[M,2048]`, style Grams `[C,C]` f64, `reference.json`; written by [`eval::write_eval_reference`] |
//! | `eval-source` | evaluate --reference-only source | [`eval::read_references`] (with an `eval-style`): pool3 features, the views' Grams as upper triangles `[N,C(C+1)/2]` f64, `source.json`; written by [`eval::write_eval_source`] |
//! | `eval-style` | evaluate --reference-only style | [`eval::read_references`] (with an `eval-source`): pool3 features, style Grams `[C,C]` f64, `style.json`; written by [`eval::write_eval_style`] |
//!
//! Artifacts of one iteration of the stage chain (`render-views --window` ->
//! `encode-latents` -> `mvfc-filter` -> `csd-step`) record the iteration and its window
//! in `meta.iteration` ([`chain::iteration_of`]).
//!
//! Stage inputs that may be an artifact or a plain file: [`load_scene`] (a `.ply`, a
//! `.splat`, a `.spz` or a scene artifact); cameras (an `orbit:` spec, a camera file or
//! directory, or any artifact holding a `cameras.json`) are [`crate::camera::load_cameras`]'.

pub mod chain;
pub mod eval;
pub mod regions;
pub mod selection;

pub use chain::{
    Latents, NoisedLatents, Targets, agreed_iteration, iteration_of, open_latents, read_latents,
    read_noised_latents, read_targets, window_rows,
};
pub use eval::{
    ReferenceFor, read_references, write_eval_reference, write_eval_source, write_eval_style,
};
pub use regions::{read_regions, write_regions};
pub use selection::{SELECTION_WEIGHTS, read_selection, write_selection};

use crate::camera::{self, Camera};
use crate::metrics::views::ViewSet;
use crate::render::source::SourceViews;
use crate::scene::{self, Scene};
use crate::{Error, Result};
use fantasystyle_schemas::{Artifact, ArtifactKind};
use ndarray::{Array3, Array4, Axis};
use std::path::Path;

/// True when `dir` is an artifact directory (holds a manifest).
pub fn is_artifact(dir: &Path) -> bool {
    dir.is_dir() && dir.join(fantasystyle_schemas::MANIFEST_FILE).is_file()
}

/// Read tensor `name` of `art` as `[N, C, h, w]`.
pub(crate) fn read4(art: &Artifact, name: &str) -> Result<Array4<f32>> {
    let t = art.read_f32(name)?;
    let [n, c, h, w] = t.shape[..] else {
        return Err(Error::input(
            art.path(name),
            format!("expected shape [N, C, h, w], found {:?}", t.shape),
        ));
    };
    Array4::from_shape_vec((n, c, h, w), t.data)
        .map_err(|e| Error::input(art.path(name), e.to_string()))
}

/// Read tensor `name` of `art` as RGB images `[N, H, W, 3]`, `N, H, W >= 1`.
pub(crate) fn read_rgb(art: &Artifact, name: &str) -> Result<Array4<f32>> {
    let t = art.read_f32(name)?;
    let [n, h, w, 3] = t.shape[..] else {
        return Err(Error::input(
            art.path(name),
            format!("expected shape [N, H, W, 3], found {:?}", t.shape),
        ));
    };
    if n == 0 || h == 0 || w == 0 {
        return Err(Error::input(
            art.path(name),
            format!("empty image set, shape {:?}", t.shape),
        ));
    }
    Ok(Array4::from_shape_vec((n, h, w, 3), t.data).expect("shape checked"))
}

/// A `views` artifact's tensors, shape-checked against each other.
#[derive(Debug)]
pub struct Views {
    pub art: Artifact,
    /// `[N, H, W, 3]` in [0, 1].
    pub rgb: Array4<f32>,
    /// Expected depth `sum_i w_i z_i` (not divided by alpha), `[N, H, W]`.
    pub depth: Array3<f32>,
    /// Accumulated opacity, `[N, H, W]`.
    pub alpha: Array3<f32>,
}

impl Views {
    /// The views as the loop's source views (render-views of the original scene). The
    /// loop composites over black, render-views' default background (the views' own
    /// `--background` is not read).
    pub fn source_views(&self) -> SourceViews {
        let (n, h, w) = self.dim();
        let plane = |x: &Array3<f32>, i: usize| -> Vec<f32> {
            x.index_axis(Axis(0), i).iter().copied().collect()
        };
        SourceViews {
            width: w,
            height: h,
            rgb: (0..n)
                .map(|i| self.rgb.index_axis(Axis(0), i).iter().copied().collect())
                .collect(),
            alpha: (0..n).map(|i| plane(&self.alpha, i)).collect(),
            depth: (0..n).map(|i| plane(&self.depth, i)).collect(),
            background: [0.0; 3],
        }
    }

    /// `(N, H, W)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        let (n, h, w, _) = self.rgb.dim();
        (n, h, w)
    }

    /// The views' cameras (`cameras.json`, INRIA format), at the views' size.
    pub fn cameras(&self) -> Result<Vec<Camera>> {
        camera::inria::read_inria(&self.art.path("cameras.json"))
    }

    /// The views' cameras, refused unless there is one per view.
    pub fn cameras_per_view(&self) -> Result<Vec<Camera>> {
        let cameras = self.cameras()?;
        let n = self.dim().0;
        if cameras.len() != n {
            return Err(Error::input(
                self.art.path("cameras.json"),
                format!("{} cameras for {n} views", cameras.len()),
            ));
        }
        Ok(cameras)
    }
}

/// Open a `views` artifact and read only its images, `rgb.npy` `[N, H, W, 3]`
/// (N, H, W >= 1); for stages that need neither depth nor alpha.
pub fn read_view_images(dir: &Path) -> Result<(Artifact, Array4<f32>)> {
    let art = Artifact::open(dir, ArtifactKind::Views)?;
    let rgb = read_rgb(&art, "rgb.npy")?;
    Ok((art, rgb))
}

/// Open a `views` artifact and read `rgb.npy` `[N, H, W, 3]` (N, H, W >= 1) and
/// `depth.npy`, `alpha.npy` `[N, H, W]`.
pub fn read_views(dir: &Path) -> Result<Views> {
    let (art, rgb) = read_view_images(dir)?;
    let (n, h, w, _) = rgb.dim();
    let plane = |name: &str| -> Result<Array3<f32>> {
        let t = art.read_f32(name)?;
        if t.shape != [n, h, w] {
            return Err(Error::input(
                art.path(name),
                format!(
                    "expected shape [{n}, {h}, {w}] to match rgb.npy, got {:?}",
                    t.shape
                ),
            ));
        }
        Ok(Array3::from_shape_vec((n, h, w), t.data).expect("shape checked"))
    };
    let depth = plane("depth.npy")?;
    let alpha = plane("alpha.npy")?;
    Ok(Views {
        art,
        rgb,
        depth,
        alpha,
    })
}

/// A `views` artifact as the evaluation holds it ([`ViewSet`], validated).
pub fn read_view_set(dir: &Path) -> Result<ViewSet> {
    if !dir.is_dir() {
        return Err(Error::input(dir, "views artifact directory not found"));
    }
    let views = read_views(dir)?;
    let cameras = views.cameras()?;
    let Views {
        rgb, depth, alpha, ..
    } = views;
    ViewSet::new(dir, rgb, depth, alpha, cameras)
}

/// Read a `scene` artifact's `scene.ply` (manifest and hashes checked first).
pub fn read_scene(dir: &Path) -> Result<Scene> {
    let a = Artifact::open(dir, ArtifactKind::Scene)?;
    scene::ply::read_ply(&a.path("scene.ply"))
}

/// The `loss.json` of a `stylize-baseline` artifact (a scene artifact).
pub fn read_baseline_log(dir: &Path) -> Result<serde_json::Value> {
    let art = Artifact::open(dir, ArtifactKind::Scene)?;
    if !art.path("loss.json").is_file() {
        return Err(Error::input(
            dir,
            "scene artifact holds no loss.json: not written by stylize-baseline",
        ));
    }
    Ok(art.read_json("loss.json")?)
}

/// Write an array as the `.npy` tensor `name` of `out` (in standard layout).
pub fn write_array<D: ndarray::Dimension>(
    out: &mut fantasystyle_schemas::ArtifactWriter,
    name: &str,
    x: &ndarray::Array<f32, D>,
) -> Result<()> {
    let data = x.as_standard_layout();
    out.write_tensor(name, x.shape(), data.as_slice().expect("standard layout"))?;
    Ok(())
}

/// A stage's scene input: a scene artifact directory ([`read_scene`]), else a `.ply`, a
/// `.splat`, a `.spz` or a directory holding `scene.ply` ([`scene::read_scene_file`]).
pub fn load_scene(path: &Path) -> Result<Scene> {
    if is_artifact(path) {
        read_scene(path)
    } else {
        scene::read_scene_file(path)
    }
}

/// The scene at `path` for the evaluation report's 3D viewer, and the scene itself: a scene artifact or
/// directory with a `scene.spz`, or a `.spz` file, is embedded as it is (after reading it
/// back with [`scene::spz::parse_spz`]); any other scene ([`load_scene`]) is encoded as `.spz`.
pub fn read_viewer_scene(
    label: &str,
    path: &Path,
) -> Result<(crate::metrics::viewer::ViewerScene, Scene)> {
    let spz_file = if path.is_dir() {
        Some(path.join("scene.spz")).filter(|p| p.is_file())
    } else {
        let ext = path.extension().map(|e| e.to_ascii_lowercase());
        (ext.as_deref() == Some("spz".as_ref())).then(|| path.to_path_buf())
    };
    let (spz_bytes, scene, source) = match spz_file {
        Some(f) => {
            let b = std::fs::read(&f).map_err(|e| Error::io(&f, e))?;
            let s = scene::spz::parse_spz(&f, &b)?;
            (b, s, f.display().to_string())
        }
        None => {
            let s = load_scene(path)?;
            let b = scene::spz::encode_spz(path, &s)?;
            (b, s, format!("{} (as .spz)", path.display()))
        }
    };
    Ok((
        crate::metrics::viewer::ViewerScene {
            label: label.into(),
            source,
            gaussians: scene.len(),
            spz: spz_bytes,
        },
        scene,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use fantasystyle_schemas::{ArtifactWriter, Producer};

    fn write(
        dir: &Path,
        kind: ArtifactKind,
        tensors: &[(&str, &[usize])],
        meta: serde_json::Value,
    ) {
        let mut w =
            ArtifactWriter::create(dir, kind, Producer::new("test", "0", serde_json::json!({})))
                .unwrap();
        for (name, shape) in tensors {
            let n = shape.iter().product::<usize>();
            let data: Vec<f32> = (0..n).map(|i| i as f32 * 0.01).collect();
            w.write_tensor(name, shape, &data).unwrap();
        }
        if kind == ArtifactKind::Views {
            w.write_bytes("cameras.json", b"[]").unwrap();
        }
        w.set_meta(meta);
        w.commit().unwrap();
    }

    #[test]
    fn readers_check_shapes_and_name_the_file() {
        let d = tempfile::tempdir().unwrap();
        let v = d.path().join("views");
        let planes: &[(&str, &[usize])] = &[
            ("rgb.npy", &[2, 4, 6, 3]),
            ("depth.npy", &[2, 4, 6]),
            ("alpha.npy", &[2, 4, 5]),
        ];
        write(&v, ArtifactKind::Views, planes, serde_json::json!({}));
        let e = read_views(&v).unwrap_err().to_string();
        assert!(e.contains("alpha.npy") && e.contains("[2, 4, 6]"), "{e}");
        // A views artifact is a valid targets input; latents are not.
        let good: &[(&str, &[usize])] = &[
            ("rgb.npy", &[2, 4, 6, 3]),
            ("depth.npy", &[2, 4, 6]),
            ("alpha.npy", &[2, 4, 6]),
        ];
        let v2 = d.path().join("views2");
        write(&v2, ArtifactKind::Views, good, serde_json::json!({}));
        let views = read_views(&v2).unwrap();
        assert_eq!(views.dim(), (2, 4, 6));
        assert_eq!(views.rgb[[1, 3, 5, 2]], (2 * 4 * 6 * 3 - 1) as f32 * 0.01);
        assert_eq!(read_targets(&v2).unwrap().rgb, views.rgb);
        let l = d.path().join("lat");
        write(
            &l,
            ArtifactKind::Latents,
            &[("latents.npy", &[2, 4, 1, 2])],
            serde_json::json!({}),
        );
        assert_eq!(read_latents(&l).unwrap().dim(), (2, 4, 1, 2));
        let e = read_targets(&l).unwrap_err().to_string();
        assert!(e.contains("`targets` or `views`"), "{e}");
        // Noised latents: one shape for the three tensors, and a timestep.
        let z: &[usize] = &[2, 4, 1, 2];
        let n = d.path().join("noised");
        let parts: &[(&str, &[usize])] = &[
            ("z_src.npy", z),
            ("z_tgt.npy", z),
            ("eps.npy", &[2, 4, 2, 1]),
            ("eps_shared.npy", &[4, 1, 2]),
        ];
        write(
            &n,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({"timestep": 7}),
        );
        let e = read_noised_latents(&n).unwrap_err().to_string();
        assert!(e.contains("eps.npy") && e.contains("z_src.npy"), "{e}");
        let parts: &[(&str, &[usize])] = &[
            ("z_src.npy", z),
            ("z_tgt.npy", z),
            ("eps.npy", z),
            ("eps_shared.npy", &[4, 1, 2]),
        ];
        let n2 = d.path().join("noised2");
        write(
            &n2,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({}),
        );
        let e = read_noised_latents(&n2).unwrap_err().to_string();
        assert!(e.contains("meta.timestep"), "{e}");
        let n3 = d.path().join("noised3");
        write(
            &n3,
            ArtifactKind::NoisedLatents,
            parts,
            serde_json::json!({"timestep": 7}),
        );
        let nl = read_noised_latents(&n3).unwrap();
        assert_eq!((nl.timestep, nl.eps_shared.dim()), (7, (4, 1, 2)));
    }

    #[test]
    fn viewer_scene_embeds_spz_files_as_written() {
        let d = tempfile::tempdir().unwrap();
        let s = crate::sample::sample_scene(0);
        let spz_path = d.path().join("s.spz");
        scene::spz::write_spz(&spz_path, &s).unwrap();
        let (v, back) = read_viewer_scene("original", &spz_path).unwrap();
        assert_eq!(v.spz, std::fs::read(&spz_path).unwrap());
        assert_eq!(back.len(), s.len());
        let ply = d.path().join("s.ply");
        crate::scene::ply::write_ply(&ply, &s).unwrap();
        let (v, _) = read_viewer_scene("stylized", &ply).unwrap();
        assert!(v.source.ends_with("(as .spz)"));
        assert_eq!(scene::spz::parse_spz(&ply, &v.spz).unwrap().len(), s.len());
        let bad = d.path().join("bad.spz");
        std::fs::write(&bad, b"nope").unwrap();
        assert!(
            read_viewer_scene("x", &bad)
                .unwrap_err()
                .to_string()
                .contains("bad.spz")
        );
    }
}

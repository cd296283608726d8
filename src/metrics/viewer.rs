//! The report's interactive 3D viewer: the original and the stylized splat side by side,
//! one camera shared by both panes (orbit, pan or zoom either and the other follows),
//! starting at the first evaluation view's camera.
//!
//! Rendering is Spark (`@sparkjsdev/spark`, MIT) on three.js (MIT), not our own WebGL:
//! set-up (`scripts/setup/50_viewer.sh`) installs both from the npm registry at pinned
//! versions into `vendor/viewer/` and bundles them with `scripts/viewer/entry.js` into
//! one classic script, `vendor/viewer/viewer.js` (the global `FantasyViewerLib`). The
//! report inlines that script and the two scenes, so `report.html` opens from disk
//! (file://) by double-click with no server, no network and no files beside it. A file://
//! page cannot fetch local files in Chromium, so the scenes are embedded as base64 `.spz`
//! (version 3, [`crate::scene::spz`]; a scene artifact's own `scene.spz` is embedded as
//! written, anything else is encoded on the fly) and loaded with Spark's from-bytes API.
//! When the bundle is not installed the section says so and how to install it.
//!
//! The start camera is evaluation view 0 exactly (OpenCV axes converted to three.js's:
//! x right, y up, z backward; the principal point is taken at the image centre). Orbits
//! turn about the mean "up" of the evaluation cameras around the point of view 0's
//! optical axis nearest the scene's median position.

use crate::camera::Camera;
use crate::scene::Scene;
use crate::{Error, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Environment variable naming the directory that holds the viewer bundle (`viewer.js`).
pub const VIEWER_ENV: &str = "FANTASYSTYLE_VIEWER";
/// File name of the bundle in that directory.
pub const BUNDLE_FILE: &str = "viewer.js";
/// Longer side of a viewer pane in CSS pixels.
pub const PANE_SIDE: usize = 420;

/// The installed bundle: `$FANTASYSTYLE_VIEWER/viewer.js` when the variable is set, else
/// the first `vendor/viewer/viewer.js` near the executable, the current directory or the
/// source tree ([`crate::models::vendor_candidates`]); `None` if there is none.
pub fn bundle_path() -> Option<PathBuf> {
    if let Some(d) = std::env::var_os(VIEWER_ENV).filter(|d| !d.is_empty()) {
        let p = PathBuf::from(d).join(BUNDLE_FILE);
        return p.is_file().then_some(p);
    }
    crate::models::vendor_candidates("viewer")
        .into_iter()
        .map(|d| d.join(BUNDLE_FILE))
        .find(|p| p.is_file())
}

/// Read the bundle at `path` as inline-script text; refused if it could end the
/// `<script>` element early.
pub fn load_bundle(path: &Path) -> Result<String> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let lower = text.to_ascii_lowercase();
    if lower.contains("</script") || lower.contains("<!--") {
        return Err(Error::input(
            path,
            "the viewer bundle contains `</script` or `<!--` and cannot be inlined",
        ));
    }
    Ok(text)
}

/// One pane's scene as the page embeds it.
#[derive(Debug, Clone)]
pub struct ViewerScene {
    /// "original" or "stylized".
    pub label: String,
    /// Where it came from, for the caption.
    pub source: String,
    /// The `.spz` bytes embedded.
    pub spz: Vec<u8>,
    pub gaussians: usize,
}

/// The start camera, in three.js terms.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ViewerCamera {
    /// The evaluation view it reproduces.
    pub name: String,
    /// Image size of the evaluation views.
    pub width: usize,
    pub height: usize,
    /// Vertical field of view, degrees.
    pub fov_y: f64,
    pub near: f64,
    pub far: f64,
    /// Camera centre.
    pub position: [f64; 3],
    /// three.js camera axes in world coordinates: x right, y up, z backward.
    pub x: [f64; 3],
    pub y: [f64; 3],
    pub z: [f64; 3],
    /// The orbit centre and the orbit's up axis.
    pub target: [f64; 3],
    pub up: [f64; 3],
}

impl ViewerCamera {
    /// View 0 of `cams`, orbiting the point of its optical axis nearest `scene`'s median
    /// position, about the mean up direction of all `cams`.
    pub fn from_views(cams: &[Camera], scene: &Scene) -> ViewerCamera {
        use crate::geometry::DVec3;
        let c = &cams[0];
        let (r, _) = c.w2c();
        let (right, down, fwd) = (r.row(0), r.row(1), r.row(2));
        let pos = DVec3::from_array(c.center().map(f64::from));
        let median = |k: usize| {
            let mut v: Vec<f32> = scene.positions.iter().map(|p| p[k]).collect();
            if v.is_empty() {
                return 0.0;
            }
            let m = v.len() / 2;
            *v.select_nth_unstable_by(m, f32::total_cmp).1 as f64
        };
        let mid = DVec3::new(median(0), median(1), median(2));
        let along = (mid - pos).dot(fwd);
        let dist = if along > 1e-6 {
            along
        } else {
            (mid - pos).length().max(1.0)
        };
        let target = pos + fwd * dist;
        let up: DVec3 = cams.iter().map(|cam| -cam.w2c().0.row(1)).sum();
        let n = up.length();
        let up = if n > 1e-6 { up * (1.0 / n) } else { -down };
        ViewerCamera {
            name: c.name.clone(),
            width: c.width as usize,
            height: c.height as usize,
            fov_y: 2.0 * (c.height as f64 / (2.0 * c.fy as f64)).atan().to_degrees(),
            near: dist * 0.01,
            far: dist * 100.0,
            position: pos.to_array(),
            x: right.to_array(),
            y: (-down).to_array(),
            z: (-fwd).to_array(),
            target: target.to_array(),
            up: up.to_array(),
        }
    }

    /// Pane size in CSS pixels: the views' aspect, longer side [`PANE_SIDE`].
    pub fn pane_size(&self) -> (usize, usize) {
        let s = PANE_SIDE as f64 / self.width.max(self.height) as f64;
        (
            (self.width as f64 * s).round().max(1.0) as usize,
            (self.height as f64 * s).round().max(1.0) as usize,
        )
    }
}

/// The page script: builds the two panes once the bundle has loaded (see the module
/// docs). Frames are drawn on demand, not continuously. Sets `<html data-viewer="ready">`
/// once both panes have drawn their splats (after Spark's first sort), or `"error"` with
/// the reason in `#fs-viewer-status`; counts the frames drawn in `data-frames` and says
/// `data-drawing="1"` while a frame is due (what the browser test waits for).
const VIEWER_JS: &str = r#"(() => {
  const status = document.getElementById("fs-viewer-status");
  const root = document.documentElement;
  const fail = (msg) => {
    status.textContent = "viewer error: " + msg;
    root.dataset.viewer = "error";
  };
  try {
    const cfg = JSON.parse(document.getElementById("fs-viewer-config").textContent);
    const L = window.FantasyViewerLib;
    if (!L) return fail("the viewer library did not load");
    const THREE = L.THREE;
    const cam = cfg.camera;
    const camera = new THREE.PerspectiveCamera(cam.fov_y, cam.width / cam.height, cam.near, cam.far);
    camera.up.fromArray(cam.up);
    const target = new THREE.Vector3();
    const v3 = (a) => new THREE.Vector3().fromArray(a);
    const home = () => {
      camera.position.fromArray(cam.position);
      camera.quaternion.setFromRotationMatrix(new THREE.Matrix4().makeBasis(v3(cam.x), v3(cam.y), v3(cam.z)));
      camera.updateMatrixWorld();
      target.fromArray(cam.target);
    };
    // Frames are drawn on demand: after loading, after each camera change, and when
    // Spark says a pane needs one (its sort, done in a worker, has caught up).
    let pending = false, drawn = 0, loaded = false;
    const request = () => {
      if (!pending) {
        pending = true;
        root.dataset.drawing = "1";
        requestAnimationFrame(frame);
      }
    };
    const frame = () => {
      pending = false;
      if (loaded) {
        // Spark shows a pane's splats once their first sort is in.
        const sorted = panes.every((p) => p.spark.activeSplats > 0);
        for (const p of panes) p.renderer.render(p.scene, camera);
        drawn += 1;
        root.dataset.frames = String(drawn);
        if (!sorted) {
          request();
        } else if (root.dataset.viewer !== "ready") {
          status.textContent = "";
          root.dataset.viewer = "ready";
        }
      }
      if (!pending) root.dataset.drawing = "0";
    };
    const panes = cfg.scenes.map((sc, i) => {
      const canvas = document.getElementById("fs-viewer-" + i);
      const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
      renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
      renderer.setSize(cfg.pane_width, cfg.pane_height, false);
      renderer.setClearColor(new THREE.Color().fromArray(cfg.background), 1);
      const scene = new THREE.Scene();
      const spark = new L.SparkRenderer({ renderer, onDirty: request });
      scene.add(spark);
      const bin = atob(sc.spz);
      const bytes = new Uint8Array(bin.length);
      for (let k = 0; k < bin.length; k++) bytes[k] = bin.charCodeAt(k);
      const mesh = new L.SplatMesh({ fileBytes: bytes, fileType: L.SplatFileType.SPZ });
      scene.add(mesh);
      const controls = new L.OrbitControls(camera, canvas);
      controls.target = target;
      controls.addEventListener("change", request);
      return { renderer, scene, mesh, spark };
    });
    home();
    document.getElementById("fs-viewer-reset").addEventListener("click", () => {
      home();
      request();
    });
    root.dataset.drawing = "1";
    Promise.all(panes.map((p) => p.mesh.initialized)).then(() => {
      loaded = true;
      request();
    }, (e) => fail("loading a scene: " + e));
  } catch (e) {
    fail(String(e));
  }
})();"#;

/// The viewer section's HTML: two panes, a reset button, the embedded scenes and, when
/// `bundle` is given, the library and the page script; else a note saying how to install
/// the viewer.
pub fn section_html(
    bundle: Option<&str>,
    scenes: &[ViewerScene; 2],
    cam: &ViewerCamera,
    background: [f32; 3],
) -> String {
    let esc = super::html::esc;
    let (pw, ph) = cam.pane_size();
    let mut s = String::from("<div id=\"fs-viewer\">");
    if bundle.is_some() {
        let _ = write!(
            s,
            "<p class=\"note\">Drag to orbit, right-drag to pan, wheel to zoom: both panes \
             share one camera. It starts at evaluation view 0 (<code>{}</code>). \
             <button id=\"fs-viewer-reset\" type=\"button\">reset view</button> \
             <span id=\"fs-viewer-status\">loading&hellip;</span></p>",
            esc(&cam.name)
        );
    } else {
        s.push_str(
            "<p class=\"warn\" id=\"fs-viewer-missing\">The interactive viewer was not \
             included: its library is not installed (<code>scripts/setup/50_viewer.sh</code> \
             installs it into <code>vendor/viewer</code>, or set <code>FANTASYSTYLE_VIEWER</code>); \
             evaluate again after installing it. The scenes are:</p>",
        );
    }
    s.push_str("<div id=\"fs-viewer-panes\" style=\"display:flex;gap:12px;flex-wrap:wrap\">");
    for (i, sc) in scenes.iter().enumerate() {
        let caption = format!(
            "{}: {} ({} Gaussians, .spz {:.1} KiB)",
            sc.label,
            sc.source,
            sc.gaussians,
            sc.spz.len() as f64 / 1024.0
        );
        if bundle.is_some() {
            let _ = write!(
                s,
                "<figure style=\"width:{pw}px\"><canvas id=\"fs-viewer-{i}\" \
                 style=\"width:{pw}px;height:{ph}px;display:block;touch-action:none\"></canvas>\
                 <figcaption>{}</figcaption></figure>",
                esc(&caption)
            );
        } else {
            let _ = write!(
                s,
                "<figure><figcaption>{}</figcaption></figure>",
                esc(&caption)
            );
        }
    }
    s.push_str("</div>");
    if let Some(lib) = bundle {
        let cfg = serde_json::json!({
            "camera": cam,
            "pane_width": pw,
            "pane_height": ph,
            "background": background,
            "scenes": scenes.iter().map(|sc| serde_json::json!({
                "label": sc.label,
                "spz": super::html::base64(&sc.spz),
            })).collect::<Vec<_>>(),
        });
        // `<` only occurs inside JSON strings; as \u003c it cannot end the element.
        let cfg = cfg.to_string().replace('<', "\\u003c");
        let _ = write!(
            s,
            "<script type=\"application/json\" id=\"fs-viewer-config\">{cfg}</script>\n\
             <script>{lib}</script>\n<script>{VIEWER_JS}</script>"
        );
    }
    s.push_str("</div>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::orbit::{OrbitSpec, orbit};

    fn scene() -> Scene {
        crate::sample::sample_scene(0)
    }

    fn cameras(s: &Scene, n: usize, w: u32, h: u32) -> Vec<Camera> {
        let o = OrbitSpec::parse(&format!("{n},elev=30,radius=2.4,fov=50")).unwrap();
        orbit(&o, &s.bounds(), w, h).unwrap()
    }

    #[test]
    fn start_camera_is_view_zero_in_three_js_axes() {
        let s = scene();
        let cams = cameras(&s, 8, 64, 48);
        let c = ViewerCamera::from_views(&cams, &s);
        let cv = &cams[0];
        assert_eq!(c.position, cv.center().map(f64::from));
        // Looking down -z: the target is in front, straight ahead.
        use crate::geometry::DVec3;
        let v = DVec3::from_array;
        let dir = v(c.target) - v(c.position);
        let fwd = v(cv.rotation[2].map(f64::from));
        assert!((dir.normalize().dot(fwd) - 1.0).abs() < 1e-6);
        assert_eq!(c.z, (-fwd).to_array());
        // Right-handed basis.
        assert!(v(c.x).cross(v(c.y)).dot(v(c.z)) > 0.999);
        // The sample's up is -y; an orbit's mean camera up is exactly that.
        assert!((c.up[1] + 1.0).abs() < 1e-6, "{:?}", c.up);
        let fov = 2.0 * (48.0 / (2.0 * cv.fy as f64)).atan().to_degrees();
        assert!((c.fov_y - fov).abs() < 1e-9);
        assert_eq!(c.pane_size(), (420, 315));
    }

    #[test]
    fn section_embeds_scenes_or_says_how_to_install() {
        let s = scene();
        let cams = cameras(&s, 4, 32, 32);
        let cam = ViewerCamera::from_views(&cams, &s);
        let spz = crate::scene::spz::encode_spz(Path::new("x"), &s).unwrap();
        let sc = |label: &str| ViewerScene {
            label: label.into(),
            source: "a<b>.ply".into(),
            spz: spz.clone(),
            gaussians: s.len(),
        };
        let scenes = [sc("original"), sc("stylized")];
        let html = section_html(Some("window.FantasyViewerLib={};"), &scenes, &cam, [0.0; 3]);
        assert!(html.contains("fs-viewer-0") && html.contains("fs-viewer-1"));
        assert!(html.contains(&super::super::html::base64(&spz)));
        assert!(html.contains("a&lt;b&gt;.ply") && !html.contains("a<b>"));
        let cfg = html.split("id=\"fs-viewer-config\">").nth(1).unwrap();
        let cfg: serde_json::Value =
            serde_json::from_str(cfg.split("</script>").next().unwrap()).unwrap();
        assert_eq!(cfg["scenes"][1]["label"], "stylized");
        assert_eq!(cfg["camera"]["width"], 32);
        let none = section_html(None, &scenes, &cam, [0.0; 3]);
        assert!(none.contains("50_viewer.sh") && !none.contains("<script"));
    }

    #[test]
    fn bundles_that_would_end_the_script_element_are_refused() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("viewer.js");
        std::fs::write(&p, "var a = 1;").unwrap();
        assert_eq!(load_bundle(&p).unwrap(), "var a = 1;");
        std::fs::write(&p, "var a = '</SCRIPT>';").unwrap();
        assert!(load_bundle(&p).is_err());
    }
}

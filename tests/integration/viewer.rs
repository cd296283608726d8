//! Issue 19: the report's interactive 3D viewer in a real browser. `evaluate` is run on
//! the sample scene and a recoloured copy of it (written as `.spz`, so the browser loads
//! the file our writer made); headless Chromium with software WebGL opens report.html
//! from disk (file://), the test waits until the page says the viewer has drawn, and
//! takes a screenshot. Both panes must show the object where evaluation view 0 shows it,
//! and each pane must look like its own scene's render of that view, not the other's.
//! Then a mouse drag orbits the left pane: the view must change and both panes must
//! still show the same silhouette (one camera).
//!
//! Needs Chromium (scripts/setup/05_chromium.sh), the viewer bundle
//! (scripts/setup/50_viewer.sh) and the metric networks; under CI=true a missing one is
//! a failure, otherwise the test says SKIPPED.

use fantasystyle::artifacts::read_view_set;
use fantasystyle::imageio::Image;
use fantasystyle::metrics::nets::LpipsNet;
use fantasystyle::metrics::viewer::{PANE_SIDE, bundle_path};
use fantasystyle::scene::SH_C0;
use fantasystyle::stages::evaluate::{Args, run};
use std::path::{Path, PathBuf};
use std::process::Command;

/// `Some(())` if `ok`; else a failure under CI=true, or SKIPPED.
fn need(ok: bool, what: &str) -> Option<()> {
    if ok {
        return Some(());
    }
    assert!(
        !std::env::var("CI").is_ok_and(|v| v == "true"),
        "{what} is required under CI"
    );
    eprintln!("SKIPPED: {what} is not installed");
    None
}

fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        })
}

/// Headless Chromium driven over the DevTools protocol on a pipe
/// (`--remote-debugging-pipe`: commands on its fd 3, replies on its fd 4, NUL-separated
/// JSON), so the test can wait in real time for the page to say it has drawn. `sh` only
/// moves our stdin/stdout pipes to fds 3 and 4; the arguments stay arguments.
struct Browser {
    child: std::process::Child,
    input: std::process::ChildStdin,
    replies: std::sync::mpsc::Receiver<serde_json::Value>,
    next: u64,
    session: Option<String>,
}

impl Browser {
    fn launch(bin: &str, profile: &Path) -> Browser {
        use std::io::Read;
        use std::process::Stdio;
        let mut child = Command::new("sh")
            .arg("-c")
            .arg("exec \"$0\" \"$@\" 3<&0 4>&1 </dev/null >/dev/null")
            .arg(bin)
            .args([
                "--headless",
                "--no-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist",
                "--no-first-run",
                "--disable-quic",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--hide-scrollbars",
                "--remote-debugging-pipe",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let input = child.stdin.take().unwrap();
        let mut out = child.stdout.take().unwrap();
        let (tx, replies) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let (mut buf, mut chunk) = (Vec::new(), vec![0u8; 1 << 16]);
            loop {
                match out.read(&mut chunk) {
                    Ok(0) | Err(_) => return,
                    Ok(k) => buf.extend_from_slice(&chunk[..k]),
                }
                while let Some(end) = buf.iter().position(|b| *b == 0) {
                    let msg: Vec<u8> = buf.drain(..=end).collect();
                    if let Ok(v) = serde_json::from_slice(&msg[..end])
                        && tx.send(v).is_err()
                    {
                        return;
                    }
                }
            }
        });
        Browser {
            child,
            input,
            replies,
            next: 0,
            session: None,
        }
    }

    /// Send `method` (to the attached page, if any) and wait up to a minute for its reply.
    fn call(&mut self, method: &str, params: serde_json::Value) -> serde_json::Value {
        use std::io::Write;
        self.next += 1;
        let mut msg = serde_json::json!({"id": self.next, "method": method, "params": params});
        if let Some(s) = &self.session {
            msg["sessionId"] = s.clone().into();
        }
        let mut bytes = serde_json::to_vec(&msg).unwrap();
        bytes.push(0);
        self.input.write_all(&bytes).unwrap();
        self.input.flush().unwrap();
        loop {
            let m = self
                .replies
                .recv_timeout(std::time::Duration::from_secs(60))
                .unwrap_or_else(|e| panic!("chromium: no reply to {method}: {e}"));
            if m["id"] == self.next {
                assert!(m.get("error").is_none(), "chromium: {method}: {m}");
                return m["result"].clone();
            }
        }
    }

    /// Open `url` in a new page of `w` x `h` CSS pixels (device scale 1).
    fn open(&mut self, url: &str, w: usize, h: usize) {
        let t = self.call(
            "Target.createTarget",
            serde_json::json!({"url": "about:blank"}),
        );
        let a = self.call(
            "Target.attachToTarget",
            serde_json::json!({"targetId": t["targetId"], "flatten": true}),
        );
        self.session = Some(a["sessionId"].as_str().unwrap().to_string());
        self.call(
            "Emulation.setDeviceMetricsOverride",
            serde_json::json!({"width": w, "height": h, "deviceScaleFactor": 1, "mobile": false}),
        );
        self.call("Page.navigate", serde_json::json!({ "url": url }));
    }

    /// A left-button mouse event at page coordinates (`buttons`: 1 while held).
    fn mouse(&mut self, kind: &str, x: f64, y: f64, buttons: u32) {
        self.call(
            "Input.dispatchMouseEvent",
            serde_json::json!({"type": kind, "x": x, "y": y, "button": "left",
                "buttons": buttons, "clickCount": 1}),
        );
    }

    /// A PNG screenshot of the page's viewport, written to `path`.
    fn screenshot(&mut self, path: &Path) {
        let t = std::time::Instant::now();
        let png = self.call(
            "Page.captureScreenshot",
            serde_json::json!({"format": "png", "optimizeForSpeed": true}),
        );
        std::fs::write(path, unbase64(png["data"].as_str().unwrap())).unwrap();
        eprintln!("screenshot: {:.1} s", t.elapsed().as_secs_f64());
    }

    /// The value of a JavaScript expression in the page.
    fn eval(&mut self, expr: &str) -> serde_json::Value {
        let r = self.call(
            "Runtime.evaluate",
            serde_json::json!({"expression": expr, "returnByValue": true}),
        );
        r["result"]["value"].clone()
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Standard base64 (with padding) decoded; the screenshot comes as such.
fn unbase64(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c}"),
    };
    let mut out = Vec::with_capacity(s.len() / 4 * 3);
    for q in s.as_bytes().chunks(4) {
        let n = q.iter().take_while(|c| **c != b'=').count();
        let v = q[..n].iter().fold(0u32, |a, c| a << 6 | val(*c) as u32) << (6 * (4 - n));
        out.extend_from_slice(&v.to_be_bytes()[1..n]);
    }
    out
}

/// Render `scene` from `cameras` into a views artifact at `out` (the stage binary).
fn render_views(scene: &Path, cameras: &str, out: &Path) -> PathBuf {
    let o = Command::new(env!("CARGO_BIN_EXE_render-views"))
        .arg("--scene")
        .arg(scene)
        .args(["--cameras", cameras, "--width", "128", "--height", "128"])
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out.to_path_buf()
}

/// A distinct, deterministic "stylization": every base colour remapped.
fn recolour(s: &mut fantasystyle::Scene) {
    for d in &mut s.sh_dc {
        let b = d.map(|v| (0.5 + SH_C0 * v).clamp(0.0, 1.0));
        let n = [1.0 - b[1], 0.2 + 0.7 * b[0] * b[2], 0.5 * (b[0] + b[1])];
        *d = n.map(|v| (v - 0.5) / SH_C0);
    }
}

/// Mean absolute difference of `a` and `b` over `mask`.
fn mad(a: &Image, b: &Image, mask: &[bool]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for (i, m) in mask.iter().enumerate() {
        if *m {
            for c in 0..3 {
                s += (a.data[i * 3 + c] - b.data[i * 3 + c]).abs() as f64;
            }
            n += 3;
        }
    }
    s / n.max(1) as f64
}

/// `img` resized to `w` x `h` (nearest neighbour).
fn nearest(img: &Image, w: usize, h: usize) -> Image {
    Image::from_fn(w, h, |x, y| img.px(x * img.width / w, y * img.height / h))
}

#[test]
fn report_viewer_shows_both_splats_in_chromium() {
    let Some(chrome_bin) = chromium() else {
        need(false, "chromium (scripts/setup/05_chromium.sh)");
        return;
    };
    if need(
        bundle_path().is_some(),
        "the viewer bundle (scripts/setup/50_viewer.sh)",
    )
    .is_none()
        || need(
            fantasystyle::runtime::library_path().is_ok()
                && fantasystyle::models::models_dir().is_ok_and(|m| m.join("metrics").is_dir()),
            "onnxruntime and the metric networks (scripts/setup.sh)",
        )
        .is_none()
    {
        return;
    }
    let root = crate::harness::repo_root();
    let d = tempfile::tempdir().unwrap();
    let orig_scene = root.join("data-sample/scene.ply");
    let mut s = fantasystyle::artifacts::load_scene(&orig_scene).unwrap();
    recolour(&mut s);
    let styl_scene = d.path().join("stylized.spz");
    fantasystyle::scene::spz::write_spz(&styl_scene, &s).unwrap();
    let cams = "orbit:4,elev=30,radius=2.4,fov=50";
    let t_all = std::time::Instant::now();
    let orig = render_views(&orig_scene, cams, &d.path().join("orig"));
    let styl = render_views(&styl_scene, cams, &d.path().join("styl"));
    let out = d.path().join("eval");
    eprintln!("scenes and renders: {:.1} s", t_all.elapsed().as_secs_f64());
    let t_eval = std::time::Instant::now();
    run(Args {
        original: Some(orig.clone()),
        stylized: Some(styl.clone()),
        style: Some(root.join("data-sample/style.png")),
        out: out.clone(),
        reference_only: None,
        reference: Vec::new(),
        cameras: None,
        width: None,
        height: None,
        lpips_net: LpipsNet::Alex,
        short_range: 1,
        long_range: 2,
        seed: 0,
        object_squares: 0,
        inception: false,
        style_size: fantasystyle::metrics::interior::STYLE_SHORTER_SIDE,
        threads: fantasystyle::stages::Threads::new(2),
        sweep: None,
        original_scene: Some(orig_scene.clone()),
        stylized_scene: Some(styl_scene.clone()),
        history: None,
        refit_baseline: None,
        preview: None,
    })
    .unwrap();
    eprintln!("evaluate: {:.1} s", t_eval.elapsed().as_secs_f64());
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("id=\"fs-viewer-config\"") && html.contains("FantasyViewerLib"));
    // The stylized pane embeds the very file the writer made.
    let b64 = fantasystyle::metrics::html::base64(&std::fs::read(&styl_scene).unwrap());
    assert!(html.contains(&b64));

    // Open the report from disk and wait (real time) until the viewer says it has drawn.
    let report = out.join("report.html");
    let t0 = std::time::Instant::now();
    let mut b = Browser::launch(chrome_bin, &d.path().join("profile"));
    b.open(&format!("file://{}", report.display()), 1100, 1000);
    let mut state = String::new();
    while t0.elapsed().as_secs() < 120 {
        let v = b.eval(
            "(document.documentElement.dataset.viewer || '') + '|' + \
             (document.getElementById('fs-viewer-status') || {}).textContent",
        );
        state = v.as_str().unwrap_or("").to_string();
        if state.starts_with("ready") || state.starts_with("error") {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
    eprintln!(
        "viewer state after {:.1} s: {state}",
        t0.elapsed().as_secs_f64()
    );
    assert!(
        state.starts_with("ready|"),
        "the viewer did not draw: {state}"
    );
    let rects: Vec<[f64; 4]> = serde_json::from_value(b.eval(
        "[0, 1].map(i => { const r = document.getElementById('fs-viewer-' + i)\
         .getBoundingClientRect(); return [r.left, r.top, r.width, r.height]; })",
    ))
    .unwrap();
    // Until the frames due are drawn (a screenshot waits for a frame of its own).
    let idle = |b: &mut Browser| {
        let t = std::time::Instant::now();
        while b.eval("document.documentElement.dataset.drawing") != "0" {
            assert!(t.elapsed().as_secs() < 60, "the viewer keeps drawing");
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
    };
    idle(&mut b);
    let shot = d.path().join("shot.png");
    b.screenshot(&shot);
    if let Ok(keep) = std::env::var("FANTASYSTYLE_KEEP_SCREENSHOT") {
        std::fs::copy(&shot, &keep).unwrap();
        std::fs::copy(&report, format!("{keep}.html")).unwrap();
    }
    // Orbit: drag across the left pane; both panes must follow.
    let frames = |b: &mut Browser| {
        let v = b.eval("Number(document.documentElement.dataset.frames || 0)");
        v.as_u64().unwrap_or(0)
    };
    // Idle now (the screenshot above waited for that): every frame from here is the drag's.
    let before = frames(&mut b);
    let (cx, cy) = (
        rects[0][0] + rects[0][2] / 2.0,
        rects[0][1] + rects[0][3] / 2.0,
    );
    b.mouse("mousePressed", cx, cy, 1);
    for k in 1..=8 {
        b.mouse("mouseMoved", cx + 12.0 * k as f64, cy, 1);
    }
    b.mouse("mouseReleased", cx + 96.0, cy, 0);
    let t1 = std::time::Instant::now();
    while frames(&mut b) == before {
        assert!(t1.elapsed().as_secs() < 60, "no redraw after the drag");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    idle(&mut b);
    eprintln!("orbit redrawn in {:.1} s", t1.elapsed().as_secs_f64());
    let shot2 = d.path().join("shot2.png");
    b.screenshot(&shot2);
    drop(b);
    if let Ok(keep) = std::env::var("FANTASYSTYLE_KEEP_SCREENSHOT") {
        std::fs::copy(&shot2, format!("{keep}.orbited.png")).unwrap();
    }
    let side = PANE_SIDE;
    for r in &rects {
        assert!(
            r[2] as usize == side
                && r[3] as usize == side
                && r[0] + r[2] <= 1100.0
                && r[1] + r[3] <= 1000.0,
            "panes {rects:?} are not {side} px squares inside the page"
        );
    }
    assert!(
        rects[1][0] >= rects[0][0] + rects[0][2],
        "side by side: {rects:?}"
    );
    let img = Image::load(&shot).unwrap();
    let views_o = read_view_set(&orig).unwrap();
    let views_s = read_view_set(&styl).unwrap();
    let (w, h) = (views_o.width, views_o.height);
    let pane = |i: usize| {
        let (x0, y0) = (rects[i][0].round() as usize, rects[i][1].round() as usize);
        Image::from_fn(side, side, |x, y| img.px(x0 + x, y0 + y))
    };
    let (left, right) = (pane(0), pane(1));
    let img2 = Image::load(&shot2).unwrap();
    let pane2 = |i: usize| {
        let (x0, y0) = (rects[i][0].round() as usize, rects[i][1].round() as usize);
        Image::from_fn(side, side, |x, y| img2.px(x0 + x, y0 + y))
    };
    let (left2, right2) = (pane2(0), pane2(1));
    let ref_o = nearest(&views_o.images[0], side, side);
    let ref_s = nearest(&views_s.images[0], side, side);
    // Object: alpha of view 0 above 0.9; background: below 0.01 (edges are left out).
    let alpha = |x: usize, y: usize| views_o.alpha[(y * h / side) * w + x * w / side];
    let obj: Vec<bool> = (0..side * side)
        .map(|i| alpha(i % side, i / side) > 0.9)
        .collect();
    let bg: Vec<bool> = (0..side * side)
        .map(|i| alpha(i % side, i / side) < 0.01)
        .collect();
    let lit = |p: &Image, i: usize| (0..3).any(|c| p.data[i * 3 + c] > 0.06);
    let share = |p: &Image, mask: &[bool], want: bool| {
        let n = mask.iter().filter(|m| **m).count();
        let k = (0..mask.len())
            .filter(|&i| mask[i] && lit(p, i) == want)
            .count();
        k as f64 / n.max(1) as f64
    };
    let (e_lo, e_ls) = (mad(&left, &ref_o, &obj), mad(&left, &ref_s, &obj));
    let (e_rs, e_ro) = (mad(&right, &ref_s, &obj), mad(&right, &ref_o, &obj));
    let (d_panes, d_renders) = (mad(&left, &right, &obj), mad(&ref_o, &ref_s, &obj));
    // After the orbit: the view changed, and both panes show the same silhouette.
    let n = side * side;
    let frac = |f: &dyn Fn(usize) -> bool| (0..n).filter(|&i| f(i)).count() as f64 / n as f64;
    let moved = frac(&|i| lit(&left, i) != lit(&left2, i));
    let agree = frac(&|i| lit(&left2, i) == lit(&right2, i));
    let agree0 = frac(&|i| lit(&left, i) == lit(&right, i));
    let report = format!(
        "orbit changed {moved:.3} of the left pane's silhouette; silhouettes agree \
         {agree0:.3} before, {agree:.3} after; \
         object pixels lit: left {:.3} right {:.3}; background dark: left {:.3} right {:.3}; \
         left vs original render {e_lo:.4} vs stylized {e_ls:.4}; right vs stylized {e_rs:.4} \
         vs original {e_ro:.4}; panes differ {d_panes:.4}, renders differ {d_renders:.4}",
        share(&left, &obj, true),
        share(&right, &obj, true),
        share(&left, &bg, false),
        share(&right, &bg, false),
    );
    eprintln!(
        "viewer: {report}; whole test {:.1} s",
        t_all.elapsed().as_secs_f64()
    );
    let ok = share(&left, &obj, true) > 0.95
        && share(&right, &obj, true) > 0.95
        && share(&left, &bg, false) > 0.95
        && share(&right, &bg, false) > 0.95
        && e_lo < 0.5 * e_ls
        && e_rs < 0.5 * e_ro
        && e_lo < 0.08
        && e_rs < 0.08
        && d_panes > 0.7 * d_renders
        && moved > 0.05
        && agree > 0.97
        && agree0 > 0.97;
    assert!(ok, "{report}");
}

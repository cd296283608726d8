//! Several regions in one run (`distill --region`, issue 54): each region takes its own
//! style in one pass, the geometry and every Gaussian outside the regions keep their
//! bits, one region over the whole scene is the plain run bit for bit, and bad input is
//! refused naming the region with nothing written.

use crate::harness::{bin, ok, repo_root};
use fantasystyle::Scene;
use fantasystyle::artifacts::load_scene;
use fantasystyle::sample::sample_parts;
use std::path::{Path, PathBuf};
use std::process::Command;

fn part(name: &str) -> std::ops::Range<usize> {
    sample_parts(0).into_iter().find(|p| p.0 == name).unwrap().1
}

fn sample(rel: &str) -> PathBuf {
    repo_root().join(rel)
}

const SPHERE: &str = "ellipsoid:-0.42,-0.29,0.12,0.285,0.285,0.285";
const MOSAIC: &str = "benches/quality/styles/mosaic.png";

/// 4 views of 64 x 64 of the sample into `dir/views`.
fn views(dir: &Path) -> PathBuf {
    let out = dir.join("views");
    ok(bin("render-views")
        .arg("--scene")
        .arg(sample("data-sample/scene.ply"))
        .args(["--cameras", "orbit:4,elev=30,radius=2.4"])
        .args(["--width", "64", "--height", "64", "--threads", "2", "--out"])
        .arg(&out));
    out
}

/// The default end on the sample with `args`, into `out`.
fn distill(views: &Path, args: &[String], out: &Path) -> Command {
    let mut c = bin("distill");
    c.arg("--scene")
        .arg(sample("data-sample/scene.ply"))
        .arg("--source-views")
        .arg(views)
        .arg("--style")
        .arg(sample("data-sample/style.png"))
        .args(["--preset", "default", "--iters", "0", "--threads", "2"])
        .args(args)
        .arg("--out")
        .arg(out);
    c
}

fn dc(s: &Scene, r: std::ops::Range<usize>) -> Vec<f32> {
    r.flat_map(|i| s.sh_dc[i]).collect()
}

fn rms(a: &[f32], b: &[f32]) -> f64 {
    let s: f64 = a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum();
    (s / a.len() as f64).sqrt()
}

fn geometry_bits(s: &Scene, i: usize) -> Vec<u32> {
    let mut v: Vec<u32> = s.positions[i]
        .iter()
        .chain(&s.log_scales[i])
        .chain(&s.rotations[i])
        .map(|x| x.to_bits())
        .collect();
    v.push(s.opacity_logits[i].to_bits());
    v
}

#[test]
fn two_regions_take_their_own_styles_in_one_run() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = views(d);
    let mosaic = sample(MOSAIC).display().to_string();
    let style = sample("data-sample/style.png").display().to_string();
    // The sphere in the sample's style, the cube in the mosaic; the ground and the cone
    // in no region.
    let input = load_scene(&sample("data-sample/scene.ply")).unwrap();
    let (sphere, cube) = (part("sphere"), part("cube"));
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for i in cube.clone() {
        for c in 0..3 {
            lo[c] = lo[c].min(input.positions[i][c]);
            hi[c] = hi[c].max(input.positions[i][c]);
        }
    }
    let cube_box = format!(
        "box:{},{},{},{},{},{}",
        lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
    );
    let two = vec![
        "--region".into(),
        format!("{SPHERE}={style}"),
        "--region".into(),
        format!("{cube_box}={mosaic}"),
    ];
    ok(&mut distill(&v, &two, &d.join("two")));
    let out = load_scene(&d.join("two")).unwrap();
    let record = fantasystyle::artifacts::read_regions(&d.join("two"))
        .unwrap()
        .unwrap();
    let mut outside = 0;
    for i in 0..input.len() {
        assert_eq!(geometry_bits(&input, i), geometry_bits(&out, i), "{i}");
        if record.weights.iter().all(|w| w[i] == 0.0) {
            outside += 1;
            assert_eq!(input.sh_dc[i], out.sh_dc[i], "Gaussian {i} is in no region");
        }
    }
    assert!(outside > 5000, "{outside}");
    // Each region in its style: nearer the run of that style alone than the other's.
    let whole = |style: &str, name: &str| {
        let args = vec![
            "--region".into(),
            format!("{SPHERE}={style}"),
            "--region".into(),
            format!("{cube_box}={style}"),
        ];
        ok(&mut distill(&v, &args, &d.join(name)));
        load_scene(&d.join(name)).unwrap()
    };
    let (a, b) = (whole(&style, "a"), whole(&mosaic, "b"));
    let n_sphere = sphere.len();
    for (name, r, own, other) in [("sphere", sphere, &a, &b), ("cube", cube, &b, &a)] {
        let got = dc(&out, r.clone());
        let (near, far) = (rms(&got, &dc(own, r.clone())), rms(&got, &dc(other, r)));
        println!("{name}: {near:.4} from its style's run, {far:.4} from the other's");
        assert!(near < 0.7 * far, "{name}: {near} vs {far}");
    }
    let record = fantasystyle::artifacts::read_regions(&d.join("two"))
        .unwrap()
        .unwrap();
    assert_eq!(record.regions.len(), 2);
    assert_eq!(record.regions[0].selected, n_sphere);
    // The report draws the regions and measures each against both styles.
    if !crate::evaluate::ready() {
        return;
    }
    ok(bin("render-views")
        .arg("--scene")
        .arg(d.join("two"))
        .arg("--cameras")
        .arg(&v)
        .args(["--width", "64", "--height", "64", "--threads", "2", "--out"])
        .arg(d.join("two-views")));
    ok(bin("evaluate")
        .arg("--original")
        .arg(&v)
        .arg("--stylized")
        .arg(d.join("two-views"))
        .arg("--style")
        .arg(sample("data-sample/style.png"))
        .arg("--original-scene")
        .arg(sample("data-sample/scene.ply"))
        .arg("--stylized-scene")
        .arg(d.join("two"))
        .args(["--threads", "2", "--out"])
        .arg(d.join("eval")));
    let html = std::fs::read_to_string(d.join("eval/report.html")).unwrap();
    assert!(html.contains("<h2>Regions</h2>") && html.contains("mosaic.png x 1.00"));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("eval/regions.json")).unwrap()).unwrap();
    assert_eq!(json["styles"].as_array().unwrap().len(), 2);
    for (r, region) in json["regions"].as_array().unwrap().iter().enumerate() {
        let g = region["gram"].as_array().unwrap();
        let (own, other) = (g[r][0].as_f64().unwrap(), g[1 - r][0].as_f64().unwrap());
        println!("region {r}: Gram to its own style {own:.3}, to the other {other:.3}");
        assert!(own < other, "region {r} is not nearest its own style");
    }
}

#[test]
fn one_region_over_the_whole_scene_is_the_plain_run() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = views(d);
    ok(&mut distill(&v, &[], &d.join("plain")));
    let mosaic = sample(MOSAIC).display().to_string();
    let style = sample("data-sample/style.png").display().to_string();
    ok(&mut distill(
        &v,
        &["--region".into(), format!("rest={style}")],
        &d.join("rest"),
    ));
    let read = |n: &str| std::fs::read(d.join(n).join("scene.ply")).unwrap();
    assert!(
        read("plain") == read("rest"),
        "the one region's run differs"
    );
    // A blend of one image at weight 1 and another at 0 is that image.
    let blend = format!("rest={style}:1,{mosaic}:0");
    ok(&mut distill(
        &v,
        &["--region".into(), blend],
        &d.join("blend"),
    ));
    assert!(
        read("plain") == read("blend"),
        "the blend of weight 0 changed it"
    );
}

#[test]
fn bad_regions_are_refused_naming_the_region() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let v = views(d);
    let style = sample("data-sample/style.png").display().to_string();
    let file = d.join("regions.toml");
    let cases: Vec<(Vec<String>, &str, &str)> = vec![
        (
            vec!["--region".into(), "box:9,9,9,10,10,10".into()],
            "region `region 1`",
            "selects no Gaussian",
        ),
        (
            vec!["--region".into(), format!("{SPHERE}=missing.png")],
            "region `region 1`",
            "missing.png",
        ),
        (
            vec!["--region".into(), format!("{SPHERE}={style}:-1")],
            "region `region 1`",
            "negative",
        ),
        (
            vec!["--region".into(), format!("{SPHERE}={style}:0")],
            "region `region 1`",
            "every weight is 0",
        ),
        (
            vec!["--region".into(), format!("{SPHERE}={style}:1,{style}:1")],
            "region `region 1`",
            "named twice",
        ),
        (
            vec!["--region".into(), format!("{SPHERE}@2")],
            "region `region 1`",
            "strength 2",
        ),
        (
            vec![
                "--region".into(),
                "rest".into(),
                "--region".into(),
                "rest".into(),
            ],
            "regions",
            "`rest` is given twice",
        ),
        (
            vec!["--regions".into(), file.display().to_string()],
            "regions.toml",
            "unknown field `colour`",
        ),
        (
            vec![
                "--region".into(),
                "rest".into(),
                "--iters".into(),
                "2".into(),
            ],
            "regions",
            "--iters 0",
        ),
    ];
    std::fs::write(
        &file,
        "[[regions]]\nselection = \"rest\"\ncolour = \"red\"\n",
    )
    .unwrap();
    for (i, (args, names, says)) in cases.into_iter().enumerate() {
        let out = d.join(format!("out{i}"));
        let mut c = distill(&v, &args, &out);
        if args.contains(&"--iters".to_string()) {
            // The case's own --iters comes last and wins over the default's.
            c = bin("distill");
            c.arg("--scene")
                .arg(sample("data-sample/scene.ply"))
                .arg("--source-views")
                .arg(&v)
                .arg("--style")
                .arg(sample("data-sample/style.png"))
                .args(["--preset", "default"])
                .args(&args)
                .arg("--out")
                .arg(&out);
        }
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(names) && err.contains(says), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?}: an output was left behind");
    }
    // Weights past 1 are normalised, and the run says so.
    let all = "box:-9,-9,-9,9,9,9";
    let args = vec![
        "--region".into(),
        format!("{SPHERE}={style}"),
        "--region".into(),
        all.into(),
    ];
    let o = ok(&mut distill(&v, &args, &d.join("overlap")));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("sum past 1"), "{err}");
}

//! Masks of one part of the sample scene (`ground`, `sphere`, `cube` or `cone`) as seen
//! from some of its cameras ([`fantasystyle::sample::part_masks`]), as PNGs named after
//! the cameras: what `select --from masks:DIR` reads. The committed
//! `data-sample/masks/` were made with
//!
//!   cargo run --release --example sample_masks -- data-sample/cameras.json sphere \
//!       data-sample/masks orbit_003 orbit_007
use fantasystyle::sample::{part_masks, sample_parts, sample_scene};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [cameras, part, out, names @ ..] = args.as_slice() else {
        return Err("usage: sample_masks CAMERAS PART OUT_DIR CAMERA_NAME...".into());
    };
    let scene = sample_scene(0);
    let range = sample_parts(0)
        .into_iter()
        .find(|(n, _)| n == part)
        .ok_or(format!("no part `{part}`"))?
        .1;
    let (cams, _) = fantasystyle::camera::load_camera_file(std::path::Path::new(cameras))?;
    let cams: Vec<_> = cams
        .into_iter()
        .filter(|c| names.contains(&c.name))
        .collect();
    if cams.len() != names.len() {
        return Err(format!("not every camera of {names:?} is in {cameras}").into());
    }
    std::fs::create_dir_all(out)?;
    for (cam, m) in cams.iter().zip(part_masks(&scene, range, &cams)?) {
        let p = std::path::Path::new(out).join(format!("{}.png", cam.name));
        let w = cam.width as usize;
        fantasystyle::imageio::write_png_gray(&p, &m, w, m.len() / w, false)?;
        println!("{}", p.display());
    }
    Ok(())
}

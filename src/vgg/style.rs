//! The style image's size limit for the VGG losses (the receptive field of relu4_3) and
//! its resizing to the drawing scale.

use super::layer::{Layer, receptive_field};
use crate::{Error, Result};

/// Smallest accepted style image side for the VGG losses: the receptive field of relu4_3
/// (92 px). A smaller image cannot fill even one deepest-layer unit, so its "style" at
/// that layer would be the zero padding's.
pub const MIN_STYLE_SIDE: usize = 92;

/// Check that a style image is large enough (see module docs) and resize it so its
/// shorter side is `style_size` ([`crate::imageio::Image::with_shorter_side`]; aspect kept). `path` names it in
/// errors.
pub fn prepare_style(
    img: &crate::imageio::Image,
    style_size: usize,
    path: &std::path::Path,
) -> Result<crate::imageio::Image> {
    debug_assert_eq!(receptive_field(Layer::Relu4_3), MIN_STYLE_SIDE);
    let short = img.width.min(img.height);
    if short < MIN_STYLE_SIDE {
        return Err(Error::input(
            path,
            format!(
                "style image is {}x{}; VGG16 needs a shorter side of at least {MIN_STYLE_SIDE} px (the receptive field of relu4_3)",
                img.width, img.height
            ),
        ));
    }
    if style_size < MIN_STYLE_SIDE {
        return Err(Error::param(format!(
            "--style-size {style_size} is below the VGG receptive field ({MIN_STYLE_SIDE} px)"
        )));
    }
    Ok(img.with_shorter_side(style_size))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn style_size_limits() {
        let p = std::path::Path::new("style.png");
        let small = crate::imageio::Image {
            width: 91,
            height: 300,
            data: vec![0.5; 91 * 300 * 3],
        };
        let e = prepare_style(&small, 256, p).unwrap_err().to_string();
        assert!(e.contains("style.png") && e.contains("92"), "{e}");
        let ok = crate::imageio::Image {
            width: 92,
            height: 184,
            data: vec![0.5; 92 * 184 * 3],
        };
        let s = prepare_style(&ok, 128, p).unwrap();
        assert_eq!((s.width, s.height), (128, 256));
        assert!(s.data.iter().all(|&v| (v - 0.5).abs() < 1e-6));
        assert!(prepare_style(&ok, 64, p).is_err());
    }
}

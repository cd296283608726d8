//! [`Tensor3`], the `[C, H, W]` feature map the VGG passes exchange.

use ndarray::ArrayView2;

/// A `[C, H, W]` feature map, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor3 {
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub data: Vec<f32>,
}

impl Tensor3 {
    pub fn zeros(c: usize, h: usize, w: usize) -> Self {
        Tensor3 {
            c,
            h,
            w,
            data: vec![0.0; c * h * w],
        }
    }
    /// Spatial positions `H W`.
    pub fn hw(&self) -> usize {
        self.h * self.w
    }
    /// The map as a `[C, H W]` matrix.
    pub fn matrix(&self) -> ArrayView2<'_, f32> {
        ArrayView2::from_shape((self.c, self.hw()), &self.data).expect("shape matches data")
    }
}

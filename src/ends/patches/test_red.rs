//! `test-red`, a part for the tests only: the source views' red channel matched beside
//! the colours, switched on per thread by [`switched_on`]. It is here to show that a new
//! part of the synthesis is one file and one line of [`super::PARTS`].

use super::SynthesisParams;
use super::parts::Channel;
use crate::imageio::Image;
use std::cell::Cell;

thread_local! {
    static ON: Cell<bool> = const { Cell::new(false) };
}

/// Whether the part is on (on this thread).
pub fn on() -> bool {
    ON.with(Cell::get)
}

/// Run `f` with the part on (on this thread).
pub fn switched_on<T>(f: impl FnOnce() -> T) -> T {
    ON.with(|c| c.set(true));
    let out = f();
    ON.with(|c| c.set(false));
    out
}

/// The red channel as a guide.
#[derive(Debug, Clone, Copy)]
pub struct Red;

impl Channel for Red {
    fn source(
        &self,
        rgb: &[Vec<f32>],
        _: &[Vec<f32>],
        _: &[(usize, usize)],
        _: [f32; 3],
        _: &Image,
    ) -> Vec<Vec<f32>> {
        rgb.iter()
            .map(|v| v.iter().step_by(3).copied().collect())
            .collect()
    }

    fn style(&self, sized: &Image, _: &SynthesisParams) -> Vec<f32> {
        sized.data.iter().step_by(3).copied().collect()
    }

    fn weight(&self, _: &SynthesisParams) -> f32 {
        4.0
    }
}

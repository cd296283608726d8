//! The tapped ReLU outputs of VGG16 up to relu4_3, the network's block structure (2, 2,
//! 3 and 3 convolutions, a 2x2 max-pool between blocks) and the receptive field of a
//! layer's unit.

use crate::{Error, Result};

/// Convolutions per block in VGG16 (blocks 1-4; block 5 is not built, see module docs).
const BLOCKS: [usize; 4] = [2, 2, 3, 3];

/// A tapped ReLU output, in network order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Layer {
    Relu1_1,
    Relu1_2,
    Relu2_1,
    Relu2_2,
    Relu3_1,
    Relu3_2,
    Relu3_3,
    Relu4_1,
    Relu4_2,
    Relu4_3,
}

impl Layer {
    pub const ALL: [Layer; 10] = [
        Layer::Relu1_1,
        Layer::Relu1_2,
        Layer::Relu2_1,
        Layer::Relu2_2,
        Layer::Relu3_1,
        Layer::Relu3_2,
        Layer::Relu3_3,
        Layer::Relu4_1,
        Layer::Relu4_2,
        Layer::Relu4_3,
    ];
    /// Index of the convolution this ReLU follows (0..10).
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn name(self) -> &'static str {
        [
            "relu1_1", "relu1_2", "relu2_1", "relu2_2", "relu3_1", "relu3_2", "relu3_3", "relu4_1",
            "relu4_2", "relu4_3",
        ][self.index()]
    }
    /// Number of 2x2 poolings before this layer (its stride is `2^pools`).
    pub fn pools(self) -> usize {
        block_of(self.index())
    }
}

impl std::str::FromStr for Layer {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Layer::ALL
            .iter()
            .copied()
            .find(|l| l.name() == s)
            .ok_or_else(|| Error::param(format!("unknown VGG layer `{s}` (relu1_1 .. relu4_3)")))
    }
}

impl serde::Serialize for Layer {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for Layer {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let s = <String as serde::Deserialize>::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Block (0-based) of convolution `i`.
fn block_of(i: usize) -> usize {
    let mut end = 0;
    for (b, n) in BLOCKS.iter().enumerate() {
        end += n;
        if i < end {
            return b;
        }
    }
    BLOCKS.len() - 1
}

/// Whether convolution `i` starts a block after the first (a max-pool precedes it).
pub(super) fn pooled_before(i: usize) -> bool {
    i > 0 && block_of(i) != block_of(i - 1)
}

/// Receptive field, in input pixels, of one unit of `layer`: each 3x3 convolution adds
/// 2 strides, each 2x2 pool adds 1 stride and doubles the stride. relu4_3: 92.
pub fn receptive_field(layer: Layer) -> usize {
    let (mut rf, mut stride) = (1, 1);
    for i in 0..=layer.index() {
        if pooled_before(i) {
            rf += stride;
            stride *= 2;
        }
        rf += 2 * stride;
    }
    rf
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn receptive_fields() {
        assert_eq!(receptive_field(Layer::Relu1_1), 3);
        assert_eq!(receptive_field(Layer::Relu1_2), 5);
        assert_eq!(receptive_field(Layer::Relu2_2), 14);
        assert_eq!(receptive_field(Layer::Relu3_3), 40);
        assert_eq!(receptive_field(Layer::Relu4_3), 92);
    }
}

//! The strided convolutional encoder shared in shape by the illumination and material modules:
//! k convolutions with stride 2 (the paper: 7, for 256² → 2²), each followed by a ReLU.

use super::{Init, Widths};
use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

/// Strided convolutions from `[B, C, S, S]` to `[B, channels, S/2^k, S/2^k]`.
#[derive(Module, Debug)]
pub struct Encoder {
    convs: Vec<Conv2d>,
}

/// Number of stride-2 layers that bring `size` down to 2×2 (7 for 256).
pub fn levels_for(size: usize) -> usize {
    (size.max(4).ilog2() as usize).saturating_sub(1)
}

/// Output channels of layer `i`.
pub fn channels_at(w: &Widths, i: usize) -> usize {
    (w.base_channels << i.min(20)).min(w.max_channels)
}

/// A 4×4 stride-2 convolution with padding 1 (halves the size exactly).
pub fn down(cin: usize, cout: usize, init: Init, device: &Device) -> Conv2d {
    let mut c = Conv2dConfig::new([cin, cout], [4, 4])
        .with_stride([2, 2])
        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1));
    if let Some(i) = init.initializer() {
        c = c.with_initializer(i);
    }
    c.init(device)
}

/// A 4×4 stride-2 deconvolution with padding 1 (doubles the size exactly).
pub fn up(cin: usize, cout: usize, init: Init, device: &Device) -> ConvTranspose2d {
    let mut c = ConvTranspose2dConfig::new([cin, cout], [4, 4])
        .with_stride([2, 2])
        .with_padding([1, 1]);
    if let Some(x) = init.initializer() {
        c = c.with_initializer(x);
    }
    c.init(device)
}

impl Encoder {
    /// `levels` stride-2 convolutions from `input` channels.
    pub fn new(input: usize, levels: usize, w: &Widths, init: Init, device: &Device) -> Self {
        let convs = (0..levels)
            .map(|i| {
                let cin = if i == 0 { input } else { channels_at(w, i - 1) };
                down(cin, channels_at(w, i), init, device)
            })
            .collect();
        Self { convs }
    }

    /// Output channels.
    pub fn out_channels(&self, w: &Widths) -> usize {
        channels_at(w, self.convs.len().saturating_sub(1))
    }

    /// Runs the encoder.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.convs.iter().fold(x, |x, c| relu(c.forward(x)))
    }
}

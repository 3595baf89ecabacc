//! Normal prediction (Sec. 3.2) after Eigen & Fergus's multi-scale network, with four scales
//! instead of three:
//!
//! 1. a global scale: strided convolutions down to 4×4 and two fully connected layers giving a
//!    coarse map at 1/16 of the input side (at least 2×2), upsampled to 1/4;
//! 2. 1/4 resolution: convolutions on the image, concatenated with scale 1, refined;
//! 3. 1/2 resolution: the same, fed by scale 2;
//! 4. full resolution: two convolutions whose input and output are the size of the image;
//!
//! then a normalisation layer that makes every normal unit length.

use super::encoder::{Encoder, down, levels_for};
use super::material::linear;
use super::{Init, Widths, network_input};
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Dropout, DropoutConfig, Linear, PaddingConfig2d};
use burn::tensor::activation::relu;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor};

fn same(cin: usize, cout: usize, init: Init, device: &Device) -> Conv2d {
    let mut c = Conv2dConfig::new([cin, cout], [3, 3]).with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1));
    if let Some(i) = init.initializer() {
        c = c.with_initializer(i);
    }
    c.init(device)
}

fn upsample(x: Tensor<4>, side: usize) -> Tensor<4> {
    interpolate(
        x,
        InterpolateOptions::new(InterpolateMode::Bilinear).with_output_size([side, side]),
    )
}

/// The normal module.
#[derive(Module, Debug)]
pub struct NormalNet {
    global: Encoder,
    global_fc: Vec<Linear>,
    dropout: Dropout,
    quarter_in: Vec<Conv2d>,
    quarter: Vec<Conv2d>,
    half_in: Conv2d,
    half: Vec<Conv2d>,
    full_in: Conv2d,
    full: Vec<Conv2d>,
    size: usize,
    coarse_side: usize,
    channels: usize,
}

impl NormalNet {
    /// A module for `size`² inputs (`size` a power of two ≥ 16).
    pub fn new(size: usize, w: &Widths, init: Init, device: &Device) -> Self {
        let c = w.normal_channels;
        let levels = levels_for(size).saturating_sub(1).max(1);
        let global = Encoder::new(4, levels, w, init, device);
        let side = size >> levels;
        let coarse_side = (size / 16).max(2);
        let flat = global.out_channels(w) * side * side;
        Self {
            global,
            global_fc: vec![
                linear(flat, w.hidden, init, device),
                linear(w.hidden, c * coarse_side * coarse_side, init, device),
            ],
            dropout: DropoutConfig::new(w.dropout).init(),
            quarter_in: vec![down(4, c, init, device), down(c, c, init, device)],
            quarter: vec![
                same(2 * c, c, init, device),
                same(c, c, init, device),
                same(c, c, init, device),
            ],
            half_in: down(4, c, init, device),
            half: vec![same(2 * c, c, init, device), same(c, c, init, device)],
            full_in: same(4, c, init, device),
            full: vec![same(2 * c, c, init, device), same(c, 3, init, device)],
            size,
            coarse_side,
            channels: c,
        }
    }

    /// Unit normals `[B, 3, H, W]` (camera space) for `image` `[B, 3, H, W]` and `mask`
    /// `[B, 1, H, W]`.
    pub fn forward(&self, image: Tensor<4>, mask: Tensor<4>) -> Tensor<4> {
        let x = network_input(image, mask);
        let b = x.dims()[0];
        let s = self.size;
        // Scale 1: global.
        let g = self.global.forward(x.clone());
        let [_, gc, gh, gw] = g.dims();
        let mut v = g.reshape([b, gc * gh * gw]);
        for (i, fc) in self.global_fc.iter().enumerate() {
            v = fc.forward(v);
            if i == 0 {
                v = self.dropout.forward(relu(v));
            }
        }
        let coarse = v.reshape([b, self.channels, self.coarse_side, self.coarse_side]);
        // Scale 2: quarter resolution.
        let q_in = self.quarter_in.iter().fold(x.clone(), |y, c| relu(c.forward(y)));
        let mut q = Tensor::cat(vec![q_in, upsample(coarse, s / 4)], 1);
        for c in &self.quarter {
            q = relu(c.forward(q));
        }
        // Scale 3: half resolution.
        let mut hf = Tensor::cat(vec![relu(self.half_in.forward(x.clone())), upsample(q, s / 2)], 1);
        for c in &self.half {
            hf = relu(c.forward(hf));
        }
        // Scale 4: full resolution, two convolutions.
        let mut f = Tensor::cat(vec![relu(self.full_in.forward(x)), upsample(hf, s)], 1);
        f = relu(self.full[0].forward(f));
        let n = self.full[1].forward(f);
        normalize(n)
    }
}

/// n / sqrt(|n|² + ε): unit length, and a zero vector stays finite (its gradient too).
pub fn normalize(n: Tensor<4>) -> Tensor<4> {
    let len = n.clone().powi_scalar(2).sum_dim(1).add_scalar(1e-12).sqrt();
    n / len
}

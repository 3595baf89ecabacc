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
use crate::parallel::share::dropout;
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

/// Bilinear resampling of `x` (`[B, C, h, w]`) to `side`², corners aligned (Burn's default).
fn upsample(x: Tensor<4>, side: usize) -> Tensor<4> {
    if crate::device::on_cube(&x.device()) {
        // Burn 0.22.1's CubeCL backend has no backward for its bilinear kernel.
        return upsample_by_products(x, side);
    }
    interpolate(
        x,
        InterpolateOptions::new(InterpolateMode::Bilinear).with_output_size([side, side]),
    )
}

/// [`upsample`] as `R · x · Cᵀ` with the 1-D interpolation matrices: matrix products, whose
/// backward every backend has. Equal to Burn's bilinear kernel up to rounding.
fn upsample_by_products(x: Tensor<4>, side: usize) -> Tensor<4> {
    let [_, _, h, w] = x.dims();
    let device = x.device();
    // `[1, 1, ·, ·]` matrices: matmul broadcasts them over batch and channels.
    let rows = interpolation(h, side, &device).unsqueeze::<4>();
    let cols = interpolation(w, side, &device).transpose().unsqueeze::<4>();
    rows.matmul(x).matmul(cols)
}

/// The `[out, n]` matrix of 1-D linear interpolation from `n` samples to `out`, corners aligned,
/// with Burn's sample positions (`o · (n − 1) / max(out − 1, 1)`).
fn interpolation(n: usize, out: usize, device: &Device) -> Tensor<2> {
    let ratio = (n as f64 - 1.0) / out.saturating_sub(1).max(1) as f64;
    let mut m = vec![0.0f32; out * n];
    for o in 0..out {
        let y = o as f64 * ratio;
        let lo = (y.floor().max(0.0) as usize).min(n - 1);
        let hi = (lo + 1).min(n - 1);
        let t = (y - lo as f64).clamp(0.0, 1.0) as f32;
        m[o * n + lo] += 1.0 - t;
        m[o * n + hi] += t;
    }
    Tensor::from_data(burn::tensor::TensorData::new(m, [out, n]), device)
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
                v = dropout(&self.dropout, relu(v));
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

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    fn noise(n: usize, seed: u32) -> Vec<f32> {
        let mut x = seed.wrapping_mul(2_654_435_761).max(1);
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                (x as f32 / u32::MAX as f32) * 2.0 - 1.0
            })
            .collect()
    }

    /// The product form of the upsampling (what a GPU device runs) agrees with Burn's bilinear
    /// kernel, values and gradients, for every size the network uses and the degenerate ones
    /// (one sample, no change of size, non-square inputs).
    #[test]
    fn upsampling_by_products_equals_burns_bilinear_kernel() {
        let device = Device::flex().autodiff();
        for (i, &(h, w, side)) in [
            (1, 1, 4),
            (1, 2, 3),
            (2, 2, 4),
            (2, 3, 8),
            (4, 4, 8),
            (4, 4, 4),
            (8, 8, 32),
            (16, 16, 64),
            (3, 5, 1),
        ]
        .iter()
        .enumerate()
        {
            let (b, c) = (2, 3);
            let data = noise(b * c * h * w, i as u32 + 1);
            let weights = Tensor::<4>::from_data(
                TensorData::new(noise(b * c * side * side, 99 + i as u32), [b, c, side, side]),
                &device,
            );
            let run = |products: bool| {
                let x = Tensor::<4>::from_data(TensorData::new(data.clone(), [b, c, h, w]), &device).require_grad();
                let y = if products {
                    upsample_by_products(x.clone(), side)
                } else {
                    interpolate(
                        x.clone(),
                        InterpolateOptions::new(InterpolateMode::Bilinear).with_output_size([side, side]),
                    )
                };
                let values: Vec<f32> = y.clone().into_data().try_to_vec::<f32>().expect("f32");
                let grads = (y * weights.clone()).sum().backward();
                let g: Vec<f32> = x
                    .grad(&grads)
                    .expect("x learns")
                    .into_data()
                    .try_to_vec::<f32>()
                    .expect("f32");
                (values, g)
            };
            let ((v0, g0), (v1, g1)) = (run(false), run(true));
            assert_eq!(v0.len(), v1.len());
            for (a, b) in v0.iter().zip(&v1).chain(g0.iter().zip(&g1)) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + a.abs()), "{h}x{w} -> {side}: {a} vs {b}");
            }
        }
    }
}

//! Illumination prediction (Sec. 3.2): strided convolutions, two fully connected layers with
//! dropout, then deconvolutions up to the 64×128 environment map. The output is exp of the last
//! layer (clamped to e^±12), so radiance is positive and spans the orders of magnitude of HDR
//! light probes.

use super::encoder::{Encoder, levels_for, up};
use super::material::linear;
use super::{Init, Widths, network_input};
use crate::parallel::share::dropout;
use burn::module::Module;
use burn::nn::conv::ConvTranspose2d;
use burn::nn::{Dropout, DropoutConfig, Linear};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor};

/// Radiance bound, in natural-log units, of the predicted map.
pub const LOG_RADIANCE_BOUND: f32 = 12.0;

/// The illumination module.
#[derive(Module, Debug)]
pub struct IlluminationNet {
    encoder: Encoder,
    fc: Vec<Linear>,
    dropout: Dropout,
    deconvs: Vec<ConvTranspose2d>,
    seed_channels: usize,
    env_height: usize,
}

impl IlluminationNet {
    /// A module for `size`² inputs and `2·env_height × env_height` maps (`env_height` a power
    /// of two ≥ 4).
    pub fn new(size: usize, env_height: usize, w: &Widths, init: Init, device: &Device) -> Self {
        let levels = levels_for(size);
        let encoder = Encoder::new(4, levels, w, init, device);
        let side = size >> levels;
        let flat = encoder.out_channels(w) * side * side;
        // The deconvolutions start from a 2×4 map and double it up to He × 2He.
        let ups = (env_height / 2).max(1).ilog2() as usize;
        let seed_channels = w.max_channels.min(w.base_channels << ups.min(20));
        let deconvs = (0..ups)
            .map(|i| {
                let cin = (seed_channels >> i).max(8);
                let cout = if i + 1 == ups {
                    3
                } else {
                    (seed_channels >> (i + 1)).max(8)
                };
                up(cin, cout, init, device)
            })
            .collect();
        Self {
            encoder,
            fc: vec![
                linear(flat, w.hidden, init, device),
                linear(w.hidden, seed_channels * 8, init, device),
            ],
            dropout: DropoutConfig::new(w.dropout).init(),
            deconvs,
            seed_channels,
            env_height,
        }
    }

    /// The environment `[B, 3, He, 2He]` seen in `image` `[B, 3, H, W]` with object `mask`
    /// `[B, 1, H, W]`.
    pub fn forward(&self, image: Tensor<4>, mask: Tensor<4>) -> Tensor<4> {
        let x = self.encoder.forward(network_input(image, mask));
        let [n, c, sh, sw] = x.dims();
        let mut x = x.reshape([n, c * sh * sw]);
        for fc in &self.fc {
            x = dropout(&self.dropout, relu(fc.forward(x)));
        }
        let mut y = x.reshape([n, self.seed_channels, 2, 4]);
        let last = self.deconvs.len().saturating_sub(1);
        for (i, d) in self.deconvs.iter().enumerate() {
            y = d.forward(y);
            if i < last {
                y = relu(y);
            }
        }
        debug_assert_eq!(y.dims()[2], self.env_height);
        y.clamp(-LOG_RADIANCE_BOUND, LOG_RADIANCE_BOUND).exp()
    }
}

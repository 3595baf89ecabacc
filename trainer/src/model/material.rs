//! Material prediction (Sec. 3.2): strided convolutions, three fully connected layers with
//! dropout, tanh to the 108 normalised DSBRDF parameters. For multi-material objects the module
//! runs once per region, on the image masked to that region (Sec. 3.4).

use super::encoder::{Encoder, levels_for};
use super::{Init, Widths, network_input};
use crate::parallel::share::dropout;
use burn::module::Module;
use burn::nn::{Dropout, DropoutConfig, Linear, LinearConfig};
use burn::tensor::activation::{relu, tanh};
use burn::tensor::{Device, Tensor};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// The material module.
#[derive(Module, Debug)]
pub struct MaterialNet {
    encoder: Encoder,
    fc: Vec<Linear>,
    dropout: Dropout,
}

pub(crate) fn linear(i: usize, o: usize, init: Init, device: &Device) -> Linear {
    let mut c = LinearConfig::new(i, o);
    if let Some(x) = init.initializer() {
        c = c.with_initializer(x);
    }
    c.init(device)
}

impl MaterialNet {
    /// A module for `size`² inputs.
    pub fn new(size: usize, w: &Widths, init: Init, device: &Device) -> Self {
        let levels = levels_for(size);
        let encoder = Encoder::new(4, levels, w, init, device);
        let side = size >> levels;
        let flat = encoder.out_channels(w) * side * side;
        Self {
            encoder,
            fc: vec![
                linear(flat, w.hidden, init, device),
                linear(w.hidden, w.hidden, init, device),
                linear(w.hidden, PARAMS, init, device),
            ],
            dropout: DropoutConfig::new(w.dropout).init(),
        }
    }

    /// Normalised materials `[B, R, 108]` of the `regions` regions of `image` `[B, 3, H, W]`;
    /// `region_masks` is `[B, R, H, W]` (1 inside region r).
    pub fn forward(&self, image: Tensor<4>, region_masks: Tensor<4>) -> Tensor<3> {
        let [b, r, h, w] = region_masks.dims();
        // Each region becomes its own batch item: image masked to the region, plus the mask.
        let img = image
            .unsqueeze_dim::<5>(1)
            .expand([b, r, 3, h, w])
            .reshape([b * r, 3, h, w]);
        let masks = region_masks.reshape([b * r, 1, h, w]);
        let x = self.encoder.forward(network_input(img, masks));
        let [n, c, sh, sw] = x.dims();
        let mut x = x.reshape([n, c * sh * sw]);
        let last = self.fc.len() - 1;
        for (i, fc) in self.fc.iter().enumerate() {
            x = fc.forward(x);
            if i < last {
                x = dropout(&self.dropout, relu(x));
            }
        }
        tanh(x).reshape([b, r, PARAMS])
    }
}

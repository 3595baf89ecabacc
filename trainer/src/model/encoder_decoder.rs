//! Baseline 1 of Sec. 4.5, after Kulkarni et al. (2015, "Deep convolutional inverse graphics
//! network"): an encoder–decoder that edits without rendering.
//!
//! The encoder's code splits into f_m, which regresses the input's 108 normalised material
//! parameters (tanh, like the material module), and f_o, everything else. To edit, f_m is
//! replaced by the target material's code E(m_t) (a small network embeds m_t into f_m's space),
//! and the decoder, with skip connections from every encoder level and from the input itself,
//! synthesises O'. Trained with the perceptual loss on O' and the L2 loss on f_m (Sec. 4.5).
//!
//! What the paper leaves open, chosen here: f_m is the 108-vector itself (its L2 loss is then
//! the material module's Eq. 4); f_o has `hidden` values; E is two fully connected layers with
//! a tanh; the decoder mirrors the encoder (4×4 stride-2 deconvolutions, U-Net skips); O' is
//! exp of the last layer, clamped like the illumination module's radiance. One material per
//! object, as in the paper's Table 3.

use super::encoder::{channels_at, down, levels_for, up};
use super::illumination::LOG_RADIANCE_BOUND;
use super::material::linear;
use super::{Init, Widths, network_input};
use crate::parallel::share::dropout;
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d};
use burn::nn::{Dropout, DropoutConfig, Linear, PaddingConfig2d};
use burn::tensor::activation::{relu, tanh};
use burn::tensor::{Device, Tensor};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// Baseline 1's network.
#[derive(Module, Debug)]
pub struct EncoderDecoder {
    downs: Vec<Conv2d>,
    /// Flattened code → f_o.
    to_other: Linear,
    /// Flattened code → hidden → f_m (108, tanh).
    to_material: Vec<Linear>,
    /// m_t → hidden → E(m_t) (108, tanh).
    embed: Vec<Linear>,
    /// (f_o, f_m or E(m_t)) → the decoder's seed.
    from_code: Linear,
    ups: Vec<ConvTranspose2d>,
    out: Conv2d,
    dropout: Dropout,
    seed_channels: usize,
}

/// What the encoder makes of an image: its skip features (finest first), f_o and f_m.
pub struct Encoded {
    skips: Vec<Tensor<4>>,
    input: Tensor<4>,
    other: Tensor<2>,
    /// f_m: the predicted material `[B, 108]`.
    pub material: Tensor<2>,
}

impl EncoderDecoder {
    /// A network for `size`² inputs.
    pub fn new(size: usize, w: &Widths, init: Init, device: &Device) -> Self {
        let levels = levels_for(size);
        let downs: Vec<Conv2d> = (0..levels)
            .map(|i| {
                let cin = if i == 0 { 4 } else { channels_at(w, i - 1) };
                down(cin, channels_at(w, i), init, device)
            })
            .collect();
        let seed_channels = channels_at(w, levels.saturating_sub(1));
        let side = size >> levels;
        let flat = seed_channels * side * side;
        let ups = (0..levels)
            .map(|i| {
                let cin = 2 * channels_at(w, i);
                let cout = if i == 0 { w.base_channels } else { channels_at(w, i - 1) };
                up(cin, cout, init, device)
            })
            .collect();
        let mut out = Conv2dConfig::new([w.base_channels + 4, 3], [3, 3]).with_padding(PaddingConfig2d::Same);
        if let Some(x) = init.initializer() {
            out = out.with_initializer(x);
        }
        Self {
            downs,
            to_other: linear(flat, w.hidden, init, device),
            to_material: vec![
                linear(flat, w.hidden, init, device),
                linear(w.hidden, PARAMS, init, device),
            ],
            embed: vec![
                linear(PARAMS, w.hidden, init, device),
                linear(w.hidden, PARAMS, init, device),
            ],
            from_code: linear(w.hidden + PARAMS, flat, init, device),
            ups,
            out: out.init(device),
            dropout: DropoutConfig::new(w.dropout).init(),
            seed_channels,
        }
    }

    /// Encodes `image` `[B, 3, S, S]` with object `mask` `[B, 1, S, S]`.
    pub fn encode(&self, image: Tensor<4>, mask: Tensor<4>) -> Encoded {
        let input = network_input(image, mask);
        let mut skips = Vec::with_capacity(self.downs.len());
        let mut x = input.clone();
        for d in &self.downs {
            x = relu(d.forward(x));
            skips.push(x.clone());
        }
        let [n, c, sh, sw] = x.dims();
        let flat = x.reshape([n, c * sh * sw]);
        let other = dropout(&self.dropout, relu(self.to_other.forward(flat.clone())));
        let hidden = dropout(&self.dropout, relu(self.to_material[0].forward(flat)));
        let material = tanh(self.to_material[1].forward(hidden));
        Encoded {
            skips,
            input,
            other,
            material,
        }
    }

    /// E(m_t): the code of normalised materials `[B, 108]` in f_m's place.
    pub fn embed(&self, materials: Tensor<2>) -> Tensor<2> {
        tanh(self.embed[1].forward(relu(self.embed[0].forward(materials))))
    }

    /// The decoder: the image of `code` (f_m or E(m_t)) with the rest of `e`, `[B, 3, S, S]`,
    /// positive, zero off the object `mask` `[B, 1, S, S]`.
    pub fn decode(&self, e: &Encoded, code: Tensor<2>, mask: Tensor<4>) -> Tensor<4> {
        let z = Tensor::cat(vec![e.other.clone(), code], 1);
        let [n, _] = z.dims();
        let seed = e.skips.last().map_or(2, |s| s.dims()[2]);
        let mut x = relu(self.from_code.forward(z)).reshape([n, self.seed_channels, seed, seed]);
        for (up, skip) in self.ups.iter().zip(&e.skips).rev() {
            x = relu(up.forward(Tensor::cat(vec![x, skip.clone()], 1)));
        }
        let y = self.out.forward(Tensor::cat(vec![x, e.input.clone()], 1));
        y.clamp(-LOG_RADIANCE_BOUND, LOG_RADIANCE_BOUND).exp() * mask
    }

    /// f_m of the input and O' for target materials `m_t` `[B, 108]`.
    pub fn edit(&self, image: Tensor<4>, mask: Tensor<4>, target: Tensor<2>) -> (Tensor<2>, Tensor<4>) {
        let e = self.encode(image, mask.clone());
        let code = self.embed(target);
        let o = self.decode(&e, code, mask);
        (e.material.clone(), o)
    }
}

//! The three prediction modules of Fig. 2 (Sec. 3.2), each configurable in width and input
//! resolution: the paper's configuration is 256² input with the widths of [`Widths::paper`];
//! CPU configurations shrink both.
//!
//! * [`normal::NormalNet`]: multi-scale normal prediction after Eigen & Fergus, four scales, the
//!   last two convolutions at full resolution, unit-length output;
//! * [`illumination::IlluminationNet`]: strided convolutions, two fully connected layers with
//!   dropout, deconvolutions to a positive 64×128 HDR map;
//! * [`material::MaterialNet`]: strided convolutions, three fully connected layers with dropout,
//!   tanh to the 108 normalised DSBRDF parameters; one prediction per region.
//!
//! [`encoder_decoder::EncoderDecoder`] is Baseline 1 of Sec. 4.5 (after Kulkarni et al.), which
//! edits without rendering.
//!
//! Every module sees the same input: ln(1 + I) (3 channels, which keeps the HDR scale the
//! illumination module needs while compressing highlights) and the object or region mask.

pub mod encoder;
pub mod encoder_decoder;
pub mod export;
pub mod illumination;
pub mod material;
pub mod network;
pub mod normal;
pub mod prediction;
pub mod vgg16;

use burn::config::Config;
use burn::nn::Initializer;
use burn::tensor::Tensor;

/// Widths of the modules.
#[derive(Config, Debug, PartialEq)]
pub struct Widths {
    /// Channels of the first strided convolution; later ones double up to `max_channels`.
    pub base_channels: usize,
    /// Channel cap of the strided encoders.
    pub max_channels: usize,
    /// Width of the fully connected layers.
    pub hidden: usize,
    /// Channels of the normal module's fine scales.
    pub normal_channels: usize,
    /// Dropout probability after each fully connected layer.
    #[config(default = 0.5)]
    pub dropout: f64,
}

/// A named width configuration and its constructor.
pub type Preset = (&'static str, fn() -> Widths);

impl Widths {
    /// The paper's widths (Sec. 3.2 gives layer counts, not widths: these follow Eigen & Fergus
    /// and common encoder practice).
    pub fn paper() -> Self {
        Self::new(32, 512, 1024, 64)
    }

    /// A configuration small enough to train on two CPU cores.
    pub fn cpu_small() -> Self {
        Self::new(8, 64, 128, 16)
    }

    /// The named configurations (training manifests' `widths`, `trainer bench --train`).
    pub const PRESETS: [Preset; 2] = [("cpu-small", Widths::cpu_small), ("paper", Widths::paper)];

    /// A named configuration; `None` for a name not in [`Widths::PRESETS`].
    pub fn preset(name: &str) -> Option<Self> {
        Self::PRESETS.iter().find(|(n, _)| *n == name).map(|(_, make)| make())
    }

    /// The names of [`Widths::PRESETS`], for messages.
    pub fn preset_names() -> String {
        Self::PRESETS.map(|(n, _)| n).join(", ")
    }
}

/// Weight initialisation of every convolution and linear layer.
#[derive(Config, Debug, Copy, PartialEq, Eq)]
pub enum Init {
    /// Burn's default (Kaiming uniform).
    Default,
    /// The paper's uniform [−0.08, 0.08] (Sec. 4, training procedure).
    Uniform008,
}

impl matedit_contract::manifest::Named for Init {
    const NAMES: &'static [(&'static str, Self)] = &[("uniform-0.08", Init::Uniform008), ("default", Init::Default)];
}

impl Init {
    /// The Burn initializer, or `None` for the layer default.
    pub fn initializer(self) -> Option<Initializer> {
        match self {
            Init::Default => None,
            Init::Uniform008 => Some(Initializer::Uniform { min: -0.08, max: 0.08 }),
        }
    }
}

/// What the network's exposure and `matedit edit`'s exposure measure an object's brightness with.
pub use matedit_physics::LUMINANCE_WEIGHTS;

/// An image as the modules read it: NaN as 0, negative values as 0, values capped at 10³⁰.
pub fn finite_image(image: Tensor<4>) -> Tensor<4> {
    image.clone().mask_fill(image.is_nan(), 0.0).clamp(0.0, 1e30)
}

/// The network input: ln(1 + max(I, 0)) with non-finite values as 0, and the mask, `[B, 4, H, W]`.
pub fn network_input(image: Tensor<4>, mask: Tensor<4>) -> Tensor<4> {
    let x = finite_image(image).log1p() * mask.clone();
    Tensor::cat(vec![x, mask], 1)
}

//! The whole network of Fig. 2: the three prediction modules (the rendering layer has no
//! parameters and lives in [`crate::render`]); and, in a Baseline 1 run, its encoder–decoder.

use crate::model::encoder_decoder::EncoderDecoder;
use crate::model::illumination::IlluminationNet;
use crate::model::material::MaterialNet;
use crate::model::normal::NormalNet;
use crate::model::{Init, Widths};
use burn::config::Config;
use burn::module::Module;
use burn::tensor::{Device, Tensor};

/// Shape of the network: input resolution, environment resolution, widths, initialisation.
#[derive(Config, Debug, PartialEq)]
pub struct NetConfig {
    /// Input image side (a power of two ≥ 16; the paper: 256).
    pub input_size: usize,
    /// Environment map height (width is twice; the paper: 64).
    #[config(default = 64)]
    pub env_height: usize,
    /// Layer widths.
    pub widths: Widths,
    /// Weight initialisation.
    #[config(default = "Init::Uniform008")]
    pub init: Init,
    /// Whether the network also holds Baseline 1's encoder–decoder (a run with an
    /// `encoder-decoder` stage).
    #[config(default = false)]
    pub encoder_decoder: bool,
}

/// The three prediction modules.
#[derive(Module, Debug)]
pub struct Net {
    /// Normal prediction.
    pub normal: NormalNet,
    /// Material prediction.
    pub material: MaterialNet,
    /// Illumination prediction.
    pub illumination: IlluminationNet,
    /// Baseline 1 (Sec. 4.5), in a run that trains it.
    pub encoder_decoder: Option<EncoderDecoder>,
}

impl NetConfig {
    /// The largest input side accepted (the paper: 256).
    pub const MAX_INPUT_SIZE: usize = 1024;
    /// The largest environment height accepted (the paper: 64).
    pub const MAX_ENV_HEIGHT: usize = 256;
    /// The largest layer width accepted (the paper's widths: at most 1024).
    pub const MAX_WIDTH: usize = 4096;

    /// Checks what the modules need of the sizes, and bounds them: a configuration read from a
    /// file (a manifest, a checkpoint's state) must not make `init` ask for unbounded memory or
    /// Burn panic.
    pub fn validate(&self) -> Result<(), String> {
        let s = self.input_size;
        if !(s.is_power_of_two() && (16..=Self::MAX_INPUT_SIZE).contains(&s)) {
            return Err(format!(
                "input_size must be a power of two from 16 to {}, got {s}",
                Self::MAX_INPUT_SIZE
            ));
        }
        let h = self.env_height;
        if !(h.is_power_of_two() && (4..=Self::MAX_ENV_HEIGHT).contains(&h)) {
            return Err(format!(
                "env_height must be a power of two from 4 to {}, got {h}",
                Self::MAX_ENV_HEIGHT
            ));
        }
        let w = &self.widths;
        for (name, v) in [
            ("base_channels", w.base_channels),
            ("max_channels", w.max_channels),
            ("hidden", w.hidden),
            ("normal_channels", w.normal_channels),
        ] {
            if !(1..=Self::MAX_WIDTH).contains(&v) {
                return Err(format!("widths.{name} must be 1 to {}, got {v}", Self::MAX_WIDTH));
            }
        }
        if !(0.0..1.0).contains(&w.dropout) {
            return Err(format!("widths.dropout must be in [0, 1), got {}", w.dropout));
        }
        Ok(())
    }

    /// Initialises the network on `device` (seed the device first for reproducible weights).
    pub fn init(&self, device: &Device) -> Net {
        Net {
            normal: NormalNet::new(self.input_size, &self.widths, self.init, device),
            material: MaterialNet::new(self.input_size, &self.widths, self.init, device),
            illumination: IlluminationNet::new(self.input_size, self.env_height, &self.widths, self.init, device),
            encoder_decoder: self
                .encoder_decoder
                .then(|| EncoderDecoder::new(self.input_size, &self.widths, self.init, device)),
        }
    }
}

/// What the network predicts for a batch.
pub struct Predictions {
    /// n'.
    pub normals: Tensor<4>,
    /// m'.
    pub materials: Tensor<3>,
    /// L' (`None` when the illumination module was not run).
    pub env: Option<Tensor<4>>,
}

impl Net {
    /// Predicts n', m' and, with `with_light`, L' from input images `[B, 3, H, W]` (linear),
    /// their object masks `[B, 1, H, W]` and region masks `[B, R, H, W]`.
    pub fn predict(
        &self,
        input: &Tensor<4>,
        mask: &Tensor<4>,
        region_masks: &Tensor<4>,
        with_light: bool,
    ) -> Predictions {
        Predictions {
            normals: self.normal.forward(input.clone(), mask.clone()),
            materials: self.material.forward(input.clone(), region_masks.clone()),
            env: with_light.then(|| self.illumination.forward(input.clone(), mask.clone())),
        }
    }
}

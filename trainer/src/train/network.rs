//! The whole network of Fig. 2: the three prediction modules (the rendering layer has no
//! parameters and lives in [`crate::render`]).

use crate::model::illumination::IlluminationNet;
use crate::model::material::MaterialNet;
use crate::model::normal::NormalNet;
use crate::model::{Init, Widths};
use burn::config::Config;
use burn::module::Module;
use burn::tensor::Device;

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
}

impl NetConfig {
    /// Checks what the modules need of the sizes.
    pub fn validate(&self) -> Result<(), String> {
        let s = self.input_size;
        if !(s.is_power_of_two() && s >= 16) {
            return Err(format!("input_size must be a power of two ≥ 16, got {s}"));
        }
        let h = self.env_height;
        if !(h.is_power_of_two() && h >= 4) {
            return Err(format!("env_height must be a power of two ≥ 4, got {h}"));
        }
        Ok(())
    }

    /// Initialises the network on `device` (seed the device first for reproducible weights).
    pub fn init(&self, device: &Device) -> Net {
        Net {
            normal: NormalNet::new(self.input_size, &self.widths, self.init, device),
            material: MaterialNet::new(self.input_size, &self.widths, self.init, device),
            illumination: IlluminationNet::new(self.input_size, self.env_height, &self.widths, self.init, device),
        }
    }
}

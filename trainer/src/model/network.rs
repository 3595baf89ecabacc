//! The whole network of Fig. 2: the three prediction modules (the rendering layer has no
//! parameters and lives in [`crate::rendering_layer`]); and, in a Baseline 1 run, its encoder–decoder.

use crate::model::encoder_decoder::EncoderDecoder;
use crate::model::illumination::IlluminationNet;
use crate::model::material::MaterialNet;
use crate::model::normal::NormalNet;
use crate::model::{Init, LUMINANCE_WEIGHTS, Widths, finite_image};
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
    /// The exposure the modules see the object at; `None` (what a checkpoint from before this
    /// choice reads as) is [`Exposure::Absolute`].
    pub exposure: Option<Exposure>,
}

/// The exposure the prediction modules see an object at.
///
/// A photo's exposure is arbitrary, so `matedit edit` scales every photo to one mean object
/// luminance before the network sees it. A network trained on images at their rendered exposure
/// learns the albedo from the object's absolute brightness (the training lights have a few fixed
/// levels), a cue that edit-time scaling removes: it then answers one albedo for every photo.
/// `Normalised` shows the modules every image, in training as in editing, at
/// [`NORMALISED_MEAN_LUMINANCE`] and scales L' back, so the network is exactly equivariant to
/// exposure (kI gives n', m', kL') and must find the albedo in what an exposure does not change:
/// highlights against the diffuse body, saturation, shading contrast.
#[derive(Config, Debug, Copy, PartialEq, Eq)]
pub enum Exposure {
    /// The image as rendered (the paper; checkpoints from before this choice).
    Absolute,
    /// Each image scaled so that its object's mean luminance is [`NORMALISED_MEAN_LUMINANCE`].
    Normalised,
}

impl matedit_contract::manifest::Named for Exposure {
    const NAMES: &'static [(&'static str, Self)] =
        &[("absolute", Exposure::Absolute), ("normalised", Exposure::Normalised)];
}

/// The object's mean luminance (Rec. 709) an [`Exposure::Normalised`] network sees: the median
/// over the quickstart training split, the level `matedit edit` scales photos to.
pub const NORMALISED_MEAN_LUMINANCE: f64 = 0.48;

/// The range of the gain [`exposure_gain`] applies: an object 10⁶ times darker or brighter than
/// the normalised level (or black) is seen at the bound's exposure instead of overflowing.
pub const MAX_EXPOSURE_GAIN: f64 = 1e6;

/// Per image, the gain `[B, 1, 1, 1]` that brings the mean luminance of `image` `[B, 3, H, W]`
/// over `mask` `[B, 1, H, W]` to [`NORMALISED_MEAN_LUMINANCE`], within 1/[`MAX_EXPOSURE_GAIN`] to
/// [`MAX_EXPOSURE_GAIN`]. Non-finite and negative pixels count as 0, as in the network's input.
/// It is a constant of the image: no gradient flows through it.
pub fn exposure_gain(image: &Tensor<4>, mask: &Tensor<4>) -> Tensor<4> {
    let clean = finite_image(image.clone());
    let [b, _, h, w] = clean.dims();
    let device = clean.device();
    let weights = Tensor::<1>::from_floats(LUMINANCE_WEIGHTS.map(|w| w as f32), &device).reshape([1, 3, 1, 1]);
    let luminance = (clean * weights).sum_dim(1) * mask.clone();
    let total = luminance.reshape([b, h * w]).sum_dim(1);
    let area = mask.clone().reshape([b, h * w]).sum_dim(1).clamp_min(1.0);
    let mean = (total / area).reshape([b, 1, 1, 1]);
    let (lo, hi) = (1.0 / MAX_EXPOSURE_GAIN, MAX_EXPOSURE_GAIN);
    (mean.clamp_min(NORMALISED_MEAN_LUMINANCE / hi).recip() * NORMALISED_MEAN_LUMINANCE)
        .clamp(lo, hi)
        .detach()
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
    /// Whether the modules see each image at [`NORMALISED_MEAN_LUMINANCE`] ([`Exposure`]).
    pub normalised_exposure: bool,
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
            normalised_exposure: self.exposure == Some(Exposure::Normalised),
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
    /// their object masks `[B, 1, H, W]` and region masks `[B, R, H, W]`. L' is in the input's
    /// units whatever the [`Exposure`].
    pub fn predict(
        &self,
        input: &Tensor<4>,
        mask: &Tensor<4>,
        region_masks: &Tensor<4>,
        with_light: bool,
    ) -> Predictions {
        let gain = self.normalised_exposure.then(|| exposure_gain(input, mask));
        let seen = match &gain {
            Some(g) => input.clone() * g.clone(),
            None => input.clone(),
        };
        Predictions {
            normals: self.normal.forward(seen.clone(), mask.clone()),
            materials: self.material.forward(seen.clone(), region_masks.clone()),
            env: with_light.then(|| {
                let env = self.illumination.forward(seen, mask.clone());
                match gain {
                    Some(g) => env / g,
                    None => env,
                }
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Widths;
    use crate::rendering_layer::op::host;

    fn net(exposure: Exposure) -> Net {
        let device = Device::flex();
        NetConfig::new(16, Widths::new(4, 16, 32, 8))
            .with_env_height(8)
            .with_exposure(Some(exposure))
            .init(&device)
    }

    /// A 16² object on the lower right, shaded and coloured so every module has something to see.
    fn photo() -> (Vec<f32>, Vec<f32>, Vec<u8>) {
        let (s, p) = (16, 256);
        let mask: Vec<f32> = (0..p).map(|k| f32::from(k % s >= 3 && k / s >= 2)).collect();
        let regions: Vec<u8> = mask.iter().map(|&m| m as u8).collect();
        let input = (0..3 * p)
            .map(|k| 0.05 + ((k * 37) % 11) as f32 * 0.08 + (k / p) as f32 * 0.1)
            .collect();
        (input, mask, regions)
    }

    fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
        a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= tol * (1.0 + x.abs().max(y.abs())))
    }

    #[test]
    fn a_normalised_network_is_equivariant_to_exposure_over_the_gain_range() {
        let device = Device::flex();
        let n = net(Exposure::Normalised);
        let (input, mask, regions) = photo();
        let at = |k: f32| {
            let scaled: Vec<f32> = input.iter().map(|v| v * k).collect();
            n.predict_photo(&scaled, &mask, &regions, 1, &device).unwrap()
        };
        let one = at(1.0);
        for k in [1e-5_f32, 1e-3, 0.37, 3.0, 250.0, 1e5] {
            let x = at(k);
            assert!(close(&x.normals, &one.normals, 1e-3), "n' at exposure ×{k}");
            assert!(close(&x.materials, &one.materials, 1e-3), "m' at exposure ×{k}");
            let scaled: Vec<f32> = one.env.iter().map(|v| v * k).collect();
            assert!(close(&x.env, &scaled, 1e-3), "L' at exposure ×{k} is not k L'");
        }
        // The absolute network (the paper's) sees the exposure: the same test fails for it.
        let a = net(Exposure::Absolute);
        let p = |k: f32| {
            let scaled: Vec<f32> = input.iter().map(|v| v * k).collect();
            a.predict_photo(&scaled, &mask, &regions, 1, &device).unwrap()
        };
        let (x, y) = (p(1.0), p(250.0));
        let scaled: Vec<f32> = x.env.iter().map(|v| v * 250.0).collect();
        assert!(!close(&y.env, &scaled, 1e-3));
    }

    #[test]
    fn the_exposure_gain_brings_the_object_to_the_normalised_level_and_stays_finite() {
        let device = Device::flex();
        let mask = Tensor::<4>::from_floats([[[[1.0_f32, 1.0], [0.0, 0.0]]]], &device);
        let gain = |rgb: [[f32; 4]; 3]| {
            let image = Tensor::<1>::from_floats(rgb.concat().as_slice(), &device).reshape([1, 3, 2, 2]);
            host(&exposure_gain(&image, &mask))[0] as f64
        };
        // Grey 0.12 and 0.36 on the object (mean 0.24), anything off it: gain 2.
        let g = gain([[0.12, 0.36, 99.0, 5.0]; 3]);
        assert!((g - NORMALISED_MEAN_LUMINANCE / 0.24).abs() < 1e-5, "{g}");
        // Rec. 709 weights: pure green 1.0 has luminance 0.7152.
        let g = gain([[0.0; 4], [1.0, 1.0, 0.0, 0.0], [0.0; 4]]);
        assert!((g - NORMALISED_MEAN_LUMINANCE / 0.7152).abs() < 1e-5, "{g}");
        // Black, NaN, negative and infinite objects get a bounded, finite gain.
        for (v, want) in [
            (0.0_f32, MAX_EXPOSURE_GAIN),
            (f32::NAN, MAX_EXPOSURE_GAIN),
            (-3.0, MAX_EXPOSURE_GAIN),
            (1e-30, MAX_EXPOSURE_GAIN),
            (f32::INFINITY, 1.0 / MAX_EXPOSURE_GAIN),
            (1e30, 1.0 / MAX_EXPOSURE_GAIN),
        ] {
            let g = gain([[v; 4]; 3]);
            assert!(g.is_finite() && (g / want - 1.0).abs() < 1e-4, "pixels {v}: gain {g}");
        }
        // An empty mask (no object) too.
        let image = Tensor::<4>::ones([1, 3, 2, 2], &device);
        let g = host(&exposure_gain(&image, &Tensor::<4>::zeros([1, 1, 2, 2], &device)))[0];
        assert!(g.is_finite() && g > 0.0);
    }
}

//! VGG16's convolutional features up to `relu4_3`, for the perceptual loss of Sec. 3.3 (Johnson
//! et al.: squared differences of pretrained VGG16 activations).
//!
//! The layout is torchvision's `vgg16().features`: 3×3 convolutions with padding 1 and ReLU, 2×2
//! max pooling between blocks of 2, 2, 3 and 3 convolutions (64, 128, 256, 512 channels). In a
//! torchvision state dict the convolutions are `features.{0,2,5,7,10,12,14,17,19,21,…}`; the stores
//! renumber those indices contiguously (`features.0` … `features.9` here), so a torchvision
//! checkpoint (`.pth`/`.pt`) or its safetensors export loads as it is. Tensors this module does
//! not have (block 5, the classifier) are ignored; a missing one is an error naming the file.
//!
//! Two input conventions exist, and a safetensors file says which it was trained with in its
//! metadata (`preprocessing`): `torchvision` (the default, and every `.pth`): RGB in [0, 1], minus
//! the ImageNet mean, over its standard deviation; `caffe` (Keras' VGG16, which
//! `scripts/fetch_vgg16.sh` converts from a pinned ONNX export): 0–255, minus the ImageNet mean in
//! 0–255 units, no division. The original Caffe/Keras graph takes BGR; the converter reverses
//! conv1_1's input channels, so both files take RGB here.

use anyhow::{Result, bail};
use burn::module::Module;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::store::{ModuleSnapshot, PyTorchToBurnAdapter, PytorchStore, SafetensorsStore};
use burn::tensor::activation::relu;
use burn::tensor::module::max_pool2d;
use burn::tensor::ops::MaxPoolOptions;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Channels of the four blocks and their convolution counts.
const BLOCKS: [(usize, usize); 4] = [(64, 2), (128, 2), (256, 3), (512, 3)];

/// A feature layer the perceptual loss can compare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Layer {
    /// After the second convolution of block 1 (64 channels, full resolution).
    Relu1_2,
    /// After block 2 (128 channels, 1/2).
    Relu2_2,
    /// After block 3 (256 channels, 1/4).
    Relu3_3,
    /// After block 4 (512 channels, 1/8).
    Relu4_3,
}

impl Layer {
    fn block(self) -> usize {
        self as usize
    }
}

#[cfg(test)]
mod tests;

/// Indices of the convolutions in torchvision's `vgg16().features`, `conv1_1` … `conv4_3`.
pub const TORCHVISION_INDICES: [usize; 10] = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21];

/// ImageNet statistics the torchvision weights were trained with.
const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// The ImageNet mean Caffe's VGG16 subtracts, in 0–255 units, RGB order.
const CAFFE_MEAN: [f32; 3] = [123.68, 116.779, 103.939];

/// How an image in [0, 1] is turned into what the weights were trained on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Preprocessing {
    /// `(x − mean) / std` with ImageNet's statistics (torchvision).
    #[default]
    Torchvision,
    /// `255 x − mean₂₅₅` (Caffe's and Keras' VGG16).
    Caffe,
}

impl Preprocessing {
    /// The convention a safetensors file's metadata names; `torchvision` when it names none.
    fn of_safetensors(path: &Path) -> Result<Self> {
        use std::io::Read;
        let mut f = std::fs::File::open(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let mut len = [0u8; 8];
        f.read_exact(&mut len)
            .map_err(|e| anyhow::anyhow!("{}: not a safetensors file: {e}", path.display()))?;
        let len = u64::from_le_bytes(len);
        if len > 100 << 20 {
            bail!("{}: not a safetensors file: a header of {len} bytes", path.display());
        }
        let mut header = vec![0u8; len as usize];
        f.read_exact(&mut header)
            .map_err(|e| anyhow::anyhow!("{}: truncated safetensors header: {e}", path.display()))?;
        let header: serde_json::Value = serde_json::from_slice(&header)
            .map_err(|e| anyhow::anyhow!("{}: not a safetensors header: {e}", path.display()))?;
        match header.get("__metadata__").and_then(|m| m.get("preprocessing")) {
            None => Ok(Self::Torchvision),
            Some(v) => match v.as_str() {
                Some("torchvision") => Ok(Self::Torchvision),
                Some("caffe") => Ok(Self::Caffe),
                _ => bail!(
                    "{}: unknown preprocessing {v} in its metadata (expected \"torchvision\" or \"caffe\")",
                    path.display()
                ),
            },
        }
    }
}

/// VGG16 convolutions `conv1_1` … `conv4_3`.
#[derive(Module, Debug)]
pub struct Vgg16 {
    features: Vec<Conv2d>,
    /// The input convention of the weights.
    #[module(skip)]
    preprocessing: Preprocessing,
}

impl Vgg16 {
    /// Randomly initialised weights (tests; real use loads a file with [`Vgg16::load`]).
    pub fn new(device: &Device) -> Self {
        let mut features = Vec::new();
        let mut cin = 3;
        for (c, n) in BLOCKS {
            for _ in 0..n {
                features.push(
                    Conv2dConfig::new([cin, c], [3, 3])
                        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                        .init(device),
                );
                cin = c;
            }
        }
        Self {
            features,
            preprocessing: Preprocessing::Torchvision,
        }
    }

    /// The input convention of the loaded weights.
    pub fn preprocessing(&self) -> Preprocessing {
        self.preprocessing
    }

    /// Loads torchvision VGG16 weights from a PyTorch checkpoint (`.pth`, `.pt`) or a
    /// safetensors file (torchvision's keys, the input convention in its metadata), frozen (no
    /// parameter takes a gradient).
    pub fn load(path: &Path, device: &Device) -> Result<Self> {
        if !path.is_file() {
            bail!("{}: no such VGG16 weights file", path.display());
        }
        let mut net = Self::new(device);
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or_default();
        let result = match ext {
            "safetensors" => {
                net.preprocessing = Preprocessing::of_safetensors(path)?;
                let mut store = SafetensorsStore::from_file(path)
                    .with_from_adapter(PyTorchToBurnAdapter)
                    .map_indices_contiguous(true)
                    .allow_partial(true)
                    .with_regex(r"^features\.");
                net.load_from(&mut store)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
            }
            "pth" | "pt" | "bin" => {
                let mut store = PytorchStore::from_file(path)
                    .map_indices_contiguous(true)
                    .allow_partial(true)
                    .with_regex(r"^features\.");
                net.load_from(&mut store)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
            }
            other => bail!(
                "{}: unknown weights format {other:?} (expected .pth, .pt or .safetensors)",
                path.display()
            ),
        };
        if !result.errors.is_empty() {
            bail!("{}: {:?}", path.display(), result.errors);
        }
        let missing: Vec<String> = result
            .missing
            .iter()
            .map(|(k, _)| k.clone())
            .filter(|k| k.starts_with("features."))
            .collect();
        if !missing.is_empty() {
            bail!(
                "{}: not VGG16 features: {} of its tensors are missing ({}), expected torchvision's `features.N.weight/bias`",
                path.display(),
                missing.len(),
                missing.iter().take(4).cloned().collect::<Vec<_>>().join(", ")
            );
        }
        Ok(net.no_grad())
    }

    /// The activations at `layers` (sorted, deduplicated) of display-range images `x`
    /// (`[B, 3, H, W]`, RGB values in [0, 1]); the weights' preprocessing is applied here.
    pub fn features(&self, x: Tensor<4>, layers: &[Layer]) -> Vec<Tensor<4>> {
        let device = x.device();
        let stat = |v: [f32; 3]| Tensor::<1>::from_floats(v, &device).reshape([1, 3, 1, 1]);
        let mut y = match self.preprocessing {
            Preprocessing::Torchvision => (x - stat(MEAN)) / stat(STD),
            Preprocessing::Caffe => x.mul_scalar(255.0) - stat(CAFFE_MEAN),
        };
        let last = layers.iter().map(|l| l.block()).max().unwrap_or(0);
        let mut out = Vec::new();
        let mut conv = self.features.iter();
        for (block, (_, n)) in BLOCKS.iter().enumerate().take(last + 1) {
            if block > 0 {
                y = max_pool2d(y, MaxPoolOptions::new([2, 2]).with_stride([2, 2]));
            }
            for c in conv.by_ref().take(*n) {
                y = relu(c.forward(y));
            }
            if layers.iter().any(|l| l.block() == block) {
                out.push(y.clone());
            }
        }
        out
    }
}

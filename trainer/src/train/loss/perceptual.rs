//! The perceptual loss of Eq. 5 between a re-rendered image (I' or O') and its ground truth.
//!
//! * With VGG16 weights (a torchvision checkpoint or its safetensors export, named in the
//!   training manifest): Johnson et al.'s feature reconstruction loss, the mean squared difference
//!   of VGG16 activations, summed over the chosen layers. Both images are masked to the object and
//!   mapped to display values first (the tone map of [`super::display`] at the ground
//!   truth's exposure, divided by 255), so the network sees what a viewer would.
//! * Without: the documented fallback of [`perceptual_fallback`] (tone-mapped
//!   multi-scale L2). The run's log says which one is in use; the fallback is never silent.

use super::{Compute, ImagePair, Term, display, exposure, mean, sum_all};
use crate::model::vgg16::{Layer, Vgg16};
use crate::parallel::share;
use crate::train::stage_kind::StageKind;
use anyhow::Result;
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;
use burn::tensor::{Device, Tensor};
use std::path::{Path, PathBuf};

/// The term.
pub const TERM: Term = Term {
    name: "perceptual",
    symbol: "w_p",
    label: "w_p · perceptual",
    colour: (44, 160, 44),
    default_weight: 1.0,
    logged_at_zero: true,
    written_when_zero: true,
    stages: &[StageKind::Joint, StageKind::EncoderDecoder],
    compute: Compute::Image(on_image),
};

fn on_image(x: &ImagePair) -> Tensor<1> {
    x.perceptual.loss(x.rendered.clone(), x.truth.clone(), x.mask.clone())
}

/// The layers compared by default: the four block ends, as in most perceptual losses built on
/// Johnson et al.
pub const DEFAULT_LAYERS: [Layer; 4] = [Layer::Relu1_2, Layer::Relu2_2, Layer::Relu3_3, Layer::Relu4_3];

/// Which perceptual loss a run uses.
#[derive(Debug)]
pub enum Perceptual {
    /// Tone-mapped multi-scale L2 (no VGG16 weights configured).
    Fallback {
        /// Why: for the run's log.
        why: &'static str,
    },
    /// VGG16 feature reconstruction loss.
    Vgg16 {
        /// The frozen network.
        net: Box<Vgg16>,
        /// Compared layers (sorted).
        layers: Vec<Layer>,
        /// Where the weights came from.
        source: PathBuf,
        /// `blake3:HEX` of the weights file.
        checksum: String,
    },
}

impl Perceptual {
    /// VGG16 from `weights` on `device`, comparing `layers`.
    pub fn vgg16(weights: &Path, layers: &[Layer], device: &Device) -> Result<Self> {
        let mut layers = layers.to_vec();
        layers.sort();
        layers.dedup();
        if layers.is_empty() {
            anyhow::bail!("at least one VGG16 layer is needed for the perceptual loss");
        }
        Ok(Self::Vgg16 {
            net: Box::new(Vgg16::load(weights, device)?),
            layers,
            source: weights.to_path_buf(),
            checksum: crate::train::checkpoint::checksum(weights)?,
        })
    }

    /// What a checkpoint records of the loss: `None` for the fallback, `vgg16 blake3:HEX` for
    /// VGG16 (the same weights wherever they are).
    pub fn identity(&self) -> Option<String> {
        match self {
            Self::Fallback { .. } => None,
            Self::Vgg16 { checksum, layers, .. } => Some(format!("vgg16 {checksum} {layers:?}")),
        }
    }

    /// One line for the run's log.
    pub fn description(&self) -> String {
        match self {
            Self::Fallback { why } => {
                format!(
                    "perceptual loss: fallback (multi-scale L2 in [0, 255] after the metric's tone map, made \
                     smooth; see trainer/src/train/loss/perceptual.rs): {why}"
                )
            }
            Self::Vgg16 {
                net, layers, source, ..
            } => {
                format!(
                    "perceptual loss: VGG16 features {layers:?} from {} ({:?} preprocessing)",
                    source.display(),
                    net.preprocessing()
                )
            }
        }
    }

    /// The loss between `pred` and `truth` (`[B, 3, H, W]`, linear radiance) on the object
    /// (`mask`, `[B, 1, H, W]`).
    pub fn loss(&self, pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
        match self {
            Self::Fallback { .. } => perceptual_fallback(pred, truth, mask),
            Self::Vgg16 { net, layers, .. } => {
                let e = exposure(&truth, &mask);
                let show = |x: Tensor<4>| (display(x, e.clone()) * mask.clone()).div_scalar(255.0);
                let fp = net.features(show(pred), layers);
                let ft = net.features(show(truth).detach(), layers);
                fp.into_iter()
                    .zip(ft)
                    .map(|(a, b)| mean((a - b).powi_scalar(2)))
                    .reduce(|a, b| a + b)
                    .unwrap_or_else(|| Tensor::zeros([1], &mask.device()))
            }
        }
    }
}

/// The fallback perceptual loss between a rendered image and the ground truth (`[B, 3, H, W]`,
/// linear), on object pixels (`mask` `[B, 1, H, W]`).
pub fn perceptual_fallback(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let e = exposure(&truth, &mask);
    let mut d = (display(pred, e.clone()) - display(truth, e)) * mask.clone();
    let mut m = mask;
    let mut total: Option<Tensor<1>> = None;
    for level in 0..3 {
        if level > 0 {
            let [_, _, h, w] = d.dims();
            if h < 2 || w < 2 {
                break;
            }
            d = avg_pool2d(d, AvgPoolOptions::new([2, 2]).with_stride([2, 2]));
            m = avg_pool2d(m, AvgPoolOptions::new([2, 2]).with_stride([2, 2]));
        }
        // Mean over covered pixels and channels.
        let covered = share::batch_total(sum_all(m.clone()).mul_scalar(3.0));
        let term = sum_all(d.clone().powi_scalar(2)) / covered.add_scalar(1e-6);
        total = Some(match total {
            Some(t) => t + term,
            None => term,
        });
    }
    total.unwrap_or_else(|| Tensor::zeros([1], &d.device()))
}

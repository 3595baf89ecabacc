//! Eq. 4, the material loss: the mean squared difference of the normalised DSBRDF parameters.

use super::mean;
use super::{Compute, Predicted, Term};
use crate::data::TensorBatch;
use crate::train::stage_kind::StageKind;
use burn::tensor::Tensor;

/// The term.
pub const TERM: Term = Term {
    name: "material",
    symbol: "w_m",
    label: "w_m · material",
    colour: (255, 127, 14),
    default_weight: 1e3,
    logged_at_zero: true,
    written_when_zero: true,
    stages: &[StageKind::Pretrain, StageKind::Joint, StageKind::EncoderDecoder],
    compute: Compute::Prediction(on_prediction),
};

fn on_prediction(p: &Predicted, b: &TensorBatch) -> Option<Tensor<1>> {
    Some(material_loss(p.materials?.clone(), b.materials.clone()))
}

/// Mean squared difference of the normalised parameters (Eq. 4).
pub fn material_loss(pred: Tensor<3>, truth: Tensor<3>) -> Tensor<1> {
    mean((pred - truth).powi_scalar(2))
}

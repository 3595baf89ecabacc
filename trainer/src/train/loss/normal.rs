//! Eq. 3, the normal loss: the masked mean of |n − n'|² over object pixels.

use super::sum_all;
use super::{Compute, Predicted, Term};
use crate::data::TensorBatch;
use crate::parallel::share;
use crate::train::stage_kind::StageKind;
use burn::tensor::Tensor;

/// The term.
pub const TERM: Term = Term {
    name: "normal",
    symbol: "w_n",
    label: "w_n · normal",
    colour: (31, 119, 180),
    default_weight: 1e4,
    logged_at_zero: true,
    written_when_zero: true,
    stages: &[StageKind::Pretrain, StageKind::Joint],
    compute: Compute::Prediction(on_prediction),
};

fn on_prediction(p: &Predicted, b: &TensorBatch) -> Option<Tensor<1>> {
    Some(normal_loss(p.normals?.clone(), b.normals.clone(), b.mask.clone()))
}

/// Masked mean of |n − n'|² over object pixels (Eq. 3, averaged rather than summed so that the
/// weight does not depend on the resolution). `mask` is `[B, 1, H, W]`.
pub fn normal_loss(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let d = (pred - truth).powi_scalar(2).sum_dim(1) * mask.clone();
    sum_all(d) / share::batch_total(sum_all(mask)).add_scalar(1e-6)
}

//! The direct loss on L' (not in the paper, which trains L' only through the rendering layer).

use super::{Compute, Term};
use super::{display, exposure, mean};
use crate::train::stage_kind::StageKind;
use burn::tensor::Tensor;

/// The term.
pub const TERM: Term = Term {
    name: "illumination",
    symbol: "w_L",
    label: "w_L · illumination",
    colour: (148, 103, 189),
    default_weight: 0.0,
    logged_at_zero: false,
    written_when_zero: true,
    stages: &[StageKind::Pretrain, StageKind::Joint],
    compute: Compute::Light(illumination_loss),
};

/// The direct loss on the predicted illumination (an option, not in the paper): the mean over
/// texels and channels of the squared difference of the two maps (`[B, 3, He, 2He]`) after
/// [`display`] at the true map's own exposure (its 99th-percentile value becomes white), so on
/// the [0, 255] scale of the image losses. In the display domain the optimum for an ambiguous
/// input is a tone-mapped mean of the candidates, not the darker geometric mean a log-L2 gives.
pub fn illumination_loss(pred: Tensor<4>, truth: Tensor<4>) -> Tensor<1> {
    let [b, _, h, w] = truth.dims();
    let all = Tensor::ones([b, 1, h, w], &truth.device());
    let e = exposure(&truth, &all);
    mean((display(pred, e.clone()) - display(truth, e)).powi_scalar(2))
}

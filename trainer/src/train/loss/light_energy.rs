//! The loss on the energy of L' (not in the paper): what the direct loss clips away.

use super::{Compute, Term};
use super::{mean, row_sums};
use crate::train::stage_kind::StageKind;
use burn::tensor::{Tensor, TensorData};
use matedit_physics::envmap::texel_solid_angle;

/// The term.
pub const TERM: Term = Term {
    name: "light_energy",
    symbol: "w_E",
    label: "w_E · light energy",
    colour: (140, 86, 75),
    default_weight: 0.0,
    logged_at_zero: false,
    written_when_zero: false,
    stages: &[StageKind::Pretrain, StageKind::Joint],
    compute: Compute::Light(light_energy_loss),
};

/// Added to both energies of [`light_energy_loss`] so that a black map has a finite logarithm:
/// far below any map's mean radiance in the datasets here (real maps' means are 1e-2 to 1e2).
pub const LIGHT_ENERGY_FLOOR: f64 = 1e-6;

/// The loss on the predicted light's energy (an option, not in the paper): the mean over images
/// and channels of ln²((E' + ε) / (E + ε)), E the map's mean radiance over the sphere (each
/// texel weighted by its solid angle over 4π) and ε = [`LIGHT_ENERGY_FLOOR`].
/// [`super::illumination::illumination_loss`] compares the maps where the true map's 99th percentile is white, so a
/// sun's or a lamp's energy above that clip costs the prediction nothing; this term charges a
/// dim or an over-bright L' for all of it, whatever the map's absolute scale.
pub fn light_energy_loss(pred: Tensor<4>, truth: Tensor<4>) -> Tensor<1> {
    let [b, c, h, w] = truth.dims();
    let device = truth.device();
    let rows: Vec<f32> = (0..h)
        .map(|i| (texel_solid_angle(i, w, h) / (4.0 * std::f64::consts::PI)) as f32)
        .collect();
    let weights = Tensor::<4>::from_data(TensorData::new(rows, [1, 1, h, 1]), &device);
    // Clamped so that no sum of texels can overflow f32 (a map's texels are far below 1e30).
    let energy = |x: Tensor<4>| {
        row_sums((x.clamp(0.0, 1e30) * weights.clone()).reshape([b * c, h * w])).add_scalar(LIGHT_ENERGY_FLOOR)
    };
    let ratio = energy(pred) / energy(truth.detach());
    mean(ratio.log().powi_scalar(2))
}

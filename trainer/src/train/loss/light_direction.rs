//! The loss on where L' comes from (not in the paper): the key light's side, which the direct
//! loss lets a module average away.

use super::light_energy::LIGHT_ENERGY_FLOOR;
use super::{Compute, Term};
use super::{mean, row_sums};
use crate::train::stage_kind::StageKind;
use burn::tensor::{Tensor, TensorData};
use matedit_physics::LUMINANCE_WEIGHTS;
use matedit_physics::envmap::{texel_direction, texel_solid_angle};

/// The term.
pub const TERM: Term = Term {
    name: "light_direction",
    symbol: "w_D",
    label: "w_D · light direction",
    colour: (227, 119, 194),
    default_weight: 0.0,
    logged_at_zero: false,
    written_when_zero: false,
    stages: &[StageKind::Pretrain, StageKind::Joint],
    compute: Compute::Light(light_direction_loss),
};

/// The loss on where the predicted light comes from (an option, not in the paper): the mean over
/// images of |d' − d|², where d = ∫ Y(ω) ω dΩ / ∫ Y(ω) dΩ is a map's mean direction weighted
/// by its luminance Y (Rec. 709; |d| ≤ 1: 0 for light alike from every side, 1 for a point).
/// Free of the map's scale, like [`super::light_energy::light_energy_loss`]. [`super::illumination::illumination_loss`] compares the maps
/// texel by texel after a tone map that clips the sun or the lamp, so a module that cannot place
/// the key light answers the mean over the light's rotations at little cost (measured: one
/// layout for every photo, docs/PERFORMANCE.md); the mean over turns about the vertical keeps
/// only d's vertical part, and here costs the horizontal part's |d|².
pub fn light_direction_loss(pred: Tensor<4>, truth: Tensor<4>) -> Tensor<1> {
    // Both maps in one batch: the direction weights are built and summed once.
    let b = pred.dims()[0];
    let d = light_direction(Tensor::cat(vec![pred, truth.detach()], 0));
    mean(
        (d.clone().narrow(0, 0, b) - d.narrow(0, b, b))
            .powi_scalar(2)
            .sum_dim(1),
    )
}

/// Each map's luminance-weighted mean direction d (`[B, 3, He, We]` → `[B, 3]`), the map's
/// convention (`texel_direction`); negative texels count as black.
pub fn light_direction(x: Tensor<4>) -> Tensor<2> {
    let [b, _, h, w] = x.dims();
    let device = x.device();
    let lum = TensorData::new(LUMINANCE_WEIGHTS.map(|v| v as f32).to_vec(), [1, 3, 1, 1]);
    let y = (x.clamp(0.0, 1e30) * Tensor::<4>::from_data(lum, &device))
        .sum_dim(1)
        .reshape([b, h * w]);
    // Each texel's solid angle over 4π, and that times each component of its direction.
    let mut rows: [Vec<f32>; 4] = std::array::from_fn(|_| Vec::with_capacity(h * w));
    for t in 0..h * w {
        let (row, col) = (t / w, t % w);
        let o = texel_solid_angle(row, w, h) / (4.0 * std::f64::consts::PI);
        let d = texel_direction(col, row, w, h).to_array();
        for (r, v) in rows.iter_mut().zip([1.0, d[0], d[1], d[2]]) {
            r.push((o * v) as f32);
        }
    }
    let [energy, moments @ ..] = rows.map(|r| {
        let weights = Tensor::<2>::from_data(TensorData::new(r, [1, h * w]), &device);
        row_sums(y.clone() * weights).reshape([b, 1])
    });
    Tensor::cat(moments.to_vec(), 1) / energy.add_scalar(LIGHT_ENERGY_FLOOR)
}

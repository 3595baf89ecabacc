//! The losses of Eq. 3–5: masked L2 on normals, L2 on normalised material parameters, and the
//! perceptual loss on the re-rendered images I' and O'.
//!
//! **Perceptual loss.** The paper uses VGG16 features (Johnson et al.). No VGG16 weights ship
//! with this repository, so without them the trainer uses a documented fallback and says so in
//! the log: the tone-mapped multi-scale L2 — both images mapped to display values in [0, 255] by
//! [`display`], masked to the object, compared at full, half and quarter resolution (average
//! pooling), the three mean squared errors summed. Its scale is that of the paper's image metric
//! (L2 on [0, 255] images), so the Eq. 5 weights keep their meaning.
//!
//! [`display`] is a smooth version of the evaluation's tone map (`eval::metrics`): the ground
//! truth's exposure (its 99th-percentile channel value on the object becomes white), a soft clamp
//! to [0, 1] instead of the hard one (so an over-bright prediction still has a gradient back),
//! and a display gamma whose slope at black is bounded like sRGB's. The loss therefore weighs
//! each pixel as the L2 and SSIM scores will see it, whatever the light probe's absolute scale.
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;
use burn::tensor::{Tensor, TensorData};

/// Masked mean of |n − n'|² over object pixels (Eq. 3, averaged rather than summed so that the
/// weight does not depend on the resolution). `mask` is `[B, 1, H, W]`.
pub fn normal_loss(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let d = (pred - truth).powi_scalar(2).sum_dim(1) * mask.clone();
    d.sum() / mask.sum().add_scalar(1e-6)
}

/// Mean squared difference of the normalised parameters (Eq. 4).
pub fn material_loss(pred: Tensor<3>, truth: Tensor<3>) -> Tensor<1> {
    (pred - truth).powi_scalar(2).mean()
}

/// Exponent of [`display`]'s soft clamp s = y·(1 + y^p)^(−1/p): within 2 % of y up to y = 0.5.
const SOFT_CLAMP_P: f64 = 4.0;
/// Where the sRGB transfer function turns from its linear toe to the power law.
const SRGB_KNEE: f64 = 0.003_130_8;

/// The fallback's tone map: linear radiance `x` (`[B, 3, H, W]`) at `exposure` (`[B, 1, 1, 1]`,
/// one per image, treated as a constant) to display values in [0, 255]; smooth up to the sRGB
/// knee, finite and with a finite gradient for any finite input (see the module docs).
pub fn display(x: Tensor<4>, exposure: Tensor<4>) -> Tensor<4> {
    // Clamped before the power so that y^p cannot overflow; s(1e3) = 1 − 2.5e-13.
    let y = (x * exposure.detach()).clamp(0.0, 1e3);
    let s = y.clone()
        * y.powf_scalar(SOFT_CLAMP_P)
            .add_scalar(1.0)
            .powf_scalar(-1.0 / SOFT_CLAMP_P);
    // sRGB, as the metric's tone map. The power branch is evaluated at ≥ the knee so that its
    // gradient stays finite where the linear branch is selected (0 · ∞ would be NaN).
    let power = s
        .clone()
        .clamp_min(SRGB_KNEE)
        .powf_scalar(1.0 / 2.4)
        .mul_scalar(1.055)
        .sub_scalar(0.055);
    let toe = s.clone().mul_scalar(12.92);
    power.mask_where(s.lower_equal_elem(SRGB_KNEE), toe).mul_scalar(255.0)
}

/// The evaluation's exposure of each ground-truth image (`[B, 3, H, W]`) on its mask
/// (`[B, 1, H, W]`), as a `[B, 1, 1, 1]` constant: see `eval::metrics::metric_exposure`.
pub fn exposure(truth: &Tensor<4>, mask: &Tensor<4>) -> Tensor<4> {
    let [b, c, h, w] = truth.dims();
    let device = truth.device();
    let values = |t: &Tensor<4>| -> Vec<f32> {
        // A tensor's own data always converts to f32 on the float backends used here; an empty
        // vector (no exposure information) falls back to exposure 1 below.
        t.clone()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap_or_default()
    };
    let (tv, mv) = (values(truth), values(mask));
    let e: Vec<f32> = (0..b)
        .map(|i| {
            let (img, m) = (
                tv.get(i * c * h * w..(i + 1) * c * h * w),
                mv.get(i * h * w..(i + 1) * h * w),
            );
            match (img, m) {
                (Some(img), Some(m)) => crate::eval::metrics::metric_exposure(img, m),
                _ => 1.0,
            }
        })
        .collect();
    Tensor::from_data(TensorData::new(e, [b, 1, 1, 1]), &device)
}

/// The direct loss on the predicted illumination (an option, not in the paper): the mean over
/// texels and channels of the squared difference of the two maps (`[B, 3, He, 2He]`) after
/// [`display`] at the true map's own exposure (its 99th-percentile value becomes white), so on
/// the [0, 255] scale of the image losses. In the display domain the optimum for an ambiguous
/// input is a tone-mapped mean of the candidates, not the darker geometric mean a log-L2 gives.
pub fn illumination_loss(pred: Tensor<4>, truth: Tensor<4>) -> Tensor<1> {
    let [b, _, h, w] = truth.dims();
    let all = Tensor::ones([b, 1, h, w], &truth.device());
    let e = exposure(&truth, &all);
    (display(pred, e.clone()) - display(truth, e)).powi_scalar(2).mean()
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
        let term = d.clone().powi_scalar(2).sum() / m.clone().sum().mul_scalar(3.0).add_scalar(1e-6);
        total = Some(match total {
            Some(t) => t + term,
            None => term,
        });
    }
    total.unwrap_or_else(|| Tensor::zeros([1], &d.device()))
}

//! The image terms' tone map: linear radiance to display values in [0, 255] at the truth's
//! exposure, as the evaluation's L2 and SSIM see an image (see the parent module).

use burn::tensor::{Tensor, TensorData};

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
/// (`[B, 1, H, W]`), as a `[B, 1, 1, 1]` constant: see `metrics::metric_exposure`.
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
                (Some(img), Some(m)) => crate::metrics::metric_exposure(img, m),
                _ => 1.0,
            }
        })
        .collect();
    Tensor::from_data(TensorData::new(e, [b, 1, 1, 1]), &device)
}

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
//! [`display`] is a smooth version of the evaluation's tone map (`metrics`): the ground
//! truth's exposure (its 99th-percentile channel value on the object becomes white), a soft clamp
//! to [0, 1] instead of the hard one (so an over-bright prediction still has a gradient back),
//! and a display gamma whose slope at black is bounded like sRGB's. The loss therefore weighs
//! each pixel as the L2 and SSIM scores will see it, whatever the light probe's absolute scale.
//!
//! **Structural loss** (an option, not in the paper): [`ssim_loss`], 1 − the evaluation's SSIM
//! on the same tone map, added to the perceptual loss with its own weight (`[loss] ssim`).
use crate::metrics::{SSIM_C1, SSIM_C2, SSIM_RADIUS, SSIM_SIGMA};
use crate::parallel::share;
use burn::tensor::module::{avg_pool2d, conv2d};
use burn::tensor::ops::{AvgPoolOptions, ConvOptions};
use burn::tensor::{Tensor, TensorData};
use matedit_physics::LUMINANCE_WEIGHTS;
use matedit_physics::envmap::{texel_direction, texel_solid_angle};

/// The sum of each row of `x` (`[B, N]` → `[B]`). On a CubeCL device Burn 0.22.1's reduction
/// kernels are wrong once a reduction spans more than 65,535 workgroups (measured on lavapipe:
/// the row sums of a `[16, 65534]` tensor of ones came out 65520, 0, 0, …; `trainer gpu-info`
/// probes a device), so there the sum is a matrix product with a column of ones, whose kernels
/// tile the output instead; the host keeps Burn's reduction.
pub fn row_sums(x: Tensor<2>) -> Tensor<1> {
    let [b, n] = x.dims();
    let device = x.device();
    if crate::render::on_cube(&device) {
        // Burn's matrix product is wrong there too for long enough rows (a `[1, 3·2²⁰]` row of
        // ones summed to 262140 on lavapipe): rows longer than CHUNK are summed in pieces of
        // CHUNK (zero padded), then the pieces' sums.
        const CHUNK: usize = 4096;
        if n <= CHUNK {
            return x.matmul(Tensor::ones([n, 1], &device)).reshape([b]);
        }
        let k = n.div_ceil(CHUNK);
        let x = if k * CHUNK > n {
            Tensor::cat(vec![x, Tensor::zeros([b, k * CHUNK - n], &device)], 1)
        } else {
            x
        };
        row_sums(
            x.reshape([b * k, CHUNK])
                .matmul(Tensor::ones([CHUNK, 1], &device))
                .reshape([b, k]),
        )
    } else {
        x.sum_dim(1).reshape([b])
    }
}

/// The sum of every value of `x`, as `[1]` (see [`row_sums`]; the host keeps Burn's `sum`).
pub fn sum_all<const D: usize>(x: Tensor<D>) -> Tensor<1> {
    if crate::render::on_cube(&x.device()) {
        let n = x.shape().num_elements();
        row_sums(x.reshape([1, n]))
    } else {
        x.sum()
    }
}

/// The mean of every value of `x`, as `[1]` (see [`row_sums`]; the host keeps Burn's `mean`).
/// Inside a data-parallel step `x` is this rank's part of the global batch, and the mean is
/// this rank's share of the global batch's: its sum over the global count.
pub fn mean<const D: usize>(x: Tensor<D>) -> Tensor<1> {
    if let Some(n) = share::batch_count(x.shape().num_elements()) {
        return sum_all(x).div_scalar(n.max(1.0));
    }
    if crate::render::on_cube(&x.device()) {
        let n = x.shape().num_elements();
        sum_all(x).div_scalar(n.max(1) as f64)
    } else {
        x.mean()
    }
}

/// Masked mean of |n − n'|² over object pixels (Eq. 3, averaged rather than summed so that the
/// weight does not depend on the resolution). `mask` is `[B, 1, H, W]`.
pub fn normal_loss(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let d = (pred - truth).powi_scalar(2).sum_dim(1) * mask.clone();
    sum_all(d) / share::batch_total(sum_all(mask)).add_scalar(1e-6)
}

/// Mean squared difference of the normalised parameters (Eq. 4).
pub fn material_loss(pred: Tensor<3>, truth: Tensor<3>) -> Tensor<1> {
    mean((pred - truth).powi_scalar(2))
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

/// Added to both energies of [`light_energy_loss`] so that a black map has a finite logarithm:
/// far below any map's mean radiance in the datasets here (real maps' means are 1e-2 to 1e2).
pub const LIGHT_ENERGY_FLOOR: f64 = 1e-6;

/// The loss on the predicted light's energy (an option, not in the paper): the mean over images
/// and channels of ln²((E' + ε) / (E + ε)), E the map's mean radiance over the sphere (each
/// texel weighted by its solid angle over 4π) and ε = [`LIGHT_ENERGY_FLOOR`].
/// [`illumination_loss`] compares the maps where the true map's 99th percentile is white, so a
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

/// The loss on where the predicted light comes from (an option, not in the paper): the mean over
/// images of |d' − d|², where d = ∫ Y(ω) ω dΩ / ∫ Y(ω) dΩ is a map's mean direction weighted
/// by its luminance Y (Rec. 709; |d| ≤ 1: 0 for light alike from every side, 1 for a point).
/// Free of the map's scale, like [`light_energy_loss`]. [`illumination_loss`] compares the maps
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

/// Gaussian local means of the SSIM window, as the evaluation computes them
/// (`metrics::ssim`): 11 × 11 taps of σ = 1.5 pixels, the window cut at the image border
/// and renormalised over the pixels it keeps.
#[allow(clippy::large_enum_variant)] // one short-lived value per loss evaluation
enum SsimWindow {
    /// On the host: two 1-D passes with zero padding, then a division by the same passes over an
    /// all-ones image (the kept weight, a constant).
    Convolutions {
        row: Tensor<4>,
        col: Tensor<4>,
        kept: Tensor<4>,
    },
    /// On a CubeCL device, where Burn 0.22.1's fused convolutions gave wrong SSIM values (on
    /// lavapipe): `R · x · Cᵀ` with the two 1-D windows as banded matrices whose rows are already
    /// renormalised. The kept weight is separable (a row sum times a column sum), so this is the
    /// same mean up to rounding. Unverified on a GPU whose matmul runs f32 inputs in TF32
    /// (CUDA from compute capability 8.0): the variances below are differences of such means.
    Products { rows: Tensor<2>, cols: Tensor<2> },
}

impl SsimWindow {
    fn new(h: usize, w: usize, device: &burn::tensor::Device) -> Self {
        if crate::render::on_cube(device) {
            Self::products(h, w, device)
        } else {
            Self::convolutions(h, w, device)
        }
    }

    fn products(h: usize, w: usize, device: &burn::tensor::Device) -> Self {
        Self::Products {
            rows: Self::band(h, device),
            cols: Self::band(w, device).transpose(),
        }
    }

    fn convolutions(h: usize, w: usize, device: &burn::tensor::Device) -> Self {
        let n = 2 * SSIM_RADIUS + 1;
        let taps: Vec<f32> = (0..n).map(|i| Self::tap(i as f64 - SSIM_RADIUS as f64)).collect();
        let row = Tensor::<4>::from_data(TensorData::new(taps.clone(), [1, 1, 1, n]), device);
        let col = Tensor::<4>::from_data(TensorData::new(taps, [1, 1, n, 1]), device);
        let kept = Self::pass(&row, &col, Tensor::ones([1, 1, h, w], device)).detach();
        Self::Convolutions { row, col, kept }
    }

    fn tap(d: f64) -> f32 {
        (-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp() as f32
    }

    /// The `[n, n]` matrix of the 1-D window over `n` samples, each row divided by its sum.
    fn band(n: usize, device: &burn::tensor::Device) -> Tensor<2> {
        let mut m = vec![0.0f32; n * n];
        for i in 0..n {
            let (lo, hi) = (i.saturating_sub(SSIM_RADIUS), (i + SSIM_RADIUS).min(n - 1));
            let sum: f32 = (lo..=hi).map(|j| Self::tap(j as f64 - i as f64)).sum();
            for j in lo..=hi {
                m[i * n + j] = Self::tap(j as f64 - i as f64) / sum;
            }
        }
        Tensor::from_data(TensorData::new(m, [n, n]), device).detach()
    }

    /// The two 1-D passes over each plane of `x` (`[N, 1, H, W]`), zero padded.
    fn pass(row: &Tensor<4>, col: &Tensor<4>, x: Tensor<4>) -> Tensor<4> {
        let r = SSIM_RADIUS;
        let x = conv2d(x, row.clone(), None, ConvOptions::new([1, 1], [0, r], [1, 1], 1));
        conv2d(x, col.clone(), None, ConvOptions::new([1, 1], [r, 0], [1, 1], 1))
    }

    /// Window-weighted mean of each plane of `x` (`[N, 1, H, W]`).
    fn mean(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            Self::Convolutions { row, col, kept } => Self::pass(row, col, x) / kept.clone(),
            // `[1, 1, ·, ·]` matrices: matmul broadcasts them over the planes.
            Self::Products { rows, cols } => rows
                .clone()
                .unsqueeze::<4>()
                .matmul(x)
                .matmul(cols.clone().unsqueeze::<4>()),
        }
    }
}

/// The structural loss (an option, not in the paper): 1 − SSIM between a rendered image and its
/// ground truth (`[B, 3, H, W]`, linear), both through [`display`] at the truth's exposure, the
/// SSIM map of `metrics::ssim` (same window, constants and border rule) averaged over each
/// image's object pixels (`mask`, `[B, 1, H, W]`) and channels, then over the batch. In [0, 2];
/// 0 for identical images and for an image without object pixels (the metric's "nothing wrong").
///
/// The paper's perceptual loss compares VGG16 features, which respond to local structure; the
/// fallback's L2 does not. This term restores a structural signal when no VGG16 weights are
/// available.
pub fn ssim_loss(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let [b, c, h, w] = truth.dims();
    let window = SsimWindow::new(h, w, &truth.device());
    let e = exposure(&truth, &mask);
    let planes = |t: Tensor<4>| t.reshape([b * c, 1, h, w]);
    let x = planes(display(pred, e.clone()));
    let y = planes(display(truth, e).detach());
    let (mx, my) = (window.mean(x.clone()), window.mean(y.clone()));
    let vx = window.mean(x.clone() * x.clone()) - mx.clone() * mx.clone();
    let vy = window.mean(y.clone() * y.clone()) - my.clone() * my.clone();
    let vxy = window.mean(x * y) - mx.clone() * my.clone();
    let num = (mx.clone() * my.clone()).mul_scalar(2.0).add_scalar(SSIM_C1) * vxy.mul_scalar(2.0).add_scalar(SSIM_C2);
    // Both factors are ≥ the constants (variances are ≥ 0 up to rounding), so the quotient is
    // finite; the clamp keeps a rounding-negative variance from shrinking the denominator.
    let den = (mx.clone() * mx + my.clone() * my).add_scalar(SSIM_C1) * (vx + vy).clamp_min(0.0).add_scalar(SSIM_C2);
    let dissimilarity = (num / den).neg().add_scalar(1.0).reshape([b, c, h, w]) * mask.clone();
    let per_image = row_sums(dissimilarity.reshape([b, c * h * w]))
        / row_sums(mask.reshape([b, h * w])).mul_scalar(c as f64).add_scalar(1e-6);
    mean(per_image)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The SSIM window as matrix products (what a GPU device runs) gives the convolutions' local
    /// means, for images smaller than the window, non-square ones and a typical size.
    #[test]
    fn the_ssim_window_as_products_equals_the_convolutions() {
        let device = burn::tensor::Device::flex();
        for (k, &(h, w)) in [(1, 1), (1, 7), (3, 20), (9, 14), (11, 11), (32, 24)]
            .iter()
            .enumerate()
        {
            let n = 2;
            let mut x = 0x9e37_79b9u32 ^ k as u32;
            let data: Vec<f32> = (0..n * h * w)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as f32 / u32::MAX as f32 * 255.0
                })
                .collect();
            let plane = || Tensor::<4>::from_data(TensorData::new(data.clone(), [n, 1, h, w]), &device);
            let values = |t: Tensor<4>| -> Vec<f32> { t.into_data().try_to_vec::<f32>().expect("f32") };
            let a = values(SsimWindow::convolutions(h, w, &device).mean(plane()));
            let b = values(SsimWindow::products(h, w, &device).mean(plane()));
            assert_eq!(a.len(), b.len());
            for (p, q) in a.iter().zip(&b) {
                assert!((p - q).abs() <= 1e-4 * (1.0 + p.abs()), "{h}x{w}: {p} vs {q}");
            }
        }
    }

    /// The losses' sums on the GPU device are exact where Burn's reductions are not (lavapipe,
    /// 2026-11-27: Burn's row sums of `[16, 65534]` ones gave 65520, 0, 0, …).
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_losses_sums_on_the_gpu_device_are_exact_at_training_sizes() {
        let Some(gpu) = crate::render::gpu::tests::device() else {
            return;
        };
        for (b, n) in [
            (1, 3),
            (2, 4097),
            (1, 65535),
            (16, 65534),
            (16, 196_608),
            (4, 1 << 20),
            (1, 3 << 20),
        ] {
            let sums: Vec<f32> = row_sums(Tensor::<2>::ones([b, n], &gpu))
                .into_data()
                .try_to_vec()
                .expect("f32");
            assert_eq!(sums, vec![n as f32; b], "[{b}, {n}]");
        }
        let all = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().expect("f32")[0];
        assert_eq!(
            all(sum_all(Tensor::<4>::ones([16, 3, 256, 256], &gpu))),
            (16 * 3 * 65536) as f32
        );
        assert_eq!(all(mean(Tensor::<4>::ones([16, 3, 256, 256], &gpu))), 1.0);
        // Not only ones: a ramp whose sum is exact in f32.
        let ramp: Vec<f32> = (0..2 * 65536).map(|i| (i % 256) as f32).collect();
        let t = Tensor::<2>::from_data(TensorData::new(ramp, [2, 65536]), &gpu);
        assert_eq!(
            row_sums(t).into_data().try_to_vec::<f32>().expect("f32"),
            vec![255.0 * 128.0 * 256.0; 2]
        );
    }

    /// The structural loss on the wgpu device (the window as matrix products) against the CPU
    /// device (the convolutions), at the paper's 256²: the answer to whether a device's matmul
    /// rounds the window's means (TF32 on CUDA from compute capability 8.0) enough to move the
    /// variances, which are differences of such means. Prints the worst relative difference.
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_structural_loss_on_the_gpu_device_equals_the_cpu_devices() {
        let Some(gpu) = crate::render::gpu::tests::device() else {
            return;
        };
        let cpu = burn::tensor::Device::flex();
        let (b, h, w) = (2, 256, 256);
        let mut x = 0x2545_f491u32;
        let mut noise = move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x as f32 / u32::MAX as f32
        };
        // Smooth shading with texture, HDR highlights, and a disc mask: what a render looks like.
        let mut truth = Vec::with_capacity(b * 3 * h * w);
        let mut pred = Vec::with_capacity(b * 3 * h * w);
        for i in 0..b * 3 * h * w {
            let (y, x) = ((i / w) % h, i % w);
            let base = 0.2 + 0.6 * ((x as f32 / 37.0).sin() * (y as f32 / 23.0).cos()).abs();
            let t = base + 0.1 * noise() + if noise() > 0.995 { 20.0 } else { 0.0 };
            truth.push(t);
            pred.push(t * (0.9 + 0.2 * noise()));
        }
        let mask: Vec<f32> = (0..b * h * w)
            .map(|i| {
                let (y, x) = ((i / w) % h, i % w);
                let (dy, dx) = (y as f32 - 128.0, x as f32 - 128.0);
                f32::from(dy * dy + dx * dx < 100.0 * 100.0)
            })
            .collect();
        let loss = |device: &burn::tensor::Device| -> f32 {
            let t = |v: &Vec<f32>, c| Tensor::<4>::from_data(TensorData::new(v.clone(), [b, c, h, w]), device);
            let l = ssim_loss(t(&pred, 3), t(&truth, 3), t(&mask, 1));
            l.into_data().try_to_vec::<f32>().expect("f32")[0]
        };
        let (on_cpu, on_gpu) = (loss(&cpu), loss(&gpu));
        let rel = (on_cpu - on_gpu).abs() / on_cpu.abs().max(1e-6);
        eprintln!(
            "structural loss at 256²: CPU device {on_cpu:.7}, GPU device {on_gpu:.7}, relative difference {rel:.2e}"
        );
        assert!(on_cpu > 0.01, "the case must be dissimilar: {on_cpu}");
        // The variances are differences of means of squares on the 0–255 scale, so the two
        // windows' roundings (products against convolutions) leave ~1e-4 in a pixel's SSIM;
        // lavapipe: 8.3e-5 of the loss. Burn's own row sums were off by 33 % here.
        assert!(rel <= 5e-4, "CPU {on_cpu} vs GPU {on_gpu}: relative {rel:.2e}");
    }
}

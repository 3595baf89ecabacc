//! The structural loss (not in the paper): 1 − the evaluation's SSIM on the image terms' tone
//! map, added to the perceptual loss with its own weight (`[loss] ssim`).

use super::{Compute, ImagePair, Term, display, exposure, mean, row_sums};
use crate::metrics::{SSIM_C1, SSIM_C2, SSIM_RADIUS, SSIM_SIGMA};
use crate::train::stage_kind::StageKind;
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Tensor, TensorData};

/// The term.
pub const TERM: Term = Term {
    name: "ssim",
    symbol: "w_s",
    label: "w_s · (1 − SSIM)",
    colour: (214, 39, 40),
    default_weight: 0.0,
    logged_at_zero: false,
    written_when_zero: true,
    stages: &[StageKind::Joint, StageKind::EncoderDecoder],
    compute: Compute::Image(on_image),
};

fn on_image(x: &ImagePair) -> Tensor<1> {
    ssim_loss(x.rendered.clone(), x.truth.clone(), x.mask.clone())
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
        if crate::device::on_cube(device) {
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

    /// The structural loss on the wgpu device (the window as matrix products) against the CPU
    /// device (the convolutions), at the paper's 256²: the answer to whether a device's matmul
    /// rounds the window's means (TF32 on CUDA from compute capability 8.0) enough to move the
    /// variances, which are differences of such means. Prints the worst relative difference.
    #[cfg(feature = "wgpu")]
    #[test]
    fn the_structural_loss_on_the_gpu_device_equals_the_cpu_devices() {
        let Some(gpu) = crate::rendering_layer::gpu::tests::device() else {
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

//! The losses of Eq. 3–5: masked L2 on normals, L2 on normalised material parameters, and the
//! perceptual loss on the re-rendered images I' and O'.
//!
//! **Perceptual loss.** The paper uses VGG16 features (Johnson et al.). No VGG16 weights ship
//! with this repository, so without them the trainer uses a documented fallback and says so in
//! the log: the tone-mapped multi-scale L2 — both images mapped to display values in [0, 255] by
//! 255·(x/(1+x))^(1/2.2) (Reinhard, then display gamma; smooth, so it has useful gradients up to
//! the brightest highlight), masked to the object, compared at full, half and quarter resolution
//! (average pooling), the three mean squared errors summed. Its scale is that of the paper's
//! image metric (L2 on [0, 255] images), so the Eq. 5 weights keep their meaning.

use burn::tensor::Tensor;
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::AvgPoolOptions;

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

/// The smooth display transform of the fallback perceptual loss, in [0, 255].
pub fn display(x: Tensor<4>) -> Tensor<4> {
    let x = x.clamp(0.0, 1e30);
    let r = x.clone() / x.add_scalar(1.0);
    r.add_scalar(1e-6).powf_scalar(1.0 / 2.2).mul_scalar(255.0)
}

/// The fallback perceptual loss between a rendered image and the ground truth (`[B, 3, H, W]`,
/// linear), on object pixels (`mask` `[B, 1, H, W]`).
pub fn perceptual_fallback(pred: Tensor<4>, truth: Tensor<4>, mask: Tensor<4>) -> Tensor<1> {
    let mut d = (display(pred) - display(truth)) * mask.clone();
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

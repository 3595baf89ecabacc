//! The fused rendering layer inside a Burn autodiff graph.
//!
//! The fused layer runs on the host, outside Burn's backends (the GPU layer, `rendering_layer::gpu`, is a
//! backend extension with its own backward), so it joins the graph through its vector–Jacobian
//! product:
//!
//! 1. [`Rendered::new`] reads n, m and L off their (tracked) tensors, runs the fused forward pass,
//!    and hands out the image as a fresh leaf ([`Rendered::image`]) that requires a gradient;
//! 2. everything downstream (the perceptual loss) is built on that leaf, and its backward pass
//!    yields ∂loss/∂image;
//! 3. [`Rendered::pullback`] runs the fused backward pass and returns the scalar surrogate
//!    Σ n ⊙ ḡ_n + Σ m ⊙ ḡ_m + Σ L ⊙ ḡ_L (ḡ constant), whose gradient with respect to anything
//!    upstream of n, m and L is exactly the chain rule through the layer. Adding it to the
//!    upstream losses and calling `backward` once trains the modules.
//!
//! The surrogate's *value* is meaningless; the loss that is logged is computed separately.

use super::{Gradients, LayerInput, RenderError, RenderingLayer};
use burn::tensor::{Device, Tensor, TensorData};

/// Copies a tensor's values to the host.
pub fn host<const D: usize>(t: &Tensor<D>) -> Vec<f32> {
    t.to_data().try_into_vec_as::<f32>().unwrap_or_default()
}

/// One application of the rendering layer to a batch.
pub struct Rendered {
    size: (usize, usize),
    batch: usize,
    regions: usize,
    normals: Vec<f32>,
    region_map: Vec<u8>,
    materials: Vec<f32>,
    env: Vec<f32>,
    image: Vec<f32>,
}

impl Rendered {
    /// Renders `normals` `[B, 3, H, W]`, `materials` `[B, R, 108]` (normalised) and `env`
    /// `[B, 3, He, 2He]` with the region map `[B, H, W]`.
    pub fn new(
        layer: &RenderingLayer,
        normals: &Tensor<4>,
        materials: &Tensor<3>,
        env: &Tensor<4>,
        region_map: &[u8],
    ) -> Result<Self, RenderError> {
        let [batch, _, h, w] = normals.dims();
        let regions = materials.dims()[1];
        let mut r = Self {
            size: (h, w),
            batch,
            regions,
            normals: host(normals),
            region_map: region_map.to_vec(),
            materials: host(materials),
            env: host(env),
            image: Vec::new(),
        };
        r.image = layer.forward(&r.batch_view())?;
        Ok(r)
    }

    fn batch_view(&self) -> LayerInput<'_> {
        LayerInput {
            batch: self.batch,
            size: self.size,
            regions: self.regions,
            normals: &self.normals,
            region_map: &self.region_map,
            materials: &self.materials,
            env: &self.env,
        }
    }

    /// The rendered image `[B, 3, H, W]` as host values.
    pub fn values(&self) -> &[f32] {
        &self.image
    }

    /// The rendered image as a leaf on `device`, tracked when `device` has autodiff.
    pub fn image(&self, device: &Device) -> Tensor<4> {
        let [h, w] = [self.size.0, self.size.1];
        let t = Tensor::<4>::from_data(TensorData::new(self.image.clone(), [self.batch, 3, h, w]), device);
        if t.is_autodiff() { t.require_grad() } else { t }
    }

    /// The fused backward pass for ∂loss/∂image.
    pub fn gradients(&self, layer: &RenderingLayer, upstream: &[f32]) -> Result<Gradients, RenderError> {
        layer.backward(&self.batch_view(), upstream)
    }

    /// The surrogate scalar whose gradient through `normals`, `materials` and `env` (the tracked
    /// tensors this was rendered from) is the layer's chain rule for ∂loss/∂image = `upstream`.
    /// Pass `None` for an input that should receive no gradient (e.g. a ground-truth target
    /// material).
    pub fn pullback(
        &self,
        layer: &RenderingLayer,
        upstream: &[f32],
        normals: Option<Tensor<4>>,
        materials: Option<Tensor<3>>,
        env: Option<Tensor<4>>,
    ) -> Result<Option<Tensor<1>>, RenderError> {
        let g = self.gradients(layer, upstream)?;
        Ok(surrogate(&g, normals, materials, env))
    }
}

/// Σ input ⊙ constant gradient, over the inputs given.
pub fn surrogate(
    g: &Gradients,
    normals: Option<Tensor<4>>,
    materials: Option<Tensor<3>>,
    env: Option<Tensor<4>>,
) -> Option<Tensor<1>> {
    fn dot<const D: usize>(x: Tensor<D>, g: &[f32]) -> Tensor<1> {
        let c = Tensor::<D>::from_data(TensorData::new(g.to_vec(), x.dims()), &x.device());
        (x * c).sum()
    }
    let terms = [
        normals.map(|n| dot(n, &g.normals)),
        materials.map(|m| dot(m, &g.materials)),
        env.map(|e| dot(e, &g.env)),
    ];
    terms.into_iter().flatten().reduce(|a, b| a + b)
}

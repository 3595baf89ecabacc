//! The rendering layer on a GPU: Eq. 2 and its vector–Jacobian product as CubeCL kernels
//! ([`kernels`]), joined to Burn's autodiff through a backend extension with a hand-written
//! backward. n', m', L', the images and every gradient stay on the device for the whole step.
//!
//! [`DeviceLayer::render`] takes the same tensors as the CPU layer ([`super::RenderingLayer`],
//! layouts in the parent module) and returns I' as a tensor tracked by autodiff: a loss built on
//! it back-propagates into whichever of n, m and L require a gradient, in the one `backward` of
//! the step. Detach an input to keep the layer's gradient from reaching it.
//!
//! It runs on Burn's CubeCL devices (`--features wgpu`: Vulkan, Metal, DX12, and Mesa's lavapipe
//! on machines without a GPU). The fused CPU layer stays the path for the CPU device; the test
//! suite holds the two to 1e-4 of each other.

mod kernels;
#[cfg(test)]
pub(crate) mod tests;

use super::texels::TexelTable;
use super::{MAX_RADIANCE, RenderError, material::log_affine};
use burn::backend::autodiff::{
    Autodiff,
    checkpoint::{base::Checkpointer, strategy::CheckpointStrategy},
    grads::Gradients,
    ops::{Backward, Ops, OpsKind},
};
use burn::backend::cubecl::dtype_to_storage_type;
use burn::backend::fusion::custom::TensorSpec;
use burn::backend::{AutodiffBackend, Dispatch, TensorMetadata, backend_extension, tensor::FloatTensor};
use burn::tensor::{Device, Tensor as BTensor, TensorData};
use burn_cubecl::{CubeBackend, kernel::into_contiguous, ops::numeric::empty_device_dtype, tensor::CubeTensor};
use cubecl::prelude::*;
use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, PARAMS};

/// The layer's operations on a Burn backend: `Cube` runs the kernels, `Fusion` defers them like
/// Burn's own operations, `Autodiff` records the hand-written backward.
#[backend_extension(Cube, Autodiff, Fusion)]
pub trait RenderingLayerBackend: burn::backend::Backend {
    /// I = R(n, m, L): `[B, 3, H, W]`.
    #[fusion(dtype = normals, shape = normals)]
    fn rendering_layer(
        normals: FloatTensor<Self>,
        regions: FloatTensor<Self>,
        materials: FloatTensor<Self>,
        env: FloatTensor<Self>,
        table: FloatTensor<Self>,
    ) -> FloatTensor<Self>;

    /// (∂l/∂n, ∂l/∂m, ∂l/∂L) given ∂l/∂I.
    #[fusion(meta = vjp_meta)]
    fn rendering_layer_vjp(
        normals: FloatTensor<Self>,
        regions: FloatTensor<Self>,
        materials: FloatTensor<Self>,
        env: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

/// The VJP's outputs have the shapes of n, m and L.
fn vjp_meta(
    normals: &TensorSpec,
    _regions: &TensorSpec,
    materials: &TensorSpec,
    env: &TensorSpec,
    _table: &TensorSpec,
    _grad: &TensorSpec,
) -> (TensorSpec, TensorSpec, TensorSpec) {
    (normals.clone(), materials.clone(), env.clone())
}

/// Threads per cube.
const CUBE: u32 = 256;

fn launch_size(client: &cubecl::client::Client, n: usize) -> (CubeCount, CubeDim) {
    let dim = CubeDim::new_1d(CUBE);
    (cubecl::calculate_cube_count_elemwise(client, n, dim), dim)
}

/// The sizes the kernels index with.
struct Sizes {
    pixels: usize,
    texels: usize,
    materials: usize,
}

impl Sizes {
    fn of(normals: &CubeTensor, materials: &CubeTensor, env: &CubeTensor) -> Self {
        let (n, m, e) = (normals.shape(), materials.shape(), env.shape());
        Self {
            pixels: n[2] * n[3],
            texels: e[2] * e[3],
            materials: m[1],
        }
    }
}

/// The per-texel lobes of every material and L·dω, shared by the forward and backward passes.
fn prepare(materials: &CubeTensor, env: &CubeTensor, table: &CubeTensor, s: &Sizes) -> (CubeTensor, CubeTensor) {
    let client = &materials.client;
    let dtype = materials.dtype;
    let images = env.shape()[0];
    let lobes = empty_device_dtype(
        client.clone(),
        materials.device.clone(),
        [images, s.materials, 18, s.texels].into(),
        dtype,
    );
    let lsa = empty_device_dtype(client.clone(), env.device.clone(), [images, 3, s.texels].into(), dtype);
    let (ak, bk) = log_affine(KAPPA_RANGE);
    let (ag, bg) = log_affine(GAMMA_RANGE);
    let (count, dim) = launch_size(client, images * s.materials * 9 * s.texels);
    kernels::lobes_kernel::launch(
        client,
        count,
        dim,
        materials.clone().into_tensor_arg(),
        table.clone().into_tensor_arg(),
        lobes.clone().into_tensor_arg(),
        s.texels,
        ak as f32,
        bk as f32,
        ag as f32,
        bg as f32,
        dtype_to_storage_type(dtype),
    );
    let (count, dim) = launch_size(client, images * 3 * s.texels);
    kernels::light_kernel::launch(
        client,
        count,
        dim,
        env.clone().into_tensor_arg(),
        table.clone().into_tensor_arg(),
        lsa.clone().into_tensor_arg(),
        s.texels,
        MAX_RADIANCE,
        dtype_to_storage_type(dtype),
    );
    (lobes, lsa)
}

impl RenderingLayerBackend for CubeBackend {
    fn rendering_layer(
        normals: CubeTensor,
        regions: CubeTensor,
        materials: CubeTensor,
        env: CubeTensor,
        table: CubeTensor,
    ) -> CubeTensor {
        let [normals, regions, materials, env, table] = [normals, regions, materials, env, table].map(into_contiguous);
        let s = Sizes::of(&normals, &materials, &env);
        let (lobes, lsa) = prepare(&materials, &env, &table, &s);
        let dtype = normals.dtype;
        let client = &normals.client.clone();
        let image = empty_device_dtype(client.clone(), normals.device.clone(), normals.shape(), dtype);
        let (count, dim) = launch_size(client, regions.meta.num_elements());
        kernels::forward_kernel::launch(
            client,
            count,
            dim,
            normals.clone().into_tensor_arg(),
            regions.into_tensor_arg(),
            table.into_tensor_arg(),
            lobes.into_tensor_arg(),
            lsa.into_tensor_arg(),
            image.clone().into_tensor_arg(),
            s.pixels,
            s.texels,
            s.materials,
            dtype_to_storage_type(dtype),
        );
        image
    }

    fn rendering_layer_vjp(
        normals: CubeTensor,
        regions: CubeTensor,
        materials: CubeTensor,
        env: CubeTensor,
        table: CubeTensor,
        grad: CubeTensor,
    ) -> (CubeTensor, CubeTensor, CubeTensor) {
        let [normals, regions, materials, env, table, grad] =
            [normals, regions, materials, env, table, grad].map(into_contiguous);
        let s = Sizes::of(&normals, &materials, &env);
        let (lobes, lsa) = prepare(&materials, &env, &table, &s);
        let dtype = normals.dtype;
        let (client, device) = (&normals.client.clone(), &normals.device.clone());
        let images = env.shape()[0];
        let grad_n = empty_device_dtype(client.clone(), device.clone(), normals.shape(), dtype);
        let grad_m = empty_device_dtype(client.clone(), device.clone(), materials.shape(), dtype);
        let grad_env = empty_device_dtype(client.clone(), device.clone(), env.shape(), dtype);
        let texel_grads = empty_device_dtype(
            client.clone(),
            device.clone(),
            [images, s.materials, 3, kernels::SLOTS, s.texels].into(),
            dtype,
        );
        let (count, dim) = launch_size(client, regions.meta.num_elements());
        kernels::normal_grad_kernel::launch(
            client,
            count,
            dim,
            normals.clone().into_tensor_arg(),
            regions.clone().into_tensor_arg(),
            table.clone().into_tensor_arg(),
            lobes.clone().into_tensor_arg(),
            lsa.clone().into_tensor_arg(),
            grad.clone().into_tensor_arg(),
            grad_n.clone().into_tensor_arg(),
            s.pixels,
            s.texels,
            s.materials,
            dtype_to_storage_type(dtype),
        );
        let (count, dim) = launch_size(client, images * s.materials * 3 * s.texels);
        kernels::texel_grad_kernel::launch(
            client,
            count,
            dim,
            normals.into_tensor_arg(),
            regions.into_tensor_arg(),
            table.clone().into_tensor_arg(),
            lobes.into_tensor_arg(),
            lsa.into_tensor_arg(),
            grad.into_tensor_arg(),
            texel_grads.clone().into_tensor_arg(),
            s.pixels,
            s.texels,
            s.materials,
            dtype_to_storage_type(dtype),
        );
        let (_, bk) = log_affine(KAPPA_RANGE);
        let (_, bg) = log_affine(GAMMA_RANGE);
        let (count, dim) = launch_size(client, materials.meta.num_elements());
        kernels::knot_grad_kernel::launch(
            client,
            count,
            dim,
            materials.into_tensor_arg(),
            table.clone().into_tensor_arg(),
            texel_grads.clone().into_tensor_arg(),
            grad_m.clone().into_tensor_arg(),
            s.texels,
            bk as f32,
            bg as f32,
            dtype_to_storage_type(dtype),
        );
        let (count, dim) = launch_size(client, env.meta.num_elements());
        kernels::env_grad_kernel::launch(
            client,
            count,
            dim,
            env.into_tensor_arg(),
            table.into_tensor_arg(),
            texel_grads.into_tensor_arg(),
            grad_env.clone().into_tensor_arg(),
            s.texels,
            s.materials,
            MAX_RADIANCE,
            dtype_to_storage_type(dtype),
        );
        (grad_n, grad_m, grad_env)
    }
}

/// Under autodiff: the forward pass on the inner backend, and a backward that runs the VJP
/// kernels and hands each tracked input its gradient.
impl<B: RenderingLayerBackend, C: CheckpointStrategy> RenderingLayerBackend for Autodiff<B, C> {
    fn rendering_layer(
        normals: FloatTensor<Self>,
        regions: FloatTensor<Self>,
        materials: FloatTensor<Self>,
        env: FloatTensor<Self>,
        table: FloatTensor<Self>,
    ) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct LayerBackward;

        /// n, region map, m, L and the texel table, on the inner backend.
        type State<B> = [FloatTensor<B>; 5];

        impl<B: RenderingLayerBackend> Backward<B, 3> for LayerBackward {
            type State = State<B>;

            fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
                let [node_n, node_m, node_l] = ops.parents;
                let grad = grads.consume::<B>(&ops.node);
                let [n, r, m, l, t] = ops.state;
                let (gn, gm, gl) = B::rendering_layer_vjp(n, r, m, l, t, grad);
                for (node, g) in [(node_n, gn), (node_m, gm), (node_l, gl)] {
                    if let Some(node) = node {
                        grads.register::<B>(node.id, g);
                    }
                }
            }
        }

        let parents = [normals.node(), materials.node(), env.node()];
        match LayerBackward.prepare::<C>(parents).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let state = [
                    normals.primitive().clone(),
                    regions.into_primitive(),
                    materials.primitive().clone(),
                    env.primitive().clone(),
                    table.into_primitive(),
                ];
                let [n, r, m, l, t] = state.clone();
                prep.finish(state, B::rendering_layer(n, r, m, l, t))
            }
            OpsKind::UnTracked(prep) => prep.finish(B::rendering_layer(
                normals.into_primitive(),
                regions.into_primitive(),
                materials.into_primitive(),
                env.into_primitive(),
                table.into_primitive(),
            )),
        }
    }

    fn rendering_layer_vjp(
        normals: FloatTensor<Self>,
        regions: FloatTensor<Self>,
        materials: FloatTensor<Self>,
        env: FloatTensor<Self>,
        table: FloatTensor<Self>,
        grad: FloatTensor<Self>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        // Not differentiated again: the VJP's outputs are constants of the graph.
        let (gn, gm, gl) = B::rendering_layer_vjp(
            normals.into_primitive(),
            regions.into_primitive(),
            materials.into_primitive(),
            env.into_primitive(),
            table.into_primitive(),
            grad.into_primitive(),
        );
        (Self::from_inner(gn), Self::from_inner(gm), Self::from_inner(gl))
    }
}

/// The rendering layer for one environment resolution on one CubeCL device.
#[derive(Clone, Debug)]
pub struct DeviceLayer {
    height: usize,
    /// `[9, T]`: ω_i, h, dω, knot segment, knot weight.
    table: BTensor<2>,
}

impl DeviceLayer {
    /// The layer for `2·env_height × env_height` maps, its constants uploaded to `device`.
    pub fn new(env_height: usize, device: &Device) -> Self {
        let tex = TexelTable::new(env_height);
        let t = tex.count();
        let mut rows = Vec::with_capacity(kernels::TABLE_ROWS * t);
        for row in tex.w.iter().chain(&tex.h).chain([&tex.sa]) {
            rows.extend_from_slice(&row[..t]);
        }
        rows.extend(tex.seg[..t].iter().map(|&s| s as f32));
        rows.extend_from_slice(&tex.u[..t]);
        let table = BTensor::<2>::from_data(TensorData::new(rows, [kernels::TABLE_ROWS, t]), &device.clone().inner());
        Self {
            height: env_height,
            table,
        }
    }

    /// The region map as floats and the texel table, on `device` (untracked under autodiff).
    fn constants(&self, region_map: &[u8], shape: [usize; 3], device: &Device) -> (BTensor<3>, BTensor<2>) {
        let map: Vec<f32> = region_map.iter().map(|&r| r as f32).collect();
        let map = BTensor::<3>::from_data(TensorData::new(map, shape), device);
        let table = if device.is_autodiff() {
            BTensor::from_inner(self.table.clone())
        } else {
            self.table.clone()
        };
        (map, table)
    }

    /// The environment height the layer was built for.
    pub fn env_height(&self) -> usize {
        self.height
    }

    /// I = R(n, m, L) for `normals` `[B, 3, H, W]`, the region map `[B, H, W]` (0 = background,
    /// r = material r − 1), `materials` `[B, R, 108]` and `env` `[B, 3, He, 2He]`, tracked by
    /// autodiff through whichever inputs require a gradient.
    pub fn render(
        &self,
        normals: BTensor<4>,
        region_map: &[u8],
        materials: BTensor<3>,
        env: BTensor<4>,
    ) -> Result<BTensor<4>, RenderError> {
        let [batch, _, h, w] = normals.dims();
        let [mb, regions, params] = materials.dims();
        let [eb, _, eh, ew] = env.dims();
        let shape = RenderError::expect;
        shape(
            "region map",
            format!("[{batch}, {h}, {w}]"),
            batch * h * w,
            region_map.len(),
        )?;
        shape(
            "materials",
            format!("[{batch}, {regions}, {PARAMS}]"),
            batch * regions * PARAMS,
            mb * regions * params,
        )?;
        if eh != self.height || ew != 2 * self.height {
            return Err(RenderError::EnvHeight {
                layer: self.height,
                got: eh,
            });
        }
        shape("environment", format!("[{batch}, 3, {eh}, {ew}]"), batch, eb)?;
        let p = h * w;
        if let Some((i, &r)) = region_map.iter().enumerate().find(|(_, r)| **r as usize > regions) {
            return Err(RenderError::Region {
                image: i / p.max(1),
                pixel: i % p.max(1),
                region: r,
                regions,
            });
        }
        let device = normals.device();
        let (map, table) = self.constants(region_map, [batch, h, w], &device);
        Ok(BTensor::from_dispatch(Dispatch::rendering_layer(
            normals.into_dispatch(),
            map.into_dispatch(),
            materials.into_dispatch(),
            env.into_dispatch(),
            table.into_dispatch(),
        )))
    }

    /// (∂l/∂n, ∂l/∂m, ∂l/∂L) for ∂l/∂I = `grad`, on the device (no autodiff).
    pub fn vjp(
        &self,
        normals: BTensor<4>,
        region_map: &[u8],
        materials: BTensor<3>,
        env: BTensor<4>,
        grad: BTensor<4>,
    ) -> (BTensor<4>, BTensor<3>, BTensor<4>) {
        let [batch, _, h, w] = normals.dims();
        let (map, table) = self.constants(region_map, [batch, h, w], &normals.device());
        let (gn, gm, gl) = Dispatch::rendering_layer_vjp(
            normals.into_dispatch(),
            map.into_dispatch(),
            materials.into_dispatch(),
            env.into_dispatch(),
            table.into_dispatch(),
            grad.into_dispatch(),
        );
        (
            BTensor::from_dispatch(gn),
            BTensor::from_dispatch(gm),
            BTensor::from_dispatch(gl),
        )
    }
}

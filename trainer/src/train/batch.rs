//! A training batch on a Burn device. The batch in host memory is the data pipeline's
//! [`Batch`](crate::data::Batch) (Fig. 2's tuple I, O, n, mask, regions, m, m_t, L, stacked).

use crate::data::Batch;
use crate::model::prediction::region_masks;
use burn::tensor::{Device, Tensor, TensorData};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// The batch as tensors on a device (none of them tracked).
pub struct TensorBatch {
    /// I.
    pub input: Tensor<4>,
    /// O.
    pub target: Tensor<4>,
    /// n.
    pub normals: Tensor<4>,
    /// `[B, 1, S, S]`.
    pub mask: Tensor<4>,
    /// `[B, R, S, S]`, 1 inside each region.
    pub region_masks: Tensor<4>,
    /// L.
    pub env: Tensor<4>,
    /// m.
    pub materials: Tensor<3>,
    /// m_t.
    pub target_materials: Tensor<3>,
}

impl Batch {
    /// Uploads the batch.
    pub fn to_device(&self, device: &Device) -> TensorBatch {
        let (b, s, r, he) = (self.batch, self.size, self.regions, self.env_height);
        let t4 = |v: &[f32], c: usize, h: usize, w: usize| {
            Tensor::<4>::from_data(TensorData::new(v.to_vec(), [b, c, h, w]), device)
        };
        let t3 = |v: &[f32]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [b, r, PARAMS]), device);
        let rm = region_masks(&self.region_map, b, r, s * s);
        TensorBatch {
            input: t4(&self.input, 3, s, s),
            target: t4(&self.target, 3, s, s),
            normals: t4(&self.normals, 3, s, s),
            mask: t4(&self.mask, 1, s, s),
            region_masks: t4(&rm, r, s, s),
            env: t4(&self.env, 3, he, 2 * he),
            materials: t3(&self.materials),
            target_materials: t3(&self.target_materials),
        }
    }
}

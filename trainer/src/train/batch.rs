//! A training batch in host memory and on a Burn device.

use burn::tensor::{Device, Tensor, TensorData};
use matedit_physics::brdf::dsbrdf::PARAMS;

/// One batch of training tuples (Fig. 2: I, O, n, mask, regions, m, m_t, L), channel-first.
#[derive(Clone, Debug, Default)]
pub struct HostBatch {
    /// Samples.
    pub batch: usize,
    /// Image side.
    pub size: usize,
    /// Material regions per sample (padded to the batch's largest).
    pub regions: usize,
    /// Environment height.
    pub env_height: usize,
    /// Sample ids.
    pub ids: Vec<String>,
    /// Input images I `[B, 3, S, S]`.
    pub input: Vec<f32>,
    /// Target images O `[B, 3, S, S]`.
    pub target: Vec<f32>,
    /// Unit camera-space normals `[B, 3, S, S]`.
    pub normals: Vec<f32>,
    /// Object mask `[B, S, S]`.
    pub mask: Vec<f32>,
    /// Region map `[B, S, S]`, 0 = background, r = material r − 1.
    pub region_map: Vec<u8>,
    /// Camera-space environment `[B, 3, He, 2He]`.
    pub env: Vec<f32>,
    /// Normalised materials m `[B, R, 108]`.
    pub materials: Vec<f32>,
    /// Normalised target materials m_t `[B, R, 108]`.
    pub target_materials: Vec<f32>,
}

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

impl HostBatch {
    /// Uploads the batch.
    pub fn to_device(&self, device: &Device) -> TensorBatch {
        let (b, s, r, he) = (self.batch, self.size, self.regions, self.env_height);
        let t4 = |v: &[f32], c: usize, h: usize, w: usize| {
            Tensor::<4>::from_data(TensorData::new(v.to_vec(), [b, c, h, w]), device)
        };
        let t3 = |v: &[f32]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [b, r, PARAMS]), device);
        let p = s * s;
        let mut rm = vec![0.0f32; b * r * p];
        for i in 0..b {
            for k in 0..p {
                let reg = self.region_map[i * p + k] as usize;
                if reg > 0 && reg <= r {
                    rm[(i * r + reg - 1) * p + k] = 1.0;
                }
            }
        }
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

impl From<crate::data::Batch> for HostBatch {
    fn from(b: crate::data::Batch) -> Self {
        Self {
            batch: b.batch,
            size: b.size,
            regions: b.regions,
            env_height: b.env_height,
            ids: b.ids,
            input: b.input,
            target: b.target,
            normals: b.normals,
            mask: b.mask,
            region_map: b.region_map,
            env: b.env,
            materials: b.materials,
            target_materials: b.target_materials,
        }
    }
}

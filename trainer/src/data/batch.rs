//! Samples stacked into channel-first batch buffers: Fig. 2's tuple for B samples in host memory,
//! what training, evaluation and the benchmarks take, and the same tuple as tensors on a Burn
//! device ([`TensorBatch`]).

use super::sample::Sample;
use crate::model::prediction::region_masks;
use anyhow::{Result, bail};
use burn::tensor::{Device, Tensor, TensorData};
use matedit_physics::brdf::dsbrdf::PARAMS;
use std::path::PathBuf;

/// A batch of B samples, stacked channel-first.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Batch {
    /// Samples B.
    pub batch: usize,
    /// Image side S.
    pub size: usize,
    /// Material regions R: the largest region count of the batch's samples.
    pub regions: usize,
    /// Environment height He (width 2He).
    pub env_height: usize,
    /// Sample ids.
    pub ids: Vec<String>,
    /// Stream position of each sample (see [`Loader`](super::Loader)).
    pub positions: Vec<u64>,
    /// The stream position after this batch: where a resumed loader continues.
    pub next_position: u64,
    /// Regions of each sample before padding.
    pub region_counts: Vec<usize>,
    /// Input images I `[B, 3, S, S]`.
    pub input: Vec<f32>,
    /// Target images O `[B, 3, S, S]`.
    pub target: Vec<f32>,
    /// Unit, facing camera-space normals `[B, 3, S, S]` (zero off the mask).
    pub normals: Vec<f32>,
    /// Object mask `[B, S, S]`.
    pub mask: Vec<f32>,
    /// Region map `[B, S, S]`: 0 = background, r = material r − 1 (never a padded material).
    pub region_map: Vec<u8>,
    /// Camera-space environments `[B, 3, He, 2He]`.
    pub env: Vec<f32>,
    /// Normalised materials m `[B, R, 108]`; a sample with fewer regions repeats its last one.
    pub materials: Vec<f32>,
    /// Normalised target materials m_t `[B, R, 108]`, padded like `materials`.
    pub target_materials: Vec<f32>,
    /// Non-finite file values replaced by 0, summed over the samples.
    pub sanitized: usize,
    /// Covered pixels taken out of the masks (unshadeable normals), summed over the samples.
    pub dropped: usize,
    /// Corrupt samples passed over while this batch was assembled (`OnCorrupt::Skip`).
    pub skipped: Vec<Skipped>,
}

impl Batch {
    /// Stacks samples (all of one image and environment size) at the given stream positions.
    pub fn stack(samples: &[Sample], positions: &[u64], next_position: u64) -> Result<Batch> {
        Self::stack_with_regions(samples, positions, next_position, 1)
    }

    /// [`Batch::stack`] with at least `regions` material regions (a part of a batch padded to
    /// the whole batch's count).
    pub fn stack_with_regions(
        samples: &[Sample],
        positions: &[u64],
        next_position: u64,
        regions: usize,
    ) -> Result<Batch> {
        let Some(first) = samples.first() else {
            bail!("cannot stack an empty batch");
        };
        if positions.len() != samples.len() {
            bail!("{} positions for {} samples", positions.len(), samples.len());
        }
        let (size, env_height) = (first.size, first.env_height);
        for s in samples {
            if s.size != size || s.env_height != env_height {
                bail!(
                    "sample {} is {}² with a {}-row environment, sample {} is {size}² with {env_height} rows: \
                     one batch needs one size",
                    s.id,
                    s.size,
                    s.env_height,
                    first.id
                );
            }
        }
        let regions = samples.iter().map(Sample::region_count).max().unwrap_or(1).max(regions);
        let b = samples.len();
        let (p, t) = (size * size, 2 * env_height * env_height);
        let mut out = Batch {
            batch: b,
            size,
            regions,
            env_height,
            ids: samples.iter().map(|s| s.id.clone()).collect(),
            positions: positions.to_vec(),
            next_position,
            region_counts: samples.iter().map(Sample::region_count).collect(),
            input: Vec::with_capacity(b * 3 * p),
            target: Vec::with_capacity(b * 3 * p),
            normals: Vec::with_capacity(b * 3 * p),
            mask: Vec::with_capacity(b * p),
            region_map: Vec::with_capacity(b * p),
            env: Vec::with_capacity(b * 3 * t),
            materials: Vec::with_capacity(b * regions * PARAMS),
            target_materials: Vec::with_capacity(b * regions * PARAMS),
            sanitized: 0,
            dropped: 0,
            skipped: Vec::new(),
        };
        for s in samples {
            out.input.extend_from_slice(&s.input);
            out.target.extend_from_slice(&s.target);
            out.normals.extend_from_slice(&s.normals);
            out.mask.extend_from_slice(&s.mask);
            out.region_map.extend_from_slice(&s.regions);
            out.env.extend_from_slice(&s.env);
            pad(&mut out.materials, &s.materials, regions);
            pad(&mut out.target_materials, &s.target_materials, regions);
            out.sanitized += s.sanitized;
            out.dropped += s.dropped;
        }
        Ok(out)
    }
}

/// Appends `mats` and repeats the last one up to `regions`: a padded slot then holds a real
/// material (finite, in range) that no pixel refers to, so it adds nothing to any loss.
fn pad(out: &mut Vec<f32>, mats: &[[f32; PARAMS]], regions: usize) {
    for m in mats {
        out.extend_from_slice(m);
    }
    if let Some(last) = mats.last() {
        for _ in mats.len()..regions {
            out.extend_from_slice(last);
        }
    }
}

/// A sample left out under [`OnCorrupt::Skip`](super::OnCorrupt::Skip).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Skipped {
    /// Sample id.
    pub id: String,
    /// Stream position where it was met.
    pub position: u64,
    /// The offending file.
    pub file: PathBuf,
    /// What is wrong with it.
    pub reason: String,
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

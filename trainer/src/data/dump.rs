//! `trainer dump-batch`: samples of a split as the trainer's [`Batch`] holds them, written as a
//! safetensors file, so that another reader (the Python package in `python/`) can be checked
//! against the trainer value for value.
//!
//! Tensor names are the [`Batch`] fields: `input`, `target`, `normals` `[B, 3, S, S]` f32,
//! `mask` `[B, S, S]` f32, `region_map` `[B, S, S]` u8, `env` `[B, 3, He, 2He]` f32, `materials`,
//! `target_materials` `[B, R, 108]` f32. The metadata holds `ids` and `region_counts` (JSON).

use super::{Batch, Dataset};
use anyhow::{Context, Result, bail};
use matedit_physics::brdf::dsbrdf::PARAMS;
use safetensors::Dtype;
use safetensors::tensor::TensorView;
use std::collections::HashMap;
use std::path::Path;

/// Stacks `count` samples of `split` from index position `first` (checksums verified) and writes
/// them to `out`. Returns the ids written.
pub fn dump_batch(dir: &Path, split: &str, first: usize, count: usize, out: &Path) -> Result<Vec<String>> {
    let ds = Dataset::open(dir)?;
    let Some(records) = ds.split(split) else {
        bail!(
            "{}: no split {split:?} (it has {})",
            dir.join("dataset.json").display(),
            ds.split_names().join(", ")
        );
    };
    let end = first.checked_add(count).filter(|&e| e <= records.len() && count > 0);
    let Some(end) = end else {
        bail!(
            "--first {first} --count {count}: split {split} has {} samples",
            records.len()
        );
    };
    let samples = records[first..end]
        .iter()
        .map(|r| ds.load(r, true))
        .collect::<Result<Vec<_>>>()?;
    let positions: Vec<u64> = (first as u64..end as u64).collect();
    let batch = Batch::stack(&samples, &positions, end as u64)?;
    let bytes = serialize(&batch)?;
    matedit_contract::io::write_atomically(out, |t| Ok(std::fs::write(t, &bytes)?))
        .with_context(|| format!("cannot write {}", out.display()))?;
    Ok(batch.ids)
}

/// The batch as safetensors bytes.
fn serialize(b: &Batch) -> Result<Vec<u8>> {
    let (n, s, r, he) = (b.batch, b.size, b.regions, b.env_height);
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let tensors: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = vec![
        ("input", Dtype::F32, vec![n, 3, s, s], f32s(&b.input)),
        ("target", Dtype::F32, vec![n, 3, s, s], f32s(&b.target)),
        ("normals", Dtype::F32, vec![n, 3, s, s], f32s(&b.normals)),
        ("mask", Dtype::F32, vec![n, s, s], f32s(&b.mask)),
        ("region_map", Dtype::U8, vec![n, s, s], b.region_map.clone()),
        ("env", Dtype::F32, vec![n, 3, he, 2 * he], f32s(&b.env)),
        ("materials", Dtype::F32, vec![n, r, PARAMS], f32s(&b.materials)),
        (
            "target_materials",
            Dtype::F32,
            vec![n, r, PARAMS],
            f32s(&b.target_materials),
        ),
    ];
    let views = tensors
        .iter()
        .map(|(name, dtype, shape, data)| Ok((*name, TensorView::new(*dtype, shape.clone(), data)?)))
        .collect::<Result<Vec<_>>>()?;
    let metadata = HashMap::from([
        ("ids".to_string(), serde_json::to_string(&b.ids)?),
        ("region_counts".to_string(), serde_json::to_string(&b.region_counts)?),
    ]);
    Ok(safetensors::serialize(views, Some(metadata))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Sample;

    fn sample(id: &str, regions: usize, fill: f32) -> Sample {
        let (s, he) = (2, 1);
        Sample {
            id: id.into(),
            split: "test".into(),
            category: "car".into(),
            shape_id: "s".into(),
            size: s,
            input: vec![fill; 3 * s * s],
            target: vec![fill + 1.0; 3 * s * s],
            normals: vec![0.0; 3 * s * s],
            mask: vec![1.0, 0.0, 1.0, 0.0],
            regions: vec![1, 0, regions as u8, 0],
            env_height: he,
            env: vec![fill * 2.0; 6 * he * he],
            materials: vec![[fill; PARAMS]; regions],
            target_materials: vec![[-fill; PARAMS]; regions],
            material_ids: vec!["m".into(); regions],
            target_material_ids: vec!["m".into(); regions],
            env_id: "e".into(),
            sanitized: 0,
            dropped: 0,
        }
    }

    #[test]
    fn a_dumped_batch_reads_back_with_its_shapes_values_and_ids() {
        let b = Batch::stack(&[sample("a", 1, 0.25), sample("b", 2, 0.5)], &[0, 1], 2).unwrap();
        let bytes = serialize(&b).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let m = st.tensor("materials").unwrap();
        assert_eq!(m.shape(), [2, 2, PARAMS]);
        let back: Vec<f32> = m
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(back, b.materials, "the padded materials, bit for bit");
        let r = st.tensor("region_map").unwrap();
        assert_eq!((r.dtype(), r.shape()), (Dtype::U8, &[2usize, 2, 2][..]));
        assert_eq!(r.data(), b.region_map.as_slice());
        assert_eq!(st.tensor("env").unwrap().shape(), [2, 3, 1, 2]);
        let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        let meta = meta.metadata().clone().unwrap();
        assert_eq!(meta["ids"], r#"["a","b"]"#);
        assert_eq!(meta["region_counts"], "[1,2]");
    }
}

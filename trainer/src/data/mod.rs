//! The trainer's data pipeline: reads a dataset written by `datagen run` (layout in
//! `manifests/README.md`).
//!
//! * [`Dataset`]: `dataset.json` (splits, material table) and `index.jsonl` (one
//!   [`SampleRecord`] per sample), checked on opening; [`Dataset::load`] decodes one sample;
//! * [`Sample`]: one decoded tuple (I, O, normals, mask, regions, environment, m, m_t);
//! * [`Loader`]: batches in an order that is a pure function of the seed and the stream
//!   position, decoded ahead by background threads, resumable at any position;
//! * [`Batch`]: samples stacked channel-first, materials padded to the batch's largest R.
//!
//! Materials are not stored per sample: a record names its material ids, and the 108
//! normalised parameters of each id come from `dataset.json` → `materials[ID].normalised`
//! (the same values datagen derived from `materials/ID.dsbrdf.json`).

mod batch;
pub mod dump;
pub mod rate;
mod sample;
mod stream;

pub use batch::{Batch, Skipped, TensorBatch};
pub use matedit_contract::records::SampleRecord;
pub use matedit_contract::records::{DatasetRecord, MaterialRecord};
pub use sample::{LoadError, Sample};
pub use stream::{Epochs, Loader, LoaderConfig, OnCorrupt, Part, epoch_order};

use anyhow::{Context, Result, bail};
use matedit_contract::layout::{check_record, read_dataset_record, read_index};
use matedit_contract::records::checksum;
use matedit_physics::brdf::dsbrdf::PARAMS;
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

/// An opened dataset: its description, material table and sample records by split.
#[derive(Clone, Debug)]
pub struct Dataset {
    dir: PathBuf,
    record: DatasetRecord,
    /// Splits in manifest order with their records in index order.
    splits: Vec<(String, Vec<SampleRecord>)>,
    materials: BTreeMap<String, [f32; PARAMS]>,
}

impl Dataset {
    /// Opens the dataset in `dir`: reads `dataset.json` and `index.jsonl` and checks that they
    /// agree (index checksum, splits, counts, unique ids, known materials, one material and
    /// target per region, relative file paths). Errors name the file and, for the index, the
    /// line. Sample files are not read here.
    pub fn open(dir: &Path) -> Result<Dataset> {
        let ds_path = dir.join("dataset.json");
        let record = read_dataset_record(dir)?;

        let mut materials = BTreeMap::new();
        for (id, m) in &record.materials {
            if m.normalised.len() != PARAMS || m.normalised.iter().any(|v| !v.is_finite()) {
                bail!(
                    "{}: material {id}: expected {PARAMS} finite normalised parameters, found {}",
                    ds_path.display(),
                    m.normalised.len()
                );
            }
            materials.insert(id.clone(), std::array::from_fn(|i| m.normalised[i] as f32));
        }

        let index_path = dir.join("index.jsonl");
        let (index, lines) = read_index(dir)?;
        let mut splits: Vec<(String, Vec<SampleRecord>)> = record
            .plan
            .splits
            .iter()
            .map(|s| (s.name.clone(), Vec::new()))
            .collect();
        let mut ids = HashSet::new();
        for (n, rec) in lines {
            let at = || format!("{}:{n}", index_path.display());
            let rec = rec.with_context(|| format!("{}: bad record", at()))?;
            check_record(&rec, |id| materials.contains_key(id))
                .map_err(|e| anyhow::anyhow!("{}: sample {}: {e}", at(), rec.id))?;
            if !ids.insert(rec.id.clone()) {
                bail!("{}: sample id {} appears twice", at(), rec.id);
            }
            let Some((_, list)) = splits.iter_mut().find(|(name, _)| *name == rec.split) else {
                bail!("{}: split {:?} is not in {}", at(), rec.split, ds_path.display());
            };
            list.push(rec);
        }
        // After the records: a bad line is better reported by its number than as a checksum.
        if checksum(&index) != record.index_checksum {
            bail!(
                "{}: checksum differs from {}'s index_checksum (modified or from another run)",
                index_path.display(),
                ds_path.display()
            );
        }
        for (name, list) in &splits {
            let want = record.counts.get(name).copied().unwrap_or(0);
            if list.len() != want {
                bail!(
                    "{}: {} samples of split {name}, {} says {want}",
                    index_path.display(),
                    list.len(),
                    ds_path.display()
                );
            }
        }
        Ok(Dataset {
            dir: dir.to_path_buf(),
            record,
            splits,
            materials,
        })
    }

    /// The dataset's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// `dataset.json` as read (manifest, split membership, material table with raw values).
    pub fn info(&self) -> &DatasetRecord {
        &self.record
    }

    /// Split names in manifest order.
    pub fn split_names(&self) -> Vec<&str> {
        self.splits.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// The records of `split` in index order; empty for an unknown split.
    pub fn records(&self, split: &str) -> &[SampleRecord] {
        self.split(split).unwrap_or(&[])
    }

    /// The records of `split`, or `None` when there is no such split.
    pub fn split(&self, split: &str) -> Option<&[SampleRecord]> {
        self.splits.iter().find(|(n, _)| n == split).map(|(_, v)| v.as_slice())
    }

    /// The same dataset with only the samples of the given categories in every split (all of
    /// them when `categories` is empty): e.g. the paper's Table 2, scored on cars.
    pub fn only_categories(&self, categories: &[String]) -> Dataset {
        let mut d = self.clone();
        if !categories.is_empty() {
            for (_, records) in &mut d.splits {
                records.retain(|r| categories.contains(&r.category));
            }
        }
        d
    }

    /// The normalised parameters of material `id` (`dataset.json` → `materials[id].normalised`).
    pub fn normalised_material(&self, id: &str) -> Option<&[f32; PARAMS]> {
        self.materials.get(id)
    }

    /// Reads and decodes one sample. With `verify`, the blake3 checksum of each file is compared
    /// with the record's first. Errors (missing, truncated, undecodable or modified files) name
    /// the file; they are [`LoadError`]s, reachable with `downcast_ref`.
    pub fn load(&self, record: &SampleRecord, verify: bool) -> Result<Sample> {
        Ok(self.try_load(record, verify)?)
    }

    /// [`Dataset::load`] with the typed error.
    pub fn try_load(&self, record: &SampleRecord, verify: bool) -> Result<Sample, LoadError> {
        let ds_path = self.dir.join("dataset.json");
        let lookup = |ids: &[String]| -> Result<Vec<[f32; PARAMS]>, LoadError> {
            ids.iter()
                .map(|id| {
                    self.materials.get(id).copied().ok_or_else(|| {
                        LoadError::new(
                            &ds_path,
                            format!("material {id} of sample {} is not in the material table", record.id),
                        )
                    })
                })
                .collect()
        };
        let materials = lookup(&record.material_ids)?;
        let target_materials = lookup(&record.target_material_ids)?;
        if materials.len() != record.regions.len() || target_materials.len() != record.regions.len() {
            return Err(LoadError::new(
                &self.dir.join("index.jsonl"),
                format!("sample {}: one material and one target per region expected", record.id),
            ));
        }

        let (image_path, image) = self.read_file(record, "image", verify)?;
        let px = sample::decode_image(&image, record.regions.len()).map_err(|e| LoadError::new(&image_path, e))?;
        let (env_path, env) = self.read_file(record, "env", verify)?;
        let (env_height, env, env_sanitized) = sample::decode_env(&env).map_err(|e| LoadError::new(&env_path, e))?;
        Ok(Sample {
            id: record.id.clone(),
            split: record.split.clone(),
            category: record.category.clone(),
            shape_id: record.shape_id.clone(),
            size: px.size,
            input: px.input,
            target: px.target,
            normals: px.normals,
            mask: px.mask,
            regions: px.regions,
            env_height,
            env,
            materials,
            target_materials,
            material_ids: record.material_ids.clone(),
            target_material_ids: record.target_material_ids.clone(),
            env_id: record.env_id.clone(),
            sanitized: px.sanitized + env_sanitized,
            dropped: px.dropped,
        })
    }

    /// The path of file `key` of a record and its bytes, checked against the record's checksum
    /// when `verify`.
    fn read_file(&self, record: &SampleRecord, key: &str, verify: bool) -> Result<(PathBuf, Vec<u8>), LoadError> {
        let index = self.dir.join("index.jsonl");
        let rel = record
            .files
            .get(key)
            .ok_or_else(|| LoadError::new(&index, format!("sample {}: no {key} file recorded", record.id)))?;
        let path = self.dir.join(rel);
        let bytes = std::fs::read(&path).map_err(|e| LoadError::new(&path, format!("cannot read: {e}")))?;
        if verify {
            let want = record
                .checksums
                .get(key)
                .map(String::as_str)
                .unwrap_or("(none recorded)");
            let got = checksum(&bytes);
            if got != want {
                return Err(LoadError::new(
                    &path,
                    format!("checksum mismatch (corrupt or modified): {got}, the index says {want}"),
                ));
            }
        }
        Ok((path, bytes))
    }
}

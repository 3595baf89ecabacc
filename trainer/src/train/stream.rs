//! The training stream of each stage: its dataset's split, shuffled from the run seed, read
//! in the background and positioned for resume (and, in a data-parallel run, this rank's part
//! of every batch).

use super::manifest::TrainPlan;
use crate::data;
use crate::data::{Dataset, Epochs, Loader, LoaderConfig, OnCorrupt, Part};
use anyhow::{Context, Result, bail};

/// A stream of training batches that can be positioned (for resume).
pub trait BatchSource {
    /// The next batch.
    fn next_batch(&mut self) -> Result<data::Batch>;
    /// Position of the next sample in the stream.
    fn position(&self) -> u64;
    /// What the ranks of a data-parallel run compare before they train on the stream: a
    /// checksum of its dataset, and how to name it.
    fn identity(&self) -> Option<(String, [u8; 32])> {
        None
    }
}

/// Opens the data stream of stage `stage` at `position`, reading `part` of every batch.
pub type OpenStream<'a> = dyn Fn(&TrainPlan, usize, u64, Part) -> Result<Box<dyn BatchSource>> + 'a;

/// The training stream of a stage from its dataset: shuffled from (run seed, stage), endless,
/// decoded in the background, positioned for resume.
pub struct DatasetStream {
    loader: Loader,
    reported: usize,
    identity: (String, [u8; 32]),
}

impl DatasetStream {
    /// Opens stage `stage`'s dataset and split at stream `position` (reading `part` of every
    /// batch), checking that its images and environments have the network's sizes.
    pub fn open(plan: &TrainPlan, stage: usize, position: u64, part: Part) -> Result<Self> {
        let st = plan.manifest.stages[stage].get_ref();
        let dir = plan.stage_dataset(stage)?;
        let dataset = std::sync::Arc::new(Dataset::open(&dir)?);
        let records = dataset.split(&st.split).with_context(|| {
            format!(
                "{}: stage {}: the dataset {} has no split {:?} (splits: {})",
                plan.path().display(),
                st.name,
                dir.display(),
                st.split,
                dataset.split_names().join(", ")
            )
        })?;
        // The first readable sample gives the sizes; under `on_corrupt = "skip"` an unreadable
        // one is passed over here too (the loader skips and reports it when it comes up).
        let mut first = None;
        for r in records {
            match dataset.try_load(r, false) {
                Ok(s) => {
                    first = Some(s);
                    break;
                }
                Err(_) if plan.skip_corrupt => continue,
                Err(e) => return Err(e.into()),
            }
        }
        if let Some(s) = first
            && (s.size != plan.net.input_size || s.env_height != plan.net.env_height)
        {
            bail!(
                "{}: stage {}: the dataset {} has {}² images with {}×{} environments, but [model] asks for \
                 input_size = {} and env_height = {} (set them to the dataset's, or render the dataset at that size)",
                plan.path().display(),
                st.name,
                dir.display(),
                s.size,
                s.env_height,
                2 * s.env_height,
                plan.net.input_size,
                plan.net.env_height
            );
        }
        let d = &plan.manifest.data;
        let seed = blake3::hash(format!("{}/data/{stage}", plan.manifest.run.seed).as_bytes());
        let config = LoaderConfig {
            seed: u64::from_le_bytes(seed.as_bytes()[..8].try_into().unwrap_or([0; 8])),
            shuffle: true,
            shuffle_buffer: d.shuffle_buffer,
            batch_size: st.batch_size,
            workers: d.workers,
            prefetch: 2,
            on_corrupt: if plan.skip_corrupt {
                OnCorrupt::Skip
            } else {
                OnCorrupt::Stop
            },
            verify_checksums: d.verify_checksums,
            epochs: Epochs::Infinite,
            start_position: position,
            part,
        };
        // The dataset's record names its index's checksum: one hash covers both.
        let record = std::fs::read(dir.join("dataset.json"))
            .with_context(|| format!("cannot read {}", dir.join("dataset.json").display()))?;
        let identity = (
            format!("the dataset {}", dir.display()),
            *blake3::hash(&record).as_bytes(),
        );
        Ok(Self {
            loader: Loader::new(dataset, &st.split, config)?,
            reported: 0,
            identity,
        })
    }
}

impl BatchSource for DatasetStream {
    fn next_batch(&mut self) -> Result<data::Batch> {
        let b = self.loader.next_batch().context("the training stream ended")??;
        for s in &self.loader.skipped()[self.reported..] {
            eprintln!(
                "warning: skipped corrupt sample {} ({}: {})",
                s.id,
                s.file.display(),
                s.reason
            );
        }
        self.reported = self.loader.skipped().len();
        Ok(b)
    }

    fn position(&self) -> u64 {
        self.loader.position()
    }

    fn identity(&self) -> Option<(String, [u8; 32])> {
        Some(self.identity.clone())
    }
}

/// [`OpenStream`] over the stages' datasets.
pub fn open_dataset_stream(plan: &TrainPlan, stage: usize, position: u64, part: Part) -> Result<Box<dyn BatchSource>> {
    Ok(Box::new(DatasetStream::open(plan, stage, position, part)?))
}

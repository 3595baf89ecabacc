//! The streaming loader: deterministic order, background decoding, resume, corrupt files.
//!
//! # Order
//!
//! A split of N samples is read as an endless *stream*: stream position `p` is slot `p mod N`
//! of epoch `p / N`'s order ([`epoch_order`]), a pure function of (seed, epoch, N, shuffle,
//! shuffle buffer). With shuffling, an epoch is a Fisher–Yates permutation from a PCG-64 seeded
//! by (seed, epoch), passed through a shuffle buffer with its own seeded generator; every epoch
//! holds each sample exactly once. A batch takes the next `batch_size` usable samples of the
//! stream, so batches may straddle epochs; with [`Epochs::Finite`] the stream ends after the
//! last epoch and the final batch may be short.
//!
//! Worker threads decode the samples of a batch in parallel, but results are put back in stream
//! order before anything is emitted, so the batches depend neither on the worker count nor on
//! timing.
//!
//! # Resume
//!
//! [`Batch::next_position`] (also [`Loader::position`] after a batch) is the stream position
//! where the following batch starts. A checkpoint that stores it and a resumed run that starts
//! there (`LoaderConfig::start_position` or [`Loader::seek`]) sees exactly the batches that the
//! uninterrupted run would have seen. While no sample is skipped, batch k starts at position
//! k · batch_size, so [`Loader::skip_to`]`(k)` is the same as iterating k batches; a skipped
//! sample shifts later batches by one, which only the stored position accounts for.
//!
//! # Corrupt files
//!
//! With [`OnCorrupt::Stop`], a sample that cannot be read ends the stream with its
//! [`LoadError`] (naming the file) in place of the batch that would hold it. With
//! [`OnCorrupt::Skip`], it is left out, recorded in that batch's [`Batch::skipped`] and in
//! [`Loader::skipped`], and never read again by this loader; the remaining samples keep their
//! order.

use super::Dataset;
use super::batch::{Batch, Skipped};
use super::sample::{LoadError, Sample};
use anyhow::{Context, Result, anyhow, bail};
use rand_core::Rng;
use rand_pcg::Pcg64;
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

/// What the loader does with a sample whose files are missing, truncated, undecodable or (with
/// checksum verification) modified.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OnCorrupt {
    /// End the stream with an error naming the file.
    #[default]
    Stop,
    /// Leave the sample out and report it.
    Skip,
}

impl matedit_contract::manifest::Named for OnCorrupt {
    const NAMES: &'static [(&'static str, Self)] = &[("stop", OnCorrupt::Stop), ("skip", OnCorrupt::Skip)];
}

/// How long the stream runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Epochs {
    /// This many passes over the split, then the end.
    Finite(u64),
    /// For ever (training runs stop by step count).
    Infinite,
}

/// A loader's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LoaderConfig {
    /// Seed of the order.
    pub seed: u64,
    /// Whether epochs are shuffled; without, every epoch is the index order.
    pub shuffle: bool,
    /// Shuffle buffer size on top of the epoch permutation (0 or 1: none). Changes the order.
    pub shuffle_buffer: usize,
    /// Samples per batch (≥ 1).
    pub batch_size: usize,
    /// Background decoding threads; 0 decodes in the calling thread, on demand.
    pub workers: usize,
    /// Batches decoded ahead of the consumer (with `workers` ≥ 1).
    pub prefetch: usize,
    /// What to do with corrupt samples.
    pub on_corrupt: OnCorrupt,
    /// Recompute each file's blake3 checksum before decoding it.
    pub verify_checksums: bool,
    /// Length of the stream.
    pub epochs: Epochs,
    /// Stream position of the first sample (resume; see the module documentation).
    pub start_position: u64,
    /// Which part of every batch this loader reads (a rank's slice in data-parallel training).
    pub part: Part,
}

/// Part `index` of `of` of every batch: its samples `index·n/of .. (index+1)·n/of` of a batch
/// of n, in stream order. The other parts are never decoded. A batch read in parts has the
/// region count of the whole batch (the largest of its records'), so that the parts stack
/// into tensors of the whole batch's shape. Corrupt samples cannot be skipped then (a part
/// cannot know that another part's sample is unreadable, and the batches would drift apart).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    /// This part, 0 ≤ index < of.
    pub index: usize,
    /// Parts per batch.
    pub of: usize,
}

impl Part {
    /// The whole batch.
    pub const WHOLE: Part = Part { index: 0, of: 1 };
}

impl LoaderConfig {
    /// Training: shuffled, endless, decoded ahead by up to 4 threads, stopping on corrupt files.
    pub fn training(seed: u64, batch_size: usize) -> Self {
        Self {
            seed,
            shuffle: true,
            shuffle_buffer: 64,
            batch_size,
            workers: default_workers(),
            prefetch: 2,
            on_corrupt: OnCorrupt::Stop,
            verify_checksums: false,
            epochs: Epochs::Infinite,
            start_position: 0,
            part: Part::WHOLE,
        }
    }

    /// Evaluation: one pass in index order with verified checksums; the last batch may be short.
    pub fn evaluation(batch_size: usize) -> Self {
        Self {
            seed: 0,
            shuffle: false,
            shuffle_buffer: 0,
            batch_size,
            workers: default_workers(),
            prefetch: 2,
            on_corrupt: OnCorrupt::Stop,
            verify_checksums: true,
            epochs: Epochs::Finite(1),
            start_position: 0,
            part: Part::WHOLE,
        }
    }
}

fn default_workers() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().min(4))
}

/// Domain-separated generator for one (seed, epoch, purpose): hashing keeps nearby seeds and
/// epochs from giving correlated PCG states.
fn order_rng(seed: u64, epoch: u64, purpose: &[u8]) -> Pcg64 {
    let mut h = blake3::Hasher::new();
    h.update(b"matedit-trainer/data/order/");
    h.update(purpose);
    h.update(&seed.to_le_bytes());
    h.update(&epoch.to_le_bytes());
    let bytes = h.finalize();
    let b = bytes.as_bytes();
    let (mut state, mut stream) = ([0u8; 16], [0u8; 16]);
    state.copy_from_slice(&b[..16]);
    stream.copy_from_slice(&b[16..]);
    Pcg64::new(u128::from_le_bytes(state), u128::from_le_bytes(stream))
}

/// Uniform in `0..n` (n ≥ 1) without modulo bias (Lemire's method).
fn below(rng: &mut Pcg64, n: usize) -> usize {
    let n = n as u64;
    let threshold = n.wrapping_neg() % n;
    loop {
        let m = rng.next_u64() as u128 * n as u128;
        if m as u64 >= threshold {
            return (m >> 64) as usize;
        }
    }
}

/// The order of epoch `epoch` over `n` samples: indices into the split's records.
pub fn epoch_order(n: usize, seed: u64, epoch: u64, shuffle: bool, shuffle_buffer: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n).collect();
    if !shuffle || n < 2 {
        return order;
    }
    let mut rng = order_rng(seed, epoch, b"permutation");
    for i in (1..n).rev() {
        order.swap(i, below(&mut rng, i + 1));
    }
    if shuffle_buffer < 2 {
        return order;
    }
    let mut rng = order_rng(seed, epoch, b"buffer");
    let mut buf = Vec::with_capacity(shuffle_buffer);
    let mut out = Vec::with_capacity(n);
    for k in order {
        if buf.len() < shuffle_buffer {
            buf.push(k);
            continue;
        }
        let j = below(&mut rng, buf.len());
        out.push(std::mem::replace(&mut buf[j], k));
    }
    while !buf.is_empty() {
        let j = below(&mut rng, buf.len());
        out.push(buf.swap_remove(j));
    }
    out
}

/// What the producer hands to the consumer.
enum Item {
    Batch(Box<Batch>),
    /// The stream ended; samples skipped after the last batch, and the end position.
    End(Vec<Skipped>, u64),
    Error(anyhow::Error),
}

/// Assembles batches in stream order; runs in the loader's thread or in a background thread.
struct Producer {
    dataset: Arc<Dataset>,
    split: String,
    n: u64,
    cfg: LoaderConfig,
    pos: u64,
    end: Option<u64>,
    order: Option<(u64, Vec<usize>)>,
    /// Records found corrupt (Skip), by record index: not read again.
    bad: HashMap<usize, LoadError>,
    pool: Option<rayon::ThreadPool>,
}

impl Producer {
    fn record_at(&mut self, pos: u64) -> usize {
        let epoch = pos / self.n;
        let slot = (pos % self.n) as usize;
        match &self.order {
            Some((e, order)) if *e == epoch => order[slot],
            _ => {
                let c = &self.cfg;
                let order = epoch_order(self.n as usize, c.seed, epoch, c.shuffle, c.shuffle_buffer);
                let k = order[slot];
                self.order = Some((epoch, order));
                k
            }
        }
    }

    fn next_item(&mut self) -> Item {
        match self.assemble() {
            Ok(item) => item,
            Err(e) => Item::Error(e),
        }
    }

    fn assemble(&mut self) -> Result<Item> {
        if self.cfg.part != Part::WHOLE {
            return self.assemble_part();
        }
        let b = self.cfg.batch_size;
        let mut samples: Vec<Sample> = Vec::with_capacity(b);
        let mut positions = Vec::with_capacity(b);
        let mut skipped = Vec::new();
        while samples.len() < b {
            let left = self.end.map_or(u64::MAX, |e| e.saturating_sub(self.pos));
            let take = ((b - samples.len()) as u64).min(left);
            if take == 0 {
                break;
            }
            let jobs: Vec<(u64, usize)> = (self.pos..self.pos + take).map(|p| (p, self.record_at(p))).collect();
            self.pos += take;
            let records = self.dataset.records(&self.split);
            let (ds, bad, verify) = (&*self.dataset, &self.bad, self.cfg.verify_checksums);
            let decode = |&(_, k): &(u64, usize)| match bad.get(&k) {
                Some(e) => Err(e.clone()),
                None => ds.try_load(&records[k], verify),
            };
            let results: Vec<Result<Sample, LoadError>> = match &self.pool {
                Some(pool) => pool.install(|| jobs.par_iter().map(decode).collect()),
                None => jobs.iter().map(decode).collect(),
            };
            for ((p, k), r) in jobs.into_iter().zip(results) {
                match r {
                    Ok(s) => {
                        samples.push(s);
                        positions.push(p);
                    }
                    Err(e) if self.cfg.on_corrupt == OnCorrupt::Skip => {
                        skipped.push(Skipped {
                            id: records[k].id.clone(),
                            position: p,
                            file: e.file.clone(),
                            reason: e.reason.clone(),
                        });
                        self.bad.insert(k, e);
                    }
                    Err(e) => return Err(anyhow::Error::new(e)),
                }
            }
            if self.bad.len() as u64 >= self.n {
                bail!(
                    "every sample of split {} is corrupt (skipped {})",
                    self.split,
                    self.bad.len()
                );
            }
        }
        if samples.is_empty() {
            return Ok(Item::End(skipped, self.pos));
        }
        let mut batch = Batch::stack(&samples, &positions, self.pos)?;
        batch.skipped = skipped;
        Ok(Item::Batch(Box::new(batch)))
    }
}

impl Producer {
    /// The next batch's part `cfg.part` (see [`Part`]): the whole batch's positions, this
    /// part's samples decoded, padded to the whole batch's region count.
    fn assemble_part(&mut self) -> Result<Item> {
        let left = self.end.map_or(u64::MAX, |e| e.saturating_sub(self.pos));
        let n = (self.cfg.batch_size as u64).min(left) as usize;
        let Part { index, of } = self.cfg.part;
        let (a, e) = crate::parallel::share::slice_of(index, of, n);
        let whole: Vec<(u64, usize)> = (self.pos..self.pos + n as u64)
            .map(|p| (p, self.record_at(p)))
            .collect();
        self.pos += n as u64;
        if a == e {
            return Ok(Item::End(Vec::new(), self.pos));
        }
        let records = self.dataset.records(&self.split);
        let regions = whole
            .iter()
            .map(|&(_, k)| records[k].material_ids.len())
            .max()
            .unwrap_or(1);
        let jobs = &whole[a..e];
        let (ds, verify) = (&*self.dataset, self.cfg.verify_checksums);
        let decode = |&(_, k): &(u64, usize)| ds.try_load(&records[k], verify);
        let results: Vec<Result<Sample, LoadError>> = match &self.pool {
            Some(pool) => pool.install(|| jobs.par_iter().map(decode).collect()),
            None => jobs.iter().map(decode).collect(),
        };
        let samples = results.into_iter().collect::<Result<Vec<_>, _>>()?;
        let positions: Vec<u64> = jobs.iter().map(|&(p, _)| p).collect();
        let batch = Batch::stack_with_regions(&samples, &positions, self.pos, regions)?;
        Ok(Item::Batch(Box::new(batch)))
    }
}

/// The background thread and its channel; dropping it stops and joins the thread.
struct Background {
    rx: Option<Receiver<Item>>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Drop for Background {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // Dropping the receiver wakes a producer blocked in `send`.
        self.rx.take();
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

enum Source {
    Inline(Box<Producer>),
    Background(Background),
    Done,
}

fn run_producer(mut p: Producer, tx: SyncSender<Item>, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::Relaxed) {
        let item = p.next_item();
        let last = !matches!(item, Item::Batch(_));
        if tx.send(item).is_err() || last {
            break;
        }
    }
}

/// Batches of one split, in a deterministic, resumable order (see the module documentation).
/// An iterator of `Result<Batch>`; after an error or the end of the stream it yields `None`.
pub struct Loader {
    dataset: Arc<Dataset>,
    split: String,
    config: LoaderConfig,
    source: Source,
    position: u64,
    skipped: Vec<Skipped>,
}

impl Loader {
    /// A loader over `split` of `dataset`, starting at `config.start_position`. Errors for an
    /// unknown or empty split, a zero batch size, or when threads cannot be started.
    pub fn new(dataset: Arc<Dataset>, split: &str, config: LoaderConfig) -> Result<Loader> {
        let Some(records) = dataset.split(split) else {
            bail!(
                "{}: no split {split:?} (splits: {})",
                dataset.dir().display(),
                dataset.split_names().join(", ")
            );
        };
        if records.is_empty() {
            bail!("{}: split {split} has no samples", dataset.dir().display());
        }
        if config.batch_size == 0 {
            bail!("batch_size must be at least 1");
        }
        let Part { index, of } = config.part;
        if of == 0 || index >= of {
            bail!("part {index} of {of} of a batch does not exist");
        }
        if of > 1 && config.on_corrupt == OnCorrupt::Skip {
            bail!(
                "corrupt samples cannot be skipped when every batch is read in {of} parts (data-parallel \
                 training): a part cannot know that another part's sample is unreadable (on_corrupt = \"stop\")"
            );
        }
        let start = config.start_position;
        let mut loader = Loader {
            dataset,
            split: split.to_string(),
            config,
            source: Source::Done,
            position: start,
            skipped: Vec::new(),
        };
        loader.seek(start)?;
        Ok(loader)
    }

    /// The settings.
    pub fn config(&self) -> &LoaderConfig {
        &self.config
    }

    /// Samples in one epoch of the split.
    pub fn samples_per_epoch(&self) -> usize {
        self.dataset.records(&self.split).len()
    }

    /// The stream position of the next batch: store it to resume (see the module docs).
    pub fn position(&self) -> u64 {
        self.position
    }

    /// The epoch of the next sample.
    pub fn epoch(&self) -> u64 {
        self.position / self.samples_per_epoch().max(1) as u64
    }

    /// Samples skipped so far as corrupt, once per sample, in the order met.
    pub fn skipped(&self) -> &[Skipped] {
        &self.skipped
    }

    /// Restarts the stream at `position`, dropping anything decoded ahead.
    pub fn seek(&mut self, position: u64) -> Result<()> {
        // Stop the old producer first: two would compete for the cores.
        self.source = Source::Done;
        self.position = position;
        let c = &self.config;
        let n = self.dataset.records(&self.split).len() as u64;
        let pool = if c.workers > 0 {
            Some(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(c.workers)
                    .thread_name(|i| format!("matedit-data-{i}"))
                    .build()
                    .context("cannot start the loader's decoding threads")?,
            )
        } else {
            None
        };
        let producer = Producer {
            dataset: self.dataset.clone(),
            split: self.split.clone(),
            n,
            cfg: c.clone(),
            pos: position,
            end: match c.epochs {
                Epochs::Finite(e) => Some(e.saturating_mul(n)),
                Epochs::Infinite => None,
            },
            order: None,
            bad: HashMap::new(),
            pool,
        };
        if c.workers == 0 {
            self.source = Source::Inline(Box::new(producer));
            return Ok(());
        }
        let (tx, rx) = sync_channel(c.prefetch);
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("matedit-loader".into())
            .spawn(move || run_producer(producer, tx, flag))
            .context("cannot start the loader thread")?;
        self.source = Source::Background(Background {
            rx: Some(rx),
            stop,
            handle: Some(handle),
        });
        Ok(())
    }

    /// Restarts at the start of batch `step` of a run that skipped no sample, i.e. stream
    /// position `step · batch_size` (see the module documentation for runs that skipped some).
    pub fn skip_to(&mut self, step: u64) -> Result<()> {
        self.seek(step.saturating_mul(self.config.batch_size as u64))
    }

    /// The next batch, an error, or `None` at the end of the stream.
    pub fn next_batch(&mut self) -> Option<Result<Batch>> {
        let item = match &mut self.source {
            Source::Done => return None,
            Source::Inline(p) => p.next_item(),
            Source::Background(bg) => match bg.rx.as_ref().map(Receiver::recv) {
                Some(Ok(item)) => item,
                _ => {
                    // The producer ended without a final item: only a panic does that.
                    let panicked = bg.handle.take().map(JoinHandle::join).is_some_and(|r| r.is_err());
                    let why = if panicked { "panicked" } else { "stopped" };
                    Item::Error(anyhow!("the loader thread {why} (split {})", self.split))
                }
            },
        };
        match item {
            Item::Batch(b) => {
                self.position = b.next_position;
                self.note_skipped(&b.skipped);
                Some(Ok(*b))
            }
            Item::End(skipped, position) => {
                self.position = position;
                self.note_skipped(&skipped);
                self.source = Source::Done;
                None
            }
            Item::Error(e) => {
                self.source = Source::Done;
                Some(Err(e))
            }
        }
    }

    fn note_skipped(&mut self, new: &[Skipped]) {
        for s in new {
            if !self.skipped.iter().any(|k| k.id == s.id) {
                self.skipped.push(s.clone());
            }
        }
    }
}

impl Iterator for Loader {
    type Item = Result<Batch>;

    fn next(&mut self) -> Option<Result<Batch>> {
        self.next_batch()
    }
}

//! `trainer bench-loader`: how fast the trainer's [`Loader`] reads a split, one pass in index
//! order as evaluation reads it (checksums verified, decoded ahead by `workers` threads), for
//! comparing readers of one dataset (the Python package's figures are beside it in
//! docs/PERFORMANCE.md).

use super::{Dataset, Loader, LoaderConfig};
use anyhow::Result;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// One timed pass: samples read and seconds taken.
pub fn loader_rate(dir: &Path, split: &str, batch_size: usize, workers: usize, verify: bool) -> Result<(usize, f64)> {
    let ds = Arc::new(Dataset::open(dir)?);
    let config = LoaderConfig {
        workers,
        verify_checksums: verify,
        ..LoaderConfig::evaluation(batch_size)
    };
    let t = Instant::now();
    let mut loader = Loader::new(ds, split, config)?;
    let mut samples = 0;
    while let Some(batch) = loader.next_batch() {
        samples += batch?.batch;
    }
    Ok((samples, t.elapsed().as_secs_f64()))
}

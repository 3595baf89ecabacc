//! `trainer bench-loader`: how fast the trainer's [`Loader`] reads a split, one pass in index
//! order as evaluation reads it (checksums verified, decoded ahead by `workers` threads), for
//! comparing readers of one dataset (the Python package's figures are beside it in
//! docs/PERFORMANCE.md).

use super::{Dataset, Loader, LoaderConfig};
use anyhow::Result;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// `runs` timed passes: the samples of a pass, and each pass's samples per second, slowest first.
pub fn loader_rates(
    dir: &Path,
    split: &str,
    batch_size: usize,
    workers: usize,
    runs: usize,
) -> Result<(usize, Vec<f64>)> {
    let ds = Arc::new(Dataset::open(dir)?);
    let config = LoaderConfig {
        workers,
        verify_checksums: true,
        ..LoaderConfig::evaluation(batch_size)
    };
    let mut samples = 0;
    let mut rates = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = Instant::now();
        let mut loader = Loader::new(ds.clone(), split, config.clone())?;
        samples = 0;
        while let Some(batch) = loader.next_batch() {
            samples += batch?.batch;
        }
        rates.push(samples as f64 / t.elapsed().as_secs_f64().max(1e-9));
    }
    rates.sort_by(f64::total_cmp);
    Ok((samples, rates))
}

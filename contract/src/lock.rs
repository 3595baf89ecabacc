//! Who writes a dataset folder: the worker layout of a run and the lock each worker holds.

use anyhow::{Context, Result, bail};
use std::fs::{File, TryLockError};
use std::path::Path;

/// Which part of the shards a process renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Worker {
    /// This worker, 0-based.
    pub index: usize,
    /// Number of workers.
    pub count: usize,
}

impl Worker {
    /// The whole job.
    pub const ALL: Worker = Worker { index: 0, count: 1 };

    /// Whether shard `ordinal` belongs to this worker (round robin, so every worker gets a mix
    /// of splits and shard sizes).
    pub fn owns(self, ordinal: usize) -> bool {
        ordinal % self.count == self.index
    }
}

impl std::str::FromStr for Worker {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let err = || format!("--worker {s:?}: expected I/N with 0 ≤ I < N (e.g. 3/16)");
        let (i, n) = s.split_once('/').ok_or_else(err)?;
        let (index, count): (usize, usize) = (
            i.trim().parse().map_err(|_| err())?,
            n.trim().parse().map_err(|_| err())?,
        );
        if count == 0 || index >= count {
            return Err(err());
        }
        Ok(Worker { index, count })
    }
}

/// Holds the output directory's lock for this worker layout until dropped.
pub struct OutputLock {
    _file: File,
}

/// Locks `dir` for `worker`. Runs with the same worker count but different indices may share a
/// directory; a second run of the same worker, or any run with a different worker count,
/// is refused while the first holds its lock. The OS releases locks of killed processes.
pub fn lock_output(dir: &Path, worker: Worker) -> Result<OutputLock> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for e in std::fs::read_dir(dir)? {
        let p = e?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(layout) = name.strip_prefix(".lock-") else {
            continue;
        };
        if layout.ends_with(&format!("-of-{}", worker.count)) {
            continue;
        }
        let f = File::open(&p)?;
        if let Err(TryLockError::WouldBlock) = f.try_lock() {
            bail!(
                "{} is being written by a run with another worker layout ({layout}); refusing to start",
                dir.display()
            );
        }
    }
    let p = dir.join(format!(".lock-{}-of-{}", worker.index, worker.count));
    let f = File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&p)
        .with_context(|| format!("cannot open {}", p.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(OutputLock { _file: f }),
        Err(TryLockError::WouldBlock) => bail!(
            "another datagen run is writing {} (worker {}/{}); refusing to start a second one",
            dir.display(),
            worker.index,
            worker.count
        ),
        Err(TryLockError::Error(e)) => Err(e).with_context(|| format!("cannot lock {}", p.display())),
    }
}

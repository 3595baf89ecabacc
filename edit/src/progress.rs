//! Watching and stopping a running edit (`matedit serve`): the phase it is in, Eq. 6's energy
//! after every L-BFGS iteration as it happens (Eq. 6 reports to it as its
//! [`Watcher`]), and a cancel flag checked between phases and, inside Eq. 6, before every
//! evaluation. `matedit edit` passes none.

use matedit_trainer::post_optimisation::watcher::{Cancelled, Watcher};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Shared between the thread that edits and those that watch it.
#[derive(Debug, Default)]
pub struct Progress {
    cancelled: AtomicBool,
    state: Mutex<Snapshot>,
}

/// What a watcher sees.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Snapshot {
    /// The phase running now ("reading", "network", "eq6", "render", "write").
    pub phase: &'static str,
    /// Eq. 6's energy: at the network's prediction, then after every L-BFGS iteration.
    pub energies: Vec<f64>,
}

impl Progress {
    /// Asks the edit to stop at its next check.
    pub fn cancel(&self) {
        self.cancelled.store(true, Ordering::SeqCst);
    }

    /// Enters `phase`, or stops with [`Cancelled`].
    pub fn enter(&self, phase: &'static str) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            return Err(Cancelled);
        }
        if let Ok(mut s) = self.state.lock() {
            s.phase = phase;
        }
        Ok(())
    }

    /// A copy of the state.
    pub fn snapshot(&self) -> Snapshot {
        self.state.lock().map(|s| s.clone()).unwrap_or_default()
    }
}

impl Watcher for Progress {
    fn energy(&self, e: f64) {
        if let Ok(mut s) = self.state.lock() {
            s.energies.push(e);
        }
    }

    fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::SeqCst)
    }
}

/// [`Progress::enter`] on an optional watcher.
pub fn enter(p: Option<&Progress>, phase: &'static str) -> anyhow::Result<()> {
    if let Some(p) = p {
        p.enter(phase)?;
    }
    Ok(())
}

/// Who watches a request and when it began: what `matedit serve` hands each job; the command
/// line's edits are watched by nobody.
#[derive(Clone, Copy, Debug)]
pub struct Watch<'a> {
    /// Shown each phase and Eq. 6's energies; `None` from the command line.
    pub progress: Option<&'a Arc<Progress>>,
    /// When the request began (the report's seconds count from it).
    pub t0: Instant,
}

impl Watch<'_> {
    /// A request that begins now and that nobody watches.
    pub fn unwatched() -> Self {
        Watch {
            progress: None,
            t0: Instant::now(),
        }
    }

    /// [`Progress::enter`], when somebody watches.
    pub fn enter(&self, phase: &'static str) -> anyhow::Result<()> {
        enter(self.progress.map(|p| p.as_ref()), phase)
    }

    /// The watcher as the stages that show a phase take it.
    pub fn progress(&self) -> Option<&Progress> {
        self.progress.map(|p| p.as_ref())
    }
}

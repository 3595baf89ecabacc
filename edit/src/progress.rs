//! Watching and stopping a running edit (`matedit serve`): the phase it is in, Eq. 6's energy
//! after every L-BFGS iteration as it happens (Eq. 6 reports to it as its
//! [`Watcher`]), and a cancel flag checked between phases and, inside Eq. 6, before every
//! evaluation. `matedit edit` passes none.

use matedit_trainer::post_optimisation::watcher::{Cancelled, Watcher};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

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

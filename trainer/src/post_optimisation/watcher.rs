//! Watching and stopping a running post-optimisation (Eq. 6): its energy after every L-BFGS
//! iteration as it happens, and a cancel flag checked before every evaluation. `trainer eval
//! --eq6` and `matedit edit` pass none; the editing page (`matedit serve`) shows the energies
//! live and cancels through its job's progress (`matedit_edit::progress::Progress`).

/// What Eq. 6 reports to while it runs. Shared with the threads that watch it.
pub trait Watcher: Send + Sync {
    /// Eq. 6's energy: at the start, then after every iteration.
    fn energy(&self, e: f64);
    /// Whether to stop at the next check.
    fn is_cancelled(&self) -> bool;
}

/// The error Eq. 6 (and an edit around it) stops with once its watcher cancels.
#[derive(Debug, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

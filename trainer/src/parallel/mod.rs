//! Data-parallel training (not in the paper, which trained on one GPU): `trainer run` as W
//! ranks over MPI, equal to one process within rounding.
//!
//! Every step of a stage takes one *global* batch of `batch_size` samples from the stage's
//! stream (a pure function of the run seed and the stream position). Rank r of W reads and
//! computes samples `r·B/W .. (r+1)·B/W` of it, and the ranks then sum their gradients, so
//! that every rank applies the very update one process would have applied to the whole batch:
//!
//! * [`share`]: the step's slice of the global batch. Each loss is a mean over the global
//!   batch, so a rank's part is its own numerator over the *global* denominator (the masks'
//!   pixel counts are summed across ranks); and dropout draws the global batch's mask and keeps
//!   this rank's rows, so that a sample gets the same mask whichever rank computes it.
//! * [`ranks`]: who is here (one process, or W ranks under `mpirun`/`srun --mpi=pmix`) and the
//!   one small collective everything agrees through, so that a failure on one rank (a corrupt
//!   file, a non-finite loss, a signal) stops every rank the same way and none is left waiting.
//! * [`gradients`]: the gradients flattened in module-visit order into one buffer, summed in
//!   one all-reduce, and put back before the optimiser's step; [`bench`] times that.
//!
//! One process (or an MPI build started without a launcher) never communicates and computes
//! exactly what a build without MPI computes: the same bytes in `metrics.jsonl` and checkpoints.

pub mod bench;
pub mod gradients;
pub mod ranks;
pub mod share;

pub use ranks::Ranks;

//! # matedit-trainer
//!
//! The network of Fig. 2 of the paper and everything around it:
//!
//! * [`data`]: reading the factory's datasets (through `matedit-contract`'s reader and checker);
//! * [`model`]: the normal, material and illumination modules, the network, and Baseline 1's
//!   encoder–decoder;
//! * [`rendering_layer`]: the differentiable rendering layer (Sec. 3.1, Eq. 2; CPU, and GPU kernels
//!   with `wgpu`);
//! * [`device`]: the device a run trains on (by name, per rank) and what wgpu sees of the machine;
//! * [`targets`]: the 108 DSBRDF parameters normalised to the tanh range [−0.95, 0.95]
//!   (Sec. 3.2) and back;
//! * [`train`]: losses (Eq. 5), steps, stages, checkpoints and training manifests;
//! * [`parallel`]: training as several ranks over MPI (data parallelism), equal to one process;
//! * [`metrics`]: the paper's metrics, shared by the losses and the evaluation;
//! * [`post_optimisation`]: the refinement of Sec. 3.5 (Eq. 6);
//! * [`eval`]: Tables 1–3; [`baseline`]: the comparison methods that are not networks;
//! * [`cli`]: the `trainer` command line; [`bench`]: speed of the layer and of training; [`alloc`]: the counting allocator behind
//!   peak-memory figures.
//!
//! It depends on `matedit-physics` and `matedit-contract` only: the factory (meshes, BVHs) and
//! the material library's fitting are not part of its build, not even of its tests'. Editing
//! photos (`matedit`) is the crate `matedit-edit` (`edit/`) built on this one.

#![warn(missing_docs)]

pub mod alloc;
pub mod baseline;
pub mod bench;
pub mod cli;
pub mod data;
pub mod device;
pub mod eval;
pub mod metrics;
pub mod model;
pub mod parallel;
pub mod post_optimisation;
pub mod rendering_layer;
pub mod targets;
pub mod train;

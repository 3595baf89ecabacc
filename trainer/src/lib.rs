//! # matedit-trainer
//!
//! The network of Fig. 2 of the paper and everything around it:
//!
//! * [`data`]: reading the factory's datasets (through `matedit-contract`'s reader and checker);
//! * [`model`]: the normal, material and illumination modules, the network, and Baseline 1's
//!   encoder–decoder;
//! * [`render`]: the differentiable rendering layer (Eq. 2; CPU, and GPU kernels with `wgpu`);
//! * [`targets`]: the 108 DSBRDF parameters normalised to the tanh range [−0.95, 0.95]
//!   (Sec. 3.2) and back;
//! * [`train`]: losses (Eq. 5), steps, stages, checkpoints and training manifests;
//! * [`metrics`]: the paper's metrics, shared by the losses and the evaluation;
//! * [`eval`]: Tables 1–3; [`baseline`]: the comparison methods that are not networks;
//! * [`edit`]: editing photos, material transfer and swap, and the post-optimisation of Eq. 6;
//! * [`serve`]: the editing web page; [`bench`]: speed of the layer and of training;
//!   [`alloc`]: the counting allocator behind peak-memory figures.
//!
//! It depends on `matedit-physics`, `matedit-contract` and `matedit-assets` only; the factory
//! (meshes, BVHs) is not part of its build.

#![warn(missing_docs)]

pub mod alloc;
pub mod baseline;
pub mod bench;
pub mod data;
pub mod edit;
pub mod eval;
pub mod metrics;
pub mod model;
pub mod render;
pub mod serve;
pub mod targets;
pub mod train;

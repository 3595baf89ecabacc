//! # matedit-trainer
//!
//! The network of Fig. 2 of the paper and everything around it: reading the factory's datasets
//! (`data`), the prediction modules and Baseline 1's encoder–decoder (`model`), the
//! differentiable rendering layer (`render`), losses, steps, stages and checkpoints (`train`),
//! the paper's metrics, shared by losses and evaluation (`metrics`), Tables 1–3 (`eval`), the comparison methods that are not networks
//! (`baseline`), editing photos and the post-optimisation of Eq. 6 (`edit`), the editing web page
//! (`serve`), and the material
//! targets (`targets`): the 108 DSBRDF parameters normalised to the tanh range [−0.95, 0.95]
//! (Sec. 3.2) and back.

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

//! # matedit-trainer
//!
//! The trainer of the material-editing network (Fig. 2 of the paper). This first part holds the
//! material targets: the material module predicts the 108 DSBRDF parameters normalised to the
//! tanh range [−0.95, 0.95] (Sec. 3.2), and its outputs map back to raw, renderable materials.
//! The Burn modules, the rendering layer and the training loop build on it.

#![warn(missing_docs)]

pub mod alloc;
pub mod baseline;
pub mod bench;
pub mod data;
pub mod edit;
pub mod eval;
pub mod model;
pub mod render;
pub mod targets;
pub mod train;

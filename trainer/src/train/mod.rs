//! Training: the network, its losses, one step of each stage, and manifest-driven runs with
//! checkpoints and resume.

pub mod checkpoint;
pub mod data_parallel;
pub mod loss;
pub mod manifest;
pub mod plot;
pub mod records;
pub mod run;
pub mod schedule;
pub mod stage_kind;
pub mod step;
pub mod stream;
pub mod synthetic;
#[cfg(test)]
mod tests;
pub mod validation;

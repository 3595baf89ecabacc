//! # matedit-contract
//!
//! What the factory promises the trainer, and the one place both read it from:
//!
//! * [`records`]: the records of a dataset (`index.jsonl`, `shard.json`, `plan.json`,
//!   `dataset.json`) and the `blake3:` checksums that bind them to the files;
//! * [`layout`]: the folder layout, and reading shards and plans;
//! * [`verify`]: the checker behind `datagen verify` (checksums, schema, split integrity);
//! * [`io`]: atomic writes and the file formats (EXR channels and environments, PNG previews and
//!   labelled contact sheets);
//! * [`lock`]: worker layouts and the output folder's locks;
//! * [`manifest`]: the manifest error kit (`FILE:LINE: FIELD: message`) both manifests use;
//! * [`progress`]: progress bars on a terminal, plain progress lines in batch logs.
//!
//! It depends on the physics crate only (for the tone map and environment maps), so the trainer
//! reads datasets without building the factory's meshes, BVHs or fitting.

#![warn(missing_docs)]

pub mod args;
pub mod io;
pub mod layout;
pub mod lock;
pub mod manifest;
pub mod progress;
pub mod records;
pub mod verify;

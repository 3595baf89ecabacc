//! The batch dataset factory: a TOML [manifest] and a seed define a dataset completely.
//!
//! * [`manifest`]: the file format, with errors that name the file, line and field;
//! * [`catalogue`]: every shape, material and environment the manifest's sources provide;
//! * [`content`]: fingerprints of what they are, and groups of identical or near-duplicate
//!   content that the plan deals whole;
//! * [`plan`]: the split deal (no shape or material in two splits), combinations, views,
//!   samples and shards;
//! * [`materials`]: fitted 108-parameter labels and the BRDFs that render them;
//! * [`spec`]: one sample fully described, every random choice made (shape, environment and
//!   its rotation, view, regions, materials and targets);
//! * [`sample`]: one training tuple rendered from its description (I, O, normals, mask, regions, environment);
//! * [`store`]: atomic shards, `index.jsonl`, `dataset.json`, joining workers (the layout,
//!   the records and their readers are the contract: `matedit_contract::{layout, records}`);
//! * [`run`]: `plan` and `run` (locking, resuming, workers);
//! * [`provenance`]: the factory's build and every source's origin and licence, recorded in the
//!   dataset; [`card`]: the dataset card (`README.md`) made from them;
//! * [`webdataset`]: the dataset as WebDataset tar shards (`datagen export --webdataset`);
//! * [`verify`] and [`inspect`]: a dataset's content against its sources (the checks that need
//!   only the files are `matedit_contract::verify`), and looking at a finished dataset;
//! * [`bench`]: speed against error of the shading options on a manifest's samples.

pub mod bench;
pub mod card;
pub mod catalogue;
pub mod content;
pub mod deal;
pub mod inspect;
pub mod manifest;
pub mod materials;
pub mod plan;
pub mod provenance;
pub mod run;
pub mod sample;
pub mod spec;
pub mod store;
pub mod verify;
pub mod webdataset;

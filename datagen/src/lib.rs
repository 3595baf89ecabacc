//! # matedit-datagen
//!
//! The synthetic-dataset factory's library. Its layout follows the scene description:
//!
//! * [`shapes`]: the analytic sphere and triangle meshes (OBJ through tobj), normalised to the
//!   unit ball, with angle-weighted vertex normals where a file has none;
//! * [`accel`]: the obvhs BVH for primary visibility and shadow rays;
//! * [`gbuffer`]: per-pixel camera-space normals, mask and hit points of the orthographic view;
//! * [`preview`]: the one-scene preview renderer behind `datagen render`;
//! * [`dataset`]: the manifest-driven dataset factory behind `datagen plan/run/verify/inspect/join`;
//! * [`cli`]: the `datagen` command line.
//!
//! The image formation itself (Eq. 2, BRDFs, environment maps) lives in `matedit-physics`;
//! what a dataset is on disk (records, layout, checker, file formats, locks) in
//! `matedit-contract` (`contract`); the procedural environment maps and the material
//! library with its fits in `matedit-assets` (`assets`).

#![warn(missing_docs)]

pub mod accel;
pub mod cli;
pub mod dataset;
pub mod gbuffer;
pub mod preview;
pub mod shapes;

//! # matedit-datagen
//!
//! The synthetic-dataset factory's library. Its layout follows the scene description:
//!
//! * [`shapes`]: the analytic sphere and triangle meshes (OBJ through tobj), normalised to the
//!   unit ball, with angle-weighted vertex normals where a file has none;
//! * [`accel`]: the obvhs BVH for primary visibility and shadow rays;
//! * [`gbuffer`]: per-pixel camera-space normals, mask and hit points of the orthographic view;
//! * [`assets`]: embedded default data (procedural environment maps);
//! * [`io`]: environment-map loading (.hdr, .exr), EXR and PNG writing, all writes atomic;
//! * [`render`]: the one-scene preview renderer behind `datagen render`;
//! * [`dataset`]: the manifest-driven dataset factory behind `datagen plan/run/verify/inspect/join`.
//!
//! The image formation itself (Eq. 2, BRDFs, environment maps) lives in `matedit-physics`.

#![warn(missing_docs)]

pub mod accel;
pub mod assets;
pub mod dataset;
pub mod gbuffer;
pub mod io;
pub mod materials;
pub mod progress;
pub mod render;
pub mod shapes;

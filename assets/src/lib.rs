//! # matedit-assets
//!
//! The embedded default data that the factory renders with and the editor offers:
//!
//! * [`envmaps`]: procedural environment maps (two fixed maps and four seeded families);
//! * [`envfile`]: loading environment maps from `.hdr` and `.exr` files or `builtin:NAME`;
//! * [`materials`]: the material library, its DSBRDF fits and their cache;
//! * [`random`]: the seeded draws the generators use.

#![warn(missing_docs)]

pub mod envfile;
pub mod envmaps;
pub mod materials;
pub mod random;

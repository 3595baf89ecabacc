//! Embedded default data, so that every command runs on a fresh machine: procedural environment
//! maps, generated deterministically from a seed.

pub mod envmaps;
pub mod random;

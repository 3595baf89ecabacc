//! Embedded default data, so that every command runs on a fresh machine: procedural environment
//! maps and shapes of the four categories, generated deterministically from a seed.

pub mod envmaps;
pub mod random;
pub mod shapes;

//! Embedded default data, so that every command runs on a fresh machine.

pub mod envmaps;

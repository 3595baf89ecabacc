//! The comparison methods of Table 3 (Sec. 4.5) that are not the network of Fig. 2.
//!
//! * [`lombardi`]: Lombardi & Nishino 2012, an optimiser of material and light given the true
//!   normals, under priors on both.
//!
//! Baseline 2 (three independent networks trained with L2 losses only) is the network of Fig. 2
//! after its `pretrain` stage (with a direct loss on L'): it needs no code of its own.

pub mod lombardi;

//! Seeded randomness for procedural assets: PCG (rand_pcg), so an asset is a pure function of
//! its seed on every platform.

use rand_core::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A seeded generator with the few draws the generators need.
pub struct Draw(Pcg64Mcg);

impl Draw {
    /// Generator for `seed`, decorrelated per `stream` (e.g. one stream per asset kind).
    pub fn new(seed: u64, stream: u64) -> Self {
        Self(Pcg64Mcg::seed_from_u64(
            seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15),
        ))
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let u = (self.0.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        lo + (hi - lo) * u
    }

    /// Log-uniform in [lo, hi) (for quantities spanning orders of magnitude).
    pub fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.uniform(lo.ln(), hi.ln()).exp()
    }

    /// An integer in [lo, hi].
    pub fn int(&mut self, lo: usize, hi: usize) -> usize {
        (lo + (self.uniform(0.0, (hi - lo + 1) as f64) as usize)).min(hi)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform(0.0, 1.0) < p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_deterministic_and_in_range() {
        let (mut a, mut b) = (Draw::new(7, 1), Draw::new(7, 1));
        for _ in 0..1000 {
            let (x, y) = (a.uniform(2.0, 3.0), b.uniform(2.0, 3.0));
            assert_eq!(x, y);
            assert!((2.0..3.0).contains(&x));
            let k = a.int(1, 3);
            assert_eq!(k, b.int(1, 3));
            assert!((1..=3).contains(&k));
        }
        assert_ne!(Draw::new(7, 1).uniform(0.0, 1.0), Draw::new(7, 2).uniform(0.0, 1.0));
    }
}

//! Ideal diffuse reflection.

use super::Brdf;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// Lambertian BRDF f = albedo / π.
#[derive(Clone, Debug, PartialEq)]
pub struct Lambert {
    /// Hemispherical reflectance per channel, in [0, 1].
    pub albedo: [f64; 3],
}

impl Brdf for Lambert {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return [0.0; 3];
        }
        self.albedo.map(|a| a * FRAC_1_PI)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::testing;

    #[test]
    fn lambert_is_reciprocal_finite_and_conserves_energy_exactly() {
        let b = Lambert {
            albedo: [0.5, 0.25, 1.0],
        };
        testing::check_basic(&b);
        let a = testing::albedo(&b, DVec3::new(0.6, 0.0, 0.8), 64, 64);
        for (got, want) in a.iter().zip(b.albedo) {
            assert!((got - want).abs() < 1e-12);
        }
    }
}

//! GGX (Trowbridge–Reitz) microfacet reflection with separable Smith masking-shadowing.
//!
//! f = F(ω_i·h) · D(h) · G1(ω_i) · G1(ω_o) / (4 cos θ_i cos θ_o), evaluated in the equivalent
//! form F · D · g(cos θ_i) · g(cos θ_o) / 4 with g(c) = G1/c = 2 / (c + √(α² + (1−α²)c²)),
//! which stays finite at grazing angles where G1 → 0 and 1/cos θ → ∞.

use super::{Brdf, half_angles};
use glam::DVec3;
use std::f64::consts::PI;

/// Smallest roughness accepted: below it D exceeds 3e5/sr and a discrete environment sum cannot
/// resolve the lobe anyway.
pub const ALPHA_MIN: f64 = 1e-3;

/// Fresnel term of a microfacet model.
#[derive(Clone, Debug, PartialEq)]
pub enum Fresnel {
    /// F = 1 (no Fresnel falloff).
    None,
    /// Schlick: F = F0 + (1 − F0)(1 − cos θ_d)^5, per channel.
    Schlick([f64; 3]),
}

impl Fresnel {
    /// F at cos θ_d = ω_i · h.
    pub fn eval(&self, cos_d: f64) -> [f64; 3] {
        match self {
            Fresnel::None => [1.0; 3],
            Fresnel::Schlick(f0) => {
                let m = (1.0 - cos_d).clamp(0.0, 1.0);
                let m5 = m * m * m * m * m;
                f0.map(|f| f + (1.0 - f) * m5)
            }
        }
    }
}

/// GGX microfacet BRDF.
#[derive(Clone, Debug, PartialEq)]
pub struct Ggx {
    /// Roughness α (GGX width), clamped to [`ALPHA_MIN`, 1].
    pub alpha: f64,
    /// Fresnel term.
    pub fresnel: Fresnel,
}

impl Ggx {
    /// A GGX lobe; α is clamped to [[`ALPHA_MIN`], 1] and a Schlick F0 of (1, 1, 1) is
    /// [`Fresnel::None`].
    pub fn new(alpha: f64, fresnel: Fresnel) -> Self {
        let fresnel = match fresnel {
            Fresnel::Schlick(f0) if f0 == [1.0; 3] => Fresnel::None,
            f => f,
        };
        let alpha = if alpha.is_nan() {
            1.0
        } else {
            alpha.clamp(ALPHA_MIN, 1.0)
        };
        Self { alpha, fresnel }
    }

    /// Normal distribution D(h) for cos θ_h, normalised so that ∫ D cos θ_h dω_h = 1.
    pub fn distribution(&self, cos_h: f64) -> f64 {
        let a2 = self.alpha * self.alpha;
        let c2 = cos_h * cos_h;
        let t = c2 * (a2 - 1.0) + 1.0;
        a2 / (PI * t * t)
    }

    /// g(c) = G1(ω)/cos θ for the Smith masking term, finite for c → 0.
    pub fn g_over_cos(&self, cos: f64) -> f64 {
        let a2 = self.alpha * self.alpha;
        2.0 / (cos + (a2 + (1.0 - a2) * cos * cos).sqrt())
    }
}

impl Brdf for Ggx {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        let Some((_, cos_h, cos_d)) = half_angles(wi, wo) else {
            return [0.0; 3];
        };
        let s = self.distribution(cos_h) * self.g_over_cos(wi.z) * self.g_over_cos(wo.z) * 0.25;
        self.fresnel.eval(cos_d).map(|f| f * s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::testing;

    #[test]
    fn distribution_is_normalised_for_every_roughness() {
        for alpha in [0.05, 0.2, 0.5, 1.0] {
            let g = Ggx::new(alpha, Fresnel::None);
            // ∫ D(h) cos θ_h dω_h with u = cos²θ_h: dω cos = du/2 dφ.
            let n = 200_000;
            let s: f64 = (0..n)
                .map(|i| {
                    let u = (i as f64 + 0.5) / n as f64;
                    g.distribution(u.sqrt()) * 0.5 / n as f64 * 2.0 * PI
                })
                .sum();
            assert!((s - 1.0).abs() < 2e-3, "alpha {alpha}: {s}");
        }
    }

    #[test]
    fn ggx_is_reciprocal_finite_and_never_creates_energy() {
        for alpha in [ALPHA_MIN, 0.01, 0.2, 0.6, 1.0] {
            for fresnel in [Fresnel::None, Fresnel::Schlick([0.04, 0.5, 0.95])] {
                let b = Ggx::new(alpha, fresnel);
                testing::check_basic(&b);
                if alpha >= 0.2 {
                    for cos_o in [1.0_f64, 0.7, 0.2, 0.02] {
                        let wo = DVec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
                        let a = testing::albedo(&b, wo, 2000, 400);
                        for v in a {
                            assert!(v <= 1.0 + 2e-3, "alpha {alpha} cos_o {cos_o}: albedo {v}");
                        }
                    }
                }
            }
        }
        // White GGX at normal incidence loses only the separable-Smith masking energy
        // (about 5 % at α = 0.2).
        let b = Ggx::new(0.2, Fresnel::None);
        let a = testing::albedo(&b, DVec3::Z, 4000, 400);
        assert!(a[0] > 0.93, "{a:?}");
    }

    #[test]
    fn grazing_and_degenerate_parameters_stay_finite() {
        let b = Ggx::new(0.0, Fresnel::None);
        assert_eq!(b.alpha, ALPHA_MIN);
        assert_eq!(Ggx::new(f64::NAN, Fresnel::None).alpha, 1.0);
        assert_eq!(
            Ggx::new(7.0, Fresnel::Schlick([1.0; 3])),
            Ggx {
                alpha: 1.0,
                fresnel: Fresnel::None
            }
        );
        // θ_h → 90°: both directions grazing on opposite sides.
        let wi = DVec3::new(1.0, 0.0, 1e-12).normalize();
        let wo = DVec3::new(-1.0, 0.0, 1e-12).normalize();
        for f in b.eval(wi, wo) {
            assert!(f.is_finite() && f >= 0.0);
        }
        // Peak of the sharpest lobe is large but finite.
        let f = b.eval(DVec3::Z, DVec3::Z);
        assert!(f[0].is_finite() && f[0] > 1e4);
        assert_eq!(Fresnel::Schlick([0.04; 3]).eval(1.0), [0.04; 3]);
        assert_eq!(Fresnel::Schlick([0.04; 3]).eval(0.0), [1.0; 3]);
    }
}

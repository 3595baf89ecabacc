//! "Plastic": a Lambertian base under a dielectric GGX coat.

use super::{Brdf, Fresnel, Ggx, Lambert};
use glam::DVec3;

/// Normal-incidence reflectance of the coat (index of refraction ≈ 1.5).
pub const COAT_F0: f64 = 0.04;

/// Lambert(albedo) + GGX(α, Schlick F0 = 0.04), summed. The sum is not energy-coupled: at grazing
/// angles the coat's Fresnel rises while the base is not dimmed, as in the paper's synthetic data.
#[derive(Clone, Debug, PartialEq)]
pub struct Plastic {
    /// Diffuse base.
    pub base: Lambert,
    /// Specular coat.
    pub coat: Ggx,
}

impl Plastic {
    /// A plastic of diffuse `albedo` and coat roughness `alpha`.
    pub fn new(alpha: f64, albedo: [f64; 3]) -> Self {
        Self {
            base: Lambert { albedo },
            coat: Ggx::new(alpha, Fresnel::Schlick([COAT_F0; 3])),
        }
    }
}

impl Brdf for Plastic {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        let a = self.base.eval(wi, wo);
        let b = self.coat.eval(wi, wo);
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::testing;

    #[test]
    fn plastic_is_base_plus_coat() {
        let p = Plastic::new(0.3, [0.2, 0.4, 0.6]);
        testing::check_basic(&p);
        let wi = DVec3::new(0.3, 0.1, 0.9).normalize();
        let wo = DVec3::new(-0.2, 0.4, 0.8).normalize();
        let (a, b, s) = (p.base.eval(wi, wo), p.coat.eval(wi, wo), p.eval(wi, wo));
        for c in 0..3 {
            assert_eq!(s[c], a[c] + b[c]);
        }
        // At normal incidence the coat reflects about 4 %.
        let alb = testing::albedo(&p, DVec3::Z, 2000, 200);
        assert!((alb[0] - 0.2 - 0.04).abs() < 0.01, "{alb:?}");
    }
}

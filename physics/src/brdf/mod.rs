//! Reflectance models, each behind the [`Brdf`] trait and evaluated in a local frame whose +z
//! axis is the surface normal.
//!
//! * [`lambert::Lambert`]: ideal diffuse, f = ρ/π;
//! * [`ggx::Ggx`]: GGX microfacet with separable Smith masking and Schlick (or no) Fresnel;
//! * [`plastic::Plastic`]: Lambert plus a GGX coat with F0 = 0.04;
//! * [`dsbrdf::Dsbrdf`]: the paper's 108-parameter Directional Statistics BRDF;
//! * [`merl::MerlBrdf`] and [`nbrdf::NeuralBrdf`]: measured materials, as MERL's tables and as
//!   the neural BRDFs of Sztrajman et al. 2021.
//!
//! [`BrdfModel`] is the closed set the fast shading path specialises for; [`BrdfSpec`] parses
//! the `--brdf` strings of the command line.

pub mod dsbrdf;
pub mod ggx;
pub mod lambert;
pub mod merl;
pub mod nbrdf;
pub mod plastic;
mod spec;

pub use dsbrdf::Dsbrdf;
pub use ggx::{Fresnel, Ggx};
pub use lambert::Lambert;
pub use merl::MerlBrdf;
pub use nbrdf::NeuralBrdf;
pub use plastic::Plastic;
pub use spec::{BrdfSpec, SpecError};

use glam::DVec3;

/// A bidirectional reflectance distribution function, in 1/sr, per RGB channel.
///
/// `wi` (towards the light) and `wo` (towards the viewer) are unit vectors in the local frame
/// (normal = +z). Implementations return 0 when either direction is below the surface, and must
/// return finite, non-negative values for every unit input, grazing angles included.
pub trait Brdf: Send + Sync {
    /// f(ω_i, ω_o) per channel.
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3];
}

/// Every BRDF the renderer can shade.
#[derive(Clone, Debug, PartialEq)]
pub enum BrdfModel {
    /// Ideal diffuse.
    Lambert(Lambert),
    /// GGX microfacet.
    Ggx(Ggx),
    /// Lambert + GGX (F0 = 0.04).
    Plastic(Plastic),
    /// Directional Statistics BRDF (108 parameters).
    Dsbrdf(Box<Dsbrdf>),
    /// A measured MERL table, shaded through the exact path (a 3-D table has no per-texel
    /// factorisation).
    Measured(std::sync::Arc<MerlBrdf>),
    /// A measured material as a neural BRDF (`nbrdf:`), shaded through the exact path too.
    Neural(std::sync::Arc<NeuralBrdf>),
}

impl Brdf for BrdfModel {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        match self {
            BrdfModel::Lambert(b) => b.eval(wi, wo),
            BrdfModel::Ggx(b) => b.eval(wi, wo),
            BrdfModel::Plastic(b) => b.eval(wi, wo),
            BrdfModel::Dsbrdf(b) => b.eval(wi, wo),
            BrdfModel::Measured(b) => b.eval(wi, wo),
            BrdfModel::Neural(b) => b.eval(wi, wo),
        }
    }
}

/// Half vector and the (cos θ_h, cos θ_d) pair of the Rusinkiewicz parameterisation, or `None`
/// when either direction is at or below the horizon.
pub(crate) fn half_angles(wi: DVec3, wo: DVec3) -> Option<(DVec3, f64, f64)> {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return None;
    }
    // wi + wo cannot vanish when both are in the upper hemisphere.
    let h = (wi + wo).normalize();
    Some((h, h.z.clamp(0.0, 1.0), wi.dot(h).clamp(0.0, 1.0)))
}

#[cfg(test)]
pub(crate) mod testing {
    //! Shared checks every BRDF must pass: finiteness, reciprocity and energy bounds.
    use super::Brdf;
    use glam::DVec3;
    use std::f64::consts::PI;

    /// Directions covering normal, oblique and grazing incidence.
    pub fn hard_directions() -> Vec<DVec3> {
        let mut v = Vec::new();
        for &theta in &[0.0, 0.3, 1.0, 1.4, 1.55, 1.5699, std::f64::consts::FRAC_PI_2 - 1e-9] {
            for &phi in &[0.0_f64, 0.7, 2.0, 3.1, 4.5] {
                let (st, ct) = f64::sin_cos(theta);
                v.push(DVec3::new(st * phi.cos(), st * phi.sin(), ct).normalize());
            }
        }
        v
    }

    /// f is finite, ≥ 0, reciprocal, and 0 below the horizon.
    pub fn check_basic(b: &dyn Brdf) {
        let dirs = hard_directions();
        for &wi in &dirs {
            for &wo in &dirs {
                let f = b.eval(wi, wo);
                let g = b.eval(wo, wi);
                for c in 0..3 {
                    assert!(f[c].is_finite() && f[c] >= 0.0, "f({wi},{wo}) = {f:?}");
                    let tol = 1e-9 * f[c].abs().max(1.0);
                    assert!((f[c] - g[c]).abs() <= tol, "reciprocity: {f:?} vs {g:?} at {wi},{wo}");
                }
            }
            let below = DVec3::new(wi.x, wi.y, -wi.z - 1e-3).normalize();
            assert_eq!(b.eval(below, DVec3::Z), [0.0; 3]);
            assert_eq!(b.eval(DVec3::Z, below), [0.0; 3]);
        }
    }

    /// Directional albedo ∫ f(ω_i, ω_o) cos θ_i dω_i by midpoint quadrature in (cos θ, φ).
    pub fn albedo(b: &dyn Brdf, wo: DVec3, n_theta: usize, n_phi: usize) -> [f64; 3] {
        let mut acc = [0.0; 3];
        // Substituting u = cos²θ puts more samples near the pole where GGX peaks.
        for i in 0..n_theta {
            let u = (i as f64 + 0.5) / n_theta as f64;
            let ct = u.sqrt();
            let st = (1.0 - u).max(0.0).sqrt();
            for j in 0..n_phi {
                let phi = 2.0 * PI * (j as f64 + 0.5) / n_phi as f64;
                let wi = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
                let f = b.eval(wi, wo);
                // dω cosθ = d(cos θ) dφ cos θ = (du / 2) dφ.
                let w = 0.5 / n_theta as f64 * 2.0 * PI / n_phi as f64;
                for c in 0..3 {
                    acc[c] += f[c] * w;
                }
            }
        }
        acc
    }
}

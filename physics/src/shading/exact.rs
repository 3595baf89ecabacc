//! The `f64` reference implementation of Eq. 2.

use super::{Shader, shading_normal};
use crate::brdf::{Brdf, BrdfModel};
use crate::camera::VIEW_DIR;
use crate::envmap::{EnvMap, texel_direction, texel_solid_angle};
use crate::frame::Frame;
use glam::DVec3;

/// Evaluates the BRDF through [`Brdf::eval`] in a per-pixel local frame, for every texel, with
/// compensated (Neumaier) summation. Independent of the fast path's per-texel factorisation.
pub struct ExactShader {
    brdf: BrdfModel,
    dirs: Vec<DVec3>,
    dirs32: Vec<[f32; 3]>,
    /// L(ω_i) · dω_i per texel.
    radiance_sa: Vec<[f64; 3]>,
}

impl ExactShader {
    /// Prepares the texel directions and L·dω of `env`.
    pub fn new(brdf: BrdfModel, env: &EnvMap) -> Self {
        let (w, h) = (env.width(), env.height());
        let mut dirs = Vec::with_capacity(w * h);
        let mut radiance_sa = Vec::with_capacity(w * h);
        for j in 0..h {
            let sa = texel_solid_angle(j, w, h);
            for i in 0..w {
                dirs.push(texel_direction(i, j, w, h));
                radiance_sa.push(env.texel(i, j).map(|v| v as f64 * sa));
            }
        }
        let dirs32 = dirs.iter().map(|d| [d.x as f32, d.y as f32, d.z as f32]).collect();
        Self {
            brdf,
            dirs,
            dirs32,
            radiance_sa,
        }
    }

    /// Radiance in `f64`.
    pub fn shade_f64(&self, n: [f32; 3], visibility: Option<&[f32]>) -> [f64; 3] {
        let Some(n) = shading_normal(n) else {
            return [0.0; 3];
        };
        let frame = Frame::from_normal(n);
        let wo = frame.to_local(VIEW_DIR);
        let mut sum = [Neumaier::default(); 3];
        for (t, (d, lsa)) in self.dirs.iter().zip(&self.radiance_sa).enumerate() {
            let wi = frame.to_local(*d);
            if wi.z <= 0.0 || visibility.is_some_and(|v| v[t] == 0.0) {
                continue;
            }
            let f = self.brdf.eval(wi, wo);
            for c in 0..3 {
                sum[c].add(f[c] * lsa[c] * wi.z);
            }
        }
        sum.map(|s| s.total())
    }
}

impl Shader for ExactShader {
    fn light_dirs(&self) -> &[[f32; 3]] {
        &self.dirs32
    }

    fn shade(&self, n: [f32; 3], visibility: Option<&[f32]>) -> [f32; 3] {
        self.shade_f64(n, visibility).map(|v| v as f32)
    }
}

/// Neumaier's improved Kahan summation.
#[derive(Clone, Copy, Default)]
struct Neumaier {
    sum: f64,
    comp: f64,
}

impl Neumaier {
    fn add(&mut self, x: f64) {
        let t = self.sum + x;
        if self.sum.abs() >= x.abs() {
            self.comp += (self.sum - t) + x;
        } else {
            self.comp += (x - t) + self.sum;
        }
        self.sum = t;
    }

    fn total(self) -> f64 {
        self.sum + self.comp
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn neumaier_recovers_cancelled_terms() {
        let mut s = Neumaier::default();
        for x in [1.0, 1e100, 1.0, -1e100] {
            s.add(x);
        }
        assert_eq!(s.total(), 2.0);
    }
}

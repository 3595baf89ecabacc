//! Local shading frames: the BRDFs are evaluated with the normal along +z.

use glam::DVec3;

/// An orthonormal basis whose `n` axis is the surface normal.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// Tangent.
    pub s: DVec3,
    /// Bitangent.
    pub t: DVec3,
    /// Normal.
    pub n: DVec3,
}

impl Frame {
    /// Builds a frame around a unit normal (Duff et al. 2017, branch-free and stable for every
    /// orientation, including n = ±z).
    pub fn from_normal(n: DVec3) -> Self {
        let sign = 1.0_f64.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = DVec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }

    /// World direction into the local frame.
    pub fn to_local(&self, v: DVec3) -> DVec3 {
        DVec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_orthonormal_for_hard_normals() {
        for n in [
            DVec3::Z,
            -DVec3::Z,
            DVec3::X,
            DVec3::new(1e-12, -1e-12, -1.0).normalize(),
            DVec3::new(0.3, -0.4, 0.866).normalize(),
        ] {
            let f = Frame::from_normal(n);
            for (a, b) in [(f.s, f.t), (f.s, f.n), (f.t, f.n)] {
                assert!(a.dot(b).abs() < 1e-12);
            }
            for v in [f.s, f.t, f.n] {
                assert!((v.length() - 1.0).abs() < 1e-12);
            }
            assert!((f.to_local(n) - DVec3::Z).length() < 1e-12);
        }
    }
}

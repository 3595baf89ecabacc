//! Primitive geometry for the procedural shapes: rounded boxes and capped cylinders, with
//! analytic smooth normals, each tagged with a region.

use crate::shapes::Mesh;
use glam::{Mat3, Vec3};

/// Accumulates primitives into a [`Mesh`].
pub struct Builder {
    mesh: Mesh,
}

impl Builder {
    /// An empty mesh with the given region names.
    pub fn new(regions: [&str; 2], source: String) -> Self {
        Self {
            mesh: Mesh {
                regions: regions.map(String::from).to_vec(),
                source,
                ..Default::default()
            },
        }
    }

    fn tri(&mut self, p: [Vec3; 3], n: [Vec3; 3], region: u32) {
        let base = self.mesh.positions.len() as u32;
        self.mesh.positions.extend(p);
        self.mesh.triangles.push([base, base + 1, base + 2]);
        self.mesh.corner_normals.push(n);
        self.mesh.triangle_region.push(region);
    }

    /// A box of half-extents `half` whose edges are rounded with radius `round` (clamped to the
    /// smallest half-extent), rotated by `rot` and centred at `centre`. Each face is a 6×6 grid
    /// projected onto the rounded surface, normals from the inner box.
    pub fn rounded_box(&mut self, centre: Vec3, half: Vec3, round: f32, rot: Mat3, region: u32) {
        const N: usize = 6;
        let round = round.clamp(1e-4, half.min_element());
        let inner = half - Vec3::splat(round);
        let point = |u: Vec3| {
            let p = u * half;
            let q = p.clamp(-inner, inner);
            let n = (p - q).normalize_or(u);
            (centre + rot * (q + n * round), rot * n)
        };
        for axis in 0..3 {
            for sign in [-1.0_f32, 1.0] {
                // Face frame (a, b, normal) right-handed so triangles wind outwards.
                let mut nrm = Vec3::ZERO;
                nrm[axis] = sign;
                let a = Vec3::from_array(std::array::from_fn(|k| if k == (axis + 1) % 3 { 1.0 } else { 0.0 }));
                let b = nrm.cross(a);
                let at = |i: usize, j: usize| {
                    let (s, t) = (2.0 * i as f32 / N as f32 - 1.0, 2.0 * j as f32 / N as f32 - 1.0);
                    point(nrm + a * s + b * t)
                };
                for i in 0..N {
                    for j in 0..N {
                        let (p00, p10, p11, p01) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                        self.tri([p00.0, p10.0, p11.0], [p00.1, p10.1, p11.1], region);
                        self.tri([p00.0, p11.0, p01.0], [p00.1, p11.1, p01.1], region);
                    }
                }
            }
        }
    }

    /// A capped cylinder from `a` to `b` of radius `r` with `segments` sides.
    pub fn cylinder(&mut self, a: Vec3, b: Vec3, r: f32, segments: usize, region: u32) {
        let axis = (b - a).normalize_or(Vec3::Y);
        let u = axis.any_orthonormal_vector();
        let v = axis.cross(u);
        let ring = |k: usize| {
            let t = std::f32::consts::TAU * k as f32 / segments as f32;
            u * t.cos() + v * t.sin()
        };
        for k in 0..segments {
            let (n0, n1) = (ring(k), ring(k + 1));
            let (a0, a1, b0, b1) = (a + n0 * r, a + n1 * r, b + n0 * r, b + n1 * r);
            self.tri([a0, a1, b1], [n0, n1, n1], region);
            self.tri([a0, b1, b0], [n0, n1, n0], region);
            self.tri([b, b0, b1], [axis; 3], region);
            self.tri([a, a1, a0], [-axis; 3], region);
        }
    }

    /// The finished mesh, normalised to the unit ball like any loaded mesh.
    pub fn finish(self) -> Mesh {
        let n = self.mesh.triangles.len();
        let source = self.mesh.source.clone();
        self.mesh
            .finish(vec![true; n])
            .unwrap_or_else(|e| panic!("procedural shape {source} is invalid: {e}"))
    }
}

/// Rotation about +x by `deg` degrees (e.g. a chair back's recline).
pub fn rot_x(deg: f32) -> Mat3 {
    Mat3::from_rotation_x(deg.to_radians())
}

/// Rotation about +y by `deg` degrees.
pub fn rot_y(deg: f32) -> Mat3 {
    Mat3::from_rotation_y(deg.to_radians())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounded_boxes_wind_outwards_with_unit_normals() {
        let mut b = Builder::new(["a", "b"], "test".into());
        b.rounded_box(Vec3::ZERO, Vec3::new(1.0, 0.5, 0.25), 0.1, Mat3::IDENTITY, 0);
        b.cylinder(Vec3::new(0.0, 1.0, 0.0), Vec3::new(0.0, 2.0, 0.0), 0.2, 12, 1);
        let m = &b.mesh;
        for (t, ns) in m.triangles.iter().zip(&m.corner_normals) {
            let [p0, p1, p2] = t.map(|i| m.positions[i as usize]);
            let g = (p1 - p0).cross(p2 - p0);
            if g.length() > 1e-9 {
                let avg = ns[0] + ns[1] + ns[2];
                assert!(g.dot(avg) > 0.0, "triangle winds inwards");
            }
            for n in ns {
                assert!((n.length() - 1.0).abs() < 1e-5);
            }
        }
    }
}

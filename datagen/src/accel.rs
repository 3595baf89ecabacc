//! Ray queries against a mesh through an obvhs compressed wide BVH (CWBVH).

use crate::shapes::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::{BvhBuildParams, cwbvh::CwBvh, cwbvh::builder::build_cwbvh_from_tris, ray::Ray, triangle::Triangle};
use std::time::Duration;

/// A closest hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Triangle index in the mesh.
    pub triangle: u32,
    /// Ray parameter.
    pub t: f32,
    /// Barycentric weight of corner 1.
    pub u: f32,
    /// Barycentric weight of corner 2.
    pub v: f32,
}

/// A mesh with its BVH.
pub struct Scene {
    bvh: CwBvh,
    tris: Vec<Triangle>,
}

impl Scene {
    /// Builds the BVH over the mesh's triangles.
    pub fn new(mesh: &Mesh) -> Self {
        let tris: Vec<Triangle> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [v0, v1, v2] = t.map(|i| Vec3A::from(mesh.positions[i as usize]));
                Triangle { v0, v1, v2 }
            })
            .collect();
        let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
        Self { bvh, tris }
    }

    /// Closest hit along `origin + t·dir`, t > `tmin`. Ties in t go to the lowest triangle index,
    /// so the result does not depend on the BVH's layout.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32) -> Option<Hit> {
        let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
        let mut best = (f32::INFINITY, u32::MAX);
        let mut hit = obvhs::ray::RayHit::none();
        self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            let prim = self.bvh.primitive_indices[id];
            let t = self.tris[prim as usize].intersect(r);
            if t < best.0 || (t == best.0 && prim < best.1) {
                best = (t, prim);
            }
            t
        });
        if !best.0.is_finite() {
            return None;
        }
        let (u, v) = barycentrics(&self.tris[best.1 as usize], origin, dir);
        Some(Hit {
            triangle: best.1,
            t: best.0,
            u,
            v,
        })
    }

    /// Whether anything blocks `origin + t·dir` for t > `tmin`.
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32) -> bool {
        let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            self.tris[self.bvh.primitive_indices[id] as usize].intersect(r)
        })
    }
}

/// Barycentric (u, v) of the ray's intersection with the triangle's plane (Möller–Trumbore),
/// clamped into the triangle; obvhs reports only t.
fn barycentrics(tri: &Triangle, origin: Vec3, dir: Vec3) -> (f32, f32) {
    let (v0, v1, v2) = (
        Vec3::from(tri.v0).as_dvec3(),
        Vec3::from(tri.v1).as_dvec3(),
        Vec3::from(tri.v2).as_dvec3(),
    );
    let (o, d) = (origin.as_dvec3(), dir.as_dvec3());
    let e1 = v1 - v0;
    let e2 = v2 - v0;
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-300 {
        return (1.0 / 3.0, 1.0 / 3.0);
    }
    let s = o - v0;
    let u = s.dot(p) / det;
    let q = s.cross(e1);
    let v = d.dot(q) / det;
    let u = u.clamp(0.0, 1.0);
    let v = v.clamp(0.0, 1.0 - u);
    (u as f32, v as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_triangles() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(-1.0, -1.0, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(-1.0, -1.0, -0.5),
                Vec3::new(1.0, -1.0, -0.5),
                Vec3::new(0.0, 1.0, -0.5),
            ],
            triangles: vec![[3, 4, 5], [0, 1, 2]],
            corner_normals: vec![[Vec3::Z; 3]; 2],
            ..Default::default()
        }
    }

    #[test]
    fn closest_hit_and_barycentrics() {
        let s = Scene::new(&two_triangles());
        let h = s.intersect(Vec3::new(0.0, -0.5, 2.0), Vec3::NEG_Z, 0.0).unwrap();
        assert_eq!(h.triangle, 1);
        assert!((h.t - 2.0).abs() < 1e-6);
        // Point (0, −0.5) = v0 + u e1 + v e2 with e1 = (2, 0), e2 = (1, 2): v = 0.25, u = 0.375.
        assert!((h.u - 0.375).abs() < 1e-6 && (h.v - 0.25).abs() < 1e-6, "{h:?}");
        assert!(s.intersect(Vec3::new(5.0, 0.0, 2.0), Vec3::NEG_Z, 0.0).is_none());
        assert!(s.occluded(Vec3::new(0.0, -0.5, -0.25), Vec3::Z, 1e-4));
        assert!(!s.occluded(Vec3::new(0.0, -0.5, 0.25), Vec3::Z, 1e-4));
    }
}

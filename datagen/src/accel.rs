//! Ray queries against a mesh: through an obvhs compressed wide BVH (CWBVH), the default, or
//! through Embree 4 (`--features embree`, chosen per run with [`Accel`]). Either backend only
//! finds which triangle a ray hits; t and the barycentrics are then computed from that triangle
//! by the same code, so the two agree bit for bit wherever they hit the same triangle.

use crate::shapes::Mesh;
use glam::{Vec3, Vec3A};
use obvhs::{BvhBuildParams, cwbvh::CwBvh, cwbvh::builder::build_cwbvh_from_tris, ray::Ray, triangle::Triangle};
use std::time::Duration;

/// Which ray-query backend a run uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Accel {
    /// obvhs (pure Rust, always built).
    #[default]
    Obvhs,
    /// Embree 4 through embree4-rs (a build with `--features embree`).
    Embree,
}

impl Accel {
    /// Its name in manifests and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Accel::Obvhs => "obvhs",
            Accel::Embree => "embree",
        }
    }

    /// By name; `None` for an unknown one.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "obvhs" => Some(Accel::Obvhs),
            "embree" => Some(Accel::Embree),
            _ => None,
        }
    }

    /// Whether this build can use it.
    pub fn available(self) -> bool {
        match self {
            Accel::Obvhs => true,
            Accel::Embree => cfg!(feature = "embree"),
        }
    }

    /// Why it cannot be used in this build, if it cannot.
    pub fn unavailable_reason(self) -> Option<&'static str> {
        (!self.available()).then_some(
            "this build has no Embree backend: build with `--features embree` after `eval \"$(scripts/install_embree.sh)\"`",
        )
    }
}

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

/// A mesh with its acceleration structure.
pub struct Scene {
    tris: Vec<Triangle>,
    backend: Backend,
}

enum Backend {
    Obvhs(CwBvh),
    #[cfg(feature = "embree")]
    Embree(embree::EmbreeScene),
}

impl Scene {
    /// Builds the obvhs BVH over the mesh's triangles.
    pub fn new(mesh: &Mesh) -> Self {
        let tris = triangles(mesh);
        let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
        Self {
            tris,
            backend: Backend::Obvhs(bvh),
        }
    }

    /// Builds the structure of `accel`; an error where this build lacks it.
    pub fn with_accel(mesh: &Mesh, accel: Accel) -> anyhow::Result<Self> {
        match accel {
            Accel::Obvhs => Ok(Self::new(mesh)),
            #[cfg(feature = "embree")]
            Accel::Embree => Ok(Self {
                backend: Backend::Embree(embree::EmbreeScene::new(mesh)?),
                tris: triangles(mesh),
            }),
            #[cfg(not(feature = "embree"))]
            Accel::Embree => anyhow::bail!("accel = \"embree\": {}", accel.unavailable_reason().unwrap_or("")),
        }
    }

    /// Closest hit along `origin + t·dir`, t > `tmin`. With obvhs, ties in t go to the lowest
    /// triangle index, so the result does not depend on the BVH's layout (Embree picks one of
    /// the tied triangles the same way whatever the thread count).
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmin: f32) -> Option<Hit> {
        let bvh = match &self.backend {
            Backend::Obvhs(bvh) => bvh,
            #[cfg(feature = "embree")]
            Backend::Embree(e) => {
                let (prim, t_embree) = e.closest(origin, dir, tmin)?;
                let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
                // obvhs's own triangle test gives t, as the obvhs path does; Embree's t where
                // that test misses the triangle Embree hit (on its edge).
                let t = self.tris[prim as usize].intersect(&ray);
                let t = if t.is_finite() { t } else { t_embree };
                let (u, v) = barycentrics(&self.tris[prim as usize], origin, dir);
                return Some(Hit { triangle: prim, t, u, v });
            }
        };
        let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
        let mut best = (f32::INFINITY, u32::MAX);
        let mut hit = obvhs::ray::RayHit::none();
        bvh.ray_traverse(ray, &mut hit, |r, id| {
            let prim = bvh.primitive_indices[id];
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
        match &self.backend {
            Backend::Obvhs(bvh) => {
                let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
                !bvh.ray_traverse_miss(ray, |r, id| self.tris[bvh.primitive_indices[id] as usize].intersect(r))
            }
            #[cfg(feature = "embree")]
            Backend::Embree(e) => e.closest(origin, dir, tmin).is_some(),
        }
    }
}

fn triangles(mesh: &Mesh) -> Vec<Triangle> {
    mesh.triangles
        .iter()
        .map(|t| {
            let [v0, v1, v2] = t.map(|i| Vec3A::from(mesh.positions[i as usize]));
            Triangle { v0, v1, v2 }
        })
        .collect()
}

#[cfg(feature = "embree")]
mod embree {
    //! The Embree 4 scene. embree4-rs 0.0.16 offers closest-hit queries only (its scene handle
    //! is private), so shadow rays are closest-hit queries too.

    use crate::shapes::Mesh;
    use anyhow::Result;
    use embree4_rs::geometry::TriangleMeshGeometry;
    use embree4_rs::{CommittedScene, Device, Scene, SceneOptions};
    use embree4_sys::{RTCBuildQuality, RTCRay, RTCSceneFlags};
    use glam::Vec3;

    pub struct EmbreeScene(CommittedScene);

    // Safety: a committed Embree scene is immutable and Embree documents concurrent queries from
    // any thread as safe; the handles are plain pointers owned by this value.
    unsafe impl Send for EmbreeScene {}

    impl EmbreeScene {
        pub fn new(mesh: &Mesh) -> Result<Self> {
            // `Some(config)` would pass a string without its NUL terminator.
            let device = Device::try_new(None)?;
            let vertices: Vec<(f32, f32, f32)> = mesh.positions.iter().map(|p| (p.x, p.y, p.z)).collect();
            let indices: Vec<(u32, u32, u32)> = mesh.triangles.iter().map(|t| (t[0], t[1], t[2])).collect();
            let geometry = TriangleMeshGeometry::try_new(&device, &vertices, &indices)?;
            let scene = Scene::try_new(
                device,
                SceneOptions {
                    build_quality: RTCBuildQuality::HIGH,
                    flags: RTCSceneFlags::ROBUST,
                },
            )?;
            scene.attach_geometry(&geometry)?;
            Ok(Self(scene.commit()?))
        }

        /// The closest triangle hit at t > `tmin`, and its t.
        pub fn closest(&self, origin: Vec3, dir: Vec3, tmin: f32) -> Option<(u32, f32)> {
            let ray = RTCRay {
                org_x: origin.x,
                org_y: origin.y,
                org_z: origin.z,
                dir_x: dir.x,
                dir_y: dir.y,
                dir_z: dir.z,
                tnear: tmin,
                tfar: f32::INFINITY,
                mask: u32::MAX,
                flags: 0,
                ..Default::default()
            };
            let hit = self.0.intersect_1(ray, None).ok()??;
            Some((hit.hit.primID, hit.ray.tfar))
        }
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

    #[test]
    fn embree_without_the_feature_is_a_clear_error() {
        let m = two_triangles();
        match Scene::with_accel(&m, Accel::Embree) {
            Ok(_) => assert!(cfg!(feature = "embree")),
            Err(e) => {
                assert!(!cfg!(feature = "embree"));
                assert!(e.to_string().contains("--features embree"), "{e}");
            }
        }
        assert_eq!(Accel::from_name("embree"), Some(Accel::Embree));
        assert_eq!(Accel::from_name("optix"), None);
    }

    /// Primary rays on a grid and shadow rays from the hits towards fixed directions, through
    /// both backends: the same triangle for all but 0.1 % of the rays, and then t, u, v equal
    /// bit for bit; the same occlusion for all but 0.1 %.
    #[cfg(feature = "embree")]
    #[test]
    fn embree_and_obvhs_agree_on_real_meshes() {
        use crate::shapes::{Shape, UpAxis};
        let mut specs: Vec<String> = ["car:1", "chair:2", "sofa:3", "monitor:4"]
            .iter()
            .map(|s| format!("procedural:{s}"))
            .collect();
        // Real meshes when the evaluation assets are beside the checkout.
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/eval-assets/meshes");
        for f in ["common-3d-test-models/teapot.obj", "common-3d-test-models/bunny.obj"] {
            if assets.join(f).is_file() {
                specs.push(assets.join(f).display().to_string());
            }
        }
        let lights = [Vec3::new(0.3, 0.9, 0.2), Vec3::new(-0.7, 0.4, 0.6), Vec3::new(0.1, 0.2, -1.0)];
        for spec in &specs {
            let Ok(Shape::Mesh(m)) = Shape::load(spec, UpAxis::Y) else {
                panic!("{spec}")
            };
            let (o, e) = (Scene::new(&m), Scene::with_accel(&m, Accel::Embree).unwrap());
            let (mut rays, mut differ, mut shadow, mut shadow_differ) = (0, 0, 0, 0);
            let n = 160;
            for j in 0..n {
                for i in 0..n {
                    let x = -1.05 + 2.1 * (i as f32 + 0.5) / n as f32;
                    let y = -1.05 + 2.1 * (j as f32 + 0.5) / n as f32;
                    let (org, dir) = (Vec3::new(x, y, 4.0), Vec3::NEG_Z);
                    let (a, b) = (o.intersect(org, dir, 0.0), e.intersect(org, dir, 0.0));
                    rays += 1;
                    match (a, b) {
                        (Some(a), Some(b)) if a.triangle == b.triangle => {
                            assert_eq!(a, b, "{spec}: same triangle, different hit");
                            let p = org + a.t * dir;
                            for l in lights {
                                let l = l.normalize();
                                shadow += 1;
                                if o.occluded(p, l, 1e-4) != e.occluded(p, l, 1e-4) {
                                    shadow_differ += 1;
                                }
                            }
                        }
                        (None, None) => {}
                        _ => differ += 1,
                    }
                }
            }
            assert!(differ * 1000 <= rays, "{spec}: {differ} of {rays} primary rays hit different triangles");
            assert!(
                shadow_differ * 1000 <= shadow,
                "{spec}: {shadow_differ} of {shadow} shadow rays disagree"
            );
        }
    }
}

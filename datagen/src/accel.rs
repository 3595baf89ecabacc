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

impl matedit_contract::manifest::Named for Accel {
    const NAMES: &'static [(&'static str, Self)] = &[("obvhs", Accel::Obvhs), ("embree", Accel::Embree)];
}

impl Accel {
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
        let ray = Ray::new(origin.into(), dir.into(), tmin, f32::INFINITY);
        let (prim, t) = match &self.backend {
            Backend::Obvhs(bvh) => {
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
                (best.1, best.0)
            }
            #[cfg(feature = "embree")]
            Backend::Embree(e) => {
                let (prim, t_embree) = e.closest(origin, dir, tmin)?;
                // obvhs's own triangle test gives t, as on the obvhs path; Embree's t where that
                // test misses the triangle Embree hit (on its edge).
                let t = self.tris[prim as usize].intersect(&ray);
                (prim, if t.is_finite() { t } else { t_embree })
            }
        };
        let (u, v) = barycentrics(&self.tris[prim as usize], origin, dir);
        Some(Hit {
            triangle: prim,
            t,
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
            Backend::Embree(e) => e.occluded(origin, dir, tmin),
        }
    }
}

impl Scene {
    /// [`occluded`](Self::occluded) for rays from one `origin` along each of `dirs` into
    /// `out` (a pixel's shadow rays): Embree traces them in packets (sixteen or eight).
    pub fn occluded_from(&self, origin: Vec3, dirs: &[Vec3], tmin: f32, out: &mut [bool]) {
        #[cfg(feature = "embree")]
        if let Backend::Embree(e) = &self.backend {
            return e.occluded_from(origin, dirs, tmin, out);
        }
        for (o, &d) in out.iter_mut().zip(dirs) {
            *o = self.occluded(origin, d, tmin);
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
    //! The Embree 4 scene, through the embree4-sys bindings that embree4-rs is built on.
    //! embree4-rs 0.0.16 keeps its device and scene handles private, so it cannot issue occlusion
    //! queries (`rtcOccluded1`, what shadow rays want), and it asks for the device's error after
    //! every ray; measured on the same rays, that costs 1.5–2× (docs/PERFORMANCE.md). The calls
    //! here are the ones it makes, plus `rtcOccluded1`.

    use crate::shapes::Mesh;
    use anyhow::{Result, bail};
    use embree4_sys as sys;
    use glam::Vec3;
    use std::ptr::null_mut;

    pub struct EmbreeScene {
        device: sys::RTCDevice,
        scene: sys::RTCScene,
        /// Trace shadow rays sixteen at a time (AVX-512).
        packet16: bool,
    }

    // Safety: a committed scene is immutable; Embree allows queries from any number of threads
    // at once. The two handles are owned by this value and released once, in `drop`.
    unsafe impl Send for EmbreeScene {}
    unsafe impl Sync for EmbreeScene {}

    fn check(device: sys::RTCDevice, what: &str) -> Result<()> {
        let e = unsafe { sys::rtcGetDeviceError(device) };
        if e != sys::RTCError::NONE {
            bail!("Embree: {what}: {e:?}");
        }
        Ok(())
    }

    /// A packet query of `$w` rays from one origin through `sys::$occluded` (Embree wants the
    /// validity mask aligned to the packet's size in bytes, `$align`). Unused lanes are invalid.
    macro_rules! occluded_packets {
        ($(#[$doc:meta])* $name:ident, $w:literal, $ray:ident, $occluded:ident, $align:literal) => {
            $(#[$doc])*
            pub(crate) fn $name(&self, origin: Vec3, dirs: &[Vec3], tmin: f32, out: &mut [bool]) {
                #[repr(C, align($align))]
                struct Valid([i32; $w]);
                for (dirs, out) in dirs.chunks($w).zip(out.chunks_mut($w)) {
                    let mut valid = Valid([0; $w]);
                    let mut r = sys::$ray {
                        org_x: [origin.x; $w],
                        org_y: [origin.y; $w],
                        org_z: [origin.z; $w],
                        tnear: [tmin; $w],
                        dir_x: [0.0; $w],
                        dir_y: [0.0; $w],
                        dir_z: [1.0; $w],
                        time: [0.0; $w],
                        tfar: [f32::INFINITY; $w],
                        mask: [u32::MAX; $w],
                        id: [0; $w],
                        flags: [0; $w],
                    };
                    for (k, d) in dirs.iter().enumerate() {
                        valid.0[k] = -1;
                        r.dir_x[k] = d.x;
                        r.dir_y[k] = d.y;
                        r.dir_z[k] = d.z;
                    }
                    unsafe { sys::$occluded(valid.0.as_ptr(), self.scene, &mut r, null_mut()) };
                    for (k, o) in out.iter_mut().enumerate() {
                        *o = r.tfar[k] == f32::NEG_INFINITY;
                    }
                }
            }
        };
    }

    impl EmbreeScene {
        pub fn new(mesh: &Mesh) -> Result<Self> {
            unsafe {
                let device = sys::rtcNewDevice(null_mut());
                if device.is_null() {
                    bail!(
                        "Embree: cannot create a device ({:?})",
                        sys::rtcGetDeviceError(null_mut())
                    );
                }
                // From here on `drop` releases what exists.
                #[cfg(target_arch = "x86_64")]
                let packet16 = std::is_x86_feature_detected!("avx512f");
                #[cfg(not(target_arch = "x86_64"))]
                let packet16 = false;
                let mut out = Self {
                    device,
                    scene: null_mut(),
                    packet16,
                };
                out.scene = sys::rtcNewScene(device);
                check(device, "new scene")?;
                sys::rtcSetSceneBuildQuality(out.scene, sys::RTCBuildQuality::HIGH);
                sys::rtcSetSceneFlags(out.scene, sys::RTCSceneFlags::ROBUST);
                let geometry = sys::rtcNewGeometry(device, sys::RTCGeometryType::TRIANGLE);
                check(device, "new geometry")?;
                let n_v = mesh.positions.len().max(1);
                let v = sys::rtcSetNewGeometryBuffer(
                    geometry,
                    sys::RTCBufferType::VERTEX,
                    0,
                    sys::RTCFormat::FLOAT3,
                    3 * 4,
                    n_v,
                ) as *mut f32;
                let n_t = mesh.triangles.len();
                let t = sys::rtcSetNewGeometryBuffer(
                    geometry,
                    sys::RTCBufferType::INDEX,
                    0,
                    sys::RTCFormat::UINT3,
                    3 * 4,
                    n_t,
                ) as *mut u32;
                if v.is_null() || (t.is_null() && n_t > 0) {
                    sys::rtcReleaseGeometry(geometry);
                    check(device, "geometry buffers")?;
                    bail!("Embree: cannot allocate the geometry's buffers");
                }
                let vs = std::slice::from_raw_parts_mut(v, 3 * n_v);
                for (k, p) in mesh.positions.iter().enumerate() {
                    vs[3 * k..3 * k + 3].copy_from_slice(&[p.x, p.y, p.z]);
                }
                if n_t > 0 {
                    let ts = std::slice::from_raw_parts_mut(t, 3 * n_t);
                    for (k, tri) in mesh.triangles.iter().enumerate() {
                        ts[3 * k..3 * k + 3].copy_from_slice(tri);
                    }
                }
                sys::rtcCommitGeometry(geometry);
                sys::rtcAttachGeometry(out.scene, geometry);
                sys::rtcReleaseGeometry(geometry);
                sys::rtcCommitScene(out.scene);
                check(device, "building the scene")?;
                Ok(out)
            }
        }

        fn ray(origin: Vec3, dir: Vec3, tmin: f32) -> sys::RTCRay {
            sys::RTCRay {
                org_x: origin.x,
                org_y: origin.y,
                org_z: origin.z,
                tnear: tmin,
                dir_x: dir.x,
                dir_y: dir.y,
                dir_z: dir.z,
                time: 0.0,
                tfar: f32::INFINITY,
                mask: u32::MAX,
                id: 0,
                flags: 0,
            }
        }

        /// The closest triangle hit at t > `tmin`, and its t.
        pub fn closest(&self, origin: Vec3, dir: Vec3, tmin: f32) -> Option<(u32, f32)> {
            let mut rh = sys::RTCRayHit {
                ray: Self::ray(origin, dir, tmin),
                hit: sys::RTCHit {
                    geomID: sys::RTC_INVALID_GEOMETRY_ID,
                    ..Default::default()
                },
            };
            unsafe { sys::rtcIntersect1(self.scene, &mut rh, null_mut()) };
            (rh.hit.geomID != sys::RTC_INVALID_GEOMETRY_ID).then_some((rh.hit.primID, rh.ray.tfar))
        }

        /// Occlusion of rays from `origin` along `dirs`: sixteen per `rtcOccluded16` call where the
        /// CPU has AVX-512 (Embree's 16-wide kernels), else eight per `rtcOccluded8` (on AVX2,
        /// sixteen were slower). Occlusion is exact either way: the same bits.
        pub fn occluded_from(&self, origin: Vec3, dirs: &[Vec3], tmin: f32, out: &mut [bool]) {
            if self.packet16 {
                self.occluded_from16(origin, dirs, tmin, out)
            } else {
                self.occluded_from8(origin, dirs, tmin, out)
            }
        }

        occluded_packets!(
            /// [`occluded_from`](Self::occluded_from) in packets of sixteen.
            occluded_from16, 16, RTCRay16, rtcOccluded16, 64
        );
        occluded_packets!(
            /// [`occluded_from`](Self::occluded_from) in packets of eight.
            occluded_from8, 8, RTCRay8, rtcOccluded8, 32
        );

        /// Whether anything is hit at t > `tmin` (Embree sets tfar to −∞ then).
        pub fn occluded(&self, origin: Vec3, dir: Vec3, tmin: f32) -> bool {
            let mut r = Self::ray(origin, dir, tmin);
            unsafe { sys::rtcOccluded1(self.scene, &mut r, null_mut()) };
            r.tfar == f32::NEG_INFINITY
        }
    }

    impl Drop for EmbreeScene {
        fn drop(&mut self) {
            unsafe {
                if !self.scene.is_null() {
                    sys::rtcReleaseScene(self.scene);
                }
                sys::rtcReleaseDevice(self.device);
            }
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
    use matedit_contract::manifest::Named;

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
        let built = Scene::with_accel(&m, Accel::Embree);
        assert_eq!(built.is_ok(), Accel::Embree.available());
        if let Err(e) = built {
            assert!(e.to_string().contains("--features embree"), "{e}");
        }
        assert_eq!(Accel::from_name("embree"), Some(Accel::Embree));
        assert_eq!(Accel::from_name("optix"), None);
    }

    /// Primary rays on a grid and shadow rays from the hits towards fixed directions, through
    /// both backends: the same triangle for all but 0.1 % of the rays, and then t, u, v equal
    /// bit for bit; the same occlusion (Embree's single rays and packets alike) for all but 0.1 %.
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
        for f in [
            "common-3d-test-models/teapot.obj",
            "common-3d-test-models/stanford-bunny.obj",
            "codeyeJR-Models/chair.obj",
            "Azdepredador-binvox/sofa.obj",
        ] {
            if assets.join(f).is_file() {
                specs.push(assets.join(f).display().to_string());
            }
        }
        let lights = [
            Vec3::new(0.3, 0.9, 0.2),
            Vec3::new(-0.7, 0.4, 0.6),
            Vec3::new(0.1, 0.2, -1.0),
        ];
        for spec in &specs {
            let Ok(Shape::Mesh(m)) = Shape::load(spec, UpAxis::PosY) else {
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
                            let ls: Vec<Vec3> = lights.iter().map(|l| l.normalize()).collect();
                            let mut packet = vec![false; ls.len()];
                            e.occluded_from(p, &ls, 1e-4, &mut packet);
                            for (l, in_packet) in ls.iter().zip(packet) {
                                shadow += 1;
                                let single = e.occluded(p, *l, 1e-4);
                                if o.occluded(p, *l, 1e-4) != single || in_packet != single {
                                    shadow_differ += 1;
                                }
                            }
                        }
                        (None, None) => {}
                        _ => differ += 1,
                    }
                }
            }
            assert!(
                differ * 1000 <= rays,
                "{spec}: {differ} of {rays} primary rays hit different triangles"
            );
            assert!(
                shadow_differ * 1000 <= shadow,
                "{spec}: {shadow_differ} of {shadow} shadow rays disagree"
            );
        }
    }

    /// Packets of eight and of sixteen give each ray the answer of a single-ray query, whatever
    /// the packet's fill (1 to 40 rays: full, partial and mixed packets), from points on the
    /// surface of self-shadowing shapes, grazing directions included.
    #[cfg(feature = "embree")]
    #[test]
    fn embree_packets_of_eight_and_sixteen_agree_with_single_rays() {
        use crate::shapes::{Shape, UpAxis};
        let mut checked = (0, 0);
        for spec in ["procedural:chair:2", "procedural:sofa:3", "procedural:car:1"] {
            let Ok(Shape::Mesh(m)) = Shape::load(spec, UpAxis::PosY) else {
                panic!("{spec}")
            };
            let Backend::Embree(e) = Scene::with_accel(&m, Accel::Embree).unwrap().backend else {
                unreachable!()
            };
            let mut state = 0x9e37_79b9_u32;
            let mut next = move || {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                state as f32 / u32::MAX as f32
            };
            for k in 0..300 {
                // A point on a random triangle, just off its face.
                let t = m.triangles[(next() * m.triangles.len() as f32) as usize % m.triangles.len()];
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                let (u, v) = (next(), next());
                let (u, v) = if u + v > 1.0 { (1.0 - u, 1.0 - v) } else { (u, v) };
                let ng = (b - a).cross(c - a).normalize_or_zero();
                let p = a + u * (b - a) + v * (c - a) + 1e-4 * ng;
                let count = 1 + k % 40;
                let dirs: Vec<Vec3> = (0..count)
                    .map(|_| {
                        let d = Vec3::new(2.0 * next() - 1.0, 2.0 * next() - 1.0, 2.0 * next() - 1.0);
                        // Every fifth ray grazes the face.
                        let d = if checked.1 % 5 == 0 {
                            d - 0.999 * d.dot(ng) * ng
                        } else {
                            d
                        };
                        checked.1 += 1;
                        d.normalize_or(Vec3::Y)
                    })
                    .collect();
                let single: Vec<bool> = dirs.iter().map(|&d| e.occluded(p, d, 1e-4)).collect();
                let (mut p8, mut p16) = (vec![false; count], vec![false; count]);
                e.occluded_from8(p, &dirs, 1e-4, &mut p8);
                e.occluded_from16(p, &dirs, 1e-4, &mut p16);
                assert_eq!(p8, single, "{spec}: packets of eight at point {k}");
                assert_eq!(p16, single, "{spec}: packets of sixteen at point {k}");
                checked.0 += single.iter().filter(|&&b| b).count();
            }
        }
        // Both answers occur, or the comparison proves little.
        assert!(
            checked.0 > checked.1 / 10 && checked.0 < checked.1 * 9 / 10,
            "{checked:?}"
        );
    }

    /// Whole renders with shadows: masks and regions equal but for 0.1 % of the pixels, radiance
    /// equal wherever the normals are (the same triangle), and Embree's images the same bits on
    /// one and two threads.
    #[cfg(feature = "embree")]
    #[test]
    fn embree_renders_agree_with_obvhs_and_do_not_depend_on_threads() {
        use crate::preview::{EnvRes, RenderOptions, Shadows, render};
        let opts = |shape: &str, accel| RenderOptions {
            shape: shape.into(),
            up: Default::default(),
            yaw_deg: 30.0,
            pitch_deg: 10.0,
            brdf: "plastic:0.2:0.7,0.3,0.2".parse().unwrap(),
            env: "builtin:sky".into(),
            env_rotation_deg: 20.0,
            env_res: EnvRes::Rows(16),
            res: 96,
            shadows: Shadows::On,
            quality: matedit_physics::shading::Quality::Fast,
            progress: false,
            accel,
        };
        for shape in ["procedural:chair:5", "procedural:sofa:6", "procedural:car:7"] {
            let a = render(&opts(shape, Accel::Obvhs)).unwrap();
            let b = render(&opts(shape, Accel::Embree)).unwrap();
            let (ga, gb) = (&a.gbuffer, &b.gbuffer);
            let px = ga.mask.len();
            let mask_differ = (0..px)
                .filter(|&k| ga.mask[k] != gb.mask[k] || ga.region[k] != gb.region[k])
                .count();
            assert!(
                mask_differ * 1000 <= px,
                "{shape}: {mask_differ} of {px} pixels differ in mask or region"
            );
            let same_triangle: Vec<usize> = (0..px)
                .filter(|&k| ga.mask[k] > 0.0 && ga.normal[k] == gb.normal[k] && ga.position[k] == gb.position[k])
                .collect();
            let shaded_differ = same_triangle
                .iter()
                .filter(|&&k| a.radiance[k] != b.radiance[k])
                .count();
            assert!(
                shaded_differ * 1000 <= px,
                "{shape}: {shaded_differ} of {} pixels on the same triangle shade differently",
                same_triangle.len()
            );
            let bits = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
                let r = pool.install(|| render(&opts(shape, Accel::Embree)).unwrap());
                r.radiance.iter().flatten().map(|v| v.to_bits()).collect::<Vec<u32>>()
            };
            assert_eq!(bits(1), bits(2), "{shape}: Embree's image depends on the thread count");
        }
    }
}

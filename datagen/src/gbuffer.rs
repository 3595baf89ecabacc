//! The geometry buffer of an orthographic view: per-pixel camera-space normals, coverage mask,
//! hit points and geometric normals (for shadow rays).

use crate::accel::Scene;
use crate::shapes::{Mesh, Shape};
use glam::{Mat3, Vec3};
use matedit_physics::camera::pixel_center;
use rayon::prelude::*;
use std::cell::RefCell;
use std::sync::{Arc, OnceLock, RwLock};

/// Per-pixel geometry of an `res × res` view, row-major from the top row.
#[derive(Clone, Debug)]
pub struct GBuffer {
    /// Image side in pixels.
    pub res: usize,
    /// Camera-space shading normal (unit) where covered, zero elsewhere.
    pub normal: Vec<[f32; 3]>,
    /// 1 where the pixel centre sees the object, 0 elsewhere.
    pub mask: Vec<f32>,
    /// Camera-space hit point.
    pub position: Vec<[f32; 3]>,
    /// Geometric normal, oriented towards the camera.
    pub geometric_normal: Vec<[f32; 3]>,
    /// Semantic region id of the visible surface (0 outside the mask and for the sphere).
    pub region: Vec<u32>,
}

/// Camera ray origins start at z = 2, outside the unit ball every normalised shape fits in.
const CAMERA_Z: f32 = 2.0;

impl GBuffer {
    /// Traces the pixel centres against `shape`.
    pub fn trace(shape: &Shape, scene: Option<&Scene>, res: usize) -> GBuffer {
        Self::trace_rotated(shape, scene, res, Mat3::IDENTITY)
    }

    /// Traces the pixel centres against `shape` turned by `rotation` (object → camera space),
    /// without moving the mesh: rays go into object space and normals come back, so one BVH
    /// serves every view of a shape.
    pub fn trace_rotated(shape: &Shape, scene: Option<&Scene>, res: usize, rotation: Mat3) -> GBuffer {
        let px: Vec<_> = (0..res * res)
            .into_par_iter()
            .map(|p| {
                let (x, y) = pixel_center(p % res, p / res, res);
                let (x, y) = (x as f32, y as f32);
                match (shape, scene) {
                    (Shape::Sphere, _) => sphere_pixel(x, y),
                    (Shape::Mesh(mesh), Some(scene)) => mesh_pixel(mesh, scene, x, y, rotation),
                    (Shape::Mesh(_), None) => None,
                }
            })
            .collect();
        let mut g = GBuffer {
            res,
            normal: vec![[0.0; 3]; res * res],
            mask: vec![0.0; res * res],
            position: vec![[0.0; 3]; res * res],
            geometric_normal: vec![[0.0; 3]; res * res],
            region: vec![0; res * res],
        };
        for (p, hit) in px.into_iter().enumerate() {
            if let Some((pos, ng, ns, region)) = hit {
                g.region[p] = region;
                g.normal[p] = ns.to_array();
                g.mask[p] = 1.0;
                g.position[p] = pos.to_array();
                g.geometric_normal[p] = ng.to_array();
            }
        }
        g
    }

    /// Shadow rays for pixel `p` towards camera-space `dirs`: `out[t]` is 1 when direction t is
    /// open, 0 when the object blocks it. `to_object` turns camera-space vectors into the frame
    /// of `scene` (see [`trace_rotated`](GBuffer::trace_rotated)). Directions below the geometric
    /// surface (the object itself blocks them) or behind the shading normal (they contribute
    /// nothing) get no ray.
    pub fn shadow_visibility(&self, scene: &Scene, to_object: Mat3, p: usize, dirs: &[[f32; 3]], out: &mut [f32]) {
        self.shadow_rays(scene, to_object, p, dirs, |_, d| to_object * d, out);
    }

    /// [`shadow_visibility`](GBuffer::shadow_visibility) with `turn(t, d)` giving direction `t`
    /// in the scene's frame: a table of a view's turned directions serves every pixel.
    fn shadow_rays(
        &self,
        scene: &Scene,
        to_object: Mat3,
        p: usize,
        dirs: &[[f32; 3]],
        turn: impl Fn(usize, Vec3) -> Vec3,
        out: &mut [f32],
    ) {
        let ng = Vec3::from(self.geometric_normal[p]);
        let ns = Vec3::from(self.normal[p]);
        let origin = to_object * (Vec3::from(self.position[p]) + ng * 1e-4);
        // The rays worth tracing, traced together (Embree takes them in packets of eight, so
        // which rays share a packet stays as it always was), in per-thread buffers: this runs
        // once per pixel.
        thread_local! {
            static SCRATCH: RefCell<(Vec<usize>, Vec<Vec3>, Vec<bool>)> = const { RefCell::new((Vec::new(), Vec::new(), Vec::new())) };
        }
        SCRATCH.with_borrow_mut(|(traced, rays, blocked)| {
            traced.clear();
            rays.clear();
            for (t, (d, o)) in dirs.iter().zip(out.iter_mut()).enumerate() {
                let d = Vec3::from(*d);
                *o = 0.0;
                if d.dot(ng) > 0.0 && d.dot(ns) > 0.0 {
                    traced.push(t);
                    rays.push(turn(t, d));
                }
            }
            blocked.clear();
            blocked.resize(rays.len(), false);
            scene.occluded_from(origin, rays, 0.0, blocked);
            for (&t, &b) in traced.iter().zip(blocked.iter()) {
                out[t] = if b { 0.0 } else { 1.0 };
            }
        });
    }

    /// Number of covered pixels.
    pub fn covered(&self) -> usize {
        self.mask.iter().filter(|&&m| m > 0.0).count()
    }
}

/// The shadow rays of one G-buffer, traced once per pixel and set of light directions and then
/// reused: visibility does not depend on the material, and a dataset sample shades each pixel
/// under the same directions for I and for O. What it hands out is
/// [`GBuffer::shadow_visibility`]'s result, bit for bit.
pub struct SharedVisibility<'a> {
    g: &'a GBuffer,
    scene: &'a Scene,
    to_object: Mat3,
    /// One table per distinct direction set (a measured material's exact shader keeps the
    /// zero-radiance texels that the fast shader drops): per pixel, one bit per direction, set
    /// where the direction is open.
    tables: RwLock<Vec<Arc<VisibilityTable>>>,
}

struct VisibilityTable {
    dirs: Vec<[f32; 3]>,
    /// `dirs` in the scene's frame.
    turned: Vec<Vec3>,
    open: Vec<OnceLock<Box<[u64]>>>,
}

impl<'a> SharedVisibility<'a> {
    /// No ray is traced until a pixel asks.
    pub fn new(g: &'a GBuffer, scene: &'a Scene, to_object: Mat3) -> Self {
        Self {
            g,
            scene,
            to_object,
            tables: RwLock::new(Vec::new()),
        }
    }

    /// [`GBuffer::shadow_visibility`] for pixel `p` towards `dirs`, traced on the first request.
    pub fn fill(&self, p: usize, dirs: &[[f32; 3]], out: &mut [f32]) {
        self.fill_from(&self.table(dirs), p, dirs, out);
    }

    /// The table of `dirs` looked up once, for a shader that asks every pixel for the same
    /// directions ([`SharedView::fill`]): the lookup compares every direction, which costs as
    /// much as handing out the bits.
    pub fn view<'v>(&'v self, dirs: &'v [[f32; 3]]) -> SharedView<'v> {
        SharedView {
            shared: self,
            table: self.table(dirs),
            dirs,
        }
    }

    fn fill_from(&self, table: &VisibilityTable, p: usize, dirs: &[[f32; 3]], out: &mut [f32]) {
        let open = table.open[p].get_or_init(|| {
            self.g
                .shadow_rays(self.scene, self.to_object, p, dirs, |t, _| table.turned[t], out);
            out.chunks(64)
                .map(|chunk| {
                    let mut word = 0_u64;
                    for (j, &v) in chunk.iter().enumerate() {
                        word |= u64::from(v > 0.0) << j;
                    }
                    word
                })
                .collect()
        });
        for (chunk, &word) in out.chunks_mut(64).zip(open.iter()) {
            for (j, o) in chunk.iter_mut().enumerate() {
                *o = ((word >> j) & 1) as f32;
            }
        }
    }

    /// The table of `dirs`, made on first sight. Directions are compared by value, bit for bit
    /// (each shader owns its own copy), under a shared lock: pixels look up concurrently.
    fn table(&self, dirs: &[[f32; 3]]) -> Arc<VisibilityTable> {
        // Every pixel asks, so the comparison has no early exit (it vectorises).
        let same = |t: &&Arc<VisibilityTable>| {
            t.dirs.len() == dirs.len()
                && t.dirs
                    .as_flattened()
                    .iter()
                    .zip(dirs.as_flattened())
                    .fold(0, |diff, (a, b)| diff | (a.to_bits() ^ b.to_bits()))
                    == 0
        };
        if let Some(t) = self.tables.read().unwrap_or_else(|e| e.into_inner()).iter().find(same) {
            return t.clone();
        }
        let mut tables = self.tables.write().unwrap_or_else(|e| e.into_inner());
        if let Some(t) = tables.iter().find(same) {
            return t.clone();
        }
        let t = Arc::new(VisibilityTable {
            dirs: dirs.to_vec(),
            turned: dirs.iter().map(|&d| self.to_object * Vec3::from(d)).collect(),
            open: (0..self.g.mask.len()).map(|_| OnceLock::new()).collect(),
        });
        tables.push(t.clone());
        t
    }
}

/// [`SharedVisibility`] for one set of directions, its table looked up once.
pub struct SharedView<'v> {
    shared: &'v SharedVisibility<'v>,
    table: Arc<VisibilityTable>,
    dirs: &'v [[f32; 3]],
}

impl SharedView<'_> {
    /// [`SharedVisibility::fill`]. `dirs` is the very slice the view was made for (the same
    /// address and length, so the same values: it is borrowed for the view's life) or any other,
    /// which is looked up as usual.
    pub fn fill(&self, p: usize, dirs: &[[f32; 3]], out: &mut [f32]) {
        if std::ptr::eq(dirs, self.dirs) {
            self.shared.fill_from(&self.table, p, dirs, out);
        } else {
            self.shared.fill(p, dirs, out);
        }
    }
}

/// Position, geometric normal, shading normal, region.
type PixelHit = Option<(Vec3, Vec3, Vec3, u32)>;

fn sphere_pixel(x: f32, y: f32) -> PixelHit {
    // f64 so that the normal is unit to full f32 precision up to the silhouette.
    let r2 = x as f64 * x as f64 + y as f64 * y as f64;
    if r2 >= 1.0 {
        return None;
    }
    let n = Vec3::new(x, y, (1.0 - r2).sqrt() as f32);
    Some((n, n, n, 0))
}

fn mesh_pixel(mesh: &Mesh, scene: &Scene, x: f32, y: f32, rotation: Mat3) -> PixelHit {
    let to_object = rotation.transpose();
    let hit = scene.intersect(to_object * Vec3::new(x, y, CAMERA_Z), to_object * Vec3::NEG_Z, 0.0)?;
    let tri = mesh.triangles[hit.triangle as usize];
    let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
    let pos = Vec3::new(x, y, CAMERA_Z - hit.t);
    // Meshes are two-sided: a back face seen by the camera is shaded as its front.
    let mut ng = (rotation * (b - a).cross(c - a)).normalize_or_zero();
    if ng.z < 0.0 {
        ng = -ng;
    }
    let [n0, n1, n2] = mesh.corner_normals[hit.triangle as usize];
    let w0 = 1.0 - hit.u - hit.v;
    let mut ns = (rotation * (n0 * w0 + n1 * hit.u + n2 * hit.v)).normalize_or_zero();
    // File normals may be wound opposite to the faces; keep them on the camera's side.
    if ns.dot(ng) < 0.0 {
        ns = -ns;
    }
    if ns == Vec3::ZERO {
        ns = ng;
    }
    Some((pos, ng, ns, mesh.triangle_region[hit.triangle as usize]))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shared table hands out what each pixel's own shadow rays give, for two direction sets
    /// (one a subset, as a fast and an exact shader of the same light), on first and repeated
    /// requests, from several threads, in a rotated view of a shape that shadows itself.
    #[test]
    fn shared_visibility_equals_tracing_each_request() {
        use crate::shapes::UpAxis;
        let Ok(Shape::Mesh(mesh)) = Shape::load("procedural:chair:3", UpAxis::PosY) else {
            panic!("procedural chair")
        };
        let scene = Scene::new(&mesh);
        let rotation = Mat3::from_rotation_x(0.35) * Mat3::from_rotation_y(-0.8);
        let g = GBuffer::trace_rotated(&Shape::Mesh(mesh.clone()), Some(&scene), 24, rotation);
        let all: Vec<[f32; 3]> = (0..48)
            .map(|k| {
                let (a, z) = (k as f32 * 2.4, 1.0 - 2.0 * (k as f32 + 0.5) / 48.0);
                let r = (1.0 - z * z).sqrt();
                [r * a.cos(), r * a.sin(), z]
            })
            .collect();
        let some: Vec<[f32; 3]> = all.iter().step_by(3).copied().collect();
        let shared = SharedVisibility::new(&g, &scene, rotation.transpose());
        let covered: Vec<usize> = (0..g.mask.len()).filter(|&p| g.mask[p] > 0.0).collect();
        assert!(covered.len() > 100);
        let mut blocked = 0;
        for round in 0..2 {
            for dirs in [&all, &some] {
                let seen: Vec<(Vec<f32>, Vec<f32>)> = covered
                    .par_iter()
                    .map(|&p| {
                        let (mut a, mut b) = (vec![0.5; dirs.len()], vec![0.5; dirs.len()]);
                        shared.fill(p, dirs, &mut a);
                        g.shadow_visibility(&scene, rotation.transpose(), p, dirs, &mut b);
                        (a, b)
                    })
                    .collect();
                for (a, b) in &seen {
                    assert_eq!(a, b, "round {round}");
                    blocked += b.iter().filter(|&&v| v == 0.0).count();
                }
            }
        }
        assert!(blocked > 0, "the chair shadows some directions");
        assert_eq!(shared.tables.read().unwrap().len(), 2, "one table per direction set");
        // A view hands out the same bits for the slice it was made for, and for any other slice
        // (an equal copy, a subset) looks it up as usual.
        let view = shared.view(&all);
        let copy = all.clone();
        for dirs in [&all, &copy, &some] {
            for &p in &covered {
                let (mut a, mut b) = (vec![0.5; dirs.len()], vec![0.5; dirs.len()]);
                view.fill(p, dirs, &mut a);
                g.shadow_visibility(&scene, rotation.transpose(), p, dirs, &mut b);
                assert_eq!(a, b, "view, pixel {p}");
            }
        }
        assert_eq!(shared.tables.read().unwrap().len(), 2, "no new table for the view");
    }

    #[test]
    fn sphere_normals_are_unit_and_match_pixel_positions() {
        let g = GBuffer::trace(&Shape::Sphere, None, 32);
        let covered = g.covered();
        // π/4 of the pixels, within the boundary's pixel count.
        assert!((covered as f64 - 32.0 * 32.0 * std::f64::consts::FRAC_PI_4).abs() < 4.0 * 32.0);
        for p in 0..g.normal.len() {
            if g.mask[p] > 0.0 {
                let n = Vec3::from(g.normal[p]);
                assert!((n.length() - 1.0).abs() < 1e-6);
                let (x, y) = pixel_center(p % 32, p / 32, 32);
                assert!((n.x - x as f32).abs() < 1e-6 && (n.y - y as f32).abs() < 1e-6);
            }
        }
    }
}

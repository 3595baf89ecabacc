//! One training tuple of Fig. 2: the input image I (material m), the target image O (same shape,
//! view and light, material m_t), camera-space normals, mask, region map and the environment as
//! the camera sees it.
//!
//! It renders a sample the plan has fully described ([`super::spec::SampleSpec`]); it makes no
//! choice of its own.
//!
//! Shortcuts ("model only what a scene needs"), each measured in `docs/PERFORMANCE.md`:
//! one BVH per shape serves all its views (rays are turned into object space instead);
//! no shadow rays for convex shapes under `shadows = "auto"`; a pixel's shadow rays traced once for
//! I and O (visibility does not depend on the material); a region that no pixel shows gets no
//! shader; the `zonal` quality shades a grid of normals per material instead of every pixel,
//! and shares one set of environment spectra between all materials on the same grid; with
//! shadows, it sums per pixel only the texels a shadow ray found blocked and takes their light
//! off.

use super::catalogue::ShapeItem;
use super::materials::MaterialEntry;
use super::plan::Plan;
use super::spec::SampleSpec;
use crate::accel::Scene;
use crate::gbuffer::{GBuffer, SharedVisibility};
use crate::preview::Shadows;
use crate::shapes::{Mesh, Shape};
use anyhow::{Context, Result};
use glam::Mat3;
use matedit_assets::envfile::load_env;
use matedit_contract::io::{encode_env_exr, encode_exr_channels};
use matedit_contract::records::SampleRecord;
use matedit_physics::EnvMap;
use matedit_physics::shading::fast::FastShader;
use matedit_physics::shading::zonal::{PolarNormals, ZonalEnv, ZonalKernel, ZonalRefusal, shade_image_zonal};
use matedit_physics::shading::{Quality, Shader, VisibilityFn, remove_blocked_light, shade_with};
use rayon::prelude::*;
use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex, OnceLock};

/// A loaded shape with its BVH.
pub struct LoadedShape {
    /// The mesh (object space, normalised).
    pub shape: Shape,
    /// Its BVH.
    pub scene: Option<Scene>,
    /// Whether no part of it can shadow another.
    pub convex: bool,
}

/// Whether every vertex lies on or behind every face's plane (then no point can see another
/// part of the surface, so shadow rays are pointless). Gives up, answering `false`, beyond
/// `budget` vertex–plane tests.
pub fn is_convex(mesh: &Mesh, budget: usize) -> bool {
    if mesh.triangles.len().saturating_mul(mesh.positions.len()) > budget {
        return false;
    }
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = (b - a).cross(c - a);
        let len = n.length();
        if len == 0.0 {
            continue;
        }
        let n = n / len;
        // Faces may be wound either way: all vertices must sit on one side.
        let (mut above, mut below) = (false, false);
        for p in &mesh.positions {
            let d = n.dot(*p - a);
            above |= d > 1e-5;
            below |= d < -1e-5;
            if above && below {
                return false;
            }
        }
    }
    true
}

/// Assets loaded once and shared between threads, by catalogue index. Loading happens outside
/// the lock (two threads may load the same asset once each; both get equal values). When
/// `capacity` is reached the cache starts over.
struct Cache<T> {
    map: Mutex<HashMap<usize, Arc<T>>>,
    capacity: usize,
}

impl<T> Cache<T> {
    fn new(capacity: usize) -> Self {
        Self {
            map: Mutex::new(HashMap::new()),
            capacity,
        }
    }

    fn get_or_load(&self, k: usize, load: impl FnOnce() -> Result<T>) -> Result<Arc<T>> {
        let poisoned = || anyhow::anyhow!("asset cache poisoned by a panicked thread");
        if let Some(v) = self.map.lock().map_err(|_| poisoned())?.get(&k) {
            return Ok(v.clone());
        }
        let v = Arc::new(load()?);
        let mut map = self.map.lock().map_err(|_| poisoned())?;
        if map.len() >= self.capacity {
            map.clear();
        }
        map.insert(k, v.clone());
        Ok(v)
    }
}

/// A material's zonal kernel for the log: its rows, or why it has none.
pub type ZonalStatus = std::result::Result<usize, ZonalRefusal>;

/// Shared, thread-safe state for rendering the samples of a plan.
pub struct Renderer<'a> {
    plan: &'a Plan,
    materials: &'a [Option<MaterialEntry>],
    shapes: Cache<LoadedShape>,
    envs: Cache<EnvMap>,
    /// Per catalogue material, its zonal kernel (`zonal` quality) or why it has none, built once.
    zonal: Vec<OnceLock<Result<ZonalKernel, ZonalRefusal>>>,
}

/// Shapes kept loaded at once; samples are ordered by shape, so a small cache suffices.
const SHAPE_CACHE: usize = 16;

/// The rendered pixels of a sample, before encoding.
pub struct SamplePixels {
    /// Record (files and checksums not yet filled).
    pub record: SampleRecord,
    /// EXR channels of the image file.
    pub image: Vec<(&'static str, Vec<f32>)>,
    /// The camera-space environment.
    pub env: EnvMap,
}

impl<'a> Renderer<'a> {
    /// A renderer for `plan` with its prepared `materials` (catalogue order).
    pub fn new(plan: &'a Plan, materials: &'a [Option<MaterialEntry>]) -> Self {
        Self {
            plan,
            materials,
            shapes: Cache::new(SHAPE_CACHE),
            // Environments are small (a few hundred KB at 2 × 64 rows): keep them all.
            envs: Cache::new(usize::MAX),
            zonal: (0..materials.len()).map(|_| OnceLock::new()).collect(),
        }
    }

    /// Builds the zonal kernels of `materials` (catalogue indices) in parallel, one material per
    /// thread, ahead of rendering (otherwise each is built on first use, on one thread while the
    /// others wait for it). A no-op unless the quality is `zonal`. `on_done` is called after each
    /// kernel. Returns how many were built.
    pub fn prepare_zonal(&self, materials: &[usize], on_done: &(dyn Fn() + Sync)) -> Result<usize> {
        if self.plan.settings.quality != Quality::Zonal {
            return Ok(0);
        }
        let todo: Vec<usize> = materials
            .iter()
            .copied()
            .filter(|&k| self.zonal.get(k).is_some_and(|c| c.get().is_none()))
            .collect();
        // A kernel is built without rayon, so a thread waiting on another's cell cannot hold up
        // the one building it.
        todo.par_iter().try_for_each(|&k| {
            if let Some(kernel) = self.zonal_kernel(k)? {
                kernel.prepare_for_maps(self.plan.settings.env_rows);
            }
            on_done();
            Ok::<_, anyhow::Error>(())
        })?;
        Ok(todo.len())
    }

    /// The zonal kernel of material `k`, built and checked on first use.
    fn zonal_kernel(&self, k: usize) -> Result<Option<&ZonalKernel>> {
        Ok(self.zonal_outcome(k)?.as_ref().ok())
    }

    fn zonal_outcome(&self, k: usize) -> Result<&Result<ZonalKernel, ZonalRefusal>> {
        let render = &self.material(k)?.render;
        let cell = self.zonal.get(k).context("material index out of range")?;
        Ok(cell.get_or_init(|| ZonalKernel::checked(render, &Default::default())))
    }

    /// For the log: each of `materials` (catalogue indices) with its kernel's rows or why it has
    /// none. Builds what is not built yet.
    pub fn zonal_report(&self, materials: &[usize]) -> Result<Vec<(String, ZonalStatus)>> {
        materials
            .iter()
            .map(|&k| {
                let outcome = self.zonal_outcome(k)?;
                let id = self.plan.catalogue.materials[k].id.clone();
                Ok((id, outcome.as_ref().map(|z| z.grid().rows).map_err(|e| *e)))
            })
            .collect()
    }

    fn shape(&self, k: usize) -> Result<Arc<LoadedShape>> {
        self.shapes.get_or_load(k, || {
            let item: &ShapeItem = &self.plan.catalogue.shapes[k];
            let shape = Shape::load(&item.spec, item.up).with_context(|| format!("shape {}", item.id))?;
            let (scene, convex) = match &shape {
                Shape::Mesh(m) => (
                    Some(Scene::with_accel(m, self.plan.settings.accel)?),
                    is_convex(m, 200_000_000),
                ),
                Shape::Sphere => (None, true),
            };
            Ok(LoadedShape { shape, scene, convex })
        })
    }

    /// The environment at twice the output resolution (what [`EnvMap::rotated`] reads).
    fn env(&self, k: usize) -> Result<Arc<EnvMap>> {
        self.envs.get_or_load(k, || {
            let item = &self.plan.catalogue.envs[k];
            let (map, _) = load_env(&item.spec).with_context(|| format!("environment {}", item.id))?;
            Ok(map.resampled(2 * self.plan.settings.env_rows, 0.0))
        })
    }

    fn material(&self, k: usize) -> Result<&MaterialEntry> {
        self.materials
            .get(k)
            .and_then(Option::as_ref)
            .with_context(|| format!("material {} was not prepared", self.plan.catalogue.materials[k].id))
    }

    /// Renders a described sample.
    pub fn render(&self, spec: &SampleSpec) -> Result<SamplePixels> {
        let plan = self.plan;
        let st = &plan.settings;
        let (azimuth, elevation, rotation) = (spec.view_azimuth_deg, spec.view_elevation_deg, spec.env_rotation_deg);
        let loaded = self.shape(spec.shape)?;
        let item = &plan.catalogue.shapes[spec.shape];
        let (materials, targets) = (&spec.materials, &spec.targets);

        // Object → camera: yaw by −azimuth (the camera moves +azimuth around the object), then
        // pitch by the elevation (the camera looks down).
        let rot = Mat3::from_rotation_x((elevation as f32).to_radians())
            * Mat3::from_rotation_y((-azimuth as f32).to_radians());
        let res = st.resolution;
        let g = GBuffer::trace_rotated(&loaded.shape, loaded.scene.as_ref(), res, rot);
        let region_of: Vec<u32> = if st.per_region {
            g.region.clone()
        } else {
            vec![0; g.region.len()]
        };

        // L_cam(d) = L_src(R_y(azimuth − rotation) · R_x(−elevation) · d).
        let env = self.env(spec.env)?.tilted(st.env_rows, azimuth - rotation, -elevation);

        let shadows = st.shadows.for_shape(loaded.convex) == Shadows::On && loaded.scene.is_some();
        let shared = loaded
            .scene
            .as_ref()
            .map(|scene| SharedVisibility::new(&g, scene, rot.transpose()));
        let visibility = |p: usize, dirs: &[[f32; 3]], out: &mut [f32]| {
            if let Some(s) = &shared {
                s.fill(p, dirs, out);
            }
        };
        let vis: Option<&VisibilityFn<'_>> = if shadows { Some(&visibility) } else { None };

        // The zonal quality shares the pixels' polar normals between I and O and every region,
        // and the environment's spectra between materials on the same grid; with shadows, the
        // blocked light is then taken off per pixel.
        let zonal = st.quality == Quality::Zonal;
        let polar = zonal.then(|| PolarNormals::new(&g.normal, &g.mask));
        let mut spectra: Vec<ZonalEnv> = Vec::new();
        let mut image_i = vec![[0.0_f32; 3]; res * res];
        let mut image_o = vec![[0.0_f32; 3]; res * res];
        for (r, (&mi, &mt)) in materials.iter().zip(targets).enumerate() {
            let mask_r: Vec<f32> = g
                .mask
                .iter()
                .zip(&region_of)
                .map(|(&m, &reg)| if m > 0.0 && reg as usize == r { 1.0 } else { 0.0 })
                .collect();
            if !mask_r.iter().any(|&m| m > 0.0) {
                continue;
            }
            for (mat, out) in [(mi, &mut image_i), (mt, &mut image_o)] {
                let kernel = if zonal { self.zonal_kernel(mat)? } else { None };
                let (rgb, _) = match (&polar, kernel) {
                    (Some(polar), Some(kernel)) => {
                        let at = match spectra.iter().position(|e| e.serves(&kernel.grid())) {
                            Some(i) => i,
                            None => {
                                spectra.push(ZonalEnv::new(&env, kernel.grid()));
                                spectra.len() - 1
                            }
                        };
                        let unshadowed = shade_image_zonal(kernel, &spectra[at], polar, &mask_r);
                        // The per-texel tables of the fast shader only where shadows need them.
                        let fast = match vis {
                            Some(vis) => FastShader::new(&self.material(mat)?.render, &env).map(|f| (vis, f)),
                            None => None,
                        };
                        match fast {
                            Some((vis, fast)) => {
                                // Every pixel asks for the fast shader's directions: their table
                                // is looked up once.
                                let view = shared.as_ref().map(|s| s.view(fast.light_dirs()));
                                let vis = |p: usize, dirs: &[[f32; 3]], out: &mut [f32]| match &view {
                                    Some(view) => view.fill(p, dirs, out),
                                    None => vis(p, dirs, out),
                                };
                                let (rgb, bad) = remove_blocked_light(&fast, &unshadowed.0, &g.normal, &mask_r, &vis);
                                (rgb, unshadowed.1 + bad)
                            }
                            None => unshadowed,
                        }
                    }
                    // Shadows, or a material the zonal grid cannot resolve (or a measured one,
                    // which the fast shader hands to the exact path): shade per pixel.
                    _ => {
                        let quality = if st.quality == Quality::Zonal {
                            Quality::Fast
                        } else {
                            st.quality
                        };
                        shade_with(&self.material(mat)?.render, &env, quality, &g.normal, &mask_r, vis)
                    }
                };
                for ((o, v), &m) in out.iter_mut().zip(rgb).zip(&mask_r) {
                    if m > 0.0 {
                        *o = v;
                    }
                }
            }
        }

        let chan = |img: &[[f32; 3]], c: usize| img.iter().map(|p| p[c]).collect::<Vec<f32>>();
        let nrm = |c: usize| g.normal.iter().map(|p| p[c]).collect::<Vec<f32>>();
        let image = vec![
            ("R", chan(&image_i, 0)),
            ("G", chan(&image_i, 1)),
            ("B", chan(&image_i, 2)),
            ("O.R", chan(&image_o, 0)),
            ("O.G", chan(&image_o, 1)),
            ("O.B", chan(&image_o, 2)),
            ("normal.X", nrm(0)),
            ("normal.Y", nrm(1)),
            ("normal.Z", nrm(2)),
            ("mask", g.mask.clone()),
            ("region", region_of.iter().map(|&r| r as f32).collect()),
        ];
        let ids =
            |v: &[usize]| -> Result<Vec<String>> { v.iter().map(|&m| Ok(self.material(m)?.id.clone())).collect() };
        let record = SampleRecord {
            id: spec.id.clone(),
            split: plan.splits[spec.split].name.clone(),
            index: spec.index,
            category: item.category.clone(),
            shape_id: item.id.clone(),
            regions: spec.regions.clone(),
            material_ids: ids(materials)?,
            target_material_ids: ids(targets)?,
            env_id: plan.catalogue.envs[spec.env].id.clone(),
            env_rotation_deg: rotation,
            view_azimuth_deg: azimuth,
            view_elevation_deg: elevation,
            shadows,
            covered_pixels: g.covered(),
            shard: String::new(),
            files: BTreeMap::new(),
            checksums: BTreeMap::new(),
        };
        Ok(SamplePixels { record, image, env })
    }
}

/// Encodes a sample's two EXR files: (image bytes, env bytes).
pub fn encode(px: SamplePixels) -> Result<(SampleRecord, Vec<u8>, Vec<u8>)> {
    let res = (px.image[0].1.len() as f64).sqrt() as usize;
    let image = encode_exr_channels(res, res, px.image).with_context(|| px.record.id.clone())?;
    let env = encode_env_exr(&px.env).with_context(|| px.record.id.clone())?;
    Ok((px.record, image, env))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::procedural::Category;
    use glam::Vec3;

    #[test]
    fn convexity_is_detected() {
        let cylinder = || {
            let mut b = crate::shapes::procedural::Builder::new(&["a"], "cylinder".into());
            b.superquadric(
                Vec3::ZERO,
                Vec3::new(0.5, 1.0, 0.5),
                0.3,
                1.0,
                glam::Mat3::IDENTITY,
                (24, 12),
                0,
            );
            b.finish()
        };
        assert!(is_convex(&cylinder(), usize::MAX));
        let chair = Category::Chair.generate(1);
        assert!(!is_convex(&chair, usize::MAX));
        // Beyond the budget the answer is the safe one.
        assert!(!is_convex(&cylinder(), 1));
    }
}

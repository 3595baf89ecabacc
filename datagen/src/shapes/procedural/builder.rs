//! Assembling the procedural shapes from smooth closed parts ([`surface`](super::surface)), each
//! tagged with regions.

use super::surface::{self, Patch, Topology};
use crate::shapes::Mesh;
use glam::{Mat3, Vec2, Vec3};

/// Accumulates parts into a [`Mesh`].
pub struct Builder {
    mesh: Mesh,
    parts: Vec<std::ops::Range<usize>>,
}

/// Grid density of a part: (around, along).
pub type Grid = (usize, usize);

impl Builder {
    /// An empty mesh with the given region names.
    pub fn new(regions: &[&str], source: String) -> Self {
        Self {
            mesh: Mesh {
                regions: regions.iter().map(|r| r.to_string()).collect(),
                source,
                ..Default::default()
            },
            parts: Vec::new(),
        }
    }

    /// Adds a sampled part; `region(centroid, normal, uv)` labels each triangle.
    pub fn patch(&mut self, p: Patch, region: &dyn Fn(Vec3, Vec3, Vec2) -> u32) {
        let base = self.mesh.positions.len() as u32;
        let first = self.mesh.triangles.len();
        for (t, uv) in &p.triangles {
            let corners = t.map(|i| p.positions[i as usize]);
            let normals = t.map(|i| p.normals[i as usize]);
            let centroid = (corners[0] + corners[1] + corners[2]) / 3.0;
            let normal = (normals[0] + normals[1] + normals[2]).normalize_or_zero();
            self.mesh.triangles.push(t.map(|i| base + i));
            self.mesh.corner_normals.push(normals);
            self.mesh.triangle_region.push(region(centroid, normal, *uv));
        }
        self.mesh.positions.extend(p.positions);
        self.parts.push(first..self.mesh.triangles.len());
    }

    /// A superellipsoid part (see [`surface::superellipsoid`]) of one region, its polar axis
    /// along its smallest extent (`e_polar` shapes the profile along it): the poles' fans then
    /// cover the broad faces, and a thin edge is not left to a few long triangles.
    #[allow(clippy::too_many_arguments)]
    pub fn superquadric(
        &mut self,
        centre: Vec3,
        half: Vec3,
        e_polar: f32,
        e_around: f32,
        rot: Mat3,
        grid: Grid,
        region: u32,
    ) {
        self.superquadric_with(centre, half, (e_polar, e_around), rot, grid, &|_| region);
    }

    /// [`Builder::superquadric`] with regions: `region(p)` labels each quad of the grid by its
    /// centre `p` in the part's own frame (before `rot` and `centre`), so region edges follow
    /// the grid.
    pub fn superquadric_with(
        &mut self,
        centre: Vec3,
        half: Vec3,
        (e_polar, e_around): (f32, f32),
        rot: Mat3,
        grid: Grid,
        region: &dyn Fn(Vec3) -> u32,
    ) {
        let k = if half.x <= half.y.min(half.z) {
            0
        } else if half.z < half.y {
            2
        } else {
            1
        };
        let swap = move |mut v: Vec3| {
            let y = v.y;
            v.y = v[k];
            v[k] = y;
            v
        };
        let g = surface::superellipsoid(swap(half), e_polar, e_around);
        let f = move |u: f32, v: f32| swap(g(u, v));
        self.patch(
            surface::sample(Topology::Sphere, grid.0, grid.1, &f).placed(centre, rot),
            &|_, _, uv| region(f(uv.x, uv.y)),
        );
    }

    /// A solid of revolution about the segment `a` → `b`: `radius(t)` for t from 0 at `a` to 1
    /// at `b` (0 at both ends closes it).
    pub fn lathe(&mut self, a: Vec3, b: Vec3, radius: &dyn Fn(f32) -> f32, grid: Grid, region: u32) {
        let axis = b - a;
        let len = axis.length().max(1e-6);
        let rot = Mat3::from_quat(glam::Quat::from_rotation_arc(Vec3::Y, axis / len));
        let f = surface::lathe(|t| (radius(t), t * len));
        self.patch(
            surface::sample(Topology::Sphere, grid.0, grid.1, &f).placed(a, rot),
            &|_, _, _| region,
        );
    }

    /// A rod from `a` to `b` of radius `r` with rounded ends (a capsule's profile, flattened so
    /// its ends read as cut).
    pub fn rod(&mut self, a: Vec3, b: Vec3, r: f32, region: u32) {
        let cap = (r / (b - a).length().max(1e-6)).min(0.5);
        self.tapered_rod(a, b, r, 1.0, cap, (16, 24), region);
    }

    /// A rod from `a` (radius `taper`·`r`) to `b` (radius `r`) whose ends round off over the
    /// fraction `cap` of its length, flattened so that they read as cut: legs, columns, spokes.
    #[allow(clippy::too_many_arguments)]
    pub fn tapered_rod(&mut self, a: Vec3, b: Vec3, r: f32, taper: f32, cap: f32, grid: Grid, region: u32) {
        let radius = move |t: f32| {
            let edge = (t / cap).min((1.0 - t) / cap).min(1.0);
            r * (taper + (1.0 - taper) * t) * (1.0 - (1.0 - edge).powi(4)).max(0.0).powf(0.25)
        };
        self.lathe(a, b, &radius, grid, region);
    }

    /// Triangle ranges of the parts, in the order added (each part is closed).
    pub fn parts(&self) -> &[std::ops::Range<usize>] {
        &self.parts
    }

    /// The mesh so far, before normalisation.
    #[cfg(test)]
    pub fn mesh(&self) -> &Mesh {
        &self.mesh
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

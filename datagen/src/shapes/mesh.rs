//! Triangle meshes: storage, normalisation and vertex normals.

use glam::Vec3;
use matedit_contract::manifest::Named;

/// A triangle mesh with per-corner shading normals.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// Shading normal at each corner of each triangle (unit, or zero where undefined).
    pub corner_normals: Vec<[Vec3; 3]>,
    /// Semantic region of each triangle, an index into `regions`.
    pub triangle_region: Vec<u32>,
    /// Region names, in order of first appearance (OBJ material, else object/group name).
    pub regions: Vec<String>,
    /// Triangles dropped at load because their area is zero.
    pub degenerate_dropped: usize,
    /// Triangles whose normals were computed (the file had none for them).
    pub normals_computed: usize,
    /// Where the mesh came from, for messages.
    pub source: String,
}

/// Why a mesh cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    /// The OBJ parser failed.
    #[error("{path}: cannot read OBJ: {message}")]
    Parse {
        /// File.
        path: String,
        /// Parser message.
        message: String,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{path}: vertex {index} has a non-finite coordinate {value:?}")]
    NonFinite {
        /// File.
        path: String,
        /// Vertex index (0-based) across the file.
        index: usize,
        /// Its coordinates.
        value: [f32; 3],
    },
    /// Nothing renderable remained.
    #[error("{path}: no triangle with non-zero area")]
    Empty {
        /// File.
        path: String,
    },
    /// An index points outside the vertex list.
    #[error("{path}: face index {index} is out of range ({count} vertices)")]
    BadIndex {
        /// File.
        path: String,
        /// The index.
        index: u32,
        /// Number of vertices.
        count: usize,
    },
}

impl Mesh {
    /// Drops zero-area triangles, fills missing normals and normalises to the unit ball.
    /// `has_normals[t]` says whether triangle `t` came with normals.
    pub(crate) fn finish(mut self, has_normals: Vec<bool>) -> Result<Mesh, MeshError> {
        for (i, p) in self.positions.iter().enumerate() {
            if !p.is_finite() {
                return Err(MeshError::NonFinite {
                    path: self.source.clone(),
                    index: i,
                    value: p.to_array(),
                });
            }
        }
        for t in &self.triangles {
            for &i in t {
                if i as usize >= self.positions.len() {
                    return Err(MeshError::BadIndex {
                        path: self.source.clone(),
                        index: i,
                        count: self.positions.len(),
                    });
                }
            }
        }
        let computed = angle_weighted_normals(&self.positions, &self.triangles);
        if self.triangle_region.len() != self.triangles.len() {
            self.triangle_region = vec![0; self.triangles.len()];
        }
        if self.regions.is_empty() {
            self.regions.push("default".into());
        }
        let mut keep = Vec::with_capacity(self.triangles.len());
        let mut normals = Vec::with_capacity(self.triangles.len());
        let mut regions = Vec::with_capacity(self.triangles.len());
        for (t, tri) in self.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|i| self.positions[i as usize].as_dvec3());
            if (b - a).cross(c - a).length_squared() == 0.0 {
                self.degenerate_dropped += 1;
                continue;
            }
            keep.push(*tri);
            regions.push(self.triangle_region[t]);
            if has_normals[t] {
                normals.push(self.corner_normals[t].map(|n| n.normalize_or_zero()));
            } else {
                self.normals_computed += 1;
                normals.push(tri.map(|i| computed[i as usize]));
            }
        }
        if keep.is_empty() {
            return Err(MeshError::Empty { path: self.source });
        }
        self.triangles = keep;
        self.corner_normals = normals;
        self.triangle_region = regions;
        self.normalise();
        Ok(self)
    }

    /// Moves the bounding-box centre of the used vertices to the origin and scales so that the
    /// farthest used vertex is at distance 1 (the convention of `docs/CONVENTIONS.md`).
    fn normalise(&mut self) {
        let used = || {
            self.triangles
                .iter()
                .flatten()
                .map(|&i| self.positions[i as usize].as_dvec3())
        };
        let (mut lo, mut hi) = (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY);
        for p in used() {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        let centre = (lo + hi) * 0.5;
        let radius = used().map(|p| (p - centre).length()).fold(0.0, f64::max);
        let scale = if radius > 0.0 { 1.0 / radius } else { 1.0 };
        for p in &mut self.positions {
            *p = ((p.as_dvec3() - centre) * scale).as_vec3();
        }
    }
}

/// Which axis of a file points up. Meshes are turned so that it becomes +y (camera up).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum UpAxis {
    /// +x is up.
    PosX,
    /// −x is up.
    NegX,
    /// +y is up (no change; OBJ's usual convention and ShapeNet's).
    #[default]
    PosY,
    /// −y is up.
    NegY,
    /// +z is up (CAD and many scans).
    PosZ,
    /// −z is up.
    NegZ,
}

/// The names of the up axes (`+x` is `x`, and so on): one list for manifests' `up` and
/// `datagen render --up`.
impl Named for UpAxis {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("x", UpAxis::PosX),
        ("+x", UpAxis::PosX),
        ("-x", UpAxis::NegX),
        ("y", UpAxis::PosY),
        ("+y", UpAxis::PosY),
        ("-y", UpAxis::NegY),
        ("z", UpAxis::PosZ),
        ("+z", UpAxis::PosZ),
        ("-z", UpAxis::NegZ),
    ];
}

impl std::str::FromStr for UpAxis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::from_name(s).ok_or_else(|| format!("up axis {}", Self::refusal(s)))
    }
}

impl UpAxis {
    /// The proper rotation (an axis permutation with signs) taking this axis to +y.
    pub fn to_y_up(self, v: Vec3) -> Vec3 {
        match self {
            UpAxis::PosX => Vec3::new(-v.y, v.x, v.z),
            UpAxis::NegX => Vec3::new(v.y, -v.x, v.z),
            UpAxis::PosY => v,
            UpAxis::NegY => Vec3::new(v.x, -v.y, -v.z),
            UpAxis::PosZ => Vec3::new(v.x, v.z, -v.y),
            UpAxis::NegZ => Vec3::new(v.x, -v.z, v.y),
        }
    }
}

impl Mesh {
    /// Turns the mesh so that `up` points along +y. Distances and the normalisation are kept.
    pub fn reoriented(mut self, up: UpAxis) -> Mesh {
        for p in &mut self.positions {
            *p = up.to_y_up(*p);
        }
        for ns in &mut self.corner_normals {
            for n in ns {
                *n = up.to_y_up(*n);
            }
        }
        self
    }
}

/// Per-vertex normals: each triangle's unit normal weighted by its corner angle (Thürmer and
/// Wüthrich 1998), which makes the result independent of how a surface is triangulated.
fn angle_weighted_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![glam::DVec3::ZERO; positions.len()];
    for tri in triangles {
        let p = tri.map(|i| positions[i as usize].as_dvec3());
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        if n.length_squared() == 0.0 {
            continue;
        }
        let n = n.normalize();
        for k in 0..3 {
            let e1 = p[(k + 1) % 3] - p[k];
            let e2 = p[(k + 2) % 3] - p[k];
            let angle = e1.angle_between(e2);
            if angle.is_finite() {
                acc[tri[k] as usize] += n * angle;
            }
        }
    }
    acc.into_iter().map(|n| n.normalize_or_zero().as_vec3()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_up_axis_name_turns_its_axis_to_plus_y_and_others_are_refused() {
        for &(name, axis) in UpAxis::NAMES {
            let sign = if name.starts_with('-') { -1.0 } else { 1.0 };
            let v = match name.trim_start_matches(['+', '-']) {
                "x" => Vec3::X,
                "y" => Vec3::Y,
                "z" => Vec3::Z,
                other => panic!("unexpected name {other}"),
            } * sign;
            assert_eq!(name.parse::<UpAxis>(), Ok(axis), "{name}");
            assert_eq!(axis.to_y_up(v), Vec3::Y, "{name}");
        }
        for bad in ["", "Y", "xx", "+-x", " y", "w"] {
            let e = bad.parse::<UpAxis>().unwrap_err();
            assert!(
                e.starts_with("up axis") && e.contains("expected x, +x, -x"),
                "{bad:?}: {e}"
            );
        }
    }

    fn quad_mesh() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(10.0, 10.0, 5.0),
                Vec3::new(14.0, 10.0, 5.0),
                Vec3::new(14.0, 14.0, 5.0),
                Vec3::new(10.0, 14.0, 5.0),
                Vec3::new(12.0, 12.0, 5.0),
            ],
            // Second triangle is degenerate (collinear points).
            triangles: vec![[0, 1, 2], [0, 4, 2], [0, 2, 3]],
            corner_normals: vec![[Vec3::ZERO; 3]; 3],
            source: "quad".into(),
            ..Default::default()
        }
    }

    #[test]
    fn degenerate_triangles_are_dropped_and_normals_computed() {
        let m = quad_mesh().finish(vec![false; 3]).unwrap();
        assert_eq!(m.degenerate_dropped, 1);
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.normals_computed, 2);
        for ns in &m.corner_normals {
            for n in ns {
                assert!((*n - Vec3::Z).length() < 1e-6, "{n}");
            }
        }
        // Normalised: bbox centre at the origin, farthest vertex at 1.
        let r = m.positions[..4].iter().map(|p| p.length()).fold(0.0, f32::max);
        assert!((r - 1.0).abs() < 1e-6);
        assert!(m.positions[0].z.abs() < 1e-6);
    }

    #[test]
    fn bad_meshes_are_refused_with_the_reason() {
        let mut m = quad_mesh();
        m.positions[3].x = f32::NAN;
        assert!(matches!(
            m.finish(vec![false; 3]),
            Err(MeshError::NonFinite { index: 3, .. })
        ));
        let mut m = quad_mesh();
        m.triangles = vec![[0, 4, 2]];
        m.corner_normals.truncate(1);
        assert!(matches!(m.finish(vec![false]), Err(MeshError::Empty { .. })));
        let mut m = quad_mesh();
        m.triangles[0][1] = 99;
        assert!(matches!(
            m.finish(vec![false; 3]),
            Err(MeshError::BadIndex { index: 99, .. })
        ));
    }

    #[test]
    fn up_axes_are_proper_rotations_to_plus_y() {
        for up in ["x", "-x", "y", "-y", "z", "-z"] {
            let a: UpAxis = up.parse().unwrap();
            let axis = match up {
                "x" => Vec3::X,
                "-x" => Vec3::NEG_X,
                "y" => Vec3::Y,
                "-y" => Vec3::NEG_Y,
                "z" => Vec3::Z,
                _ => Vec3::NEG_Z,
            };
            assert_eq!(a.to_y_up(axis), Vec3::Y, "{up}");
            // Right-handed: x × y = z is preserved.
            assert_eq!(a.to_y_up(Vec3::X).cross(a.to_y_up(Vec3::Y)), a.to_y_up(Vec3::Z), "{up}");
        }
        assert!("w".parse::<UpAxis>().is_err());
    }

    #[test]
    fn angle_weighting_ignores_triangulation_density() {
        // A corner shared by one big face (+z) and a fan of thin faces (+x): the face normals
        // count by angle, so splitting the +x face into many triangles changes nothing.
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(0.0, 0.5, -1.0),
        ];
        let one = angle_weighted_normals(&p, &[[0, 1, 2], [0, 2, 3]]);
        let split = angle_weighted_normals(&p, &[[0, 1, 2], [0, 2, 4], [0, 4, 3]]);
        assert!((one[0] - split[0]).length() < 1e-6, "{} vs {}", one[0], split[0]);
    }
}

//! Wavefront OBJ loading through tobj.

use super::{Mesh, MeshError};
use glam::Vec3;
use std::path::Path;

impl Mesh {
    /// Loads every object and group of an OBJ file into one mesh. Polygons are triangulated,
    /// negative (relative) indices resolved, missing or broken `.mtl` files ignored (materials do
    /// not affect the geometry), and normals computed for faces that have none.
    pub fn from_obj(path: &Path) -> Result<Mesh, MeshError> {
        let name = path.display().to_string();
        let options = tobj::LoadOptions {
            triangulate: true,
            single_index: false,
            ignore_points: true,
            ignore_lines: true,
        };
        let (models, _materials) = tobj::load_obj(path, &options).map_err(|e| MeshError::Parse {
            path: name.clone(),
            message: e.to_string(),
        })?;
        let mut mesh = Mesh {
            source: name,
            ..Default::default()
        };
        let mut has_normals = Vec::new();
        for model in &models {
            let m = &model.mesh;
            let base = mesh.positions.len() as u32;
            mesh.positions
                .extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
            let with_normals = !m.normal_indices.is_empty() && m.normal_indices.len() == m.indices.len();
            for (t, tri) in m.indices.chunks_exact(3).enumerate() {
                mesh.triangles.push([tri[0] + base, tri[1] + base, tri[2] + base]);
                let corner = |k: usize| {
                    let i = m.normal_indices[3 * t + k] as usize * 3;
                    m.normals
                        .get(i..i + 3)
                        .map_or(Vec3::ZERO, |n| Vec3::new(n[0], n[1], n[2]))
                };
                if with_normals {
                    let ns = [corner(0), corner(1), corner(2)];
                    // A file normal that is zero or non-finite is as good as none.
                    let ok = ns.iter().all(|n| n.is_finite() && n.length_squared() > 0.0);
                    mesh.corner_normals.push(ns);
                    has_normals.push(ok);
                } else {
                    mesh.corner_normals.push([Vec3::ZERO; 3]);
                    has_normals.push(false);
                }
            }
        }
        mesh.finish(has_normals)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(name: &str, text: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("matedit-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    #[test]
    fn ngons_negative_indices_and_missing_mtl_load() {
        let p = write(
            "quad.obj",
            "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf -4 -3 -2 -1\n",
        );
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.triangles.len(), 2);
        assert_eq!(m.normals_computed, 2);
    }

    #[test]
    fn nan_vertices_and_garbage_are_refused_naming_the_file() {
        let p = write("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
        let e = Mesh::from_obj(&p).unwrap_err().to_string();
        assert!(e.contains("nan.obj") && e.contains("non-finite"), "{e}");
        let p = write("empty.obj", "# nothing\n");
        let e = Mesh::from_obj(&p).unwrap_err().to_string();
        assert!(e.contains("empty.obj"), "{e}");
        let e = Mesh::from_obj(Path::new("/nonexistent/x.obj")).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/x.obj"), "{e}");
    }

    #[test]
    fn file_normals_are_used_when_present() {
        let p = write("n.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nf 1//1 2//1 3//1\n");
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.normals_computed, 0);
        assert_eq!(m.corner_normals[0][0], Vec3::Z);
    }
}

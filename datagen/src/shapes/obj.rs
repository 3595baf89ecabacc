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
        let (models, materials) = tobj::load_obj(path, &options).map_err(|e| {
            let message = match locate_error(path, &e) {
                Some((line, text)) => format!("{e} at line {line}: {text:?}"),
                None => e.to_string(),
            };
            MeshError::Parse {
                path: name.clone(),
                message,
            }
        })?;
        let mut mesh = Mesh {
            source: name,
            ..Default::default()
        };
        let mut has_normals = Vec::new();
        // A missing or broken .mtl leaves material ids unresolved: fall back to object names.
        let materials = materials.unwrap_or_default();
        for model in &models {
            let m = &model.mesh;
            let key = match m.material_id.and_then(|i| materials.get(i)) {
                Some(mat) => mat.name.clone(),
                None if model.name.is_empty() => "default".to_string(),
                None => model.name.clone(),
            };
            let region = match mesh.regions.iter().position(|r| *r == key) {
                Some(i) => i,
                None => {
                    mesh.regions.push(key);
                    mesh.regions.len() - 1
                }
            } as u32;
            let base = mesh.positions.len() as u32;
            mesh.positions
                .extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
            let with_normals = !m.normal_indices.is_empty() && m.normal_indices.len() == m.indices.len();
            for (t, tri) in m.indices.chunks_exact(3).enumerate() {
                mesh.triangles.push([tri[0] + base, tri[1] + base, tri[2] + base]);
                mesh.triangle_region.push(region);
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

impl Mesh {
    /// Writes the mesh as OBJ with per-corner normals, one `usemtl` run per region, and a
    /// matching `.mtl` beside it (region colours from `palette`, cycled). Both files atomically.
    pub fn write_obj(&self, path: &Path, palette: &[[f32; 3]]) -> anyhow::Result<()> {
        use std::fmt::Write as _;
        let mtl = path.with_extension("mtl");
        let mtl_name = mtl
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut obj = format!("# {}\nmtllib {mtl_name}\n", self.source);
        for p in &self.positions {
            let _ = writeln!(obj, "v {} {} {}", p.x, p.y, p.z);
        }
        for n in self.corner_normals.iter().flatten() {
            let _ = writeln!(obj, "vn {} {} {}", n.x, n.y, n.z);
        }
        for (region, name) in self.regions.iter().enumerate() {
            let _ = writeln!(obj, "o {name}\nusemtl {name}");
            for (t, tri) in self.triangles.iter().enumerate() {
                if self.triangle_region[t] as usize == region {
                    let [a, b, c] = tri.map(|i| i + 1);
                    let n = 3 * t + 1;
                    let _ = writeln!(obj, "f {a}//{n} {b}//{} {c}//{}", n + 1, n + 2);
                }
            }
        }
        let mut m = String::new();
        for (k, name) in self.regions.iter().enumerate() {
            let c = palette.get(k % palette.len().max(1)).copied().unwrap_or([0.8; 3]);
            let _ = writeln!(m, "newmtl {name}\nKd {} {} {}\n", c[0], c[1], c[2]);
        }
        matedit_contract::io::write_atomically(&mtl, |tmp| Ok(std::fs::write(tmp, m)?))?;
        matedit_contract::io::write_atomically(path, |tmp| Ok(std::fs::write(tmp, obj)?))
    }
}

/// tobj reports what failed but not where: find the first line of that kind that does not parse.
fn locate_error(path: &Path, e: &tobj::LoadError) -> Option<(usize, String)> {
    use tobj::LoadError as E;
    let (prefix, min, max) = match e {
        E::PositionParseError => ("v", 3, 7),
        E::NormalParseError => ("vn", 3, 3),
        E::TexcoordParseError => ("vt", 1, 3),
        E::FaceParseError | E::InvalidPolygon => ("f", 3, usize::MAX),
        _ => return None,
    };
    let text = std::fs::read_to_string(path).ok()?;
    text.lines().enumerate().find_map(|(i, line)| {
        let mut words = line.split_whitespace();
        if words.next() != Some(prefix) {
            return None;
        }
        let fields: Vec<&str> = words.collect();
        let ok = (min..=max).contains(&fields.len())
            && fields.iter().all(|w| {
                if prefix == "f" {
                    w.split('/')
                        .next()
                        .is_some_and(|i| i.parse::<i64>().is_ok_and(|i| i != 0))
                } else {
                    w.parse::<f32>().is_ok()
                }
            });
        (!ok).then(|| (i + 1, line.to_string()))
    })
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
    fn materials_and_objects_become_regions() {
        std::fs::write(
            std::env::temp_dir()
                .join(format!("matedit-obj-{}", std::process::id()))
                .join("two.mtl"),
            "newmtl frame\nKd 1 0 0\nnewmtl seat\nKd 0 1 0\n",
        )
        .ok();
        let p = write(
            "two.obj",
            "mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\no a\nusemtl frame\nf 1 2 3\nusemtl seat\nf 2 4 3\no b\nusemtl frame\nf 1 3 4\n",
        );
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.regions, vec!["frame".to_string(), "seat".to_string()]);
        assert_eq!(m.triangle_region, vec![0, 1, 0]);
        // Without the .mtl, object names are the regions.
        let p = write(
            "objs.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\no left\nf 1 2 3\no right\nf 2 4 3\n",
        );
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.regions, vec!["left".to_string(), "right".to_string()]);
    }

    #[test]
    fn written_obj_files_load_back_with_their_regions() {
        let m = crate::shapes::procedural::Category::Chair.generate(4);
        let dir = std::env::temp_dir().join(format!("matedit-obj-{}", std::process::id()));
        let p = dir.join("chair.obj");
        m.write_obj(&p, &[[0.5, 0.6, 0.8], [0.9, 0.5, 0.2]]).unwrap();
        let back = Mesh::from_obj(&p).unwrap();
        assert_eq!(back.regions, m.regions);
        assert_eq!(back.triangles.len(), m.triangles.len());
        assert_eq!(back.normals_computed, 0);
        let count = |mesh: &Mesh, r| mesh.triangle_region.iter().filter(|&&x| x == r).count();
        assert_eq!(count(&back, 1), count(&m, 1));
        // tobj re-indexes vertices per object, so compare order-free properties: area per region
        // and the bounding box.
        let area = |mesh: &Mesh, r: u32| -> f32 {
            mesh.triangles
                .iter()
                .zip(&mesh.triangle_region)
                .filter(|(_, x)| **x == r)
                .map(|(t, _)| {
                    let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
                    (b - a).cross(c - a).length() / 2.0
                })
                .sum()
        };
        for r in 0..2 {
            assert!((area(&back, r) - area(&m, r)).abs() < 1e-4 * area(&m, r), "region {r}");
        }
        let bbox = |mesh: &Mesh| mesh.positions.iter().fold(glam::Vec3::ZERO, |a, p| a.max(p.abs()));
        assert!((bbox(&back) - bbox(&m)).length() < 1e-5);
    }

    #[test]
    fn a_broken_mtl_falls_back_to_object_names() {
        let p = write(
            "brokenmtl.obj",
            "mtllib broken.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\no part\nusemtl a\nf 1 2 3\n",
        );
        write("broken.mtl", "newmtl a\nKd not numbers at all\n\u{0}\u{1}garbage\n");
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.triangles.len(), 1);
        assert_eq!(m.regions.len(), 1);
    }

    #[test]
    fn huge_and_tiny_scales_normalise_to_the_unit_ball() {
        for scale in [1e-6_f32, 1e6] {
            let text = format!(
                "v {} 0 0\nv {} 0 0\nv 0 {} 0\nv 0 0 {}\nf 1 2 3\nf 1 3 4\n",
                7.0 * scale,
                9.0 * scale,
                scale,
                scale
            );
            let m = Mesh::from_obj(&write("scaled.obj", &text)).unwrap();
            let r = m.positions.iter().map(|p| p.length()).fold(0.0, f32::max);
            assert!((r - 1.0).abs() < 1e-5, "scale {scale}: radius {r}");
            assert!(
                m.corner_normals
                    .iter()
                    .flatten()
                    .all(|n| (n.length() - 1.0).abs() < 1e-5)
            );
        }
    }

    #[test]
    fn parse_errors_name_the_line() {
        let p = write(
            "badvn.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn  -1.2 -13.8\nf 1//1 2//1 3//1\n",
        );
        let e = Mesh::from_obj(&p).unwrap_err().to_string();
        assert!(e.contains("badvn.obj") && e.contains("line 5"), "{e}");
    }

    #[test]
    fn file_normals_are_used_when_present() {
        let p = write("n.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 2\nf 1//1 2//1 3//1\n");
        let m = Mesh::from_obj(&p).unwrap();
        assert_eq!(m.normals_computed, 0);
        assert_eq!(m.corner_normals[0][0], Vec3::Z);
    }
}

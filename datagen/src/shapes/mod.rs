//! Shapes the renderer can place in front of the camera.

mod mesh;
mod obj;
pub mod procedural;
pub mod sets;
pub mod sources;

pub use mesh::{Mesh, MeshError, UpAxis};

use std::path::Path;

/// The object of a scene.
#[derive(Clone, Debug)]
pub enum Shape {
    /// The unit sphere at the origin, traced analytically (convex: never self-shadows).
    Sphere,
    /// A triangle mesh normalised to the unit ball.
    Mesh(Mesh),
}

impl Shape {
    /// `sphere`, `procedural:CATEGORY:SEED`, or the path of an OBJ file whose `up` axis
    /// becomes +y.
    pub fn load(spec: &str, up: UpAxis) -> Result<Shape, MeshError> {
        if spec == "sphere" {
            return Ok(Shape::Sphere);
        }
        if let Some(rest) = spec.strip_prefix("procedural:") {
            let bad = |message: String| MeshError::Parse {
                path: spec.to_string(),
                message,
            };
            let (cat, seed) = rest
                .split_once(':')
                .ok_or_else(|| bad("expected procedural:CATEGORY:SEED".into()))?;
            let cat: procedural::Category = cat.parse().map_err(bad)?;
            let seed: u64 = seed
                .parse()
                .map_err(|_| bad(format!("seed {seed:?} is not an unsigned integer")))?;
            return Ok(Shape::Mesh(cat.generate(seed)));
        }
        Ok(Shape::Mesh(Mesh::from_obj(Path::new(spec))?.reoriented(up)))
    }

    /// Turns the object: `yaw` degrees about +y, then `pitch` degrees about +x (positive pitch
    /// tips the top towards the camera). The environment stays fixed in camera space.
    pub fn posed(self, yaw_deg: f32, pitch_deg: f32) -> Shape {
        match self {
            Shape::Sphere => Shape::Sphere,
            Shape::Mesh(mut m) => {
                let r = glam::Mat3::from_rotation_x(pitch_deg.to_radians())
                    * glam::Mat3::from_rotation_y(yaw_deg.to_radians());
                for p in &mut m.positions {
                    *p = r * *p;
                }
                for n in m.corner_normals.iter_mut().flatten() {
                    *n = r * *n;
                }
                Shape::Mesh(m)
            }
        }
    }
}

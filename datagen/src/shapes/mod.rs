//! Shapes the renderer can place in front of the camera.

mod mesh;
mod obj;

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
    /// `sphere`, or the path of an OBJ file whose `up` axis becomes +y.
    pub fn load(spec: &str, up: UpAxis) -> Result<Shape, MeshError> {
        if spec == "sphere" {
            return Ok(Shape::Sphere);
        }
        Ok(Shape::Mesh(Mesh::from_obj(Path::new(spec))?.reoriented(up)))
    }
}

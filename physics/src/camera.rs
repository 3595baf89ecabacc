//! The orthographic camera of the paper's setting.
//!
//! Camera space: x right, y up, z towards the viewer. The camera looks along −z from +z, so the
//! direction towards the viewer is ω_o = +z for every pixel. The image of `n × n` pixels spans
//! [−1, 1]² in x and y; pixel (column `c`, row `r`) has its centre at
//! x = −1 + (2c+1)/n, y = 1 − (2r+1)/n (row 0 at the top).

use glam::DVec3;

/// Direction from the surface towards the orthographic camera (camera space).
pub const VIEW_DIR: DVec3 = DVec3::Z;

/// Camera-space (x, y) of the centre of pixel (`col`, `row`) in an `n × n` image.
pub fn pixel_center(col: usize, row: usize, n: usize) -> (f64, f64) {
    let nf = n as f64;
    (-1.0 + (2 * col + 1) as f64 / nf, 1.0 - (2 * row + 1) as f64 / nf)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_centres_span_the_unit_square_symmetrically() {
        let n = 4;
        assert_eq!(pixel_center(0, 0, n), (-0.75, 0.75));
        assert_eq!(pixel_center(3, 3, n), (0.75, -0.75));
        let (x, y) = pixel_center(1, 2, n);
        assert_eq!((x, y), (-0.25, -0.25));
    }
}

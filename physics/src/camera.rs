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

/// Normals and mask of the analytic unit sphere seen by the `res × res` camera: the test
/// object of furnaces, benchmarks and fits. Normals are computed in `f64`, unit to `f32` precision.
pub fn unit_sphere_normals(res: usize) -> (Vec<[f32; 3]>, Vec<f32>) {
    let mut normals = vec![[0.0_f32; 3]; res * res];
    let mut mask = vec![0.0_f32; res * res];
    for p in 0..res * res {
        let (x, y) = pixel_center(p % res, p / res, res);
        let r2 = x * x + y * y;
        if r2 < 1.0 {
            normals[p] = [x as f32, y as f32, (1.0 - r2).sqrt() as f32];
            mask[p] = 1.0;
        }
    }
    (normals, mask)
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

    #[test]
    fn the_unit_sphere_covers_pi_over_4_of_the_image() {
        let (n, m) = unit_sphere_normals(64);
        let covered = m.iter().filter(|&&v| v > 0.0).count() as f64 / (64.0 * 64.0);
        assert!((covered - std::f64::consts::FRAC_PI_4).abs() < 0.02, "{covered}");
        for (n, m) in n.iter().zip(&m) {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!(if *m > 0.0 { (len - 1.0).abs() < 1e-6 } else { len == 0.0 });
        }
    }
}

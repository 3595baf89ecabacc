//! Per-texel constants of Eq. 2 for the orthographic camera.
//!
//! The camera looks along −z, so the view direction ω_o = +z is the same for every pixel. The half
//! vector h = normalize(ω_i + ω_o) and the difference angle θ_d = ∠(ω_i, h) therefore depend on the
//! texel only, not on the pixel's normal: the DSBRDF's κ(θ_d) and γ(θ_d) are interpolated once per
//! texel and material, and only cos θ_h = n·h and n·ω_i remain per pixel.

use matedit_physics::brdf::dsbrdf::THETA_D_KNOTS_DEG;
use matedit_physics::envmap::{texel_direction, texel_solid_angle};

/// Texels are processed in groups of this many lanes (one AVX2 register of `f32`).
pub const LANES: usize = 8;

/// Directions, half vectors, solid angles and θ_d knot weights of every texel of an
/// equirectangular map (row-major from the zenith row, the layout of the environment tensor),
/// padded with inert texels (zero direction and solid angle) to a multiple of [`LANES`].
#[derive(Clone, Debug)]
pub struct TexelTable {
    height: usize,
    count: usize,
    /// ω_i components.
    pub(crate) w: [Vec<f32>; 3],
    /// Half-vector components.
    pub(crate) h: [Vec<f32>; 3],
    /// Solid angle dω_i.
    pub(crate) sa: Vec<f32>,
    /// Knot segment of θ_d: κ(θ_d) interpolates knots `seg` and `seg + 1`.
    pub(crate) seg: Vec<u8>,
    /// Interpolation weight of knot `seg + 1`.
    pub(crate) u: Vec<f32>,
}

impl TexelTable {
    /// The table of a `2·height × height` environment map.
    pub fn new(height: usize) -> Self {
        let width = 2 * height;
        let count = width * height;
        let padded = count.div_ceil(LANES) * LANES;
        let mut w = [vec![0.0; padded], vec![0.0; padded], vec![0.0; padded]];
        let mut h = [vec![0.0; padded], vec![0.0; padded], vec![0.0; padded]];
        let mut sa = vec![0.0; padded];
        let mut seg = vec![0u8; padded];
        let mut u = vec![0.0; padded];
        for row in 0..height {
            let s = texel_solid_angle(row, width, height);
            for col in 0..width {
                let t = row * width + col;
                let d = texel_direction(col, row, width, height);
                let hv = (d + glam::DVec3::Z).normalize_or_zero();
                let (k, wt) = knot_segment(d.dot(hv).clamp(0.0, 1.0).acos().to_degrees());
                for a in 0..3 {
                    w[a][t] = d[a] as f32;
                    h[a][t] = hv[a] as f32;
                }
                sa[t] = s as f32;
                seg[t] = k as u8;
                u[t] = wt as f32;
            }
        }
        Self {
            height,
            count,
            w,
            h,
            sa,
            seg,
            u,
        }
    }

    /// Rows of the map.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Texels of the map (without padding).
    pub fn count(&self) -> usize {
        self.count
    }

    /// Texels including the inert padding.
    pub fn padded(&self) -> usize {
        self.sa.len()
    }
}

/// The knot segment and weight of θ_d (degrees), exactly as `Dsbrdf::lobes_at` interpolates.
pub fn knot_segment(theta_d_deg: f64) -> (usize, f64) {
    let deg = theta_d_deg.clamp(0.0, 90.0);
    let knots = THETA_D_KNOTS_DEG;
    let seg = knots.windows(2).position(|w| deg <= w[1]).unwrap_or(knots.len() - 2);
    let (a, b) = (knots[seg], knots[seg + 1]);
    (seg, ((deg - a) / (b - a)).clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solid_angles_cover_the_sphere_and_half_vectors_are_unit() {
        let t = TexelTable::new(64);
        assert_eq!((t.count(), t.padded()), (8192, 8192));
        let total: f64 = t.sa.iter().map(|&s| s as f64).sum();
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-4, "{total}");
        for i in 0..t.count() {
            let hl = (t.h[0][i].powi(2) + t.h[1][i].powi(2) + t.h[2][i].powi(2)).sqrt();
            assert!((hl - 1.0).abs() < 1e-6 && t.h[2][i] > 0.0);
        }
    }

    #[test]
    fn knot_segments_match_the_knots_and_clamp() {
        assert_eq!(knot_segment(0.0), (0, 0.0));
        assert_eq!(knot_segment(30.0), (0, 1.0));
        assert_eq!(knot_segment(40.0), (1, 0.5));
        assert_eq!(knot_segment(90.0), (4, 1.0));
        assert_eq!(knot_segment(120.0), (4, 1.0));
        assert_eq!(knot_segment(-5.0), (0, 0.0));
        assert_eq!(knot_segment(f64::NAN).0, 4);
    }

    #[test]
    fn odd_sizes_are_padded_with_inert_texels() {
        let t = TexelTable::new(3);
        assert_eq!((t.count(), t.padded()), (18, 24));
        assert!(t.sa[18..].iter().all(|&s| s == 0.0));
        assert!(t.w[2][18..].iter().all(|&s| s == 0.0));
    }
}

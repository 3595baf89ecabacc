//! Measured isotropic BRDFs in the MERL format (Matusik et al. 2003), rendered directly from the
//! table, as the paper's ground truth was.
//!
//! File layout: three little-endian `i32` dimensions (90, 90, 180), then three blocks (R, G, B)
//! of 90·90·180 little-endian `f64`, indexed `θ_h · (90·180) + θ_d · 180 + φ_d`. The θ_h axis is
//! square-root spaced (bin i covers ((i/90)², ((i+1)/90)²)·π/2), θ_d is linear over [0, π/2),
//! φ_d linear over [0, π) (reciprocity folds φ_d and φ_d + π). Channel scales are 1/1500,
//! 1.15/1500 and 1.66/1500. Lookup is nearest-bin, as in MERL's reference code.
//!
//! Real files hold negative values (−1) in bins that were not measured (mostly grazing). They are
//! replaced by 0 and counted ([`MerlBrdf::invalid_entries`]).

use super::Brdf;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::Path;

/// Bins along θ_h.
pub const RES_THETA_H: usize = 90;
/// Bins along θ_d.
pub const RES_THETA_D: usize = 90;
/// Bins along φ_d (over [0, π)).
pub const RES_PHI_D: usize = 180;
/// Samples per channel.
pub const SAMPLES: usize = RES_THETA_H * RES_THETA_D * RES_PHI_D;
/// Size of a MERL file in bytes: 12 + 8·3·90·90·180 = 34,992,012.
pub const FILE_BYTES: usize = 12 + 8 * 3 * SAMPLES;
/// Per-channel scale from stored values to BRDF values.
pub const SCALES: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];

/// Why a MERL file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MerlError {
    /// The file could not be read.
    #[error("cannot read MERL file {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Wrong size.
    #[error("{path}: {got} bytes; a MERL BRDF has exactly {FILE_BYTES}")]
    Size {
        /// File.
        path: String,
        /// Its size.
        got: usize,
    },
    /// Wrong dimensions in the header.
    #[error("{path}: header says {dims:?}; a MERL BRDF has (90, 90, 180)")]
    Header {
        /// File.
        path: String,
        /// The header's dimensions.
        dims: [i32; 3],
    },
    /// A NaN or infinite entry.
    #[error("{path}: entry {index} is not finite")]
    NotFinite {
        /// File.
        path: String,
        /// Flat index (channel-major).
        index: usize,
    },
}

/// A tabulated MERL BRDF (values already scaled, in 1/sr).
#[derive(Clone, Debug, PartialEq)]
pub struct MerlBrdf {
    values: Vec<f32>,
    invalid: usize,
}

impl MerlBrdf {
    /// Reads a `.binary` file.
    pub fn read(path: &Path) -> Result<Self, MerlError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| MerlError::Io {
            path: name.clone(),
            source,
        })?;
        Self::from_bytes(&bytes, &name)
    }

    /// Parses the bytes of a MERL file; `origin` names it in errors.
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self, MerlError> {
        if bytes.len() != FILE_BYTES {
            return Err(MerlError::Size {
                path: origin.into(),
                got: bytes.len(),
            });
        }
        let dims: [i32; 3] =
            std::array::from_fn(|i| i32::from_le_bytes(bytes[4 * i..4 * i + 4].try_into().unwrap_or([0; 4])));
        if dims != [RES_THETA_H as i32, RES_THETA_D as i32, RES_PHI_D as i32] {
            return Err(MerlError::Header {
                path: origin.into(),
                dims,
            });
        }
        let mut values = Vec::with_capacity(3 * SAMPLES);
        let mut invalid = 0;
        for (index, chunk) in bytes[12..].chunks_exact(8).enumerate() {
            let v = f64::from_le_bytes(chunk.try_into().unwrap_or([0; 8]));
            if !v.is_finite() {
                return Err(MerlError::NotFinite {
                    path: origin.into(),
                    index,
                });
            }
            if v < 0.0 {
                invalid += 1;
                values.push(0.0);
            } else {
                values.push((v * SCALES[index / SAMPLES]) as f32);
            }
        }
        Ok(Self { values, invalid })
    }

    /// Tabulates any BRDF at the bin centres, in the MERL layout. Bins whose directions fall
    /// below the horizon get −1, as in real files.
    pub fn tabulate_bytes(brdf: &dyn Brdf) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for d in [RES_THETA_H, RES_THETA_D, RES_PHI_D] {
            out.extend((d as i32).to_le_bytes());
        }
        let mut blocks = vec![vec![0.0_f64; SAMPLES]; 3];
        for ih in 0..RES_THETA_H {
            let th = ((ih as f64 + 0.5) / RES_THETA_H as f64).powi(2) * FRAC_PI_2;
            for id in 0..RES_THETA_D {
                let td = (id as f64 + 0.5) / RES_THETA_D as f64 * FRAC_PI_2;
                for ip in 0..RES_PHI_D {
                    let pd = (ip as f64 + 0.5) / RES_PHI_D as f64 * PI;
                    let (wi, wo) = half_diff_to_directions(th, td, pd);
                    let idx = (ih * RES_THETA_D + id) * RES_PHI_D + ip;
                    let f = if wi.z > 0.0 && wo.z > 0.0 {
                        Some(brdf.eval(wi, wo))
                    } else {
                        None
                    };
                    for c in 0..3 {
                        blocks[c][idx] = f.map_or(-1.0, |f| f[c] / SCALES[c]);
                    }
                }
            }
        }
        for b in blocks {
            for v in b {
                out.extend(v.to_le_bytes());
            }
        }
        out
    }

    /// Entries that were negative (unmeasured) in the file and read as 0.
    pub fn invalid_entries(&self) -> usize {
        self.invalid
    }

    fn lookup(&self, th: f64, td: f64, pd: f64) -> [f64; 3] {
        let ih = ((th.max(0.0) / FRAC_PI_2 * (RES_THETA_H * RES_THETA_H) as f64).sqrt() as usize).min(RES_THETA_H - 1);
        let id = ((td.max(0.0) / FRAC_PI_2 * RES_THETA_D as f64) as usize).min(RES_THETA_D - 1);
        let pd = if pd < 0.0 { pd + PI } else { pd };
        let ip = ((pd.max(0.0) / PI * RES_PHI_D as f64) as usize).min(RES_PHI_D - 1);
        let idx = (ih * RES_THETA_D + id) * RES_PHI_D + ip;
        [0, 1, 2].map(|c| self.values[c * SAMPLES + idx] as f64)
    }
}

/// (θ_h, φ_h, θ_d, φ_d) of a direction pair, after MERL's `std_coords_to_half_diff_coords`:
/// θ_d, φ_d are ω_i expressed in the frame where the half vector is the pole.
pub fn directions_to_half_diff(wi: DVec3, wo: DVec3) -> (f64, f64, f64, f64) {
    let h = (wi + wo).normalize();
    let th = h.z.clamp(-1.0, 1.0).acos();
    let ph = h.y.atan2(h.x);
    let t = rotate(wi, DVec3::Z, -ph);
    let d = rotate(t, DVec3::Y, -th);
    (th, ph, d.z.clamp(-1.0, 1.0).acos(), d.y.atan2(d.x))
}

/// Inverse of [`directions_to_half_diff`] with φ_h = 0.
pub fn half_diff_to_directions(th: f64, td: f64, pd: f64) -> (DVec3, DVec3) {
    let d = DVec3::new(td.sin() * pd.cos(), td.sin() * pd.sin(), td.cos());
    let wi = rotate(d, DVec3::Y, th);
    let h = DVec3::new(th.sin(), 0.0, th.cos());
    let wo = 2.0 * h.dot(wi) * h - wi;
    (wi, wo)
}

/// Rodrigues rotation of `v` about unit `axis` by `angle`.
fn rotate(v: DVec3, axis: DVec3, angle: f64) -> DVec3 {
    let (s, c) = angle.sin_cos();
    v * c + axis.cross(v) * s + axis * axis.dot(v) * (1.0 - c)
}

impl Brdf for MerlBrdf {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        if wi.z <= 0.0 || wo.z <= 0.0 {
            return [0.0; 3];
        }
        let (th, _, td, pd) = directions_to_half_diff(wi, wo);
        self.lookup(th, td, pd)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{Fresnel, Ggx, Lambert, Plastic, testing};

    #[test]
    fn half_diff_round_trips() {
        for (th, td, pd) in [(0.1, 0.3, 0.5), (1.2, 0.7, 2.9), (0.01, 1.5, 0.01)] {
            let (wi, wo) = half_diff_to_directions(th, td, pd);
            let (a, _, b, c) = directions_to_half_diff(wi, wo);
            assert!((a - th).abs() < 1e-9 && (b - td).abs() < 1e-9 && (c - pd).abs() < 1e-9);
        }
    }

    #[test]
    fn a_tabulated_lambert_is_exact_and_a_tabulated_ggx_is_close() {
        let l = Lambert {
            albedo: [0.5, 0.3, 0.1],
        };
        let m = MerlBrdf::from_bytes(&MerlBrdf::tabulate_bytes(&l), "mem").unwrap();
        assert!(m.invalid_entries() > 0, "below-horizon bins are marked like real files");
        let wi = DVec3::new(0.3, 0.2, 0.9).normalize();
        let wo = DVec3::new(-0.5, 0.1, 0.8).normalize();
        for (a, b) in m.eval(wi, wo).iter().zip(l.eval(wi, wo)) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        testing::check_basic(&m);
        let g = Plastic::new(0.4, [0.2, 0.2, 0.2]);
        let mg = MerlBrdf::from_bytes(&MerlBrdf::tabulate_bytes(&g), "mem").unwrap();
        let (a, b) = (mg.eval(wi, wo), g.eval(wi, wo));
        assert!((a[0] - b[0]).abs() / b[0] < 0.05, "{a:?} vs {b:?}");
        let _ = Ggx::new(0.3, Fresnel::None);
    }

    #[test]
    fn wrong_files_are_refused_with_the_reason() {
        assert!(matches!(
            MerlBrdf::from_bytes(&[0; 100], "x.binary"),
            Err(MerlError::Size { got: 100, .. })
        ));
        let mut b = MerlBrdf::tabulate_bytes(&Lambert { albedo: [0.5; 3] });
        b[0] = 91;
        let e = MerlBrdf::from_bytes(&b, "x.binary").unwrap_err().to_string();
        assert!(e.contains("x.binary") && e.contains("[91, 90, 180]"), "{e}");
        b[0] = 90;
        b[12..20].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(matches!(
            MerlBrdf::from_bytes(&b, "x"),
            Err(MerlError::NotFinite { index: 0, .. })
        ));
        assert!(
            MerlBrdf::read(Path::new("/nonexistent.binary"))
                .unwrap_err()
                .to_string()
                .contains("/nonexistent.binary")
        );
    }
}

//! Measured isotropic BRDFs in the MERL format (Matusik et al. 2003), rendered directly from the
//! table, as the paper's ground truth was.
//!
//! File layout: three little-endian `i32` dimensions (90, 90, 180), then three blocks (R, G, B)
//! of 90·90·180 little-endian `f64`, indexed `θ_h · (90·180) + θ_d · 180 + φ_d`. The θ_h axis is
//! square-root spaced, θ_d is linear over [0, π/2), φ_d linear over [0, π) (reciprocity folds
//! φ_d and φ_d + π, so the axis is periodic with period π). Channel scales are 1/1500,
//! 1.15/1500 and 1.66/1500.
//!
//! Where the samples sit: MERL's reference code maps an angle to an index by truncation
//! (`int(sqrt(θ_h/(π/2))·90)`, `int(θ_d/(π/2)·90)`, `int(φ_d/π·180)`), so the angle that maps
//! exactly onto index i is the *lower edge* of bin i: θ_h = (i/90)²·π/2, θ_d = i·π/180,
//! φ_d = i·π/180 ([`sample_angles`]). The common inverse mappings of MERL readers use the same
//! positions, and they put sample 0 on the mirror direction (θ_h = 0), where a specular peak
//! is. [`MerlBrdf::from_fn`] tabulates there, and lookups place sample i at index-space
//! coordinate i.
//!
//! Lookup ([`MerlLookup`]) is trilinear in index space by default: u_h = √(θ_h/(π/2))·90,
//! u_d = θ_d/(π/2)·90, u_p = φ_d/π·180. u_h and u_d are clamped to the last sample (89: the
//! table holds nothing beyond θ_h ≈ 88°, θ_d = 89°); u_p wraps (sample 179 is followed by
//! sample 0 at φ_d = π ≡ 0). The nearest-sample lookup is kept for measuring what interpolation
//! buys (`docs/PERFORMANCE.md`, "MERL lookups"); it is MERL's reference lookup moved by half a
//! bin to the nearest sample.
//!
//! Real files hold negative values (−1) in bins that were not measured (mostly grazing). They
//! are counted ([`MerlBrdf::invalid_entries`]) and read as 0 by the nearest lookup; the
//! trilinear lookup leaves them out and renormalises the weights of the valid corners, so an
//! unmeasured neighbour does not drag a measured value towards 0. Only where none of the eight
//! corners is valid is the value 0.

use super::Brdf;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_2, PI};
use std::path::{Path, PathBuf};

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

/// Internal marker of an unmeasured entry (any negative value in a file).
const UNMEASURED: f32 = -1.0;

/// Why a MERL file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum MerlError {
    /// The file could not be read.
    #[error("cannot read MERL file {path}: {cause}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        cause: std::io::Error,
    },
    /// The file could not be written.
    #[error("cannot write MERL file {path}: {cause}")]
    Write {
        /// File.
        path: String,
        /// Cause.
        cause: std::io::Error,
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

/// How [`MerlBrdf`] turns a direction pair into a value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MerlLookup {
    /// Trilinear in index space over the valid corners (see the module docs).
    #[default]
    Trilinear,
    /// The nearest sample in index space; unmeasured entries read as 0.
    Nearest,
}

/// The angles (θ_h, θ_d, φ_d) at which entry (`ih`, `id`, `ip`) of a table is sampled: the lower
/// edge of MERL's bin (see the module docs).
pub fn sample_angles(ih: usize, id: usize, ip: usize) -> (f64, f64, f64) {
    (
        (ih as f64 / RES_THETA_H as f64).powi(2) * FRAC_PI_2,
        id as f64 / RES_THETA_D as f64 * FRAC_PI_2,
        ip as f64 / RES_PHI_D as f64 * PI,
    )
}

/// A tabulated MERL BRDF (values already scaled, in 1/sr).
#[derive(Clone, Debug, PartialEq)]
pub struct MerlBrdf {
    /// RGB per entry, interleaved so that one corner of a lookup is one cache access;
    /// [`UNMEASURED`] where the file held a negative value.
    values: Vec<[f32; 3]>,
    invalid: usize,
    lookup: MerlLookup,
}

impl MerlBrdf {
    /// Reads a `.binary` file.
    pub fn read(path: &Path) -> Result<Self, MerlError> {
        let name = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| MerlError::Io {
            path: name.clone(),
            cause: source,
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
        let mut values = vec![[0.0_f32; 3]; SAMPLES];
        let mut invalid = 0;
        for (index, chunk) in bytes[12..].chunks_exact(8).enumerate() {
            let v = f64::from_le_bytes(chunk.try_into().unwrap_or([0; 8]));
            if !v.is_finite() {
                return Err(MerlError::NotFinite {
                    path: origin.into(),
                    index,
                });
            }
            let (c, i) = (index / SAMPLES, index % SAMPLES);
            values[i][c] = if v < 0.0 {
                invalid += 1;
                UNMEASURED
            } else {
                (v * SCALES[c]) as f32
            };
        }
        Ok(Self {
            values,
            invalid,
            lookup: MerlLookup::default(),
        })
    }

    /// Tabulates `f(θ_h, θ_d, φ_d)` (RGB in 1/sr, `None` for unmeasured) at every sample
    /// position ([`sample_angles`]). Non-finite or negative values are stored as unmeasured.
    pub fn from_half_diff_fn(f: impl Fn(f64, f64, f64) -> Option<[f64; 3]>) -> Self {
        // Sequential on purpose: tables may be built lazily on rayon workers, where a nested
        // parallel loop inside a `OnceLock` initialiser can deadlock. 1.5 M samples of an
        // analytic BRDF take a fraction of a second.
        let mut values = Vec::with_capacity(SAMPLES);
        let mut invalid = 0;
        for ih in 0..RES_THETA_H {
            for id in 0..RES_THETA_D {
                for ip in 0..RES_PHI_D {
                    let (th, td, pd) = sample_angles(ih, id, ip);
                    let v = f(th, td, pd).unwrap_or([-1.0; 3]).map(|x| {
                        if x.is_finite() && x >= 0.0 {
                            x as f32
                        } else {
                            invalid += 1;
                            UNMEASURED
                        }
                    });
                    values.push(v);
                }
            }
        }
        Self {
            values,
            invalid,
            lookup: MerlLookup::default(),
        }
    }

    /// Tabulates `f(ω_i, ω_o)` at every sample position; samples with a direction at or below
    /// the horizon are unmeasured, as in real files.
    pub fn from_fn(f: impl Fn(DVec3, DVec3) -> [f64; 3]) -> Self {
        Self::from_half_diff_fn(|th, td, pd| {
            let (wi, wo) = half_diff_to_directions(th, td, pd);
            (wi.z > 0.0 && wo.z > 0.0).then(|| f(wi, wo))
        })
    }

    /// Tabulates any BRDF ([`MerlBrdf::from_fn`]).
    pub fn tabulate(brdf: &dyn Brdf) -> Self {
        Self::from_fn(|wi, wo| brdf.eval(wi, wo))
    }

    /// The bytes of a MERL file holding [`MerlBrdf::tabulate`] of `brdf`.
    pub fn tabulate_bytes(brdf: &dyn Brdf) -> Vec<u8> {
        Self::tabulate(brdf).to_bytes()
    }

    /// The table as the bytes of a MERL file (unmeasured entries as −1).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FILE_BYTES);
        for d in [RES_THETA_H, RES_THETA_D, RES_PHI_D] {
            out.extend((d as i32).to_le_bytes());
        }
        for (c, scale) in SCALES.iter().enumerate() {
            for v in &self.values {
                let stored = if v[c] < 0.0 { -1.0 } else { v[c] as f64 / scale };
                out.extend(stored.to_le_bytes());
            }
        }
        out
    }

    /// Writes the table as a MERL `.binary` file, atomically: a reader never sees a partial
    /// file (the bytes go to a temporary file in the same folder, renamed into place).
    pub fn write(&self, path: &Path) -> Result<(), MerlError> {
        let err = |source| MerlError::Write {
            path: path.display().to_string(),
            cause: source,
        };
        let name = path
            .file_name()
            .ok_or_else(|| err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a file path")))?;
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let mut tmp_name = std::ffi::OsString::from(".");
        tmp_name.push(name);
        tmp_name.push(format!(".tmp-{}", std::process::id()));
        let tmp: PathBuf = dir.join(tmp_name);
        let result = (|| {
            use std::io::Write;
            let mut file = std::fs::File::create(&tmp)?;
            file.write_all(&self.to_bytes())?;
            file.sync_all()?;
            std::fs::rename(&tmp, path)
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        result.map_err(err)
    }

    /// Entries (per channel) that were negative (unmeasured) in the file.
    pub fn invalid_entries(&self) -> usize {
        self.invalid
    }

    /// The same table with another lookup.
    pub fn with_lookup(mut self, lookup: MerlLookup) -> Self {
        self.lookup = lookup;
        self
    }

    /// The lookup in use.
    pub fn lookup(&self) -> MerlLookup {
        self.lookup
    }

    /// Entry (`ih`, `id`, `ip`) in 1/sr, `None` where unmeasured.
    pub fn entry(&self, ih: usize, id: usize, ip: usize) -> Option<[f64; 3]> {
        let v = self.values.get((ih * RES_THETA_D + id) * RES_PHI_D + ip)?;
        (v.iter().all(|&x| x >= 0.0)).then(|| v.map(f64::from))
    }

    /// The value at index-space coordinates `u` = (u_h, u_d, u_p) (see the module docs).
    fn value_at(&self, u: [f64; 3]) -> [f64; 3] {
        match self.lookup {
            MerlLookup::Nearest => self.nearest(u),
            MerlLookup::Trilinear => self.trilinear(u),
        }
    }

    fn nearest(&self, [uh, ud, up]: [f64; 3]) -> [f64; 3] {
        let ih = (uh.round() as usize).min(RES_THETA_H - 1);
        let id = (ud.round() as usize).min(RES_THETA_D - 1);
        let ip = (up.round() as usize) % RES_PHI_D;
        let v = self.values[(ih * RES_THETA_D + id) * RES_PHI_D + ip];
        v.map(|x| f64::from(x.max(0.0)))
    }

    fn trilinear(&self, [uh, ud, up]: [f64; 3]) -> [f64; 3] {
        let (h0, h1, fh) = corners(uh, RES_THETA_H, false);
        let (d0, d1, fd) = corners(ud, RES_THETA_D, false);
        let (p0, p1, fp) = corners(up, RES_PHI_D, true);
        let (mut acc, mut wsum) = ([0.0_f64; 3], [0.0_f64; 3]);
        let (mut plain, mut count) = ([0.0_f64; 3], [0_u32; 3]);
        for (ih, wh) in [(h0, 1.0 - fh), (h1, fh)] {
            for (id, wd) in [(d0, 1.0 - fd), (d1, fd)] {
                let row = (ih * RES_THETA_D + id) * RES_PHI_D;
                for (ip, wp) in [(p0, 1.0 - fp), (p1, fp)] {
                    let w = wh * wd * wp;
                    let v = self.values[row + ip];
                    for c in 0..3 {
                        if v[c] >= 0.0 {
                            let x = f64::from(v[c]);
                            acc[c] += w * x;
                            wsum[c] += w;
                            plain[c] += x;
                            count[c] += 1;
                        }
                    }
                }
            }
        }
        std::array::from_fn(|c| {
            if wsum[c] > 0.0 {
                acc[c] / wsum[c]
            } else if count[c] > 0 {
                // Exactly on a face whose valid corners all have weight 0: those corners are
                // still the nearest measurements.
                plain[c] / f64::from(count[c])
            } else {
                0.0
            }
        })
    }
}

/// The two samples around index-space coordinate `u` on an axis of `n` samples, and the weight
/// of the second. `u` is already in range ([`index_coords`]).
fn corners(u: f64, n: usize, periodic: bool) -> (usize, usize, f64) {
    let i0 = (u as usize).min(n - 1);
    let f = (u - i0 as f64).clamp(0.0, 1.0);
    let i1 = if periodic { (i0 + 1) % n } else { (i0 + 1).min(n - 1) };
    (i0, i1, f)
}

/// Index-space coordinates (u_h, u_d, u_p) of a direction pair, sample i of each axis at i;
/// `None` when either direction is at or below the horizon or the input is not finite.
///
/// Computes the same angles as [`directions_to_half_diff`] from the half vector's frame
/// directly (no rotations), which is about twice as fast and the bulk of a lookup's cost.
fn index_coords(wi: DVec3, wo: DVec3) -> Option<[f64; 3]> {
    // Written so that NaN fails the test.
    if !(wi.z > 0.0 && wo.z > 0.0) {
        return None;
    }
    let h = (wi + wo).normalize();
    if !h.is_finite() {
        return None;
    }
    let sin_h = (h.x * h.x + h.y * h.y).sqrt();
    // At θ_h = 0 φ_h is undefined; MERL's atan2(0, 0) = 0 picks the x axis, and an isotropic
    // table does not depend on φ_d there anyway.
    let (cos_ph, sin_ph) = if sin_h > 0.0 {
        (h.x / sin_h, h.y / sin_h)
    } else {
        (1.0, 0.0)
    };
    // ω_i in the frame (t, b, h) that MERL reaches by rotating −φ_h about z, then −θ_h about y.
    let t = DVec3::new(h.z * cos_ph, h.z * sin_ph, -sin_h);
    let b = DVec3::new(-sin_ph, cos_ph, 0.0);
    // atan2 rather than MERL's acos: acos loses half the digits near 0, and the square-root
    // θ_h axis magnifies exactly there (θ_h = 1e-8 would read 5 % off in index space).
    let th = sin_h.atan2(h.z);
    let td = wi.cross(h).length().atan2(wi.dot(h));
    let pd = wi.dot(b).atan2(wi.dot(t));
    if !(th.is_finite() && td.is_finite() && pd.is_finite()) {
        return None;
    }
    Some(angles_to_index(th, td, pd))
}

/// Index-space coordinates of (θ_h, θ_d, φ_d), clamped (θ) and wrapped (φ) into the table.
fn angles_to_index(th: f64, td: f64, pd: f64) -> [f64; 3] {
    let last_h = (RES_THETA_H - 1) as f64;
    let last_d = (RES_THETA_D - 1) as f64;
    let uh = ((th.max(0.0) / FRAC_PI_2).sqrt() * RES_THETA_H as f64).min(last_h);
    let ud = (td.max(0.0) / FRAC_PI_2 * RES_THETA_D as f64).min(last_d);
    let n = RES_PHI_D as f64;
    let up = (pd / PI * n).rem_euclid(n);
    // rem_euclid rounds a tiny negative up to n itself, which is sample 0 again.
    let up = if up >= n { 0.0 } else { up };
    [uh, ud, up]
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
        index_coords(wi, wo).map_or([0.0; 3], |u| self.value_at(u))
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

    /// Deterministic points in [0, 1)³ (additive recurrence on the plastic constant's powers).
    fn points(n: usize) -> impl Iterator<Item = [f64; 3]> {
        let a = [
            0.819_172_513_396_164_4,
            0.671_043_606_703_789_2,
            0.549_700_477_901_970_5,
        ];
        (0..n).map(move |k| a.map(|x| (0.5 + x * k as f64).fract()))
    }

    fn ggx_table(alpha: f64) -> MerlBrdf {
        MerlBrdf::tabulate(&Ggx::new(alpha, Fresnel::Schlick([0.9, 0.5, 0.04])))
    }

    /// The index MERL's reference code gives θ_h, θ_d, φ_d (truncation).
    fn reference_index(th: f64, td: f64, pd: f64) -> [usize; 3] {
        [
            ((th / FRAC_PI_2 * 8100.0).sqrt() as usize).min(89),
            ((td / FRAC_PI_2 * 90.0) as usize).min(89),
            ((pd / PI * 180.0) as usize).min(179),
        ]
    }

    #[test]
    fn samples_sit_on_the_lower_edges_of_merls_bins_and_interpolate_linearly_in_index_space() {
        // The reference lookup switches from bin i − 1 to bin i exactly at the sample angle.
        for i in 1..89 {
            let (th, td, pd) = sample_angles(i, i, 2 * i);
            assert_eq!(
                reference_index(th * (1.0 + 1e-9), td * (1.0 + 1e-9), pd * (1.0 + 1e-9)),
                [i, i, 2 * i]
            );
            assert_eq!(
                reference_index(th * (1.0 - 1e-9), td * (1.0 - 1e-9), pd * (1.0 - 1e-9)),
                [i - 1, i - 1, 2 * i - 1]
            );
        }
        // A table holding its own index-space coordinates (θ_h through the square-root mapping)
        // reads back the coordinates of any direction: a half-bin offset between where the
        // table is written and where lookups put the samples would show as an error of 0.5.
        let m = MerlBrdf::from_half_diff_fn(|th, td, pd| {
            let [uh, ud, _] = angles_to_index(th, td, pd);
            Some([uh, ud, 2.0 + (2.0 * pd).cos()])
        });
        let mut checked = 0;
        for [a, b, c] in points(4000).chain([[0.0, 0.0, 0.0], [1e-12, 0.3, 0.999_999]]) {
            let (th, td, pd) = (a * a * 1.2, b * 0.6, c * 2.0 * PI);
            let (wi, wo) = half_diff_to_directions(th, td, pd);
            if wi.z <= 1e-3 || wo.z <= 1e-3 {
                continue;
            }
            let [uh, ud, _] = angles_to_index(th, td, pd);
            let f = m.eval(wi, wo);
            assert!((f[0] - uh).abs() < 2e-5 * uh.max(1.0), "θ_h {th}: {} vs {uh}", f[0]);
            assert!((f[1] - ud).abs() < 2e-5 * ud.max(1.0), "θ_d {td}: {} vs {ud}", f[1]);
            // cos 2φ_d is periodic in π: no seam at φ_d = 0 ≡ π, curvature error only.
            assert!((f[2] - 2.0 - (2.0 * pd).cos()).abs() < 2e-4, "φ_d {pd}: {}", f[2]);
            checked += 1;
        }
        assert!(checked > 2000, "{checked}");
    }

    #[test]
    fn the_fast_half_diff_coordinates_match_merls_rotations() {
        for [a, b, c] in points(2000) {
            let wi = DVec3::new(2.0 * a - 1.0, 2.0 * b - 1.0, c + 1e-3).normalize();
            let wo = DVec3::new(2.0 * c - 1.0, 1.0 - 2.0 * a, b + 1e-3).normalize();
            let (th, _, td, pd) = directions_to_half_diff(wi, wo);
            let want = angles_to_index(th, td, pd);
            let Some(got) = index_coords(wi, wo) else {
                panic!("{wi} {wo}");
            };
            for k in 0..3 {
                let mut d = (got[k] - want[k]).abs();
                if k == 2 {
                    d = d.min(RES_PHI_D as f64 - d);
                }
                assert!(d < 1e-7, "{wi} {wo}: {got:?} vs {want:?}");
            }
        }
    }

    #[test]
    fn extreme_and_invalid_directions_give_finite_non_negative_values() {
        let m = ggx_table(0.1);
        let g = Ggx::new(0.1, Fresnel::Schlick([0.9, 0.5, 0.04]));
        let eps = 1e-9;
        let mut pairs = Vec::new();
        for th in [
            0.0,
            1e-12,
            1e-6,
            0.3,
            FRAC_PI_2 - 0.2,
            FRAC_PI_2 - 1e-3,
            FRAC_PI_2 - eps,
        ] {
            for td in [0.0, 1e-12, 0.4, 1.0, FRAC_PI_2 - 1e-3, FRAC_PI_2 - eps] {
                for pd in [0.0, eps, PI - eps, PI, PI + eps, 2.0 * PI - eps, -eps, -PI] {
                    pairs.push(half_diff_to_directions(th, td, pd));
                }
            }
        }
        let nan = DVec3::new(f64::NAN, 0.0, 1.0);
        let inf = DVec3::new(f64::INFINITY, 0.0, 1.0);
        pairs.extend([
            (DVec3::Z, DVec3::Z),
            (nan, DVec3::Z),
            (DVec3::Z, nan),
            (DVec3::splat(f64::NAN), DVec3::splat(f64::NAN)),
            (inf, DVec3::Z),
            (DVec3::new(0.0, 0.0, f64::INFINITY), DVec3::Z),
            (DVec3::ZERO, DVec3::Z),
            (DVec3::new(1.0, 0.0, 1e-300), DVec3::new(-1.0, 0.0, 1e-300)),
            (DVec3::new(1.0, 0.0, 1e-300), DVec3::new(1.0, 0.0, 1e-300)),
        ]);
        for lookup in [MerlLookup::Trilinear, MerlLookup::Nearest] {
            let m = m.clone().with_lookup(lookup);
            for &(wi, wo) in &pairs {
                let f = m.eval(wi, wo);
                assert!(
                    f.iter().all(|v| v.is_finite() && *v >= 0.0),
                    "{lookup:?} f({wi}, {wo}) = {f:?}"
                );
                let usable = wi.z > 0.0 && wo.z > 0.0 && wi.is_finite() && wo.is_finite();
                if !usable {
                    assert_eq!(f, [0.0; 3], "{lookup:?} below the horizon or not finite: {wi}, {wo}");
                }
            }
        }
        // θ_h = 0 is sample 0: on the θ_d samples the table returns the analytic peak itself.
        for id in [0, 10, 45, 80] {
            let (_, td, _) = sample_angles(0, id, 0);
            for pd in [0.0, 1.0, PI - eps, 2.0 * PI - eps] {
                let (wi, wo) = half_diff_to_directions(0.0, td, pd);
                let (a, b) = (m.eval(wi, wo), g.eval(wi, wo));
                for c in 0..3 {
                    assert!((a[c] - b[c]).abs() <= 1e-6 * b[c], "θ_d {td} φ_d {pd}: {a:?} vs {b:?}");
                }
            }
        }
        // φ_d wraps: both sides of 0 ≡ π agree, and φ_d + π (reciprocity) is the same entry.
        for (th, td) in [(0.2, 0.3), (0.6, 1.0), (0.05, 0.8)] {
            let at = |pd| {
                let (wi, wo) = half_diff_to_directions(th, td, pd);
                m.eval(wi, wo)
            };
            let (a, b, c, d) = (at(1e-9), at(2.0 * PI - 1e-9), at(PI - 1e-9), at(PI + 1e-9));
            for k in 0..3 {
                let tol = 1e-6 * a[k].max(1e-3);
                assert!((a[k] - b[k]).abs() < tol && (a[k] - c[k]).abs() < tol && (a[k] - d[k]).abs() < tol);
            }
        }
    }

    #[test]
    fn unmeasured_neighbours_are_left_out_not_read_as_zero() {
        // Measured (0.5, 0.25, 0.125) where θ_d < 30°, except for a hole of single bins;
        // unmeasured elsewhere.
        let m = MerlBrdf::from_half_diff_fn(|th, td, pd| {
            let [uh, ud, up] = angles_to_index(th, td, pd);
            let hole = uh as usize == 20 && ud as usize == 10 && up as usize == 40;
            (ud < 30.0 && !hole).then_some([0.5, 0.25, 0.125])
        });
        assert_eq!(m.invalid_entries(), 3 * (RES_THETA_H * 60 * RES_PHI_D + 1));
        let at = |m: &MerlBrdf, uh: f64, ud: f64, up: f64| {
            let th = (uh / RES_THETA_H as f64).powi(2) * FRAC_PI_2;
            let (wi, wo) = half_diff_to_directions(th, ud / 90.0 * FRAC_PI_2, up / 180.0 * PI);
            m.eval(wi, wo)
        };
        for (uh, ud, up) in [
            (20.0, 10.0, 40.0),
            (19.5, 9.7, 40.3),
            (20.3, 10.0, 39.5),
            (10.0, 29.5, 5.0),
            (10.0, 29.0, 5.0),
        ] {
            let f = at(&m, uh, ud, up);
            for (v, want) in f.iter().zip([0.5, 0.25, 0.125]) {
                assert!((v - want).abs() < 1e-6, "({uh}, {ud}, {up}): {f:?}");
            }
        }
        // No measured corner: 0.
        assert_eq!(at(&m, 10.0, 45.5, 5.0), [0.0; 3]);
        // The nearest lookup reads an unmeasured sample as 0, as before.
        assert_eq!(
            at(&m.clone().with_lookup(MerlLookup::Nearest), 20.0, 10.0, 40.0),
            [0.0; 3]
        );
    }

    /// Worst ratio, over consecutive points of `path`, of the jump in value to what trilinear
    /// interpolation of the table allows: |Δf| ≤ Σ_k |Δu_k| · (largest difference between
    /// neighbouring entries along axis k in the box of samples around both points).
    fn worst_jump(m: &MerlBrdf, path: &[(DVec3, DVec3)]) -> f64 {
        let mut worst: f64 = 0.0;
        for pair in path.windows(2) {
            let [(ai, ao), (bi, bo)] = [pair[0], pair[1]];
            let (Some(ua), Some(ub)) = (index_coords(ai, ao), index_coords(bi, bo)) else {
                continue;
            };
            let (fa, fb) = (m.eval(ai, ao), m.eval(bi, bo));
            // Samples along each axis, in order, covering the cells of both points.
            let mut axes: [Vec<usize>; 3] = Default::default();
            let mut du = [0.0; 3];
            for k in 0..3 {
                let (lo, hi) = (ua[k].min(ub[k]), ua[k].max(ub[k]));
                du[k] = hi - lo;
                axes[k] = if k == 2 && du[k] > RES_PHI_D as f64 / 2.0 {
                    du[k] = RES_PHI_D as f64 - du[k];
                    (hi as usize..RES_PHI_D).chain(0..=lo as usize + 1).collect()
                } else if k == 2 {
                    (lo as usize..=hi as usize + 1).map(|p| p % RES_PHI_D).collect()
                } else {
                    (lo as usize..=(hi as usize + 1).min(RES_THETA_H - 1)).collect()
                };
            }
            let at = |ih: usize, id: usize, ip: usize| {
                m.entry(ih, id, ip)
                    .unwrap_or_else(|| panic!("paths stay where the table is measured: ({ih}, {id}, {ip})"))
            };
            let mut step = [[0.0_f64; 3]; 3];
            let mut top = [0.0_f64; 3];
            for (jh, &ih) in axes[0].iter().enumerate() {
                for (jd, &id) in axes[1].iter().enumerate() {
                    for (jp, &ip) in axes[2].iter().enumerate() {
                        let v = at(ih, id, ip);
                        let next = [
                            axes[0].get(jh + 1).map(|&n| at(n, id, ip)),
                            axes[1].get(jd + 1).map(|&n| at(ih, n, ip)),
                            axes[2].get(jp + 1).map(|&n| at(ih, id, n)),
                        ];
                        for c in 0..3 {
                            top[c] = top[c].max(v[c]);
                            for k in 0..3 {
                                if let Some(w) = next[k] {
                                    step[k][c] = step[k][c].max((w[c] - v[c]).abs());
                                }
                            }
                        }
                    }
                }
            }
            for c in 0..3 {
                let bound = (0..3).map(|k| du[k] * step[k][c]).sum::<f64>() + 1e-6 * top[c] + 1e-12;
                worst = worst.max((fa[c] - fb[c]).abs() / bound);
            }
        }
        worst
    }

    #[test]
    fn interpolated_values_have_no_jumps_beyond_the_tables_local_variation() {
        let m = ggx_table(0.15);
        let dir = |theta: f64, phi: f64| DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let n = 20_000;
        let mut paths: Vec<Vec<(DVec3, DVec3)>> = Vec::new();
        // The light circling a fixed viewer: through the mirror direction (θ_h = 0) and across
        // the φ_d seam.
        let wo = dir(0.5, 0.0);
        paths.push((0..n).map(|k| (dir(0.5, 2.0 * PI * k as f64 / n as f64), wo)).collect());
        // The light sweeping the plane of incidence through the specular peak.
        paths.push(
            (0..n)
                .map(|k| (dir(-1.0 + 2.0 * k as f64 / n as f64, PI), wo))
                .collect(),
        );
        // Both directions moving: θ_d from 0 (ω_i = ω_o) outwards.
        paths.push(
            (0..n)
                .map(|k| {
                    let t = 1.0 * k as f64 / n as f64;
                    (dir(0.3 + t, 0.2), dir(0.3, 0.2 + 2.0 * t))
                })
                .collect(),
        );
        // Across the φ_d seam (0 ≡ π) away from the degenerate θ_h = 0 and θ_d = 0, where the
        // circling light crosses it.
        for centre in [0.0, PI] {
            paths.push(
                (0..n)
                    .map(|k| half_diff_to_directions(0.5, 0.8, centre - 0.3 + 0.6 * k as f64 / n as f64))
                    .collect(),
            );
        }
        for (i, path) in paths.iter().enumerate() {
            let w = worst_jump(&m, path);
            assert!(w <= 1.0, "path {i}: a jump {w:.3}× the table's local variation");
            // The check is sharp enough to see the nearest lookup's steps.
            let w = worst_jump(&m.clone().with_lookup(MerlLookup::Nearest), path);
            assert!(w > 5.0, "path {i}: nearest lookup's worst step only {w:.3}× the bound");
        }
    }

    #[test]
    fn written_files_read_back_identical_and_a_failed_write_leaves_nothing() {
        let m = ggx_table(0.3);
        let dir = std::env::temp_dir().join(format!("matedit-merl-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ggx.binary");
        m.write(&path).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len() as usize, FILE_BYTES);
        let back = MerlBrdf::read(&path).unwrap();
        assert_eq!(back, m);
        assert_eq!(back.invalid_entries(), m.invalid_entries());
        let missing = dir.join("no/such/dir/x.binary");
        let e = m.write(&missing).unwrap_err().to_string();
        assert!(e.contains("no/such/dir/x.binary"), "{e}");
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left, [std::ffi::OsString::from("ggx.binary")]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

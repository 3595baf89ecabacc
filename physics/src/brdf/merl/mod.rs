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
mod tests;

//! The Directional Statistics BRDF (Nishino 2009) with 3 lobes: the paper's 108-parameter
//! material **m**.
//!
//! Per colour channel c and lobe k ∈ {1, 2, 3}:
//!
//! ```text
//! ρ_c(θ_h, θ_d) = Σ_k expm1( κ_{c,k}(θ_d) · cos(θ_h)^{γ_{c,k}(θ_d)} )
//! ```
//!
//! κ (lobe magnitude) and γ (lobe sharpness) are each given at the 6 knots
//! [`THETA_D_KNOTS_DEG`] and interpolated piecewise linearly in **log space** between them:
//! 3 channels × 3 lobes × {κ, γ} × 6 knots = 108 numbers.
//!
//! **Parameter order** (the flat vector the network predicts):
//! `index = ((channel · 3 + lobe) · 2 + p) · 6 + knot`, p = 0 for κ and 1 for γ.
//!
//! **Normalisation** to the network's tanh range: each parameter v with raw range [lo, hi] maps
//! to x = −0.95 + 1.9 · (ln v − ln lo) / (ln hi − ln lo). Raw ranges: κ ∈ [`KAPPA_RANGE`],
//! γ ∈ [`GAMMA_RANGE`]. The inverse accepts x ∈ [−1, 1] (what tanh can output) and clamps
//! beyond, so a network output always maps to a finite, positive material.

use super::{Brdf, half_angles};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Colour channels.
pub const CHANNELS: usize = 3;
/// Lobes per channel.
pub const LOBES: usize = 3;
/// Knots in θ_d per lobe parameter.
pub const KNOTS: usize = 6;
/// Total parameter count.
pub const PARAMS: usize = CHANNELS * LOBES * 2 * KNOTS;
/// θ_d of the knots, in degrees. Spacing shrinks towards grazing, where Fresnel reflectance and
/// masking change fastest (Schlick's (1 − cos θ_d)^5 is 4e-5 at 30° but 0.24 at 78°).
pub const THETA_D_KNOTS_DEG: [f64; KNOTS] = [0.0, 30.0, 50.0, 65.0, 78.0, 90.0];
/// Raw range of κ. expm1(20) ≈ 4.9e8 covers the peaks of measured near-mirrors; 1e-5 is an
/// "off" lobe.
pub const KAPPA_RANGE: (f64, f64) = (1e-5, 20.0);
/// Raw range of γ: 1e-3 is flat (cos^γ ≈ 1), 1e4 is a lobe about 0.8° wide.
pub const GAMMA_RANGE: (f64, f64) = (1e-3, 1e4);
/// Normalised values of the raw range ends.
pub const NORMALISED_BOUND: f64 = 0.95;

/// Which lobe parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LobeParam {
    /// Magnitude κ.
    Kappa,
    /// Sharpness γ.
    Gamma,
}

impl LobeParam {
    /// Raw range of this parameter.
    pub fn range(self) -> (f64, f64) {
        match self {
            LobeParam::Kappa => KAPPA_RANGE,
            LobeParam::Gamma => GAMMA_RANGE,
        }
    }

    /// The value of normalised `x`, clamped to [−1, 1]: ±0.95 are the raw range's ends, ±1
    /// slightly beyond them (a tanh output that saturates).
    fn denormalised(self, x: f64) -> f64 {
        let (lo, hi) = self.range();
        let t = (x.clamp(-1.0, 1.0) + NORMALISED_BOUND) / (2.0 * NORMALISED_BOUND);
        (lo.ln() + t * (hi.ln() - lo.ln())).exp()
    }

    /// What a material may hold: the raw range widened to what normalised values in [−1, 1] map
    /// to, so that every m' a network predicts (its `material.dsbrdf.json`) reads back.
    pub fn accepted(self) -> (f64, f64) {
        (self.denormalised(-1.0), self.denormalised(1.0))
    }
}

/// Flat index of one parameter.
pub fn param_index(channel: usize, lobe: usize, p: LobeParam, knot: usize) -> usize {
    ((channel * LOBES + lobe) * 2 + p as usize) * KNOTS + knot
}

/// (channel, lobe, parameter, knot) of a flat index.
pub fn param_meaning(index: usize) -> (usize, usize, LobeParam, usize) {
    let knot = index % KNOTS;
    let p = if (index / KNOTS).is_multiple_of(2) {
        LobeParam::Kappa
    } else {
        LobeParam::Gamma
    };
    let lobe = (index / (2 * KNOTS)) % LOBES;
    let channel = index / (2 * KNOTS * LOBES);
    (channel, lobe, p, knot)
}

/// How a material file names a parameter: `kappa[c][k][j]` or `gamma[c][k][j]`.
pub fn param_name(index: usize) -> String {
    let (c, k, p, j) = param_meaning(index);
    let p = match p {
        LobeParam::Kappa => "kappa",
        LobeParam::Gamma => "gamma",
    };
    format!("{p}[{c}][{k}][{j}]")
}

/// Why a set of DSBRDF parameters or a material file was refused.
#[derive(Debug, thiserror::Error)]
pub enum DsbrdfError {
    /// A parameter is NaN, infinite or outside its raw range.
    #[error("{name} = {value} is outside its range [{lo}, {hi}]")]
    OutOfRange {
        /// Field path, e.g. `kappa[0][2][5]` (channel, lobe, knot).
        name: String,
        /// The value.
        value: f64,
        /// Lower bound.
        lo: f64,
        /// Upper bound.
        hi: f64,
    },
    /// The vector does not have 108 entries.
    #[error("expected {PARAMS} parameters, got {0}")]
    Length(usize),
    /// A normalised parameter is NaN.
    #[error("normalised parameter {0} is NaN")]
    NormalisedNan(usize),
    /// The file could not be read.
    #[error("cannot read material file {path}: {cause}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        cause: std::io::Error,
    },
    /// The file is not valid material JSON (serde names line and column).
    #[error("{path}: {cause}")]
    Parse {
        /// File.
        path: String,
        /// Cause, with line and column.
        cause: serde_json::Error,
    },
    /// The file's header does not describe this model.
    #[error("{path}: field `{field}`: {message}")]
    Header {
        /// File.
        path: String,
        /// Field name.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
}

/// A 3-lobe DSBRDF material (raw parameters).
#[derive(Clone, Debug, PartialEq)]
pub struct Dsbrdf {
    params: [f64; PARAMS],
}

/// κ and γ of every (channel, lobe) at one θ_d: `[channel][lobe] = (κ, γ)`.
pub type LobesAt = [[(f64, f64); LOBES]; CHANNELS];

impl Dsbrdf {
    /// From raw parameters in the documented order; every value must lie in its accepted range
    /// ([`LobeParam::accepted`]: the raw range and what a network's normalised ±1 maps to).
    pub fn from_params(params: &[f64]) -> Result<Self, DsbrdfError> {
        if params.len() != PARAMS {
            return Err(DsbrdfError::Length(params.len()));
        }
        let mut out = [0.0; PARAMS];
        for (i, &v) in params.iter().enumerate() {
            let (lo, hi) = param_meaning(i).2.accepted();
            if !(v >= lo && v <= hi) {
                return Err(DsbrdfError::OutOfRange {
                    name: param_name(i),
                    value: v,
                    lo,
                    hi,
                });
            }
            out[i] = v;
        }
        Ok(Self { params: out })
    }

    /// The same (κ, γ) at every knot: `lobes[channel][lobe] = (κ, γ)`, clamped to the accepted
    /// ranges ([`LobeParam::accepted`]).
    pub fn isotropic_in_theta_d(lobes: LobesAt) -> Self {
        let mut params = [0.0; PARAMS];
        for (c, ch) in lobes.iter().enumerate() {
            for (k, &(kappa, gamma)) in ch.iter().enumerate() {
                for j in 0..KNOTS {
                    params[param_index(c, k, LobeParam::Kappa, j)] = clamp_param(kappa, LobeParam::Kappa.accepted());
                    params[param_index(c, k, LobeParam::Gamma, j)] = clamp_param(gamma, LobeParam::Gamma.accepted());
                }
            }
        }
        Self { params }
    }

    /// A near-Lambertian material of the given albedo: one flat lobe with expm1(κ) = albedo/π,
    /// the other two off. (cos^γ with γ = 1e-3 is within 0.5 % of 1 for θ_h < 89.4°.)
    pub fn near_lambertian(albedo: [f64; 3]) -> Self {
        let off = (KAPPA_RANGE.0, GAMMA_RANGE.1);
        let lobes = albedo.map(|a| [((a / std::f64::consts::PI).ln_1p(), GAMMA_RANGE.0), off, off]);
        Self::isotropic_in_theta_d(lobes)
    }

    /// Raw parameters in the documented order.
    pub fn params(&self) -> &[f64; PARAMS] {
        &self.params
    }

    /// The lobe members `(channel, lobe, knot, κ, γ)` whose peak expm1(κ) is at least `fraction`
    /// of their channel's summed peaks at that knot: the members that shape the BRDF there.
    pub fn significant_members(&self, fraction: f64) -> impl Iterator<Item = (usize, usize, usize, f64, f64)> + '_ {
        let p = &self.params;
        (0..CHANNELS).flat_map(move |c| {
            (0..KNOTS).flat_map(move |j| {
                let kappa = move |k| p[param_index(c, k, LobeParam::Kappa, j)];
                let total: f64 = (0..LOBES).map(|k| kappa(k).exp_m1()).sum();
                (0..LOBES)
                    .filter(move |&k| kappa(k).exp_m1() >= fraction * total)
                    .map(move |k| (c, k, j, kappa(k), p[param_index(c, k, LobeParam::Gamma, j)]))
            })
        })
    }

    /// Normalised parameters in [−0.95, 0.95] (the network's target).
    pub fn to_normalised(&self) -> [f64; PARAMS] {
        let mut x = [0.0; PARAMS];
        for (i, v) in self.params.iter().enumerate() {
            let (lo, hi) = param_meaning(i).2.range();
            x[i] = -NORMALISED_BOUND + 2.0 * NORMALISED_BOUND * (v.ln() - lo.ln()) / (hi.ln() - lo.ln());
        }
        x
    }

    /// From normalised parameters (e.g. a tanh output). Values are clamped to [−1, 1], which maps
    /// slightly beyond the raw ranges; NaN is an error.
    pub fn from_normalised(x: &[f64]) -> Result<Self, DsbrdfError> {
        if x.len() != PARAMS {
            return Err(DsbrdfError::Length(x.len()));
        }
        let mut params = [0.0; PARAMS];
        for (i, &xi) in x.iter().enumerate() {
            if xi.is_nan() {
                return Err(DsbrdfError::NormalisedNan(i));
            }
            params[i] = param_meaning(i).2.denormalised(xi);
        }
        Ok(Self { params })
    }

    /// κ and γ of every lobe at difference angle θ_d (radians), log-linear between knots.
    pub fn lobes_at(&self, theta_d: f64) -> LobesAt {
        let deg = theta_d.to_degrees().clamp(0.0, 90.0);
        let seg = THETA_D_KNOTS_DEG
            .windows(2)
            .position(|w| deg <= w[1])
            .unwrap_or(KNOTS - 2);
        let (a, b) = (THETA_D_KNOTS_DEG[seg], THETA_D_KNOTS_DEG[seg + 1]);
        let t = ((deg - a) / (b - a)).clamp(0.0, 1.0);
        let mut out = [[(0.0, 0.0); LOBES]; CHANNELS];
        for (c, ch) in out.iter_mut().enumerate() {
            for (k, lobe) in ch.iter_mut().enumerate() {
                let lerp = |p| {
                    let v0 = self.params[param_index(c, k, p, seg)].ln();
                    let v1 = self.params[param_index(c, k, p, seg + 1)].ln();
                    (v0 + t * (v1 - v0)).exp()
                };
                *lobe = (lerp(LobeParam::Kappa), lerp(LobeParam::Gamma));
            }
        }
        out
    }

    /// ρ per channel at (cos θ_h, θ_d).
    pub fn eval_half(&self, cos_h: f64, theta_d: f64) -> [f64; 3] {
        let lobes = self.lobes_at(theta_d);
        let c = cos_h.clamp(0.0, 1.0);
        lobes.map(|ch| ch.iter().map(|&(kappa, gamma)| (kappa * c.powf(gamma)).exp_m1()).sum())
    }

    /// Reads a material file (see [`DsbrdfFile`]).
    pub fn load(path: &Path) -> Result<Self, DsbrdfError> {
        let p = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| DsbrdfError::Io {
            path: p.clone(),
            cause: source,
        })?;
        Self::from_json(&text, &p)
    }

    /// Parses material JSON; `origin` names the source in errors.
    pub fn from_json(text: &str, origin: &str) -> Result<Self, DsbrdfError> {
        let f: DsbrdfFile = serde_json::from_str(text).map_err(|source| DsbrdfError::Parse {
            path: origin.to_string(),
            cause: source,
        })?;
        let header = |field, message: String| DsbrdfError::Header {
            path: origin.to_string(),
            field,
            message,
        };
        if f.model != "dsbrdf" {
            return Err(header("model", format!("expected \"dsbrdf\", got {:?}", f.model)));
        }
        if f.version != 1 {
            return Err(header("version", format!("expected 1, got {}", f.version)));
        }
        if f.theta_d_knots_deg != THETA_D_KNOTS_DEG {
            return Err(header("theta_d_knots_deg", format!("expected {THETA_D_KNOTS_DEG:?}")));
        }
        let mut params = [0.0; PARAMS];
        for c in 0..CHANNELS {
            for k in 0..LOBES {
                for j in 0..KNOTS {
                    params[param_index(c, k, LobeParam::Kappa, j)] = f.kappa[c][k][j];
                    params[param_index(c, k, LobeParam::Gamma, j)] = f.gamma[c][k][j];
                }
            }
        }
        Self::from_params(&params).map_err(|e| match e {
            DsbrdfError::OutOfRange { name, value, lo, hi } => DsbrdfError::OutOfRange {
                name: format!("{origin}: {name}"),
                value,
                lo,
                hi,
            },
            e => e,
        })
    }

    /// The material as JSON (pretty-printed).
    pub fn to_json(&self) -> String {
        let mut f = DsbrdfFile {
            model: "dsbrdf".into(),
            version: 1,
            theta_d_knots_deg: THETA_D_KNOTS_DEG,
            channels: ["R".into(), "G".into(), "B".into()],
            kappa: [[[0.0; KNOTS]; LOBES]; CHANNELS],
            gamma: [[[0.0; KNOTS]; LOBES]; CHANNELS],
        };
        for c in 0..CHANNELS {
            for k in 0..LOBES {
                for j in 0..KNOTS {
                    f.kappa[c][k][j] = self.params[param_index(c, k, LobeParam::Kappa, j)];
                    f.gamma[c][k][j] = self.params[param_index(c, k, LobeParam::Gamma, j)];
                }
            }
        }
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string_pretty(&f).unwrap_or_default()
    }
}

fn clamp_param(v: f64, (lo, hi): (f64, f64)) -> f64 {
    if v.is_nan() { lo } else { v.clamp(lo, hi) }
}

/// The on-disk form of a DSBRDF material (JSON). `kappa[c][k][j]` and `gamma[c][k][j]` are
/// indexed by channel (R, G, B), lobe and knot.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DsbrdfFile {
    /// Always `"dsbrdf"`.
    pub model: String,
    /// Format version, 1.
    pub version: u32,
    /// Must equal [`THETA_D_KNOTS_DEG`].
    pub theta_d_knots_deg: [f64; KNOTS],
    /// `["R", "G", "B"]`, for readers.
    pub channels: [String; CHANNELS],
    /// κ per channel, lobe, knot.
    pub kappa: [[[f64; KNOTS]; LOBES]; CHANNELS],
    /// γ per channel, lobe, knot.
    pub gamma: [[[f64; KNOTS]; LOBES]; CHANNELS],
}

impl Brdf for Dsbrdf {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        let Some((_, cos_h, cos_d)) = half_angles(wi, wo) else {
            return [0.0; 3];
        };
        self.eval_half(cos_h, cos_d.acos())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::testing;

    fn sample() -> Dsbrdf {
        let mut p = [0.0; PARAMS];
        for (i, v) in p.iter_mut().enumerate() {
            let (c, k, q, j) = param_meaning(i);
            *v = match q {
                LobeParam::Kappa => [0.05, 0.8, 3.0][k] * (1.0 + 0.1 * c as f64) * (1.0 + 0.2 * j as f64),
                LobeParam::Gamma => [0.01, 20.0, 800.0][k] * (1.0 + 0.05 * j as f64),
            };
        }
        Dsbrdf::from_params(&p).unwrap()
    }

    #[test]
    fn index_and_meaning_are_inverse() {
        for i in 0..PARAMS {
            let (c, k, p, j) = param_meaning(i);
            assert_eq!(param_index(c, k, p, j), i);
        }
        assert_eq!(param_index(2, 2, LobeParam::Gamma, 5), PARAMS - 1);
        assert_eq!(param_name(6), "gamma[0][0][0]");
    }

    #[test]
    fn normalisation_round_trips_and_spans_the_tanh_range() {
        let m = sample();
        let x = m.to_normalised();
        assert!(x.iter().all(|v| (-0.95..=0.95).contains(v)));
        let back = Dsbrdf::from_normalised(&x).unwrap();
        for (a, b) in m.params().iter().zip(back.params()) {
            assert!((a - b).abs() <= 1e-12 * a.abs());
        }
        let lo = Dsbrdf::from_normalised(&[-0.95; PARAMS]).unwrap();
        assert!((lo.params()[0] - KAPPA_RANGE.0).abs() < 1e-15);
        let hi = Dsbrdf::from_normalised(&[0.95; PARAMS]).unwrap();
        assert!((hi.params()[6] - GAMMA_RANGE.1).abs() < 1e-8);
        // tanh outputs beyond ±0.95, and garbage beyond ±1, still give finite materials.
        let far = Dsbrdf::from_normalised(&[7.0; PARAMS]).unwrap();
        assert!(far.params().iter().all(|v| v.is_finite() && *v > 0.0));
        assert!(matches!(
            Dsbrdf::from_normalised(&[f64::NAN; PARAMS]),
            Err(DsbrdfError::NormalisedNan(0))
        ));
        assert!(matches!(
            Dsbrdf::from_normalised(&[0.0; 3]),
            Err(DsbrdfError::Length(3))
        ));
    }

    #[test]
    fn every_material_a_network_predicts_is_written_and_read_back() {
        // Normalised values over the whole tanh range and beyond (clamped): the ends ±1, the
        // raw range's ends ±0.95, values between, in a deterministic scatter over all 108.
        let grid: Vec<f64> = (0..=400).map(|k| -1.2 + 2.4 * k as f64 / 400.0).collect();
        for shift in 0..grid.len() {
            let x: Vec<f64> = (0..PARAMS).map(|i| grid[(i * 37 + shift * 11) % grid.len()]).collect();
            let m = Dsbrdf::from_normalised(&x).unwrap();
            let back = Dsbrdf::from_json(&m.to_json(), "m'.json").unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(back, m);
        }
        for p in [LobeParam::Kappa, LobeParam::Gamma] {
            let (lo, hi) = p.accepted();
            let (raw_lo, raw_hi) = p.range();
            assert!(lo < raw_lo && hi > raw_hi && lo > 0.0 && hi.is_finite());
            // Just outside what ±1 gives: refused, naming the parameter and the accepted range.
            for (bad, k) in [(lo * (1.0 - 1e-9), 0), (hi * (1.0 + 1e-9), 5)] {
                let mut params = *sample().params();
                params[param_index(2, 1, p, k)] = bad;
                let e = Dsbrdf::from_params(&params).unwrap_err().to_string();
                let name = if p == LobeParam::Kappa { "kappa" } else { "gamma" };
                assert!(
                    e.contains(&format!("{name}[2][1][{k}]")) && e.contains(&hi.to_string()),
                    "{e}"
                );
            }
        }
        // The widened extremes evaluate finite and non-negative, peak and grazing alike.
        let (k_hi, g_lo, g_hi) = (
            LobeParam::Kappa.accepted().1,
            LobeParam::Gamma.accepted().0,
            LobeParam::Gamma.accepted().1,
        );
        for (kappa, gamma) in [(k_hi, g_lo), (k_hi, g_hi), (LobeParam::Kappa.accepted().0, g_lo)] {
            let params: Vec<f64> = (0..PARAMS)
                .map(|i| {
                    if param_meaning(i).2 == LobeParam::Kappa {
                        kappa
                    } else {
                        gamma
                    }
                })
                .collect();
            let m = Dsbrdf::from_params(&params).unwrap();
            for (cos_h, theta_d) in [(1.0, 0.0), (0.5, 1.0), (1e-9, 1.5), (0.0, std::f64::consts::FRAC_PI_2)] {
                for ch in m.eval_half(cos_h, theta_d) {
                    assert!(
                        ch.is_finite() && ch >= 0.0 && ch <= 3.0 * k_hi.exp_m1() * 1.000001,
                        "{ch}"
                    );
                }
            }
        }
    }

    #[test]
    fn out_of_range_parameters_are_named() {
        let mut p = *sample().params();
        p[param_index(1, 2, LobeParam::Kappa, 3)] = f64::NAN;
        let e = Dsbrdf::from_params(&p).unwrap_err().to_string();
        assert!(e.contains("kappa[1][2][3]"), "{e}");
        p[param_index(1, 2, LobeParam::Kappa, 3)] = 1.0;
        p[param_index(0, 0, LobeParam::Gamma, 0)] = -1.0;
        assert!(
            Dsbrdf::from_params(&p)
                .unwrap_err()
                .to_string()
                .contains("gamma[0][0][0]")
        );
    }

    #[test]
    fn json_round_trips_and_bad_files_name_the_problem() {
        let m = sample();
        let text = m.to_json();
        assert_eq!(Dsbrdf::from_json(&text, "m.json").unwrap(), m);
        let e = Dsbrdf::from_json(&text.replace("\"version\": 1", "\"version\": 2"), "m.json").unwrap_err();
        assert!(e.to_string().contains("version"), "{e}");
        let e = Dsbrdf::from_json(&text.replace("\"model\"", "\"modle\""), "m.json").unwrap_err();
        assert!(
            e.to_string().contains("m.json") && e.to_string().contains("line"),
            "{e}"
        );
        let e = Dsbrdf::from_json("{\"model\": \"dsbrdf\",", "bad.json")
            .unwrap_err()
            .to_string();
        assert!(e.contains("bad.json") && e.contains("line 1"), "{e}");
    }

    #[test]
    fn interpolation_is_log_linear_and_exact_at_knots() {
        let m = sample();
        for (j, deg) in THETA_D_KNOTS_DEG.iter().enumerate() {
            let l = m.lobes_at(deg.to_radians());
            assert!((l[1][2].0 - m.params()[param_index(1, 2, LobeParam::Kappa, j)]).abs() < 1e-12);
        }
        // Midway in log space between knots 0 and 1 is the geometric mean.
        let l = m.lobes_at(15f64.to_radians());
        let (k0, k1) = (
            m.params()[param_index(0, 1, LobeParam::Kappa, 0)],
            m.params()[param_index(0, 1, LobeParam::Kappa, 1)],
        );
        assert!((l[0][1].0 - (k0 * k1).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn dsbrdf_is_reciprocal_and_finite_on_hard_cases() {
        testing::check_basic(&sample());
        // Extremes of every range.
        for (kappa, gamma) in [
            (KAPPA_RANGE.1, GAMMA_RANGE.0),
            (KAPPA_RANGE.1, GAMMA_RANGE.1),
            (KAPPA_RANGE.0, GAMMA_RANGE.0),
        ] {
            let m = Dsbrdf::isotropic_in_theta_d([[(kappa, gamma); LOBES]; CHANNELS]);
            testing::check_basic(&m);
            for ch in m.eval_half(1.0, 0.0) {
                assert!(ch.is_finite() && ch <= 3.0 * KAPPA_RANGE.1.exp_m1() * 1.000001);
            }
            // θ_h → 90°: cos θ_h = 0 exactly and just above.
            for cos_h in [0.0, 1e-300, 1e-9] {
                for ch in m.eval_half(cos_h, 1.5) {
                    assert!(ch.is_finite() && ch >= 0.0);
                }
            }
        }
        assert!(
            Dsbrdf::isotropic_in_theta_d([[(f64::NAN, f64::INFINITY); LOBES]; CHANNELS])
                .params()
                .iter()
                .all(|v| v.is_finite())
        );
    }

    #[test]
    fn near_lambertian_matches_lambert_albedo() {
        let m = Dsbrdf::near_lambertian([0.5, 0.2, 0.9]);
        let a = testing::albedo(&m, DVec3::new(0.0, 0.6, 0.8), 400, 200);
        for (got, want) in a.iter().zip([0.5, 0.2, 0.9]) {
            assert!((got - want).abs() / want < 5e-3, "{got} vs {want}");
        }
    }
}

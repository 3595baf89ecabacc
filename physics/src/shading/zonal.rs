//! Eq. 2 as a convolution about the view axis: the `zonal` quality.
//!
//! With the orthographic camera (ω_o = +z for every pixel) and no shadows, the summand of Eq. 2,
//! k(n, ω) = f(ω, ω_o; n) · max(0, n·ω), is unchanged when n and ω turn together about +z: an
//! isotropic BRDF sees only the angles between n, ω and ω_o. In polar coordinates about +z (θ
//! from the view, φ around it) the radiance of a normal at (θ_n, φ_n) is therefore
//!
//! ```text
//! R(θ_n, φ_n) = Σ_rows Σ_φ k(θ_n, θ_ω, φ_n − φ) · W(θ_ω, φ),     W = L · dω
//! ```
//!
//! a circular convolution in φ for each pair of a normal row and an environment row. So:
//!
//! 1. **per material** ([`ZonalKernel`], cached by the caller): k is tabulated for every
//!    (normal row, environment row, φ offset) of a [`ZonalGrid`] and Fourier-transformed along
//!    φ once. Each spectrum is cut where its tail no longer matters ([`TAIL`]): broad lobes need a
//!    few harmonics, sharp lobes many but only for the few rows their peak reaches;
//! 2. **per environment** ([`ZonalEnv`]): the map's texels (camera space, the same texels the
//!    exact path sums) are spread onto the grid's rows and columns with Catmull–Rom weights and
//!    each row is Fourier-transformed; a few bright texels behind the object (a sun lighting a
//!    crescent, [`POINT_SHARE`]) stay off the grid and are summed per pixel in step 3;
//! 3. **per image** ([`shade_image_zonal`]): for each normal row, Σ_rows K̂·Ŵ and one inverse
//!    transform give the radiance of every grid normal; each pixel interpolates its normal
//!    bicubically (Catmull–Rom) on that grid.
//!
//! No transcendental function is evaluated per sample: the per-sample work is a few thousand
//! short FFTs, multiply–adds, and 16 taps per pixel. The approximations are the spreading of
//! texels onto the grid (the kernel is, in effect, interpolated between grid directions), the
//! normal grid's interpolation and the cut spectra; all three shrink with the grid spacing, which
//! follows, band by band of θ_d, the material's sharpest significant lobe and how fast its lobes
//! change ([`ZonalGrid::for_brdf`]); materials too
//! sharp for any grid up to [`MAX_ROWS`] get no kernel ([`ZonalPlan::Unresolved`]) and callers
//! shade them per pixel. Measured errors and costs are in `docs/PERFORMANCE.md`.
//!
//! FFTs use rustfft's scalar planner and every sum has a fixed order, so the output bits depend
//! neither on the thread count nor on the CPU's SIMD features.

use super::{catmull_rom, sanitize, shading_normal};
use crate::brdf::dsbrdf::{KNOTS, THETA_D_KNOTS_DEG};
use crate::brdf::{Brdf, BrdfModel, Dsbrdf};
use crate::envmap::{EnvMap, texel_direction, texel_solid_angle};
use crate::fastmath;
use crate::frame::Frame;
use crate::memo::Memo;
use glam::DVec3;
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlannerScalar};
use std::f64::consts::PI;
use std::sync::Arc;

/// Grid spacing as a fraction of the angular width 1/√γ of the material's sharpest lobe that
/// carries energy.
pub const SPACING_PER_WIDTH: f64 = 0.5;
/// Fewest normal rows: the clamped cosine's kink at the terminator needs resolution even for a
/// matte material. Under a real sun behind the object (rooitou_park turned 130°) a matte sphere
/// was 0.82 % off at 32 rows and 0.40 % at 48, at 256² (`zonal_range 256 --probe 1e-5,1,ROWS`).
pub const MIN_ROWS: usize = 48;
/// Most normal rows (the spectra of a 128-row grid take tens of MB per material).
pub const MAX_ROWS: usize = 128;
/// Up to this many times the cap, a material is still tried on the capped grid and the check
/// against the fast path decides; beyond, no kernel is built. The lobe-width rule is an estimate
/// over the worst θ_d band, and a lobe that is sharp only in a few bands, or narrow but weak, can
/// still hold the budget: the library's 16 rough metals ask for 265–274 rows (a κ ≈ 0.15,
/// γ ≈ 3·10³–8·10³ spike at small θ_d on a broad base) and their capped grids are 0.05 % off on
/// the probes and at most 0.12 % over 53 samples of real meshes under 12 real HDRIs at 256²
/// (docs/PERFORMANCE.md).
pub const CHECKED_BEYOND_CAP: usize = 4;
/// Beyond this many times the cap, the capped grid under-resolves a lobe the width rule counts,
/// and its error depends on where the lights fall between grid directions, which the five probe
/// maps sample sparsely: such a kernel must hold [`PROBE_BUDGET_BEYOND`] at the first try. (A
/// random material asking for 2.6× the cap passed the probes at 0.40 % and was 1.03 % off under
/// a real studio HDRI; refined until it passed 0.10 %, it was still 0.76 % off. The rough
/// metals' real errors ran 2.4× their probe error.)
pub const RESOLVED_BEYOND_CAP: usize = 2;
/// The probe budget of a kernel whose lobes ask for more than [`RESOLVED_BEYOND_CAP`] times the
/// cap: a quarter of [`PROBE_BUDGET`], so that 2.4× its probe error stays well inside the
/// factory's 0.5 %; the capped grid must hold it at the first try ([`ZonalKernel::checked`]).
pub const PROBE_BUDGET_BEYOND: f64 = PROBE_BUDGET / 4.0;
/// A spectrum is cut after the harmonic beyond which the sum of |coefficients| falls below this
/// fraction of its mean (the zeroth coefficient).
pub const TAIL: f64 = 1e-3;
/// The accuracy knobs of the zonal method (defaults: the module constants). The speed/error
/// trade-off they span is measured in `docs/PERFORMANCE.md`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZonalParams {
    /// See [`SPACING_PER_WIDTH`].
    pub spacing_per_width: f64,
    /// See [`MIN_ROWS`].
    pub min_rows: usize,
    /// See [`MAX_ROWS`].
    pub max_rows: usize,
    /// See [`TAIL`].
    pub tail: f64,
    /// See [`LOBE_STEP`].
    pub lobe_step: f64,
}

impl Default for ZonalParams {
    fn default() -> Self {
        Self {
            spacing_per_width: SPACING_PER_WIDTH,
            min_rows: MIN_ROWS,
            max_rows: MAX_ROWS,
            tail: TAIL,
            lobe_step: LOBE_STEP,
        }
    }
}

/// A DSBRDF lobe member sets the grid when its share of the image under a point light, peak
/// times width (expm1(κ)·min(1, 1/√γ'): the highlight's value times the square root of its
/// area, i.e. its part of the image's RMS), is at least this fraction of its channel's sum at
/// that θ_d. A lobe the grid does not resolve is wrong by up to its whole share, so this bounds
/// what weak lobes can add to the error. (Energy, peak × width², is the wrong measure: a lobe
/// with 10⁻³ of a matte base's energy but γ = 10⁴ is 8× brighter than the base at its peak, and
/// on a 32-row grid it made a 5 % error under a sun.) Weaker members (the fits' narrow "sparkle"
/// lobes with κ ~ 1e-3) are still summed, at the grid's resolution.
pub const SIGNIFICANT_SHARE: f64 = 1e-3;

/// The most a kernel may differ from the fast path on the [`probe_maps`] (relative RMSE of a
/// 48² sphere, worst over the maps); the factory's budget against `exact` is 0.5 %, and the fast
/// path is within 10⁻³ of `exact` over the whole range.
pub const PROBE_BUDGET: f64 = 4e-3;

/// Side of the sphere image of the check.
const PROBE_RES: usize = 48;

/// Height of the probe maps (the kernel's error comes from interpolating between grid
/// directions, not from the texel size, so a small map tests it as well as the factory's 64×128
/// and keeps the fast-path reference cheap).
const PROBE_MAP_ROWS: usize = 32;

/// The largest angle of a shading normal from the view (see [`shading_normal`]).
fn theta_max() -> f64 {
    super::MIN_FACING.acos()
}

/// Whether the zonal method can shade a material, and on which grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ZonalPlan {
    /// The grid the lobes ask for, within the cap. Where they ask for more than the cap (up to
    /// [`CHECKED_BEYOND_CAP`] times), the capped grid may miss the budget, and
    /// [`ZonalKernel::checked`] decides.
    Grid(ZonalGrid),
    /// The material's lobes are narrower than the grid can be: they need `rows_needed` rows,
    /// more than [`CHECKED_BEYOND_CAP`] times the cap. Shading it on the capped grid would be
    /// wrong by more than the method's error budget (up to 9× the radiance at sharp
    /// highlights), so callers use the per-pixel fast path for it.
    Unresolved {
        /// Normal (and environment) rows the material would need.
        rows_needed: usize,
        /// The cap it exceeds ([`ZonalParams::max_rows`]).
        max_rows: usize,
    },
    /// A measured (tabulated) BRDF: its sharpness is unknown, so it is shaded by the exact path.
    Measured,
}

impl ZonalPlan {
    /// The plan of `brdf` with the default knobs.
    pub fn for_brdf(brdf: &BrdfModel) -> Self {
        Self::for_brdf_with(brdf, &ZonalParams::default())
    }

    /// The plan of `brdf` with explicit knobs.
    pub fn for_brdf_with(brdf: &BrdfModel, params: &ZonalParams) -> Self {
        let Some(need) = ZonalGrid::band_rows_needed(brdf, params) else {
            return Self::Measured;
        };
        let rows = uniform_equivalent(&need).ceil() as usize;
        let max_rows = params.max_rows.max(params.min_rows);
        if rows > CHECKED_BEYOND_CAP * max_rows {
            Self::Unresolved {
                rows_needed: rows,
                max_rows,
            }
        } else {
            let grid = ZonalGrid::for_needs(&need, params);
            Self::Grid(grid.refined_for(brdf, params.lobe_step))
        }
    }

    /// The grid, when the zonal method can shade the material.
    pub fn grid(&self) -> Option<ZonalGrid> {
        match self {
            Self::Grid(g) => Some(*g),
            _ => None,
        }
    }
}

/// The polar grid about the view axis on which a material is tabulated.
///
/// * normal rows a = 0..=`rows` from the normal facing the camera (θ = 0) to the most grazing
///   shading normal (θ_max ≈ 90°), evenly spaced within each of the [`BANDS`] bands of θ_n
///   (`normal_bands` intervals in each);
/// * environment rows from the view direction to straight behind the object, evenly spaced
///   within each band of θ_ω (`env_bands` rows in each, `env_rows` in all);
/// * `phi` columns at φ_j = 2πj/`phi`, shared by normals and environment.
///
/// With the camera's ω_o on the axis, θ_d = θ_ω/2, and a lobe lit from θ_ω peaks at the normal
/// θ_n = θ_ω/2: so the bands' edges are the DSBRDF's θ_d knots (θ_n) and twice them (θ_ω), and
/// a material whose lobes sharpen towards grazing, as fitted measured materials do, gets fine
/// rows at the silhouette and coarse ones elsewhere ([`ZonalGrid::band_rows_needed`]); one whose
/// lobes change steeply between two knots gets finer environment rows in that band
/// ([`ZonalGrid::refined_for`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ZonalGrid {
    /// Normal rows beyond the pole row (the sum of `normal_bands`).
    pub rows: usize,
    /// Environment rows (the sum of `env_bands`).
    pub env_rows: usize,
    /// Columns (FFT length).
    pub phi: usize,
    /// Normal row intervals in each band of θ_n.
    pub normal_bands: [u16; BANDS],
    /// Environment rows in each band of θ_ω.
    pub env_bands: [u16; BANDS],
}

/// Bands of rows: between consecutive DSBRDF θ_d knots, where every lobe is log-linear in θ_d.
pub const BANDS: usize = KNOTS - 1;

/// The most environment rows one band may get from [`ZonalGrid::refined_for`].
pub const MAX_BAND_ROWS: usize = MAX_ROWS;

/// The change of a significant lobe's log-peak allowed between neighbouring environment rows
/// (the kernel is interpolated between rows with Catmull–Rom weights).
pub const LOBE_STEP: f64 = 0.3;

/// Margin (degrees of θ_d) beyond its edges over which a band's lobes set its rows: a normal
/// near a band's edge also sees lobes lit from just across it.
const BAND_MARGIN_DEG: f64 = 5.0;

/// Edges of the bands of θ_n (radians): the knots, the last one θ_max.
fn normal_edges() -> [f64; BANDS + 1] {
    let mut e = THETA_D_KNOTS_DEG.map(f64::to_radians);
    e[BANDS] = theta_max();
    e
}

/// Edges of the bands of θ_ω (radians): twice the knots.
fn env_edges() -> [f64; BANDS + 1] {
    THETA_D_KNOTS_DEG.map(|d| (2.0 * d).to_radians())
}

/// The angle at continuous row coordinate `x` (0 at the first edge, a band's rows evenly
/// spaced within it).
fn band_theta(bands: &[u16; BANDS], edges: &[f64; BANDS + 1], x: f64) -> f64 {
    let mut first = 0.0;
    for (i, &n) in bands.iter().enumerate() {
        let n = n as f64;
        if x <= first + n || i == BANDS - 1 {
            return edges[i] + (x - first) / n * (edges[i + 1] - edges[i]);
        }
        first += n;
    }
    edges[BANDS]
}

/// The continuous row coordinate of an angle over bands of rows (the inverse of [`band_theta`]), with each band's edges, width
/// and first row worked out once: a pixel's lookup is then a few compares, not a trip through
/// the knots (and `acos` for the last edge).
#[derive(Clone, Copy, Debug)]
struct BandCoords {
    edges: [f64; BANDS + 1],
    widths: [f64; BANDS],
    rows: [f64; BANDS],
    first: [f64; BANDS],
}

impl BandCoords {
    fn new(bands: &[u16; BANDS], edges: &[f64; BANDS + 1]) -> Self {
        let rows = bands.map(f64::from);
        let mut first = [0.0; BANDS];
        for i in 1..BANDS {
            first[i] = first[i - 1] + rows[i - 1];
        }
        Self {
            edges: *edges,
            widths: std::array::from_fn(|i| edges[i + 1] - edges[i]),
            rows,
            first,
        }
    }

    /// Row coordinate of `theta` (0 at the first edge; beyond the last edge, extrapolated).
    #[inline]
    fn coord(&self, theta: f64) -> f64 {
        let mut i = 0;
        while i < BANDS - 1 && theta > self.edges[i + 1] {
            i += 1;
        }
        self.first[i] + (theta - self.edges[i]) / self.widths[i] * self.rows[i]
    }
}

/// The rows a uniform grid of `rows` rows over the bands puts in each.
fn dealt(rows: f64, edges: &[f64; BANDS + 1]) -> [usize; BANDS] {
    let span = edges[BANDS] - edges[0];
    std::array::from_fn(|i| ((edges[i + 1] - edges[i]) / span * rows).round().max(1.0) as usize)
}

impl ZonalGrid {
    /// A grid as fine as a uniform one of `rows` normal rows (rounded up to a multiple of 4)
    /// everywhere, with as many environment rows and 4× as many columns, so that rows and
    /// columns have the same spacing at the silhouette.
    pub fn with_rows(rows: usize) -> Self {
        let rows = rows.max(4).div_ceil(4) * 4;
        Self::with_bands(dealt(rows as f64, &normal_edges()), rows)
    }

    /// A grid with `normal` row intervals in each band of θ_n, as many environment rows in each
    /// band of θ_ω (twice as wide, as is a lobe in ω), and 4 × `columns_for` columns: enough for
    /// a uniform grid of `columns_for` rows, i.e. for the finest band.
    pub fn with_bands(normal: [usize; BANDS], columns_for: usize) -> Self {
        let bands = normal.map(|n| n.clamp(1, MAX_BAND_ROWS) as u16);
        let sum = |b: &[u16; BANDS]| b.iter().map(|&n| n as usize).sum();
        Self {
            rows: sum(&bands),
            env_rows: sum(&bands),
            phi: 4 * columns_for.max(1),
            normal_bands: bands,
            env_bands: bands,
        }
    }

    /// This grid with each band's normal and environment rows raised (never lowered) so that
    /// no significant lobe of `brdf` changes its log-peak by more than `step` between
    /// neighbouring rows (at most [`MAX_BAND_ROWS`] a band; the columns stay). Only DSBRDFs
    /// change with θ_d; other models keep the grid. Both directions need it: lit from θ_ω, a
    /// lobe peaks at the normal θ_n = θ_d = θ_ω/2, so a lobe that brightens towards grazing
    /// makes the radiance climb as steeply across the normal rows of that band.
    pub fn refined_for(mut self, brdf: &BrdfModel, step: f64) -> Self {
        let BrdfModel::Dsbrdf(m) = brdf else {
            return self;
        };
        let knots = THETA_D_KNOTS_DEG.map(f64::to_radians);
        for i in 0..BANDS {
            let needed = (lobe_variation(m, knots[i], knots[i + 1]) / step).ceil();
            let needed = if needed.is_finite() {
                needed as usize
            } else {
                MAX_BAND_ROWS
            };
            for n in [&mut self.normal_bands[i], &mut self.env_bands[i]] {
                *n = (*n as usize).max(needed).min(MAX_BAND_ROWS) as u16;
            }
        }
        self.rows = self.normal_bands.iter().map(|&n| n as usize).sum();
        self.env_rows = self.env_bands.iter().map(|&n| n as usize).sum();
        self
    }

    /// The grid a material needs (see [`ZonalPlan::for_brdf`]). `None` for measured BRDFs
    /// (unknown sharpness) and for materials whose lobes need more than twice [`MAX_ROWS`]
    /// ([`ZonalPlan::Unresolved`]).
    pub fn for_brdf(brdf: &BrdfModel) -> Option<Self> {
        ZonalPlan::for_brdf(brdf).grid()
    }

    /// [`for_brdf`](ZonalGrid::for_brdf) with explicit knobs.
    pub fn for_brdf_with(brdf: &BrdfModel, params: &ZonalParams) -> Option<Self> {
        ZonalPlan::for_brdf_with(brdf, params).grid()
    }

    /// Normal rows each band of θ_n needs, uncapped: enough for [`SPACING_PER_WIDTH`] of the
    /// width of the sharpest significant lobe over the band's θ_d (and [`BAND_MARGIN_DEG`]
    /// beyond). `None` for measured BRDFs. This is the starting point: [`ZonalKernel::checked`]
    /// then measures the kernel and refines the grid where that is not enough.
    pub fn band_rows_needed(brdf: &BrdfModel, params: &ZonalParams) -> Option<[f64; BANDS]> {
        let edges = normal_edges();
        let uniform = match brdf {
            BrdfModel::Dsbrdf(_) => 0.0,
            BrdfModel::Measured(_) | BrdfModel::Neural(_) => return None,
            other => 1.0 / sharpness(other)?.max(1.0).sqrt(),
        };
        Some(std::array::from_fn(|i| {
            let width = match brdf {
                BrdfModel::Dsbrdf(m) => {
                    let (lo, hi) = (THETA_D_KNOTS_DEG[i], THETA_D_KNOTS_DEG[i + 1]);
                    dsbrdf_width_over(m, lo - BAND_MARGIN_DEG, hi + BAND_MARGIN_DEG)
                }
                _ => uniform,
            };
            let rows = (edges[i + 1] - edges[i]) / (params.spacing_per_width * width);
            // Non-finite only for absurd parameters: treat as unresolvable.
            if rows.is_finite() { rows } else { f64::MAX }
        }))
    }

    /// The grid for per-band needs `need`, each band within the shares of `params.min_rows` and
    /// of `params.max_rows`.
    fn for_needs(need: &[f64; BANDS], params: &ZonalParams) -> Self {
        let edges = normal_edges();
        let max_rows = params.max_rows.max(params.min_rows);
        let (lo, hi) = (dealt(params.min_rows as f64, &edges), dealt(max_rows as f64, &edges));
        let bands: [usize; BANDS] = std::array::from_fn(|i| {
            let n = need[i].ceil();
            let n = if n.is_finite() {
                n.min(hi[i] as f64) as usize
            } else {
                hi[i]
            };
            n.clamp(lo[i], hi[i])
        });
        let columns = uniform_equivalent(&bands.map(|n| n as f64)).ceil() as usize;
        Self::with_bands(bands, columns.div_ceil(4) * 4)
    }

    /// This grid's normal (and so environment) rows × `factor` in every band, within the shares
    /// of `params.max_rows`; environment rows as [`with_bands`](ZonalGrid::with_bands) gives.
    fn finer(&self, factor: f64, params: &ZonalParams) -> Self {
        let need = self.normal_bands.map(|n| n as f64 * factor);
        Self::for_needs(&need, params)
    }

    fn normal_theta(&self, a: usize) -> f64 {
        band_theta(&self.normal_bands, &normal_edges(), a as f64)
    }

    /// The normal rows' [`BandCoords`]: θ_n ∈ [0, θ_max] to a row coordinate (row a at a), for
    /// lookups per pixel.
    fn normal_coords(&self) -> BandCoords {
        BandCoords::new(&self.normal_bands, &normal_edges())
    }

    fn env_theta(&self, r: usize) -> f64 {
        band_theta(&self.env_bands, &env_edges(), r as f64 + 0.5)
    }

    /// The continuous environment-row coordinate of θ_ω ∈ [0, π]: row r's centre is at r.
    fn env_row_coord(&self, theta: f64) -> f64 {
        BandCoords::new(&self.env_bands, &env_edges()).coord(theta) - 0.5
    }

    /// What an environment's spread and spectra depend on: the environment rows and columns.
    fn env_layout(&self) -> ([u16; BANDS], usize) {
        (self.env_bands, self.phi)
    }

    /// Harmonics kept per spectrum (0..=phi/2).
    fn harmonics(&self) -> usize {
        self.phi / 2 + 1
    }
}

/// The rows of a uniform normal grid as fine as the finest of per-band rows `bands`.
fn uniform_equivalent(bands: &[f64; BANDS]) -> f64 {
    let edges = normal_edges();
    (0..BANDS)
        .map(|i| bands[i] * theta_max() / (edges[i + 1] - edges[i]))
        .fold(0.0, f64::max)
}

/// The sharpness γ of an analytic BRDF's narrowest lobe, as in cos^γ θ_h. `None` for measured
/// BRDFs.
pub fn sharpness(brdf: &BrdfModel) -> Option<f64> {
    match brdf {
        BrdfModel::Lambert(_) => Some(1.0),
        // GGX near its peak falls off like exp(−θ_h²/α²): γ ≈ 2/α².
        BrdfModel::Ggx(g) => Some(2.0 / (g.alpha * g.alpha)),
        BrdfModel::Plastic(p) => Some(2.0 / (p.coat.alpha * p.coat.alpha)),
        BrdfModel::Dsbrdf(m) => Some(1.0 / dsbrdf_width_over(m, 0.0, 90.0).powi(2)),
        BrdfModel::Measured(_) | BrdfModel::Neural(_) => None,
    }
}

/// The curvature-equivalent sharpness of expm1(κ cos^γ θ) at its peak: γ·κ/(1 − e^−κ). For
/// κ ≪ 1 the lobe is κ cos^γ (sharpness γ); for large κ it is e^κ·e^(−κγθ²/2), κ times sharper.
pub fn effective_gamma(kappa: f64, gamma: f64) -> f64 {
    if kappa < 1e-6 {
        gamma
    } else {
        gamma * kappa / -(-kappa).exp_m1()
    }
}

/// A lobe member's share of the image under a point light (see [`SIGNIFICANT_SHARE`]).
fn lobe_share(&(kappa, gamma): &(f64, f64)) -> f64 {
    kappa.exp_m1() * (1.0 / effective_gamma(kappa, gamma).sqrt()).min(1.0)
}

/// Width 1/√γ' of a DSBRDF's sharpest member that carries energy (γ' the curvature-equivalent
/// sharpness, [`effective_gamma`]), over θ_d in whole degrees from `lo` to `hi` (clamped to
/// [0°, 90°]).
fn dsbrdf_width_over(m: &Dsbrdf, lo: f64, hi: f64) -> f64 {
    let (lo, hi) = (
        lo.clamp(0.0, 90.0).floor() as usize,
        hi.clamp(0.0, 90.0).ceil() as usize,
    );
    let mut sharpest = 1.0_f64;
    for deg in lo..=hi {
        for ch in &m.lobes_at((deg as f64).to_radians()) {
            let total: f64 = ch.iter().map(lobe_share).sum();
            for lobe in ch {
                if lobe_share(lobe) >= SIGNIFICANT_SHARE * total {
                    sharpest = sharpest.max(effective_gamma(lobe.0, lobe.1));
                }
            }
        }
    }
    1.0 / sharpest.sqrt()
}

/// The largest total change of a significant lobe's log-peak, ln expm1(κ), plus that of its
/// ln γ (its value at a given fraction of its width changes about as fast), over θ_d ∈ [lo, hi]
/// (radians). A member counts in proportion to its share of its channel (fully from a tenth of
/// it) and not at all below [`SIGNIFICANT_SHARE`]: a lobe that switches on at grazing changes
/// enormously in log terms while it is still invisible.
fn lobe_variation(m: &Dsbrdf, lo: f64, hi: f64) -> f64 {
    const STEPS: usize = 48;
    let at = |t: f64| m.lobes_at(lo + (hi - lo) * t);
    let shares = |l: &[(f64, f64); 3]| l.map(|x| lobe_share(&x));
    let log_peak = |(kappa, _): (f64, f64)| kappa.exp_m1().ln();
    let mut total = [[0.0_f64; 3]; 3];
    let mut prev = at(0.0);
    for s in 1..=STEPS {
        let cur = at(s as f64 / STEPS as f64);
        for c in 0..3 {
            let (sp, sc) = (shares(&prev[c]), shares(&cur[c]));
            let (tp, tc) = (sp.iter().sum::<f64>(), sc.iter().sum::<f64>());
            for k in 0..3 {
                let share = (sp[k] / tp).max(sc[k] / tc);
                // NaN-safe: a channel with no share at all counts nothing.
                if share.is_nan() || share < SIGNIFICANT_SHARE {
                    continue;
                }
                let d =
                    (log_peak(cur[c][k]) - log_peak(prev[c][k])).abs() + (cur[c][k].1.ln() - prev[c][k].1.ln()).abs();
                total[c][k] += (10.0 * share).min(1.0) * d;
            }
        }
        prev = cur;
    }
    total.iter().flatten().fold(0.0, |a, &b| a.max(b))
}

/// One cut spectrum: environment row, channel, and where its coefficients are.
#[derive(Clone, Copy, Debug)]
struct Entry {
    env_row: u32,
    channel: u32,
    start: u32,
    len: u32,
}

/// A material's kernel spectra on a grid (step 1 of the module docs). Build once per material
/// and grid; share between threads.
pub struct ZonalKernel {
    grid: ZonalGrid,
    /// The material, for the texels shaded per pixel ([`POINT_SHARE`]).
    brdf: BrdfModel,
    /// Per normal row, its cut spectra.
    entries: Vec<Vec<Entry>>,
    /// Per normal row, the real cosine coefficients of its spectra.
    coeffs: Vec<Vec<f32>>,
}

/// Why the zonal method does not shade a material (the caller shades it per pixel instead).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum ZonalRefusal {
    /// A measured BRDF: unknown sharpness (the exact path shades it).
    #[error("measured BRDF")]
    Measured,
    /// Lobes narrower than the finest grid resolves.
    #[error("lobes need {rows_needed} zonal rows > {max_rows}")]
    TooSharp {
        /// Rows the widest rule asks for.
        rows_needed: usize,
        /// The cap.
        max_rows: usize,
    },
    /// Even the finest grid misses its probe budget ([`ZonalKernel::probe_budget`]) on a probe
    /// map (e.g. lobes that change too fast with θ_d for the environment rows).
    #[error("{:.2} % off under the {map} probe map on {rows} rows > {:.2} %", 100.0 * error, 100.0 * budget)]
    OverBudget {
        /// Rows of the last grid tried.
        rows: usize,
        /// Its largest error.
        error: f64,
        /// The budget it misses ([`ZonalKernel::probe_budget`]).
        budget: f64,
        /// The probe map that showed it.
        map: &'static str,
    },
}

impl ZonalKernel {
    /// Tabulates and transforms `brdf`'s kernel on `grid` (single-threaded; 0.01–0.5 s for the
    /// library's materials). `None` for measured BRDFs, which are shaded by the exact path.
    pub fn new(brdf: &BrdfModel, grid: ZonalGrid) -> Option<Self> {
        Self::with_tail(brdf, grid, TAIL)
    }

    /// [`new`](ZonalKernel::new) with spectra cut at `tail` (see [`TAIL`]).
    pub fn with_tail(brdf: &BrdfModel, grid: ZonalGrid, tail: f64) -> Option<Self> {
        if matches!(brdf, BrdfModel::Measured(_) | BrdfModel::Neural(_)) {
            return None;
        }
        let n = grid.phi;
        let fft = forward_plan(n);
        let geometry = Geometry::new(&grid);
        let dsbrdf_rows: Option<Vec<RowLobes>> = match brdf {
            BrdfModel::Dsbrdf(m) => Some(
                (0..grid.env_rows)
                    .map(|r| RowLobes::new(m, grid.env_theta(r) / 2.0))
                    .collect(),
            ),
            _ => None,
        };
        // Sequential on purpose: callers build kernels lazily inside `OnceLock`s on rayon
        // threads, where a nested parallel loop could steal a job that waits on the same cell.
        // Build several kernels in parallel instead (one per material).
        let per_row: Vec<(Vec<Entry>, Vec<f32>)> = (0..=grid.rows)
            .map(|a| {
                let mut seqs: Vec<(u32, u32, Vec<f32>)> = Vec::new();
                for r in 0..grid.env_rows {
                    let k = match &dsbrdf_rows {
                        Some(rows) => geometry.dsbrdf_kernel(a, r, &rows[r]),
                        None => geometry.generic_kernel(a, r, brdf),
                    };
                    let Some(k) = k else { continue };
                    for (c, seq) in k.into_iter().enumerate() {
                        if seq.iter().any(|&v| v > 0.0) {
                            seqs.push((r as u32, c as u32, seq));
                        }
                    }
                }
                cut_spectra(&*fft, n, seqs, tail)
            })
            .collect();
        let (entries, coeffs) = per_row.into_iter().unzip();
        Some(Self {
            grid,
            brdf: brdf.clone(),
            entries,
            coeffs,
        })
    }

    /// The kernel of `brdf`, checked ([`checked`](ZonalKernel::checked)); `None` for measured BRDFs
    /// and lobes the grid cannot resolve (callers then shade per pixel).
    pub fn for_brdf(brdf: &BrdfModel) -> Option<Self> {
        Self::checked(brdf, &ZonalParams::default()).ok()
    }

    /// [`for_brdf`](ZonalKernel::for_brdf) with explicit knobs.
    pub fn for_brdf_with(brdf: &BrdfModel, params: &ZonalParams) -> Option<Self> {
        Self::checked(brdf, params).ok()
    }

    /// Builds the kernel on the grid the lobe widths ask for and checks it against the fast path
    /// on the [`probe_maps`]; where it misses [`probe_budget`](ZonalKernel::probe_budget), on finer
    /// grids (×1.5 rows each time) up to the cap, except beyond [`RESOLVED_BEYOND_CAP`]. Refuses measured BRDFs, materials whose lobes need more than
    /// [`CHECKED_BEYOND_CAP`] times the cap, and materials no grid up to the cap holds within
    /// [`probe_budget`](ZonalKernel::probe_budget) (callers shade those per pixel).
    pub fn checked(brdf: &BrdfModel, params: &ZonalParams) -> Result<Self, ZonalRefusal> {
        let mut grid = match ZonalPlan::for_brdf_with(brdf, params) {
            ZonalPlan::Grid(g) => g,
            ZonalPlan::Unresolved { rows_needed, max_rows } => {
                return Err(ZonalRefusal::TooSharp { rows_needed, max_rows });
            }
            ZonalPlan::Measured => return Err(ZonalRefusal::Measured),
        };
        let reference = ProbeReference::new(brdf).ok_or(ZonalRefusal::Measured)?;
        let budget = Self::probe_budget(brdf, params);
        let mut scale = 1.0;
        loop {
            let kernel = Self::with_tail(brdf, grid, params.tail).ok_or(ZonalRefusal::Measured)?;
            let (error, map) = probe_error(&kernel, &reference);
            if error <= budget {
                return Ok(kernel);
            }
            // Finer in every band and direction (×1.5 rows, the environment rows' allowed step
            // shrinking alike), up to the cap. Not beyond the resolved range: there the capped
            // grid is already short of the lobes, and refining until the five probes pass would
            // fit the kernel to the probes rather than test it (a random material refined to 465
            // rows passed them at 0.10 % and was 0.76 % off under a real studio).
            let refused = ZonalRefusal::OverBudget {
                rows: grid.rows,
                error,
                budget,
                map,
            };
            if budget < PROBE_BUDGET {
                return Err(refused);
            }
            scale *= 1.5;
            let finer = grid.finer(1.5, params).refined_for(brdf, params.lobe_step / scale);
            if finer.normal_bands == grid.normal_bands {
                return Err(refused);
            }
            grid = finer;
        }
    }

    /// The largest probe error [`checked`](ZonalKernel::checked) accepts for `brdf`:
    /// [`PROBE_BUDGET`], or [`PROBE_BUDGET_BEYOND`] where its lobes ask for more than
    /// [`RESOLVED_BEYOND_CAP`] times the cap.
    pub fn probe_budget(brdf: &BrdfModel, params: &ZonalParams) -> f64 {
        let max_rows = params.max_rows.max(params.min_rows);
        match ZonalGrid::band_rows_needed(brdf, params) {
            Some(need) if uniform_equivalent(&need) > (RESOLVED_BEYOND_CAP * max_rows) as f64 => PROBE_BUDGET_BEYOND,
            _ => PROBE_BUDGET,
        }
    }

    /// The kernel on the grid the material needs, capped at `params.max_rows` even where that
    /// cannot resolve it. Only for measuring what the fallback of [`ZonalPlan::Unresolved`]
    /// avoids; shading never uses it.
    pub fn on_capped_grid(brdf: &BrdfModel, params: &ZonalParams) -> Option<Self> {
        let need = ZonalGrid::band_rows_needed(brdf, params)?;
        let grid = ZonalGrid::for_needs(&need, params).refined_for(brdf, params.lobe_step);
        Self::with_tail(brdf, grid, params.tail)
    }

    /// The grid.
    pub fn grid(&self) -> ZonalGrid {
        self.grid
    }

    /// Builds, ahead of shading, what spreading maps of `env_height` rows onto this kernel's grid
    /// needs (a few ms, memoised for the process), so that a run pays it with the kernel's set-up
    /// rather than in its first samples.
    pub fn prepare_for_maps(&self, env_height: usize) {
        spread_for(env_height, self.grid);
    }

    /// Stored coefficients (memory: 4 bytes each).
    pub fn coefficients(&self) -> usize {
        self.coeffs.iter().map(Vec::len).sum()
    }
}

/// κ and γ of every (channel, lobe) at one environment row's θ_d, as f32.
struct RowLobes {
    /// κ and γ of lobe k of channel c at `3 c + k`, padded with κ = 0 lobes (which add
    /// expm1(0) = 0) to three 4-wide vectors.
    kappa: [f32; LOBE_LANES],
    gamma: [f32; LOBE_LANES],
}

/// Lanes of [`RowLobes`]: the 9 (channel, lobe) pairs, padded.
const LOBE_LANES: usize = 12;

impl RowLobes {
    /// Σ_k expm1(κ_k cos^γ_k θ_h) of each channel, from lc = ln cos θ_h; 0 where the half
    /// vector is behind the surface (`front` false). The kernel and the per-pixel texels use
    /// this one formula, so they agree to the bit. Branch-free over flat lanes, so it
    /// vectorises.
    #[inline]
    fn rho(&self, lc: f32, front: bool) -> [f32; 3] {
        let mut v = [0.0_f32; LOBE_LANES];
        for (i, v) in v.iter_mut().enumerate() {
            let pw = fastmath::exp(self.gamma[i] * lc);
            let pw = if front { pw } else { 0.0 };
            *v = fastmath::expm1(self.kappa[i] * pw);
        }
        std::array::from_fn(|c| v[3 * c] + v[3 * c + 1] + v[3 * c + 2])
    }

    fn new(m: &Dsbrdf, theta_d: f64) -> Self {
        let l = m.lobes_at(theta_d);
        let lane = |i: usize, kappa: bool| {
            if i >= 9 {
                return 0.0;
            }
            let (k, g) = l[i / 3][i % 3];
            (if kappa { k } else { g }) as f32
        };
        Self {
            kappa: std::array::from_fn(|i| lane(i, true)),
            gamma: std::array::from_fn(|i| lane(i, false)),
        }
    }
}

/// Trigonometry of a grid, shared by all kernels on it.
struct Geometry {
    grid: ZonalGrid,
    /// cos φ_j and sin²(φ_j/2) for j = 0..=phi/2.
    cos_phi: Vec<f32>,
    half_sin2: Vec<f32>,
}

impl Geometry {
    fn new(grid: &ZonalGrid) -> Self {
        let m = grid.phi / 2 + 1;
        let phi = |j: usize| 2.0 * PI * j as f64 / grid.phi as f64;
        Self {
            grid: *grid,
            cos_phi: (0..m).map(|j| phi(j).cos() as f32).collect(),
            half_sin2: (0..m).map(|j| (phi(j) / 2.0).sin().powi(2) as f32).collect(),
        }
    }

    /// The three channels' kernel k(θ_a, θ_r, φ_j) for j = 0..phi, or `None` when every
    /// direction of the environment row is behind the normal.
    fn dsbrdf_kernel(&self, a: usize, r: usize, lobes: &RowLobes) -> Option<[Vec<f32>; 3]> {
        let (ta, tw) = (self.grid.normal_theta(a), self.grid.env_theta(r));
        // The row's directions closest to the normal are at φ = 0, at angle |θ_a − θ_ω|.
        if (ta - tw).cos() <= 0.0 {
            return None;
        }
        let th = tw / 2.0;
        let (sa, ca) = ta.sin_cos();
        let (sw, cw) = tw.sin_cos();
        let (p, q) = ((sa * sw) as f32, (ca * cw) as f32);
        // 1 − n·h = 2 sin²((θ_a − θ_h)/2) + 2 sin θ_a sin θ_h sin²(φ/2): no cancellation, so f32
        // keeps the sharpest lobes' peaks.
        let base = (2.0 * ((ta - th) / 2.0).sin().powi(2)) as f32;
        let coef = (2.0 * sa * th.sin()) as f32;
        let half: Vec<[f32; 3]> = self
            .cos_phi
            .iter()
            .zip(&self.half_sin2)
            .map(|(&cos_phi, &half_sin2)| {
                let cos_i = p * cos_phi + q;
                let w = if cos_i > 0.0 { cos_i } else { 0.0 };
                let t = base + coef * half_sin2;
                let front = t < 1.0;
                let rho = lobes.rho(fastmath::ln_1m(t), front);
                std::array::from_fn(|c| w * rho[c])
            })
            .collect();
        Some(std::array::from_fn(|c| {
            let channel: Vec<f32> = half.iter().map(|v| v[c]).collect();
            mirror(&channel, self.grid.phi)
        }))
    }

    /// The kernel of any isotropic BRDF through [`Brdf::eval`] in a local frame (f64).
    fn generic_kernel(&self, a: usize, r: usize, brdf: &BrdfModel) -> Option<[Vec<f32>; 3]> {
        let (ta, tw) = (self.grid.normal_theta(a), self.grid.env_theta(r));
        if (ta - tw).cos() <= 0.0 {
            return None;
        }
        let n = DVec3::new(ta.sin(), 0.0, ta.cos());
        let frame = Frame::from_normal(n);
        let wo = frame.to_local(DVec3::Z);
        let half: Vec<[f32; 3]> = (0..self.cos_phi.len())
            .map(|j| {
                let phi = 2.0 * PI * j as f64 / self.grid.phi as f64;
                let w = DVec3::new(tw.sin() * phi.cos(), tw.sin() * phi.sin(), tw.cos());
                let wi = frame.to_local(w);
                if wi.z <= 0.0 {
                    return [0.0; 3];
                }
                let f = brdf.eval(wi, wo);
                std::array::from_fn(|c| (f[c] * wi.z) as f32)
            })
            .collect();
        Some(std::array::from_fn(|c| {
            let channel: Vec<f32> = half.iter().map(|v| v[c]).collect();
            mirror(&channel, self.grid.phi)
        }))
    }
}

/// The even sequence of length n whose first n/2 + 1 values are `half`.
fn mirror(half: &[f32], n: usize) -> Vec<f32> {
    (0..n).map(|j| half[j.min(n - j)]).collect()
}

/// Transforms real even sequences two at a time (one as the real, one as the imaginary part:
/// both spectra are real, so they come back as the real and imaginary parts) and cuts each after
/// its last significant harmonic.
fn cut_spectra(
    fft: &dyn Fft<f32>,
    n: usize,
    seqs: Vec<(u32, u32, Vec<f32>)>,
    tail_fraction: f64,
) -> (Vec<Entry>, Vec<f32>) {
    let m = n / 2 + 1;
    let mut entries = Vec::new();
    let mut coeffs = Vec::new();
    let mut buf = vec![Complex32::default(); n];
    let mut scratch = vec![Complex32::default(); fft.get_inplace_scratch_len()];
    for pair in seqs.chunks(2) {
        for (j, b) in buf.iter_mut().enumerate() {
            *b = Complex32::new(pair[0].2[j], pair.get(1).map_or(0.0, |s| s.2[j]));
        }
        fft.process_with_scratch(&mut buf, &mut scratch);
        for (i, (r, c, _)) in pair.iter().enumerate() {
            let spec: Vec<f32> = buf[..m].iter().map(|z| if i == 0 { z.re } else { z.im }).collect();
            let dc = spec[0].max(0.0) as f64;
            if dc <= 0.0 {
                continue;
            }
            // Keep harmonics 0..len where the tail beyond is ≤ tail_fraction · dc.
            let mut tail = 0.0_f64;
            let mut len = m;
            while len > 1 {
                let next = tail + spec[len - 1].abs() as f64;
                if next > tail_fraction * dc {
                    break;
                }
                tail = next;
                len -= 1;
            }
            entries.push(Entry {
                env_row: *r,
                channel: *c,
                start: coeffs.len() as u32,
                len: len as u32,
            });
            coeffs.extend_from_slice(&spec[..len]);
        }
    }
    (entries, coeffs)
}

type Plan = Arc<dyn Fft<f32>>;
static FORWARD: Memo<usize, Plan> = Memo::new();
static INVERSE: Memo<usize, Plan> = Memo::new();
/// Keyed by map height and [`ZonalGrid::env_layout`]: all a spread depends on.
static SPLATS: Memo<(usize, ([u16; BANDS], usize)), Splat> = Memo::new();

fn forward_plan(n: usize) -> Plan {
    FORWARD
        .get(n, || FftPlannerScalar::new().plan_fft_forward(n))
        .as_ref()
        .clone()
}

fn inverse_plan(n: usize) -> Plan {
    INVERSE
        .get(n, || FftPlannerScalar::new().plan_fft_inverse(n))
        .as_ref()
        .clone()
}

/// Where each texel of an equirectangular map of a given height lands on a grid's environment
/// rows: 4×4 Catmull–Rom weights in (θ, φ) about the view axis, the texel's solid angle folded
/// in. Rows beyond a pole continue on the other side of it, half a turn round.
struct Splat {
    /// Per texel (row-major), 16 (grid node, weight) pairs.
    nodes: Vec<[(u32, f32); 16]>,
}

impl Splat {
    fn new(height: usize, grid: ZonalGrid) -> Self {
        let w = 2 * height;
        let (rows, n) = (grid.env_rows as i64, grid.phi as i64);
        let dphi = 2.0 * PI / grid.phi as f64;
        let mut nodes = Vec::with_capacity(w * height);
        for j in 0..height {
            let sa = texel_solid_angle(j, w, height);
            for i in 0..w {
                let d = texel_direction(i, j, w, height);
                let theta = d.z.clamp(-1.0, 1.0).acos();
                let phi = d.y.atan2(d.x).rem_euclid(2.0 * PI);
                let u = grid.env_row_coord(theta);
                let s = phi / dphi;
                let (r0, c0) = (u.floor(), s.floor());
                let (wr, wc) = (catmull_rom(u - r0), catmull_rom(s - c0));
                let mut out = [(0_u32, 0.0_f32); 16];
                for (dr, wr) in wr.iter().enumerate() {
                    let mut row = r0 as i64 - 1 + dr as i64;
                    let mut shift = 0;
                    if row < 0 {
                        row = -row - 1;
                        shift = n / 2;
                    } else if row >= rows {
                        row = 2 * rows - row - 1;
                        shift = n / 2;
                    }
                    for (dc, wc) in wc.iter().enumerate() {
                        let col = (c0 as i64 - 1 + dc as i64 + shift).rem_euclid(n);
                        out[dr * 4 + dc] = ((row * n + col) as u32, (wr * wc * sa) as f32);
                    }
                }
                nodes.push(out);
            }
        }
        Self { nodes }
    }
}

/// Texels behind the object (θ_ω at least this, radians: θ_d ≥ 65°, the last two knot
/// intervals) that carry at least [`POINT_SHARE`] of the map's power are shaded per pixel
/// instead of on the grid. Lit from there, a lobe peaks at θ_n = θ_ω/2, only 90° − θ_d from the
/// terminator θ_n = θ_ω − 90°, so bright grazing lobes sit on the clamped cosine's kink, which
/// no grid interpolates well: a pixel 0.5° past the terminator of a sun at 168° came out 7 %
/// dark on a grid twice as fine as the cap. Behind the object a sun lights only a crescent, so
/// the per-pixel sum is cheap.
pub const POINT_MIN_THETA_DEG: f64 = 130.0;
/// See [`POINT_MIN_THETA_DEG`]: the share of the map's power (L·dω over the three channels) a
/// texel behind the object needs to be shaded per pixel.
pub const POINT_SHARE: f64 = 2e-3;
/// At most this many texels are shaded per pixel (the brightest; the rest stay on the grid).
pub const MAX_POINTS: usize = 32;

/// A bright texel behind the object, shaded per pixel: its direction (camera space) and L·dω.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PointTexel {
    dir: DVec3,
    power: [f32; 3],
}

/// The texels of `env` (camera space) shaded per pixel, by index, brightest first.
fn point_texels(env: &EnvMap) -> Vec<(usize, PointTexel)> {
    let (w, h) = (env.width(), env.height());
    let solid: Vec<f64> = (0..h).map(|j| texel_solid_angle(j, w, h)).collect();
    let power = |t: usize, l: &[f32; 3]| l.map(|v| v as f64 * solid[t / w]);
    let total: f64 = env
        .texels()
        .iter()
        .enumerate()
        .map(|(t, l)| power(t, l).iter().sum::<f64>())
        .sum();
    if total.is_nan() || total <= 0.0 {
        return Vec::new();
    }
    let min_cos = POINT_MIN_THETA_DEG.to_radians().cos();
    let mut points: Vec<(f64, usize, PointTexel)> = env
        .texels()
        .iter()
        .enumerate()
        .filter_map(|(t, l)| {
            let p = power(t, l);
            let share = p.iter().sum::<f64>() / total;
            if share.is_nan() || share < POINT_SHARE {
                return None;
            }
            let dir = texel_direction(t % w, t / w, w, h);
            (dir.z <= min_cos).then(|| {
                (
                    share,
                    t,
                    PointTexel {
                        dir,
                        power: p.map(|v| v as f32),
                    },
                )
            })
        })
        .collect();
    // Brightest first; ties by index, so the choice is deterministic.
    points.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    points.truncate(MAX_POINTS);
    points.into_iter().map(|(_, t, p)| (t, p)).collect()
}

/// A point texel prepared for one material: what every pixel shares.
struct LitPoint {
    point: PointTexel,
    /// Half vector between the texel and the view (+z).
    half: DVec3,
    /// The DSBRDF's lobes at the texel's θ_d (`None` for other models, evaluated per pixel).
    lobes: Option<RowLobes>,
}

/// The point texels prepared for one material, and the polar angle below which a normal sees
/// none of them.
struct LitPoints {
    points: Vec<LitPoint>,
    /// n·ω ≤ cos(θ_ω − θ_n), so a normal with θ_n ≤ θ_ω − 90° for every point is lit by none;
    /// a thousandth of a radian short of that, so the skip never drops light.
    unlit_below: f32,
}

fn lit_points(brdf: &BrdfModel, points: &[PointTexel]) -> LitPoints {
    let points: Vec<LitPoint> = points
        .iter()
        .map(|&point| {
            let half = (point.dir + DVec3::Z).normalize_or_zero();
            let lobes = match brdf {
                BrdfModel::Dsbrdf(m) => Some(RowLobes::new(m, point.dir.z.clamp(-1.0, 1.0).acos() / 2.0)),
                _ => None,
            };
            LitPoint { point, half, lobes }
        })
        .collect();
    let unlit_below = points
        .iter()
        .map(|p| p.point.dir.z.clamp(-1.0, 1.0).acos() - PI / 2.0 - 1e-3)
        .fold(f64::INFINITY, f64::min) as f32;
    LitPoints { points, unlit_below }
}

/// Radiance at shading normal `n` from the point texels (Eq. 2's summands for those texels, as
/// the exact path evaluates them).
fn point_radiance(brdf: &BrdfModel, lit: &[LitPoint], n: DVec3) -> [f32; 3] {
    let mut out = [0.0_f32; 3];
    for p in lit {
        let cos_i = n.dot(p.point.dir);
        if cos_i <= 0.0 {
            continue;
        }
        let f: [f32; 3] = match &p.lobes {
            Some(lobes) => {
                if n.dot(p.half) <= 0.0 {
                    continue;
                }
                // 1 − n·h as |n − h|²/2: no cancellation for the sharpest lobes.
                lobes.rho(fastmath::ln_1m(((n - p.half).length_squared() / 2.0) as f32), true)
            }
            None => {
                let frame = Frame::from_normal(n);
                let (wi, wo) = (frame.to_local(p.point.dir), frame.to_local(DVec3::Z));
                if wi.z <= 0.0 || wo.z <= 0.0 {
                    continue;
                }
                brdf.eval(wi, wo).map(|v| v as f32)
            }
        };
        let cos_i = cos_i as f32;
        for c in 0..3 {
            out[c] += f[c] * cos_i * p.point.power[c];
        }
    }
    out
}

/// The radiance of a pixel whose shading normal is at polar angles (θ, φ): the grid's table
/// there plus the texels shaded per pixel.
fn pixel_radiance(
    table: &Padded,
    grid: &ZonalGrid,
    brdf: &BrdfModel,
    lit: &LitPoints,
    theta: f32,
    phi: f32,
) -> [f32; 3] {
    let mut rgb = table.at(grid, theta, phi);
    if theta > lit.unlit_below {
        let direct = point_radiance(brdf, &lit.points, from_polar(theta, phi));
        for c in 0..3 {
            rgb[c] += direct[c];
        }
    }
    rgb
}

/// The unit normal at polar angles (θ, φ) about the view.
fn from_polar(theta: f32, phi: f32) -> DVec3 {
    let (st, ct) = (theta as f64).sin_cos();
    let (sp, cp) = (phi as f64).sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// The spreading weights of maps of `height` rows onto `grid` (memoised for the process).
fn spread_for(height: usize, grid: ZonalGrid) -> Arc<Splat> {
    SPLATS.get((height, grid.env_layout()), || Splat::new(height, grid))
}

/// An environment's row spectra on a grid (step 2 of the module docs).
pub struct ZonalEnv {
    grid: ZonalGrid,
    /// Real and imaginary parts, `[(row · 3 + channel) · harmonics + f]`.
    re: Vec<f32>,
    im: Vec<f32>,
    /// Bright texels behind the object, left off the grid and shaded per pixel.
    points: Vec<PointTexel>,
}

impl ZonalEnv {
    /// Spreads `env`'s texels (L·dω at each texel centre, camera space) onto `grid` and
    /// transforms each row.
    pub fn new(env: &EnvMap, grid: ZonalGrid) -> Self {
        let splat = spread_for(env.height(), grid);
        let (rows, n) = (grid.env_rows, grid.phi);
        // Per channel, the spread power of every grid node.
        let mut power = vec![vec![0.0_f32; rows * n]; 3];
        let points = point_texels(env);
        let mut off_grid: Vec<usize> = points.iter().map(|&(i, _)| i).collect();
        off_grid.sort_unstable();
        for (t, (l, nodes)) in env.texels().iter().zip(&splat.nodes).enumerate() {
            if *l == [0.0; 3] || off_grid.binary_search(&t).is_ok() {
                continue;
            }
            for &(node, w) in nodes {
                for c in 0..3 {
                    power[c][node as usize] += w * l[c];
                }
            }
        }
        let m = grid.harmonics();
        let fft = forward_plan(n);
        let mut re = vec![0.0_f32; rows * 3 * m];
        let mut im = vec![0.0_f32; rows * 3 * m];
        let mut buf = vec![Complex32::default(); n];
        let mut scratch = vec![Complex32::default(); fft.get_inplace_scratch_len()];
        // Sequences s = row · 3 + channel, transformed two at a time (x + iy).
        let count = rows * 3;
        let seq = |s: usize| &power[s % 3][(s / 3) * n..(s / 3 + 1) * n];
        let mut s = 0;
        while s < count {
            let second = s + 1 < count;
            let x = seq(s);
            for (j, b) in buf.iter_mut().enumerate() {
                *b = Complex32::new(x[j], if second { seq(s + 1)[j] } else { 0.0 });
            }
            fft.process_with_scratch(&mut buf, &mut scratch);
            for f in 0..m {
                let z = buf[f];
                let zc = buf[(n - f) % n].conj();
                // X = (Z + conj Z[−f]) / 2, Y = (Z − conj Z[−f]) / 2i.
                let x = (z + zc) * 0.5;
                let y = (z - zc) * Complex32::new(0.0, -0.5);
                re[s * m + f] = x.re;
                im[s * m + f] = x.im;
                if second {
                    re[(s + 1) * m + f] = y.re;
                    im[(s + 1) * m + f] = y.im;
                }
            }
            s += 2;
        }
        Self {
            grid,
            re,
            im,
            points: points.into_iter().map(|(_, p)| p).collect(),
        }
    }

    /// The grid.
    pub fn grid(&self) -> ZonalGrid {
        self.grid
    }

    /// Whether these spectra serve a kernel on `grid`: they depend only on the environment rows
    /// and the columns, so materials whose normal rows differ can share them.
    pub fn serves(&self, grid: &ZonalGrid) -> bool {
        self.grid.env_layout() == grid.env_layout()
    }
}

/// Pixel normals in polar coordinates about the view axis, after the [normal
/// policy](shading_normal): computed once per image and shared by every material shaded on it.
pub struct PolarNormals {
    /// θ from the view (NaN: no usable normal, the pixel shades to black).
    theta: Vec<f32>,
    /// φ about the view, in [0, 2π).
    phi: Vec<f32>,
}

impl PolarNormals {
    /// Converts the pixels with `mask > 0`.
    pub fn new(normals: &[[f32; 3]], mask: &[f32]) -> Self {
        let (theta, phi) = normals
            .par_iter()
            .zip(mask.par_iter())
            .map(|(n, &m)| polar(n, m))
            .unzip();
        Self { theta, phi }
    }

    /// Which normal rows of `grid` the pixels with `mask > 0` interpolate from.
    fn rows_needed(&self, grid: &ZonalGrid, mask: &[f32]) -> Vec<bool> {
        let mut need = vec![false; grid.rows + 1];
        let coords = grid.normal_coords();
        for (t, &m) in self.theta.iter().zip(mask) {
            if m > 0.0 && !t.is_nan() {
                let i = row_of(*t as f64, &coords, grid.rows);
                // Rows i−1..=i+2; row −1 is row 1 across the pole, rows beyond the last are
                // extrapolated from the last two.
                let (lo, hi) = (i.saturating_sub(1), (i + 2).min(grid.rows));
                need[lo..=hi].fill(true);
                need[1.min(grid.rows)] |= i == 0;
                need[grid.rows - 1] |= i + 2 > grid.rows;
            }
        }
        need
    }
}

/// A pixel's shading normal in polar coordinates about the view (θ NaN: shades to black).
fn polar(n: &[f32; 3], m: f32) -> (f32, f32) {
    match (m > 0.0).then(|| shading_normal(*n)).flatten() {
        Some(d) => (
            d.z.clamp(-1.0, 1.0).acos() as f32,
            d.y.atan2(d.x).rem_euclid(2.0 * PI) as f32,
        ),
        None => (f32::NAN, 0.0),
    }
}

/// The interval of angle θ among a grid's normal rows.
fn row_of(theta: f64, coords: &BandCoords, rows: usize) -> usize {
    (coords.coord(theta).clamp(0.0, rows as f64).floor() as usize).min(rows - 1)
}

/// Radiance at the normals of the grid, `[row][column]`, for the rows `need` marks (the others
/// stay 0) (step 3 of the module docs).
fn normal_table(kernel: &ZonalKernel, env: &ZonalEnv, need: &[bool]) -> Vec<Vec<[f32; 3]>> {
    normal_table_with(kernel, env, need, true)
}

/// [`normal_table`] on rayon's threads or (`parallel` false: inside a kernel build, where a
/// nested parallel loop could wait on the cell being built) on this one; the same bits.
fn normal_table_with(kernel: &ZonalKernel, env: &ZonalEnv, need: &[bool], parallel: bool) -> Vec<Vec<[f32; 3]>> {
    let grid = kernel.grid;
    let (n, m) = (grid.phi, grid.harmonics());
    let ifft = inverse_plan(n);
    let scale = 1.0 / n as f32;
    // Σ_r K̂ Ŵ for one row: per channel, (re, im) of harmonics 0..m.
    let accumulate = |a: usize| -> [(Vec<f32>, Vec<f32>); 3] {
        let mut acc: [(Vec<f32>, Vec<f32>); 3] = Default::default();
        for slot in acc.iter_mut() {
            *slot = (vec![0.0; m], vec![0.0; m]);
        }
        let coeffs = &kernel.coeffs[a];
        for e in &kernel.entries[a] {
            let (c, len) = (e.channel as usize, e.len as usize);
            let k = &coeffs[e.start as usize..e.start as usize + len];
            let off = (e.env_row as usize * 3 + c) * m;
            let (wr, wi) = (&env.re[off..off + len], &env.im[off..off + len]);
            let (ar, ai) = &mut acc[c];
            for (((ar, ai), kk), (xr, xi)) in ar[..len]
                .iter_mut()
                .zip(ai[..len].iter_mut())
                .zip(k)
                .zip(wr.iter().zip(wi))
            {
                *ar += kk * xr;
                *ai += kk * xi;
            }
        }
        acc
    };
    // Rows in pairs, so the six real results take three inverse transforms (x + iy).
    let buffers = || {
        (
            vec![Complex32::default(); n],
            vec![Complex32::default(); ifft.get_inplace_scratch_len()],
        )
    };
    let pair = |(buf, scratch): &mut (Vec<Complex32>, Vec<Complex32>), p: usize| -> [Vec<[f32; 3]>; 2] {
        let rows = [2 * p, 2 * p + 1];
        let live = rows.map(|a| a <= grid.rows && need[a]);
        let mut out = [vec![[0.0_f32; 3]; n], vec![[0.0_f32; 3]; n]];
        if !live[0] && !live[1] {
            return out;
        }
        let acc = rows.map(|a| {
            if a <= grid.rows && need[a] {
                Some(accumulate(a))
            } else {
                None
            }
        });
        for (x, y) in [((0, 0), Some((0, 1))), ((0, 2), Some((1, 2))), ((1, 0), Some((1, 1)))] {
            let spectrum = |(row, c): (usize, usize)| acc[row].as_ref().map(|a| &a[c]);
            let (sx, sy) = (spectrum(x), y.and_then(spectrum));
            if sx.is_none() && sy.is_none() {
                continue;
            }
            for f in 0..m {
                let real_only = f == 0 || 2 * f == n;
                let get = |s: Option<&(Vec<f32>, Vec<f32>)>| {
                    s.map_or(Complex32::default(), |(re, im)| {
                        Complex32::new(re[f], if real_only { 0.0 } else { im[f] })
                    })
                };
                let (zx, zy) = (get(sx), get(sy));
                buf[f] = zx + Complex32::new(-zy.im, zy.re);
                if f > 0 && f < n - f {
                    buf[n - f] = zx.conj() + Complex32::new(zy.im, zy.re);
                }
            }
            ifft.process_with_scratch(buf, scratch);
            for (j, z) in buf.iter().enumerate() {
                out[x.0][j][x.1] = z.re * scale;
                if let Some((row, c)) = y {
                    out[row][j][c] = z.im * scale;
                }
            }
        }
        out
    };
    let pairs: Vec<[Vec<[f32; 3]>; 2]> = if parallel {
        (0..=grid.rows / 2).into_par_iter().map_init(buffers, pair).collect()
    } else {
        let mut b = buffers();
        (0..=grid.rows / 2).map(|p| pair(&mut b, p)).collect()
    };
    let mut rows: Vec<Vec<[f32; 3]>> = pairs.into_iter().flatten().collect();
    rows.truncate(grid.rows + 1);
    rows
}

/// The normal table with a border, so that every pixel's 4×4 neighbourhood is a plain
/// rectangle: row −1 (row 1 half a turn round, across the pole), row `rows + 1` (extrapolated
/// linearly from the last two), and columns −1, `phi`, `phi + 1` (wrapped).
struct Padded {
    width: usize,
    values: Vec<[f32; 3]>,
    coords: BandCoords,
}

impl Padded {
    fn new(rows: &[Vec<[f32; 3]>], grid: &ZonalGrid) -> Self {
        let n = grid.phi;
        let width = n + 3;
        let last = grid.rows;
        let mut values = Vec::with_capacity((last + 3) * width);
        for a in -1..=(last as i64 + 1) {
            for col in -1..=(n as i64 + 1) {
                let v = if a < 0 {
                    rows[1.min(last)][(col + n as i64 / 2).rem_euclid(n as i64) as usize]
                } else if a as usize > last {
                    let c = col.rem_euclid(n as i64) as usize;
                    let (x, y) = (rows[last][c], rows[last - 1][c]);
                    [0, 1, 2].map(|k| 2.0 * x[k] - y[k])
                } else {
                    rows[a as usize][col.rem_euclid(n as i64) as usize]
                };
                values.push(v);
            }
        }
        Self {
            width,
            values,
            coords: grid.normal_coords(),
        }
    }

    /// Bicubic (Catmull–Rom) value at polar angles (θ, φ), negative values clamped to 0 (the
    /// interpolant may undershoot next to a sharp peak).
    fn at(&self, grid: &ZonalGrid, theta: f32, phi: f32) -> [f32; 3] {
        let u = self.coords.coord(theta as f64).clamp(0.0, grid.rows as f64);
        let i = (u.floor() as usize).min(grid.rows - 1);
        let s = (phi as f64 / (2.0 * PI) * grid.phi as f64).clamp(0.0, grid.phi as f64);
        let j = (s.floor() as usize).min(grid.phi - 1);
        let (wr, wc) = (catmull_rom(u - i as f64), catmull_rom(s - j as f64));
        let wc = wc.map(|w| w as f32);
        // Padded row i − 1 + 1 = i, column j − 1 + 1 = j.
        let mut acc = [0.0_f32; 3];
        for (dr, &wr) in wr.iter().enumerate() {
            let base = (i + dr) * self.width + j;
            let mut row = [0.0_f32; 3];
            for (dc, &wc) in wc.iter().enumerate() {
                let v = self.values[base + dc];
                for c in 0..3 {
                    row[c] += wc * v[c];
                }
            }
            for c in 0..3 {
                acc[c] += wr as f32 * row[c];
            }
        }
        // Not `max`, which would turn NaN (an overflow, absurd input) into a silent 0:
        // `sanitize` replaces and counts it.
        acc.map(|v| if v < 0.0 { 0.0 } else { v })
    }
}

/// Small maps shaped like the hard real ones: a sky whose sun carries 60 % of the power (real
/// sunny HDRIs put up to 60 % in their brightest texel at 64×128) in front of the object, to its
/// side and behind it (150° and 168° from the view: the rim light where θ_d nears grazing and
/// fitted lobes switch on between the last two knots), and a studio of two sharp-edged panels
/// over a dark room. Camera space: +z towards the viewer.
pub fn probe_maps() -> Vec<(&'static str, EnvMap)> {
    ProbeParts::new().composed()
}

/// The [`probe_maps`] as smooth bases shared by several probes plus a sparse part each (a sun,
/// two panels). The fast path is linear in the map and skips black texels, so its reference
/// images cost one full pass per base and a few texels per probe, not a full pass per probe.
struct ProbeParts {
    bases: Vec<EnvMap>,
    probes: Vec<ProbePart>,
}

struct ProbePart {
    name: &'static str,
    base: usize,
    /// What the probe adds to its base: black but for a few texels.
    sparse: EnvMap,
}

impl ProbeParts {
    /// Each probe's whole map: its base plus its sparse part.
    fn composed(&self) -> Vec<(&'static str, EnvMap)> {
        self.probes
            .iter()
            .map(|p| {
                let base = self.bases[p.base].texels();
                let texels = base
                    .iter()
                    .zip(p.sparse.texels())
                    .map(|(b, s)| [0, 1, 2].map(|c| b[c] + s[c]))
                    .collect();
                let env = EnvMap::from_texels(p.sparse.width(), p.sparse.height(), texels)
                    .map_or_else(|_| self.bases[p.base].clone(), |(e, _)| e);
                (p.name, env)
            })
            .collect()
    }

    fn new() -> Self {
        let sky = EnvMap::from_fn(PROBE_MAP_ROWS, |d| {
            if d.y >= 0.0 {
                let t = (0.3 + 0.7 * d.y) as f32;
                [0.6 * t, 0.8 * t, t]
            } else {
                [0.15, 0.13, 0.1]
            }
        });
        let (w, h) = (sky.width(), sky.height());
        let sparse = |texels: Vec<[f32; 3]>| EnvMap::from_texels(w, h, texels).map(|(e, _)| e);
        let sky_power: f64 = sky.power().iter().sum::<f64>() / 3.0;
        let sun = |dir: DVec3| {
            let (col, row) = crate::envmap::direction_to_texel(dir.normalize(), w, h);
            // Sun power 1.5× the sky's: 60 % of the total. The sparse part replaces the sky's texel.
            let l = (1.5 * sky_power / texel_solid_angle(row, w, h)) as f32;
            let under = sky.texel(col, row);
            let mut texels = vec![[0.0_f32; 3]; w * h];
            texels[row * w + col] = [l - under[0], 0.95 * l - under[1], 0.85 * l - under[2]];
            sparse(texels)
        };
        let room = [0.05_f32; 3];
        let dark_room = EnvMap::from_fn(PROBE_MAP_ROWS, |_| room);
        let panel = |d: DVec3, centre: DVec3| d.dot(centre.normalize()) > 0.97;
        let panels = EnvMap::from_fn(PROBE_MAP_ROWS, |d| {
            if panel(d, DVec3::new(0.5, 0.5, 0.7)) || panel(d, DVec3::new(-0.8, 0.3, -0.5)) {
                [20.0 - room[0], 20.0 - room[1], 19.0 - room[2]]
            } else {
                [0.0; 3]
            }
        });
        let suns = [
            ("sun in front", DVec3::new(0.3, 0.45, 0.85)),
            ("sun to the side", DVec3::new(-0.9, 0.4, 0.1)),
            ("sun behind", DVec3::new(0.3, 0.4, -0.866)),
            ("sun straight behind", DVec3::new(-0.15, 0.15, -0.98)),
        ];
        let mut probes: Vec<ProbePart> = suns
            .iter()
            .filter_map(|&(name, dir)| sun(dir).ok().map(|sparse| ProbePart { name, base: 0, sparse }))
            .collect();
        probes.push(ProbePart {
            name: "studio",
            base: 1,
            sparse: panels,
        });
        Self {
            bases: vec![sky, dark_room],
            probes,
        }
    }
}

/// The fast path's images of the check's sphere under every [`probe_maps`] map, made once per
/// material: the check of each finer grid compares against the same images.
pub struct ProbeReference {
    normals: Vec<[f32; 3]>,
    mask: Vec<f32>,
    pixels: PolarNormals,
    probes: Vec<(&'static str, EnvMap, Vec<[f32; 3]>)>,
}

impl ProbeReference {
    /// `None` for a measured BRDF (no fast path). Single-threaded, like the kernel build (see
    /// [`ZonalKernel::with_tail`]).
    pub fn new(brdf: &BrdfModel) -> Option<Self> {
        let (normals, mask) = crate::camera::unit_sphere_normals(PROBE_RES);
        let polar: Vec<(f32, f32)> = normals.iter().zip(&mask).map(|(n, &m)| polar(n, m)).collect();
        let pixels = PolarNormals {
            theta: polar.iter().map(|p| p.0).collect(),
            phi: polar.iter().map(|p| p.1).collect(),
        };
        let image = |env: &EnvMap| -> Option<Vec<[f32; 3]>> {
            let fast = super::fast::FastShader::new(brdf, env)?;
            Some(
                normals
                    .iter()
                    .zip(&mask)
                    .map(|(n, &m)| {
                        if m > 0.0 {
                            super::Shader::shade(&fast, *n, None)
                        } else {
                            [0.0; 3]
                        }
                    })
                    .collect(),
            )
        };
        let parts = ProbeParts::new();
        let bases: Vec<Vec<[f32; 3]>> = parts.bases.iter().map(image).collect::<Option<_>>()?;
        let mut probes = Vec::with_capacity(parts.probes.len());
        for (part, (name, env)) in parts.probes.iter().zip(parts.composed()) {
            let extra = image(&part.sparse)?;
            let sum = bases[part.base]
                .iter()
                .zip(extra)
                .map(|(b, e)| [0, 1, 2].map(|c| b[c] + e[c]))
                .collect();
            probes.push((name, env, sum));
        }
        Some(Self {
            normals,
            mask,
            pixels,
            probes,
        })
    }
}

/// The kernel's largest relative RMSE against the fast path on a [`PROBE_RES`]² sphere under the
/// [`probe_maps`], and the map that showed it.
pub fn probe_error(kernel: &ZonalKernel, reference: &ProbeReference) -> (f64, &'static str) {
    let ProbeReference {
        normals,
        mask,
        pixels,
        probes,
    } = reference;
    let need = pixels.rows_needed(&kernel.grid, mask);
    let mut worst = (0.0_f64, "none");
    for (name, env, fast) in probes {
        let spectra = ZonalEnv::new(env, kernel.grid);
        let lit = lit_points(&kernel.brdf, &spectra.points);
        let table = Padded::new(&normal_table_with(kernel, &spectra, &need, false), &kernel.grid);
        let (mut err, mut norm) = (0.0_f64, 0.0_f64);
        for p in 0..normals.len() {
            let (t, ph) = (pixels.theta[p], pixels.phi[p]);
            if mask[p] <= 0.0 || t.is_nan() {
                continue;
            }
            let z = pixel_radiance(&table, &kernel.grid, &kernel.brdf, &lit, t, ph);
            let f = fast[p];
            for c in 0..3 {
                err += ((z[c] - f[c]) as f64).powi(2);
                norm += (f[c] as f64).powi(2);
            }
        }
        let e = if norm > 0.0 { (err / norm).sqrt() } else { 0.0 };
        // A non-finite error is a failed check.
        let e = if e.is_finite() { e } else { f64::INFINITY };
        if e > worst.0 {
            worst = (e, *name);
        }
    }
    worst
}

/// Shades every pixel with `mask > 0` from a material's kernel and an environment on the same
/// grid. Returns radiance (0 outside the mask) and the number of non-finite values replaced
/// (see [`sanitize`](super::sanitize)).
pub fn shade_image_zonal(
    kernel: &ZonalKernel,
    env: &ZonalEnv,
    pixels: &PolarNormals,
    mask: &[f32],
) -> (Vec<[f32; 3]>, usize) {
    assert!(env.serves(&kernel.grid), "kernel and environment on different grids");
    let grid = kernel.grid;
    let need = pixels.rows_needed(&grid, mask);
    let table = Padded::new(&normal_table(kernel, env, &need), &grid);
    let lit = lit_points(&kernel.brdf, &env.points);
    let out: Vec<([f32; 3], usize)> = pixels
        .theta
        .par_iter()
        .zip(pixels.phi.par_iter())
        .zip(mask.par_iter())
        .map(|((&t, &p), &m)| {
            if m <= 0.0 || t.is_nan() {
                return ([0.0; 3], 0);
            }
            let mut rgb = pixel_radiance(&table, &grid, &kernel.brdf, &lit, t, p);
            let bad = sanitize(&mut rgb);
            (rgb, bad)
        })
        .collect();
    let bad = out.iter().map(|o| o.1).sum();
    (out.into_iter().map(|o| o.0).collect(), bad)
}

/// Shades an image with the zonal method, building the kernel and the environment's spectra on
/// the spot (callers that shade many images keep a [`ZonalKernel`] per material instead).
/// `None` where the zonal method does not shade this material: measured BRDFs and lobes the grid
/// cannot resolve.
pub fn shade_image_once(
    brdf: &BrdfModel,
    env: &EnvMap,
    normals: &[[f32; 3]],
    mask: &[f32],
) -> Option<(Vec<[f32; 3]>, usize)> {
    let kernel = ZonalKernel::for_brdf(brdf)?;
    let spectra = ZonalEnv::new(env, kernel.grid);
    let pixels = PolarNormals::new(normals, mask);
    Some(shade_image_zonal(&kernel, &spectra, &pixels, mask))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::Lambert;

    /// A map with structure at every scale: a sun, a gradient and per-texel noise.
    fn busy_env(rows: usize) -> EnvMap {
        let sun = DVec3::new(0.4, 0.6, 0.5).normalize();
        EnvMap::from_fn(rows, |d| {
            let noise = ((d.x * 91.0).sin() * (d.y * 37.0 + d.z * 53.0).cos()).abs() as f32;
            let base = [0.3 + 0.2 * noise, 0.5 + d.y as f32 * 0.3, 0.8];
            if d.dot(sun) > 0.999 { [2e4, 1.8e4, 1.5e4] } else { base }
        })
    }

    #[test]
    fn row_spectra_equal_a_direct_fourier_sum_of_the_spread_texels() {
        let grid = ZonalGrid::with_rows(8);
        let env = busy_env(16);
        let spectra = ZonalEnv::new(&env, grid);
        // The spread power, directly (f64).
        let n = grid.phi;
        let power = spread_power(&env, grid);
        let m = grid.harmonics();
        for (r, row) in power.chunks(n).enumerate() {
            for c in 0..3 {
                let channel: Vec<f64> = row.iter().map(|p| p[c]).collect();
                let scale = channel.iter().map(|v| v.abs()).sum::<f64>().max(1e-30);
                for f in 0..m {
                    let (mut re, mut im) = (0.0, 0.0);
                    for (j, v) in channel.iter().enumerate() {
                        let a = -2.0 * PI * (f * j) as f64 / n as f64;
                        re += v * a.cos();
                        im += v * a.sin();
                    }
                    let i = (r * 3 + c) * m + f;
                    assert!(
                        (spectra.re[i] as f64 - re).abs() < 1e-5 * scale,
                        "row {r} ch {c} f {f}: re"
                    );
                    assert!(
                        (spectra.im[i] as f64 - im).abs() < 1e-5 * scale,
                        "row {r} ch {c} f {f}: im"
                    );
                }
            }
        }
    }

    /// The environment's power L·dω spread onto `grid`'s nodes, directly in f64.
    fn spread_power(env: &EnvMap, grid: ZonalGrid) -> Vec<[f64; 3]> {
        let splat = Splat::new(env.height(), grid);
        let mut power = vec![[0.0_f64; 3]; grid.env_rows * grid.phi];
        // The texels shaded per pixel stay off the grid.
        let points = point_texels(env);
        for (t, (l, nodes)) in env.texels().iter().zip(&splat.nodes).enumerate() {
            if points.iter().any(|&(i, _)| i == t) {
                continue;
            }
            for &(node, w) in nodes {
                for (p, &lc) in power[node as usize].iter_mut().zip(l.iter()) {
                    *p += w as f64 * lc as f64;
                }
            }
        }
        power
    }

    #[test]
    fn spreading_keeps_each_texels_power() {
        // Catmull–Rom weights sum to 1 in each direction, so a texel's L·dω is kept exactly.
        let grid = ZonalGrid::with_rows(12);
        let splat = Splat::new(16, grid);
        for (t, nodes) in splat.nodes.iter().enumerate() {
            let sum: f64 = nodes.iter().map(|&(_, w)| w as f64).sum();
            let sa = texel_solid_angle(t / 32, 32, 16);
            assert!((sum - sa).abs() < 1e-6 * sa, "texel {t}: {sum} vs {sa}");
            assert!(nodes.iter().all(|&(i, _)| (i as usize) < grid.env_rows * grid.phi));
        }
    }

    #[test]
    fn the_table_is_the_circular_convolution_of_kernel_and_spread_map() {
        // Direct Σ_r Σ_j k(a, r, m − j) W(r, j) at every grid normal against the FFT route;
        // the only difference allowed is the cut spectra (TAIL) and f32 rounding.
        let grid = ZonalGrid::with_rows(8);
        let m = Dsbrdf::isotropic_in_theta_d([[(0.2, 0.01), (1.0, 20.0), (0.5, 200.0)]; 3]);
        let brdf = BrdfModel::Dsbrdf(Box::new(m.clone()));
        let kernel = ZonalKernel::new(&brdf, grid).unwrap();
        let env = busy_env(16);
        let spectra = ZonalEnv::new(&env, grid);
        let table = normal_table(&kernel, &spectra, &vec![true; grid.rows + 1]);
        let n = grid.phi;
        let power = spread_power(&env, grid);
        let geometry = Geometry::new(&grid);
        for (a, row) in table.iter().enumerate().take(grid.rows + 1) {
            let mut direct = vec![[0.0_f64; 3]; n];
            for r in 0..grid.env_rows {
                let Some(k) = geometry.dsbrdf_kernel(a, r, &RowLobes::new(&m, grid.env_theta(r) / 2.0)) else {
                    continue;
                };
                for (mm, d) in direct.iter_mut().enumerate() {
                    for j in 0..n {
                        for c in 0..3 {
                            d[c] += k[c][(mm + n - j) % n] as f64 * power[r * n + j][c];
                        }
                    }
                }
            }
            let scale = direct.iter().flatten().fold(0.0_f64, |a, b| a.max(b.abs()));
            for (mm, d) in direct.iter().enumerate() {
                for c in 0..3 {
                    let got = row[mm][c] as f64;
                    assert!(
                        (got - d[c]).abs() <= 2e-3 * scale,
                        "row {a} col {mm} ch {c}: {got} vs {}",
                        d[c]
                    );
                }
            }
        }
    }

    #[test]
    fn grids_follow_the_sharpest_energetic_lobe() {
        let matte = BrdfModel::Lambert(Lambert { albedo: [0.5; 3] });
        assert_eq!(ZonalGrid::for_brdf(&matte).unwrap().rows, MIN_ROWS);
        let glossy = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
            [[(0.1, 0.01), (0.5, 400.0), (1e-5, 1e4)]; 3],
        )));
        // γ' = 400·0.5/(1 − e^−0.5) ≈ 508: width 0.0444, so about θ_max/(0.5 · 0.0444) ≈ 71 rows
        // dealt to the bands by their length (each rounded up), and columns as fine.
        let g = ZonalGrid::for_brdf(&glossy).unwrap();
        let width = 1.0 / 508.3_f64.sqrt();
        let edges = normal_edges();
        for i in 0..BANDS {
            let spacing = (edges[i + 1] - edges[i]) / g.normal_bands[i] as f64;
            assert!(
                spacing <= 0.5 * width && spacing > 0.4 * width,
                "band {i}: {spacing} for {width}"
            );
        }
        assert_eq!(g.normal_bands, g.env_bands, "no lobe changes with θ_d");
        assert!((71..=76).contains(&g.rows), "{} rows", g.rows);
        assert!(2.0 * PI / g.phi as f64 <= 0.5 * width, "{} columns", g.phi);
        // A lobe with no share of the image (κ = 1e-5) does not refine the grid; a mirror is
        // beyond the cap, so it is refused rather than shaded on a grid too coarse for it.
        let mirror = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d([[(5.0, 1e4); 3]; 3])));
        assert_eq!(ZonalGrid::for_brdf(&mirror), None);
        assert!(matches!(
            ZonalKernel::checked(&mirror, &ZonalParams::default()),
            Err(ZonalRefusal::TooSharp { max_rows: MAX_ROWS, .. })
        ));
        // A lobe with 10⁻³ of a matte base's energy but 8× its peak (κ 1, γ 10⁴) refines the grid
        // to the cap: measured by its share of the image under a point light, not by its energy.
        // It needs more than the cap, so the check decides, and on the capped grid it misses the
        // budget.
        let peaky = BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
            [[(0.2, 1e-3), (1.0, 1e4), (1e-5, 1e4)]; 3],
        )));
        let need = ZonalGrid::band_rows_needed(&peaky, &ZonalParams::default()).unwrap();
        assert!(uniform_equivalent(&need) > 2.0 * MAX_ROWS as f64, "{need:?}");
        let g = ZonalGrid::for_brdf(&peaky).expect("within CHECKED_BEYOND_CAP × the cap");
        assert!(g.rows >= MAX_ROWS - 8 && g.rows <= MAX_ROWS, "{} rows", g.rows);
        assert!(matches!(
            ZonalKernel::checked(&peaky, &ZonalParams::default()),
            Err(ZonalRefusal::OverBudget { .. })
        ));
    }

    #[test]
    fn band_coordinates_invert_band_angles() {
        let bands = [7, 3, 12, 1, 40];
        for edges in [normal_edges(), env_edges()] {
            let mut prev = -1.0;
            for k in 0..=(63 * 4) {
                let x = k as f64 / 4.0;
                let theta = band_theta(&bands, &edges, x);
                assert!(theta > prev, "not increasing at {x}");
                prev = theta;
                assert!((BandCoords::new(&bands, &edges).coord(theta) - x).abs() < 1e-9, "x {x}");
            }
            assert!((band_theta(&bands, &edges, 63.0) - edges[BANDS]).abs() < 1e-12);
        }
    }

    #[test]
    fn lobes_brightening_at_grazing_get_finer_rows_there_only() {
        // κ from 0.05 to 8 between the last two knots (78°, 90°); flat elsewhere.
        let mut m = Dsbrdf::isotropic_in_theta_d([[(0.2, 1e-3), (0.05, 50.0), (1e-5, 1e4)]; 3]);
        let mut p = *m.params();
        for c in 0..3 {
            p[crate::brdf::dsbrdf::param_index(c, 1, crate::brdf::dsbrdf::LobeParam::Kappa, KNOTS - 1)] = 8.0;
        }
        m = Dsbrdf::from_params(&p).unwrap();
        let brdf = BrdfModel::Dsbrdf(Box::new(m));
        let base = ZonalGrid::with_rows(48);
        let g = base.refined_for(&brdf, LOBE_STEP);
        assert_eq!(g.normal_bands[..3], base.normal_bands[..3]);
        assert_eq!(g.env_bands[..3], base.env_bands[..3]);
        // ln expm1(8) − ln expm1(0.05) ≈ 11 over the last band (counted once the lobe has a
        // tenth of its channel): about 35 rows at a step of 0.3, against 6.
        assert!(g.normal_bands[4] >= 30 && g.env_bands[4] >= 30, "{g:?}");
        assert_eq!(g.phi, base.phi);
        assert_eq!(g.rows, g.normal_bands.iter().map(|&n| n as usize).sum::<usize>());
    }

    #[test]
    fn the_probe_reference_from_bases_and_sparse_parts_is_the_fast_path_on_the_whole_maps() {
        // The check's reference is summed from shared bases and sparse parts; it must be what
        // the fast path gives on each composed map, for every kind of material.
        let mut p = *Dsbrdf::isotropic_in_theta_d([[(0.3, 1e-3), (0.5, 300.0), (1e-5, 1e4)]; 3]).params();
        for c in 0..3 {
            p[crate::brdf::dsbrdf::param_index(c, 1, crate::brdf::dsbrdf::LobeParam::Kappa, KNOTS - 1)] = 6.0;
        }
        let materials = [
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::from_params(&p).unwrap())),
            BrdfModel::Lambert(Lambert {
                albedo: [0.7, 0.5, 0.2],
            }),
            BrdfModel::Ggx(crate::brdf::Ggx::new(
                0.05,
                crate::brdf::Fresnel::Schlick([0.9, 0.6, 0.3]),
            )),
        ];
        for brdf in &materials {
            let reference = ProbeReference::new(brdf).unwrap();
            let maps = probe_maps();
            assert_eq!(reference.probes.len(), maps.len());
            assert_eq!(maps.len(), 5);
            for ((name, env), (rname, renv, image)) in maps.iter().zip(&reference.probes) {
                assert_eq!(name, rname);
                assert_eq!(env.texels(), renv.texels());
                let fast = super::super::fast::FastShader::new(brdf, env).unwrap();
                let (mut err, mut norm) = (0.0_f64, 0.0_f64);
                for (i, n) in reference.normals.iter().enumerate() {
                    let f = if reference.mask[i] > 0.0 {
                        super::super::Shader::shade(&fast, *n, None)
                    } else {
                        [0.0; 3]
                    };
                    for c in 0..3 {
                        err += ((image[i][c] - f[c]) as f64).powi(2);
                        norm += (f[c] as f64).powi(2);
                    }
                }
                assert!(norm > 0.0, "{name}: black reference");
                let e = (err / norm).sqrt();
                assert!(e < 1e-5, "{name}: {e}");
            }
        }
    }

    #[test]
    fn a_sun_behind_the_object_is_shaded_per_pixel_on_the_terminator() {
        // One texel with 60 % of the power 168° from the view: the lobe peaks 6° from the
        // terminator, where the grid alone was 7 % off at single pixels (PERFORMANCE.md).
        let sun = DVec3::new(-0.15, 0.15, -0.98).normalize();
        let env = probe_maps()
            .into_iter()
            .find(|(n, _)| *n == "sun straight behind")
            .unwrap()
            .1;
        let (w, h) = (env.width(), env.height());
        let points = point_texels(&env);
        assert_eq!(points.len(), 1, "the sun alone");
        assert!(points[0].1.dir.dot(sun) > 0.99);
        assert!(points[0].0 < w * h);
        // A glossy lobe that brightens at grazing, like the library's smooth plastics.
        let mut p = *Dsbrdf::isotropic_in_theta_d([[(0.3, 1e-3), (0.5, 300.0), (1e-5, 1e4)]; 3]).params();
        for c in 0..3 {
            p[crate::brdf::dsbrdf::param_index(c, 1, crate::brdf::dsbrdf::LobeParam::Kappa, KNOTS - 1)] = 6.0;
        }
        let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::from_params(&p).unwrap()));
        let kernel = ZonalKernel::new(&brdf, ZonalGrid::with_rows(64).refined_for(&brdf, LOBE_STEP)).unwrap();
        let (normals, mask) = crate::camera::unit_sphere_normals(64);
        let zonal = shade_image_zonal(
            &kernel,
            &ZonalEnv::new(&env, kernel.grid),
            &PolarNormals::new(&normals, &mask),
            &mask,
        )
        .0;
        let fast = super::super::fast::FastShader::new(&brdf, &env).unwrap();
        let (mut err, mut norm) = (0.0_f64, 0.0_f64);
        for (i, n) in normals.iter().enumerate() {
            if mask[i] <= 0.0 {
                continue;
            }
            let f = super::super::Shader::shade(&fast, *n, None);
            for c in 0..3 {
                err += ((zonal[i][c] - f[c]) as f64).powi(2);
                norm += (f[c] as f64).powi(2);
            }
        }
        let e = (err / norm).sqrt();
        assert!(e < 2e-3, "relative RMSE {e}");
    }

    #[test]
    fn point_texels_are_the_bright_ones_behind_at_most_the_cap_brightest_first() {
        let (h, w) = (64, 128);
        let map = |texels: Vec<[f32; 3]>| EnvMap::from_texels(w, h, texels).unwrap().0;
        // Black, and uniform (each texel ~1/8192 of the power): nothing leaves the grid.
        assert!(point_texels(&map(vec![[0.0; 3]; w * h])).is_empty());
        assert!(point_texels(&map(vec![[5.0; 3]; w * h])).is_empty());
        // 40 equal suns behind the object (θ > 130°), one brighter in front, a dim sky.
        let mut texels = vec![[0.01_f32; 3]; w * h];
        let mut behind = Vec::new();
        for t in 0..w * h {
            let d = texel_direction(t % w, t / w, w, h);
            if d.z < -0.9 && behind.len() < 40 {
                behind.push(t);
                texels[t] = [50.0; 3];
            } else if d.z > 0.9 && texels[t] == [0.01; 3] && !texels.contains(&[500.0; 3]) {
                texels[t] = [500.0; 3];
            }
        }
        let env = map(texels);
        let points = point_texels(&env);
        assert_eq!(points.len(), MAX_POINTS);
        for (t, p) in &points {
            assert!(behind.contains(t), "texel {t} is not one of the suns behind");
            assert!(p.dir.z <= POINT_MIN_THETA_DEG.to_radians().cos());
        }
        // Brightest first (by power, so by solid angle among equal radiances), ties by index,
        // and the same choice every time.
        let power = |t: usize| texel_solid_angle(t / w, w, h);
        for pair in points.windows(2) {
            let (a, b) = (pair[0].0, pair[1].0);
            assert!(power(a) > power(b) || (power(a) == power(b) && a < b));
        }
        assert_eq!(points, point_texels(&env));
    }

    #[test]
    fn refined_grids_stay_bounded_at_the_corners_of_the_range() {
        use crate::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, LobeParam, param_index};
        let corners = [KAPPA_RANGE.0, KAPPA_RANGE.1]
            .into_iter()
            .flat_map(|k| [GAMMA_RANGE.0, GAMMA_RANGE.1].map(|g| (k, g)));
        let corners: Vec<(f64, f64)> = corners.collect();
        // Every pair of corners, switching from one to the other at each knot.
        for &(k0, g0) in &corners {
            for &(k1, g1) in &corners {
                for switch in 1..KNOTS {
                    let mut p = *Dsbrdf::isotropic_in_theta_d([[(0.2, 1e-3), (k0, g0), (1e-5, 1e4)]; 3]).params();
                    for c in 0..3 {
                        for j in switch..KNOTS {
                            p[param_index(c, 1, LobeParam::Kappa, j)] = k1;
                            p[param_index(c, 1, LobeParam::Gamma, j)] = g1;
                        }
                    }
                    let brdf = BrdfModel::Dsbrdf(Box::new(Dsbrdf::from_params(&p).unwrap()));
                    let g = ZonalGrid::with_rows(MIN_ROWS).refined_for(&brdf, LOBE_STEP);
                    for b in g.normal_bands.iter().chain(&g.env_bands) {
                        assert!((1..=MAX_BAND_ROWS as u16).contains(b), "{g:?}");
                    }
                    assert_eq!(g.rows, g.normal_bands.iter().map(|&n| n as usize).sum::<usize>());
                    assert_eq!(g.env_rows, g.env_bands.iter().map(|&n| n as usize).sum::<usize>());
                    // The plan is finite too: a grid, or a refusal, never a panic.
                    let _ = ZonalPlan::for_brdf(&brdf);
                }
            }
        }
    }
}

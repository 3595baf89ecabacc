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
//!
//! The files follow the steps: `grid.rs` (the grid a material needs), `kernel.rs` (step 1),
//! `env.rs` (step 2, with the point lights), `normals.rs` (step 3's normal tables), `probe.rs`
//! (the check against the exact path that decides whether a grid resolves a material), and here
//! the plan, the parameters and the per-image entry points.

use super::{catmull_rom, sanitize, shading_normal};
use crate::brdf::dsbrdf::{KNOTS, THETA_D_KNOTS_DEG, param_meaning, param_name};
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

mod env;
mod grid;
mod kernel;
mod normals;
mod probe;
#[cfg(test)]
mod tests;

pub use env::*;
pub use grid::*;
pub use kernel::*;
pub use normals::*;
pub use probe::*;

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

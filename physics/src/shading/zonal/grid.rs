//! The grid of normal and environment rows a material needs: bands of θ_d, lobe widths and
//! how fast the lobes change ([`ZonalGrid::for_brdf`]).

use super::*;

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
pub(super) const BAND_MARGIN_DEG: f64 = 5.0;

/// Edges of the bands of θ_n (radians): the knots, the last one θ_max.
pub(super) fn normal_edges() -> [f64; BANDS + 1] {
    let mut e = THETA_D_KNOTS_DEG.map(f64::to_radians);
    e[BANDS] = theta_max();
    e
}

/// Edges of the bands of θ_ω (radians): twice the knots.
pub(super) fn env_edges() -> [f64; BANDS + 1] {
    THETA_D_KNOTS_DEG.map(|d| (2.0 * d).to_radians())
}

/// The angle at continuous row coordinate `x` (0 at the first edge, a band's rows evenly
/// spaced within it).
pub(super) fn band_theta(bands: &[u16; BANDS], edges: &[f64; BANDS + 1], x: f64) -> f64 {
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
pub(super) struct BandCoords {
    pub(super) edges: [f64; BANDS + 1],
    pub(super) widths: [f64; BANDS],
    pub(super) rows: [f64; BANDS],
    pub(super) first: [f64; BANDS],
}

impl BandCoords {
    pub(super) fn new(bands: &[u16; BANDS], edges: &[f64; BANDS + 1]) -> Self {
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
    pub(super) fn coord(&self, theta: f64) -> f64 {
        let mut i = 0;
        while i < BANDS - 1 && theta > self.edges[i + 1] {
            i += 1;
        }
        self.first[i] + (theta - self.edges[i]) / self.widths[i] * self.rows[i]
    }
}

/// The rows a uniform grid of `rows` rows over the bands puts in each.
pub(super) fn dealt(rows: f64, edges: &[f64; BANDS + 1]) -> [usize; BANDS] {
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
    pub(super) fn for_needs(need: &[f64; BANDS], params: &ZonalParams) -> Self {
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
    pub(super) fn finer(&self, factor: f64, params: &ZonalParams) -> Self {
        let need = self.normal_bands.map(|n| n as f64 * factor);
        Self::for_needs(&need, params)
    }

    pub(super) fn normal_theta(&self, a: usize) -> f64 {
        band_theta(&self.normal_bands, &normal_edges(), a as f64)
    }

    /// The normal rows' [`BandCoords`]: θ_n ∈ [0, θ_max] to a row coordinate (row a at a), for
    /// lookups per pixel.
    pub(super) fn normal_coords(&self) -> BandCoords {
        BandCoords::new(&self.normal_bands, &normal_edges())
    }

    pub(super) fn env_theta(&self, r: usize) -> f64 {
        band_theta(&self.env_bands, &env_edges(), r as f64 + 0.5)
    }

    /// The continuous environment-row coordinate of θ_ω ∈ [0, π]: row r's centre is at r.
    pub(super) fn env_row_coord(&self, theta: f64) -> f64 {
        BandCoords::new(&self.env_bands, &env_edges()).coord(theta) - 0.5
    }

    /// What an environment's spread and spectra depend on: the environment rows and columns.
    pub(super) fn env_layout(&self) -> ([u16; BANDS], usize) {
        (self.env_bands, self.phi)
    }

    /// Harmonics kept per spectrum (0..=phi/2).
    pub(super) fn harmonics(&self) -> usize {
        self.phi / 2 + 1
    }
}

/// The rows of a uniform normal grid as fine as the finest of per-band rows `bands`.
pub(super) fn uniform_equivalent(bands: &[f64; BANDS]) -> f64 {
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
pub(super) fn lobe_share(&(kappa, gamma): &(f64, f64)) -> f64 {
    kappa.exp_m1() * (1.0 / effective_gamma(kappa, gamma).sqrt()).min(1.0)
}

/// Width 1/√γ' of a DSBRDF's sharpest member that carries energy (γ' the curvature-equivalent
/// sharpness, [`effective_gamma`]), over θ_d in whole degrees from `lo` to `hi` (clamped to
/// [0°, 90°]).
pub(super) fn dsbrdf_width_over(m: &Dsbrdf, lo: f64, hi: f64) -> f64 {
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
pub(super) fn lobe_variation(m: &Dsbrdf, lo: f64, hi: f64) -> f64 {
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

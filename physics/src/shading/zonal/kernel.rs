//! Per material: the kernel k tabulated on the grid and Fourier-transformed along φ, its
//! spectra cut where their tail no longer matters ([`ZonalKernel`]).

use super::*;

/// One cut spectrum: environment row, channel, and where its coefficients are.
#[derive(Clone, Copy, Debug)]
pub(super) struct Entry {
    pub(super) env_row: u32,
    pub(super) channel: u32,
    pub(super) start: u32,
    pub(super) len: u32,
}

/// A material's kernel spectra on a grid (step 1 of the module docs). Build once per material
/// and grid; share between threads.
pub struct ZonalKernel {
    pub(super) grid: ZonalGrid,
    /// The material, for the texels shaded per pixel ([`POINT_SHARE`]).
    pub(super) brdf: BrdfModel,
    /// Per normal row, its cut spectra.
    pub(super) entries: Vec<Vec<Entry>>,
    /// Per normal row, the real cosine coefficients of its spectra.
    pub(super) coeffs: Vec<Vec<f32>>,
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
    /// A DSBRDF parameter beyond its raw range (a network's saturated output, which a material
    /// file may hold): the grid and its probe check are validated on the raw range only.
    #[error("{} = {value} is beyond the range the zonal grid was validated on", param_name(*index))]
    BeyondRange {
        /// The parameter's flat index ([`param_name`] names it as a material file does).
        index: usize,
        /// Its value.
        value: f64,
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
        if let BrdfModel::Dsbrdf(m) = brdf
            && let Some((i, &value)) = m.params().iter().enumerate().find(|&(i, v)| {
                let (lo, hi) = param_meaning(i).2.range();
                !(lo..=hi).contains(v)
            })
        {
            return Err(ZonalRefusal::BeyondRange { index: i, value });
        }
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
pub(super) struct RowLobes {
    /// κ and γ of lobe k of channel c at `3 c + k`, padded with κ = 0 lobes (which add
    /// expm1(0) = 0) to three 4-wide vectors.
    pub(super) kappa: [f32; LOBE_LANES],
    pub(super) gamma: [f32; LOBE_LANES],
}

/// Lanes of [`RowLobes`]: the 9 (channel, lobe) pairs, padded.
pub(super) const LOBE_LANES: usize = 12;

impl RowLobes {
    /// Σ_k expm1(κ_k cos^γ_k θ_h) of each channel, from lc = ln cos θ_h; 0 where the half
    /// vector is behind the surface (`front` false). The kernel and the per-pixel texels use
    /// this one formula, so they agree to the bit. Branch-free over flat lanes, so it
    /// vectorises.
    #[inline]
    pub(super) fn rho(&self, lc: f32, front: bool) -> [f32; 3] {
        let mut v = [0.0_f32; LOBE_LANES];
        for (i, v) in v.iter_mut().enumerate() {
            let pw = fastmath::exp(self.gamma[i] * lc);
            let pw = if front { pw } else { 0.0 };
            *v = fastmath::expm1(self.kappa[i] * pw);
        }
        std::array::from_fn(|c| v[3 * c] + v[3 * c + 1] + v[3 * c + 2])
    }

    pub(super) fn new(m: &Dsbrdf, theta_d: f64) -> Self {
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
pub(super) struct Geometry {
    pub(super) grid: ZonalGrid,
    /// cos φ_j and sin²(φ_j/2) for j = 0..=phi/2.
    pub(super) cos_phi: Vec<f32>,
    pub(super) half_sin2: Vec<f32>,
}

impl Geometry {
    pub(super) fn new(grid: &ZonalGrid) -> Self {
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
    pub(super) fn dsbrdf_kernel(&self, a: usize, r: usize, lobes: &RowLobes) -> Option<[Vec<f32>; 3]> {
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
    pub(super) fn generic_kernel(&self, a: usize, r: usize, brdf: &BrdfModel) -> Option<[Vec<f32>; 3]> {
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
pub(super) fn mirror(half: &[f32], n: usize) -> Vec<f32> {
    (0..n).map(|j| half[j.min(n - j)]).collect()
}

/// Transforms real even sequences two at a time (one as the real, one as the imaginary part:
/// both spectra are real, so they come back as the real and imaginary parts) and cuts each after
/// its last significant harmonic.
pub(super) fn cut_spectra(
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

pub(super) type Plan = Arc<dyn Fft<f32>>;
pub(super) static FORWARD: Memo<usize, Plan> = Memo::new();
pub(super) static INVERSE: Memo<usize, Plan> = Memo::new();
/// Keyed by map height and [`ZonalGrid::env_layout`]: all a spread depends on.
pub(super) static SPLATS: Memo<(usize, ([u16; BANDS], usize)), Splat> = Memo::new();

pub(super) fn forward_plan(n: usize) -> Plan {
    FORWARD
        .get(n, || FftPlannerScalar::new().plan_fft_forward(n))
        .as_ref()
        .clone()
}

pub(super) fn inverse_plan(n: usize) -> Plan {
    INVERSE
        .get(n, || FftPlannerScalar::new().plan_fft_inverse(n))
        .as_ref()
        .clone()
}

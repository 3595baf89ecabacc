//! Per environment: texels spread onto the grid and transformed ([`ZonalEnv`]), the few bright
//! texels behind the object kept off the grid and summed per pixel (point lights).

use super::*;

/// Where each texel of an equirectangular map of a given height lands on a grid's environment
/// rows: 4×4 Catmull–Rom weights in (θ, φ) about the view axis, the texel's solid angle folded
/// in. Rows beyond a pole continue on the other side of it, half a turn round.
pub(super) struct Splat {
    /// Per texel (row-major), 16 (grid node, weight) pairs.
    pub(super) nodes: Vec<[(u32, f32); 16]>,
}

impl Splat {
    pub(super) fn new(height: usize, grid: ZonalGrid) -> Self {
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
pub(super) struct PointTexel {
    pub(super) dir: DVec3,
    pub(super) power: [f32; 3],
}

/// The texels of `env` (camera space) shaded per pixel, by index, brightest first.
pub(super) fn point_texels(env: &EnvMap) -> Vec<(usize, PointTexel)> {
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
pub(super) struct LitPoint {
    pub(super) point: PointTexel,
    /// Half vector between the texel and the view (+z).
    pub(super) half: DVec3,
    /// The DSBRDF's lobes at the texel's θ_d (`None` for other models, evaluated per pixel).
    pub(super) lobes: Option<RowLobes>,
}

/// The point texels prepared for one material, and the polar angle below which a normal sees
/// none of them.
pub(super) struct LitPoints {
    pub(super) points: Vec<LitPoint>,
    /// n·ω ≤ cos(θ_ω − θ_n), so a normal with θ_n ≤ θ_ω − 90° for every point is lit by none;
    /// a thousandth of a radian short of that, so the skip never drops light.
    pub(super) unlit_below: f32,
}

pub(super) fn lit_points(brdf: &BrdfModel, points: &[PointTexel]) -> LitPoints {
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
pub(super) fn point_radiance(brdf: &BrdfModel, lit: &[LitPoint], n: DVec3) -> [f32; 3] {
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
pub(super) fn pixel_radiance(
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
pub(super) fn from_polar(theta: f32, phi: f32) -> DVec3 {
    let (st, ct) = (theta as f64).sin_cos();
    let (sp, cp) = (phi as f64).sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// The spreading weights of maps of `height` rows onto `grid` (memoised for the process).
pub(super) fn spread_for(height: usize, grid: ZonalGrid) -> Arc<Splat> {
    SPLATS.get((height, grid.env_layout()), || Splat::new(height, grid))
}

/// An environment's row spectra on a grid (step 2 of the module docs).
pub struct ZonalEnv {
    pub(super) grid: ZonalGrid,
    /// Real and imaginary parts, `[(row · 3 + channel) · harmonics + f]`.
    pub(super) re: Vec<f32>,
    pub(super) im: Vec<f32>,
    /// Bright texels behind the object, left off the grid and shaded per pixel.
    pub(super) points: Vec<PointTexel>,
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

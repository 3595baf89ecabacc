//! Lobe-adaptive evaluation of Eq. 2 for the DSBRDF: each lobe is summed at the environment
//! resolution and over the directions its width needs, on a normal-space table as fine as its
//! width needs.
//!
//! With ω_o = +z fixed and no shadows, outgoing radiance is a sum over the three lobe indices k
//! of R_k(n) = Σ_t W_t (n·ω_t)⁺ Σ_c expm1(κ_kc(θ_d,t) cos^γ_kc θ_h). Near the mirror
//! configuration θ_d equals the normal's angle θ_n from the view, so the lobe a normal meets
//! depends on θ_n; widths are w = 1/√γ' in θ_h with γ' the curvature-equivalent sharpness
//! ([`effective_gamma`]: a lobe with large κ is sharper than cos^γ). Per k and per degree of θ_n:
//!
//! * **environment level**: a power pyramid of the map (2×2 texels → 1, power summed, direction
//!   the power-weighted mean, so a sun keeps its direction); the coarsest level whose texel is at
//!   most [`TEXEL_PER_WIDTH`] × 2w of the narrowest member with a significant peak (the lobe's
//!   width in ω is about twice its width in θ_h);
//! * **neighbourhood**: only texels within 2·[`TAIL_WIDTHS`]·w of the mirror direction
//!   reflect(ω_o, n) for the widest member with significant energy, where
//!   cos^γ θ_h < e^(−TAIL_WIDTHS²/2) beyond (the whole sphere for broad lobes);
//! * **table** (per k): nodes spaced [`NODE_PER_WIDTH`] × w of the sharpest member over the
//!   hemisphere of normals, evaluated only where pixels need them, interpolated bicubically
//!   (Catmull–Rom); per pixel when a table would not save work.
//!
//! The three parameters trade speed for error; `docs/PERFORMANCE.md` has the measured trade-off
//! against the exact path.

use super::lut::{MAX_NODES_PER_PIXEL, needed_nodes, node_coords, pixel_coords, table_normal, table_position};
use super::{catmull_rom, shading_normal};
use crate::brdf::Dsbrdf;
use crate::brdf::dsbrdf::LOBES;
use crate::envmap::{EnvMap, texel_direction, texel_solid_angle};
use crate::fastmath;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// Coarsest environment texel allowed, as a fraction of the lobe's width in ω (2w).
pub const TEXEL_PER_WIDTH: f64 = 0.4;
/// Lobe half-extent in widths: cos^γ θ_h ≈ exp(−γθ²/2) < e^(−TAIL_WIDTHS²/2) beyond it. The
/// widest member with significant energy sets it, which is conservative: 3.7 gave the same
/// errors as 2.0, 1.5 did not (docs/PERFORMANCE.md).
pub const TAIL_WIDTHS: f64 = 2.0;
/// Table node spacing as a fraction of the lobe width w.
pub const NODE_PER_WIDTH: f64 = 0.5;
/// Pyramid levels (64×128 → 8×16).
pub const LEVELS: usize = 3;
/// A lobe member counts for the width when its peak expm1(κ) is at least this fraction of the
/// channel's peak at that knot (the table path's criterion); weaker members are still summed,
/// at the group's setting.
pub const SIGNIFICANT: f64 = super::lut::SIGNIFICANT_PEAK;
/// Smallest and largest table side.
const MIN_RES: usize = 64;
const MAX_RES: usize = 512;

const LANES: usize = 8;

/// One level of the power pyramid, row-major, each array padded with one lane of zeros.
struct Level {
    w: usize,
    h: usize,
    /// Smallest sin θ over each row's band (sizes the column range of a neighbourhood).
    row_min_sin: Vec<f64>,
    dir: [Vec<f32>; 3],
    half: [Vec<f64>; 3],
    cos_d: Vec<f64>,
    weight: [Vec<f32>; 3],
}

fn pad<T: Copy + Default>(mut v: Vec<T>) -> Vec<T> {
    v.extend(std::iter::repeat_n(T::default(), LANES));
    v
}

impl Level {
    fn from_texels(w: usize, h: usize, dirs: &[DVec3], power: &[[f64; 3]]) -> Level {
        let half: Vec<DVec3> = dirs
            .iter()
            .map(|d| {
                let s = *d + DVec3::Z;
                if s.length() < 1e-9 { DVec3::Z } else { s.normalize() }
            })
            .collect();
        Level {
            w,
            h,
            row_min_sin: (0..h)
                .map(|j| {
                    (PI * j as f64 / h as f64)
                        .sin()
                        .min((PI * (j + 1) as f64 / h as f64).sin())
                })
                .collect(),
            dir: [0, 1, 2].map(|a| pad(dirs.iter().map(|d| d[a] as f32).collect())),
            half: [0, 1, 2].map(|a| pad(half.iter().map(|v| v[a]).collect())),
            cos_d: pad(dirs.iter().zip(&half).map(|(d, v)| d.dot(*v).clamp(0.0, 1.0)).collect()),
            weight: [0, 1, 2].map(|c| pad(power.iter().map(|p| p[c] as f32).collect())),
        }
    }
}

/// The pyramid: level 0 is the map itself (texel centres), each next level merges 2×2 texels.
fn pyramid(env: &EnvMap) -> Vec<Level> {
    let (mut w, mut h) = (env.width(), env.height());
    let mut dirs: Vec<DVec3> = (0..w * h).map(|p| texel_direction(p % w, p / w, w, h)).collect();
    let mut power: Vec<[f64; 3]> = (0..w * h)
        .map(|p| {
            let sa = texel_solid_angle(p / w, w, h);
            env.texels()[p].map(|v| v as f64 * sa)
        })
        .collect();
    let mut out = vec![Level::from_texels(w, h, &dirs, &power)];
    while out.len() < LEVELS && w % 2 == 0 && h % 2 == 0 && h >= 2 {
        let (nw, nh) = (w / 2, h / 2);
        let mut nd = Vec::with_capacity(nw * nh);
        let mut np = Vec::with_capacity(nw * nh);
        for j in 0..nh {
            for i in 0..nw {
                let kids = [
                    (2 * j) * w + 2 * i,
                    (2 * j) * w + 2 * i + 1,
                    (2 * j + 1) * w + 2 * i,
                    (2 * j + 1) * w + 2 * i + 1,
                ];
                let mut p = [0.0; 3];
                let mut d = DVec3::ZERO;
                for &k in &kids {
                    let lum = power[k].iter().sum::<f64>();
                    d += dirs[k] * lum;
                    for c in 0..3 {
                        p[c] += power[k][c];
                    }
                }
                // A black block keeps its geometric centre.
                let centre = texel_direction(i, j, nw, nh);
                let d = if d.length() > 1e-30 { d.normalize() } else { centre };
                nd.push(d);
                np.push(p);
            }
        }
        (w, h, dirs, power) = (nw, nh, nd, np);
        out.push(Level::from_texels(w, h, &dirs, &power));
    }
    out
}

/// One lobe index k evaluated at its own setting.
struct Group {
    /// Neighbourhood radius around the mirror direction (radians in ω; ≥ π means everything)
    /// for normals at 0°, 1°, …, 90° from the view: near the mirror configuration θ_d equals
    /// the normal's angle θ_n, so the lobe's width there is that of γ(θ_d ≈ θ_n).
    radius: Vec<f64>,
    /// Pyramid level per normal angle (0°…90°): the narrower the lobe there, the finer.
    level: Vec<usize>,
    /// κ and γ per channel at each texel, per pyramid level (empty for unused levels).
    kappa: Vec<[Vec<f32>; 3]>,
    gamma: Vec<[Vec<f32>; 3]>,
}

/// ln κ and ln γ of one lobe index per channel, sampled every half degree of θ_d; the DSBRDF
/// is log-linear between knots that all fall on this grid, so linear interpolation of the
/// samples reproduces it.
struct LobeTable {
    ln_kappa: [Vec<f64>; 3],
    ln_gamma: [Vec<f64>; 3],
}

impl LobeTable {
    fn new(m: &Dsbrdf, k: usize) -> Self {
        let mut t = LobeTable {
            ln_kappa: Default::default(),
            ln_gamma: Default::default(),
        };
        for i in 0..=180 {
            let l = m.lobes_at((i as f64 * 0.5).to_radians());
            for (c, ch) in l.iter().enumerate() {
                t.ln_kappa[c].push(ch[k].0.ln());
                t.ln_gamma[c].push(ch[k].1.ln());
            }
        }
        t
    }

    /// κ and γ per channel for texels with the given cos θ_d.
    fn texels(&self, cos_d: &[f64]) -> ([Vec<f32>; 3], [Vec<f32>; 3]) {
        let mut kappa: [Vec<f32>; 3] = Default::default();
        let mut gamma: [Vec<f32>; 3] = Default::default();
        for &cd in cos_d {
            let x = (cd.clamp(0.0, 1.0).acos().to_degrees() * 2.0).clamp(0.0, 180.0);
            let i = (x.floor() as usize).min(179);
            let f = x - i as f64;
            for c in 0..3 {
                let lerp = |v: &[f64]| (v[i] + (v[i + 1] - v[i]) * f).exp() as f32;
                kappa[c].push(lerp(&self.ln_kappa[c]));
                gamma[c].push(lerp(&self.ln_gamma[c]));
            }
        }
        (kappa, gamma)
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

/// Width 1/√γ of lobe `k`'s sharpest significant member (γ taken as [`effective_gamma`]).
fn lobe_width(m: &Dsbrdf, k: usize) -> f64 {
    let gamma = m
        .significant_members(SIGNIFICANT)
        .filter(|&(_, lobe, ..)| lobe == k)
        .map(|(.., kappa, gamma)| effective_gamma(kappa, gamma))
        .fold(1.0, f64::max);
    1.0 / gamma.sqrt()
}

/// For each normal angle 0°, 1°, …, 90°: widths 1/√γ of lobe `k`'s members (any channel) for θ_d
/// within ±[`THETA_D_MARGIN_DEG`] of it (near the mirror configuration θ_d is the normal's angle,
/// so these are the lobes a normal there meets): the narrowest member whose *peak* is significant (it sets the
/// environment resolution), and the widest member whose *energy* is significant (it sets the
/// neighbourhood: a broad lobe with a low peak can still carry much of the light). `None` for
/// either when no member qualifies.
fn member_widths(m: &Dsbrdf, k: usize) -> Vec<(Option<f64>, Option<f64>)> {
    // Sharpest (effective) and broadest γ of the qualifying members at each whole degree of θ_d,
    // computed once; each normal angle then takes its window of them.
    let per_degree: Vec<(f64, f64)> = (0..=90)
        .map(|deg| {
            let (mut sharpest, mut broadest) = (0.0_f64, f64::INFINITY);
            for ch in &m.lobes_at((deg as f64).to_radians()) {
                let peak = |j: usize| ch[j].0.exp_m1();
                // ∫ cos^γ θ dω over the hemisphere is 2π/(γ + 1).
                let energy = |j: usize| peak(j) * 2.0 * PI / (ch[j].1 + 1.0);
                let (peaks, energies): (f64, f64) = (0..LOBES)
                    .map(|j| (peak(j), energy(j)))
                    .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
                if peak(k) >= SIGNIFICANT * peaks {
                    sharpest = sharpest.max(effective_gamma(ch[k].0, ch[k].1));
                }
                if energy(k) >= SIGNIFICANT_ENERGY * energies {
                    broadest = broadest.min(ch[k].1);
                }
            }
            (sharpest, broadest)
        })
        .collect();
    let margin = THETA_D_MARGIN_DEG;
    let width = |g: f64| 1.0 / g.max(1e-9).sqrt();
    (0..=90usize)
        .map(|deg| {
            let window = &per_degree[deg.saturating_sub(margin)..=(deg + margin).min(90)];
            let sharpest = window.iter().map(|w| w.0).fold(0.0_f64, f64::max);
            let broadest = window.iter().map(|w| w.1).fold(f64::INFINITY, f64::min);
            (
                (sharpest > 0.0).then(|| width(sharpest)),
                broadest.is_finite().then(|| width(broadest)),
            )
        })
        .collect()
}

/// A lobe member whose energy is below this fraction of the channel's total may have its tails
/// cut (it changes the result by less than this fraction).
pub const SIGNIFICANT_ENERGY: f64 = 0.002;

/// Margin in θ_d around the normal's angle when sizing a neighbourhood, degrees.
pub const THETA_D_MARGIN_DEG: usize = 10;

/// What the evaluator decided, per lobe index (for reports and tests).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupStats {
    /// Pyramid level (0 = full resolution).
    pub level: usize,
    /// Neighbourhood radius, degrees (180 = whole sphere).
    pub radius_deg: f64,
    /// Table side, 0 when per pixel.
    pub res: usize,
    /// Points evaluated (nodes or pixels).
    pub points: usize,
}

/// Shades a DSBRDF image lobe by lobe (see the module docs). Returns radiance, non-finite
/// values replaced, and per-lobe statistics.
pub fn shade_image_dsbrdf(
    m: &Dsbrdf,
    env: &EnvMap,
    normals: &[[f32; 3]],
    mask: &[f32],
) -> (Vec<[f32; 3]>, usize, [GroupStats; LOBES]) {
    shade_with_params(m, env, normals, mask, &Params::default())
}

/// The accuracy knobs (defaults: the module constants).
#[derive(Clone, Copy, Debug)]
pub struct Params {
    /// See [`TEXEL_PER_WIDTH`].
    pub texel_per_width: f64,
    /// See [`TAIL_WIDTHS`].
    pub tail_widths: f64,
    /// See [`NODE_PER_WIDTH`].
    pub node_per_width: f64,
    /// Coarsest pyramid level used.
    pub max_level: usize,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            texel_per_width: TEXEL_PER_WIDTH,
            tail_widths: TAIL_WIDTHS,
            node_per_width: NODE_PER_WIDTH,
            max_level: LEVELS - 1,
        }
    }
}

/// [`shade_image_dsbrdf`] with explicit knobs.
pub fn shade_with_params(
    m: &Dsbrdf,
    env: &EnvMap,
    normals: &[[f32; 3]],
    mask: &[f32],
    params: &Params,
) -> (Vec<[f32; 3]>, usize, [GroupStats; LOBES]) {
    let levels = pyramid(env);
    let texel0 = PI / env.height() as f64;
    let coords = pixel_coords(normals, mask);
    let pixels = coords.iter().flatten().count();
    let mut out = vec![[0.0_f32; 3]; normals.len()];
    let mut stats = [GroupStats {
        level: 0,
        radius_deg: 0.0,
        res: 0,
        points: 0,
    }; LOBES];
    for (k, st) in stats.iter_mut().enumerate() {
        let w = lobe_width(m, k);
        let max_level = (levels.len() - 1).min(params.max_level);
        let texel = |l: usize| texel0 * (1 << l) as f64;
        // Per normal angle: the level the narrowest significant member needs, and the radius
        // the widest one needs.
        let mut level_at = Vec::with_capacity(91);
        let mut radius_at = Vec::with_capacity(91);
        for (narrow, wide) in member_widths(m, k) {
            let mut l = 0;
            match narrow {
                Some(narrow) => {
                    while l < max_level && texel(l + 1) <= params.texel_per_width * 2.0 * narrow {
                        l += 1;
                    }
                }
                None => l = max_level,
            }
            level_at.push(l);
            radius_at.push(match wide {
                Some(wide) => 2.0 * params.tail_widths * wide + texel(l),
                None => texel(l),
            });
        }
        let res = (PI / (params.node_per_width * w)).ceil() as usize + 1;
        let res = res.clamp(MIN_RES, MAX_RES);
        let table_of_lobe = LobeTable::new(m, k);
        let mut kappa: Vec<[Vec<f32>; 3]> = Vec::new();
        let mut gamma: Vec<[Vec<f32>; 3]> = Vec::new();
        for (l, lv) in levels.iter().enumerate() {
            if !level_at.contains(&l) {
                kappa.push(Default::default());
                gamma.push(Default::default());
                continue;
            }
            let (kc, gc) = table_of_lobe.texels(&lv.cos_d);
            kappa.push(kc);
            gamma.push(gc);
        }
        let level = *level_at.iter().min().unwrap_or(&0);
        let group = Group {
            radius: radius_at.clone(),
            level: level_at,
            kappa,
            gamma,
        };
        let radius = radius_at;
        // Table or per pixel?
        let table = needed_nodes(&coords, res, 1, 2);
        let use_table = (table.len() as f64) < MAX_NODES_PER_PIXEL * pixels as f64;
        *st = GroupStats {
            level,
            radius_deg: radius.iter().copied().fold(0.0, f64::max).min(PI).to_degrees(),
            res: if use_table { res } else { 0 },
            points: if use_table { table.len() } else { pixels },
        };
        let add: Vec<[f32; 3]> = if use_table {
            let values: Vec<[f32; 3]> = table
                .par_iter()
                .map(|&node| {
                    let (a, b) = node_coords(node, res);
                    eval_point(&levels, &group, table_normal(a, b))
                })
                .collect();
            let mut grid = vec![[0.0_f32; 3]; res * res];
            for (&node, v) in table.iter().zip(values) {
                grid[node] = v;
            }
            coords
                .par_iter()
                .map(|c| match c {
                    Some((a, b)) => bicubic(&grid, res, *a, *b),
                    None => [0.0; 3],
                })
                .collect()
        } else {
            normals
                .par_iter()
                .zip(&coords)
                .map(|(n, c)| {
                    if c.is_some() {
                        eval_point(&levels, &group, *n)
                    } else {
                        [0.0; 3]
                    }
                })
                .collect()
        };
        for (o, a) in out.iter_mut().zip(add) {
            for c in 0..3 {
                o[c] += a[c];
            }
        }
    }
    let bad = out.iter_mut().map(super::sanitize).sum();
    (out, bad, stats)
}

/// Node `i − 1 + d` clamped to the table.
fn clamp_node(i: usize, d: usize, r: usize) -> usize {
    (i + d).saturating_sub(1).min(r - 1)
}

/// Bicubic (Catmull–Rom) interpolation; its small overshoot next to sharp peaks is clamped at 0.
fn bicubic(grid: &[[f32; 3]], r: usize, a: f64, b: f64) -> [f32; 3] {
    let ((i, fa), (j, fb)) = (table_position(a, r), table_position(b, r));
    let (wa, wb) = (catmull_rom(fa), catmull_rom(fb));
    let mut out = [0.0_f32; 3];
    for (dj, wj) in wb.iter().enumerate() {
        let row = clamp_node(j, dj, r) * r;
        for (di, wi) in wa.iter().enumerate() {
            let v = grid[row + clamp_node(i, di, r)];
            for c in 0..3 {
                out[c] += wi * wj * v[c];
            }
        }
    }
    out.map(|v| v.max(0.0))
}

/// Column ranges (start, inclusive end) of row `j` within `radius` of direction (θ, φ).
fn row_columns(
    lv: &Level,
    j: usize,
    theta: f64,
    phi: f64,
    radius: f64,
    sin_radius: f64,
) -> Option<[(usize, usize); 2]> {
    let (t0, t1) = (PI * j as f64 / lv.h as f64, PI * (j + 1) as f64 / lv.h as f64);
    // Angular distance from θ to the band, and the band's smallest sin θ.
    let dist = if theta < t0 {
        t0 - theta
    } else if theta > t1 {
        theta - t1
    } else {
        0.0
    };
    if dist > radius {
        return None;
    }
    let all = Some([(0, lv.w - 1), (1, 0)]);
    let min_sin = lv.row_min_sin[j];
    if radius >= std::f64::consts::FRAC_PI_2 || min_sin <= sin_radius || min_sin < 1e-9 {
        return all;
    }
    let dphi = (sin_radius / min_sin).min(1.0).asin();
    let width = 2.0 * PI / lv.w as f64;
    let lo = ((phi - dphi) / width).floor() as i64 - 1;
    let hi = ((phi + dphi) / width).floor() as i64 + 1;
    if hi - lo + 1 >= lv.w as i64 {
        return all;
    }
    let w = lv.w as i64;
    let (a, b) = (lo.rem_euclid(w) as usize, hi.rem_euclid(w) as usize);
    Some(if a <= b {
        [(a, b), (1, 0)]
    } else {
        [(a, lv.w - 1), (0, b)]
    })
}

/// R_k(n) for one normal, with the AVX2 build of the same code where the CPU has it (no FMA, so
/// both builds give identical bits, as in the fast path).
fn eval_point(levels: &[Level], g: &Group, n: [f32; 3]) -> [f32; 3] {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { eval_point_avx2(levels, g, n) };
    }
    eval_point_portable(levels, g, n)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn eval_point_avx2(levels: &[Level], g: &Group, n: [f32; 3]) -> [f32; 3] {
    eval_point_portable(levels, g, n)
}

#[inline(always)]
fn eval_point_portable(levels: &[Level], g: &Group, n: [f32; 3]) -> [f32; 3] {
    let Some(nd) = shading_normal(n) else { return [0.0; 3] };
    let bucket = (nd.z.clamp(-1.0, 1.0).acos().to_degrees().round() as usize).min(90);
    let (radius, l) = (g.radius[bucket], g.level[bucket]);
    let lv = &levels[l];
    let n32 = [nd.x as f32, nd.y as f32, nd.z as f32];
    let n64 = [nd.x, nd.y, nd.z];
    // Mirror direction of ω_o = +z about n, in the map's (θ, φ).
    let r = nd * (2.0 * nd.z) - DVec3::Z;
    let theta = r.y.clamp(-1.0, 1.0).acos();
    let mut phi = r.x.atan2(-r.z);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let mut acc = [[0.0_f32; LANES]; 3];
    let sin_radius = radius.min(std::f64::consts::FRAC_PI_2).sin();
    let row = |t: f64| ((t / PI) * lv.h as f64).floor().clamp(0.0, (lv.h - 1) as f64) as usize;
    for j in row(theta - radius)..=row(theta + radius) {
        let Some(ranges) = row_columns(lv, j, theta, phi, radius, sin_radius) else {
            continue;
        };
        for (c0, c1) in ranges {
            if c0 > c1 {
                continue;
            }
            let mut col = c0;
            while col <= c1 {
                let base = j * lv.w + col;
                let live = (c1 + 1 - col).min(LANES);
                chunk(lv, &g.kappa[l], &g.gamma[l], n32, n64, base, live, &mut acc);
                col += LANES;
            }
        }
    }
    acc.map(|a| ((a[0] + a[4]) + (a[2] + a[6])) + ((a[1] + a[5]) + (a[3] + a[7])))
}

#[inline(always)]
fn lanes(v: &[f32], b: usize) -> &[f32; LANES] {
    v[b..b + LANES].try_into().expect("level arrays are padded by one lane")
}

#[inline(always)]
fn lanes64(v: &[f64], b: usize) -> &[f64; LANES] {
    v[b..b + LANES].try_into().expect("level arrays are padded by one lane")
}

/// Adds eight texels from `base` (the first `live` of them) to `acc`. Fixed-size lanes and
/// branch-free arithmetic, so the loops vectorise like the fast path's.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn chunk(
    lv: &Level,
    kappa: &[Vec<f32>; 3],
    gamma: &[Vec<f32>; 3],
    n: [f32; 3],
    n64: [f64; 3],
    base: usize,
    live: usize,
    acc: &mut [[f32; LANES]; 3],
) {
    let (dx, dy, dz) = (
        lanes(&lv.dir[0], base),
        lanes(&lv.dir[1], base),
        lanes(&lv.dir[2], base),
    );
    let mut wt = [0.0_f32; LANES];
    for l in 0..LANES {
        let ci = n[0] * dx[l] + n[1] * dy[l] + n[2] * dz[l];
        let on = ci > 0.0 && l < live;
        wt[l] = if on { ci } else { 0.0 };
    }
    if wt.iter().all(|&w| w == 0.0) {
        return;
    }
    let (hx, hy, hz) = (
        lanes64(&lv.half[0], base),
        lanes64(&lv.half[1], base),
        lanes64(&lv.half[2], base),
    );
    let (mut c32, mut omc) = ([0.0_f32; LANES], [0.0_f32; LANES]);
    for l in 0..LANES {
        let d = n64[0] * hx[l] + n64[1] * hy[l] + n64[2] * hz[l];
        let d = if d > 0.0 { d } else { 0.0 };
        c32[l] = d as f32;
        omc[l] = (1.0 - d) as f32;
    }
    let mut lc = [0.0_f32; LANES];
    for l in 0..LANES {
        lc[l] = fastmath::ln_1m(omc[l]);
    }
    for (c, acc) in acc.iter_mut().enumerate() {
        let (kap, gam, w) = (
            lanes(&kappa[c], base),
            lanes(&gamma[c], base),
            lanes(&lv.weight[c], base),
        );
        let mut rho = [0.0_f32; LANES];
        for l in 0..LANES {
            let p = fastmath::exp(gam[l] * lc[l]);
            let p = if c32[l] > 0.0 { p } else { 0.0 };
            rho[l] = fastmath::expm1(kap[l] * p);
        }
        for l in 0..LANES {
            acc[l] += wt[l] * w[l] * rho[l];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::BrdfModel;
    use crate::camera::unit_sphere_normals;
    use crate::shading::{Quality, make_shader, shade_image};

    fn rel_rmse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
        let (mut e, mut s) = (0.0_f64, 0.0_f64);
        for (x, y) in a.iter().zip(b) {
            for c in 0..3 {
                e += ((x[c] - y[c]) as f64).powi(2);
                s += (y[c] as f64).powi(2);
            }
        }
        (e / s).sqrt()
    }

    #[test]
    fn the_pyramid_keeps_power_and_the_direction_of_a_sun() {
        let sun = DVec3::new(0.3, 0.7, -0.4).normalize();
        let env = EnvMap::from_fn(64, |d| if d.dot(sun) > 0.9995 { [5e4; 3] } else { [0.2, 0.3, 0.5] });
        let lv = pyramid(&env);
        assert_eq!(lv.len(), LEVELS);
        let total = |l: &Level| (0..l.w * l.h).map(|t| l.weight[1][t] as f64).sum::<f64>();
        for l in &lv[1..] {
            assert!((total(l) - total(&lv[0])).abs() < 1e-4 * total(&lv[0]));
        }
        // The brightest coarse texel points (almost) at the sun.
        let top = &lv[LEVELS - 1];
        let k = (0..top.w * top.h)
            .max_by(|&a, &b| top.weight[0][a].total_cmp(&top.weight[0][b]))
            .unwrap();
        let d = DVec3::new(top.dir[0][k] as f64, top.dir[1][k] as f64, top.dir[2][k] as f64);
        assert!(d.dot(sun) > 0.999, "{}", d.dot(sun));
    }

    #[test]
    fn lobe_adaptive_shading_matches_the_fast_path() {
        let sun = DVec3::new(0.4, 0.6, 0.5).normalize();
        let env = EnvMap::from_fn(64, |d| {
            if d.dot(sun) > 0.9995 {
                [3e4, 2.8e4, 2.5e4]
            } else if d.y > 0.0 {
                [0.3, 0.5, 1.0]
            } else {
                [0.2, 0.15, 0.1]
            }
        });
        let (normals, mask) = unit_sphere_normals(160);
        let red = Dsbrdf::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../assets/materials/red_plastic.dsbrdf.json"
        )))
        .unwrap();
        for m in [red, Dsbrdf::near_lambertian([0.6, 0.4, 0.2])] {
            let (fast, bad, stats) = shade_image_dsbrdf(&m, &env, &normals, &mask);
            assert_eq!(bad, 0);
            let model = BrdfModel::Dsbrdf(Box::new(m.clone()));
            let shader = make_shader(&model, &env, Quality::Fast);
            let (reference, _) = shade_image(shader.as_ref(), &normals, &mask, None);
            let e = rel_rmse(&fast, &reference);
            assert!(e < 0.01, "rel RMSE {e}, {stats:?}");
        }
    }

    #[test]
    fn hard_normals_and_extreme_lobes_stay_finite() {
        use crate::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, KNOTS, PARAMS};
        let env = EnvMap::from_fn(16, |d| if d.y > 0.99 { [1e6; 3] } else { [1e-3; 3] });
        let normals = vec![
            [0.0, 0.0, 0.0],
            [f32::NAN, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.3, -0.2, -0.5],
            [0.0, 0.0, 1.0],
            [1e-9, 1e-9, 1e-9],
        ];
        let mask = vec![1.0; normals.len()];
        for (kappa, gamma) in [
            (KAPPA_RANGE.1, GAMMA_RANGE.1),
            (KAPPA_RANGE.1, GAMMA_RANGE.0),
            (KAPPA_RANGE.0, GAMMA_RANGE.1),
        ] {
            let mut p = [0.0; PARAMS];
            for (i, v) in p.iter_mut().enumerate() {
                *v = if (i / KNOTS).is_multiple_of(2) { kappa } else { gamma };
            }
            let m = Dsbrdf::from_params(&p).unwrap();
            let (out, _, _) = shade_image_dsbrdf(&m, &env, &normals, &mask);
            for (n, v) in normals.iter().zip(&out) {
                assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{n:?} → {v:?}");
            }
            // No usable normal, no light.
            assert_eq!(out[0], [0.0; 3]);
            assert_eq!(out[1], [0.0; 3]);
            assert_eq!(out[2], [0.0; 3]);
        }
    }

    #[test]
    fn neighbourhoods_cover_the_lobe_and_wrap_around() {
        let env = EnvMap::constant(64, [1.0; 3]);
        let lv = &pyramid(&env)[0];
        // Near φ = 0 the range wraps to the end of the row.
        let r = row_columns(lv, 32, PI / 2.0, 0.01, 0.1, 0.1f64.sin()).unwrap();
        assert_eq!(r[0].1, lv.w - 1);
        assert_eq!(r[1].0, 0);
        // Far rows are skipped; polar rows take everything.
        assert!(row_columns(lv, 0, PI / 2.0, 1.0, 0.1, 0.1f64.sin()).is_none());
        assert_eq!(
            row_columns(lv, 0, 0.05, 1.0, 0.2, 0.2f64.sin()).unwrap()[0],
            (0, lv.w - 1)
        );
    }
}

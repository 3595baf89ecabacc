//! The fast `f32` implementation of Eq. 2.
//!
//! ω_o = +z is the same for every pixel, so everything that depends only on ω_i is computed
//! once per texel: the half vector h, θ_d, the Fresnel term and the DSBRDF's κ(θ_d), γ(θ_d),
//! folded together with L(ω_i)·dω_i. Per (pixel, texel) pair only n·ω_i, n·h and the lobe
//! shapes remain. Data is stored structure-of-arrays, padded to 8 lanes, and the loops work on
//! 8 texels at a time with branch-free arithmetic, so they vectorise. On x86-64 the same code
//! is also compiled with AVX2 and chosen at run time; FMA is not enabled, so both versions
//! perform the same IEEE operations in the same order and give identical bits.

use super::{Shader, shading_normal};
use crate::brdf::{BrdfModel, Ggx};
use crate::envmap::{EnvMap, texel_direction, texel_solid_angle};
use crate::fastmath;
use glam::DVec3;
use std::f64::consts::PI;

const LANES: usize = 8;

/// ln of the lobe value cos^γ θ_h below which a DSBRDF lobe is skipped for a block of texels.
const SKIP_LOG_LOBE: f32 = -30.0;

/// Per-texel data of a GGX lobe: half vector and L·dω·F/4 per channel.
struct GgxTexels {
    a2: f32,
    h: HalfVectors,
    w: [Vec<f32>; 3],
}

/// Half vectors in `f64`: near a sharp lobe's peak, 1 − cos θ_h is ~1e-5 and an `f32` dot
/// product would leave it with only two significant digits, which γ up to 1e4 (or α² down to
/// 1e-6) amplifies into percent errors. The dot product is therefore taken in `f64` and only
/// 1 − cos θ_h, already free of cancellation, goes back to `f32`.
struct HalfVectors {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl HalfVectors {
    /// (cos θ_h clamped to ≥ 0, 1 − cos θ_h clamped to [0, 1]) for 8 texels.
    #[inline(always)]
    fn cos_h(&self, n: [f64; 3], b: usize) -> ([f32; LANES], [f32; LANES]) {
        let (x, y, z) = (lanes64(&self.x, b), lanes64(&self.y, b), lanes64(&self.z, b));
        let (mut c, mut omc) = ([0.0; LANES], [0.0; LANES]);
        for l in 0..LANES {
            let d = n[0] * x[l] + n[1] * y[l] + n[2] * z[l];
            let d = if d > 0.0 { d } else { 0.0 };
            c[l] = d as f32;
            omc[l] = (1.0 - d) as f32;
        }
        (c, omc)
    }
}

/// Per-texel data of a DSBRDF: half vector, L·dω per channel and κ, γ per (channel, lobe).
struct DsbrdfTexels {
    h: HalfVectors,
    w: [Vec<f32>; 3],
    kappa: [Vec<f32>; 9],
    gamma: [Vec<f32>; 9],
}

// One `Kernel` exists per shader, so the variants' size difference costs nothing.
#[allow(clippy::large_enum_variant)]
enum Kernel {
    /// Lambert and/or GGX parts (Lambert, GGX and plastic).
    Microfacet {
        diffuse: Option<[Vec<f32>; 3]>,
        spec: Option<GgxTexels>,
    },
    Dsbrdf(DsbrdfTexels),
}

/// Fast shader for one analytic BRDF under one environment map.
pub struct FastShader {
    dirs: Vec<[f32; 3]>,
    dx: Vec<f32>,
    dy: Vec<f32>,
    dz: Vec<f32>,
    kernel: Kernel,
    avx2: bool,
}

/// One retained texel: direction, half vector, θ_d and L·dω.
struct Texel {
    d: DVec3,
    h: DVec3,
    cos_d: f64,
    lsa: [f64; 3],
}

fn padded(values: impl Iterator<Item = f64>, len: usize) -> Vec<f32> {
    let mut v: Vec<f32> = values.map(|x| x as f32).collect();
    v.resize(len.div_ceil(LANES) * LANES, 0.0);
    v
}

fn half_vectors(texels: &[Texel]) -> HalfVectors {
    let col = |f: fn(&Texel) -> f64| {
        let mut v: Vec<f64> = texels.iter().map(f).collect();
        v.resize(texels.len().div_ceil(LANES) * LANES, 0.0);
        v
    };
    HalfVectors {
        x: col(|t| t.h.x),
        y: col(|t| t.h.y),
        z: col(|t| t.h.z),
    }
}

impl FastShader {
    /// Precomputes the per-texel data. Texels of zero radiance are dropped, and so is a texel
    /// whose direction is exactly −z (it cannot light a surface the camera sees). `None` for a
    /// measured BRDF, which has no per-texel factorisation.
    pub fn new(brdf: &BrdfModel, env: &EnvMap) -> Option<Self> {
        let (w, h) = (env.width(), env.height());
        let mut texels = Vec::new();
        for j in 0..h {
            let sa = texel_solid_angle(j, w, h);
            for i in 0..w {
                let l = env.texel(i, j);
                if l == [0.0; 3] {
                    continue;
                }
                let d = texel_direction(i, j, w, h);
                let sum = d + DVec3::Z;
                if sum.length() < 1e-9 {
                    continue;
                }
                let hv = sum.normalize();
                texels.push(Texel {
                    d,
                    h: hv,
                    cos_d: d.dot(hv).clamp(0.0, 1.0),
                    lsa: l.map(|v| v as f64 * sa),
                });
            }
        }
        let n = texels.len();
        let col = |f: &dyn Fn(&Texel) -> f64| padded(texels.iter().map(f), n);
        let ggx = |g: &Ggx| {
            let f: Vec<[f64; 3]> = texels.iter().map(|t| g.fresnel.eval(t.cos_d)).collect();
            GgxTexels {
                a2: (g.alpha * g.alpha) as f32,
                h: half_vectors(&texels),
                w: [0, 1, 2].map(|c| padded(texels.iter().zip(&f).map(|(t, f)| t.lsa[c] * f[c] * 0.25), n)),
            }
        };
        let diffuse = |albedo: [f64; 3]| [0, 1, 2].map(|c| col(&|t| t.lsa[c] * albedo[c] / PI));
        let kernel = match brdf {
            BrdfModel::Lambert(b) => Kernel::Microfacet {
                diffuse: Some(diffuse(b.albedo)),
                spec: None,
            },
            BrdfModel::Ggx(g) => Kernel::Microfacet {
                diffuse: None,
                spec: Some(ggx(g)),
            },
            BrdfModel::Plastic(p) => Kernel::Microfacet {
                diffuse: Some(diffuse(p.base.albedo)),
                spec: Some(ggx(&p.coat)),
            },
            BrdfModel::Dsbrdf(m) => {
                let lobes: Vec<_> = texels.iter().map(|t| m.lobes_at(t.cos_d.acos())).collect();
                let lobe_col = |ck: usize, kappa: bool| {
                    padded(
                        lobes.iter().map(|l| {
                            let (k, g) = l[ck / 3][ck % 3];
                            if kappa { k } else { g }
                        }),
                        n,
                    )
                };
                Kernel::Dsbrdf(DsbrdfTexels {
                    h: half_vectors(&texels),
                    w: [0, 1, 2].map(|c| col(&|t| t.lsa[c])),
                    kappa: std::array::from_fn(|ck| lobe_col(ck, true)),
                    gamma: std::array::from_fn(|ck| lobe_col(ck, false)),
                })
            }
            BrdfModel::Measured(_) | BrdfModel::Neural(_) => return None,
        };
        #[cfg(target_arch = "x86_64")]
        let avx2 = std::is_x86_feature_detected!("avx2");
        #[cfg(not(target_arch = "x86_64"))]
        let avx2 = false;
        Some(Self {
            dirs: texels
                .iter()
                .map(|t| [t.d.x as f32, t.d.y as f32, t.d.z as f32])
                .collect(),
            dx: col(&|t| t.d.x),
            dy: col(&|t| t.d.y),
            dz: col(&|t| t.d.z),
            kernel,
            avx2,
        })
    }

    /// Forces the portable (non-AVX2) code path; for tests that compare the two.
    pub fn without_simd_dispatch(mut self) -> Self {
        self.avx2 = false;
        self
    }

    /// Number of texels summed over per pixel.
    pub fn texel_count(&self) -> usize {
        self.dirs.len()
    }

    /// For stored normal `n` and a visibility slice: how many blocks of eight texels hold at
    /// least one open texel in front of the surface, and how many at least one blocked one. The
    /// cost of shading the open or the blocked light is in proportion (other blocks are skipped).
    pub fn blocks_in_front(&self, n: [f32; 3], visibility: &[f32]) -> (usize, usize) {
        let Some(n) = shading_normal(n) else {
            return (0, 0);
        };
        let n = [n.x as f32, n.y as f32, n.z as f32];
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the running CPU reports AVX2.
            return unsafe { self.blocks_in_front_avx2(n, visibility) };
        }
        self.blocks_in_front_portable(n, visibility)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn blocks_in_front_avx2(&self, n: [f32; 3], visibility: &[f32]) -> (usize, usize) {
        self.blocks_in_front_portable(n, visibility)
    }

    #[inline(always)]
    fn blocks_in_front_portable(&self, n: [f32; 3], visibility: &[f32]) -> (usize, usize) {
        let (mut open, mut blocked) = (0, 0);
        for chunk in 0..self.chunks() {
            let b = chunk * LANES;
            let (ci, v) = (self.cos_i(n, b), vis_chunk(visibility, b, self.dirs.len()));
            // Padding texels have a zero direction, so they are never in front.
            let (mut o, mut k) = (0.0_f32, 0.0_f32);
            for l in 0..LANES {
                let front = if ci[l] > 0.0 { 1.0 } else { 0.0 };
                o += front * v[l];
                k += front * (1.0 - v[l]);
            }
            open += usize::from(o > 0.0);
            blocked += usize::from(k > 0.0);
        }
        (open, blocked)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn shade_avx2(&self, n: [f64; 3], vis: Option<&[f32]>) -> [f32; 3] {
        self.shade_portable(n, vis)
    }

    #[inline(always)]
    fn shade_portable(&self, n64: [f64; 3], vis: Option<&[f32]>) -> [f32; 3] {
        let n = n64.map(|v| v as f32);
        // Every combination is its own monomorphised loop, so no option is tested per texel.
        let empty: &[Vec<f32>; 3] = &[Vec::new(), Vec::new(), Vec::new()];
        match (&self.kernel, vis) {
            (
                Kernel::Microfacet {
                    diffuse: Some(d),
                    spec: None,
                },
                None,
            ) => self.microfacet::<true, false, false>(n, n64, &[], d, None),
            (
                Kernel::Microfacet {
                    diffuse: Some(d),
                    spec: None,
                },
                Some(v),
            ) => self.microfacet::<true, false, true>(n, n64, v, d, None),
            (
                Kernel::Microfacet {
                    diffuse: None,
                    spec: Some(s),
                },
                None,
            ) => self.microfacet::<false, true, false>(n, n64, &[], empty, Some(s)),
            (
                Kernel::Microfacet {
                    diffuse: None,
                    spec: Some(s),
                },
                Some(v),
            ) => self.microfacet::<false, true, true>(n, n64, v, empty, Some(s)),
            (
                Kernel::Microfacet {
                    diffuse: Some(d),
                    spec: Some(s),
                },
                None,
            ) => self.microfacet::<true, true, false>(n, n64, &[], d, Some(s)),
            (
                Kernel::Microfacet {
                    diffuse: Some(d),
                    spec: Some(s),
                },
                Some(v),
            ) => self.microfacet::<true, true, true>(n, n64, v, d, Some(s)),
            (
                Kernel::Microfacet {
                    diffuse: None,
                    spec: None,
                },
                _,
            ) => [0.0; 3],
            (Kernel::Dsbrdf(k), None) => self.dsbrdf::<false>(n, n64, &[], k),
            (Kernel::Dsbrdf(k), Some(v)) => self.dsbrdf::<true>(n, n64, v, k),
        }
    }

    #[inline(always)]
    fn chunks(&self) -> usize {
        self.dx.len() / LANES
    }

    #[inline(always)]
    fn cos_i(&self, n: [f32; 3], b: usize) -> [f32; LANES] {
        let (x, y, z) = (lanes(&self.dx, b), lanes(&self.dy, b), lanes(&self.dz, b));
        let mut c = [0.0; LANES];
        for l in 0..LANES {
            c[l] = n[0] * x[l] + n[1] * y[l] + n[2] * z[l];
        }
        c
    }

    #[inline(always)]
    fn microfacet<const DIFFUSE: bool, const SPEC: bool, const VIS: bool>(
        &self,
        n: [f32; 3],
        n64: [f64; 3],
        vis: &[f32],
        diffuse: &[Vec<f32>; 3],
        spec: Option<&GgxTexels>,
    ) -> [f32; 3] {
        let mut acc = [[0.0_f32; LANES]; 3];
        let a2 = spec.map_or(1.0, |s| s.a2);
        let a2_pi = a2 / std::f32::consts::PI;
        let g_over_cos = |c: f32| 2.0 / (c + (a2 + (1.0 - a2) * c * c).sqrt());
        let go = g_over_cos(n[2]);
        for chunk in 0..self.chunks() {
            let b = chunk * LANES;
            let mut ci = self.cos_i(n, b);
            let v = if VIS {
                vis_chunk(vis, b, self.dirs.len())
            } else {
                [1.0; LANES]
            };
            for l in 0..LANES {
                ci[l] = if ci[l] > 0.0 { ci[l] * v[l] } else { 0.0 };
            }
            if ci.iter().all(|&c| c == 0.0) {
                continue;
            }
            if DIFFUSE {
                for (acc, w) in acc.iter_mut().zip(diffuse) {
                    let w = lanes(w, b);
                    for l in 0..LANES {
                        acc[l] += ci[l] * w[l];
                    }
                }
            }
            if let (true, Some(s)) = (SPEC, spec) {
                let (ch, omc) = s.h.cos_h(n64, b);
                let mut k = [0.0; LANES];
                for l in 0..LANES {
                    // cos²θ_h (α² − 1) + 1 = α² cos²θ_h + (1 − cos θ_h)(1 + cos θ_h), without
                    // cancellation near the peak.
                    let t = a2 * ch[l] * ch[l] + omc[l] * (1.0 + ch[l]);
                    let d = a2_pi / (t * t);
                    k[l] = d * g_over_cos(ci[l]) * go * ci[l];
                }
                for (acc, w) in acc.iter_mut().zip(&s.w) {
                    let w = lanes(w, b);
                    for l in 0..LANES {
                        acc[l] += k[l] * w[l];
                    }
                }
            }
        }
        acc.map(reduce)
    }

    #[inline(always)]
    fn dsbrdf<const VIS: bool>(&self, n: [f32; 3], n64: [f64; 3], vis: &[f32], s: &DsbrdfTexels) -> [f32; 3] {
        let mut acc = [[0.0_f32; LANES]; 3];
        for chunk in 0..self.chunks() {
            let b = chunk * LANES;
            let v = if VIS {
                vis_chunk(vis, b, self.dirs.len())
            } else {
                [1.0; LANES]
            };
            let ci = self.cos_i(n, b);
            let mut wt = [0.0; LANES];
            for l in 0..LANES {
                wt[l] = if ci[l] > 0.0 { ci[l] * v[l] } else { 0.0 };
            }
            // Eight texels behind the surface (or shadowed) add exactly nothing: tested before
            // the half vectors' f64 dot product and the logarithm.
            if wt.iter().all(|&w| w == 0.0) {
                continue;
            }
            let (ch, omc) = s.h.cos_h(n64, b);
            let mut lc = [0.0; LANES];
            for l in 0..LANES {
                lc[l] = fastmath::ln_1m(omc[l]);
            }
            for (c, acc) in acc.iter_mut().enumerate() {
                let mut rho = [0.0_f32; LANES];
                for k in 0..3 {
                    let (kap, gam) = (lanes(&s.kappa[c * 3 + k], b), lanes(&s.gamma[c * 3 + k], b));
                    // A lobe whose cos^γ is below e^−30 on all eight texels contributes at most
                    // κ·e^−30 ≤ 2e-12 of L·dω: skip its exp and expm1 (the dominant cost; most
                    // texels lie far outside a sharp lobe).
                    let mut top = f32::MIN;
                    for l in 0..LANES {
                        top = top.max(gam[l] * lc[l]);
                    }
                    if top < SKIP_LOG_LOBE {
                        continue;
                    }
                    let mut x = [0.0_f32; LANES];
                    for l in 0..LANES {
                        // cos^γ, computed unconditionally (so the loop stays branch-free), then
                        // zeroed at cos θ_h = 0 where ln's floor would give a wrong limit.
                        let p = fastmath::exp(gam[l] * lc[l]);
                        let p = if ch[l] > 0.0 { p } else { 0.0 };
                        x[l] = kap[l] * p;
                    }
                    // expm1 has two branches; where all eight lanes take the same one, only that
                    // one is evaluated (identical bits either way).
                    let series = x.map(fastmath::expm1_uses_series);
                    if series.iter().all(|&s| s) {
                        for l in 0..LANES {
                            rho[l] += fastmath::expm1_series(x[l]);
                        }
                    } else if series.iter().all(|&s| !s) {
                        for l in 0..LANES {
                            rho[l] += fastmath::exp(x[l]) - 1.0;
                        }
                    } else {
                        for l in 0..LANES {
                            rho[l] += fastmath::expm1(x[l]);
                        }
                    }
                }
                let w = lanes(&s.w[c], b);
                for l in 0..LANES {
                    acc[l] += wt[l] * w[l] * rho[l];
                }
            }
        }
        acc.map(reduce)
    }
}

/// The 8 `f64` lanes of `v` starting at `b`.
#[inline(always)]
fn lanes64(v: &[f64], b: usize) -> &[f64; LANES] {
    v[b..b + LANES]
        .try_into()
        .expect("texel arrays are padded to whole lanes")
}

/// The 8 lanes of `v` starting at `b` (every array is padded to a multiple of 8).
#[inline(always)]
fn lanes(v: &[f32], b: usize) -> &[f32; LANES] {
    v[b..b + LANES]
        .try_into()
        .expect("texel arrays are padded to whole lanes")
}

/// Visibility of 8 texels from `b`; texels past `n` (padding) are 0.
#[inline(always)]
fn vis_chunk(v: &[f32], b: usize, n: usize) -> [f32; LANES] {
    if b + LANES <= n {
        *lanes(v, b)
    } else {
        std::array::from_fn(|l| if b + l < n { v[b + l] } else { 0.0 })
    }
}

/// Pairwise lane sum in a fixed order (deterministic).
#[inline(always)]
fn reduce(a: [f32; LANES]) -> f32 {
    ((a[0] + a[4]) + (a[2] + a[6])) + ((a[1] + a[5]) + (a[3] + a[7]))
}

impl Shader for FastShader {
    fn light_dirs(&self) -> &[[f32; 3]] {
        &self.dirs
    }

    fn shade(&self, n: [f32; 3], visibility: Option<&[f32]>) -> [f32; 3] {
        let Some(n) = shading_normal(n) else {
            return [0.0; 3];
        };
        let n = [n.x, n.y, n.z];
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: `avx2` is set only when the running CPU reports AVX2.
            return unsafe { self.shade_avx2(n, visibility) };
        }
        self.shade_portable(n, visibility)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::{Dsbrdf, Lambert, Plastic};

    #[test]
    fn zero_radiance_texels_are_dropped_and_padding_is_inert() {
        let env = EnvMap::from_fn(8, |d| if d.y > 0.0 { [1.0; 3] } else { [0.0; 3] });
        let s = FastShader::new(&BrdfModel::Lambert(Lambert { albedo: [1.0; 3] }), &env).unwrap();
        assert_eq!(s.texel_count(), 8 * 16 / 2);
        let vis = vec![1.0; s.texel_count()];
        assert_eq!(s.shade([0.0, 1.0, 1.0], None), s.shade([0.0, 1.0, 1.0], Some(&vis)));
        let dark = vec![0.0; s.texel_count()];
        assert_eq!(s.shade([0.0, 1.0, 1.0], Some(&dark)), [0.0; 3]);
    }

    #[test]
    fn simd_dispatch_gives_identical_bits() {
        let env = EnvMap::from_fn(16, |d| [(1.0 + d.x) as f32, (2.0 + d.y) as f32, 0.3]);
        for brdf in [
            BrdfModel::Plastic(Plastic::new(0.3, [0.2, 0.5, 0.7])),
            BrdfModel::Dsbrdf(Box::new(Dsbrdf::isotropic_in_theta_d(
                [[(0.1, 0.01), (1.0, 30.0), (4.0, 900.0)]; 3],
            ))),
        ] {
            let a = FastShader::new(&brdf, &env).unwrap();
            let b = FastShader::new(&brdf, &env).unwrap().without_simd_dispatch();
            for n in [[0.0, 0.0, 1.0], [0.3, -0.2, 0.5], [0.9, 0.1, 0.01]] {
                let (x, y) = (a.shade(n, None), b.shade(n, None));
                assert_eq!(x.map(f32::to_bits), y.map(f32::to_bits));
                // With shadows (every third texel blocked) too.
                let vis: Vec<f32> = (0..a.texel_count())
                    .map(|t| if t % 3 == 0 { 0.0 } else { 1.0 })
                    .collect();
                let (x, y) = (a.shade(n, Some(&vis)), b.shade(n, Some(&vis)));
                assert_eq!(x.map(f32::to_bits), y.map(f32::to_bits));
            }
        }
    }

    /// The block counts that choose between summing the blocked and the open light, against a
    /// count texel by texel, for normals from head-on to grazing, hard normals and patterns from
    /// all open to all blocked; the SIMD and portable builds agree.
    #[test]
    fn blocks_in_front_counts_blocks_with_an_open_or_a_blocked_texel_in_front() {
        let env = EnvMap::from_fn(16, |d| [(1.0 + d.x) as f32, 0.5, 0.3]);
        let s = FastShader::new(&BrdfModel::Lambert(Lambert { albedo: [0.5; 3] }), &env).unwrap();
        let portable = FastShader::new(&BrdfModel::Lambert(Lambert { albedo: [0.5; 3] }), &env)
            .unwrap()
            .without_simd_dispatch();
        let n_tex = s.texel_count();
        let patterns: Vec<Vec<f32>> = vec![
            vec![1.0; n_tex],
            vec![0.0; n_tex],
            (0..n_tex).map(|t| if t % 5 == 0 { 0.0 } else { 1.0 }).collect(),
            (0..n_tex).map(|t| if (t / 8) % 2 == 0 { 0.0 } else { 1.0 }).collect(),
            s.dirs.iter().map(|d| if d[0] > 0.3 { 0.0 } else { 1.0 }).collect(),
        ];
        let normals = [
            [0.0, 0.0, 1.0],
            [0.6, 0.3, 0.2],
            [-0.9, 0.1, 0.01],
            [0.0, 1.0, -0.5],
            [0.0, 0.0, 0.0],
            [f32::NAN, 0.0, 1.0],
        ];
        for n in normals {
            for vis in &patterns {
                let expected = match shading_normal(n) {
                    None => (0, 0),
                    Some(m) => {
                        let m = [m.x as f32, m.y as f32, m.z as f32];
                        let (mut open, mut blocked) = (0, 0);
                        for block in 0..n_tex.div_ceil(LANES) {
                            let texels = block * LANES..((block + 1) * LANES).min(n_tex);
                            let front = |t: usize| s.dx[t] * m[0] + s.dy[t] * m[1] + s.dz[t] * m[2] > 0.0;
                            open += usize::from(texels.clone().any(|t| front(t) && vis[t] > 0.0));
                            blocked += usize::from(texels.clone().any(|t| front(t) && vis[t] == 0.0));
                        }
                        (open, blocked)
                    }
                };
                assert_eq!(s.blocks_in_front(n, vis), expected, "n {n:?}");
                assert_eq!(portable.blocks_in_front(n, vis), expected, "n {n:?}");
            }
        }
        let all_open = s.blocks_in_front([0.0, 0.0, 1.0], &patterns[0]);
        assert!(all_open.0 > 0 && all_open.1 == 0);
        let all_blocked = s.blocks_in_front([0.0, 0.0, 1.0], &patterns[1]);
        assert!(all_blocked.0 == 0 && all_blocked.1 > 0);
    }
}

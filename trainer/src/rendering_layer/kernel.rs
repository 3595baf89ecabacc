//! The fused kernel of the rendering layer: Eq. 2 and its vector–Jacobian product for a tile of
//! pixels that share one material, over all texels.
//!
//! Loops run texel-group-outer, pixel-inner: one group's constants (directions, half vectors,
//! L·dω and 18 lobe parameters) stay in L1 while every pixel of the tile uses them, and in the
//! backward pass the group's gradient accumulators stay in registers instead of streaming
//! 21 × T floats per pixel. The forward pass then runs lobe by lobe over the group's front
//! pixels (docs/PERFORMANCE.md, "The rendering layer's forward pass: lobe by lobe"). Lane
//! arithmetic goes through [`F8`] (AVX2 with FMA where the CPU has it, plain arrays otherwise).
//! Groups of eight texels behind every pixel's surface, and lobes whose cos^γ is below e^−30 on a
//! whole group, are skipped (they add less than κ·e^−30 ≤ 3e-12 of L·dω to a value or a
//! gradient; κ ≤ 29.3 at the normalised parameters' clamp of ±1).

use super::material::{MEMBERS, MaterialTexels};
#[cfg(target_arch = "x86_64")]
use super::simd::Avx2;
use super::simd::{EXPM1_TINY, F8, Portable, all_small, exp_fast, expm1, expm1_taylor, expm1_tiny, ln_1m};
use super::texels::{LANES, TexelTable};

/// `[e(0), e(1), …]` without a closure: `std::array::from_fn`'s closure is not compiled with the
/// kernel's target features, so the AVX2 intrinsics inside it were calls, not instructions
/// (a fifth of Eq. 6's time in `perf`).
macro_rules! unrolled {
    ([$($n:literal),*], |$i:ident| $e:expr) => {
        [$({
            let $i = $n;
            $e
        }),*]
    };
}

/// A lobe whose γ·ln cos θ_h is below this on all lanes is skipped.
const SKIP_EXPONENT: f32 = -30.0;

/// Whether this CPU runs the AVX2 + FMA kernel.
pub fn simd_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A normal the layer can shade: finite and facing the camera (n_z > 0). Others render black and
/// receive no gradient.
#[inline(always)]
pub fn usable(n: [f32; 3]) -> bool {
    n[2] > 0.0 && n.iter().all(|v| v.is_finite())
}

/// Geometric terms of one pixel against the eight texels at `b`: the front mask, clamped
/// cos θ_i, ln cos θ_h and cos θ_h. 1 − cos θ_h is computed as ½|n − h|², exact near the lobe
/// peak where 1 − n·h cancels (and the definition the gradient differentiates).
#[inline(always)]
fn geometry<V: F8>(n: [V; 3], tex: &TexelTable, b: usize) -> (V::M, V, V, V) {
    let w = [
        V::load(&tex.w[0][b..]),
        V::load(&tex.w[1][b..]),
        V::load(&tex.w[2][b..]),
    ];
    let ci = n[0].mul_add(w[0], n[1].mul_add(w[1], n[2].mul(w[2])));
    let d: [V; 3] = unrolled!([0, 1, 2], |a| n[a].sub(V::load(&tex.h[a][b..])));
    let o = d[0]
        .mul_add(d[0], d[1].mul_add(d[1], d[2].mul(d[2])))
        .mul(V::splat(0.5));
    let front = V::and(V::splat(0.0).lt(ci), o.lt(V::splat(1.0)));
    let wt = V::select(front, ci, V::splat(0.0));
    // Back lanes get 1 − cos θ_h = 1, whose log is the floor −103.3: cos^γ = 0 there.
    let omc = V::select(front, o, V::splat(1.0));
    (front, wt, ln_1m(omc), V::splat(1.0).sub(o))
}

/// Whether lobe `gam` is negligible on the whole group: γ·ln cos θ_h < −30 on every lane.
#[inline(always)]
fn skip<V: F8>(gam: V, lc: V) -> bool {
    !V::any(gam.mul(lc).ge(V::splat(SKIP_EXPONENT)))
}

fn splat3<V: F8>(n: [f32; 3]) -> [V; 3] {
    n.map(V::splat)
}

/// Radiance of every pixel of a tile (`normals[i]`, usable ones only) into `out[i]`.
/// `lsa[c]` is L_c·dω per texel.
pub fn forward_tile(
    normals: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    out: &mut [[f32; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    if simd_available() {
        // SAFETY: the CPU supports AVX2 and FMA, checked just above.
        unsafe { forward_avx2(normals, tex, mat, lsa, out) };
        return;
    }
    forward::<Portable>(normals, tex, mat, lsa, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forward_avx2(
    normals: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    out: &mut [[f32; 3]],
) {
    forward::<Avx2>(normals, tex, mat, lsa, out)
}

#[inline(always)]
fn forward<V: F8>(
    normals: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    out: &mut [[f32; 3]],
) {
    let zero = V::splat(0.0);
    let mut acc = vec![[zero; 3]; normals.len()];
    let pixels: Vec<(usize, [V; 3])> = normals
        .iter()
        .enumerate()
        .filter(|(_, n)| usable(**n))
        .map(|(i, n)| (i, splat3(*n)))
        .collect();
    // Per texel group: the pixels in front of it with their cos θ_i and ln cos θ_h, then each
    // lobe over all of them. Lobe-outer order lets consecutive iterations be independent pixels
    // (the exp chains overlap) and keeps each lobe's skip and shortcut branches on one lobe's
    // outcomes; every pixel still sums its lobes in the same order as pixel-outer would.
    let mut front: Vec<(usize, V, V)> = Vec::with_capacity(pixels.len());
    let mut rho: Vec<[V; 3]> = Vec::with_capacity(pixels.len());
    for b in (0..tex.padded()).step_by(LANES) {
        front.clear();
        for &(i, n) in &pixels {
            let (f, wt, lc, _) = geometry(n, tex, b);
            if V::any(f) {
                front.push((i, wt, lc));
            }
        }
        if front.is_empty() {
            continue;
        }
        rho.clear();
        rho.resize(front.len(), [zero; 3]);
        for q in 0..MEMBERS {
            let (c, gam, kap) = (q / 3, V::load(&mat.gamma[q][b..]), V::load(&mat.kappa[q][b..]));
            // cos^γ ≤ 1, so κ bounds e^{κ cos^γ} − 1's argument on the whole group: a dim lobe
            // needs neither the per-pixel range test nor the full polynomial.
            // A macro, not a closure or function pointer: those would lose the kernel's target
            // features (see `unrolled!`).
            macro_rules! lobe {
                ($expm1:ident) => {
                    for (r, &(_, _, lc)) in rho.iter_mut().zip(&front) {
                        if skip(gam, lc) {
                            continue;
                        }
                        let pw = exp_fast(gam.mul(lc));
                        r[c] = r[c].add($expm1(kap.mul(pw)));
                    }
                };
            }
            if !V::any(kap.ge(V::splat(EXPM1_TINY))) {
                lobe!(expm1_tiny);
            } else if all_small(kap) {
                lobe!(expm1_taylor);
            } else {
                lobe!(expm1);
            }
        }
        let light: [V; 3] = unrolled!([0, 1, 2], |c| V::load(&lsa[c][b..]));
        for (r, &(i, wt, _)) in rho.iter().zip(&front) {
            for c in 0..3 {
                acc[i][c] = r[c].mul(wt).mul_add(light[c], acc[i][c]);
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        *o = a.map(F8::sum);
    }
}

/// Gradient accumulators of one region's material and the environment over many tiles:
/// ∂loss/∂ln κ_q(θ_d,t), ∂loss/∂ln γ_q(θ_d,t) and ∂loss/∂(L_c·dω)_t.
#[derive(Clone, Debug)]
pub struct TexelGrads {
    /// Per member and texel, ∂/∂ln κ.
    pub kappa: Vec<Vec<f32>>,
    /// Per member and texel, ∂/∂ln γ.
    pub gamma: Vec<Vec<f32>>,
    /// Per channel and texel, ∂/∂(L·dω).
    pub light: Vec<Vec<f32>>,
}

impl TexelGrads {
    /// Zeroed accumulators for `n` (padded) texels.
    pub fn zeros(n: usize) -> Self {
        Self {
            kappa: vec![vec![0.0; n]; MEMBERS],
            gamma: vec![vec![0.0; n]; MEMBERS],
            light: vec![vec![0.0; n]; 3],
        }
    }
}

/// Which gradients a backward pass computes; the others are left untouched (zero). Eq. 6 moves one
/// property at a time and needs only that property's gradient, which skips most of the
/// per-lobe work of the others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Wanted {
    /// ∂/∂n.
    pub normals: bool,
    /// ∂/∂m (through the texel accumulators of κ and γ).
    pub materials: bool,
    /// ∂/∂L.
    pub env: bool,
}

impl Wanted {
    /// Every gradient.
    pub const ALL: Wanted = Wanted {
        normals: true,
        materials: true,
        env: true,
    };
    /// Only ∂/∂n.
    pub const NORMALS: Wanted = Wanted {
        normals: true,
        materials: false,
        env: false,
    };
    /// Only ∂/∂m.
    pub const MATERIALS: Wanted = Wanted {
        normals: false,
        materials: true,
        env: false,
    };
    /// Only ∂/∂L.
    pub const ENV: Wanted = Wanted {
        normals: false,
        materials: false,
        env: true,
    };
}

/// Calls `$f::<$V, N, M, L>($args)` with the const flags of `$want` (one of [`Wanted`]'s
/// constants; any other combination computes everything).
macro_rules! by_wanted {
    ($want:expr, $f:ident, $V:ty, ($($arg:expr),*)) => {
        match $want {
            Wanted::NORMALS => $f::<$V, true, false, false>($($arg),*),
            Wanted::MATERIALS => $f::<$V, false, true, false>($($arg),*),
            Wanted::ENV => $f::<$V, false, false, true>($($arg),*),
            _ => $f::<$V, true, true, true>($($arg),*),
        }
    };
}

/// Vector–Jacobian product of [`forward_tile`]: given ∂loss/∂out per pixel (`upstream`), adds
/// ∂loss/∂n into `grad_n` and the texel gradients into `acc`, each only where `want` asks for
/// it. `lsa` is L·dω.
#[allow(clippy::too_many_arguments)]
pub fn backward_tile(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
    want: Wanted,
) {
    #[cfg(target_arch = "x86_64")]
    if simd_available() {
        // SAFETY: the CPU supports AVX2 and FMA, checked just above.
        unsafe { backward_avx2(normals, upstream, tex, mat, lsa, grad_n, acc, want) };
        return;
    }
    by_wanted!(
        want,
        backward,
        Portable,
        (normals, upstream, tex, mat, lsa, grad_n, acc)
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
fn backward_avx2(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
    want: Wanted,
) {
    by_wanted!(want, backward, Avx2, (normals, upstream, tex, mat, lsa, grad_n, acc))
}

#[inline(always)]
fn backward<V: F8, const N: bool, const M: bool, const L: bool>(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
) {
    let zero = V::splat(0.0);
    // Per pixel, lane-wise ∂loss/∂n.
    let mut gw = vec![[zero; 3]; normals.len()];
    let pixels: Vec<(usize, [V; 3], [f32; 3])> = normals
        .iter()
        .zip(upstream)
        .enumerate()
        .filter(|(_, (n, g))| usable(**n) && g.iter().any(|&v| v != 0.0))
        .map(|(i, (n, g))| (i, splat3(*n), *g))
        .collect();
    for b in (0..tex.padded()).step_by(LANES) {
        let light: [V; 3] = unrolled!([0, 1, 2], |c| V::load(&lsa[c][b..]));
        let kap: [V; MEMBERS] = unrolled!([0, 1, 2, 3, 4, 5, 6, 7, 8], |q| V::load(&mat.kappa[q][b..]));
        let gam: [V; MEMBERS] = unrolled!([0, 1, 2, 3, 4, 5, 6, 7, 8], |q| V::load(&mat.gamma[q][b..]));
        let w: [V; 3] = unrolled!([0, 1, 2], |a| V::load(&tex.w[a][b..]));
        let h: [V; 3] = unrolled!([0, 1, 2], |a| V::load(&tex.h[a][b..]));
        let mut gk = [zero; MEMBERS];
        let mut gg = [zero; MEMBERS];
        let mut gl = [zero; 3];
        let mut touched = false;
        for &(i, n, g) in &pixels {
            let (front, wt, lc, ch) = geometry(n, tex, b);
            if !V::any(front) {
                continue;
            }
            touched = true;
            // ∂(ci)/∂n = ω_i where ci > 0; ∂(cos θ_h)/∂n = h − n (from 1 − ½|n − h|²).
            let mut cw = zero;
            let mut chh = zero;
            // ci/cos θ_h: at most 2 for a unit normal, so grazing pixels stay finite.
            let ratio = if N {
                V::select(ch.ge(V::splat(1e-20)), wt.div(ch.max(V::splat(1e-20))), zero)
            } else {
                zero
            };
            for c in 0..3 {
                if g[c] == 0.0 {
                    continue;
                }
                let gc = V::splat(g[c]);
                let gl_c = gc.mul(light[c]);
                let wc = gl_c.mul(wt);
                let mut rho = zero;
                let mut dsum = zero;
                for k in 0..3 {
                    let q = c * 3 + k;
                    if skip(gam[q], lc) {
                        continue;
                    }
                    let pw = exp_fast(gam[q].mul(lc));
                    let kp = kap[q].mul(pw);
                    let e = expm1(kp);
                    if N || L {
                        rho = rho.add(e);
                    }
                    if N || M {
                        // ∂ρ/∂ln κ = e^{κ c^γ} κ c^γ; ∂ρ/∂ln γ = that · γ ln c.
                        let d = e.add(V::splat(1.0)).mul(kp);
                        if M {
                            let wd = wc.mul(d);
                            gk[q] = gk[q].add(wd);
                            gg[q] = wd.mul(gam[q]).mul_add(lc, gg[q]);
                        }
                        if N {
                            dsum = d.mul_add(gam[q], dsum);
                        }
                    }
                }
                if L {
                    gl[c] = gc.mul(rho).mul_add(wt, gl[c]);
                }
                if N {
                    cw = V::select(front, gl_c.mul_add(rho, cw), cw);
                    chh = gl_c.mul(dsum).mul_add(ratio, chh);
                }
            }
            if N {
                for a in 0..3 {
                    let dir = h[a].sub(n[a]);
                    gw[i][a] = cw.mul_add(w[a], chh.mul_add(dir, gw[i][a]));
                }
            }
        }
        if touched && M {
            for q in 0..MEMBERS {
                V::load(&acc.kappa[q][b..]).add(gk[q]).store(&mut acc.kappa[q][b..]);
                V::load(&acc.gamma[q][b..]).add(gg[q]).store(&mut acc.gamma[q][b..]);
            }
        }
        if touched && L {
            for (c, g) in gl.iter().enumerate() {
                V::load(&acc.light[c][b..]).add(*g).store(&mut acc.light[c][b..]);
            }
        }
    }
    if !N {
        return;
    }
    for (o, g) in grad_n.iter_mut().zip(&gw) {
        for (o, g) in o.iter_mut().zip(g) {
            *o += g.sum();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rendering_layer::material::knot_index;

    /// `count` unit normals on a spiral: azimuth `turn`·i, n_z from `z0` up by `dz`·i/`steps`.
    fn spiral_normals(count: usize, turn: f32, z0: f32, dz: f32, steps: f32) -> Vec<[f32; 3]> {
        (0..count)
            .map(|i| {
                let (a, z) = (i as f32 * turn, z0 + dz * (i as f32 / steps));
                let r = (1.0 - z * z).sqrt();
                [r * a.cos(), r * a.sin(), z]
            })
            .collect()
    }

    /// Eq. 2 in f64, straight from the texel table: the sum the kernel's tiles must give.
    #[allow(clippy::needless_range_loop)] // t indexes five parallel texel arrays
    fn eq2_f64(n: [f32; 3], tex: &TexelTable, mat: &MaterialTexels, lsa: &[Vec<f32>; 3]) -> [f64; 3] {
        let mut out = [0.0f64; 3];
        if !usable(n) {
            return out;
        }
        let n = n.map(|v| v as f64);
        for t in 0..tex.count() {
            let w = [0, 1, 2].map(|a| tex.w[a][t] as f64);
            let h = [0, 1, 2].map(|a| tex.h[a][t] as f64);
            let ci = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
            let o = 0.5 * ((n[0] - h[0]).powi(2) + (n[1] - h[1]).powi(2) + (n[2] - h[2]).powi(2));
            if ci <= 0.0 || o >= 1.0 {
                continue;
            }
            for (c, out) in out.iter_mut().enumerate() {
                let rho: f64 = (0..3)
                    .map(|k| {
                        let q = c * 3 + k;
                        let (kap, gam) = (mat.kappa[q][t] as f64, mat.gamma[q][t] as f64);
                        (kap * (1.0 - o).powf(gam)).exp_m1()
                    })
                    .sum();
                *out += rho * ci * lsa[c][t] as f64;
            }
        }
        out
    }

    /// Every lobe path of the forward kernel (κ below 0.04 on a whole group, below 0.35, and
    /// larger; broad and sharp γ), on the AVX2 and the portable lanes, against Eq. 2 in f64.
    #[test]
    fn every_lobe_path_of_the_forward_kernel_matches_eq2_in_f64() {
        use matedit_physics::brdf::dsbrdf::KNOTS;
        // 13 × 26 texels: padded with six inert ones.
        let tex = TexelTable::new(13);
        let lsa: [Vec<f32>; 3] = std::array::from_fn(|c| {
            (0..tex.padded())
                .map(|t| {
                    tex.sa[t]
                        * if t == 40 {
                            300.0
                        } else {
                            0.5 + ((t * 5 + c) % 7) as f32 * 0.2
                        }
                })
                .collect()
        });
        let normals = spiral_normals(37, 0.83, 0.001, 0.999, 36.0);
        // (κ, γ) per lobe k, in the normalised coordinates: κ below 0.04 (x < 0.13), around
        // 0.04–0.37 (x ≤ 0.43, so mostly the eighth-degree path) and above, with broad to sharp
        // γ, and one material mixing them.
        let regimes: [[(f32, f32); 3]; 4] = [
            [(-0.95, -0.9), (-0.6, -0.2), (-0.5, 0.3)],
            [(0.39, -0.9), (0.35, -0.5), (0.3, 0.0)],
            [(0.6, -0.9), (0.8, -0.1), (0.95, 0.5)],
            [(-0.95, 0.6), (0.2, -0.95), (0.9, 0.0)],
        ];
        for (r, lobes) in regimes.iter().enumerate() {
            let mut x = vec![0.0f32; matedit_physics::brdf::dsbrdf::PARAMS];
            for c in 0..3 {
                for (k, &(kx, gx)) in lobes.iter().enumerate() {
                    for j in 0..KNOTS {
                        let wobble = 0.005 * (j as f32 - 2.5) * (c as f32 + 1.0);
                        x[knot_index(c * 3 + k, false, j)] = (kx + wobble).clamp(-1.0, 1.0);
                        x[knot_index(c * 3 + k, true, j)] = (gx + wobble).clamp(-1.0, 1.0);
                    }
                }
            }
            let mat = MaterialTexels::new(&x, &tex);
            let mut fa = vec![[0.0; 3]; normals.len()];
            let mut fp = vec![[0.0; 3]; normals.len()];
            forward_tile(&normals, &tex, &mat, &lsa, &mut fa);
            forward::<Portable>(&normals, &tex, &mat, &lsa, &mut fp);
            let want: Vec<[f64; 3]> = normals.iter().map(|&n| eq2_f64(n, &tex, &mat, &lsa)).collect();
            let scale = want.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(scale > 0.0);
            for (i, w) in want.iter().enumerate() {
                for c in 0..3 {
                    for (which, got) in [("simd", fa[i][c]), ("portable", fp[i][c])] {
                        let err = (got as f64 - w[c]).abs();
                        assert!(
                            err <= 1e-5 * w[c].abs() + 1e-6 * scale,
                            "regime {r}, {which}, pixel {i}, channel {c}: {got} against {}",
                            w[c]
                        );
                    }
                }
            }
        }
    }

    /// The AVX2 + FMA kernel and the portable one compute the same sums up to rounding.
    #[test]
    fn simd_and_portable_kernels_agree() {
        if !simd_available() {
            eprintln!("no AVX2 + FMA on this CPU: only the portable kernel runs here");
            return;
        }
        let tex = TexelTable::new(16);
        let x: Vec<f32> = (0..matedit_physics::brdf::dsbrdf::PARAMS)
            .map(|i| ((i * 53 % 97) as f32 / 48.0 - 1.0) * 0.9)
            .collect();
        let mat = MaterialTexels::new(&x, &tex);
        let lsa: [Vec<f32>; 3] = std::array::from_fn(|c| {
            (0..tex.padded())
                .map(|t| tex.sa[t] * (1.0 + ((t * 7 + c) % 13) as f32))
                .collect()
        });
        let normals = spiral_normals(40, 0.61, 0.02, 0.98, 40.0);
        let up: Vec<[f32; 3]> = (0..40).map(|i| [1.0, -0.5, (i % 3) as f32 - 1.0]).collect();
        let mut fa = vec![[0.0; 3]; 40];
        let mut fp = vec![[0.0; 3]; 40];
        forward_tile(&normals, &tex, &mat, &lsa, &mut fa);
        forward::<Portable>(&normals, &tex, &mat, &lsa, &mut fp);
        let (mut ga, mut gp) = (vec![[0.0; 3]; 40], vec![[0.0; 3]; 40]);
        let (mut aa, mut ap) = (TexelGrads::zeros(tex.padded()), TexelGrads::zeros(tex.padded()));
        backward_tile(&normals, &up, &tex, &mat, &lsa, &mut ga, &mut aa, Wanted::ALL);
        backward::<Portable, true, true, true>(&normals, &up, &tex, &mat, &lsa, &mut gp, &mut ap);
        let close = |a: f32, b: f32, scale: f32| (a - b).abs() <= 2e-5 * scale;
        let scale = |v: &[[f32; 3]]| v.iter().flatten().fold(0.0f32, |m, x| m.max(x.abs()));
        let (sf, sg) = (scale(&fp), scale(&gp));
        for i in 0..40 {
            for c in 0..3 {
                assert!(
                    close(fa[i][c], fp[i][c], sf),
                    "forward {i} {c}: {} vs {}",
                    fa[i][c],
                    fp[i][c]
                );
                assert!(
                    close(ga[i][c], gp[i][c], sg),
                    "grad n {i} {c}: {} vs {}",
                    ga[i][c],
                    gp[i][c]
                );
            }
        }
        for (a, p) in [(&aa.kappa, &ap.kappa), (&aa.gamma, &ap.gamma), (&aa.light, &ap.light)] {
            let s = p.iter().flatten().fold(0.0f32, |m, x| m.max(x.abs()));
            for (a, p) in a.iter().flatten().zip(p.iter().flatten()) {
                assert!(close(*a, *p, s), "texel gradient {a} vs {p}");
            }
        }
    }
}

//! The fused kernel of the rendering layer: Eq. 2 and its vector–Jacobian product for a tile of
//! pixels that share one material, over all texels.
//!
//! Loops run texel-group-outer, pixel-inner: one group's constants (directions, half vectors,
//! L·dω and 18 lobe parameters) stay in L1 while every pixel of the tile uses them, and in the
//! backward pass the group's gradient accumulators stay in registers instead of streaming
//! 21 × T floats per pixel. Every lane computation is branch-free so that it vectorises; groups of
//! eight texels behind every pixel's surface, and lobes whose cos^γ is below e^−30 on a whole
//! group, are skipped (they add less than κ·e^−30 ≤ 2e-12 of L·dω to a value or a gradient).

use super::material::{MEMBERS, MaterialTexels};
use super::texels::{LANES, TexelTable};
use matedit_physics::fastmath;

/// A lobe whose γ·ln cos θ_h is below this on all lanes is skipped.
const SKIP_EXPONENT: f32 = -30.0;

type Lanes = [f32; LANES];

#[inline(always)]
fn map8(x: Lanes, f: impl Fn(f32) -> f32) -> Lanes {
    let mut o = [0.0; LANES];
    for l in 0..LANES {
        o[l] = f(x[l]);
    }
    o
}

/// Taylor polynomial of e^x − 1 to x⁸/8! (truncation below 3e-10 relative for |x| < 0.35).
#[inline(always)]
fn expm1_taylor(x: f32) -> f32 {
    let mut t = 1.0 / 40320.0_f32;
    t = t * x + 1.0 / 5040.0;
    t = t * x + 1.0 / 720.0;
    t = t * x + 1.0 / 120.0;
    t = t * x + 1.0 / 24.0;
    t = t * x + 1.0 / 6.0;
    t = t * x + 0.5;
    (t * x) * x + x
}

/// Largest |x| of eight lanes.
#[inline(always)]
fn max_abs(x: &Lanes) -> f32 {
    let mut m = 0.0f32;
    for v in x {
        m = m.max(v.abs());
    }
    m
}

/// e^x − 1 on eight lanes. A lobe far from its peak, or a weak one, has small arguments on a
/// whole group of texels: then the polynomial alone is exact to 3e-10 and costs a third of the
/// general path, which evaluates both the polynomial and e^x and selects per lane.
#[inline(always)]
fn expm1_8(x: Lanes) -> Lanes {
    if max_abs(&x) < 0.35 {
        map8(x, expm1_taylor)
    } else {
        map8(x, fastmath::expm1)
    }
}

/// e^x on eight lanes (the same shortcut for small arguments: broad lobes, γ ≪ 1).
#[inline(always)]
fn exp_8(x: Lanes) -> Lanes {
    if max_abs(&x) < 0.35 {
        map8(x, |v| 1.0 + expm1_taylor(v))
    } else {
        map8(x, fastmath::exp)
    }
}

#[inline(always)]
fn mul8(a: &Lanes, b: &Lanes) -> Lanes {
    let mut o = [0.0; LANES];
    for l in 0..LANES {
        o[l] = a[l] * b[l];
    }
    o
}

#[inline(always)]
fn lanes(v: &[f32], b: usize) -> Lanes {
    let mut out = [0.0; LANES];
    out.copy_from_slice(&v[b..b + LANES]);
    out
}

/// Sums the lanes in a fixed order.
#[inline(always)]
fn reduce(v: Lanes) -> f32 {
    let mut s = [0.0f32; 4];
    for l in 0..4 {
        s[l] = v[l] + v[l + 4];
    }
    (s[0] + s[2]) + (s[1] + s[3])
}

/// A normal the layer can shade: finite and facing the camera (n_z > 0). Others render black and
/// receive no gradient.
#[inline(always)]
pub fn usable(n: [f32; 3]) -> bool {
    n[2] > 0.0 && n.iter().all(|v| v.is_finite())
}

/// Geometric terms of one pixel against eight texels: clamped cos θ_i, ln cos θ_h, cos θ_h, and
/// whether cos θ_h is positive. 1 − cos θ_h is computed as ½|n − h|², exact near the lobe peak
/// where 1 − n·h cancels (and the definition the gradient differentiates).
#[inline(always)]
fn geometry(n: [f32; 3], tex: &TexelTable, b: usize) -> (Lanes, Lanes, Lanes) {
    let (mut wt, mut omc, mut ch) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let w = [lanes(&tex.w[0], b), lanes(&tex.w[1], b), lanes(&tex.w[2], b)];
    let h = [lanes(&tex.h[0], b), lanes(&tex.h[1], b), lanes(&tex.h[2], b)];
    for l in 0..LANES {
        let ci = n[0] * w[0][l] + n[1] * w[1][l] + n[2] * w[2][l];
        let d = [n[0] - h[0][l], n[1] - h[1][l], n[2] - h[2][l]];
        let o = 0.5 * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        let front = ci > 0.0 && o < 1.0;
        wt[l] = if front { ci } else { 0.0 };
        // Back lanes get 1 − cos θ_h = 1, whose log is the floor −103.3: cos^γ = 0 there.
        omc[l] = if front { o } else { 1.0 };
        ch[l] = 1.0 - o;
    }
    (wt, map8(omc, fastmath::ln_1m), ch)
}

#[inline(always)]
fn skip(gam: &Lanes, lc: &Lanes) -> bool {
    let mut top = f32::MIN;
    for l in 0..LANES {
        top = top.max(gam[l] * lc[l]);
    }
    top < SKIP_EXPONENT
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
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { forward_avx2(normals, tex, mat, lsa, out) };
        return;
    }
    forward_portable(normals, tex, mat, lsa, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn forward_avx2(
    normals: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    out: &mut [[f32; 3]],
) {
    forward_portable(normals, tex, mat, lsa, out)
}

#[inline(always)]
fn forward_portable(
    normals: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    out: &mut [[f32; 3]],
) {
    let mut acc = vec![[[0.0f32; LANES]; 3]; normals.len()];
    for b in (0..tex.padded()).step_by(LANES) {
        let light = [lanes(&lsa[0], b), lanes(&lsa[1], b), lanes(&lsa[2], b)];
        let kap: [Lanes; MEMBERS] = std::array::from_fn(|q| lanes(&mat.kappa[q], b));
        let gam: [Lanes; MEMBERS] = std::array::from_fn(|q| lanes(&mat.gamma[q], b));
        for (&n, acc) in normals.iter().zip(acc.iter_mut()) {
            if !usable(n) {
                continue;
            }
            let (wt, lc, _) = geometry(n, tex, b);
            if wt.iter().all(|&w| w == 0.0) {
                continue;
            }
            for c in 0..3 {
                let mut rho = [0.0f32; LANES];
                for k in 0..3 {
                    let q = c * 3 + k;
                    if skip(&gam[q], &lc) {
                        continue;
                    }
                    let pw = exp_8(mul8(&gam[q], &lc));
                    let e = expm1_8(mul8(&kap[q], &pw));
                    for l in 0..LANES {
                        rho[l] += e[l];
                    }
                }
                for l in 0..LANES {
                    acc[c][l] += rho[l] * wt[l] * light[c][l];
                }
            }
        }
    }
    for (o, a) in out.iter_mut().zip(&acc) {
        *o = a.map(reduce);
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

/// Vector–Jacobian product of [`forward_tile`]: given ∂loss/∂out per pixel (`upstream`), adds
/// ∂loss/∂n into `grad_n` and the texel gradients into `acc`. `lsa` and `env` are L·dω and L.
pub fn backward_tile(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        unsafe { backward_avx2(normals, upstream, tex, mat, lsa, grad_n, acc) };
        return;
    }
    backward_portable(normals, upstream, tex, mat, lsa, grad_n, acc);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn backward_avx2(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
) {
    backward_portable(normals, upstream, tex, mat, lsa, grad_n, acc)
}

#[inline(always)]
fn backward_portable(
    normals: &[[f32; 3]],
    upstream: &[[f32; 3]],
    tex: &TexelTable,
    mat: &MaterialTexels,
    lsa: &[Vec<f32>; 3],
    grad_n: &mut [[f32; 3]],
    acc: &mut TexelGrads,
) {
    // Per pixel, lane-wise coefficients of ω_i and of (h − n) in ∂loss/∂n.
    let mut gw = vec![[[0.0f32; LANES]; 3]; normals.len()];
    for b in (0..tex.padded()).step_by(LANES) {
        let light = [lanes(&lsa[0], b), lanes(&lsa[1], b), lanes(&lsa[2], b)];
        let kap: [Lanes; MEMBERS] = std::array::from_fn(|q| lanes(&mat.kappa[q], b));
        let gam: [Lanes; MEMBERS] = std::array::from_fn(|q| lanes(&mat.gamma[q], b));
        let w = [lanes(&tex.w[0], b), lanes(&tex.w[1], b), lanes(&tex.w[2], b)];
        let h = [lanes(&tex.h[0], b), lanes(&tex.h[1], b), lanes(&tex.h[2], b)];
        let mut gk = [[0.0f32; LANES]; MEMBERS];
        let mut gg = [[0.0f32; LANES]; MEMBERS];
        let mut gl = [[0.0f32; LANES]; 3];
        let mut touched = false;
        for ((&n, g), gw) in normals.iter().zip(upstream).zip(gw.iter_mut()) {
            if !usable(n) {
                continue;
            }
            let (wt, lc, ch) = geometry(n, tex, b);
            if wt.iter().all(|&w| w == 0.0) {
                continue;
            }
            touched = true;
            // ∂(ci)/∂n = ω_i where ci > 0; ∂(cos θ_h)/∂n = h − n (from 1 − ½|n − h|²).
            let mut cw = [0.0f32; LANES];
            let mut chh = [0.0f32; LANES];
            for c in 0..3 {
                if g[c] == 0.0 {
                    continue;
                }
                let mut rho = [0.0f32; LANES];
                let mut dsum = [0.0f32; LANES];
                let mut wc = [0.0f32; LANES];
                for l in 0..LANES {
                    wc[l] = g[c] * light[c][l] * wt[l];
                }
                for k in 0..3 {
                    let q = c * 3 + k;
                    if skip(&gam[q], &lc) {
                        continue;
                    }
                    let pw = exp_8(mul8(&gam[q], &lc));
                    let e = expm1_8(mul8(&kap[q], &pw));
                    for l in 0..LANES {
                        // ∂ρ/∂ln κ = e^{κ c^γ} κ c^γ; ∂ρ/∂ln γ = that · γ ln c.
                        let pw = pw[l];
                        let e = e[l];
                        let d = (e + 1.0) * kap[q][l] * pw;
                        rho[l] += e;
                        gk[q][l] += wc[l] * d;
                        gg[q][l] += wc[l] * d * gam[q][l] * lc[l];
                        dsum[l] += d * gam[q][l];
                    }
                }
                for l in 0..LANES {
                    gl[c][l] += g[c] * rho[l] * wt[l];
                    let front = if wt[l] > 0.0 { 1.0 } else { 0.0 };
                    cw[l] += g[c] * light[c][l] * rho[l] * front;
                    // ci · ∂ρ/∂cos θ_h = ci/cos θ_h · Σ κγ c^γ e^{κc^γ}: the ratio is at most 2
                    // for a unit normal, so grazing pixels stay finite.
                    let ratio = if ch[l] > 1e-20 { wt[l] / ch[l] } else { 0.0 };
                    chh[l] += g[c] * light[c][l] * dsum[l] * ratio;
                }
            }
            for a in 0..3 {
                for l in 0..LANES {
                    gw[a][l] += cw[l] * w[a][l] + chh[l] * (h[a][l] - n[a]);
                }
            }
        }
        if touched {
            for q in 0..MEMBERS {
                for l in 0..LANES {
                    acc.kappa[q][b + l] += gk[q][l];
                    acc.gamma[q][b + l] += gg[q][l];
                }
            }
            for c in 0..3 {
                for l in 0..LANES {
                    acc.light[c][b + l] += gl[c][l];
                }
            }
        }
    }
    for (o, g) in grad_n.iter_mut().zip(&gw) {
        for a in 0..3 {
            o[a] += reduce(g[a]);
        }
    }
}

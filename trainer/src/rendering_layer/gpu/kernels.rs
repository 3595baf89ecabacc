//! The rendering layer's CubeCL kernels: Eq. 2 and its vector–Jacobian product, with the fused
//! CPU layer's arithmetic (`rendering_layer::kernel`) and its guards.
//!
//! Work is laid out so that the threads of a cube walk the same loop in lock step: in the pixel
//! kernels every thread is a pixel and all read the same texel at once (a broadcast from cache);
//! in the texel kernel every thread is a texel and all read the same pixel. Nothing of size
//! pixels × texels is stored: sums over texels (an image, ∂/∂n) and over pixels (∂/∂κ, ∂/∂γ,
//! ∂/∂L) are accumulated in registers, the latter in blocks of [`BLOCK`] pixels so that f32
//! rounding grows with √P rather than P. Texels behind a pixel's surface are skipped, and so are
//! lobes whose cos^γ θ_h is below e^−30.
//!
//! Layouts (row-major, contiguous): normals, images and upstream gradients `[B, 3, P]`, region
//! map `[B, P]` (as floats), materials `[B, R, 108]`, environment `[B, 3, T]`, texel table
//! `[9, T]` (ω_i, h, dω, knot segment, knot weight), lobes `[B, R, 9, 2, T]` (κ then γ per member),
//! L·dω `[B, 3, T]`, texel gradients `[B, R, 3, 7, T]` (∂/∂ln κ of the channel's three lobes, then
//! ∂/∂ln γ, then ∂/∂(L·dω)).

// `#[cube]` functions translate integer arithmetic, not `usize::div_ceil`.
#![allow(clippy::manual_div_ceil)]

use cubecl::prelude::*;

/// Pixels summed in f32 before their sum joins the running total.
pub const BLOCK: usize = 256;
/// Rows of the texel table.
pub const TABLE_ROWS: usize = 9;
/// Slots per channel in the texel-gradient buffer.
pub const SLOTS: usize = 7;

/// ln(1 − o) for o ∈ [0, 1): a series where 1 − o would round away o's digits (sharp lobes
/// multiply this by γ up to 1e4).
#[cube]
fn ln_1m<F: Float>(o: F) -> F {
    if o < F::new(0.05) {
        let s = F::new(1.0) / F::new(7.0);
        let s = o * s + F::new(1.0) / F::new(6.0);
        let s = o * s + F::new(0.2);
        let s = o * s + F::new(0.25);
        let s = o * s + F::new(1.0) / F::new(3.0);
        let s = o * s + F::new(0.5);
        let s = o * s + F::new(1.0);
        -o * s
    } else {
        F::ln(F::new(1.0) - o)
    }
}

/// e^x − 1 for x ≥ 0, exact to f32 rounding for small x too.
#[cube]
fn expm1<F: Float>(x: F) -> F {
    if x < F::new(0.05) {
        let s = x / F::new(5.0) + F::new(1.0);
        let s = x / F::new(4.0) * s + F::new(1.0);
        let s = x / F::new(3.0) * s + F::new(1.0);
        let s = x / F::new(2.0) * s + F::new(1.0);
        x * s
    } else {
        F::exp(x) - F::new(1.0)
    }
}

/// Whether `v` is a finite number (NaN fails both comparisons).
#[cube]
fn finite<F: Float>(v: F) -> bool {
    v >= F::new(-3.0e38) && v <= F::new(3.0e38)
}

/// A normal the layer shades: finite and facing the camera.
#[cube]
fn usable<F: Float>(n0: F, n1: F, n2: F) -> bool {
    finite::<F>(n0) && finite::<F>(n1) && finite::<F>(n2) && n2 > F::new(0.0)
}

/// x clamped to [−1, 1], NaN → 0 (`material::clamp_x`).
#[cube]
fn clamp_x<F: Float>(x: F) -> F {
    let mut r = F::new(0.0);
    if finite::<F>(x) {
        r = F::clamp(x, F::new(-1.0), F::new(1.0));
    } else if x > F::new(0.0) {
        r = F::new(1.0);
    } else if x < F::new(0.0) {
        r = F::new(-1.0);
    }
    r
}

/// κ and γ of every member at every texel: thread (b, r, q, t). `ak, bk, ag, bg`: the
/// log-affine maps v = exp(A + B·x) of κ and γ.
#[cube(launch)]
pub fn lobes_kernel<F: Float>(
    materials: &Tensor<F>,
    table: &Tensor<F>,
    lobes: &mut Tensor<F>,
    texels: usize,
    ak: f32,
    bk: f32,
    ag: f32,
    bg: f32,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    let members = 9usize;
    if i < materials.len() / 108 * members * texels {
        let t = i % texels;
        let q = (i / texels) % members;
        let br = i / (texels * members);
        let seg = usize::cast_from(table[7 * texels + t]);
        let u = table[8 * texels + t];
        let base = br * 108 + q * 12;
        let k0 = clamp_x::<F>(materials[base + seg]);
        let k1 = clamp_x::<F>(materials[base + seg + 1]);
        let g0 = clamp_x::<F>(materials[base + 6 + seg]);
        let g1 = clamp_x::<F>(materials[base + 6 + seg + 1]);
        let xk = k0 + u * (k1 - k0);
        let xg = g0 + u * (g1 - g0);
        let o = (br * members + q) * 2 * texels + t;
        lobes[o] = F::exp(F::cast_from(ak) + F::cast_from(bk) * xk);
        lobes[o + texels] = F::exp(F::cast_from(ag) + F::cast_from(bg) * xg);
    }
}

/// L·dω per image, channel and texel: non-finite and negative radiance as 0, capped at `cap`.
#[cube(launch)]
pub fn light_kernel<F: Float>(
    env: &Tensor<F>,
    table: &Tensor<F>,
    lsa: &mut Tensor<F>,
    texels: usize,
    cap: f32,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < env.len() {
        let l = env[i];
        let mut v = F::new(0.0);
        if finite::<F>(l) && l > F::new(0.0) {
            v = F::min(l, F::cast_from(cap)) * table[6 * texels + i % texels];
        }
        lsa[i] = v;
    }
}

/// Eq. 2 for every pixel: thread (b, p).
#[cube(launch)]
pub fn forward_kernel<F: Float>(
    normals: &Tensor<F>,
    regions: &Tensor<F>,
    table: &Tensor<F>,
    lobes: &Tensor<F>,
    lsa: &Tensor<F>,
    image: &mut Tensor<F>,
    pixels: usize,
    texels: usize,
    materials: usize,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < regions.len() {
        let b = i / pixels;
        let p = i % pixels;
        let n0 = normals[(b * 3) * pixels + p];
        let n1 = normals[(b * 3 + 1) * pixels + p];
        let n2 = normals[(b * 3 + 2) * pixels + p];
        let region = usize::cast_from(regions[i]);
        let mut acc0 = F::new(0.0);
        let mut acc1 = F::new(0.0);
        let mut acc2 = F::new(0.0);
        if region > 0 && region <= materials && usable::<F>(n0, n1, n2) {
            let lob = (b * materials + region - 1) * 18 * texels;
            let lig = b * 3 * texels;
            for t in 0..texels {
                let ci = n0 * table[t] + n1 * table[texels + t] + n2 * table[2 * texels + t];
                let d0 = n0 - table[3 * texels + t];
                let d1 = n1 - table[4 * texels + t];
                let d2 = n2 - table[5 * texels + t];
                let o = (d0 * d0 + d1 * d1 + d2 * d2) * F::new(0.5);
                if ci > F::new(0.0) && o < F::new(1.0) {
                    let lc = ln_1m::<F>(o);
                    let mut rho0 = F::new(0.0);
                    let mut rho1 = F::new(0.0);
                    let mut rho2 = F::new(0.0);
                    #[unroll]
                    for q in 0..9usize {
                        let kap = lobes[lob + q * 2 * texels + t];
                        let gam = lobes[lob + (q * 2 + 1) * texels + t];
                        let ex = gam * lc;
                        if ex >= F::new(-30.0) {
                            let e = expm1::<F>(kap * F::exp(ex));
                            if q < 3 {
                                rho0 += e;
                            } else if q < 6 {
                                rho1 += e;
                            } else {
                                rho2 += e;
                            }
                        }
                    }
                    acc0 += rho0 * ci * lsa[lig + t];
                    acc1 += rho1 * ci * lsa[lig + texels + t];
                    acc2 += rho2 * ci * lsa[lig + 2 * texels + t];
                }
            }
        }
        image[(b * 3) * pixels + p] = acc0;
        image[(b * 3 + 1) * pixels + p] = acc1;
        image[(b * 3 + 2) * pixels + p] = acc2;
    }
}

/// An upstream gradient, non-finite as 0.
#[cube]
fn upstream<F: Float>(g: F) -> F {
    let mut r = F::new(0.0);
    if finite::<F>(g) {
        r = g;
    }
    r
}

/// ∂loss/∂n for every pixel: thread (b, p).
#[cube(launch)]
pub fn normal_grad_kernel<F: Float>(
    normals: &Tensor<F>,
    regions: &Tensor<F>,
    table: &Tensor<F>,
    lobes: &Tensor<F>,
    lsa: &Tensor<F>,
    grad: &Tensor<F>,
    grad_n: &mut Tensor<F>,
    pixels: usize,
    texels: usize,
    materials: usize,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < regions.len() {
        let b = i / pixels;
        let p = i % pixels;
        let n0 = normals[(b * 3) * pixels + p];
        let n1 = normals[(b * 3 + 1) * pixels + p];
        let n2 = normals[(b * 3 + 2) * pixels + p];
        let g0 = upstream::<F>(grad[(b * 3) * pixels + p]);
        let g1 = upstream::<F>(grad[(b * 3 + 1) * pixels + p]);
        let g2 = upstream::<F>(grad[(b * 3 + 2) * pixels + p]);
        let region = usize::cast_from(regions[i]);
        let mut gw0 = F::new(0.0);
        let mut gw1 = F::new(0.0);
        let mut gw2 = F::new(0.0);
        if region > 0 && region <= materials && usable::<F>(n0, n1, n2) {
            let lob = (b * materials + region - 1) * 18 * texels;
            let lig = b * 3 * texels;
            for t in 0..texels {
                let w0 = table[t];
                let w1 = table[texels + t];
                let w2 = table[2 * texels + t];
                let ci = n0 * w0 + n1 * w1 + n2 * w2;
                let h0 = table[3 * texels + t];
                let h1 = table[4 * texels + t];
                let h2 = table[5 * texels + t];
                let d0 = n0 - h0;
                let d1 = n1 - h1;
                let d2 = n2 - h2;
                let o = (d0 * d0 + d1 * d1 + d2 * d2) * F::new(0.5);
                if ci > F::new(0.0) && o < F::new(1.0) {
                    let lc = ln_1m::<F>(o);
                    let ch = F::new(1.0) - o;
                    // ci / cos θ_h: at most 2 for a unit normal, so grazing pixels stay finite.
                    let mut ratio = F::new(0.0);
                    if ch >= F::new(1e-20) {
                        ratio = ci / ch;
                    }
                    let mut cw = F::new(0.0);
                    let mut chh = F::new(0.0);
                    #[unroll]
                    for c in 0..3usize {
                        let mut gc = g0;
                        if c == 1 {
                            gc = g1;
                        } else if c == 2 {
                            gc = g2;
                        }
                        let glc = gc * lsa[lig + c * texels + t];
                        let mut rho = F::new(0.0);
                        let mut dsum = F::new(0.0);
                        #[unroll]
                        for k in 0..3usize {
                            let q = c * 3 + k;
                            let kap = lobes[lob + q * 2 * texels + t];
                            let gam = lobes[lob + (q * 2 + 1) * texels + t];
                            let ex = gam * lc;
                            if ex >= F::new(-30.0) {
                                let kp = kap * F::exp(ex);
                                let e = expm1::<F>(kp);
                                rho += e;
                                dsum += (e + F::new(1.0)) * kp * gam;
                            }
                        }
                        cw += glc * rho;
                        chh += glc * dsum * ratio;
                    }
                    // ∂(n·ω_i)/∂n = ω_i; ∂(cos θ_h)/∂n = h − n (from 1 − ½|n − h|²).
                    gw0 += cw * w0 + chh * (h0 - n0);
                    gw1 += cw * w1 + chh * (h1 - n1);
                    gw2 += cw * w2 + chh * (h2 - n2);
                }
            }
        }
        grad_n[(b * 3) * pixels + p] = gw0;
        grad_n[(b * 3 + 1) * pixels + p] = gw1;
        grad_n[(b * 3 + 2) * pixels + p] = gw2;
    }
}

/// ∂loss/∂ln κ, ∂loss/∂ln γ (the channel's three lobes) and ∂loss/∂(L·dω) of one texel, summed
/// over the pixels of one region: thread (b, r, c, t).
#[cube(launch)]
pub fn texel_grad_kernel<F: Float>(
    normals: &Tensor<F>,
    regions: &Tensor<F>,
    table: &Tensor<F>,
    lobes: &Tensor<F>,
    lsa: &Tensor<F>,
    grad: &Tensor<F>,
    out: &mut Tensor<F>,
    pixels: usize,
    texels: usize,
    materials: usize,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < out.len() / 7 {
        let t = i % texels;
        let c = (i / texels) % 3;
        let br = i / (3 * texels);
        let b = br / materials;
        let r = br % materials;
        let lob = br * 18 * texels;
        let w0 = table[t];
        let w1 = table[texels + t];
        let w2 = table[2 * texels + t];
        let h0 = table[3 * texels + t];
        let h1 = table[4 * texels + t];
        let h2 = table[5 * texels + t];
        let light = lsa[(b * 3 + c) * texels + t];
        let q0 = c * 3;
        let kap0 = lobes[lob + q0 * 2 * texels + t];
        let gam0 = lobes[lob + (q0 * 2 + 1) * texels + t];
        let kap1 = lobes[lob + (q0 * 2 + 2) * texels + t];
        let gam1 = lobes[lob + (q0 * 2 + 3) * texels + t];
        let kap2 = lobes[lob + (q0 * 2 + 4) * texels + t];
        let gam2 = lobes[lob + (q0 * 2 + 5) * texels + t];
        let mut tk0 = F::new(0.0);
        let mut tk1 = F::new(0.0);
        let mut tk2 = F::new(0.0);
        let mut tg0 = F::new(0.0);
        let mut tg1 = F::new(0.0);
        let mut tg2 = F::new(0.0);
        let mut tl = F::new(0.0);
        let blocks = (pixels + BLOCK - 1) / BLOCK;
        for blk in 0..blocks {
            let mut sk0 = F::new(0.0);
            let mut sk1 = F::new(0.0);
            let mut sk2 = F::new(0.0);
            let mut sg0 = F::new(0.0);
            let mut sg1 = F::new(0.0);
            let mut sg2 = F::new(0.0);
            let mut sl = F::new(0.0);
            let mut end = (blk + 1) * BLOCK;
            if end > pixels {
                end = pixels;
            }
            for p in blk * BLOCK..end {
                let region = usize::cast_from(regions[b * pixels + p]);
                let n0 = normals[(b * 3) * pixels + p];
                let n1 = normals[(b * 3 + 1) * pixels + p];
                let n2 = normals[(b * 3 + 2) * pixels + p];
                let gc = upstream::<F>(grad[(b * 3 + c) * pixels + p]);
                if region == r + 1 && usable::<F>(n0, n1, n2) && gc != F::new(0.0) {
                    let ci = n0 * w0 + n1 * w1 + n2 * w2;
                    let d0 = n0 - h0;
                    let d1 = n1 - h1;
                    let d2 = n2 - h2;
                    let o = (d0 * d0 + d1 * d1 + d2 * d2) * F::new(0.5);
                    if ci > F::new(0.0) && o < F::new(1.0) {
                        let lc = ln_1m::<F>(o);
                        let wc = gc * light * ci;
                        let mut rho = F::new(0.0);
                        let ex0 = gam0 * lc;
                        if ex0 >= F::new(-30.0) {
                            let kp = kap0 * F::exp(ex0);
                            let e = expm1::<F>(kp);
                            let wd = wc * (e + F::new(1.0)) * kp;
                            rho += e;
                            sk0 += wd;
                            sg0 += wd * gam0 * lc;
                        }
                        let ex1 = gam1 * lc;
                        if ex1 >= F::new(-30.0) {
                            let kp = kap1 * F::exp(ex1);
                            let e = expm1::<F>(kp);
                            let wd = wc * (e + F::new(1.0)) * kp;
                            rho += e;
                            sk1 += wd;
                            sg1 += wd * gam1 * lc;
                        }
                        let ex2 = gam2 * lc;
                        if ex2 >= F::new(-30.0) {
                            let kp = kap2 * F::exp(ex2);
                            let e = expm1::<F>(kp);
                            let wd = wc * (e + F::new(1.0)) * kp;
                            rho += e;
                            sk2 += wd;
                            sg2 += wd * gam2 * lc;
                        }
                        sl += gc * rho * ci;
                    }
                }
            }
            tk0 += sk0;
            tk1 += sk1;
            tk2 += sk2;
            tg0 += sg0;
            tg1 += sg1;
            tg2 += sg2;
            tl += sl;
        }
        let o = i / texels * 7 * texels + t;
        out[o] = tk0;
        out[o + texels] = tk1;
        out[o + 2 * texels] = tk2;
        out[o + 3 * texels] = tg0;
        out[o + 4 * texels] = tg1;
        out[o + 5 * texels] = tg2;
        out[o + 6 * texels] = tl;
    }
}

/// ∂loss/∂x for the 108 normalised parameters of every material: thread (b, r, j). Clamped and
/// NaN parameters get 0 (`material::knot_gradient`).
#[cube(launch)]
pub fn knot_grad_kernel<F: Float>(
    materials: &Tensor<F>,
    table: &Tensor<F>,
    texel_grads: &Tensor<F>,
    grad_m: &mut Tensor<F>,
    texels: usize,
    bk: f32,
    bg: f32,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < materials.len() {
        let j = i % 108;
        let br = i / 108;
        let knot = j % 6;
        let is_gamma = (j / 6) % 2;
        let q = j / 12;
        let c = q / 3;
        let k = q % 3;
        let src = ((br * 3 + c) * 7 + is_gamma * 3 + k) * texels;
        let mut total = F::new(0.0);
        let blocks = (texels + BLOCK - 1) / BLOCK;
        for blk in 0..blocks {
            let mut s = F::new(0.0);
            let mut end = (blk + 1) * BLOCK;
            if end > texels {
                end = texels;
            }
            for t in blk * BLOCK..end {
                let seg = usize::cast_from(table[7 * texels + t]);
                let u = table[8 * texels + t];
                if seg == knot {
                    s += (F::new(1.0) - u) * texel_grads[src + t];
                } else if seg + 1 == knot {
                    s += u * texel_grads[src + t];
                }
            }
            total += s;
        }
        let mut scale = F::cast_from(bk);
        if is_gamma == 1 {
            scale = F::cast_from(bg);
        }
        let x = materials[i];
        let mut g = F::new(0.0);
        if x >= F::new(-1.0) && x <= F::new(1.0) {
            g = total * scale;
        }
        grad_m[i] = g;
    }
}

/// ∂loss/∂L per image, channel and texel: the regions' ∂/∂(L·dω) times dω, 0 where the radiance
/// was clamped to 0 (negative or non-finite) or above the cap: thread (b, c, t).
#[cube(launch)]
pub fn env_grad_kernel<F: Float>(
    env: &Tensor<F>,
    table: &Tensor<F>,
    texel_grads: &Tensor<F>,
    grad_env: &mut Tensor<F>,
    texels: usize,
    materials: usize,
    cap: f32,
    #[define(F)] _dtype: ElemType,
) {
    let i = ABSOLUTE_POS;
    if i < env.len() {
        let t = i % texels;
        let c = (i / texels) % 3;
        let b = i / (3 * texels);
        let mut s = F::new(0.0);
        for r in 0..materials {
            s += texel_grads[(((b * materials + r) * 3 + c) * 7 + 6) * texels + t];
        }
        let l = env[i];
        let mut g = F::new(0.0);
        if finite::<F>(l) && l >= F::new(0.0) && l <= F::cast_from(cap) {
            g = s * table[6 * texels + t];
        }
        grad_env[i] = g;
    }
}

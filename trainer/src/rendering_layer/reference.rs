//! The rendering layer as plain Burn tensor operations, differentiated by Burn's autodiff.
//!
//! It evaluates the same function as the fused [`super::RenderingLayer`] (Eq. 2 with
//! cos θ_h = 1 − ½|n − h|², κ and γ log-linear in θ_d), but through a different route: whole
//! pixel × texel tensors, `std` exp/ln, and gradients that nobody derived by hand. That makes it
//! the independent check of the fused kernel's analytic backward pass. It is also what a
//! straightforward tensor implementation costs: every intermediate is pixels × texels large, so it
//! works on pixel chunks and takes each chunk's vector–Jacobian product before the next.

use super::material::{MEMBERS, knot_index, log_affine};
use super::{Gradients, LayerInput, RenderError, RenderingLayer};
use burn::tensor::{Device, Tensor, TensorData};
use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, KNOTS, PARAMS};

/// Pixels per chunk: bounds the pixel × texel intermediates (and the peak memory).
pub const CHUNK: usize = 256;

struct Constants {
    /// Texel directions and half vectors, `[3, T]`.
    w: Tensor<2>,
    h: Tensor<2>,
    /// |h|², `[1, T]`.
    h2: Tensor<2>,
    /// Solid angles, `[1, T]`.
    sa: Tensor<2>,
    /// θ_d interpolation matrix `[KNOTS, T]`: ln κ(θ_d,t) = Σ_j ln κ_j · interp[j, t].
    interp: Tensor<2>,
}

fn constants(layer: &RenderingLayer, device: &Device) -> Constants {
    let tex = layer.texels();
    let t = tex.count();
    let row = |v: &[f32]| v[..t].to_vec();
    let three = |a: &[Vec<f32>; 3]| {
        let mut v = row(&a[0]);
        v.extend(row(&a[1]));
        v.extend(row(&a[2]));
        Tensor::<2>::from_data(TensorData::new(v, [3, t]), device)
    };
    let h = three(&tex.h);
    let h2 = h.clone().powi_scalar(2).sum_dim(0);
    let mut interp = vec![0.0f32; KNOTS * t];
    for i in 0..t {
        let (s, u) = (tex.seg[i] as usize, tex.u[i]);
        interp[s * t + i] += 1.0 - u;
        interp[(s + 1) * t + i] += u;
    }
    Constants {
        w: three(&tex.w),
        h,
        h2,
        sa: Tensor::from_data(TensorData::new(row(&tex.sa), [1, t]), device),
        interp: Tensor::from_data(TensorData::new(interp, [KNOTS, t]), device),
    }
}

/// Per-texel `[1, T]` ln κ or ln γ of member `q` from the material leaf `x` (`[108]`).
fn lobe(x: &Tensor<1>, q: usize, gamma: bool, c: &Constants) -> Tensor<2> {
    let (a, b) = log_affine(if gamma { GAMMA_RANGE } else { KAPPA_RANGE });
    let start = knot_index(q, gamma, 0);
    let knots = x
        .clone()
        .narrow(0, start, KNOTS)
        .clamp(-1.0, 1.0)
        .mul_scalar(b)
        .add_scalar(a);
    knots.reshape([1, KNOTS]).matmul(c.interp.clone())
}

/// Radiance `[P, 3]` of `n` (`[P, 3]`) with material `x` (`[108]`) and radiance `env` (`[3, T]`).
fn shade(n: Tensor<2>, x: &Tensor<1>, env: &Tensor<2>, c: &Constants) -> Tensor<2> {
    let ci = n.clone().matmul(c.w.clone());
    let n2 = n.clone().powi_scalar(2).sum_dim(1);
    let omc = (n2 + c.h2.clone() - n.clone().matmul(c.h.clone()).mul_scalar(2.0)).mul_scalar(0.5);
    let facing = n.clone().narrow(1, 2, 1).greater_elem(0.0).float();
    let front = ci
        .clone()
        .greater_elem(0.0)
        .bool_and(omc.clone().lower_elem(1.0))
        .float()
        * facing;
    let lc = (omc.neg().add_scalar(1.0)).clamp(1e-30, 1.0).log();
    let weight = ci * front;
    let mut out = Vec::new();
    for ch in 0..3 {
        let mut rho: Option<Tensor<2>> = None;
        for k in 0..3 {
            let q = ch * 3 + k;
            let kappa = lobe(x, q, false, c).exp();
            let gamma = lobe(x, q, true, c).exp();
            let e = (kappa * (gamma * lc.clone()).exp()).exp().sub_scalar(1.0);
            rho = Some(match rho {
                Some(r) => r + e,
                None => e,
            });
        }
        let lsa = env.clone().narrow(0, ch, 1).clamp(0.0, super::MAX_RADIANCE) * c.sa.clone();
        let rho = rho.unwrap_or_else(|| weight.zeros_like());
        out.push((rho * weight.clone() * lsa).sum_dim(1));
    }
    Tensor::cat(out, 1)
}

fn leaf<const D: usize>(v: Vec<f32>, shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::<D>::from_data(TensorData::new(v, shape), device).require_grad()
}

fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap_or_default()
}

/// Forward output `[B, 3, H, W]` and the gradients of Σ output ⊙ `upstream`, computed chunk by
/// chunk on `device` (which must have autodiff enabled for the gradients).
pub fn forward_backward(
    layer: &RenderingLayer,
    b: &LayerInput,
    upstream: &[f32],
    device: &Device,
) -> Result<(Vec<f32>, Gradients), RenderError> {
    layer.check(b)?;
    let t = layer.texels().count();
    let p = b.size.0 * b.size.1;
    let c = constants(layer, device);
    let mut out = vec![0.0; b.batch * 3 * p];
    let mut grads = Gradients {
        normals: vec![0.0; b.batch * 3 * p],
        materials: vec![0.0; b.batch * b.regions * PARAMS],
        env: vec![0.0; b.batch * 3 * t],
    };
    for i in 0..b.batch {
        for r in 0..b.regions {
            let pixels: Vec<usize> = (0..p).filter(|&k| b.region_map[i * p + k] as usize == r + 1).collect();
            let mo = (i * b.regions + r) * PARAMS;
            for chunk in pixels.chunks(CHUNK) {
                let nv: Vec<f32> = chunk
                    .iter()
                    .flat_map(|&k| (0..3).map(move |a| b.normals[(i * 3 + a) * p + k]))
                    .collect();
                let gv: Vec<f32> = chunk
                    .iter()
                    .flat_map(|&k| (0..3).map(move |a| upstream[(i * 3 + a) * p + k]))
                    .collect();
                let n = leaf(nv, [chunk.len(), 3], device);
                let x = leaf(b.materials[mo..mo + PARAMS].to_vec(), [PARAMS], device);
                let env = leaf(b.env[i * 3 * t..(i + 1) * 3 * t].to_vec(), [3, t], device);
                let rgb = shade(n.clone(), &x, &env, &c);
                let g = Tensor::<2>::from_data(TensorData::new(gv, [chunk.len(), 3]), device);
                let loss = (rgb.clone() * g).sum();
                let tape = loss.backward();
                let rgb = to_vec(rgb.detach());
                for (j, &k) in chunk.iter().enumerate() {
                    for a in 0..3 {
                        out[(i * 3 + a) * p + k] = rgb[j * 3 + a];
                    }
                }
                if let Some(gn) = n.grad(&tape) {
                    let gn = to_vec(gn);
                    for (j, &k) in chunk.iter().enumerate() {
                        for a in 0..3 {
                            grads.normals[(i * 3 + a) * p + k] = gn[j * 3 + a];
                        }
                    }
                }
                if let Some(gx) = x.grad(&tape) {
                    for (d, s) in grads.materials[mo..mo + PARAMS].iter_mut().zip(to_vec(gx)) {
                        *d += s;
                    }
                }
                if let Some(ge) = env.grad(&tape) {
                    for (d, s) in grads.env[i * 3 * t..(i + 1) * 3 * t].iter_mut().zip(to_vec(ge)) {
                        *d += s;
                    }
                }
            }
        }
    }
    debug_assert_eq!(MEMBERS, 9);
    Ok((out, grads))
}

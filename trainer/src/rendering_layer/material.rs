//! The DSBRDF lobes of one material at every texel's θ_d.
//!
//! The network predicts the 108 parameters normalised to the tanh range (see
//! `matedit_physics::brdf::dsbrdf`): each raw parameter is v = exp(A + B·x), log-affine in x, and
//! the DSBRDF interpolates κ and γ log-linearly in θ_d, so ln κ(θ_d) is affine in the two
//! neighbouring knots' x. That makes both the per-texel lobes and their gradient with respect to
//! x cheap and exact.

use super::texels::TexelTable;
use matedit_physics::brdf::dsbrdf::{GAMMA_RANGE, KAPPA_RANGE, KNOTS, LOBES, NORMALISED_BOUND, PARAMS};

/// Lobes per material: 3 colour channels × [`LOBES`].
pub const MEMBERS: usize = 3 * LOBES;

/// (A, B) of v = exp(A + B·x) for a parameter with raw range `(lo, hi)`.
pub fn log_affine((lo, hi): (f64, f64)) -> (f64, f64) {
    let b = (hi.ln() - lo.ln()) / (2.0 * NORMALISED_BOUND);
    (lo.ln() + NORMALISED_BOUND * b, b)
}

/// Flat index of knot `j` of member `q` (= channel·3 + lobe), κ when `gamma` is false.
pub fn knot_index(q: usize, gamma: bool, j: usize) -> usize {
    (q * 2 + gamma as usize) * KNOTS + j
}

/// κ and γ of the 9 members at every texel: `kappa[q][t]`, `gamma[q][t]`.
#[derive(Clone, Debug)]
pub struct MaterialTexels {
    pub(crate) kappa: [Vec<f32>; MEMBERS],
    pub(crate) gamma: [Vec<f32>; MEMBERS],
}

impl MaterialTexels {
    /// Lobes of the normalised material `x` (108 values; clamped to [−1, 1] like
    /// `Dsbrdf::from_normalised`, NaN treated as 0 so that it cannot spread).
    pub fn new(x: &[f32], tex: &TexelTable) -> Self {
        assert_eq!(x.len(), PARAMS, "a material has {PARAMS} parameters");
        let ln_v = |q: usize, gamma: bool, j: usize| {
            let (a, b) = log_affine(if gamma { GAMMA_RANGE } else { KAPPA_RANGE });
            a + b * clamp_x(x[knot_index(q, gamma, j)]) as f64
        };
        let n = tex.padded();
        let mut kappa: [Vec<f32>; MEMBERS] = std::array::from_fn(|_| vec![0.0; n]);
        let mut gamma: [Vec<f32>; MEMBERS] = std::array::from_fn(|_| vec![0.0; n]);
        for q in 0..MEMBERS {
            let lk: [f64; KNOTS] = std::array::from_fn(|j| ln_v(q, false, j));
            let lg: [f64; KNOTS] = std::array::from_fn(|j| ln_v(q, true, j));
            for t in 0..n {
                let (s, u) = (tex.seg[t] as usize, tex.u[t] as f64);
                kappa[q][t] = (lk[s] + u * (lk[s + 1] - lk[s])).exp() as f32;
                gamma[q][t] = (lg[s] + u * (lg[s + 1] - lg[s])).exp() as f32;
            }
        }
        Self { kappa, gamma }
    }
}

/// x clamped to what tanh can output; NaN → 0.
pub fn clamp_x(x: f32) -> f32 {
    if x.is_nan() { 0.0 } else { x.clamp(-1.0, 1.0) }
}

/// Gradient of the per-texel lobe sums with respect to the normalised parameters: `gk[q][t]` is
/// ∂loss/∂ln κ_q(θ_d,t), `gg[q][t]` ∂loss/∂ln γ_q(θ_d,t). Clamped parameters get zero gradient.
pub fn knot_gradient(x: &[f32], gk: &[Vec<f64>], gg: &[Vec<f64>], tex: &TexelTable) -> [f32; PARAMS] {
    let mut out = [0.0f64; PARAMS];
    let (_, bk) = log_affine(KAPPA_RANGE);
    let (_, bg) = log_affine(GAMMA_RANGE);
    for q in 0..MEMBERS {
        for t in 0..tex.count() {
            let (s, u) = (tex.seg[t] as usize, tex.u[t] as f64);
            for (gamma, g, b) in [(false, &gk[q], bk), (true, &gg[q], bg)] {
                let v = g[t] * b;
                out[knot_index(q, gamma, s)] += (1.0 - u) * v;
                out[knot_index(q, gamma, s + 1)] += u * v;
            }
        }
    }
    std::array::from_fn(|i| {
        let xi = x[i];
        if xi.is_nan() || !(-1.0..=1.0).contains(&xi) {
            0.0
        } else {
            out[i] as f32
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use matedit_physics::brdf::Dsbrdf;

    #[test]
    fn texel_lobes_match_the_physics_crate() {
        let tex = TexelTable::new(16);
        let x: Vec<f32> = (0..PARAMS)
            .map(|i| ((i * 37 % 101) as f32 / 50.0 - 1.0) * 0.9)
            .collect();
        let m = Dsbrdf::from_normalised(&x.iter().map(|&v| v as f64).collect::<Vec<_>>()).unwrap();
        let mt = MaterialTexels::new(&x, &tex);
        for t in (0..tex.count()).step_by(7) {
            let w = glam::DVec3::new(tex.w[0][t] as f64, tex.w[1][t] as f64, tex.w[2][t] as f64);
            let h = (w + glam::DVec3::Z).normalize();
            let lobes = m.lobes_at(w.dot(h).clamp(0.0, 1.0).acos());
            for q in 0..MEMBERS {
                let (k, g) = lobes[q / 3][q % 3];
                assert!((mt.kappa[q][t] as f64 / k - 1.0).abs() < 1e-5, "kappa q{q} t{t}");
                assert!((mt.gamma[q][t] as f64 / g - 1.0).abs() < 1e-5, "gamma q{q} t{t}");
            }
        }
    }

    #[test]
    fn out_of_range_and_nan_inputs_stay_finite() {
        let tex = TexelTable::new(4);
        let mut x = vec![5.0f32; PARAMS];
        x[0] = f32::NAN;
        x[1] = f32::NEG_INFINITY;
        let mt = MaterialTexels::new(&x, &tex);
        assert!(
            mt.kappa
                .iter()
                .chain(&mt.gamma)
                .flatten()
                .all(|v| v.is_finite() && *v > 0.0)
        );
        let ones: Vec<Vec<f64>> = vec![vec![1.0; tex.padded()]; MEMBERS];
        let g = knot_gradient(&x, &ones, &ones, &tex);
        assert!(g.iter().all(|v| *v == 0.0), "clamped parameters have no gradient");
    }
}

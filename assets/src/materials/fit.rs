//! Fitting a 3-lobe DSBRDF to any isotropic BRDF.
//!
//! The DSBRDF depends on (θ_h, θ_d) only, and its κ, γ are given at 6 θ_d knots. So the fit is
//! done knot by knot and channel by channel: at θ_d = knot (89° for the 90° knot, where every
//! configuration is at the horizon), the source BRDF is sampled on 64 square-root-spaced θ_h
//! values and averaged over φ_d (12 values, valid configurations only, the DSBRDF having no φ_d
//! dependence), and the three lobes (ln κ, ln γ for each: 6 parameters) are fitted by
//! Levenberg–Marquardt (the `levenberg-marquardt` crate) to
//!
//! ```text
//! r_i = w_i · [ ln(1 + ρ_fit(θ_h,i)/s) − ln(1 + ρ_src(θ_h,i)/s) ],   s = 0.02 sr⁻¹
//! ```
//!
//! The log compresses highlights 10⁴ times brighter than the diffuse floor into the same range
//! (relative error above s, absolute below); w_i² is the solid angle of the θ_h bin, so each
//! residual counts as much as the light it reflects in a rendering. Four starting points
//! (diffuse + lobes of sharpness 10/300, 3/50, 100/3000, 30/1000) are tried and the lowest cost
//! kept.

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use matedit_physics::brdf::dsbrdf::{
    CHANNELS, GAMMA_RANGE, KAPPA_RANGE, LOBES, LobeParam, PARAMS, THETA_D_KNOTS_DEG, param_index,
};
use matedit_physics::brdf::{Brdf, BrdfModel, Dsbrdf};
use nalgebra::{Dyn, OMatrix, OVector, U6};
use std::f64::consts::{FRAC_PI_2, PI};

const N_THETA_H: usize = 64;
const N_PHI_D: usize = 12;
const SCALE: f64 = 0.02;

/// How well a fit reproduces its source.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    /// RMS of the weighted log residuals over all knots and channels (BRDF space).
    pub brdf_log_rmse: f64,
    /// Relative RMSE of a sphere rendered with the fit against the source, per environment.
    pub rendered: Vec<(String, f64)>,
}

/// Samples of one θ_d slice of one channel: (θ_h, ρ, weight).
struct Slice {
    theta_h: Vec<f64>,
    rho: Vec<f64>,
    weight: Vec<f64>,
}

/// The source sampled at every knot: `slices[knot][channel]`.
fn sample(brdf: &dyn Brdf) -> Vec<[Slice; CHANNELS]> {
    THETA_D_KNOTS_DEG
        .iter()
        .map(|&deg| {
            let td = deg.min(89.0).to_radians();
            let mut out: [Slice; CHANNELS] = std::array::from_fn(|_| Slice {
                theta_h: Vec::new(),
                rho: Vec::new(),
                weight: Vec::new(),
            });
            for i in 0..N_THETA_H {
                let (a, b) = (
                    (i as f64 / N_THETA_H as f64).powi(2),
                    ((i + 1) as f64 / N_THETA_H as f64).powi(2),
                );
                let th = ((i as f64 + 0.5) / N_THETA_H as f64).powi(2) * FRAC_PI_2;
                let solid = (a * FRAC_PI_2).cos() - (b * FRAC_PI_2).cos();
                let (mut acc, mut valid) = ([0.0; CHANNELS], 0);
                for k in 0..N_PHI_D {
                    let pd = (k as f64 + 0.5) / N_PHI_D as f64 * PI;
                    let (wi, wo) = matedit_physics::brdf::merl::half_diff_to_directions(th, td, pd);
                    if wi.z > 1e-6 && wo.z > 1e-6 {
                        let f = brdf.eval(wi, wo);
                        for c in 0..CHANNELS {
                            acc[c] += f[c];
                        }
                        valid += 1;
                    }
                }
                // A θ_h the camera can only see at a few azimuths is weighted down accordingly.
                if valid == 0 {
                    continue;
                }
                let share = valid as f64 / N_PHI_D as f64;
                for c in 0..CHANNELS {
                    out[c].theta_h.push(th);
                    out[c].rho.push(acc[c] / valid as f64);
                    out[c].weight.push((solid * share).sqrt());
                }
            }
            out
        })
        .collect()
}

fn clamp_log(x: f64, (lo, hi): (f64, f64)) -> f64 {
    if x.is_nan() { lo.ln() } else { x.clamp(lo.ln(), hi.ln()) }
}

/// One slice's least-squares problem over x = (ln κ₁, ln γ₁, …, ln κ₃, ln γ₃).
struct SliceProblem<'a> {
    s: &'a Slice,
    x: OVector<f64, U6>,
}

impl SliceProblem<'_> {
    fn lobes(&self) -> [(f64, f64); LOBES] {
        std::array::from_fn(|k| (self.x[2 * k].exp(), self.x[2 * k + 1].exp()))
    }
}

impl LeastSquaresProblem<f64, Dyn, U6> for SliceProblem<'_> {
    type ResidualStorage = nalgebra::VecStorage<f64, Dyn, nalgebra::U1>;
    type JacobianStorage = nalgebra::VecStorage<f64, Dyn, U6>;
    type ParameterStorage = nalgebra::ArrayStorage<f64, 6, 1>;

    fn set_params(&mut self, x: &OVector<f64, U6>) {
        for k in 0..LOBES {
            self.x[2 * k] = clamp_log(x[2 * k], KAPPA_RANGE);
            self.x[2 * k + 1] = clamp_log(x[2 * k + 1], GAMMA_RANGE);
        }
    }

    fn params(&self) -> OVector<f64, U6> {
        self.x
    }

    fn residuals(&self) -> Option<OVector<f64, Dyn>> {
        let lobes = self.lobes();
        let r = self
            .s
            .theta_h
            .iter()
            .zip(&self.s.rho)
            .zip(&self.s.weight)
            .map(|((&th, &rho), &w)| {
                let c = th.cos();
                let fit: f64 = lobes.iter().map(|&(k, g)| (k * c.powf(g)).exp_m1()).sum();
                w * ((fit / SCALE).ln_1p() - (rho.max(0.0) / SCALE).ln_1p())
            });
        Some(OVector::<f64, Dyn>::from_iterator(self.s.rho.len(), r))
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U6>> {
        let lobes = self.lobes();
        let mut j = OMatrix::<f64, Dyn, U6>::zeros(self.s.rho.len());
        for (i, (&th, &w)) in self.s.theta_h.iter().zip(&self.s.weight).enumerate() {
            let c = th.cos();
            let lc = c.ln();
            let fit: f64 = lobes.iter().map(|&(k, g)| (k * c.powf(g)).exp_m1()).sum();
            let outer = w / (SCALE + fit);
            for (k, &(kap, gam)) in lobes.iter().enumerate() {
                let p = c.powf(gam);
                let e = (kap * p).exp();
                j[(i, 2 * k)] = outer * e * kap * p;
                j[(i, 2 * k + 1)] = outer * e * kap * p * gam * lc;
            }
        }
        Some(j)
    }
}

fn fit_slice(s: &Slice) -> ([(f64, f64); LOBES], f64) {
    // Diffuse floor from the wide half-angles, peak from the narrowest.
    let tail: Vec<f64> = s
        .theta_h
        .iter()
        .zip(&s.rho)
        .filter(|(t, _)| **t > 0.6)
        .map(|(_, r)| *r)
        .collect();
    let floor = if tail.is_empty() {
        0.01
    } else {
        tail.iter().sum::<f64>() / tail.len() as f64
    };
    let peak = s.rho.first().copied().unwrap_or(floor);
    let kd = (floor.max(1e-4)).ln_1p();
    let ks = (peak - floor).max(1e-4).ln_1p();
    let mut best: Option<([(f64, f64); LOBES], f64)> = None;
    for (g2, g3) in [(10.0_f64, 300.0_f64), (3.0, 50.0), (100.0, 3000.0), (30.0, 1000.0)] {
        let x0 = OVector::<f64, U6>::from_column_slice(&[
            clamp_log(kd.ln(), KAPPA_RANGE),
            GAMMA_RANGE.0.ln(),
            clamp_log((0.5 * ks).ln(), KAPPA_RANGE),
            g2.ln(),
            clamp_log((0.5 * ks).ln(), KAPPA_RANGE),
            g3.ln(),
        ]);
        let mut problem = SliceProblem { s, x: x0 };
        let x = problem.x;
        problem.set_params(&x);
        let (done, _) = LevenbergMarquardt::new().with_patience(200).minimize(problem);
        let cost = done.residuals().map_or(f64::INFINITY, |r| r.norm_squared());
        if cost.is_finite() && best.as_ref().is_none_or(|b| cost < b.1) {
            best = Some((done.lobes(), cost));
        }
    }
    best.unwrap_or(([(KAPPA_RANGE.0, GAMMA_RANGE.0); LOBES], f64::INFINITY))
}

/// Fits the 108 DSBRDF parameters to `brdf`. Returns the material and the BRDF-space error
/// (RMS of the weighted log residuals).
pub fn fit_dsbrdf(brdf: &dyn Brdf) -> (Dsbrdf, f64) {
    let slices = sample(brdf);
    let mut params = [0.0; PARAMS];
    let (mut cost, mut count) = (0.0, 0usize);
    for (j, knot) in slices.iter().enumerate() {
        for (c, slice) in knot.iter().enumerate() {
            let (mut lobes, sq) = fit_slice(slice);
            // θ_d interpolation pairs lobes by index, so lobe k must mean the same thing at every
            // knot: order them from flattest to sharpest.
            lobes.sort_by(|a, b| a.1.total_cmp(&b.1));
            cost += sq;
            count += slice.rho.len();
            for (k, &(kap, gam)) in lobes.iter().enumerate() {
                params[param_index(c, k, LobeParam::Kappa, j)] = kap.clamp(KAPPA_RANGE.0, KAPPA_RANGE.1);
                params[param_index(c, k, LobeParam::Gamma, j)] = gam.clamp(GAMMA_RANGE.0, GAMMA_RANGE.1);
            }
        }
    }
    // Every value was clamped into range above, so construction cannot fail.
    let m = Dsbrdf::from_params(&params).unwrap_or_else(|_| Dsbrdf::near_lambertian([0.5; 3]));
    (m, (cost / count.max(1) as f64).sqrt())
}

/// Relative RMSE between a unit sphere (`res`²) rendered with `fit` and with `source`, under
/// each environment (exact path for measured sources, fast otherwise).
pub fn rendered_errors(
    source: &BrdfModel,
    fit: &Dsbrdf,
    envs: &[(String, matedit_physics::EnvMap)],
    res: usize,
) -> Vec<(String, f64)> {
    use matedit_physics::shading::{Quality, make_shader, shade_image};
    let (normals, mask) = matedit_physics::camera::unit_sphere_normals(res);
    let fit = BrdfModel::Dsbrdf(Box::new(fit.clone()));
    envs.iter()
        .map(|(name, env)| {
            let a = shade_image(make_shader(source, env, Quality::Fast).as_ref(), &normals, &mask, None).0;
            let b = shade_image(make_shader(&fit, env, Quality::Fast).as_ref(), &normals, &mask, None).0;
            let (mut num, mut den) = (0.0, 0.0);
            for (x, y) in a.iter().zip(&b) {
                for c in 0..3 {
                    num += (x[c] as f64 - y[c] as f64).powi(2);
                    den += (x[c] as f64).powi(2);
                }
            }
            (name.clone(), (num / den.max(1e-300)).sqrt())
        })
        .collect()
}

/// The three environments fits are judged under: a sunny sky, a softbox studio, a window-lit
/// room (procedural seeds 1, 2, 3 at 32×64).
pub fn judging_envs() -> Vec<(String, matedit_physics::EnvMap)> {
    use crate::envmaps::Family;
    [(Family::SunSky, 1), (Family::Softbox, 2), (Family::Window, 3)]
        .into_iter()
        .map(|(f, s)| (format!("{}:{s}", f.name()), f.generate(s, 256).resampled(32, 0.0)))
        .collect()
}

/// Fits and judges: the material and its report.
pub fn fit_and_report(source: &BrdfModel) -> (Dsbrdf, FitReport) {
    let (m, brdf_log_rmse) = fit_dsbrdf(source);
    let rendered = rendered_errors(source, &m, &judging_envs(), 64);
    (
        m,
        FitReport {
            brdf_log_rmse,
            rendered,
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_of_analytic_brdfs_render_within_5_percent_at_the_median() {
        // The DSBRDF has no φ_d dependence and its lobes fall monotonically in θ_h, while GGX's
        // masking raises the BRDF at grazing: under light from near the horizon (the window
        // room) that costs up to ~11 %. The median over materials and environments is the
        // issue's criterion.
        let mut all = Vec::new();
        for spec in [
            "lambert:0.6,0.4,0.2",
            "plastic:0.2:0.5,0.1,0.1",
            "ggx:0.3:0.95,0.64,0.54",
            "ggx:0.15:0.9,0.9,0.9",
            "ggx:0.3:1,1,1",
            "ggx:0.6:1,1,1",
        ] {
            let src = spec.parse::<matedit_physics::BrdfSpec>().unwrap().build().unwrap();
            let (_, report) = fit_and_report(&src);
            for (env, e) in &report.rendered {
                assert!(*e < 0.12, "{spec} under {env}: rendered error {e}");
                all.push(*e);
            }
            if spec.starts_with("lambert") {
                assert!(report.rendered.iter().all(|(_, e)| *e < 0.005), "{report:?}");
            }
        }
        all.sort_by(|a, b| a.total_cmp(b));
        let median = (all[all.len() / 2 - 1] + all[all.len() / 2]) / 2.0;
        assert!(median < 0.05, "median rendered error {median}");
    }

    #[test]
    fn lobes_are_ordered_from_flat_to_sharp_at_every_knot() {
        let src = "ggx:0.15:0.9,0.9,0.9"
            .parse::<matedit_physics::BrdfSpec>()
            .unwrap()
            .build()
            .unwrap();
        let (m, _) = fit_dsbrdf(&src);
        for deg in THETA_D_KNOTS_DEG {
            let l = m.lobes_at(deg.to_radians());
            for ch in l {
                assert!(ch[0].1 <= ch[1].1 && ch[1].1 <= ch[2].1, "{deg}: {ch:?}");
            }
        }
    }
}

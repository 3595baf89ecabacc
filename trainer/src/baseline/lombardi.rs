//! Lombardi & Nishino (ECCV 2012), "Reflectance and natural illumination from a single image",
//! as the optimisation baseline of Table 3 (Sec. 4.5): given the **true** normals n, recover the
//! material m* and the light L* of one image by minimising
//!
//! ```text
//! E(m*, L*) = ‖R(n, m*, L*) − I‖²  +  w_m Σ_j ((m*_j − μ_j)/σ_j)²  +  w_L Σ ρ(ln L*_a − ln L*_b)
//! ```
//!
//! through the same rendering layer (Eq. 2) as the network, from an uninformed start; O' is then
//! R(n, m_t, L*). The paper gives this baseline the true normals and says no more about it; the
//! original method differs from what is here in ways we had to choose, each marked **Choice**
//! below and listed in docs/DESIGN.md ("Baselines"):
//!
//! * **Choice (reflectance model).** The original fits its own DSBRDF variant; here m* is the
//!   paper's 108-parameter DSBRDF in the normalised (tanh) space the network predicts, so that
//!   every method of Table 3 renders through one layer.
//! * **Choice (reflectance prior).** The original puts a prior learnt from measured BRDFs on its
//!   parameters; here a diagonal Gaussian over the 108 normalised parameters, fitted (mean and
//!   variance, σ ≥ [`SIGMA_FLOOR`]) to the materials of the dataset's training splits.
//! * **Choice (illumination prior).** The original's natural-illumination prior models the
//!   heavy-tailed statistics of real environment maps; here the heavy-tailed (Charbonnier)
//!   penalty ρ(d) = √(d² + ε²) − ε on the differences of log radiance between neighbouring
//!   texels of each channel ([`LightPrior`]), uniform over the sphere.
//! * **Choice (weights).** The prior weights are relative: E is divided by N·s² (N the object's
//!   pixel values, s² their mean square), so `material_weight` weighs the mean squared z-score
//!   of the parameters and `light_weight` the mean ρ over texel pairs against the relative
//!   squared image error; the defaults were picked on the *training* split (docs/PERFORMANCE.md).
//! * **Choice (start).** "Uninformed": every region at the prior mean μ and a constant grey
//!   light whose level c minimises ‖R(n, μ, c·1) − I‖² (R is linear in L: a closed form).
//! * **Choice (solver).** The original alternates reflectance and illumination updates; here
//!   L-BFGS on m* then on L* (the machinery of Eq. 6, [`alternate`]) for `rounds` rounds.

use crate::model::prediction::Prediction;
use crate::post_optimisation::{Eq6Config, LightPrior, MaterialPrior, Optimised, Priors, Problem, Property, alternate};
use crate::rendering_layer::{LayerInput, RenderingLayer};
use anyhow::{Result, bail};
use matedit_physics::brdf::dsbrdf::PARAMS;
use serde::{Deserialize, Serialize};

/// The smallest standard deviation of the reflectance prior: a parameter every training
/// material shares is not pinned harder than this.
pub const SIGMA_FLOOR: f64 = 0.05;

/// The baseline's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LombardiConfig {
    /// w_m, relative (see the module's "Choice (weights)").
    pub material_weight: f64,
    /// w_L, relative.
    pub light_weight: f64,
    /// ε of the light prior's ρ, in ln units.
    pub light_epsilon: f64,
    /// Rounds of (material, light).
    pub rounds: usize,
    /// L-BFGS iterations per property and round.
    pub iterations: usize,
    /// L-BFGS history.
    pub history: usize,
}

/// The defaults were picked on 16 samples of the quickstart's *training* split (O' L2 of
/// 1,139 against 1,331 for two rounds of six iterations, 1,302 to 2,060 for other weights;
/// docs/PERFORMANCE.md, "Table 3").
impl Default for LombardiConfig {
    fn default() -> Self {
        Self {
            material_weight: 1.0,
            light_weight: 0.1,
            light_epsilon: 0.1,
            rounds: 3,
            iterations: 8,
            history: 7,
        }
    }
}

impl LombardiConfig {
    /// Checks the settings a user can give.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("material weight (--lombardi-material-weight)", self.material_weight),
            ("light weight (--lombardi-light-weight)", self.light_weight),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                bail!("Lombardi baseline: the {name} must be finite and ≥ 0, got {v}");
            }
        }
        if !(self.light_epsilon.is_finite() && self.light_epsilon > 0.0) {
            bail!(
                "Lombardi baseline: ε must be finite and > 0, got {}",
                self.light_epsilon
            );
        }
        if self.rounds == 0 || self.iterations == 0 {
            bail!(
                "Lombardi baseline: rounds (--lombardi-rounds) and iterations (--lombardi-iterations) must be ≥ 1, got {} and {}",
                self.rounds,
                self.iterations
            );
        }
        Ok(())
    }
}

/// The reflectance prior: a diagonal Gaussian over the normalised parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReflectancePrior {
    /// μ.
    pub mean: Vec<f64>,
    /// σ (≥ [`SIGMA_FLOOR`]).
    pub sigma: Vec<f64>,
    /// Materials it was fitted to.
    pub materials: usize,
}

impl ReflectancePrior {
    /// Fits μ and σ to normalised materials (108 values each, finite).
    pub fn fit(materials: &[&[f32; PARAMS]]) -> Result<Self> {
        if materials.is_empty() {
            bail!("Lombardi baseline: no training material to fit the reflectance prior to");
        }
        if let Some(m) = materials.iter().find(|m| m.iter().any(|v| !v.is_finite())) {
            bail!("Lombardi baseline: a training material has a non-finite parameter: {m:?}");
        }
        let n = materials.len() as f64;
        let mean: Vec<f64> = (0..PARAMS)
            .map(|j| materials.iter().map(|m| m[j] as f64).sum::<f64>() / n)
            .collect();
        let sigma = (0..PARAMS)
            .map(|j| {
                let var = materials.iter().map(|m| (m[j] as f64 - mean[j]).powi(2)).sum::<f64>() / n;
                var.sqrt().max(SIGMA_FLOOR)
            })
            .collect();
        Ok(Self {
            mean,
            sigma,
            materials: materials.len(),
        })
    }

    fn inv_var(&self) -> Vec<f64> {
        self.sigma.iter().map(|s| 1.0 / (s * s)).collect()
    }
}

/// One image to explain: its true normals, the object's regions, I.
pub struct Observed<'a> {
    /// Image side.
    pub size: usize,
    /// Material regions.
    pub regions: usize,
    /// I `[3, S, S]` (linear).
    pub image: &'a [f32],
    /// `[S, S]`, 0 off the object.
    pub region_map: &'a [u8],
    /// The true n `[3, S, S]`.
    pub normals: &'a [f32],
}

/// The uninformed start: μ in every region and the constant light c·1 that best explains I.
pub fn uninformed_start(layer: &RenderingLayer, o: &Observed, prior: &ReflectancePrior) -> Result<Prediction> {
    let he = layer.texels().height();
    let texels = 6 * he * he;
    let materials: Vec<f32> = (0..o.regions)
        .flat_map(|_| prior.mean.iter().map(|&v| v as f32))
        .collect();
    let unit = vec![1.0f32; texels];
    let r1 = layer.forward(&LayerInput {
        batch: 1,
        size: (o.size, o.size),
        regions: o.regions,
        normals: o.normals,
        region_map: o.region_map,
        materials: &materials,
        env: &unit,
    })?;
    let (mut ri, mut rr) = (0.0f64, 0.0f64);
    let p = o.size * o.size;
    for k in (0..p).filter(|&k| o.region_map[k] > 0) {
        for c in 0..3 {
            let (r, i) = (r1[c * p + k] as f64, o.image[c * p + k] as f64);
            if i.is_finite() {
                ri += r * i;
                rr += r * r;
            }
        }
    }
    let c = if rr > 0.0 && ri > 0.0 {
        (ri / rr).clamp(1e-6, 1e6)
    } else {
        1.0
    };
    Ok(Prediction {
        normals: o.normals.to_vec(),
        materials,
        env: vec![c as f32; texels],
    })
}

/// The recovered m* and L* (the point's normals are the true ones), with E at the uninformed
/// start and at the end.
pub fn recover(
    layer: &RenderingLayer,
    o: &Observed,
    prior: &ReflectancePrior,
    cfg: &LombardiConfig,
) -> Result<Optimised> {
    cfg.validate()?;
    let start = uninformed_start(layer, o, prior)?;
    let p = o.size * o.size;
    // N·s²: the image term's scale, so that the weights are relative (module docs).
    let (mut n, mut s2) = (0usize, 0.0f64);
    for k in (0..p).filter(|&k| o.region_map[k] > 0) {
        for c in 0..3 {
            let v = o.image[c * p + k] as f64;
            if v.is_finite() {
                n += 1;
                s2 += v * v;
            }
        }
    }
    let scale = if n > 0 && s2 > 0.0 { s2 } else { 1.0 };
    let he = layer.texels().height();
    let pairs = 3 * (2 * he * he + 2 * he * (he - 1));
    let inv_var = prior.inv_var();
    let zero_env = vec![0.0f32; start.env.len()];
    let problem = Problem {
        layer,
        size: o.size,
        regions: o.regions,
        image: o.image,
        region_map: o.region_map,
        normals: o.normals,
        env: &zero_env,
        a: 0.0,
        b: 0.0,
        priors: Priors {
            material: Some(MaterialPrior {
                weight: cfg.material_weight * scale / (o.regions * PARAMS) as f64,
                mean: &prior.mean,
                inv_var: &inv_var,
            }),
            light: Some(LightPrior {
                weight: cfg.light_weight * scale / pairs.max(1) as f64,
                epsilon: cfg.light_epsilon,
            }),
        },
    };
    let solver = Eq6Config {
        a: 0.0,
        b: 0.0,
        rounds: cfg.rounds,
        iterations: cfg.iterations,
        history: cfg.history,
        coarse_pixels: 0,
    };
    alternate(&problem, start, &solver, &[Property::Material, Property::Light], None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::synthetic::sphere_batch;

    fn render(layer: &RenderingLayer, size: usize, n: &[f32], map: &[u8], m: &[f32], env: &[f32]) -> Vec<f32> {
        layer
            .forward(&LayerInput {
                batch: 1,
                size: (size, size),
                regions: 1,
                normals: n,
                region_map: map,
                materials: m,
                env,
            })
            .unwrap()
    }

    /// A material family: a base drawn once and per-draw perturbations of ±0.15, so that the
    /// prior fitted to 64 draws is informative, as the training materials are.
    fn family(draw: u64) -> [f32; PARAMS] {
        let mut s = 0x9e37_79b9_7f4a_7c15_u64 ^ draw.wrapping_mul(0x2545_f491_4f6c_dd1d);
        let mut u = move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) as f32
        };
        let mut b = 0x1234_u64;
        let mut base = move || {
            b = b.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((b >> 11) as f64 / (1u64 << 53) as f64) as f32
        };
        std::array::from_fn(|_| (-0.6 + 1.0 * base() + 0.3 * (u() - 0.5)).clamp(-0.9, 0.9))
    }

    fn family_prior() -> ReflectancePrior {
        let mats: Vec<[f32; PARAMS]> = (0..64).map(family).collect();
        ReflectancePrior::fit(&mats.iter().collect::<Vec<_>>()).unwrap()
    }

    /// A smooth sky: brighter towards the zenith, a broad bright lobe around column `x0`, tinted.
    fn sky(he: usize, x0: usize, tint: [f32; 3]) -> Vec<f32> {
        let we = 2 * he;
        let mut env = Vec::with_capacity(3 * he * we);
        for t in tint {
            for y in 0..he {
                for x in 0..we {
                    let dx = (x as f32 - x0 as f32).abs();
                    let dx = dx.min(we as f32 - dx);
                    let up = 1.0 - y as f32 / he as f32;
                    env.push(t * (0.3 + 0.5 * up + 4.0 * (-dx * dx / 3.0).exp() * up));
                }
            }
        }
        env
    }

    #[test]
    fn recovers_a_known_material_and_light_on_a_synthetic_sphere() {
        use crate::eval::l2_tonemapped;
        let layer = RenderingLayer::new(4);
        let prior = family_prior();
        let size = 24;
        for seed in [3u64, 7, 11] {
            let hb = sphere_batch(1, size, 4, seed, &layer);
            let (n, map, mask) = (&hb.normals, &hb.region_map, &hb.mask);
            let at = |m: &[f32], env: &[f32]| render(&layer, size, n, map, m, env);
            let truth = family(1000 + seed);
            let light = sky(4, seed as usize % 8, [1.0, 0.9, 0.8]);
            let image = at(&truth, &light);
            let o = Observed {
                size,
                regions: 1,
                image: &image,
                region_map: map,
                normals: n,
            };
            let start = uninformed_start(&layer, &o, &prior).unwrap();
            let r = recover(&layer, &o, &prior, &LombardiConfig::default()).unwrap();
            let x = &r.point;
            let l2 = |a: &[f32], b: &[f32]| l2_tonemapped(a, b, mask, size, size);
            let target = &hb.target_materials;
            let o_true = at(target, &light);
            let fit = (
                l2(&at(&start.materials, &start.env), &image),
                l2(&at(&x.materials, &x.env), &image),
            );
            let edit = (l2(&at(target, &start.env), &o_true), l2(&at(target, &x.env), &o_true));
            let other = sky(4, (seed as usize + 4) % 8, [0.7, 0.9, 1.2]);
            let truth_novel = at(&truth, &other);
            let novel = (
                l2(&at(&start.materials, &other), &truth_novel),
                l2(&at(&x.materials, &other), &truth_novel),
            );
            let power = |e: &[f32]| e.iter().map(|v| *v as f64).sum::<f64>();
            let ratio = power(&x.env) / power(&light);
            let copy = l2(&image, &o_true);
            eprintln!(
                "seed {seed}: L2 of I' {fit:?}, O' {edit:?} (O' = I: {copy}), m under a novel light {novel:?}, power {ratio}"
            );
            // The stated tolerances (tone-mapped L2, the metric of Table 3; the 108 parameters
            // themselves are not identifiable from one image, what they render is):
            assert!(fit.1 < 0.05 * fit.0, "seed {seed}: I' {fit:?}");
            assert!(
                edit.1 < 0.8 * edit.0 && edit.1 < 0.2 * copy,
                "seed {seed}: O' {edit:?}, O' = I {copy}"
            );
            assert!(
                novel.1 < novel.0,
                "seed {seed}: the material under a novel light {novel:?}"
            );
            assert!((0.5..2.0).contains(&ratio), "seed {seed}: light power ratio {ratio}");
            assert!(r.end.total <= r.start.total);
            assert!(x.materials.iter().all(|v| v.abs() < 1.0));
            assert!(x.env.iter().all(|v| v.is_finite() && *v >= 0.0));
            assert_eq!(&x.normals, n);
        }
    }

    #[test]
    fn prior_gradients_match_finite_differences_and_stay_finite_on_hard_lights() {
        use crate::post_optimisation::Parametrised;
        let layer = RenderingLayer::new(4);
        let prior = family_prior();
        let hb = sphere_batch(1, 12, 4, 5, &layer);
        let inv_var = prior.inv_var();
        let zero = vec![0.0f32; hb.env.len()];
        let problem = Problem {
            layer: &layer,
            size: 12,
            regions: 1,
            image: &hb.input,
            region_map: &hb.region_map,
            normals: &hb.normals,
            env: &zero,
            a: 0.0,
            b: 0.0,
            priors: Priors {
                material: Some(MaterialPrior {
                    weight: 3.0,
                    mean: &prior.mean,
                    inv_var: &inv_var,
                }),
                light: Some(LightPrior {
                    weight: 2.0,
                    epsilon: 0.1,
                }),
            },
        };
        let base = Prediction {
            normals: hb.normals.clone(),
            materials: hb.materials.clone(),
            env: hb.env.clone(),
        };
        // Hard lights: a black texel next to a bright one, tiny and huge texels.
        let mut hard = base.clone();
        hard.env[0] = 0.0;
        hard.env[1] = 1e4;
        hard.env[5] = 1e-20;
        for x in [base, hard] {
            for property in [Property::Material, Property::Light] {
                let par = Parametrised::new(&problem, property, x.clone());
                let q = par.start();
                let (e, g) = par.evaluate(&q).unwrap();
                assert!(e.total.is_finite() && g.iter().all(|v| v.is_finite()));
                assert!(e.material_prior > 0.0 && e.light_prior > 0.0);
                // The priors' part of the gradient: with priors less without (the layer's own
                // gradient is checked in render/tests.rs and post_optimisation/mod.rs).
                let bare = Problem {
                    priors: Priors::NONE,
                    ..problem
                };
                let (_, g0) = Parametrised::new(&bare, property, x.clone()).evaluate(&q).unwrap();
                let prior_e = |q: &[f64]| {
                    let e = problem.energy(&par.point(q), false).unwrap().0;
                    e.material_prior + e.light_prior
                };
                // Central differences along a few coordinates.
                for &i in &[0usize, 1, 5, 17, 40] {
                    let h = 1e-4;
                    let mut qp = q.clone();
                    let mut qm = q.clone();
                    qp[i] += h;
                    qm[i] -= h;
                    let fd = (prior_e(&qp) - prior_e(&qm)) / (2.0 * h);
                    let analytic = g[i] - g0[i];
                    let tol = 1e-3 * fd.abs().max(analytic.abs()) + 1e-9;
                    assert!(
                        (fd - analytic).abs() <= tol,
                        "{property:?} [{i}]: fd {fd} vs {analytic}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_prior_is_fitted_with_a_floor_and_bad_inputs_are_refused() {
        let a = [0.5f32; PARAMS];
        let mut b = [0.5f32; PARAMS];
        b[0] = -0.5;
        let p = ReflectancePrior::fit(&[&a, &b]).unwrap();
        assert!((p.mean[0]).abs() < 1e-12 && (p.sigma[0] - 0.5).abs() < 1e-12);
        assert!((p.mean[1] - 0.5).abs() < 1e-7 && p.sigma[1] == SIGMA_FLOOR);
        assert!(ReflectancePrior::fit(&[]).is_err());
        let mut nan = a;
        nan[3] = f32::NAN;
        assert!(ReflectancePrior::fit(&[&a, &nan]).is_err());
        for bad in [
            LombardiConfig {
                material_weight: f64::NAN,
                ..Default::default()
            },
            LombardiConfig {
                light_weight: -1.0,
                ..Default::default()
            },
            LombardiConfig {
                light_epsilon: 0.0,
                ..Default::default()
            },
            LombardiConfig {
                rounds: 0,
                ..Default::default()
            },
        ] {
            let e = bad.validate().err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.starts_with("Lombardi baseline:"), "{bad:?}: {e}");
        }
    }
}

//! The post-optimisation of Sec. 3.5 (Eq. 6): from the network's n', m', L', minimise
//!
//! ```text
//! E(n*, m*, L*) = ‖R(n*, m*, L*) − I‖² + a‖n* − n'‖² + b‖L* − L'‖²      (a = 1, b = 0.1)
//! ```
//!
//! over the object's pixels, alternating as the paper does: each round optimises the light, then
//! the material, then the normals, the other two held, each by L-BFGS (argmin, More–Thuente
//! line search) through the fused rendering layer's forward pass and the VJP of the one property
//! that moves. (Why b = 0.1 and not the paper's 10: [`Eq6Config`]; why this order: [`ORDER`].)
//! Objects of more than [`Eq6Config::coarse_pixels`] pixels run the alternation on a regular
//! subset of their pixels and carry the result to all ([`coarse_to_fine`]).
//!
//! The constraints hold by construction of the parameters the optimiser moves: a normal is
//! v/|v| (unit), a material is tanh(u) (inside the normalised range the layer and the DSBRDF
//! files accept), a texel is exp(w) (non-negative light; a black texel starts at w = ln 1e-6).
//! Pixels of I that are not finite take no part. Each L-BFGS run starts where the previous
//! ended and keeps its best point, so E never increases from one logged iteration to the next.

mod parametrised;
mod priors;
#[cfg(test)]
mod tests;
pub mod watcher;

pub use parametrised::Parametrised;
use parametrised::{Lent, Recorder};
pub use priors::{LightPrior, MaterialPrior, Priors};

use crate::model::prediction::Prediction;
use crate::rendering_layer::{LayerInput, RenderingLayer, Wanted};
use anyhow::{Result, anyhow};
use argmin::core::Executor;
use argmin::core::observers::ObserverMode;
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use std::sync::{Arc, Mutex};
use watcher::{Cancelled, Watcher};

/// Forward and backward passes one L-BFGS iteration may take on average before its run is cut
/// short (typical runs take two).
pub const EVALUATIONS_PER_ITERATION: usize = 3;

/// Eq. 6's weights and the alternation's length.
///
/// The paper sets a = 1, b = 10 "experimentally" for its own scaling of the three terms, which it
/// does not state. In ours (sums over the object's pixels and the texels, linear radiance) b = 10
/// holds L* at L' (the light term ends near 10⁻³ of E), and the network's L', not n', is most of
/// O''s error; b = 0.1 was measured best on the quickstart split (docs/PERFORMANCE.md, "Eq. 6:
/// its weights, its order …"). The paper's values remain one flag away (`--eq6-b 10`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Eq6Config {
    /// Weight a of the normal prior (the paper: 1).
    pub a: f64,
    /// Weight b of the light prior (the paper: 10 in its units; here 0.1).
    pub b: f64,
    /// Rounds of (light, material, normals).
    pub rounds: usize,
    /// L-BFGS iterations per property and round.
    pub iterations: usize,
    /// L-BFGS history.
    pub history: usize,
    /// Objects of more pixels than this run the alternation on every k-th pixel of each row
    /// and column, k the smallest that leaves at most this many, then carry the normals'
    /// correction to every pixel ([`coarse_to_fine`]); 0: always every pixel.
    pub coarse_pixels: usize,
}

impl Eq6Config {
    /// The pixel stride of the alternation on an object of `object_pixels` pixels (1: every
    /// pixel).
    pub fn stride(&self, object_pixels: usize) -> usize {
        if self.coarse_pixels == 0 || object_pixels <= self.coarse_pixels {
            return 1;
        }
        let mut k = ((object_pixels as f64 / self.coarse_pixels as f64).sqrt().ceil() as usize).max(2);
        // Rounding of the square root: the smallest k whose subset fits.
        while k > 2 && object_pixels.div_ceil((k - 1) * (k - 1)) <= self.coarse_pixels {
            k -= 1;
        }
        k
    }
}

impl Default for Eq6Config {
    fn default() -> Self {
        Self {
            a: 1.0,
            b: 0.1,
            rounds: 2,
            iterations: 4,
            history: 7,
            coarse_pixels: 2048,
        }
    }
}

/// Which property an L-BFGS run moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Property {
    /// n*.
    Normals,
    /// m*.
    Material,
    /// L*.
    Light,
}

/// Eq. 6's terms at one point.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Energy {
    /// The whole of E.
    pub total: f64,
    /// ‖R − I‖².
    pub image: f64,
    /// a‖n* − n'‖².
    pub normals: f64,
    /// b‖L* − L'‖².
    pub light: f64,
    /// The material prior's term (0 in Eq. 6; see [`Priors`]).
    #[serde(skip_serializing_if = "is_zero")]
    pub material_prior: f64,
    /// The light prior's term (0 in Eq. 6; see [`Priors`]).
    #[serde(skip_serializing_if = "is_zero")]
    pub light_prior: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// One logged step: E after an L-BFGS iteration (iteration 0: the run's start).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Step {
    /// Round (0-based).
    pub round: usize,
    /// What moved.
    pub property: Property,
    /// Iteration within the run.
    pub iteration: u64,
    /// E at the run's best point so far.
    pub energy: f64,
    /// 1: E of the whole image. k > 1: E of the alternation on every k-th pixel of each row and
    /// column, its pixel terms scaled by k² to the whole image's units (an estimate of E).
    pub stride: usize,
}

/// The problem: image, mask, regions and the network's prediction (the priors and the start).
pub struct Problem<'a> {
    /// The rendering layer.
    pub layer: &'a RenderingLayer,
    /// Image side.
    pub size: usize,
    /// Regions.
    pub regions: usize,
    /// I `[3, S, S]`.
    pub image: &'a [f32],
    /// `[S, S]`.
    pub region_map: &'a [u8],
    /// n' `[3, S, S]`.
    pub normals: &'a [f32],
    /// L' `[3, He, 2He]`.
    pub env: &'a [f32],
    /// Weights.
    pub a: f64,
    /// Weights.
    pub b: f64,
    /// Priors on m* and L* ([`Priors::NONE`] in Eq. 6).
    pub priors: Priors<'a>,
}

impl<'a> Problem<'a> {
    /// Eq. 6 as the paper states it, around the network's `prediction` of `image` (`[3, S, S]`,
    /// with its `[S, S]` region map): the image term, the normal prior towards n' with weight
    /// `a`, the light prior towards L' with weight `b`, no other prior.
    #[allow(clippy::too_many_arguments)]
    pub fn eq6(
        layer: &'a RenderingLayer,
        size: usize,
        regions: usize,
        image: &'a [f32],
        region_map: &'a [u8],
        prediction: &'a Prediction,
        a: f64,
        b: f64,
    ) -> Self {
        Self {
            layer,
            size,
            regions,
            image,
            region_map,
            normals: &prediction.normals,
            env: &prediction.env,
            a,
            b,
            priors: Priors::NONE,
        }
    }
}

/// ∂E/∂(n*, m*, L*).
pub struct PredictionGradient {
    /// `[3, S, S]`.
    pub normals: Vec<f64>,
    /// `[R, 108]`.
    pub materials: Vec<f64>,
    /// `[3, He, 2He]`.
    pub env: Vec<f64>,
}

impl Problem<'_> {
    fn pixels(&self) -> usize {
        self.size * self.size
    }

    /// Whether pixel k takes part (on the object, with a finite I).
    fn on(&self, k: usize) -> bool {
        let p = self.pixels();
        self.region_map[k] > 0 && (0..3).all(|c| self.image[c * p + k].is_finite())
    }

    fn batch<'b>(&'b self, x: &'b Prediction) -> LayerInput<'b> {
        LayerInput {
            batch: 1,
            size: (self.size, self.size),
            regions: self.regions,
            normals: &x.normals,
            region_map: self.region_map,
            materials: &x.materials,
            env: &x.env,
        }
    }

    /// E at `x`, and its gradient when `grad`.
    pub fn energy(&self, x: &Prediction, grad: bool) -> Result<(Energy, Option<PredictionGradient>)> {
        self.energy_wanted(x, grad.then_some(Wanted::ALL))
    }

    /// E at `x`, and the parts of its gradient `want` names (the others zero).
    pub fn energy_wanted(&self, x: &Prediction, want: Option<Wanted>) -> Result<(Energy, Option<PredictionGradient>)> {
        let p = self.pixels();
        let rendered = self.layer.forward(&self.batch(x))?;
        let mut upstream = vec![0.0_f32; 3 * p];
        let (mut image, mut normals) = (0.0_f64, 0.0_f64);
        for k in (0..p).filter(|&k| self.on(k)) {
            for c in 0..3 {
                let i = c * p + k;
                let d = rendered[i] as f64 - self.image[i] as f64;
                image += d * d;
                upstream[i] = (2.0 * d) as f32;
                let dn = x.normals[i] as f64 - self.normals[i] as f64;
                normals += dn * dn;
            }
        }
        let light: f64 = x
            .env
            .iter()
            .zip(self.env)
            .map(|(&l, &l0)| (l as f64 - l0 as f64).powi(2))
            .sum();
        let he = self.layer.texels().height();
        let material_prior = self.priors.material.map_or(0.0, |p| p.energy(&x.materials, None));
        let light_prior = self.priors.light.map_or(0.0, |p| p.energy(&x.env, he, None));
        let e = Energy {
            total: image + self.a * normals + self.b * light + material_prior + light_prior,
            image,
            normals: self.a * normals,
            light: self.b * light,
            material_prior,
            light_prior,
        };
        let Some(want) = want else {
            return Ok((e, None));
        };
        let g = self.layer.backward_wanted(&self.batch(x), &upstream, want)?;
        let mut gn: Vec<f64> = g.normals.iter().map(|&v| v as f64).collect();
        for k in 0..p {
            for c in 0..3 {
                let i = c * p + k;
                gn[i] = if self.on(k) {
                    gn[i] + 2.0 * self.a * (x.normals[i] as f64 - self.normals[i] as f64)
                } else {
                    0.0
                };
            }
        }
        let mut gl: Vec<f64> = g
            .env
            .iter()
            .zip(&x.env)
            .zip(self.env)
            .map(|((&g, &l), &l0)| g as f64 + 2.0 * self.b * (l as f64 - l0 as f64))
            .collect();
        let mut gm: Vec<f64> = g.materials.iter().map(|&v| v as f64).collect();
        if let Some(p) = self.priors.material {
            p.energy(&x.materials, Some(&mut gm));
        }
        if let Some(p) = self.priors.light {
            p.energy(&x.env, he, Some(&mut gl));
        }
        Ok((
            e,
            Some(PredictionGradient {
                normals: gn,
                materials: gm,
                env: gl,
            }),
        ))
    }
}

/// The result of [`post_optimise`].
pub struct Optimised {
    /// The final n*, m*, L*.
    pub point: Prediction,
    /// E at the start (the network's prediction).
    pub start: Energy,
    /// E at the end.
    pub end: Energy,
    /// E after every L-BFGS iteration, in order.
    pub steps: Vec<Step>,
    /// Passes of the rendering layer (forward, or forward and backward) it ran.
    pub evaluations: usize,
    /// The alternation's pixel stride (1: every pixel).
    pub stride: usize,
}

/// Eq. 6 from `start` (the network's prediction, whose n' and L' are also `problem`'s priors).
pub fn post_optimise(problem: &Problem, start: Prediction, cfg: &Eq6Config) -> Result<Optimised> {
    post_optimise_watched(problem, start, cfg, None)
}

/// [`post_optimise`], showing its energies to `watcher` and stopping with
/// [`Cancelled`] when it cancels.
pub fn post_optimise_watched(
    problem: &Problem,
    start: Prediction,
    cfg: &Eq6Config,
    watcher: Option<&Arc<dyn Watcher>>,
) -> Result<Optimised> {
    let object = (0..problem.pixels()).filter(|&k| problem.on(k)).count();
    match cfg.stride(object) {
        1 => alternate(problem, start, cfg, &ORDER, watcher),
        k => coarse_to_fine(problem, start, cfg, k, watcher),
    }
}

/// The alternation's order: the light first, whose error dominates the edited image O'
/// (PERFORMANCE: on the quickstart test split, O' L2 with the true L and the network's n' is a
/// third of that with n' and L'), then the material, then the normals.
pub const ORDER: [Property; 3] = [Property::Light, Property::Material, Property::Normals];

/// Eq. 6 on a large image: the alternation on every `stride`-th pixel of each row and column
/// (its pixel terms weighted by stride², so that they keep their balance with the light prior),
/// then the whole image: m* and L* as found, and every pixel's normal moved by the correction
/// the coarse normals received, interpolated bilinearly between the coarse pixels of the
/// object. The whole image's E decides: the result is the lowest of that point, the same
/// without the normals' correction, and the start.
///
/// Why: m* and L* are shared by all pixels, and a fraction of them determines them about as
/// well as all; the alternation's cost grows with the pixels it renders per evaluation (tens of
/// evaluations), the whole image's with the two or three it needs here.
pub fn coarse_to_fine(
    problem: &Problem,
    start: Prediction,
    cfg: &Eq6Config,
    stride: usize,
    watcher: Option<&Arc<dyn Watcher>>,
) -> Result<Optimised> {
    let (s, k) = (problem.size, stride.max(1));
    let c = s.div_ceil(k);
    let (p, pc) = (s * s, c * c);
    // Coarse pixel (y, x) is pixel (k·y, k·x).
    let full = |j: usize| (j / c) * k * s + (j % c) * k;
    let sub = |v: &[f32], channels: usize| -> Vec<f32> {
        (0..channels)
            .flat_map(|ch| (0..pc).map(move |j| v[ch * p + full(j)]))
            .collect()
    };
    let image = sub(problem.image, 3);
    let region_map: Vec<u8> = (0..pc).map(|j| problem.region_map[full(j)]).collect();
    let prior_normals = sub(problem.normals, 3);
    let w = 1.0 / (k * k) as f64;
    let scaled = |v: f64| v * w;
    let priors = Priors {
        material: problem.priors.material.map(|m| MaterialPrior {
            weight: scaled(m.weight),
            ..m
        }),
        light: problem.priors.light.map(|l| LightPrior {
            weight: scaled(l.weight),
            ..l
        }),
    };
    let coarse = Problem {
        layer: problem.layer,
        size: c,
        regions: problem.regions,
        image: &image,
        region_map: &region_map,
        normals: &prior_normals,
        env: problem.env,
        a: problem.a,
        b: scaled(problem.b),
        priors,
    };
    let coarse_start = Prediction {
        normals: sub(&start.normals, 3),
        materials: start.materials.clone(),
        env: start.env.clone(),
    };
    let r = alternate_on_subset(&coarse, coarse_start.clone(), cfg, &ORDER, watcher, k)?;
    let (e0, _) = problem.energy(&start, false)?;
    // The normals' correction at every pixel of the object, from the coarse pixels around it.
    let mut normals = start.normals.clone();
    for y in 0..s {
        for x in 0..s {
            let i = y * s + x;
            if problem.region_map[i] == 0 {
                continue;
            }
            let (fy, fx) = (y as f64 / k as f64, x as f64 / k as f64);
            let (y0, x0) = (fy.floor() as usize, fx.floor() as usize);
            let (ty, tx) = (fy - y0 as f64, fx - x0 as f64);
            let mut delta = [0.0f64; 3];
            let mut weight = 0.0;
            for (dy, wy) in [(0, 1.0 - ty), (1, ty)] {
                for (dx, wx) in [(0, 1.0 - tx), (1, tx)] {
                    let (cy, cx) = (y0 + dy, x0 + dx);
                    let wt = wy * wx;
                    if cy >= c || cx >= c || wt <= 0.0 || !coarse.on(cy * c + cx) {
                        continue;
                    }
                    let j = cy * c + cx;
                    for (ch, d) in delta.iter_mut().enumerate() {
                        *d += wt * (r.point.normals[ch * pc + j] as f64 - coarse_start.normals[ch * pc + j] as f64);
                    }
                    weight += wt;
                }
            }
            if weight <= 0.0 {
                continue;
            }
            let v: [f64; 3] = std::array::from_fn(|ch| start.normals[ch * p + i] as f64 + delta[ch] / weight);
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if len.is_finite() && len > 1e-6 {
                for (ch, vc) in v.iter().enumerate() {
                    normals[ch * p + i] = (vc / len) as f32;
                }
            }
        }
    }
    let mut best = (start, e0);
    let mut evaluations = r.evaluations + 1;
    for normals in [normals, best.0.normals.clone()] {
        evaluations += 1;
        let candidate = Prediction {
            normals,
            materials: r.point.materials.clone(),
            env: r.point.env.clone(),
        };
        let (e, _) = problem.energy(&candidate, false)?;
        if e.total.is_finite() && e.total < best.1.total {
            best = (candidate, e);
            break;
        }
    }
    let mut steps = vec![Step {
        round: 0,
        property: Property::Normals,
        iteration: 0,
        energy: e0.total,
        stride: 1,
    }];
    steps.extend(r.steps);
    steps.push(Step {
        round: cfg.rounds,
        property: Property::Normals,
        iteration: 0,
        energy: best.1.total,
        stride: 1,
    });
    Ok(Optimised {
        point: best.0,
        start: e0,
        end: best.1,
        steps,
        evaluations,
        stride: k,
    })
}

/// `problem`'s energy from `start`, minimised over `properties` in turn (the others held), each
/// by L-BFGS, for `cfg.rounds` rounds; `watcher` sees every iteration's energy and may cancel.
pub fn alternate(
    problem: &Problem,
    start: Prediction,
    cfg: &Eq6Config,
    properties: &[Property],
    watcher: Option<&Arc<dyn Watcher>>,
) -> Result<Optimised> {
    alternate_on_subset(problem, start, cfg, properties, watcher, 1)
}

/// [`alternate`] on the problem of every `stride`-th pixel: its steps carry the stride, and they
/// and the watcher's energies are multiplied by stride², the whole image's units.
fn alternate_on_subset(
    problem: &Problem,
    start: Prediction,
    cfg: &Eq6Config,
    properties: &[Property],
    watcher: Option<&Arc<dyn Watcher>>,
    stride: usize,
) -> Result<Optimised> {
    let scale = (stride * stride) as f64;
    let (e0, _) = problem.energy(&start, false)?;
    if let Some(w) = watcher {
        w.energy(e0.total * scale);
    }
    let mut x = start;
    let mut current = e0;
    let mut steps = Vec::new();
    let mut evaluations = 1;
    for round in 0..cfg.rounds {
        for &property in properties {
            let par = Parametrised::new(problem, property, x.clone())
                .with_budget(EVALUATIONS_PER_ITERATION * cfg.iterations + 2);
            let q0 = par.start();
            let log = Arc::new(Mutex::new(Vec::new()));
            let line = MoreThuenteLineSearch::new()
                .with_c(1e-4, 0.9)
                .map_err(|e| anyhow!("line search: {e}"))?;
            let solver = LBFGS::new(line, cfg.history.max(1));
            // Its result is `par.best()`: an evaluation budget that ran out or a line search that
            // found no decrease ends the run with an error but keeps what it found.
            let _ = Executor::new(Lent(&par, watcher), solver)
                .configure(|s| s.param(q0.clone()).max_iters(cfg.iterations as u64))
                .add_observer(
                    Recorder {
                        log: log.clone(),
                        watcher: watcher.cloned(),
                        floor: current.total,
                        scale,
                    },
                    ObserverMode::Always,
                )
                .run();
            if watcher.is_some_and(|w| w.is_cancelled()) {
                return Err(Cancelled.into());
            }
            steps.push(Step {
                round,
                property,
                iteration: 0,
                energy: current.total * scale,
                stride,
            });
            let logged = log.lock().map(|v| v.clone()).unwrap_or_default();
            let mut last = (0, current.total);
            for (iteration, best) in logged.into_iter().filter(|(i, b)| *i > 0 && b.is_finite()) {
                last = (iteration, best.min(current.total));
                steps.push(Step {
                    round,
                    property,
                    iteration,
                    energy: last.1 * scale,
                    stride,
                });
            }
            if let Some((q, e)) = par.best()
                && e.total <= current.total
            {
                x = par.point(&q);
                current = e;
            }
            // A run cut short inside an iteration may have found a point below the last logged.
            if current.total < last.1 {
                steps.push(Step {
                    round,
                    property,
                    iteration: last.0 + 1,
                    energy: current.total * scale,
                    stride,
                });
            }
            evaluations += par.evaluations();
        }
    }
    Ok(Optimised {
        point: x,
        start: e0,
        end: current,
        steps,
        evaluations,
        stride,
    })
}

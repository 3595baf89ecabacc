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

pub mod progress;

use crate::render::{Batch, RenderingLayer, Wanted};
use anyhow::{Result, anyhow};
use argmin::core::observers::{Observe, ObserverMode};
use argmin::core::{CostFunction, Executor, Gradient, IterState, KV, State};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use progress::{Cancelled, Progress};
use std::cell::{Cell, RefCell};
use std::sync::{Arc, Mutex};

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

/// A Gaussian over the normalised DSBRDF parameters: w Σ_r Σ_j (m*_rj − μ_j)² / σ_j², every
/// region slot alike.
#[derive(Clone, Copy, Debug)]
pub struct MaterialPrior<'a> {
    /// w.
    pub weight: f64,
    /// μ, 108 values.
    pub mean: &'a [f64],
    /// 1/σ², 108 values.
    pub inv_var: &'a [f64],
}

/// A natural-illumination prior: w Σ ρ(ln L*_a − ln L*_b) over every pair of neighbouring texels
/// of one channel (along a row, wrapping at the seam, and along a column), with the
/// heavy-tailed ρ(d) = √(d² + ε²) − ε that natural light's log-gradients follow.
#[derive(Clone, Copy, Debug)]
pub struct LightPrior {
    /// w.
    pub weight: f64,
    /// ε: below it ρ is quadratic, above it linear.
    pub epsilon: f64,
}

/// Priors on m* and L*. Eq. 6 has none: its priors are the network's n' and L'
/// ([`Problem::a`], [`Problem::b`]). The Lombardi-style baseline (`crate::baseline::lombardi`)
/// has both.
#[derive(Clone, Copy, Debug, Default)]
pub struct Priors<'a> {
    /// On m*.
    pub material: Option<MaterialPrior<'a>>,
    /// On L*.
    pub light: Option<LightPrior>,
}

impl Priors<'_> {
    /// No prior (Eq. 6).
    pub const NONE: Priors<'static> = Priors {
        material: None,
        light: None,
    };
}

/// Texels darker than this count as this in the light prior's logarithm.
const LOG_FLOOR: f64 = 1e-30;

impl MaterialPrior<'_> {
    /// The term at `m` (`[R, 108]`), and its gradient added into `grad` when given.
    fn energy(&self, m: &[f32], mut grad: Option<&mut [f64]>) -> f64 {
        let n = self.mean.len().max(1);
        let mut e = 0.0;
        for (i, &v) in m.iter().enumerate() {
            let d = v as f64 - self.mean[i % n];
            e += d * d * self.inv_var[i % n];
            if let Some(g) = grad.as_deref_mut() {
                g[i] += 2.0 * self.weight * d * self.inv_var[i % n];
            }
        }
        self.weight * e
    }
}

impl LightPrior {
    /// The term at `env` (`[3, He, 2He]`), and its gradient added into `grad` when given.
    fn energy(&self, env: &[f32], he: usize, mut grad: Option<&mut [f64]>) -> f64 {
        let we = 2 * he;
        let eps = self.epsilon;
        let ln = |v: f32| (v as f64).max(LOG_FLOOR).ln();
        let mut e = 0.0;
        let mut pair = |a: usize, b: usize, grad: &mut Option<&mut [f64]>| {
            let d = ln(env[a]) - ln(env[b]);
            let r = (d * d + eps * eps).sqrt();
            e += r - eps;
            if let Some(g) = grad.as_deref_mut() {
                let dr = self.weight * d / r;
                if env[a] as f64 > LOG_FLOOR {
                    g[a] += dr / env[a] as f64;
                }
                if env[b] as f64 > LOG_FLOOR {
                    g[b] -= dr / env[b] as f64;
                }
            }
        };
        for c in 0..3 {
            for y in 0..he {
                for x in 0..we {
                    let k = (c * he + y) * we + x;
                    pair(k, (c * he + y) * we + (x + 1) % we, &mut grad);
                    if y + 1 < he {
                        pair(k, k + we, &mut grad);
                    }
                }
            }
        }
        self.weight * e
    }
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

/// A point: n*, m*, L* in the layer's layouts.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    /// `[3, S, S]`.
    pub normals: Vec<f32>,
    /// `[R, 108]`.
    pub materials: Vec<f32>,
    /// `[3, He, 2He]`.
    pub env: Vec<f32>,
}

/// ∂E/∂(n*, m*, L*).
pub struct PointGradient {
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

    fn batch<'b>(&'b self, x: &'b Point) -> Batch<'b> {
        Batch {
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
    pub fn energy(&self, x: &Point, grad: bool) -> Result<(Energy, Option<PointGradient>)> {
        self.energy_wanted(x, grad.then_some(Wanted::ALL))
    }

    /// E at `x`, and the parts of its gradient `want` names (the others zero).
    pub fn energy_wanted(&self, x: &Point, want: Option<Wanted>) -> Result<(Energy, Option<PointGradient>)> {
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
            Some(PointGradient {
                normals: gn,
                materials: gm,
                env: gl,
            }),
        ))
    }
}

/// Darkest texel the light's parameters start from (exp(w) cannot reach 0).
const MIN_LIGHT: f64 = 1e-6;
/// The normalised material's parameters stay inside ±(1 − this) (tanh's range, open).
const MATERIAL_EDGE: f64 = 1e-6;

/// Parameters, energy and gradient of one evaluation.
type Evaluated = (Vec<f64>, Energy, Vec<f64>);

/// The unconstrained parameters of one property and the map to the point.
pub struct Parametrised<'a> {
    problem: &'a Problem<'a>,
    property: Property,
    /// The point, of which `property` is replaced.
    base: Point,
    /// (param, energy, gradient) of the last evaluation: L-BFGS asks for cost and gradient
    /// separately, one forward and backward gives both.
    cache: RefCell<Option<Evaluated>>,
    /// Forward and backward passes run.
    evaluations: Cell<usize>,
    /// At most this many passes: L-BFGS's More–Thuente line search can spend dozens on one
    /// iteration where the energy is nearly flat along its direction.
    budget: usize,
    /// The lowest-energy point evaluated so far, and its energy.
    best: RefCell<Option<(Vec<f64>, Energy)>>,
}

/// The evaluation budget of one L-BFGS run ran out.
#[derive(Debug, thiserror::Error)]
#[error("the L-BFGS run's evaluation budget ran out")]
struct OutOfBudget;

impl<'a> Parametrised<'a> {
    /// Parameters of `property` at `x`.
    pub fn new(problem: &'a Problem<'a>, property: Property, x: Point) -> Self {
        Self {
            problem,
            property,
            base: x,
            cache: RefCell::new(None),
            evaluations: Cell::new(0),
            budget: usize::MAX,
            best: RefCell::new(None),
        }
    }

    /// The parameters of the current point.
    pub fn start(&self) -> Vec<f64> {
        let x = &self.base;
        match self.property {
            Property::Normals => x.normals.iter().map(|&v| v as f64).collect(),
            Property::Material => x
                .materials
                .iter()
                .map(|&v| (v as f64).clamp(-1.0 + MATERIAL_EDGE, 1.0 - MATERIAL_EDGE).atanh())
                .collect(),
            Property::Light => x.env.iter().map(|&v| (v as f64).max(MIN_LIGHT).ln()).collect(),
        }
    }

    /// The point at parameters `q`.
    pub fn point(&self, q: &[f64]) -> Point {
        let mut x = self.base.clone();
        match self.property {
            Property::Normals => {
                let p = self.problem.pixels();
                for k in 0..p {
                    let v = [q[k], q[p + k], q[2 * p + k]];
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    for (c, vc) in v.iter().enumerate() {
                        x.normals[c * p + k] = if len > 1e-12 { (vc / len) as f32 } else { 0.0 };
                    }
                }
            }
            Property::Material => x.materials = q.iter().map(|&u| u.tanh() as f32).collect(),
            Property::Light => x.env = q.iter().map(|&w| w.clamp(-80.0, 80.0).exp() as f32).collect(),
        }
        x
    }

    /// At most `budget` forward and backward passes; [`Parametrised::evaluate`] fails after.
    pub fn with_budget(mut self, budget: usize) -> Self {
        self.budget = budget.max(1);
        self
    }

    /// Forward and backward passes run so far.
    pub fn evaluations(&self) -> usize {
        self.evaluations.get()
    }

    /// The lowest-energy point evaluated so far: its parameters and E.
    pub fn best(&self) -> Option<(Vec<f64>, Energy)> {
        self.best.borrow().clone()
    }

    /// E and ∂E/∂q.
    pub fn evaluate(&self, q: &[f64]) -> Result<(Energy, Vec<f64>)> {
        if let Some((cq, e, g)) = self.cache.borrow().as_ref()
            && cq.as_slice() == q
        {
            return Ok((*e, g.clone()));
        }
        if self.evaluations.get() >= self.budget {
            return Err(OutOfBudget.into());
        }
        let x = self.point(q);
        let want = match self.property {
            Property::Normals => Wanted::NORMALS,
            Property::Material => Wanted::MATERIALS,
            Property::Light => Wanted::ENV,
        };
        let (e, g) = self.problem.energy_wanted(&x, Some(want))?;
        self.evaluations.set(self.evaluations.get() + 1);
        if e.total.is_finite() && self.best.borrow().as_ref().is_none_or(|(_, b)| e.total < b.total) {
            *self.best.borrow_mut() = Some((q.to_vec(), e));
        }
        let g = g.ok_or_else(|| anyhow!("no gradient"))?;
        let gq: Vec<f64> = match self.property {
            Property::Normals => {
                // n = v/|v|: ∂E/∂v = (g − (g·n) n)/|v|.
                let p = self.problem.pixels();
                let mut out = vec![0.0; 3 * p];
                for k in 0..p {
                    let v = [q[k], q[p + k], q[2 * p + k]];
                    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                    if len <= 1e-12 {
                        continue;
                    }
                    let n = v.map(|c| c / len);
                    let gk = [g.normals[k], g.normals[p + k], g.normals[2 * p + k]];
                    let dot = gk[0] * n[0] + gk[1] * n[1] + gk[2] * n[2];
                    for c in 0..3 {
                        out[c * p + k] = (gk[c] - dot * n[c]) / len;
                    }
                }
                out
            }
            Property::Material => g
                .materials
                .iter()
                .zip(q)
                .map(|(&gm, &u)| gm * (1.0 - u.tanh().powi(2)))
                .collect(),
            Property::Light => g
                .env
                .iter()
                .zip(q)
                .map(|(&gl, &w)| gl * w.clamp(-80.0, 80.0).exp())
                .collect(),
        };
        let gq: Vec<f64> = gq.into_iter().map(|v| if v.is_finite() { v } else { 0.0 }).collect();
        *self.cache.borrow_mut() = Some((q.to_vec(), e, gq.clone()));
        Ok((e, gq))
    }
}

/// What argmin's executor owns: a borrow of the parametrised problem (kept by the caller, which
/// maps the best parameters back to a point).
/// A parametrised problem lent to argmin, with the watcher whose cancel stops it before the next
/// evaluation (an L-BFGS iteration may evaluate several times).
struct Lent<'p, 'a>(&'p Parametrised<'a>, Option<&'p Arc<Progress>>);

impl Lent<'_, '_> {
    fn check(&self) -> Result<(), argmin::core::Error> {
        match self.1 {
            Some(w) if w.is_cancelled() => Err(argmin::core::Error::new(Cancelled)),
            _ => Ok(()),
        }
    }
}

impl CostFunction for Lent<'_, '_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, q: &Self::Param) -> Result<f64, argmin::core::Error> {
        self.check()?;
        let (e, _) = self
            .0
            .evaluate(q)
            .map_err(|e| argmin::core::Error::msg(e.to_string()))?;
        // A non-finite energy is a point the line search must step back from.
        Ok(if e.total.is_finite() { e.total } else { f64::INFINITY })
    }
}

impl Gradient for Lent<'_, '_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, q: &Self::Param) -> Result<Vec<f64>, argmin::core::Error> {
        self.check()?;
        Ok(self
            .0
            .evaluate(q)
            .map_err(|e| argmin::core::Error::msg(e.to_string()))?
            .1)
    }
}

/// Records the best cost after each iteration, shows it to a watcher (never above `floor`, the
/// energy the property's run started from) and stops the run once the watcher cancels.
struct Recorder {
    log: Arc<Mutex<Vec<(u64, f64)>>>,
    watcher: Option<Arc<Progress>>,
    floor: f64,
    /// What the watcher's energies are multiplied by (k² on a coarse problem).
    scale: f64,
}

impl Observe<IterState<Vec<f64>, Vec<f64>, (), (), (), f64>> for Recorder {
    fn observe_iter(
        &mut self,
        state: &IterState<Vec<f64>, Vec<f64>, (), (), (), f64>,
        _kv: &KV,
    ) -> Result<(), argmin::core::Error> {
        let best = state.get_best_cost();
        if let Ok(mut v) = self.log.lock() {
            v.push((state.get_iter(), best));
        }
        if let Some(w) = &self.watcher {
            if state.get_iter() > 0 && best.is_finite() {
                w.energy(best.min(self.floor) * self.scale);
            }
            if w.is_cancelled() {
                return Err(argmin::core::Error::new(Cancelled));
            }
        }
        Ok(())
    }
}

/// The result of [`post_optimise`].
pub struct Optimised {
    /// The final n*, m*, L*.
    pub point: Point,
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
pub fn post_optimise(problem: &Problem, start: Point, cfg: &Eq6Config) -> Result<Optimised> {
    post_optimise_watched(problem, start, cfg, None)
}

/// [`post_optimise`], showing its energies to `watcher` and stopping with
/// [`Cancelled`] when it cancels.
pub fn post_optimise_watched(
    problem: &Problem,
    start: Point,
    cfg: &Eq6Config,
    watcher: Option<&Arc<Progress>>,
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
    start: Point,
    cfg: &Eq6Config,
    stride: usize,
    watcher: Option<&Arc<Progress>>,
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
    let coarse_start = Point {
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
        let candidate = Point {
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
    start: Point,
    cfg: &Eq6Config,
    properties: &[Property],
    watcher: Option<&Arc<Progress>>,
) -> Result<Optimised> {
    alternate_on_subset(problem, start, cfg, properties, watcher, 1)
}

/// [`alternate`] on the problem of every `stride`-th pixel: its steps carry the stride, and they
/// and the watcher's energies are multiplied by stride², the whole image's units.
fn alternate_on_subset(
    problem: &Problem,
    start: Point,
    cfg: &Eq6Config,
    properties: &[Property],
    watcher: Option<&Arc<Progress>>,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::synthetic::sphere_batch;

    /// Directional derivative of E along `d` by central differences against the analytic one.
    fn check_gradient(par: &Parametrised, q: &[f64], seed: u64, what: &str) {
        let (_, g) = par.evaluate(q).unwrap();
        let mut s = seed;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        // A direction along the gradient's largest entries and a random one.
        let mut idx: Vec<usize> = (0..g.len()).collect();
        idx.sort_by(|&a, &b| g[b].abs().total_cmp(&g[a].abs()));
        let mut along = vec![0.0; g.len()];
        for &i in idx.iter().take(12) {
            along[i] = g[i].signum();
        }
        let random: Vec<f64> = (0..g.len()).map(|_| rnd()).collect();
        for (name, d) in [("gradient's largest", along), ("random", random)] {
            let norm = d.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
            let d: Vec<f64> = d.iter().map(|v| v / norm).collect();
            let analytic: f64 = g.iter().zip(&d).map(|(a, b)| a * b).sum();
            let e = |h: f64| {
                let qh: Vec<f64> = q.iter().zip(&d).map(|(a, b)| a + h * b).collect();
                par.problem.energy(&par.point(&qh), false).unwrap().0.total
            };
            let h = 1e-3;
            let fd = (e(h) - e(-h)) / (2.0 * h);
            let scale = analytic.abs().max(fd.abs()).max(1e-3 * e(0.0).abs());
            assert!(
                (fd - analytic).abs() <= 0.03 * scale,
                "{what}, {name}: finite differences {fd} against the analytic {analytic}"
            );
        }
    }

    struct Scene {
        layer: RenderingLayer,
        image: Vec<f32>,
        region_map: Vec<u8>,
        truth: Point,
        size: usize,
    }

    fn scene(seed: u64) -> Scene {
        sphere_scene(12, seed)
    }

    /// The layer's own rendering of a sphere of `size`² under a small sky.
    fn sphere_scene(size: usize, seed: u64) -> Scene {
        let layer = RenderingLayer::new(4);
        let hb = sphere_batch(1, size, 4, seed, &layer);
        Scene {
            image: hb.input.clone(),
            region_map: hb.region_map.clone(),
            truth: Point {
                normals: hb.normals.clone(),
                materials: hb.materials.clone(),
                env: hb.env.clone(),
            },
            size,
            layer,
        }
    }

    fn problem<'a>(s: &'a Scene, image: &'a [f32], prior: &'a Point) -> Problem<'a> {
        Problem {
            layer: &s.layer,
            size: s.size,
            regions: 1,
            image,
            region_map: &s.region_map,
            normals: &prior.normals,
            env: &prior.env,
            a: 1.0,
            b: 10.0,
            priors: Priors::NONE,
        }
    }

    #[test]
    fn the_stride_is_the_smallest_that_fits_the_pixel_budget() {
        for budget in [1usize, 2, 7, 100, 2048] {
            let cfg = Eq6Config {
                coarse_pixels: budget,
                ..Eq6Config::default()
            };
            let counts = (0..3000)
                .chain((3000..300_000).step_by(997))
                .chain([1 << 20, 40_000_000]);
            for object in counts {
                let k = cfg.stride(object);
                if object <= budget {
                    assert_eq!(k, 1, "{object} pixels fit {budget}");
                    continue;
                }
                assert!(k >= 2 && object.div_ceil(k * k) <= budget, "{object} / {k}² > {budget}");
                assert!(
                    k == 2 || object.div_ceil((k - 1) * (k - 1)) > budget,
                    "{object} pixels: {} would do for {budget}",
                    k - 1
                );
            }
        }
        let never = Eq6Config {
            coarse_pixels: 0,
            ..Eq6Config::default()
        };
        assert_eq!(never.stride(10_000_000), 1);
    }

    #[test]
    fn an_l_bfgs_run_stops_at_its_evaluation_budget_and_keeps_its_lowest_point() {
        let s = scene(3);
        let pr = problem(&s, &s.image, &s.truth);
        let mut start = s.truth.clone();
        start.env.iter_mut().for_each(|v| *v *= 2.0);
        let par = Parametrised::new(&pr, Property::Light, start).with_budget(3);
        let q0 = par.start();
        // Scaling the light by e^t: t = −ln 2 is the truth.
        let at = |t: f64| q0.iter().map(|w| w + t).collect::<Vec<f64>>();
        let e: Vec<f64> = [0.0, -0.69, -0.3]
            .iter()
            .map(|&t| par.evaluate(&at(t)).unwrap().0.total)
            .collect();
        assert_eq!(par.evaluations(), 3);
        // The cached last point costs nothing; a new one is refused.
        assert!(par.evaluate(&at(-0.3)).is_ok());
        assert!(par.evaluate(&at(-0.5)).is_err());
        let (q, best) = par.best().unwrap();
        assert_eq!(best.total, e[1]);
        assert_eq!(q, at(-0.69));
        assert!(e[1] < e[0] && e[1] < e[2]);
    }

    /// A sphere of `size`² under a small sky, its material, light and normals perturbed.
    fn perturbed(size: usize, seed: u64) -> (Scene, Point) {
        let s = sphere_scene(size, seed);
        let mut start = s.truth.clone();
        for (k, v) in start.materials.iter_mut().enumerate() {
            *v = (*v + if k % 3 == 0 { 0.25 } else { -0.15 }).clamp(-0.95, 0.95);
        }
        start
            .env
            .iter_mut()
            .enumerate()
            .for_each(|(k, v)| *v *= if k % 2 == 0 { 0.6 } else { 1.5 });
        let p = size * size;
        for k in 0..p {
            let v = [
                start.normals[k] + 0.15,
                start.normals[p + k] - 0.1,
                start.normals[2 * p + k],
            ];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if s.region_map[k] > 0 && len > 0.0 {
                for (c, vc) in v.iter().enumerate() {
                    start.normals[c * p + k] = vc / len;
                }
            }
        }
        (s, start)
    }

    #[test]
    fn coarse_to_fine_lowers_e_about_as_far_as_every_pixel_does_and_never_raises_it() {
        let (s, start) = perturbed(40, 11);
        let object = s.region_map.iter().filter(|&&r| r > 0).count();
        let pr = problem(&s, &s.image, &start);
        let full = post_optimise(
            &pr,
            start.clone(),
            &Eq6Config {
                coarse_pixels: 0,
                ..Eq6Config::default()
            },
        )
        .unwrap();
        assert_eq!(full.stride, 1);
        for budget in [object / 4, object / 9, 40] {
            let cfg = Eq6Config {
                coarse_pixels: budget,
                ..Eq6Config::default()
            };
            let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
            assert!(r.stride >= 2, "{budget}: stride {}", r.stride);
            assert_eq!(r.start, full.start);
            // The whole image's E at the start and the end, the coarse alternation's between.
            let (first, last) = (r.steps[0], r.steps[r.steps.len() - 1]);
            assert_eq!((first.stride, first.energy), (1, r.start.total));
            assert_eq!((last.stride, last.energy), (1, r.end.total));
            let coarse: Vec<&Step> = r.steps.iter().filter(|s| s.stride > 1).collect();
            assert!(!coarse.is_empty() && coarse.iter().all(|s| s.stride == r.stride));
            for w in coarse.windows(2) {
                assert!(w[1].energy <= w[0].energy * (1.0 + 1e-12), "{:?} → {:?}", w[0], w[1]);
            }
            assert!(r.end.total <= r.start.total);
            assert!(
                r.end.total < 0.5 * r.start.total && r.end.total < 2.0 * full.end.total,
                "budget {budget} (stride {}): E {:.4e} → {:.4e}; every pixel: {:.4e}",
                r.stride,
                r.start.total,
                r.end.total,
                full.end.total
            );
            // The constraints hold at every pixel.
            let p = s.size * s.size;
            for k in (0..p).filter(|&k| s.region_map[k] > 0) {
                let n = (0..3).map(|c| (r.point.normals[c * p + k] as f64).powi(2)).sum::<f64>();
                assert!((n - 1.0).abs() < 1e-4);
            }
            assert!(r.point.env.iter().all(|v| *v >= 0.0 && v.is_finite()));
        }
    }

    #[test]
    fn coarse_to_fine_survives_an_object_the_subset_misses_and_nan_pixels() {
        let (mut s, start) = perturbed(24, 4);
        let p = s.size * s.size;
        // Only odd columns: every second pixel's subset holds none of the object.
        for k in 0..p {
            if (k % s.size) % 2 == 0 {
                s.region_map[k] = 0;
            }
        }
        let mut image = s.image.clone();
        for k in (0..p).step_by(5) {
            image[k] = f32::NAN;
        }
        let object = s.region_map.iter().filter(|&&r| r > 0).count();
        let pr = problem(&s, &image, &start);
        let cfg = Eq6Config {
            coarse_pixels: object / 3,
            ..Eq6Config::default()
        };
        let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
        assert_eq!(r.stride, 2);
        assert!(r.end.total.is_finite() && r.end.total <= r.start.total);
        assert!(
            r.point
                .normals
                .iter()
                .chain(&r.point.env)
                .chain(&r.point.materials)
                .all(|v| v.is_finite())
        );
    }

    #[test]
    fn eq6_gradients_match_finite_differences_on_hard_cases() {
        let s = scene(5);
        let p = s.size * s.size;
        // Off the truth, so that every term has a gradient.
        let mut start = s.truth.clone();
        for (k, v) in start.materials.iter_mut().enumerate() {
            *v = (*v + 0.2 * ((k % 5) as f32 - 2.0) / 2.0).clamp(-0.95, 0.95);
        }
        for v in start.env.iter_mut() {
            *v *= 1.3;
        }
        let prior = s.truth.clone();
        let pr = problem(&s, &s.image, &prior);
        for property in [Property::Normals, Property::Material, Property::Light] {
            let par = Parametrised::new(&pr, property, start.clone());
            check_gradient(&par, &par.start(), 1, &format!("{property:?}"));
        }
        // Grazing normals: tilt every normal to n_z ≈ 0.05.
        let mut grazing = start.clone();
        for k in 0..p {
            if s.region_map[k] == 0 {
                continue;
            }
            let (x, y) = (grazing.normals[k], grazing.normals[p + k]);
            let r = (x * x + y * y).sqrt().max(1e-6);
            let (sx, sy) = (x / r, y / r);
            let z: f32 = 0.05;
            let t = (1.0 - z * z).sqrt();
            grazing.normals[k] = sx * t;
            grazing.normals[p + k] = sy * t;
            grazing.normals[2 * p + k] = z;
        }
        let par = Parametrised::new(&pr, Property::Normals, grazing.clone());
        check_gradient(&par, &par.start(), 2, "grazing normals");
        // Sharp lobes: every parameter near the normalised range's edge.
        let mut sharp = start.clone();
        for (k, v) in sharp.materials.iter_mut().enumerate() {
            *v = if k % 2 == 0 { 0.97 } else { -0.9 };
        }
        let par = Parametrised::new(&pr, Property::Material, sharp);
        check_gradient(&par, &par.start(), 3, "sharp lobes");
        // A black environment (the light starts at exp(ln 1e-6)).
        let mut black = start.clone();
        black.env.iter_mut().for_each(|v| *v = 0.0);
        for property in [Property::Light, Property::Material] {
            let par = Parametrised::new(&pr, property, black.clone());
            let (e, g) = par.evaluate(&par.start()).unwrap();
            assert!(e.total.is_finite() && g.iter().all(|v| v.is_finite()));
            if property == Property::Light {
                check_gradient(&par, &par.start(), 4, "black environment");
            }
        }
        // NaN pixels in the photo take no part: E and its gradient stay finite and equal those
        // of the image without those pixels.
        let mut holed = s.image.clone();
        let on: Vec<usize> = (0..p).filter(|&k| s.region_map[k] > 0).collect();
        for &k in on.iter().step_by(7) {
            holed[k] = f32::NAN;
        }
        let hp = problem(&s, &holed, &prior);
        for property in [Property::Normals, Property::Material, Property::Light] {
            let par = Parametrised::new(&hp, property, start.clone());
            let (e, g) = par.evaluate(&par.start()).unwrap();
            assert!(e.total.is_finite() && g.iter().all(|v| v.is_finite()), "{property:?}");
            check_gradient(&par, &par.start(), 5, &format!("NaN pixels, {property:?}"));
        }
    }

    #[test]
    fn eq6_stays_at_the_truth_and_moves_back_towards_it_from_a_perturbed_material() {
        let s = scene(9);
        let cfg = Eq6Config {
            rounds: 2,
            iterations: 10,
            ..Eq6Config::default()
        };
        // From the truth (the priors too), E is ~0 and stays there.
        let pr = problem(&s, &s.image, &s.truth);
        let r = post_optimise(&pr, s.truth.clone(), &cfg).unwrap();
        assert!(r.start.total < 1e-6 * s.image.iter().map(|v| (*v as f64).powi(2)).sum::<f64>());
        assert!(r.end.total <= r.start.total);
        let moved = r
            .point
            .materials
            .iter()
            .zip(&s.truth.materials)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0_f32, f32::max);
        assert!(moved < 0.05, "moved {moved} from the truth");
        // From a perturbed material (normals and light true): the energy falls at every logged
        // step, and the material error falls.
        let mut start = s.truth.clone();
        for (k, v) in start.materials.iter_mut().enumerate() {
            *v = (*v + if k % 3 == 0 { 0.3 } else { -0.2 }).clamp(-0.95, 0.95);
        }
        let r = post_optimise(&pr, start.clone(), &cfg).unwrap();
        for w in r.steps.windows(2) {
            assert!(
                w[1].energy <= w[0].energy * (1.0 + 1e-12),
                "energy rose: {:?} → {:?}",
                w[0],
                w[1]
            );
        }
        assert!(r.end.total < 0.5 * r.start.total, "{:?} → {:?}", r.start, r.end);
        let err = |m: &[f32]| -> f64 {
            m.iter()
                .zip(&s.truth.materials)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        // The rendered image, not the 108 parameters, is what Eq. 6 sees; its error falls.
        let img = |x: &Point| pr.energy(x, false).unwrap().0.image;
        assert!(img(&r.point) < 0.5 * img(&start));
        assert!(
            err(&r.point.materials) <= err(&start.materials),
            "{} → {}",
            err(&start.materials),
            err(&r.point.materials)
        );
        // Every point keeps the constraints: unit normals, materials inside the range, light ≥ 0.
        let p = s.size * s.size;
        for k in (0..p).filter(|&k| s.region_map[k] > 0) {
            let n = (0..3).map(|c| (r.point.normals[c * p + k] as f64).powi(2)).sum::<f64>();
            assert!((n - 1.0).abs() < 1e-4);
        }
        assert!(r.point.materials.iter().all(|v| v.abs() < 1.0));
        assert!(r.point.env.iter().all(|v| *v >= 0.0 && v.is_finite()));
    }
}

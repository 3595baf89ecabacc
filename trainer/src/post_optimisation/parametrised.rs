//! What L-BFGS moves: one property of the point as unconstrained parameters (a normal v/|v|, a
//! material tanh(u), a texel exp(w)), with the cached forward and backward pass, the evaluation
//! budget and the adaptors argmin runs.

use super::watcher::{Cancelled, Watcher};
use super::{Energy, Problem, Property};
use crate::model::prediction::Prediction;
use crate::rendering_layer::Wanted;
use anyhow::{Result, anyhow};
use argmin::core::observers::Observe;
use argmin::core::{CostFunction, Gradient, IterState, KV, State};
use std::cell::{Cell, RefCell};
use std::sync::{Arc, Mutex};

/// Darkest texel the light's parameters start from (exp(w) cannot reach 0).
const MIN_LIGHT: f64 = 1e-6;
/// The normalised material's parameters stay inside ±(1 − this) (tanh's range, open).
const MATERIAL_EDGE: f64 = 1e-6;

/// Parameters, energy and gradient of one evaluation.
type Evaluated = (Vec<f64>, Energy, Vec<f64>);

/// The unconstrained parameters of one property and the map to the point.
pub struct Parametrised<'a> {
    pub(super) problem: &'a Problem<'a>,
    property: Property,
    /// The point, of which `property` is replaced.
    base: Prediction,
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
    pub fn new(problem: &'a Problem<'a>, property: Property, x: Prediction) -> Self {
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
    pub fn point(&self, q: &[f64]) -> Prediction {
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
pub(super) struct Lent<'p, 'a>(pub(super) &'p Parametrised<'a>, pub(super) Option<&'p Arc<dyn Watcher>>);

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
pub(super) struct Recorder {
    pub(super) log: Arc<Mutex<Vec<(u64, f64)>>>,
    pub(super) watcher: Option<Arc<dyn Watcher>>,
    pub(super) floor: f64,
    /// What the watcher's energies are multiplied by (k² on a coarse problem).
    pub(super) scale: f64,
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

//! Eq. 6 on a photo: the post-optimisation of n', m', L' ([`matedit_trainer::post_optimisation`])
//! on the photo's own pixels (the detail square), started from the network's estimates.

use crate::progress::Progress;
use crate::{Model, Prepared, detail};
use anyhow::Result;
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::post_optimisation::{self, Eq6Config};
use std::sync::Arc;
use std::time::Instant;

/// What Eq. 6 did, for `report.json` and `energy.png`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Eq6Report {
    /// Weights and lengths as given.
    pub config: post_optimisation::Eq6Config,
    /// The light prior's weight the energies below were computed with: b × the ratio of the
    /// detail square's pixels to the network's (the balance b was tuned for at the network's
    /// resolution).
    pub light_weight: f64,
    /// E at the start: the network's prediction (with what of L' the checkpoint does not read
    /// replaced, [`crate::light::estimate`]).
    pub start: post_optimisation::Energy,
    /// E at the end.
    pub end: post_optimisation::Energy,
    /// E after every L-BFGS iteration.
    pub steps: Vec<post_optimisation::Step>,
    /// Passes of the rendering layer.
    pub evaluations: usize,
    /// The alternation's pixel stride (1: every pixel of the object; k: every k-th of each row
    /// and column, the whole image's E at the first and last step).
    pub stride: usize,
    /// Seconds.
    pub seconds: f64,
}

/// The estimates Eq. 6 refines: n', m', L' at the network's resolution and the object at the
/// photo's (its normals).
pub struct Estimates<'a> {
    /// At the network's resolution.
    pub coarse: &'a mut Prediction,
    /// At the photo's.
    pub fine: &'a mut detail::Detail,
}

/// Refines `estimates` with Eq. 6 (`prep` is the network's input), its energies shown to
/// `watcher`.
pub fn refine(
    model: &Model,
    prep: &Prepared,
    estimates: Estimates,
    cfg: &Eq6Config,
    watcher: Option<&Arc<Progress>>,
) -> Result<Eq6Report> {
    let Estimates {
        coarse: x,
        fine: detail,
    } = estimates;
    let t = Instant::now();
    let fine = &detail.prep;
    // Eq. 6 on the photo's own pixels: its image and normal terms sum over F² pixels where the
    // weights were chosen for S², so the light prior's weight grows with them (the same balance
    // per unit of the object's area).
    let area = (fine.size * fine.size) as f64 / (prep.size * prep.size) as f64;
    let prior = Prediction {
        normals: detail.normals.clone(),
        materials: x.materials.clone(),
        env: x.env.clone(),
    };
    let problem = post_optimisation::Problem::eq6(
        &model.layer,
        fine.size,
        fine.regions,
        &fine.input,
        &fine.region_map,
        &prior,
        cfg.a,
        cfg.b * area,
    );
    let watcher = watcher.map(|w| Arc::clone(w) as Arc<dyn post_optimisation::watcher::Watcher>);
    let r = post_optimisation::post_optimise_watched(&problem, prior.clone(), cfg, watcher.as_ref())?;
    x.normals = detail::downsample_normals(&detail.prep, &r.point.normals, prep, &x.normals);
    x.materials = r.point.materials;
    x.env = r.point.env;
    detail.normals = r.point.normals;
    Ok(Eq6Report {
        config: cfg.clone(),
        light_weight: cfg.b * area,
        start: r.start,
        end: r.end,
        steps: r.steps,
        evaluations: r.evaluations,
        stride: r.stride,
        seconds: t.elapsed().as_secs_f64(),
    })
}

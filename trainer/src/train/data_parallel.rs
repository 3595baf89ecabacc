//! One training step as one of W ranks (`crate::parallel`): this rank's slice of the global
//! batch forward and backward, one block that agrees on the step (the loss terms, whether any
//! rank's loss is not finite, whether any rank was asked to stop), one all-reduce of the
//! gradients, and the same Adam update on every rank.

use super::loss::Losses;
use super::step::{StepContext, StepKind, losses_and_gradients};
use crate::data;
use crate::model::network::Net;
use crate::parallel::ranks::{Diverged, Ranks, Tag};
use crate::parallel::{gradients, share};
use anyhow::{Result, anyhow};
use burn::optim::ModuleOptimizer;
use std::rc::Rc;

/// What a step gave every rank.
pub struct Outcome {
    /// The updated network (the same on every rank).
    pub net: Net,
    /// The global batch's loss terms (the same on every rank).
    pub losses: Losses,
    /// Whether some rank was asked to stop: every rank then checkpoints and stops here.
    pub stop: bool,
    /// Seconds of this rank's gradient exchange (flatten, all-reduce, put back).
    pub exchange_seconds: f64,
}

/// Where a rank stands at a step.
pub struct Rank<'a> {
    /// The ranks.
    pub ranks: &'a Rc<Ranks>,
    /// Samples of the global batch (the stage's `batch_size`).
    pub global: usize,
    /// Set when this rank is asked to stop (SIGTERM, SIGUSR1); read at the end of the step.
    pub stop_asked: &'a std::sync::atomic::AtomicBool,
}

/// One step of rank `at.ranks.rank()` on its slice `batch` (or its error reading it) of the
/// global batch. Every rank returns the same: the same update, or the same error.
pub fn step(
    at: Rank,
    net: Net,
    optim: &mut ModuleOptimizer,
    lr: f64,
    batch: Result<data::Batch>,
    kind: StepKind,
    ctx: &StepContext,
) -> Result<Outcome> {
    let (ranks, global) = (at.ranks, at.global);
    let batch = batch.map_err(|e| ranks.fail(e))?;
    let slice = share::Share::of(ranks.clone(), global);
    if batch.batch != slice.local {
        let e = anyhow!(
            "holds {} samples of the step's batch, not its {}",
            batch.batch,
            slice.local
        );
        return Err(ranks.fail(e));
    }
    let result = {
        let _in = share::enter(slice.clone());
        losses_and_gradients(&net, &batch, kind, ctx)
    };
    // After a divergence the other ranks are resolving it already: join them.
    let (losses, mut grads) = result.map_err(|e| {
        if slice.diverged() {
            ranks.resolve(Some(e))
        } else {
            ranks.fail(e)
        }
    })?;
    if slice.diverged() {
        return Err(ranks.resolve(None));
    }
    // The step's block: the loss terms, then a flag per reason to stop.
    let r = ranks.rank();
    let mut block = losses.to_values().to_vec();
    let n = block.len();
    let stop_asked = at.stop_asked.load(std::sync::atomic::Ordering::SeqCst);
    block.push(f64::from(u8::from(stop_asked)));
    let not_finite = !losses.total.is_finite();
    // Which ranks' losses are not finite, as bits (exact in f64 for the first 52 ranks).
    block.push(if not_finite && r < 52 { (r as f64).exp2() } else { 0.0 });
    block.push(f64::from(u8::from(not_finite)));
    let summed = ranks
        .exchange(Tag::Step, &block)
        .map_err(|Diverged| ranks.resolve(None))?;
    let losses = Losses::from_values(&summed[..n], ctx.weights);
    let (stop, bits, count) = (summed[n] > 0.0, summed[n + 1] as u64, summed[n + 2]);
    let start = batch.positions.first().copied().unwrap_or(0) - slice.offset as u64;
    if count > 0.0 {
        let named: Vec<String> = (0..52).filter(|k| bits >> k & 1 == 1).map(|k| k.to_string()).collect();
        anyhow::bail!(
            "the loss is not finite ({losses:?}) on the global batch at stream positions {start}..{} (on rank {})",
            start + global as u64,
            if named.is_empty() {
                "≥ 52".into()
            } else {
                named.join(", ")
            }
        );
    }
    let t = std::time::Instant::now();
    let (mut flat, grad_device) = gradients::flatten(&net, &mut grads);
    ranks.sum_f32_in_place(&mut flat);
    if let Some(i) = flat.iter().position(|g| !g.is_finite()) {
        anyhow::bail!(
            "a gradient is not finite (value {i} of the summed buffer) on the global batch at stream positions {start}..{}",
            start + global as u64
        );
    }
    let device = grad_device.unwrap_or_else(|| ctx.device.clone().inner());
    let grads = gradients::restore(&net, &flat, &device);
    let exchange_seconds = t.elapsed().as_secs_f64();
    let net = optim.step(lr, net, grads);
    Ok(Outcome {
        net,
        losses,
        stop,
        exchange_seconds,
    })
}

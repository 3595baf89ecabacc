//! A data-parallel step's slice of the global batch, for the two things in a step that look
//! past a rank's own samples: the denominators of the losses and dropout's random masks.
//!
//! The slice is entered for the duration of one step ([`enter`]) rather than handed down as
//! an argument: the losses and the modules are plain tensor functions that evaluation, the
//! benchmarks and the tests call on whole batches, and only inside a data-parallel step does
//! a batch span ranks. Outside a step (and in one process) nothing here changes a single bit.

use super::ranks::{Diverged, Ranks, Tag};
use burn::nn::Dropout;
use burn::tensor::{Distribution, Tensor, TensorData};
use std::cell::{Cell, RefCell};
use std::rc::Rc;

/// Rows `offset .. offset + local` of a global batch of `global` samples.
#[derive(Clone, Debug)]
pub struct Share {
    /// The slice's first sample in the global batch.
    pub offset: usize,
    /// Its samples.
    pub local: usize,
    /// The global batch's samples.
    pub global: usize,
    ranks: Rc<Ranks>,
    diverged: Rc<Cell<bool>>,
}

impl Share {
    /// Rank `ranks.rank()`'s slice of a global batch of `global` samples (the ranks' slices
    /// are as equal as can be, in rank order).
    pub fn of(ranks: Rc<Ranks>, global: usize) -> Share {
        let (r, w) = (ranks.rank(), ranks.size());
        let (offset, end) = slice_of(r, w, global);
        Share {
            offset,
            local: end - offset,
            global,
            ranks,
            diverged: Rc::new(Cell::new(false)),
        }
    }

    /// Whether a block of this step diverged (another rank failed): the step must then end in
    /// `Ranks::resolve` on every rank.
    pub fn diverged(&self) -> bool {
        self.diverged.get()
    }

    /// The sum over the ranks of a local denominator (one block). After a divergence the
    /// ranks no longer communicate until they resolve it, and the local value is returned.
    fn total(&self, local: f64) -> f64 {
        if self.diverged.get() {
            return local;
        }
        match self.ranks.exchange(Tag::Denominator, &[local]) {
            Ok(v) => v[0],
            Err(Diverged) => {
                self.diverged.set(true);
                local
            }
        }
    }
}

/// Samples `r·n/w .. (r+1)·n/w` (rounded down) of a batch of `n`: rank `r` of `w`'s part.
pub fn slice_of(r: usize, w: usize, n: usize) -> (usize, usize) {
    (r * n / w, (r + 1) * n / w)
}

thread_local! {
    static CURRENT: RefCell<Option<Share>> = const { RefCell::new(None) };
}

/// Leaves the share when dropped.
pub struct Entered(());

impl Drop for Entered {
    fn drop(&mut self) {
        CURRENT.with(|c| c.borrow_mut().take());
    }
}

/// Makes `share` the current step's until the returned guard is dropped.
pub fn enter(share: Share) -> Entered {
    CURRENT.with(|c| *c.borrow_mut() = Some(share));
    Entered(())
}

/// The current step's share, if a data-parallel step is running on this thread.
pub fn current() -> Option<Share> {
    CURRENT.with(|c| c.borrow().clone())
}

/// The denominator of a mean over the batch (`[1]`, a sum over the batch's masks, say): its
/// sum over the ranks inside a data-parallel step, else `local` itself. The masks are data,
/// so the result is a constant of the graph.
pub fn batch_total(local: Tensor<1>) -> Tensor<1> {
    let Some(share) = current() else {
        return local;
    };
    let device = local.device();
    let v = local.into_data().iter::<f32>().next().unwrap_or(0.0) as f64;
    Tensor::from_data(TensorData::new(vec![share.total(v) as f32], [1]), &device)
}

/// The number of values a mean over the batch divides by, when this rank holds `local` of
/// them: every sample holds as many, so the global batch holds `local · global / slice`.
pub fn batch_count(local: usize) -> Option<f64> {
    let share = current()?;
    Some(local as f64 / share.local.max(1) as f64 * share.global as f64)
}

/// `layer`'s dropout on `input` (`[rows, …]`, the rows sample-major: rows = samples × k).
/// Inside a data-parallel step it draws the mask of the *global* batch (the draw a single
/// process makes for the whole batch) and keeps this rank's rows, so that a sample's mask
/// depends on its place in the global batch and the step's seed, never on the rank count;
/// elsewhere it is Burn's own dropout.
pub fn dropout<const D: usize>(layer: &Dropout, input: Tensor<D>) -> Tensor<D> {
    let Some(share) = current() else {
        return layer.forward(input);
    };
    if !layer.training.is_enabled() || !input.device().is_autodiff() || layer.prob == 0.0 {
        return input;
    }
    let dims = input.dims();
    let per = dims[0] / share.local.max(1);
    let mut global = dims;
    global[0] = per * share.global;
    let keep = 1.0 - layer.prob;
    let mask = Tensor::<D>::random(global, Distribution::Bernoulli(keep), &input.device()).narrow(
        0,
        per * share.offset,
        dims[0],
    );
    // The same two products as Burn's `Dropout::forward`, in the same order.
    (input * mask) * (1.0 / keep)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::DropoutConfig;
    use burn::tensor::Device;

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().iter::<f32>().collect()
    }

    #[test]
    fn slices_cover_the_batch_once_in_rank_order() {
        for n in 1..20 {
            for w in 1..=n {
                let mut next = 0;
                for r in 0..w {
                    let (a, b) = slice_of(r, w, n);
                    assert_eq!(a, next, "n {n} w {w} r {r}");
                    assert!(b > a, "an empty slice: n {n} w {w} r {r}");
                    next = b;
                }
                assert_eq!(next, n);
            }
        }
    }

    /// A sample's dropout mask is the one the whole batch's draw gives it, whichever slice
    /// holds it; a slice that is the whole batch is Burn's dropout bit for bit.
    #[test]
    fn dropout_of_a_slice_keeps_the_whole_batchs_mask() {
        let device = Device::flex().autodiff();
        let layer = DropoutConfig::new(0.5).init();
        let (b, r, f) = (6, 2, 40);
        let input = Tensor::<2>::random([b * r, f], Distribution::Uniform(0.5, 1.5), &device);
        device.seed(11);
        let whole = values(layer.forward(input.clone()));
        assert!(
            whole.contains(&0.0) && whole.iter().any(|&v| v > 1.0),
            "dropout did nothing"
        );
        for w in [1, 2, 3] {
            let ranks = Rc::new(Ranks::single());
            for rank in 0..w {
                let (a, e) = slice_of(rank, w, b);
                let share = Share {
                    offset: a,
                    local: e - a,
                    global: b,
                    ranks: ranks.clone(),
                    diverged: Rc::new(Cell::new(false)),
                };
                device.seed(11);
                let _in = enter(share);
                let part = values(dropout(&layer, input.clone().narrow(0, a * r, (e - a) * r)));
                assert_eq!(part, whole[a * r * f..e * r * f], "rank {rank} of {w}");
            }
        }
        assert!(current().is_none(), "the share outlived its step");
    }

    #[test]
    fn outside_a_step_nothing_changes() {
        let device = Device::flex();
        let t = Tensor::<1>::from_data(TensorData::new(vec![3.5f32], [1]), &device);
        assert_eq!(values(batch_total(t)), [3.5]);
        assert_eq!(batch_count(12), None);
    }
}

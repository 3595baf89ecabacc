//! `trainer bench-ranks`: what a data-parallel step adds to a step, measured: the all-reduce
//! of one network's gradient buffer, alone and with the flattening and the putting back that
//! surround it in a step, over the ranks the command runs as (`mpirun -np W`).

use super::gradients::{Layout, flatten, parameters, restore};
use super::ranks::Ranks;
use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Distribution, Tensor};
use std::time::Instant;

/// Milliseconds of `runs` timed repetitions (after one untimed).
#[derive(Clone, Debug)]
pub struct Timing {
    /// Sorted.
    pub ms: Vec<f64>,
}

impl Timing {
    fn of(runs: usize, mut f: impl FnMut()) -> Timing {
        f();
        let mut ms: Vec<f64> = (0..runs)
            .map(|_| {
                let t = Instant::now();
                f();
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        Timing { ms }
    }

    /// The median.
    pub fn median(&self) -> f64 {
        self.ms.get(self.ms.len() / 2).copied().unwrap_or(f64::NAN)
    }
}

/// What [`measure`] found.
#[derive(Clone, Debug)]
pub struct Report {
    /// Parameter values (the network's parameter count).
    pub parameters: usize,
    /// The buffer's length (values and presence slots).
    pub buffer: usize,
    /// The all-reduce alone.
    pub all_reduce: Timing,
    /// Flattening the gradients, the all-reduce, and putting them back.
    pub step: Timing,
}

/// Gradients shaped like `module`'s parameters, random, on `device`.
fn random_gradients<M: Module>(module: &M, device: &Device) -> GradientsParams {
    struct Make<'a> {
        device: &'a Device,
        out: GradientsParams,
    }
    impl ModuleVisitor for Make<'_> {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let t = Tensor::<D>::random(p.lazy_shape(), Distribution::Uniform(-1.0, 1.0), self.device);
            self.out.register::<D>(p.id, t);
        }
    }
    let mut m = Make {
        device,
        out: GradientsParams::new(),
    };
    module.visit(&mut m);
    m.out
}

/// Times the gradient all-reduce of `module` over `ranks`, `runs` times.
pub fn measure<M: Module>(ranks: &Ranks, module: &M, device: &Device, runs: usize) -> Report {
    // Initialised here so that the buffer holds real values (a bench, not a run).
    let _ = parameters(module);
    let layout = Layout::of(module);
    let mut buffer = vec![0.5f32; layout.buffer_len()];
    let all_reduce = Timing::of(runs, || ranks.sum_f32_in_place(&mut buffer));
    // Each repetition flattens fresh gradients (made outside the timing).
    let mut ms: Vec<f64> = (0..=runs)
        .map(|_| {
            let mut grads = random_gradients(module, device);
            let t = Instant::now();
            let (mut flat, _) = flatten(module, &mut grads);
            ranks.sum_f32_in_place(&mut flat);
            let _ = restore(module, &flat, device);
            t.elapsed().as_secs_f64() * 1e3
        })
        .skip(1)
        .collect();
    ms.sort_by(f64::total_cmp);
    let step = Timing { ms };
    Report {
        parameters: layout.values(),
        buffer: layout.buffer_len(),
        all_reduce,
        step,
    }
}

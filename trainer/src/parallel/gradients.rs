//! The gradients of a step as one buffer: flattened in module-visit order (the same order on
//! every rank, for a network of one shape), summed over the ranks in one all-reduce, and put
//! back into `GradientsParams` for the optimiser.
//!
//! Burn 0.22's own collectives exist only in its CUDA server, within one process, so the
//! buffer goes through host memory and MPI (which `into_data` does anyway on a GPU device).

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::tensor::{Device, Tensor, TensorData};

/// The float parameters of a network in visit order: their sizes and the buffer's length.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Layout {
    sizes: Vec<usize>,
}

impl Layout {
    /// The layout of `module`.
    pub fn of<M: Module>(module: &M) -> Layout {
        struct Sizes(Vec<usize>);
        impl ModuleVisitor for Sizes {
            fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
                self.0.push(p.lazy_shape().num_elements());
            }
        }
        let mut v = Sizes(Vec::new());
        module.visit(&mut v);
        Layout { sizes: v.0 }
    }

    /// Parameters (tensors).
    pub fn tensors(&self) -> usize {
        self.sizes.len()
    }

    /// Parameter values (the network's parameter count).
    pub fn values(&self) -> usize {
        self.sizes.iter().sum()
    }

    /// The buffer's length: every value, then one presence slot per tensor (1 where this rank
    /// has its gradient), so that a parameter no rank has a gradient for stays without one, as
    /// in one process (Adam would otherwise move it on its momentum).
    pub fn buffer_len(&self) -> usize {
        self.values() + self.tensors()
    }
}

/// Takes the gradients of `module`'s parameters out of `grads` into one host buffer laid out
/// by [`Layout::of`]`(module)`; a missing gradient contributes zeros. Also the device the
/// gradients live on (not the autodiff device of the parameters), if there was any.
pub fn flatten<M: Module>(module: &M, grads: &mut GradientsParams) -> (Vec<f32>, Option<Device>) {
    struct Take<'a> {
        grads: &'a mut GradientsParams,
        /// Each tensor's size and whether this rank has its gradient.
        params: Vec<(usize, bool)>,
        parts: Vec<Tensor<1>>,
    }
    impl ModuleVisitor for Take<'_> {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let n = p.lazy_shape().num_elements();
            let g = self.grads.remove::<D>(p.id);
            self.params.push((n, g.is_some()));
            self.parts.extend(g.map(|g| g.reshape([n])));
        }
    }
    let mut take = Take {
        grads,
        params: Vec::new(),
        parts: Vec::new(),
    };
    module.visit(&mut take);
    let device = take.parts.first().map(Tensor::device);
    // One concatenation and one read: on a GPU device, one transfer per step.
    let present: Vec<f32> = if take.parts.is_empty() {
        Vec::new()
    } else {
        let data = Tensor::cat(take.parts, 0).into_data();
        // Without a copy where the bytes are f32 already (as_slice checks what try_into_vec does).
        match data.as_slice::<f32>() {
            Ok(_) => data.try_into_vec::<f32>().unwrap_or_default(),
            Err(_) => data.iter::<f32>().collect(),
        }
    };
    let slots = take.params.iter().map(|&(_, has)| if has { 1.0 } else { 0.0 });
    if take.params.iter().all(|&(_, has)| has) {
        // The usual case: the gradients are the buffer already.
        let mut out = present;
        out.extend(slots);
        return (out, device);
    }
    let mut out = Vec::with_capacity(present.len() + 2 * take.params.len());
    let mut from = 0;
    for &(n, has) in &take.params {
        if has {
            out.extend_from_slice(&present[from..from + n]);
            from += n;
        } else {
            out.extend(std::iter::repeat_n(0.0, n));
        }
    }
    out.extend(slots);
    (out, device)
}

/// Registers the summed buffer's gradients into a fresh `GradientsParams` for `module`, on
/// `device` (the device the gradients came from); a tensor no rank had
/// a gradient for gets none.
pub fn restore<M: Module>(module: &M, summed: &[f32], device: &Device) -> GradientsParams {
    struct Put<'a> {
        summed: &'a [f32],
        present: &'a [f32],
        at: usize,
        index: usize,
        device: &'a Device,
        out: GradientsParams,
    }
    impl ModuleVisitor for Put<'_> {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            let shape = p.lazy_shape();
            let n = shape.num_elements();
            let values = &self.summed[self.at..self.at + n];
            if self.present[self.index] > 0.0 {
                let t = Tensor::<D>::from_data(TensorData::new(values.to_vec(), shape), self.device);
                self.out.register::<D>(p.id, t);
            }
            self.at += n;
            self.index += 1;
        }
    }
    let layout = Layout::of(module);
    let (values, present) = summed.split_at(layout.values());
    let mut put = Put {
        summed: values,
        present,
        at: 0,
        index: 0,
        device,
        out: GradientsParams::new(),
    };
    module.visit(&mut put);
    put.out
}

/// Every parameter value of `module` in visit order.
pub fn parameters<M: Module>(module: &M) -> Vec<f32> {
    struct Values(Vec<f32>);
    impl ModuleVisitor for Values {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            self.0.extend(p.val().into_data().iter::<f32>());
        }
    }
    let mut v = Values(Vec::new());
    module.visit(&mut v);
    v.0
}

/// blake3 of every parameter value in visit order (the ranks compare it). A parameter Burn
/// has not initialised yet contributes its shape only: reading it would initialise it from the
/// device's random source there and then, not where the first forward pass initialises it in
/// one process, and the run would no longer equal one process's.
pub fn checksum<M: Module>(module: &M) -> [u8; 32] {
    struct Hash(blake3::Hasher);
    impl ModuleVisitor for Hash {
        fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
            if !p.is_initialized() {
                self.0.update(b"lazy");
                for d in p.lazy_shape().dims::<D>() {
                    self.0.update(&(d as u64).to_le_bytes());
                }
                return;
            }
            for v in p.val().into_data().iter::<f32>() {
                self.0.update(&v.to_le_bytes());
            }
        }
    }
    let mut h = Hash(blake3::Hasher::new());
    module.visit(&mut h);
    *h.0.finalize().as_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{Linear, LinearConfig};
    use burn::tensor::Distribution;

    #[derive(Module, Debug)]
    struct Two {
        used: Linear,
        unused: Linear,
    }

    /// Gradients flattened and put back are the gradients, in place and on the right device; a
    /// parameter without a gradient stays without one (and a zero block holds its place).
    #[test]
    fn flattened_gradients_come_back_as_they_were() {
        let device = Device::flex().autodiff();
        let net = Two {
            used: LinearConfig::new(3, 2).init(&device),
            unused: LinearConfig::new(2, 4).init(&device),
        };
        let x = Tensor::<2>::random([5, 3], Distribution::Uniform(-1.0, 1.0), &device);
        let loss = net.used.forward(x).powi_scalar(2).sum();
        let mut grads = GradientsParams::from_grads(loss.backward(), &net);
        let want_w: Vec<f32> = grads.get::<2>(net.used.weight.id).unwrap().into_data().iter().collect();
        let want_b: Vec<f32> = grads
            .get::<1>(net.used.bias.as_ref().unwrap().id)
            .unwrap()
            .into_data()
            .iter()
            .collect();
        let layout = Layout::of(&net);
        assert_eq!((layout.tensors(), layout.values()), (4, 6 + 2 + 8 + 4));
        let (flat, dev) = flatten(&net, &mut grads);
        assert_eq!(flat.len(), layout.buffer_len());
        assert_eq!(&flat[..6], &want_w[..]);
        assert_eq!(&flat[6..8], &want_b[..]);
        assert!(
            flat[8..20].iter().all(|&v| v == 0.0),
            "the unused layer's block is not zero"
        );
        assert_eq!(&flat[20..], &[1.0, 1.0, 0.0, 0.0], "presence slots");
        let back = restore(&net, &flat, &dev.expect("a gradient's device"));
        let got: Vec<f32> = back.get::<2>(net.used.weight.id).unwrap().into_data().iter().collect();
        assert_eq!(got, want_w);
        assert!(back.get::<2>(net.unused.weight.id).is_none(), "a gradient appeared");
        assert_eq!(back.len(), 2);
    }

    /// The checksum reads no parameter Burn has not initialised (that would draw it from the
    /// random source out of turn) and tells weights apart.
    #[test]
    fn the_checksum_leaves_lazy_parameters_alone() {
        let device = Device::flex();
        let a = LinearConfig::new(3, 2).init(&device);
        assert!(
            !a.weight.is_initialized(),
            "Burn initialises eagerly now: the test has no lazy parameter"
        );
        let before = checksum(&a);
        assert!(!a.weight.is_initialized(), "the checksum initialised a parameter");
        let _ = parameters(&a);
        assert_ne!(checksum(&a), before, "initialised weights hash like lazy ones");
        let b = LinearConfig::new(3, 2).init(&device);
        let _ = parameters(&b);
        assert_ne!(checksum(&a), checksum(&b));
        assert_eq!(checksum(&a), checksum(&a.clone()));
    }
}

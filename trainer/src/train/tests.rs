//! Training steps on synthetic batches: finite, decreasing on a fixed batch, reproducible.

use super::network::NetConfig;
use super::perceptual::Perceptual;
use super::step::{LossWeights, StepContext, StepKind, train_step};
use super::synthetic::sphere_batch;
use crate::model::Widths;
use crate::render::RenderingLayer;
use burn::optim::AdamConfig;
use burn::tensor::Device;

/// Burn's seed is process-wide: tests that depend on it take turns.
static SEEDED: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn run(kind: StepKind, steps: usize, seed: u64) -> Vec<f64> {
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let device = Device::flex().autodiff();
    device.seed(seed);
    let layer = RenderingLayer::new(8);
    let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(8);
    let mut net = cfg.init(&device);
    let mut optim = AdamConfig::new().init();
    let batch = sphere_batch(2, 16, 8, 3, &layer);
    let w = LossWeights::default();
    let ctx = StepContext {
        layer: &layer,
        weights: &w,
        perceptual: &Perceptual::Fallback,
        device: &device,
    };
    let mut out = Vec::new();
    for _ in 0..steps {
        let (n, l) = train_step(net, &mut optim, 1e-3, &batch, kind, &ctx).unwrap();
        net = n;
        out.push(l.total);
        assert!(l.normal.is_finite() && l.material.is_finite() && l.perceptual.is_finite());
        if kind == StepKind::JOINT {
            assert!(l.perceptual > 0.0);
        }
    }
    out
}

#[test]
fn pretraining_lowers_the_loss_on_a_fixed_batch_and_is_reproducible() {
    let a = run(StepKind::PRETRAIN, 8, 1);
    assert!(a[7] < a[0], "{a:?}");
    let b = run(StepKind::PRETRAIN, 8, 1);
    assert_eq!(a, b);
}

#[test]
fn joint_steps_through_the_rendering_layer_are_finite_and_lower_the_loss() {
    let a = run(StepKind::JOINT, 6, 2);
    assert!(a[5] < a[0], "{a:?}");
}

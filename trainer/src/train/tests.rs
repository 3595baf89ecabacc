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

/// What Sec. 3.2 asks of each module's output, on a two-region batch of spheres: normals of
/// unit length at full resolution, a positive 64×128-shaped HDR map, and one tanh-range
/// 108-vector per region; and extreme inputs (huge radiance, an empty mask) stay finite.
#[test]
fn module_outputs_have_the_papers_shapes_and_ranges() {
    use super::batch::HostBatch;
    use super::step::predict;
    use burn::tensor::TensorData;
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let device = Device::flex();
    device.seed(11);
    let (b, s, he) = (2, 32, 8);
    let layer = RenderingLayer::new(he);
    let cfg = NetConfig::new(s, Widths::new(4, 16, 32, 8)).with_env_height(he);
    let net = cfg.init(&device);
    let mut hb: HostBatch = sphere_batch(b, s, he, 5, &layer);
    // Two regions: the left half of each sphere is material 1, the right half material 2.
    hb.regions = 2;
    for (i, r) in hb.region_map.iter_mut().enumerate() {
        if *r > 0 && i % s >= s / 2 {
            *r = 2;
        }
    }
    hb.materials = hb
        .materials
        .chunks(matedit_physics::brdf::dsbrdf::PARAMS)
        .flat_map(|m| [m, m])
        .flatten()
        .copied()
        .collect();
    hb.target_materials = hb.materials.clone();
    let values = |t: TensorData| t.try_to_vec::<f32>().unwrap();
    for scale in [1.0f32, 1e6] {
        let mut hb = hb.clone();
        hb.input.iter_mut().for_each(|v| *v *= scale);
        let p = predict(&net, &hb.to_device(&device), true);
        assert_eq!(p.normals.dims(), [b, 3, s, s]);
        assert_eq!(p.materials.dims(), [b, 2, matedit_physics::brdf::dsbrdf::PARAMS]);
        let env = p.env.expect("the illumination module ran");
        assert_eq!(env.dims(), [b, 3, he, 2 * he]);
        let n = values(p.normals.into_data());
        for k in 0..b {
            for px in 0..s * s {
                if hb.mask[k * s * s + px] > 0.5 {
                    let len: f32 = (0..3).map(|c| n[(k * 3 + c) * s * s + px].powi(2)).sum::<f32>().sqrt();
                    assert!((len - 1.0).abs() < 1e-4, "scale {scale}: |n'| = {len}");
                }
            }
        }
        let m = values(p.materials.into_data());
        assert!(
            m.iter().all(|v| v.is_finite() && v.abs() <= 1.0),
            "scale {scale}: m' in tanh range"
        );
        let l = values(env.into_data());
        assert!(
            l.iter().all(|v| v.is_finite() && *v > 0.0),
            "scale {scale}: L' positive and finite"
        );
    }
    // An empty mask (nothing to see) still gives finite predictions.
    let mut empty = hb.clone();
    empty.mask.iter_mut().for_each(|v| *v = 0.0);
    empty.region_map.iter_mut().for_each(|v| *v = 0);
    let p = predict(&net, &empty.to_device(&device), true);
    for v in values(p.normals.into_data())
        .iter()
        .chain(&values(p.materials.into_data()))
    {
        assert!(v.is_finite());
    }
}

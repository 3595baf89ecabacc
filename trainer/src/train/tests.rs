//! Training steps on synthetic batches: finite, decreasing on a fixed batch, reproducible.

use super::loss::Perceptual;
use super::loss::{
    ILLUMINATION, LIGHT_DIRECTION, LIGHT_ENERGY, LossWeights, Losses, MATERIAL, NORMAL, PERCEPTUAL, SSIM,
};
use super::stage_kind::StageKind;
use super::step::{RenderWith, Source, StepContext, StepKind, train_step};
use super::synthetic::sphere_batch;
use crate::data;
use crate::model::Widths;
use crate::model::network::{Net, NetConfig};
use crate::rendering_layer::RenderingLayer;
use crate::rendering_layer::op::host;
use burn::optim::AdamConfig;
use burn::tensor::Device;

/// Burn's seed is process-wide: tests that depend on it take turns.
static SEEDED: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn run(kind: StepKind, steps: usize, seed: u64) -> Vec<f64> {
    run_with(kind, steps, seed, &LossWeights::default())
        .iter()
        .map(|l| l.total)
        .collect()
}

/// A small network seeded with `seed` (callers hold `SEEDED`), its rendering layer and one fixed
/// batch of 16² spheres under 8×16 maps.
fn fixture(seed: u64, widths: Widths) -> (Device, RenderingLayer, Net, data::Batch) {
    let device = Device::flex().autodiff();
    device.seed(seed);
    let layer = RenderingLayer::new(8);
    let net = NetConfig::new(16, widths).with_env_height(8).init(&device);
    let batch = sphere_batch(2, 16, 8, 3, &layer);
    (device, layer, net, batch)
}

/// `steps` steps on one fixed batch of spheres from a network seeded with `seed`: each step's
/// losses, all checked finite.
fn run_with(kind: StepKind, steps: usize, seed: u64, w: &LossWeights) -> Vec<Losses> {
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let (device, layer, mut net, batch) = fixture(seed, Widths::new(4, 16, 32, 8));
    let mut optim = AdamConfig::new().init();
    let ctx = StepContext {
        layer: &layer,
        weights: w,
        perceptual: &Perceptual::Fallback { why: "tests" },
        device: &device,
    };
    let mut out = Vec::new();
    for _ in 0..steps {
        let (n, l) = train_step(net, &mut optim, 1e-3, &batch, kind, &ctx).unwrap();
        net = n;
        assert!(l[&NORMAL].is_finite() && l[&MATERIAL].is_finite() && l[&PERCEPTUAL].is_finite());
        assert!(l[&ILLUMINATION].is_finite());
        if kind == StepKind::JOINT {
            assert!(l[&PERCEPTUAL] > 0.0);
        }
        out.push(l);
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

/// Baseline 1 (the encoder–decoder) on one fixed batch: its loss (L2 on f_m, perceptual and
/// structural on O') falls, reproducibly.
#[test]
fn the_encoder_decoder_baseline_lowers_its_loss_on_a_fixed_batch_and_is_reproducible() {
    let go = || {
        let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
        let device = Device::flex().autodiff();
        device.seed(7);
        let layer = RenderingLayer::new(8);
        let mut net = NetConfig::new(16, Widths::new(4, 16, 32, 8))
            .with_env_height(8)
            .with_encoder_decoder(true)
            .init(&device);
        let batch = sphere_batch(2, 16, 8, 3, &layer);
        let mut optim = AdamConfig::new().init();
        let w = LossWeights::default().with(&SSIM, 1e3);
        let ctx = StepContext {
            layer: &layer,
            weights: &w,
            perceptual: &Perceptual::Fallback { why: "tests" },
            device: &device,
        };
        let kind = StepKind {
            kind: StageKind::EncoderDecoder,
            render_with: RenderWith::default(),
        };
        let mut out = Vec::new();
        for _ in 0..10 {
            let (n, l) = train_step(net, &mut optim, 2e-3, &batch, kind, &ctx).unwrap();
            net = n;
            assert!(
                l[&MATERIAL] > 0.0 && l[&PERCEPTUAL] > 0.0 && l[&SSIM] > 0.0 && l[&NORMAL] == 0.0,
                "{l:?}"
            );
            out.push(l.total);
        }
        out
    };
    let a = go();
    assert!(a.windows(2).all(|w| w[1] < w[0]) && a[9] < 0.95 * a[0], "{a:?}");
    assert_eq!(a, go());
    // A network without the encoder–decoder refuses the stage with a message.
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let (device, layer, net, batch) = fixture(1, Widths::new(4, 16, 32, 8));
    let ctx = StepContext {
        layer: &layer,
        weights: &LossWeights::default(),
        perceptual: &Perceptual::Fallback { why: "tests" },
        device: &device,
    };
    let kind = StepKind {
        kind: StageKind::EncoderDecoder,
        render_with: RenderWith::default(),
    };
    let e = train_step(net, &mut AdamConfig::new().init(), 1e-3, &batch, kind, &ctx)
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("encoder-decoder"), "{e}");
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
    use burn::tensor::TensorData;
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let device = Device::flex();
    device.seed(11);
    let (b, s, he) = (2, 32, 8);
    let layer = RenderingLayer::new(he);
    let cfg = NetConfig::new(s, Widths::new(4, 16, 32, 8)).with_env_height(he);
    let net = cfg.init(&device);
    let mut hb: data::Batch = sphere_batch(b, s, he, 5, &layer);
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
        let tb = hb.to_device(&device);
        let p = net.predict(&tb.input, &tb.mask, &tb.region_masks, true);
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
    let tb = empty.to_device(&device);
    let p = net.predict(&tb.input, &tb.mask, &tb.region_masks, true);
    for v in values(p.normals.into_data())
        .iter()
        .chain(&values(p.materials.into_data()))
    {
        assert!(v.is_finite());
    }
}

/// With a weight on the direct illumination loss, pretraining also trains L' and reports it;
/// without (the paper), the term is 0.
#[test]
fn pretraining_with_the_direct_illumination_loss_lowers_it() {
    for w_l in [0.0, 1.0] {
        let w = LossWeights::default().with(&ILLUMINATION, w_l);
        let seen: Vec<f64> = run_with(StepKind::PRETRAIN, 8, 5, &w)
            .iter()
            .map(|l| l[&ILLUMINATION])
            .collect();
        if w_l == 0.0 {
            assert!(seen.iter().all(|v| *v == 0.0), "{seen:?}");
        } else {
            assert!(seen[0] > 0.0 && seen[7] < seen[0], "{seen:?}");
        }
    }
}

/// The loss on L''s energy trains the illumination module on its own (every other weight 0):
/// reported and falling at every pretraining step with w_E > 0, absent (0, and the total 0) without.
#[test]
fn pretraining_with_the_light_energy_loss_lowers_it() {
    for w_e in [0.0, 100.0] {
        let w = LossWeights::NONE.with(&LIGHT_ENERGY, w_e);
        let seen = run_with(StepKind::PRETRAIN, 8, 5, &w);
        let energy: Vec<f64> = seen.iter().map(|l| l[&LIGHT_ENERGY]).collect();
        if w_e == 0.0 {
            assert!(
                seen.iter().all(|l| l[&LIGHT_ENERGY] == 0.0 && l.total == 0.0),
                "{seen:?}"
            );
        } else {
            assert!(energy[0] > 0.0 && energy.windows(2).all(|p| p[1] < p[0]), "{energy:?}");
            assert!(seen.iter().all(|l| l.total == w_e * l[&LIGHT_ENERGY]), "{seen:?}");
        }
    }
}

/// The loss on where L' comes from trains the illumination module alone: with every other
/// weight 0, a pretraining step with w_D > 0 reports it (in (0, 4]) as the whole total and moves
/// L' but not n', and eight steps end below where they began; with w_D = 0 nothing is reported
/// and nothing moves. (It falls slowly: placing a light means changing the map's layout, where
/// the energy loss moves one bias.)
#[test]
fn pretraining_with_the_light_direction_loss_trains_the_illumination_module() {
    for w_d in [0.0, 100.0] {
        let w = LossWeights::NONE.with(&LIGHT_DIRECTION, w_d);
        let (l, n_moved, l_moved) = one_joint_step(5, &w, StepKind::PRETRAIN);
        let seen = run_with(StepKind::PRETRAIN, 8, 5, &w);
        let direction: Vec<f64> = seen.iter().map(|l| l[&LIGHT_DIRECTION]).collect();
        if w_d == 0.0 {
            assert!(
                seen.iter().all(|l| l[&LIGHT_DIRECTION] == 0.0 && l.total == 0.0),
                "{seen:?}"
            );
            assert!(n_moved == 0.0 && l_moved == 0.0, "nothing to learn from");
        } else {
            assert!(l[&LIGHT_DIRECTION] > 0.0 && l[&LIGHT_DIRECTION] <= 4.0, "{l:?}");
            assert!(n_moved == 0.0 && l_moved > 1e-6, "n' moved {n_moved}, L' {l_moved}");
            assert!(direction[7] < direction[0], "{direction:?}");
            assert!(seen.iter().all(|l| l.total == w_d * l[&LIGHT_DIRECTION]), "{seen:?}");
        }
    }
}

/// One joint step of a fresh seeded network (no dropout) with weights `w`: the step's losses and
/// how far (largest absolute change on the fixed batch) it moved n' and L'.
fn one_joint_step(seed: u64, w: &LossWeights, kind: StepKind) -> (Losses, f32, f32) {
    let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
    let (device, layer, net, batch) = fixture(seed, Widths::new(4, 16, 32, 8).with_dropout(0.0));
    let b = batch.to_device(&device);
    let outputs = |net: &Net| {
        (
            host(&net.normal.forward(b.input.clone(), b.mask.clone())),
            host(&net.illumination.forward(b.input.clone(), b.mask.clone())),
        )
    };
    let (n0, l0) = outputs(&net);
    let ctx = StepContext {
        layer: &layer,
        weights: w,
        perceptual: &Perceptual::Fallback { why: "tests" },
        device: &device,
    };
    let (net, l) = train_step(net, &mut AdamConfig::new().init(), 1e-3, &batch, kind, &ctx).unwrap();
    let (n1, l1) = outputs(&net);
    let moved = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
    (l, moved(&n0, &n1), moved(&l0, &l1))
}

/// `render_with = { normals = "detached" }`: the rendering layer reads n' but its gradient stops
/// there. With w_n = w_m = 0 (only the perceptual loss), one joint step leaves the normal
/// module's output where it was, while with n' predicted (Fig. 2) it moves; L' learns in both.
#[test]
fn detached_normals_get_no_gradient_from_the_rendering_layer() {
    for (normals, normals_move) in [(Source::Predicted, true), (Source::Detached, false)] {
        let w = LossWeights::default().with(&NORMAL, 0.0).with(&MATERIAL, 0.0);
        let kind = StepKind {
            kind: StageKind::Joint,
            render_with: RenderWith {
                normals,
                ..RenderWith::default()
            },
        };
        let (l, n_moved, l_moved) = one_joint_step(7, &w, kind);
        assert!(l[&PERCEPTUAL] > 0.0 && l.total.is_finite(), "{l:?}");
        assert_eq!(n_moved > 1e-6, normals_move, "{normals:?}: n' moved {n_moved}");
        assert!(l_moved > 1e-6, "{normals:?}: L' did not learn");
    }
}

/// The structural loss trains the modules through the rendering layer: with every other weight
/// 0, a joint step with w_s > 0 reports 1 − SSIM on I' and O' and moves n' and L'; with w_s = 0
/// it reports 0 and nothing moves.
#[test]
fn the_ssim_loss_trains_through_the_rendering_layer() {
    for w_s in [0.0, 100.0] {
        let w = LossWeights::NONE.with(&SSIM, w_s);
        let (l, n_moved, l_moved) = one_joint_step(11, &w, StepKind::JOINT);
        if w_s > 0.0 {
            assert!(l[&SSIM] > 0.0 && l[&SSIM] <= 4.0 && l.total == w_s * l[&SSIM], "{l:?}");
            assert!(n_moved > 1e-6 && l_moved > 1e-6, "n' and L' learn");
        } else {
            assert!(l[&SSIM] == 0.0 && l.total == 0.0, "{l:?}");
            assert!(n_moved == 0.0 && l_moved == 0.0, "nothing to learn from");
        }
    }
}

/// A device a manifest names is checked before anything runs, and a refusal says why.
#[test]
fn device_names_are_checked_with_their_reason() {
    use crate::device::check_device_name;
    assert!(check_device_name("cpu").is_ok());
    let e = check_device_name("tpu").unwrap_err();
    assert!(
        e.contains("unknown device \"tpu\"") && e.contains("cpu, wgpu, cuda"),
        "{e}"
    );
    if cfg!(feature = "wgpu") {
        assert!(check_device_name("wgpu").is_ok());
    } else {
        let e = check_device_name("wgpu").unwrap_err();
        assert!(e.contains("--features wgpu"), "{e}");
    }
    if !cfg!(feature = "cuda") {
        assert!(check_device_name("cuda").unwrap_err().contains("--features cuda"));
    }
}

/// A few training steps on the GPU device (lavapipe in CI) give the CPU device's losses: the
/// same seeded network (no dropout: its masks are drawn per device) forked to the GPU, three
/// steps of each stage on one fixed batch, with every loss term switched on. The first step's
/// losses agree to 1e-4 (the same weights; only the arithmetic differs); later steps to 1e-2,
/// as both devices' rounding moves the weights apart.
#[cfg(feature = "wgpu")]
#[test]
fn training_steps_on_the_gpu_device_give_the_cpu_devices_losses() {
    use burn::module::Module;
    let Some(gpu) = crate::rendering_layer::gpu::tests::device() else {
        return;
    };
    let gpu = gpu.autodiff();
    let w = LossWeights::default().with(&ILLUMINATION, 10.0).with(&SSIM, 100.0);
    let encoder_decoder = StepKind {
        kind: StageKind::EncoderDecoder,
        render_with: RenderWith::default(),
    };
    for (name, kind) in [
        ("pretraining", StepKind::PRETRAIN),
        ("joint", StepKind::JOINT),
        ("encoder-decoder", encoder_decoder),
    ] {
        let _turn = SEEDED.lock().unwrap_or_else(|e| e.into_inner());
        let cpu = Device::flex().autodiff();
        cpu.seed(5);
        let layer = RenderingLayer::new(8);
        let net = NetConfig::new(16, Widths::new(4, 16, 32, 8).with_dropout(0.0))
            .with_env_height(8)
            .with_encoder_decoder(kind.kind == StageKind::EncoderDecoder)
            .init(&cpu);
        let batch = sphere_batch(2, 16, 8, 3, &layer);
        let steps = |mut net: Net, device: &Device| {
            let ctx = StepContext {
                layer: &layer,
                weights: &w,
                perceptual: &Perceptual::Fallback { why: "tests" },
                device,
            };
            let mut optim = AdamConfig::new().init();
            let mut out = Vec::new();
            for _ in 0..3 {
                let (n, l) = train_step(net, &mut optim, 1e-3, &batch, kind, &ctx).unwrap();
                net = n;
                out.push(l);
            }
            out
        };
        let on_gpu = steps(net.clone().fork(&gpu), &gpu);
        let on_cpu = steps(net, &cpu);
        let mut worst = (0.0f64, "", 0);
        for (i, (c, g)) in on_cpu.iter().zip(&on_gpu).enumerate() {
            let tolerance = if i == 0 { 1e-4 } else { 1e-2 };
            let terms = [
                ("total", c.total, g.total),
                ("normal", c[&NORMAL], g[&NORMAL]),
                ("material", c[&MATERIAL], g[&MATERIAL]),
                ("perceptual", c[&PERCEPTUAL], g[&PERCEPTUAL]),
                ("illumination", c[&ILLUMINATION], g[&ILLUMINATION]),
                ("ssim", c[&SSIM], g[&SSIM]),
            ];
            for (term, a, b) in terms {
                assert!(b.is_finite(), "{name} step {i}: {term} on the GPU is {b}");
                let relative = (a - b).abs() / a.abs().max(1e-3);
                assert!(
                    relative <= tolerance,
                    "{name} step {i}: {term} {a} on the CPU, {b} on the GPU"
                );
                if relative > worst.0 {
                    worst = (relative, term, i);
                }
            }
        }
        eprintln!(
            "{name}: worst relative difference of a loss term {:.1e} ({} at step {}); total at step 2 {:.6} (CPU) vs {:.6} (GPU)",
            worst.0, worst.1, worst.2, on_cpu[2].total, on_gpu[2].total
        );
        assert!(on_cpu[0].total > 0.0);
    }
}

/// Width presets are one list, read by manifests and `trainer bench --train`.
#[test]
fn width_presets_resolve_by_name_and_unknown_names_are_listed() {
    use crate::model::Widths;
    assert_eq!(Widths::preset("cpu-small"), Some(Widths::cpu_small()));
    assert_eq!(Widths::preset("paper"), Some(Widths::paper()));
    for bad in ["", "CPU-small", "paper ", "tiny"] {
        assert_eq!(Widths::preset(bad), None, "{bad:?}");
    }
    assert_eq!(Widths::preset_names(), "cpu-small, paper");
}

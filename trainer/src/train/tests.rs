//! Training steps on synthetic batches: finite, decreasing on a fixed batch, reproducible.

use super::perceptual::Perceptual;
use super::step::{LossWeights, RenderWith, Source, StageKind, StepContext, StepKind, train_step};
use super::synthetic::sphere_batch;
use crate::data;
use crate::model::Widths;
use crate::model::network::{Net, NetConfig};
use crate::render::RenderingLayer;
use crate::render::op::host;
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
fn run_with(kind: StepKind, steps: usize, seed: u64, w: &LossWeights) -> Vec<super::step::Losses> {
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
        assert!(l.normal.is_finite() && l.material.is_finite() && l.perceptual.is_finite());
        assert!(l.illumination.is_finite());
        if kind == StepKind::JOINT {
            assert!(l.perceptual > 0.0);
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
        let w = LossWeights {
            ssim: 1e3,
            ..LossWeights::default()
        };
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
                l.material > 0.0 && l.perceptual > 0.0 && l.ssim > 0.0 && l.normal == 0.0,
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

fn tensor4(v: Vec<f32>, shape: [usize; 4], device: &Device) -> burn::tensor::Tensor<4> {
    burn::tensor::Tensor::from_data(burn::tensor::TensorData::new(v, shape), device)
}

/// ∂`loss`/∂`x` as plain values (`x` made with `require_grad`).
fn gradient(x: &burn::tensor::Tensor<4>, loss: burn::tensor::Tensor<1>) -> Vec<f32> {
    let grads = loss.backward();
    x.grad(&grads)
        .expect("gradient")
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
}

/// The fallback's tone map follows the evaluation's (`metrics`) where that one is not
/// clipped, is smooth above white, and stays finite on hard inputs.
#[test]
fn the_fallback_tone_map_follows_the_metrics_and_stays_finite() {
    use super::loss::display;
    use matedit_physics::tonemap::tonemap_u8;
    let device = Device::flex();
    let xs: Vec<f32> = vec![
        0.0,
        1e-6,
        0.01,
        0.1,
        0.25,
        0.5,
        0.7,
        1.0,
        2.0,
        1e3,
        1e30,
        f32::MAX,
        -5.0,
    ];
    let n = xs.len();
    let exposure = 0.8f32;
    let out = display(
        tensor4(xs.clone(), [1, 1, 1, n], &device),
        tensor4(vec![exposure], [1, 1, 1, 1], &device),
    )
    .into_data()
    .try_to_vec::<f32>()
    .unwrap();
    for (x, d) in xs.iter().zip(&out) {
        assert!(d.is_finite() && (0.0..=255.0).contains(d), "display({x}) = {d}");
        if (0.0..=0.5).contains(&(x * exposure)) {
            // The metric rounds to integers; the soft clamp is within 2 % of y up to y = 0.5.
            let metric = f32::from(tonemap_u8(*x, exposure));
            assert!((d - metric).abs() <= 3.0, "display({x}) = {d}, metric {metric}");
        }
    }
    assert!(out.windows(2).take(n - 2).all(|w| w[0] <= w[1]), "monotone: {out:?}");
    assert!(out[n - 2] > 254.9, "saturates at white: {out:?}");
}

/// Multiplying prediction and truth by the same factor does not change the fallback loss (the
/// exposure belongs to the truth), and an over-bright prediction still gets a gradient.
#[test]
fn the_fallback_loss_ignores_the_light_probes_scale_and_pulls_down_overshoot() {
    use super::loss::perceptual_fallback;
    let device = Device::flex().autodiff();
    let (h, w) = (8, 8);
    let truth: Vec<f32> = (0..3 * h * w)
        .map(|i| 0.05 + 0.9 * ((i * 37 % 64) as f32 / 64.0))
        .collect();
    let pred: Vec<f32> = truth
        .iter()
        .enumerate()
        .map(|(i, v)| v * (0.7 + 0.01 * (i % 50) as f32))
        .collect();
    let mask = vec![1.0f32; h * w];
    let loss = |scale: f32| {
        let s = |v: &[f32]| v.iter().map(|x| x * scale).collect::<Vec<_>>();
        let l = perceptual_fallback(
            tensor4(s(&pred), [1, 3, h, w], &device),
            tensor4(s(&truth), [1, 3, h, w], &device),
            tensor4(mask.clone(), [1, 1, h, w], &device),
        );
        l.into_data().try_to_vec::<f32>().unwrap()[0]
    };
    let (a, b) = (loss(1.0), loss(1000.0));
    assert!(a > 0.0 && ((a - b) / a).abs() < 1e-3, "{a} vs {b}");
    // Ten times too bright everywhere: far above white, yet the gradient points down.
    let p = tensor4(truth.iter().map(|v| v * 10.0).collect(), [1, 3, h, w], &device).require_grad();
    let l = perceptual_fallback(
        p.clone(),
        tensor4(truth.clone(), [1, 3, h, w], &device),
        tensor4(mask, [1, 1, h, w], &device),
    );
    let g = gradient(&p, l);
    assert!(g.iter().all(|v| v.is_finite()), "finite gradient");
    assert!(
        g.iter().all(|v| *v >= 0.0) && g.iter().any(|v| *v > 0.0),
        "pulls every pixel down"
    );
}

/// The optional direct loss on L': zero at the truth, blind to the probe's absolute scale,
/// finite with a finite gradient on hard maps (huge, zero and tiny texels).
#[test]
fn the_direct_illumination_loss_is_scale_free_and_finite() {
    use super::loss::illumination_loss;
    let device = Device::flex().autodiff();
    let (h, w) = (4, 8);
    let truth: Vec<f32> = (0..3 * h * w).map(|i| 0.01 + (i % 7) as f32).collect();
    let pred: Vec<f32> = truth.iter().rev().copied().collect();
    let loss = |p: &[f32], t: &[f32]| {
        illumination_loss(
            tensor4(p.to_vec(), [1, 3, h, w], &device),
            tensor4(t.to_vec(), [1, 3, h, w], &device),
        )
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()[0]
    };
    assert_eq!(loss(&truth, &truth), 0.0);
    let (a, b) = (
        loss(&pred, &truth),
        loss(
            &pred.iter().map(|v| v * 1e4).collect::<Vec<_>>(),
            &truth.iter().map(|v| v * 1e4).collect::<Vec<_>>(),
        ),
    );
    assert!(a > 0.0 && ((a - b) / a).abs() < 1e-3, "{a} vs {b}");
    let hard: Vec<f32> = (0..3 * h * w).map(|i| [0.0, 1e-30, 3e38, 1.0][i % 4]).collect();
    let p = tensor4(hard, [1, 3, h, w], &device).require_grad();
    let l = illumination_loss(p.clone(), tensor4(truth, [1, 3, h, w], &device));
    let g = gradient(&p, l);
    assert!(g.iter().all(|v| v.is_finite()), "finite gradient");
}

/// The optional loss on L''s energy against closed forms: ln²k for a map scaled by k, the rows
/// weighted by their solid angle, blind to the probe's absolute scale, charging the energy of a
/// sun that the direct loss clips away, finite on hard maps, its gradient equal to central
/// differences.
#[test]
fn the_light_energy_loss_matches_its_closed_forms() {
    use super::loss::{LIGHT_ENERGY_FLOOR, illumination_loss, light_energy_loss};
    let device = Device::flex().autodiff();
    let (h, w) = (8, 16);
    let n = 3 * h * w;
    let value = |t: burn::tensor::Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0] as f64;
    let loss = |p: &[f32], t: &[f32]| {
        value(light_energy_loss(
            tensor4(p.to_vec(), [1, 3, h, w], &device),
            tensor4(t.to_vec(), [1, 3, h, w], &device),
        ))
    };
    let truth: Vec<f32> = noise(n, 7).iter().map(|v| 0.05 + 2.0 * v).collect();
    assert_eq!(loss(&truth, &truth), 0.0);
    // Each channel's mean radiance over the sphere, in f64: rows weighted by sin θ.
    let sin = |row: usize| ((row as f64 + 0.5) * std::f64::consts::PI / h as f64).sin();
    let energies = |m: &[f32]| -> Vec<f64> {
        let total: f64 = (0..h).map(sin).sum::<f64>() * w as f64;
        (0..3)
            .map(|c| (0..h * w).map(|t| sin(t / w) * m[c * h * w + t] as f64).sum::<f64>() / total)
            .collect()
    };
    for k in [1e-3f32, 0.5, 2.0, 1e3] {
        let scaled: Vec<f32> = truth.iter().map(|v| v * k).collect();
        // ln²k but for the floor ε, which matters only where k·E nears it.
        let want = energies(&truth)
            .iter()
            .map(|e| {
                ((k as f64 * e + LIGHT_ENERGY_FLOOR) / (e + LIGHT_ENERGY_FLOOR))
                    .ln()
                    .powi(2)
            })
            .sum::<f64>()
            / 3.0;
        assert!((want - (k as f64).ln().powi(2)).abs() <= 1e-3 * want);
        let got = loss(&scaled, &truth);
        assert!((got - want).abs() <= 1e-4 * want, "k {k}: {got} vs ln²k {want}");
        // The same mistake at a far larger absolute scale costs ln²k, the floor negligible.
        let big: Vec<f32> = truth.iter().map(|v| v * 1e4).collect();
        let big_scaled: Vec<f32> = big.iter().map(|v| v * k).collect();
        let ln2k = (k as f64).ln().powi(2);
        assert!((loss(&big_scaled, &big) - ln2k).abs() <= 1e-4 * ln2k);
    }
    // Solid-angle weights: one bright row near the pole against the same row at the equator.
    let row_map = |row: usize| -> Vec<f32> { (0..n).map(|i| if (i / w) % h == row { 1.0 } else { 0.0 }).collect() };
    let want = (sin(0) / sin(h / 2)).ln().powi(2);
    let got = loss(&row_map(0), &row_map(h / 2));
    assert!((got - want).abs() <= 1e-3 * want, "{got} vs {want}");
    // A sun of one texel holding most of the energy: the direct loss, clipped at the truth's
    // 99th percentile, barely sees it missing; the energy loss does.
    let sky: Vec<f32> = vec![0.5; n];
    let mut sun = sky.clone();
    for c in 0..3 {
        sun[c * h * w + 2 * w + 3] = 5e4;
    }
    let direct = |p: &[f32], t: &[f32]| {
        value(illumination_loss(
            tensor4(p.to_vec(), [1, 3, h, w], &device),
            tensor4(t.to_vec(), [1, 3, h, w], &device),
        ))
    };
    assert!(
        direct(&sky, &sun) < 1e-3 * 255.0 * 255.0,
        "the clip hides the sun: {}",
        direct(&sky, &sun)
    );
    assert!(loss(&sky, &sun) > 1.0, "the energy loss sees it: {}", loss(&sky, &sun));
    // Hard maps: zero, tiny, huge and negative texels give a finite loss and gradient.
    let hard: Vec<f32> = (0..n).map(|i| [0.0, 1e-30, 3e38, -1.0][i % 4]).collect();
    for (p, t) in [(&hard, &truth), (&truth, &hard), (&vec![0.0; n], &vec![0.0; n])] {
        let p = tensor4(p.clone(), [1, 3, h, w], &device).require_grad();
        let l = light_energy_loss(p.clone(), tensor4(t.clone(), [1, 3, h, w], &device));
        assert!(value(l.clone()).is_finite());
        assert!(gradient(&p, l).iter().all(|v| v.is_finite()), "finite gradient");
    }
    // The gradient against central differences (f64 arithmetic on the f32 loss, step 1e-2 of
    // each texel's value) at a few texels of a map twice as bright as the truth.
    let pred: Vec<f32> = truth.iter().zip(noise(n, 11)).map(|(v, r)| v * (1.5 + r)).collect();
    let p = tensor4(pred.clone(), [1, 3, h, w], &device).require_grad();
    let g = gradient(
        &p,
        light_energy_loss(p.clone(), tensor4(truth.clone(), [1, 3, h, w], &device)),
    );
    for i in [0, 5, w + 3, h * w / 2, n - 1] {
        let d = pred[i] * 1e-2;
        let (mut up, mut down) = (pred.clone(), pred.clone());
        up[i] += d;
        down[i] -= d;
        let fd = (loss(&up, &truth) - loss(&down, &truth)) / (up[i] as f64 - down[i] as f64);
        assert!(
            (g[i] as f64 - fd).abs() <= 2e-2 * fd.abs().max(1e-6),
            "texel {i}: {} vs {fd}",
            g[i]
        );
    }
}

/// Deterministic values in [0, 1) (a 64-bit LCG: the tests need variety, not quality).
fn noise(n: usize, seed: u64) -> Vec<f32> {
    let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    (0..n)
        .map(|_| {
            x = x
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (x >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

/// The values of a tensor as f64.
fn values(t: burn::tensor::Tensor<4>) -> Vec<f64> {
    t.into_data()
        .try_to_vec::<f32>()
        .unwrap()
        .into_iter()
        .map(f64::from)
        .collect()
}

/// The structural loss is 1 − the evaluation's SSIM (`metrics`, itself checked against
/// scikit-image) on the fallback's tone map: same window, border rule and object-pixel mean,
/// per image, then averaged over the batch. At 9 × 14 the 11-tap window is cut at every border.
#[test]
fn the_ssim_loss_is_one_minus_the_metrics_ssim_per_image() {
    use super::loss::{display, exposure, ssim_loss};
    use crate::metrics::ssim_of_display;
    let device = Device::flex();
    let (b, h, w) = (2, 9, 14);
    let n = 3 * h * w;
    let truth: Vec<f32> = noise(b * n, 1).iter().map(|v| 2.0 * v).collect();
    let pred: Vec<f32> = truth
        .iter()
        .zip(noise(b * n, 2))
        .map(|(t, r)| t * (0.4 + 1.2 * r))
        .collect();
    // Image 0: all but a 3 × 4 corner; image 1: a disc.
    let mask: Vec<f32> = (0..b * h * w)
        .map(|i| {
            let (k, y, x) = (i / (h * w), (i / w) % h, i % w);
            let on = if k == 0 {
                !(y < 3 && x < 4)
            } else {
                (y as f32 - 4.0).powi(2) + (x as f32 - 7.0).powi(2) <= 16.0
            };
            f32::from(u8::from(on))
        })
        .collect();
    let (p, t, m) = (
        tensor4(pred, [b, 3, h, w], &device),
        tensor4(truth, [b, 3, h, w], &device),
        tensor4(mask.clone(), [b, 1, h, w], &device),
    );
    let loss = f64::from(
        ssim_loss(p.clone(), t.clone(), m.clone())
            .into_data()
            .try_to_vec::<f32>()
            .unwrap()[0],
    );
    let e = exposure(&t, &m);
    let (dp, dt) = (values(display(p, e.clone())), values(display(t, e)));
    let expected = (0..b)
        .map(|k| {
            1.0 - ssim_of_display(
                &dp[k * n..(k + 1) * n],
                &dt[k * n..(k + 1) * n],
                &mask[k * h * w..(k + 1) * h * w],
                h,
                w,
            )
        })
        .sum::<f64>()
        / b as f64;
    assert!(expected > 0.1, "the images differ in structure: {expected}");
    assert!((loss - expected).abs() < 1e-4, "loss {loss}, 1 − SSIM {expected}");
}

/// Identical images and an image without object pixels give 0 (the metric's "nothing wrong");
/// zero, tiny, huge and negative pixels and a 1 × 1 image give a finite loss and gradient.
#[test]
fn the_ssim_loss_is_zero_at_the_truth_and_finite_on_hard_images() {
    use super::loss::ssim_loss;
    let device = Device::flex().autodiff();
    let (h, w) = (6, 6);
    let truth: Vec<f32> = noise(3 * h * w, 3);
    let ones = vec![1.0f32; h * w];
    let at = |pred: Vec<f32>, mask: &[f32], size: (usize, usize)| {
        let (h, w) = size;
        let p = tensor4(pred, [1, 3, h, w], &device).require_grad();
        let t = tensor4(truth[..3 * h * w].to_vec(), [1, 3, h, w], &device);
        let l = ssim_loss(p.clone(), t, tensor4(mask.to_vec(), [1, 1, h, w], &device));
        let v = l.clone().into_data().try_to_vec::<f32>().unwrap()[0];
        (v, gradient(&p, l))
    };
    let (same, _) = at(truth.clone(), &ones, (h, w));
    assert!(same.abs() < 1e-5, "identical images: {same}");
    let (empty, g) = at(noise(3 * h * w, 4), &vec![0.0; h * w], (h, w));
    assert_eq!(empty, 0.0, "no object pixels");
    assert!(g.iter().all(|v| *v == 0.0), "no object pixels, no gradient");
    let hard: Vec<f32> = (0..3 * h * w).map(|i| [0.0, 1e-30, 3e38, -5.0][i % 4]).collect();
    let (l, g) = at(hard, &ones, (h, w));
    assert!(l.is_finite() && (0.0..=2.0).contains(&l), "hard pixels: {l}");
    assert!(g.iter().all(|v| v.is_finite()), "hard pixels: finite gradient");
    let (l, g) = at(vec![0.3, 0.0, 7.0], &[1.0], (1, 1));
    assert!(l.is_finite() && g.iter().all(|v| v.is_finite()), "1 × 1: {l}, {g:?}");
}

/// Descending the structural loss restores structure the metric sees: from a copy of the truth
/// with its detail flattened (each pixel replaced by its row's mean), 40 normalised gradient
/// steps raise the evaluation's SSIM by more than 0.1.
#[test]
fn descending_the_ssim_loss_raises_the_metrics_ssim() {
    use super::loss::ssim_loss;
    use crate::metrics::ssim;
    let device = Device::flex().autodiff();
    let (h, w) = (16, 16);
    let truth: Vec<f32> = noise(3 * h * w, 5).iter().map(|v| 0.05 + 0.9 * v).collect();
    let mask: Vec<f32> = (0..h * w).map(|i| f32::from(u8::from((i / w) % 15 != 0))).collect();
    let mut pred: Vec<f32> = (0..3 * h * w)
        .map(|i| truth[i - i % w..i - i % w + w].iter().sum::<f32>() / w as f32)
        .collect();
    let before = ssim(&pred, &truth, &mask, h, w);
    for _ in 0..40 {
        let p = tensor4(pred.clone(), [1, 3, h, w], &device).require_grad();
        let l = ssim_loss(
            p.clone(),
            tensor4(truth.clone(), [1, 3, h, w], &device),
            tensor4(mask.clone(), [1, 1, h, w], &device),
        );
        let g = gradient(&p, l);
        let scale = g.iter().fold(0.0f32, |a, v| a.max(v.abs())).max(1e-20);
        for (x, gi) in pred.iter_mut().zip(&g) {
            *x -= 0.02 * gi / scale;
        }
    }
    let after = ssim(&pred, &truth, &mask, h, w);
    assert!(after > before + 0.1, "SSIM {before} → {after}");
}

/// With a weight on the direct illumination loss, pretraining also trains L' and reports it;
/// without (the paper), the term is 0.
#[test]
fn pretraining_with_the_direct_illumination_loss_lowers_it() {
    for w_l in [0.0, 1.0] {
        let w = LossWeights {
            illumination: w_l,
            ..LossWeights::default()
        };
        let seen: Vec<f64> = run_with(StepKind::PRETRAIN, 8, 5, &w)
            .iter()
            .map(|l| l.illumination)
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
        let w = LossWeights {
            normal: 0.0,
            material: 0.0,
            perceptual: 0.0,
            illumination: 0.0,
            ssim: 0.0,
            light_energy: w_e,
        };
        let seen = run_with(StepKind::PRETRAIN, 8, 5, &w);
        let energy: Vec<f64> = seen.iter().map(|l| l.light_energy).collect();
        if w_e == 0.0 {
            assert!(seen.iter().all(|l| l.light_energy == 0.0 && l.total == 0.0), "{seen:?}");
        } else {
            assert!(energy[0] > 0.0 && energy.windows(2).all(|p| p[1] < p[0]), "{energy:?}");
            assert!(seen.iter().all(|l| l.total == w_e * l.light_energy), "{seen:?}");
        }
    }
}

/// One joint step of a fresh seeded network (no dropout) with weights `w`: the step's losses and
/// how far (largest absolute change on the fixed batch) it moved n' and L'.
fn one_joint_step(seed: u64, w: &LossWeights, kind: StepKind) -> (super::step::Losses, f32, f32) {
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
        let w = LossWeights {
            normal: 0.0,
            material: 0.0,
            ..LossWeights::default()
        };
        let kind = StepKind {
            kind: StageKind::Joint,
            render_with: RenderWith {
                normals,
                ..RenderWith::default()
            },
        };
        let (l, n_moved, l_moved) = one_joint_step(7, &w, kind);
        assert!(l.perceptual > 0.0 && l.total.is_finite(), "{l:?}");
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
        let w = LossWeights {
            normal: 0.0,
            material: 0.0,
            perceptual: 0.0,
            illumination: 0.0,
            ssim: w_s,
            light_energy: 0.0,
        };
        let (l, n_moved, l_moved) = one_joint_step(11, &w, StepKind::JOINT);
        if w_s > 0.0 {
            assert!(l.ssim > 0.0 && l.ssim <= 4.0 && l.total == w_s * l.ssim, "{l:?}");
            assert!(n_moved > 1e-6 && l_moved > 1e-6, "n' and L' learn");
        } else {
            assert!(l.ssim == 0.0 && l.total == 0.0, "{l:?}");
            assert!(n_moved == 0.0 && l_moved == 0.0, "nothing to learn from");
        }
    }
}

/// A device a manifest names is checked before anything runs, and a refusal says why.
#[test]
fn device_names_are_checked_with_their_reason() {
    use super::manifest::check_device_name;
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
    let Some(gpu) = crate::render::gpu::tests::device() else {
        return;
    };
    let gpu = gpu.autodiff();
    let w = LossWeights {
        illumination: 10.0,
        ssim: 100.0,
        ..LossWeights::default()
    };
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
                ("normal", c.normal, g.normal),
                ("material", c.material, g.material),
                ("perceptual", c.perceptual, g.perceptual),
                ("illumination", c.illumination, g.illumination),
                ("ssim", c.ssim, g.ssim),
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

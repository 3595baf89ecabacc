//! The terms on their own: the fallback's tone map and perceptual loss, the direct,
//! energy and direction losses on L', the structural loss, against the metrics, closed forms and
//! central differences, on hard inputs.

use burn::tensor::Device;

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
    use super::display;
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
    use super::perceptual::perceptual_fallback;
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
    use super::illumination::illumination_loss;
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
    use super::illumination::illumination_loss;
    use super::light_energy::{LIGHT_ENERGY_FLOOR, light_energy_loss};
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
    use super::ssim::ssim_loss;
    use super::{display, exposure};
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
    use super::ssim::ssim_loss;
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
    use super::ssim::ssim_loss;
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

/// The optional loss on where L' comes from, against closed forms: a clamped-cosine light about
/// a has d = 2a/3 (∫ cos·ω dΩ = 2πa/3 over the hemisphere, ∫ cos dΩ = π); a single texel's d
/// is its direction; light alike from every side has d = 0, so the mean over a light's rotations
/// costs |d|²; blind to either map's scale; finite on hard maps; its gradient equal to central
/// differences.
#[test]
fn the_light_direction_loss_matches_its_closed_forms() {
    use super::light_direction::{light_direction, light_direction_loss};
    use matedit_physics::envmap::texel_direction;
    let device = Device::flex().autodiff();
    let (h, w) = (32, 64);
    let n = 3 * h * w;
    let value = |t: burn::tensor::Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0] as f64;
    let map = |f: &dyn Fn(usize, usize) -> f32| -> Vec<f32> { (0..n).map(|i| f((i / w) % h, i % w)).collect() };
    let direction = |m: &[f32]| -> Vec<f32> {
        light_direction(tensor4(m.to_vec(), [1, 3, h, w], &device))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap()
    };
    let loss = |p: &[f32], t: &[f32]| {
        value(light_direction_loss(
            tensor4(p.to_vec(), [1, 3, h, w], &device),
            tensor4(t.to_vec(), [1, 3, h, w], &device),
        ))
    };
    let a = glam::DVec3::new(0.3, 0.8, -0.52).normalize();
    let cosine = map(&|row, col| texel_direction(col, row, w, h).dot(a).max(0.0) as f32);
    let d = direction(&cosine);
    for (got, want) in d.iter().zip(a.to_array().map(|v| 2.0 * v / 3.0)) {
        assert!((*got as f64 - want).abs() < 5e-3, "{d:?} vs 2a/3 = {:?}", a * 2.0 / 3.0);
    }
    let (row, col) = (9, 40);
    let point = map(&|r, c| if (r, c) == (row, col) { 1e4 } else { 0.0 });
    let t = texel_direction(col, row, w, h).to_array();
    for (got, want) in direction(&point).iter().zip(t) {
        assert!((*got as f64 - want).abs() < 1e-5);
    }
    let uniform = vec![0.6; n];
    assert!(
        direction(&uniform).iter().all(|v| v.abs() < 1e-5),
        "{:?}",
        direction(&uniform)
    );
    assert!(
        (loss(&uniform, &point) - 1.0).abs() < 1e-4,
        "{}",
        loss(&uniform, &point)
    );
    assert_eq!(loss(&cosine, &cosine), 0.0);
    // The cosine light turned half way about +y (columns shifted by w/2: x and z negated):
    // |d − Rd|² = (4/9)·4(a_x² + a_z²), at any scale of either map.
    let turned = |k: f32| map(&|r, c| k * cosine[r * w + (c + w / 2) % w]);
    let want = 16.0 / 9.0 * (a.x * a.x + a.z * a.z);
    for k in [1e-3f32, 1.0, 1e3] {
        let got = loss(&turned(k), &cosine);
        assert!((got - want).abs() < 2e-2 * want, "k {k}: {got} vs {want}");
        let big: Vec<f32> = cosine.iter().map(|v| v * 1e4).collect();
        assert!((loss(&turned(k), &big) - got).abs() < 1e-4 * got);
    }
    // Hard maps: zero, tiny, huge and negative texels give a finite loss and gradient.
    let hard: Vec<f32> = (0..n).map(|i| [0.0, 1e-30, 3e38, -1.0][i % 4]).collect();
    for (p, t) in [(&hard, &cosine), (&cosine, &hard), (&vec![0.0; n], &vec![0.0; n])] {
        let p = tensor4(p.clone(), [1, 3, h, w], &device).require_grad();
        let l = light_direction_loss(p.clone(), tensor4(t.clone(), [1, 3, h, w], &device));
        assert!(value(l.clone()).is_finite());
        assert!(gradient(&p, l).iter().all(|v| v.is_finite()), "finite gradient");
    }
    // The gradient against central differences at a few texels of a noisy 4 × 8 map (a texel of
    // a larger map moves the f32 loss by less than its rounding).
    let (h, w) = (4, 8);
    let n = 3 * h * w;
    let small = |p: &[f32], t: &[f32]| {
        value(light_direction_loss(
            tensor4(p.to_vec(), [1, 3, h, w], &device),
            tensor4(t.to_vec(), [1, 3, h, w], &device),
        ))
    };
    let truth: Vec<f32> = (0..n).map(|i| if i % (h * w) == 9 { 5.0 } else { 0.2 }).collect();
    let pred: Vec<f32> = noise(n, 5).iter().map(|r| 0.1 + r).collect();
    let p = tensor4(pred.clone(), [1, 3, h, w], &device).require_grad();
    let g = gradient(
        &p,
        light_direction_loss(p.clone(), tensor4(truth.clone(), [1, 3, h, w], &device)),
    );
    for i in [3, 9, h * w + 13, n - 2] {
        let step = pred[i] * 1e-2;
        let (mut up, mut down) = (pred.clone(), pred.clone());
        up[i] += step;
        down[i] -= step;
        let fd = (small(&up, &truth) - small(&down, &truth)) / (up[i] as f64 - down[i] as f64);
        assert!(
            (g[i] as f64 - fd).abs() <= 2e-2 * fd.abs().max(1e-5),
            "texel {i}: {} vs {fd}",
            g[i]
        );
    }
}

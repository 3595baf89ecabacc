//! The GPU layer against the fused CPU layer (an independent implementation: host SIMD code with
//! its own arithmetic), on the hard cases the CPU layer is tested on, and its backward inside
//! Burn's autodiff.
//!
//! They run on whatever device wgpu opens (lavapipe in CI). Without one they say so and pass,
//! unless `MATEDIT_REQUIRE_GPU=1` (set by `.ci/run`), where a missing device fails.

use super::super::tests::{Lcg, Scene, sphere, upstream};
use super::super::{LayerInput, RenderingLayer, material};
use super::*;
use burn::tensor::Tensor;

pub(crate) fn device() -> Option<Device> {
    match crate::device::wgpu_device() {
        Ok(d) => Some(d),
        Err(e) if std::env::var("MATEDIT_REQUIRE_GPU").as_deref() == Ok("1") => {
            panic!("MATEDIT_REQUIRE_GPU=1 but {e}")
        }
        Err(e) => {
            eprintln!("skipped: {e}");
            None
        }
    }
}

/// Scenes stacked into one batch (same size, regions and environment height).
struct Stack {
    batch: usize,
    size: usize,
    regions: usize,
    env_height: usize,
    normals: Vec<f32>,
    region_map: Vec<u8>,
    materials: Vec<f32>,
    env: Vec<f32>,
}

impl Stack {
    fn of(scenes: &[Scene]) -> Self {
        let s0 = &scenes[0];
        let cat = |f: &dyn Fn(&Scene) -> Vec<f32>| scenes.iter().flat_map(f).collect::<Vec<f32>>();
        Self {
            batch: scenes.len(),
            size: s0.size,
            regions: s0.regions,
            env_height: s0.env_height,
            normals: cat(&|s| s.normals.clone()),
            region_map: scenes.iter().flat_map(|s| s.region_map.clone()).collect(),
            materials: cat(&|s| s.materials.clone()),
            env: cat(&|s| s.env.clone()),
        }
    }

    fn cpu(&self) -> LayerInput<'_> {
        LayerInput {
            batch: self.batch,
            size: (self.size, self.size),
            regions: self.regions,
            normals: &self.normals,
            region_map: &self.region_map,
            materials: &self.materials,
            env: &self.env,
        }
    }

    fn tensors(&self, device: &Device) -> (Tensor<4>, Tensor<3>, Tensor<4>) {
        let (b, s, he) = (self.batch, self.size, self.env_height);
        (
            Tensor::from_data(TensorData::new(self.normals.clone(), [b, 3, s, s]), device),
            Tensor::from_data(
                TensorData::new(self.materials.clone(), [b, self.regions, PARAMS]),
                device,
            ),
            Tensor::from_data(TensorData::new(self.env.clone(), [b, 3, he, 2 * he]), device),
        )
    }
}

fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

/// Every value within 1e-4 of the reference's, relative to the value, with a floor of 1e-6 of the
/// largest (where a sum of terms of both signs cancels to nearly 0).
fn assert_close(what: &str, got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let mut worst = (0.0f64, 0usize);
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(g.is_finite(), "{what}[{i}] = {g} is not finite");
        let err = (*g as f64 - *w as f64).abs() / (w.abs() as f64 + 1e-2 * scale as f64).max(1e-30);
        if err > worst.0 {
            worst = (err, i);
        }
    }
    let i = worst.1;
    eprintln!(
        "{what}: worst relative difference {:.2e} at {i} ({} vs {})",
        worst.0, got[i], want[i]
    );
    assert!(
        worst.0 <= 1e-4,
        "{what}[{i}]: GPU {} vs CPU {} (relative {:.2e})",
        got[i],
        want[i],
        worst.0
    );
}

/// Renders and differentiates `stack` with both layers and compares everything.
fn agree(stack: &Stack, grad: &[f32], device: &Device) {
    let cpu = RenderingLayer::new(stack.env_height);
    let want = cpu.forward(&stack.cpu()).expect("CPU forward");
    let want_g = cpu.backward(&stack.cpu(), grad).expect("CPU backward");
    let gpu = DeviceLayer::new(stack.env_height, device);
    let (n, m, l) = stack.tensors(device);
    let got = gpu
        .render(n.clone(), &stack.region_map, m.clone(), l.clone())
        .expect("GPU forward");
    assert_close("image", &host(got), &want);
    let s = stack.size;
    let g = Tensor::<4>::from_data(TensorData::new(grad.to_vec(), [stack.batch, 3, s, s]), device);
    let (gn, gm, gl) = gpu.vjp(n, &stack.region_map, m, l, g);
    assert_close("∂l/∂n", &host(gn), &want_g.normals);
    assert_close("∂l/∂m", &host(gm), &want_g.materials);
    assert_close("∂l/∂L", &host(gl), &want_g.env);
}

#[test]
fn gpu_layer_matches_the_cpu_layer_on_spheres_with_sharp_lobes_and_two_regions() {
    let Some(device) = device() else { return };
    let stack = Stack::of(&[sphere(12, 2, 8, true, 3), sphere(12, 2, 8, false, 4)]);
    let mut rng = Lcg(9);
    let grad: Vec<f32> = (0..stack.normals.len()).map(|_| rng.next() - 0.3).collect();
    agree(&stack, &grad, &device);
}

#[test]
fn gpu_layer_matches_the_cpu_layer_at_the_paper_environment_resolution() {
    let Some(device) = device() else { return };
    let s = sphere(10, 1, 64, true, 5);
    let grad = upstream(&s, 6);
    agree(&Stack::of(&[s]), &grad, &device);
}

#[test]
fn gpu_layer_matches_the_cpu_layer_on_hard_inputs() {
    let Some(device) = device() else { return };
    let mut s = sphere(8, 2, 4, true, 1);
    let p = 64;
    // Zero, NaN, infinite, back-facing, grazing and nearly grazing normals on object pixels.
    let hard = [
        [0.0, 0.0, 0.0],
        [f32::NAN, 0.0, 1.0],
        [f32::INFINITY, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [1.0, 0.0, 1e-4],
        [0.0, 1.0, 1e-7],
        [0.6, 0.8, 1e-3],
    ];
    for (k, n) in hard.iter().enumerate() {
        let px = 27 + k;
        s.region_map[px] = 1 + (k % 2) as u8;
        for (a, v) in n.iter().enumerate() {
            s.normals[a * p + px] = *v;
        }
    }
    // Extreme lobes (the largest κ with the sharpest and the flattest γ), NaN and out-of-range
    // parameters, in both regions.
    for q in 0..material::MEMBERS {
        for j in 0..6 {
            s.materials[material::knot_index(q, false, j)] = if q % 2 == 0 { 1.0 } else { -1.0 };
            s.materials[material::knot_index(q, true, j)] = if j % 2 == 0 { 1.0 } else { -1.0 };
        }
    }
    s.materials[3] = f32::NAN;
    s.materials[50] = 7.0;
    s.materials[PARAMS + 7] = f32::NEG_INFINITY;
    s.materials[PARAMS + 8] = -1.0;
    // Non-finite, negative, huge and black radiance.
    s.env[0] = f32::NAN;
    s.env[1] = f32::INFINITY;
    s.env[2] = -5.0;
    s.env[3] = 1e30;
    for v in &mut s.env[10..20] {
        *v = 0.0;
    }
    let mut grad = upstream(&s, 2);
    grad[5] = f32::NAN;
    grad[6] = f32::INFINITY;
    agree(&Stack::of(&[s]), &grad, &device);
}

#[test]
fn gpu_layer_renders_an_all_black_environment_and_an_empty_mask_as_zero() {
    let Some(device) = device() else { return };
    let mut s = sphere(8, 1, 4, false, 2);
    s.env.iter_mut().for_each(|v| *v = 0.0);
    let mut empty = sphere(8, 1, 4, false, 3);
    empty.region_map.iter_mut().for_each(|r| *r = 0);
    let stack = Stack::of(&[s, empty]);
    let gpu = DeviceLayer::new(4, &device);
    let (n, m, l) = stack.tensors(&device);
    let img = host(gpu.render(n, &stack.region_map, m, l).unwrap());
    assert!(img.iter().all(|v| *v == 0.0));
}

#[test]
fn gpu_layer_refuses_bad_shapes_and_regions() {
    let Some(device) = device() else { return };
    let s = Stack::of(&[sphere(8, 1, 4, false, 2)]);
    let (n, m, l) = s.tensors(&device);
    let gpu = DeviceLayer::new(4, &device);
    let mut map = s.region_map.clone();
    map[20] = 2;
    let e = gpu.render(n.clone(), &map, m.clone(), l.clone()).unwrap_err();
    assert!(matches!(e, RenderError::Region { region: 2, .. }), "{e}");
    let e = gpu.render(n.clone(), &map[1..], m.clone(), l.clone()).unwrap_err();
    assert!(matches!(e, RenderError::Shape { name: "region map", .. }), "{e}");
    let e = DeviceLayer::new(8, &device).render(n, &s.region_map, m, l).unwrap_err();
    assert!(matches!(e, RenderError::EnvHeight { layer: 8, got: 4 }), "{e}");
}

/// Under autodiff the layer's backward is the CPU layer's VJP: l = Σ W ⊙ R(n, m, L) gives
/// ∂l/∂n, ∂l/∂m, ∂l/∂L = the VJP of W, through operations upstream of the layer too.
#[test]
fn autodiff_through_the_gpu_layer_gives_the_cpu_layers_gradients() {
    let Some(device) = device() else { return };
    let stack = Stack::of(&[sphere(10, 2, 8, true, 7)]);
    let mut rng = Lcg(11);
    let w: Vec<f32> = (0..stack.normals.len()).map(|_| rng.next() - 0.5).collect();
    let want = RenderingLayer::new(8).backward(&stack.cpu(), &w).unwrap();
    let ad = device.clone().autodiff();
    let (n, m, l) = stack.tensors(&ad);
    let (n, m, l) = (n.require_grad(), m.require_grad(), l.require_grad());
    // L reaches the layer through an operation (L = 2·(L/2)), so its gradient flows on upstream.
    let image = DeviceLayer::new(8, &device)
        .render(n.clone(), &stack.region_map, m.clone(), (l.clone() * 0.5) * 2.0)
        .unwrap();
    let s = stack.size;
    let wt = Tensor::<4>::from_data(TensorData::new(w, [1, 3, s, s]), &ad);
    let grads = (image * wt).sum().backward();
    assert_close("autodiff ∂l/∂n", &host(n.grad(&grads).unwrap()), &want.normals);
    assert_close("autodiff ∂l/∂m", &host(m.grad(&grads).unwrap()), &want.materials);
    assert_close("autodiff ∂l/∂L", &host(l.grad(&grads).unwrap()), &want.env);
}

/// A detached input receives nothing, and the others their full gradient.
#[test]
fn a_detached_input_gets_no_gradient_from_the_gpu_layer() {
    let Some(device) = device() else { return };
    let stack = Stack::of(&[sphere(8, 1, 4, false, 8)]);
    let ad = device.clone().autodiff();
    let (n, m, l) = stack.tensors(&ad);
    let (n, m) = (n.require_grad(), m.require_grad());
    let image = DeviceLayer::new(4, &device)
        .render(n.clone().detach(), &stack.region_map, m.clone(), l)
        .unwrap();
    let grads = image.sum().backward();
    assert!(n.grad(&grads).is_none(), "detached normals got a gradient");
    assert!(host(m.grad(&grads).unwrap()).iter().any(|v| *v != 0.0));
}

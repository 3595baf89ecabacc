//! `trainer bench`: the rendering layer's forward + backward time and peak memory (fused against
//! the tensor reference on the CPU; the GPU kernels on a GPU device), and training images/s per
//! network configuration and device.

use crate::alloc::PeakAlloc;
use crate::model::Widths;
use crate::model::network::NetConfig;
use crate::render::{Batch, RenderingLayer, reference};
use crate::train::perceptual::Perceptual;
use crate::train::step::{LossWeights, StepContext, StepKind, train_step};
use crate::train::synthetic::sphere_batch;
use anyhow::Result;
use burn::optim::AdamConfig;
use burn::tensor::Device;
use std::time::Instant;

/// One measured operation.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Measure {
    /// What was measured.
    pub name: String,
    /// Median wall time, seconds.
    pub seconds: f64,
    /// Peak heap growth during the operation, bytes (0 when no counting allocator is installed).
    pub peak_bytes: usize,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn measure(name: &str, runs: usize, alloc: Option<&PeakAlloc>, mut f: impl FnMut()) -> Measure {
    let mut times = Vec::new();
    let mut peak = 0;
    for _ in 0..runs.max(1) {
        let base = alloc.map_or(0, |a| {
            a.reset_peak();
            a.live()
        });
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64());
        peak = peak.max(alloc.map_or(0, |a| a.peak().saturating_sub(base)));
    }
    Measure {
        name: name.to_string(),
        seconds: median(times),
        peak_bytes: peak,
    }
}

/// Forward + backward of the fused layer and, with `with_reference`, of the tensor reference
/// (once: it is slow) on `batch` spheres at `size`² with a `2·env_height × env_height`
/// environment.
pub fn rendering_layer(
    batch: usize,
    size: usize,
    env_height: usize,
    runs: usize,
    with_reference: bool,
    alloc: Option<&PeakAlloc>,
) -> Result<(Measure, Option<Measure>)> {
    let layer = RenderingLayer::new(env_height);
    let hb = sphere_batch(batch, size, env_height, 1, &layer);
    let b = Batch {
        batch,
        size: (size, size),
        regions: 1,
        normals: &hb.normals,
        region_map: &hb.region_map,
        materials: &hb.materials,
        env: &hb.env,
    };
    let upstream: Vec<f32> = hb.input.iter().map(|v| 0.5 - v.min(1.0)).collect();
    let fused = measure("fused", runs, alloc, || {
        let out = layer.forward(&b).map(|o| o.len()).unwrap_or(0);
        let g = layer.backward(&b, &upstream).map(|g| g.normals.len()).unwrap_or(0);
        std::hint::black_box((out, g));
    });
    if !with_reference {
        return Ok((fused, None));
    }
    let device = Device::flex().autodiff();
    let reference = measure("tensor reference", 1, alloc, || {
        let r = reference::forward_backward(&layer, &b, &upstream, &device).map(|(o, _)| o.len());
        std::hint::black_box(r.ok());
    });
    Ok((fused, Some(reference)))
}

/// Forward + backward of the rendering layer's GPU kernels on `device` (a CubeCL device), like
/// [`rendering_layer`]: each run waits for the device. The peak is the device memory the pool
/// has reserved (its high-water mark: pools keep pages for reuse).
#[cfg(feature = "wgpu")]
pub fn rendering_layer_on_device(
    device: &Device,
    batch: usize,
    size: usize,
    env_height: usize,
    runs: usize,
) -> Result<Measure> {
    use burn::tensor::{Tensor, TensorData};
    let host_layer = RenderingLayer::new(env_height);
    let hb = sphere_batch(batch, size, env_height, 1, &host_layer);
    let layer = crate::render::gpu::DeviceLayer::new(env_height, device);
    let (p, t) = (size * size, 2 * env_height * env_height);
    let n = Tensor::<4>::from_data(TensorData::new(hb.normals.clone(), [batch, 3, size, size]), device);
    let m = Tensor::<3>::from_data(
        TensorData::new(hb.materials.clone(), [batch, 1, hb.materials.len() / batch]),
        device,
    );
    let e = Tensor::<4>::from_data(
        TensorData::new(hb.env.clone(), [batch, 3, env_height, 2 * env_height]),
        device,
    );
    let up: Vec<f32> = hb.input.iter().map(|v| 0.5 - v.min(1.0)).collect();
    let g = Tensor::<4>::from_data(TensorData::new(up, [batch, 3, size, size]), device);
    debug_assert_eq!(hb.env.len(), batch * 3 * t);
    debug_assert_eq!(hb.normals.len(), batch * 3 * p);
    let mut peak = 0u64;
    let mut failure = None;
    let mut run = || -> Result<()> {
        let image = layer.render(n.clone(), &hb.region_map, m.clone(), e.clone())?;
        let (gn, gm, ge) = layer.vjp(n.clone(), &hb.region_map, m.clone(), e.clone(), g.clone());
        device.sync().map_err(|e| anyhow::anyhow!("the device failed: {e:?}"))?;
        if let Some(u) = device.memory_pool_usage() {
            peak = peak.max(u.bytes_reserved);
        }
        std::hint::black_box((image, gn, gm, ge));
        Ok(())
    };
    // One warm-up run compiles the kernels.
    run()?;
    let mut m = measure("GPU kernels", runs, None, || {
        if let Err(e) = run() {
            failure = Some(e);
        }
    });
    if let Some(e) = failure {
        return Err(e);
    }
    m.peak_bytes = peak as usize;
    Ok(m)
}

/// Training images/s of a joint step for a network configuration on `device` (with autodiff).
pub fn training(
    device: &Device,
    name: &str,
    widths: Widths,
    size: usize,
    batch: usize,
    steps: usize,
) -> Result<Measure> {
    let device = device.clone();
    device.seed(1);
    let layer = RenderingLayer::new(64);
    let net_cfg = NetConfig::new(size, widths);
    net_cfg
        .validate()
        .map_err(|e| anyhow::anyhow!("training configuration {name}:{size}:{batch}: {e}"))?;
    if batch == 0 {
        anyhow::bail!("training configuration {name}:{size}:{batch}: the batch size must be at least 1");
    }
    let mut net = net_cfg.init(&device);
    let mut optim = AdamConfig::new().init();
    let hb = sphere_batch(batch, size, 64, 2, &layer);
    let w = LossWeights::default();
    let ctx = StepContext {
        layer: &layer,
        weights: &w,
        perceptual: &Perceptual::Fallback,
        device: &device,
    };
    // One warm-up step (allocations, kernel selection), then the measured ones.
    let (n, _) = train_step(net, &mut optim, 1e-4, &hb, StepKind::JOINT, &ctx)?;
    net = n;
    let mut times = Vec::new();
    let mut peak = 0u64;
    for _ in 0..steps.max(1) {
        let t = Instant::now();
        let (n, _) = train_step(net, &mut optim, 1e-4, &hb, StepKind::JOINT, &ctx)?;
        net = n;
        // The step reads its losses back, so the device has finished its work here.
        times.push(t.elapsed().as_secs_f64());
        if let Some(u) = device.memory_pool_usage() {
            peak = peak.max(u.bytes_reserved);
        }
    }
    Ok(Measure {
        name: format!("{name} {size}² batch {batch}"),
        seconds: median(times),
        peak_bytes: peak as usize,
    })
}

/// What `trainer bench` measures.
pub struct Options {
    /// Images per batch of the rendering layer.
    pub batch: usize,
    /// Image side of the rendering layer.
    pub size: usize,
    /// Timed runs (the median is reported).
    pub runs: usize,
    /// Also time the tensor reference of the layer (CPU device).
    pub reference: bool,
    /// Training configurations, `NAME:SIZE:BATCH` (NAME: cpu-small or paper).
    pub train: Vec<String>,
}

/// `trainer bench`'s report on device `device` (a training manifest's device name): the
/// rendering layer (the fused CPU layer against the tensor reference on the CPU device, the GPU
/// kernels on a GPU device), then training images/s per configuration. `alloc` measures peak
/// host memory where the binary installed it.
pub fn report(device: &str, opts: &Options, alloc: Option<&PeakAlloc>) -> Result<String> {
    use std::fmt::Write;
    let dev = crate::train::run::device_for(device)?;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "# trainer bench (device {device}: {dev:?}; {} threads)",
        rayon::current_num_threads()
    );
    let (batch, size, runs) = (opts.batch, opts.size, opts.runs);
    let _ = writeln!(
        out,
        "rendering layer, batch {batch} at {size}², 64x128 environment, forward+backward:"
    );
    if let Some(line) = gpu_layer_line(&dev, batch, size, runs)? {
        out.push_str(&line);
    } else {
        let (fused, reference) = rendering_layer(batch, size, 64, runs, opts.reference, alloc)?;
        let _ = writeln!(
            out,
            "  fused             {:9.3} s  peak {:9.1} MB",
            fused.seconds,
            fused.peak_bytes as f64 / 1e6
        );
        if let Some(r) = reference {
            let _ = writeln!(
                out,
                "  tensor reference  {:9.3} s  peak {:9.1} MB",
                r.seconds,
                r.peak_bytes as f64 / 1e6
            );
            let _ = writeln!(
                out,
                "  ratio             {:9.1}x faster, {:.1}x less peak memory",
                r.seconds / fused.seconds,
                r.peak_bytes as f64 / fused.peak_bytes.max(1) as f64
            );
        }
    }
    for spec in &opts.train {
        let parts: Vec<&str> = spec.split(':').collect();
        let [name, s, b] = parts.as_slice() else {
            anyhow::bail!("--train {spec}: expected NAME:SIZE:BATCH");
        };
        let Some(widths) = Widths::preset(name) else {
            anyhow::bail!(
                "--train {spec}: unknown configuration {name} ({})",
                Widths::preset_names()
            );
        };
        let (s, b): (usize, usize) = (s.parse()?, b.parse()?);
        let m = training(&dev, name, widths, s, b, 3)?;
        let memory = if m.peak_bytes > 0 {
            format!(", device memory reserved {:.1} MB", m.peak_bytes as f64 / 1e6)
        } else {
            String::new()
        };
        let _ = writeln!(
            out,
            "training (joint step) {:24} {:7.2} images/s ({:.3} s/step{memory})",
            m.name,
            b as f64 / m.seconds,
            m.seconds
        );
    }
    Ok(out)
}

/// The GPU kernels' line of the report, on a GPU device.
#[cfg(feature = "wgpu")]
fn gpu_layer_line(dev: &Device, batch: usize, size: usize, runs: usize) -> Result<Option<String>> {
    if crate::render::on_device(dev, 64).is_none() {
        return Ok(None);
    }
    let m = rendering_layer_on_device(dev, batch, size, 64, runs)?;
    Ok(Some(format!(
        "  GPU kernels       {:9.3} s  device memory reserved {:9.1} MB\n",
        m.seconds,
        m.peak_bytes as f64 / 1e6
    )))
}

/// Without the `wgpu` feature there are no GPU kernels.
#[cfg(not(feature = "wgpu"))]
fn gpu_layer_line(_dev: &Device, _batch: usize, _size: usize, _runs: usize) -> Result<Option<String>> {
    Ok(None)
}

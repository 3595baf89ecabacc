//! `trainer bench`: the rendering layer's forward + backward time and peak memory (fused against
//! the tensor reference on the CPU; the GPU kernels on a GPU device), and training images/s per
//! network configuration and device.
//!
//! A training figure must time the work training does. The fused layer skips back-facing
//! normals, and a freshly initialised network predicts mostly back-facing ones, so a joint step
//! of an untrained network renders a fraction of the pixels a training run renders (64² spheres,
//! 2026-11-26: 17.4 images/s untrained, 1.9 warmed up; docs/PERFORMANCE.md). Every training
//! figure therefore comes
//! from a network whose normals face the camera as a trained one's do: warmed up by pretraining
//! steps (L2 on the normals, as the first stage of every manifest) until [`SHADED`] of the
//! object's pixels are shaded, or loaded from a checkpoint. The report says what was timed:
//! object pixels per image, the fraction shaded, the loss terms on.

use crate::alloc::PeakAlloc;
use crate::data;
use crate::model::Widths;
use crate::model::network::{Net, NetConfig};
use crate::rendering_layer::op::host;
use crate::rendering_layer::{LayerInput, RenderingLayer, reference};
use crate::train::loss::Perceptual;
use crate::train::loss::{LossWeights, NORMAL};
use crate::train::manifest::TrainPlan;
use crate::train::stage_kind::StageKind;
use crate::train::step::{StepContext, StepKind, train_step};
use crate::train::synthetic::sphere_batch;
use anyhow::Result;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::Device;
use matedit_contract::manifest::Named;
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
    let b = LayerInput {
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
    let layer = crate::rendering_layer::gpu::DeviceLayer::new(env_height, device);
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

/// The fraction of object pixels a warmed-up network's normals must shade (face the camera)
/// before its steps are timed; the quickstart's `light` checkpoint shades 99.9 % of its
/// training batches' object pixels.
pub const SHADED: f64 = 0.9;
/// Pretraining steps the warm-up may take before it gives up (and the report says so).
const MAX_WARMUP: usize = 400;

/// What the timed steps worked on.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Workload {
    /// Mean object pixels per image.
    pub object_pixels: f64,
    /// Fraction of those whose predicted normal faces the camera (the pixels the layer shades).
    pub shaded: f64,
    /// Pretraining steps taken to reach it (`None`: loaded from a checkpoint).
    pub warmup_steps: Option<usize>,
}

/// Object pixels per image and the fraction of them `net`'s normals shade on `hb`.
pub fn shaded(net: &Net, hb: &data::Batch, device: &Device) -> (f64, f64) {
    let tb = hb.to_device(device);
    let n = host(&net.predict(&tb.input, &tb.mask, &tb.region_masks, false).normals);
    let p = hb.size * hb.size;
    let (mut object, mut front) = (0usize, 0usize);
    for i in 0..hb.batch {
        for k in 0..p {
            if hb.mask[i * p + k] > 0.0 {
                object += 1;
                let z = n[(i * 3 + 2) * p + k];
                if z.is_finite() && z > 0.0 {
                    front += 1;
                }
            }
        }
    }
    (
        object as f64 / hb.batch.max(1) as f64,
        front as f64 / object.max(1) as f64,
    )
}

/// Pretraining steps on `next()`'s batches until `net` shades [`SHADED`] of the object's pixels
/// (at most [`MAX_WARMUP`]), with an L2 loss on the normals alone (whatever the manifest
/// weighs); returns the network, the steps taken, and the object pixels per image and fraction
/// shaded on the last batch checked.
fn warm_up(
    mut net: Net,
    ctx: &StepContext,
    mut next: impl FnMut() -> Result<data::Batch>,
) -> Result<(Net, usize, (f64, f64))> {
    let normals_only = LossWeights::NONE.with(&NORMAL, NORMAL.default_weight);
    let warm_ctx = StepContext {
        weights: &normals_only,
        ..*ctx
    };
    let mut optim: ModuleOptimizer = AdamConfig::new().init();
    let mut step = 0;
    loop {
        let hb = next()?;
        let seen = shaded(&net, &hb, ctx.device);
        if seen.1 >= SHADED || step >= MAX_WARMUP {
            return Ok((net, step, seen));
        }
        net = train_step(net, &mut optim, 1e-3, &hb, StepKind::PRETRAIN, &warm_ctx)?.0;
        step += 1;
    }
}

/// Times `steps` steps of `kind` (after one untimed), each on the next batch of `next()`, as
/// `trainer run` does (the batch's loading inside the time); median seconds per step.
fn time_steps(
    mut net: Net,
    optim: &mut ModuleOptimizer,
    lr: f64,
    kind: StepKind,
    ctx: &StepContext,
    steps: usize,
    mut next: impl FnMut() -> Result<data::Batch>,
) -> Result<(f64, u64)> {
    let hb = next()?;
    net = train_step(net, optim, lr, &hb, kind, ctx)?.0;
    let mut times = Vec::new();
    let mut peak = 0u64;
    for _ in 0..steps.max(1) {
        let t = Instant::now();
        let hb = next()?;
        net = train_step(net, optim, lr, &hb, kind, ctx)?.0;
        // The step reads its losses back, so the device has finished its work here.
        times.push(t.elapsed().as_secs_f64());
        if let Some(u) = ctx.device.memory_pool_usage() {
            peak = peak.max(u.bytes_reserved);
        }
    }
    Ok((median(times), peak))
}

/// Training images/s of a joint step for a network configuration on `device` (with autodiff),
/// on synthetic spheres, the network warmed up until it shades [`SHADED`] of them, with the
/// default (the paper's) loss weights.
pub fn training(
    device: &Device,
    name: &str,
    widths: Widths,
    size: usize,
    batch: usize,
    steps: usize,
) -> Result<(Measure, Workload)> {
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
    let net = net_cfg.init(&device);
    let w = LossWeights::default();
    let ctx = StepContext {
        layer: &layer,
        weights: &w,
        perceptual: &Perceptual::Fallback { why: "bench" },
        device: &device,
    };
    let mut seed = 2;
    let mut spheres = || {
        seed += 1;
        Ok(sphere_batch(batch, size, 64, seed, &layer))
    };
    let (net, warmup_steps, (object_pixels, shaded_fraction)) = warm_up(net, &ctx, &mut spheres)?;
    let mut optim = AdamConfig::new().init();
    let (seconds, peak) = time_steps(net, &mut optim, 1e-4, StepKind::JOINT, &ctx, steps, &mut spheres)?;
    Ok((
        Measure {
            name: format!("{name} {size}² batch {batch}"),
            seconds,
            peak_bytes: peak as usize,
        },
        Workload {
            object_pixels,
            shaded: shaded_fraction,
            warmup_steps: Some(warmup_steps),
        },
    ))
}

/// Training images/s of stage `stage` (its name; default: the last joint stage) of a training
/// manifest, on its dataset, with its loss weights, perceptual loss, learning rate and Adam
/// settings: the network loaded from `checkpoint`, or initialised from the run seed and warmed
/// up. This is `trainer run`'s step, timed as `trainer run` times it.
pub fn manifest_training(
    plan: &TrainPlan,
    stage: Option<&str>,
    checkpoint: Option<&std::path::Path>,
    device_name: Option<&str>,
    steps: usize,
) -> Result<(String, usize, Measure, Workload)> {
    let stages = &plan.manifest.stages;
    let si = match stage {
        Some(name) => stages.iter().position(|s| s.get_ref().name == name).ok_or_else(|| {
            anyhow::anyhow!(
                "{}: no stage named {name:?} (stages: {})",
                plan.path().display(),
                stages
                    .iter()
                    .map(|s| s.get_ref().name.clone())
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        })?,
        None => stages
            .iter()
            .rposition(|s| s.get_ref().kind == StageKind::Joint)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: no joint stage to time; name one with --stage",
                    plan.path().display()
                )
            })?,
    };
    let st = stages[si].get_ref();
    // The manifest's device, as `trainer run` would use, unless the command line names one.
    let device = crate::device::device_for(device_name.unwrap_or(plan.device.name()))?;
    device.seed(plan.manifest.run.seed);
    let layer = RenderingLayer::new(plan.net.env_height);
    let perceptual = plan.perceptual(&device)?;
    let ctx = StepContext {
        layer: &layer,
        weights: &plan.weights,
        perceptual: &perceptual,
        device: &device,
    };
    let mut data = crate::train::stream::open_dataset_stream(plan, si, 0, crate::data::Part::WHOLE)?;
    let mut next = || data.next_batch();
    let (net, warmup_steps, (object_pixels, shaded_fraction)) = match checkpoint {
        Some(dir) => {
            let (net, state) = crate::train::checkpoint::load_net(dir, &device)
                .map_err(|e| anyhow::anyhow!("checkpoint {}: {e:#}", dir.display()))?;
            if state.net != plan.net {
                anyhow::bail!(
                    "checkpoint {}: a network of another shape ({:?}) than the manifest's [model] ({:?})",
                    dir.display(),
                    state.net,
                    plan.net
                );
            }
            let seen = shaded(&net, &next()?, &device);
            (net, None, seen)
        }
        None => {
            let (net, steps, seen) = warm_up(plan.net.init(&device), &ctx, &mut next)?;
            (net, Some(steps), seen)
        }
    };
    let mut optim = crate::train::run::adam(st);
    let kind = StepKind {
        kind: st.kind,
        render_with: st.render_with,
    };
    let (seconds, peak) = time_steps(net, &mut optim, st.lr_at(0), kind, &ctx, steps, &mut next)?;
    let terms = loss_terms(&plan.weights);
    let what = format!(
        "{} stage {:?} ({:?}, batch {}, {}²; loss terms on: {}; {})",
        plan.path().display(),
        st.name,
        st.kind,
        st.batch_size,
        plan.net.input_size,
        terms,
        perceptual.description()
    );
    Ok((
        what,
        st.batch_size,
        Measure {
            name: format!("{} {}", plan.manifest.run.name, st.name),
            seconds,
            peak_bytes: peak as usize,
        },
        Workload {
            object_pixels,
            shaded: shaded_fraction,
            warmup_steps,
        },
    ))
}

/// The loss terms a step computes (those of non-zero weight), comma-separated.
fn loss_terms(w: &LossWeights) -> String {
    w.weighted().join(", ")
}

/// One line of the report for a timed training configuration.
fn workload_line(batch: usize, m: &Measure, w: &Workload) -> String {
    let memory = if m.peak_bytes > 0 {
        format!(", device memory reserved {:.1} MB", m.peak_bytes as f64 / 1e6)
    } else {
        String::new()
    };
    let how = match w.warmup_steps {
        None => "from the checkpoint".to_string(),
        Some(n) if n >= MAX_WARMUP && w.shaded < SHADED => {
            format!("still below {:.0} % after {MAX_WARMUP} warm-up steps", SHADED * 100.0)
        }
        Some(n) => format!("after {n} warm-up steps"),
    };
    format!(
        "training step {:32} {:7.2} images/s ({:.3} s/step{memory}); {:.0} object pixels/image, {:.1} % shaded ({how})\n",
        m.name,
        batch as f64 / m.seconds,
        m.seconds,
        w.object_pixels,
        100.0 * w.shaded
    )
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
    /// Training configurations, `NAME:SIZE:BATCH` (NAME: cpu-small or paper), on spheres.
    pub train: Vec<String>,
    /// A training manifest whose stage is timed on its own dataset.
    pub manifest: Option<std::path::PathBuf>,
    /// `--set PATH=VALUE` overrides of that manifest.
    pub sets: Vec<String>,
    /// That stage's name (default: the last joint stage).
    pub stage: Option<String>,
    /// The network to time it with (default: initialised and warmed up).
    pub checkpoint: Option<std::path::PathBuf>,
    /// Timed steps of the manifest's stage (the median is printed).
    pub steps: usize,
}

/// `trainer bench`'s report on device `device` (a training manifest's device name; `None`: the
/// CPU, and for `--manifest` the manifest's own device): the
/// rendering layer (the fused CPU layer against the tensor reference on the CPU device, the GPU
/// kernels on a GPU device), then training images/s per configuration. `alloc` measures peak
/// host memory where the binary installed it.
pub fn report(device_arg: Option<&str>, opts: &Options, alloc: Option<&PeakAlloc>) -> Result<String> {
    use std::fmt::Write;
    let device = device_arg.unwrap_or("cpu");
    let dev = crate::device::device_for(device)?;
    let mut out = Printed::default();
    let _ = writeln!(
        out,
        "# trainer bench (device {device}: {dev:?}; {} threads)",
        rayon::current_num_threads()
    );
    #[cfg(feature = "wgpu")]
    if crate::device::on_cube(&dev)
        && let Some(a) = crate::device::adapter::preferred()
    {
        let _ = writeln!(out, "adapter: {a}");
    }
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
    let specs: Vec<&String> = opts.train.iter().filter(|s| !s.is_empty()).collect();
    if !specs.is_empty() {
        let _ = writeln!(
            out,
            "synthetic spheres (joint steps, loss terms on: {}; fallback perceptual loss):",
            loss_terms(&LossWeights::default())
        );
    }
    for spec in specs {
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
        let (m, w) = training(&dev, name, widths, s, b, 3)?;
        out.push_str(&workload_line(b, &m, &w));
    }
    if let Some(path) = &opts.manifest {
        let plan = crate::train::manifest::load(path, &opts.sets)?;
        let (what, batch, m, w) = manifest_training(
            &plan,
            opts.stage.as_deref(),
            opts.checkpoint.as_deref(),
            device_arg,
            opts.steps,
        )?;
        let _ = writeln!(out, "{what}:");
        out.push_str(&workload_line(batch, &m, &w));
    }
    Ok(out.text)
}

/// The report as it grows, each piece also printed at once: a bench stopped by a time limit
/// (a GPU check's, a scheduler's) still leaves the figures measured before it.
#[derive(Default)]
struct Printed {
    text: String,
}

impl Printed {
    fn push_str(&mut self, s: &str) {
        use std::io::Write as _;
        self.text.push_str(s);
        let mut stdout = std::io::stdout().lock();
        let _ = stdout.write_all(s.as_bytes()).and_then(|()| stdout.flush());
    }
}

impl std::fmt::Write for Printed {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.push_str(s);
        Ok(())
    }
}

/// The GPU kernels' line of the report, on a GPU device.
#[cfg(feature = "wgpu")]
fn gpu_layer_line(dev: &Device, batch: usize, size: usize, runs: usize) -> Result<Option<String>> {
    if crate::rendering_layer::on_device(dev, 64).is_none() {
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

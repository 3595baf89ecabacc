//! `trainer run MANIFEST`: the stages of a training manifest, in order, with checkpoints,
//! `--resume`, metrics and loss curves.
//!
//! Reproducibility: every step re-seeds Burn's random source from (seed, stage, step) before
//! its forward pass (dropout; and the first step's forward draws the fresh network's weights,
//! which Burn initialises lazily, at their first use), and the data stream of a stage is a
//! pure function of (seed, stage, position). A resumed run therefore continues with exactly the
//! batches, dropout masks and optimiser state an uninterrupted run would have had, and writes
//! the same `metrics.jsonl` (wall-clock times live in `log.jsonl`, not in the metrics).
//!
//! As W ranks ([`run_as`], `crate::parallel`) every rank makes the same draws in the same order
//! (dropout draws the global batch's masks), so the W-rank run is the one-process run up to the
//! order of its sums.

use super::checkpoint::{self, State};
use super::data_parallel;
use super::manifest::TrainPlan;
use super::records::MetricsLine;
use super::step::{StepContext, StepKind, train_step};
use super::stream::OpenStream;
use crate::data::Part;
use crate::device::device_for_rank;
use crate::model::network::Net;
use crate::parallel::{Ranks, gradients};
use crate::rendering_layer::RenderingLayer;
use anyhow::{Context, Result, bail};
use burn::module::Module;
use burn::optim::{AdamConfig, ModuleOptimizer};
use burn::tensor::Device;
use matedit_contract::manifest::Named;
use matedit_contract::progress::Progress;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// What a finished run produced.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// Output folder.
    pub out: PathBuf,
    /// Final checkpoint of each stage, in order.
    pub stage_checkpoints: Vec<(String, PathBuf)>,
    /// Steps run in this invocation.
    pub steps_run: usize,
}

fn step_seed(seed: u64, stage: usize, step: usize) -> u64 {
    let h = blake3::hash(format!("{seed}/{stage}/{step}").as_bytes());
    u64::from_le_bytes(h.as_bytes()[..8].try_into().unwrap_or([0; 8]))
}

/// On a GPU device, refuses a run whose sizes Burn's reduction kernels get wrong there (see
/// `device::adapter::inexact_reductions`): such a run would train on wrong gradients
/// without a sign. `MATEDIT_ALLOW_INEXACT_REDUCTIONS=1` trains anyway (a speed measurement).
fn check_reductions(plan: &TrainPlan, device: &Device) -> Result<()> {
    #[cfg(feature = "wgpu")]
    if crate::device::on_cube(device) {
        let m = &plan.manifest;
        let size = *m.model.input_size.get_ref();
        let batch = m.stages.iter().map(|s| s.get_ref().batch_size).max().unwrap_or(1);
        let wrong = crate::device::adapter::inexact_reductions(device, batch, size);
        if !wrong.is_empty() {
            let why = format!(
                "Burn's reduction kernels on this GPU device are wrong at batch {batch} and {size}²: {}; \
                 training would use wrong gradients (`trainer gpu-info` probes a device; train on the cpu \
                 device, or with smaller batches)",
                wrong.join("; ")
            );
            if std::env::var("MATEDIT_ALLOW_INEXACT_REDUCTIONS").as_deref() == Ok("1") {
                eprintln!("warning (MATEDIT_ALLOW_INEXACT_REDUCTIONS=1): {why}");
            } else {
                bail!("{why}");
            }
        }
    }
    let _ = (plan, device);
    Ok(())
}

/// The Adam optimiser of a stage (its β1, β2).
pub fn adam(stage: &super::manifest::StageSection) -> ModuleOptimizer {
    AdamConfig::new()
        .with_beta_1(stage.beta1 as f32)
        .with_beta_2(stage.beta2 as f32)
        .init()
}

/// Set when the run is asked to stop (by `trainer run`'s SIGTERM and SIGUSR1 handler: a
/// scheduler's notice before preemption or the time limit). The run finishes the step in
/// progress, writes a checkpoint and stops with [`Preempted`]; `--resume` continues it to the
/// same losses as an uninterrupted run.
pub fn stop_requested() -> &'static Arc<AtomicBool> {
    static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
    FLAG.get_or_init(|| Arc::new(AtomicBool::new(false)))
}

/// The run stopped at [`stop_requested`] after writing a checkpoint.
#[derive(Debug, thiserror::Error)]
#[error("stopped on request after stage {stage}, step {step}: checkpoint {checkpoint} written; continue with --resume")]
pub struct Preempted {
    /// The stage.
    pub stage: String,
    /// Its last step done.
    pub step: usize,
    /// The checkpoint's folder name.
    pub checkpoint: String,
}

/// Runs (or, with `resume`, continues) the manifest's stages into `out`, as one process.
pub fn run(plan: &TrainPlan, out: &Path, resume: bool, open: &OpenStream, quiet: bool) -> Result<RunSummary> {
    run_as(&Rc::new(Ranks::single()), plan, out, resume, open, quiet)
}

/// Refuses a stage whose batch the ranks cannot share equally (the same on every rank).
fn check_batches(plan: &TrainPlan, ranks: &Ranks) -> Result<()> {
    let w = ranks.size();
    for (i, st) in plan.manifest.stages.iter().enumerate() {
        let b = st.get_ref().batch_size;
        if w > 1 && (b < w || b % w != 0) {
            // The line of the stage's `batch_size`.
            let at = matedit_contract::manifest::key_span(&plan.source.text, st.span(), "batch_size").start;
            bail!(
                "{}: stages[{i}].batch_size = {b} cannot be shared by {w} ranks: every rank takes an equal part \
                 of each batch, so batch_size must be a multiple of the rank count (e.g. {})",
                plan.source.place(at),
                (b.div_ceil(w) * w).max(w)
            );
        }
    }
    Ok(())
}

/// [`run`] as rank `ranks.rank()` of `ranks.size()` (see `crate::parallel`): every rank
/// trains on its part of each batch and applies the same update; rank 0 alone writes the
/// folder (checkpoints, `metrics.jsonl`, `log.jsonl`, `loss.png`), the others wait for it.
pub fn run_as(
    ranks: &Rc<Ranks>,
    plan: &TrainPlan,
    out: &Path,
    resume: bool,
    open: &OpenStream,
    quiet: bool,
) -> Result<RunSummary> {
    let root = ranks.is_root();
    let quiet = quiet || !root;
    let what = format!("the manifest {}", plan.path().display());
    ranks.same_as_root(&what, blake3::hash(plan.source.text.as_bytes()).as_bytes())?;
    check_batches(plan, ranks)?;
    let _lock = ranks.agree(if root {
        matedit_contract::lock::lock_output(out, matedit_contract::lock::Worker::ALL)
            .map(Some)
            .with_context(|| format!("{} is in use by another trainer run", out.display()))
    } else {
        Ok(None)
    })?;
    let m = &plan.manifest;
    let metrics_path = out.join("metrics.jsonl");
    ranks.agree(if root {
        checkpoint::remove_stale_temporaries(out)
    } else {
        Ok(())
    })?;
    let setup = ranks.agree(set_up(plan, out, resume, ranks));
    let Setup {
        device,
        chosen,
        perceptual,
        mut net,
        mut start,
    } = setup?;
    // The manifest's text is the same on every rank, but what it expands from the environment
    // (VGG16_WEIGHTS) need not be.
    let loss = perceptual.identity().unwrap_or_else(|| "fallback".into());
    ranks.same_as_root("the perceptual loss", blake3::hash(loss.as_bytes()).as_bytes())?;
    let layer = RenderingLayer::new(plan.net.env_height);
    let layer_on = if crate::rendering_layer::on_device(&device, plan.net.env_height).is_some() {
        "the rendering layer's GPU kernels"
    } else {
        "the fused CPU rendering layer"
    };
    // Which perceptual loss trains the network, and where, is never silent, not even with --quiet.
    if root {
        eprintln!("{}", perceptual.description());
    }
    let line = if ranks.size() > 1 {
        format!(
            "rank {} of {} (rank {} of {} on this machine): device {} ({device:?}{}), {layer_on}",
            ranks.rank(),
            ranks.size(),
            ranks.local_rank(),
            ranks.local_size(),
            plan.device.name(),
            if chosen.is_empty() {
                String::new()
            } else {
                format!(": {chosen}")
            }
        )
    } else {
        format!("device {} ({device:?}), {layer_on}", plan.device.name())
    };
    // One write: the ranks' lines reach a launcher's log whole, not interleaved.
    let _ = std::io::stderr().write_all(format!("{line}\n").as_bytes());
    let ctx = StepContext {
        layer: &layer,
        weights: &plan.weights,
        perceptual: &perceptual,
        device: &device,
    };
    let mut files = ranks.agree(if root {
        RunFiles::open(out, &metrics_path).map(Some)
    } else {
        Ok(None)
    })?;
    // A checkpoint whose validation a kill cut short is scored before the run goes on.
    if let (Some(v), Some((s, dir))) = (&plan.validation, &start) {
        let scored = match &mut files {
            Some(f)
                if v.due(s.global_step, s.stage_done) && !super::records::recorded(&metrics_path, s.global_step)? =>
            {
                let name = dir
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                v.run(out, &name, &s.stage_name, s.step, s.global_step)
                    .and_then(|l| f.validation(&l))
            }
            _ => Ok(()),
        };
        ranks.agree(scored)?;
    }
    let mut summary = RunSummary {
        out: out.to_path_buf(),
        stage_checkpoints: Vec::new(),
        steps_run: 0,
    };
    let mut global = start.as_ref().map_or(0, |(s, _)| s.global_step);
    let part = Part {
        index: ranks.rank(),
        of: ranks.size(),
    };
    for (si, st) in m.stages.iter().enumerate() {
        let st = st.get_ref();
        let final_name = st.name.clone();
        // Stages already finished before the resume.
        if let Some((s, _)) = &start
            && (si < s.stage || (si == s.stage && s.stage_done))
        {
            summary
                .stage_checkpoints
                .push((st.name.clone(), out.join("checkpoints").join(&final_name)));
            continue;
        }
        let mut optim = adam(st);
        let (mut step, position) = match start.take() {
            Some((s, dir)) if s.stage == si => {
                optim = ranks.agree(checkpoint::load_optimizer(&dir, optim))?;
                (s.step, s.data_position)
            }
            _ => {
                // A stage that branches from an earlier one starts from its final weights.
                if let Some(src) = &st.from {
                    let dir = out.join("checkpoints").join(src);
                    net = ranks.agree(checkpoint::load_net(&dir, &device))?.0;
                }
                (0, 0)
            }
        };
        let mut data = ranks.agree(open(plan, si, position, part))?;
        if let Some((what, id)) = data.identity() {
            ranks.same_as_root(&what, &id)?;
        }
        // Every rank must start from rank 0's weights (a different checkpoint, or a build that
        // computes otherwise); checked again at every checkpoint.
        if ranks.size() > 1 {
            ranks.same_as_root("the network's weights", &gradients::checksum(&net))?;
        }
        let bar = Progress::new(
            !quiet,
            st.steps as u64,
            &format!("{} steps", st.name),
            "{prefix:>10} [{bar:30}] {pos}/{len} steps  {msg}  ETA {eta}",
        );
        bar.bar().set_prefix(st.name.clone());
        bar.set_position(step as u64);
        // The schedule as a function of the step: a resumed stage reads its rate where it stopped.
        let rates = st.rates();
        while step < st.steps {
            let lr = rates[step];
            let t0 = std::time::Instant::now();
            let batch = data.next_batch();
            device.seed(step_seed(m.run.seed, si, step));
            let kind = StepKind {
                kind: st.kind,
                render_with: st.render_with,
            };
            let in_step = || format!("stage {}, step {}", st.name, step + 1);
            let (n, losses, stop, exchange) = if ranks.size() == 1 {
                let batch = batch?;
                let (n, losses) = train_step(net, &mut optim, lr, &batch, kind, &ctx).with_context(in_step)?;
                (n, losses, false, None)
            } else {
                let at = data_parallel::Rank {
                    ranks,
                    global: st.batch_size,
                    stop_asked: stop_requested(),
                };
                let o = data_parallel::step(at, net, &mut optim, lr, batch, kind, &ctx).with_context(in_step)?;
                (o.net, o.losses, o.stop, Some(o.exchange_seconds))
            };
            net = n;
            step += 1;
            global += 1;
            summary.steps_run += 1;
            let line = MetricsLine {
                stage: st.name.clone(),
                step,
                global_step: global,
                lr,
                losses,
            };
            let logged = match &mut files {
                Some(f) => f.log(
                    &line,
                    t0.elapsed().as_secs_f64(),
                    st.batch_size,
                    exchange.map(|e| (ranks.size(), e)),
                ),
                None => Ok(()),
            };
            // Rank 0's disk may fill: every rank stops with it.
            ranks.agree(logged)?;
            bar.set_message(format!("loss {:.4e}", losses.total));
            bar.inc(1);
            // One process reads the flag here, after the step, as it always has; ranks agreed
            // on it inside the step.
            let stop = stop || (ranks.size() == 1 && stop_requested().load(Ordering::SeqCst));
            let done = step == st.steps;
            // A validation scores the checkpoint it follows (not on a stop: the resumed run
            // scores it).
            let validate = !stop && plan.validation.as_ref().is_some_and(|v| v.due(global, done));
            if done || stop || validate || (st.checkpoint_every > 0 && step % st.checkpoint_every == 0) {
                let state = State {
                    version: checkpoint::VERSION,
                    manifest_hash: plan.hash(),
                    stage: si,
                    stage_name: st.name.clone(),
                    step,
                    global_step: global,
                    data_position: data.position(),
                    stage_done: done,
                    net: plan.net.clone(),
                    model_checksum: String::new(),
                    optimizer_checksum: String::new(),
                    perceptual: perceptual.identity(),
                    ranks: ranks.size(),
                };
                let name = if done {
                    final_name.clone()
                } else {
                    format!("{}-step-{step:07}", st.name)
                };
                // Rank 0 writes; the others wait here for it (and stop with it if it fails).
                let saved = match &mut files {
                    Some(f) => f.checkpoint(out, &name, &net, &optim, state, &st.name),
                    None => Ok(()),
                };
                ranks.agree(saved)?;
                if ranks.size() > 1 {
                    ranks.same_as_root("the network's weights", &gradients::checksum(&net))?;
                }
                if let (true, Some(v)) = (validate, &plan.validation) {
                    let scored = match &mut files {
                        Some(f) => v.run(out, &name, &st.name, step, global).and_then(|l| f.validation(&l)),
                        None => Ok(()),
                    };
                    ranks.agree(scored)?;
                }
                if stop {
                    bar.abandon();
                    return Err(Preempted {
                        stage: st.name.clone(),
                        step,
                        checkpoint: name,
                    }
                    .into());
                }
            }
        }
        bar.finish();
        summary
            .stage_checkpoints
            .push((st.name.clone(), out.join("checkpoints").join(&final_name)));
    }
    let plotted = match files {
        Some(f) => {
            drop(f);
            super::records::read_records(&metrics_path)
                .and_then(|records| super::plot::loss_curves(&records, &out.join("loss.png"), &plan.weights))
        }
        None => Ok(()),
    };
    ranks.agree(plotted)?;
    Ok(summary)
}

/// What every rank builds before the first step: the device, the perceptual loss, and the
/// network (fresh, from `run.init_from`, or the latest checkpoint with where it stood).
struct Setup {
    device: Device,
    /// Which GPU a rank took, and why (empty where there was no choice).
    chosen: String,
    perceptual: super::loss::Perceptual,
    net: Net,
    start: Option<(State, PathBuf)>,
}

fn set_up(plan: &TrainPlan, out: &Path, resume: bool, ranks: &Ranks) -> Result<Setup> {
    let root = ranks.is_root();
    let m = &plan.manifest;
    let metrics_path = out.join("metrics.jsonl");
    let latest = checkpoint::latest(out)?;
    let (device, chosen) = device_for_rank(plan.device.name(), ranks)?;
    check_reductions(plan, &device)?;
    if let Some(v) = &plan.validation {
        v.check()?;
    }
    let perceptual = plan.perceptual(&device)?;
    // Where to start: a fresh run, or the latest checkpoint.
    let (net, start): (Net, Option<(State, PathBuf)>) = match (&latest, resume) {
        (Some(_), false) => bail!(
            "{} already holds a run (latest.json); pass --resume to continue it, or choose another --out",
            out.display()
        ),
        (Some(dir), true) => {
            let (net, state) = checkpoint::load_net(dir, &device)?;
            if state.manifest_hash != plan.hash() {
                bail!(
                    "{}: the manifest changed since this run started (hash {} ≠ {}); resume with the original manifest",
                    plan.path().display(),
                    plan.hash(),
                    state.manifest_hash
                );
            }
            if state.perceptual != perceptual.identity() {
                let name = |p: &Option<String>| p.clone().unwrap_or_else(|| "the fallback".into());
                bail!(
                    "{}: this run was trained with the perceptual loss {}, the manifest now gives {} \
                     ([loss].vgg16{}); resume with the run's own (an empty VGG16_WEIGHTS= selects the fallback), \
                     or choose another --out",
                    out.display(),
                    name(&state.perceptual),
                    name(&perceptual.identity()),
                    plan.vgg16
                        .as_ref()
                        .map(|p| format!(" = {}", p.display()))
                        .unwrap_or_default()
                );
            }
            if root {
                super::records::truncate_records(&metrics_path, state.global_step)?;
            }
            (net, Some((state, dir.clone())))
        }
        (None, _) => {
            if root && metrics_path.exists() {
                std::fs::remove_file(&metrics_path)?;
            }
            device.seed(m.run.seed);
            let net = match &plan.init_from {
                None => plan.net.init(&device),
                Some(dir) => {
                    let (net, state) = checkpoint::load_net(dir, &device)?;
                    // Dropout is not a shape: a finetuning run may change it.
                    let mut shape = state.net.clone();
                    shape.widths.dropout = plan.net.widths.dropout;
                    if shape != plan.net {
                        bail!(
                            "{}: run.init_from {} holds a network of another shape ({:?}), the manifest's [model] is {:?}",
                            plan.path().display(),
                            dir.display(),
                            state.net,
                            plan.net
                        );
                    }
                    // The record holds no dropout probability: rebuild with the manifest's.
                    let fresh = plan.net.init(&device);
                    fresh.load_record(net.into_record())
                }
            };
            (net, None)
        }
    };
    if root {
        matedit_contract::io::write_atomically(&out.join("manifest.toml"), |p| {
            Ok(std::fs::write(p, &plan.source.text)?)
        })?;
    }
    Ok(Setup {
        device,
        chosen,
        perceptual,
        net,
        start,
    })
}

/// The files rank 0 writes as it trains.
struct RunFiles {
    metrics: std::fs::File,
    log: std::fs::File,
}

impl RunFiles {
    fn open(out: &Path, metrics_path: &Path) -> Result<RunFiles> {
        let append = |p: &Path| {
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .with_context(|| format!("cannot open {}", p.display()))
        };
        Ok(RunFiles {
            metrics: append(metrics_path)?,
            log: append(&out.join("log.jsonl"))?,
        })
    }

    /// A step's line in `metrics.jsonl` and its wall-clock time in `log.jsonl` (with the rank
    /// count and rank 0's seconds of the gradient exchange in a data-parallel run).
    fn log(&mut self, line: &MetricsLine, secs: f64, batch: usize, ranks: Option<(usize, f64)>) -> Result<()> {
        writeln!(self.metrics, "{}", serde_json::to_string(line)?)?;
        let mut entry = serde_json::json!({"stage": line.stage, "step": line.step, "seconds": secs, "images_per_second": batch as f64 / secs});
        if let Some((w, exchange)) = ranks {
            entry["ranks"] = w.into();
            entry["exchange_seconds"] = exchange.into();
        }
        writeln!(self.log, "{entry}")?;
        Ok(())
    }

    /// A validation's line in `metrics.jsonl`, on disk before the run goes on.
    fn validation(&mut self, line: &super::records::ValidationLine) -> Result<()> {
        writeln!(self.metrics, "{}", serde_json::to_string(line)?)?;
        self.metrics.sync_data()?;
        Ok(())
    }

    /// Writes checkpoint `name` (after the metrics it follows), keeping the stage ends and
    /// the newest intermediate checkpoint of `stage` only.
    fn checkpoint(
        &mut self,
        out: &Path,
        name: &str,
        net: &Net,
        optim: &burn::optim::ModuleOptimizer,
        state: State,
        stage: &str,
    ) -> Result<()> {
        self.metrics.sync_data()?;
        checkpoint::save(out, name, net, optim, state)?;
        remove_older_intermediates(out, stage, name)
    }
}

fn remove_older_intermediates(out: &Path, stage: &str, keep: &str) -> Result<()> {
    let dir = out.join("checkpoints");
    let prefix = format!("{stage}-step-");
    for e in std::fs::read_dir(&dir)? {
        let p = e?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.starts_with(&prefix) && name != keep {
            std::fs::remove_dir_all(&p).with_context(|| format!("cannot remove {}", p.display()))?;
        }
    }
    Ok(())
}

//! The `trainer` command line: trains the material-editing network of Fig. 2 from manifests,
//! evaluates it like Sec. 4 of the paper, and measures the rendering layer. The binary's
//! `main` only hands over its allocator ([`main`]); tests run the same function.

use crate::alloc::PeakAlloc;
use crate::baseline::lombardi::LombardiConfig;
use crate::bench;
use crate::eval::{EvalOptions, evaluate};
use crate::parallel::Ranks;
use crate::targets::{material_from_prediction, normalised_target};
use crate::train::manifest;
use crate::train::run::{Preempted, run_as, stop_requested};
use crate::train::stream::open_dataset_stream;
use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use matedit_contract::args::{count_in, finite_in};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "trainer",
    bin_name = "trainer",
    version,
    about = "Trainer for the material-editing network"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Train the stages of a training manifest (manifests/train/*.toml), then evaluate every
    /// stage's final checkpoint on the manifest's [eval] split.
    Run {
        /// Training manifest.
        manifest: PathBuf,
        /// Output folder (default: the manifest's run.output).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Continue the run in the output folder from its latest checkpoint.
        #[arg(long)]
        resume: bool,
        /// No progress bars.
        #[arg(long)]
        quiet: bool,
        /// Override a manifest field, `PATH=VALUE` (e.g. `stages[1].steps=60`,
        /// `stages[joint].learning_rate=[[0, 1e-5]]`, `run.device=wgpu`); repeatable, applied in
        /// order after `extends`. The run records (and `--resume` compares) the result.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
    /// Score checkpoints on a dataset split: METRICS.json and Markdown tables shaped like the
    /// paper's Tables 1–3 (with both trivial baselines).
    Eval {
        /// Checkpoint folder (`OUT/checkpoints/STAGE`), or `LABEL=FOLDER` to name its row and
        /// column (default: its stage name); repeat to compare several.
        #[arg(long, required = true)]
        checkpoint: Vec<String>,
        /// Dataset folder.
        #[arg(long)]
        data: PathBuf,
        /// Split to score.
        #[arg(long, default_value = "test")]
        split: String,
        /// Dataset whose training splits define the mean-material baseline (default: --data).
        #[arg(long)]
        train_data: Option<PathBuf>,
        /// Output JSON; the tables go next to it as .md.
        #[arg(long)]
        out: PathBuf,
        /// Samples per batch (1–4096).
        #[arg(long, default_value_t = 8, value_parser = count_in(1, 4096))]
        batch: usize,
        /// At most this many samples (0: all).
        #[arg(long, default_value_t = 0)]
        max_samples: usize,
        /// Score only this shape category (repeat for several; default: all).
        #[arg(long = "category")]
        categories: Vec<String>,
        /// Samples in the contact sheet written next to --out as .png (0: none).
        #[arg(long, default_value_t = 8)]
        sheet: usize,
        /// Also score each checkpoint after the post-optimisation of every sample (Eq. 6; slow:
        /// seconds per sample), as Table 3's "+ Eq. 6" column.
        #[arg(long)]
        eq6: bool,
        /// Eq. 6's weight a of the normal prior (0–1e6).
        #[arg(long, default_value_t = crate::post_optimisation::Eq6Config::default().a, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
        eq6_a: f64,
        /// Eq. 6's weight b of the light prior (0–1e6).
        #[arg(long, default_value_t = crate::post_optimisation::Eq6Config::default().b, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
        eq6_b: f64,
        /// Eq. 6's rounds of (light, material, normals) (1–100).
        #[arg(long, default_value_t = crate::post_optimisation::Eq6Config::default().rounds, value_parser = count_in(1, 100), allow_negative_numbers = true)]
        eq6_rounds: usize,
        /// Eq. 6's L-BFGS iterations per property and round (1–1000).
        #[arg(long, default_value_t = crate::post_optimisation::Eq6Config::default().iterations, value_parser = count_in(1, 1000), allow_negative_numbers = true)]
        eq6_iterations: usize,
        /// Objects of more pixels run Eq. 6's alternation on every k-th pixel (0: never).
        #[arg(long, default_value_t = crate::post_optimisation::Eq6Config::default().coarse_pixels)]
        eq6_coarse_pixels: usize,
        /// Also score the Lombardi-style optimiser of material and light given the true normals
        /// (Table 3's baseline; slow: seconds per sample).
        #[arg(long)]
        lombardi: bool,
        /// Its reflectance prior's relative weight (0–1e6).
        #[arg(long, default_value_t = LombardiConfig::default().material_weight, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
        lombardi_material_weight: f64,
        /// Its natural-illumination prior's relative weight (0–1e6).
        #[arg(long, default_value_t = LombardiConfig::default().light_weight, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
        lombardi_light_weight: f64,
        /// Its rounds of (material, light) (1–100).
        #[arg(long, default_value_t = LombardiConfig::default().rounds, value_parser = count_in(1, 100), allow_negative_numbers = true)]
        lombardi_rounds: usize,
        /// Its L-BFGS iterations per property and round (1–1000).
        #[arg(long, default_value_t = LombardiConfig::default().iterations, value_parser = count_in(1, 1000), allow_negative_numbers = true)]
        lombardi_iterations: usize,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Print a material file's 108 normalised parameters (the material module's target) as JSON.
    MaterialTarget {
        /// DSBRDF material file.
        material: PathBuf,
    },
    /// Turn a predicted 108-vector (JSON array, tanh range) into a DSBRDF material file.
    MaterialFromPrediction {
        /// JSON array of 108 numbers.
        prediction: PathBuf,
        /// Output material file.
        #[arg(long)]
        out: PathBuf,
    },
    /// The graphics adapters wgpu sees and the one the `wgpu` device takes (`--features wgpu`).
    GpuInfo {
        /// Fail (exit 1) unless the wgpu device takes a hardware GPU: refuse Mesa's lavapipe,
        /// llvmpipe and every CPU adapter.
        #[arg(long)]
        require_hardware: bool,
    },
    /// Rendering layer forward+backward time and peak memory (fused vs tensor reference), and
    /// training images/s per network configuration.
    Bench {
        /// Batch size of the rendering-layer measurement (1–1024).
        #[arg(long, default_value_t = 8, value_parser = count_in(1, 1024), allow_negative_numbers = true)]
        batch: usize,
        /// Image side of the rendering-layer measurement (1–4096).
        #[arg(long, default_value_t = 128, value_parser = count_in(1, 4096), allow_negative_numbers = true)]
        size: usize,
        /// Timed runs of the fused layer (the median is printed; 1–1000).
        #[arg(long, default_value_t = 5, value_parser = count_in(1, 1000), allow_negative_numbers = true)]
        runs: usize,
        /// Skip the (slow) tensor reference.
        #[arg(long)]
        no_reference: bool,
        /// Training configurations to time on synthetic spheres: NAME:SIZE:BATCH with NAME
        /// cpu-small or paper ("" for none). The network is warmed up by pretraining steps until
        /// its normals shade 90 % of the object, as a trained one's do.
        #[arg(long, value_delimiter = ',', default_value = "cpu-small:64:8,cpu-small:128:8")]
        train: Vec<String>,
        /// The device of both measurements, as in a training manifest: cpu (the fused CPU layer),
        /// wgpu (`--features wgpu`: the layer's GPU kernels, the whole training step on the GPU).
        /// Default: cpu, and for --manifest the manifest's device.
        #[arg(long)]
        device: Option<String>,
        /// Also time a training manifest's stage on its own dataset, with its losses and
        /// settings, as `trainer run` steps it.
        #[arg(long)]
        manifest: Option<PathBuf>,
        /// Override a field of --manifest, `PATH=VALUE`, as `trainer run --set` does.
        #[arg(long = "set", value_name = "PATH=VALUE", requires = "manifest")]
        sets: Vec<String>,
        /// The stage of --manifest (default: its last joint stage).
        #[arg(long, requires = "manifest")]
        stage: Option<String>,
        /// The network for --manifest: a checkpoint folder (e.g. the stage before the timed
        /// one); default: initialised from the run seed and warmed up until its normals face
        /// the camera.
        #[arg(long, requires = "manifest")]
        checkpoint: Option<PathBuf>,
        /// Timed steps of --manifest's stage (the median is printed).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=10_000))]
        steps: u64,
    },
    /// Write a checkpoint's network as one safetensors file for any framework: every tensor
    /// float32, named by its path in the network, the configuration in the metadata (the names,
    /// shapes and layouts: docs/FORMAT.md, "A trained network").
    Export {
        /// Checkpoint folder (`OUT/checkpoints/STAGE`).
        checkpoint: PathBuf,
        /// The file to write (replaced atomically).
        #[arg(long)]
        safetensors: PathBuf,
    },
    /// Write samples of a split as the trainer's batch holds them (channel-first tensors,
    /// materials padded to the batch's region count) to a safetensors file: for checking
    /// another reader of the dataset against the trainer.
    DumpBatch {
        /// Dataset folder.
        data: PathBuf,
        /// Split.
        #[arg(long, default_value = "test")]
        split: String,
        /// Index position of the first sample in the split.
        #[arg(long, default_value_t = 0)]
        first: usize,
        /// Samples (1–4096).
        #[arg(long, default_value_t = 4, value_parser = count_in(1, 4096))]
        count: usize,
        /// Output file (.safetensors).
        #[arg(long)]
        out: PathBuf,
    },
    /// How fast the trainer's data loader reads a split: one pass in index order, checksums
    /// verified, decoded ahead by --workers threads; prints samples/s (median of --runs passes).
    BenchLoader {
        /// Dataset folder.
        data: PathBuf,
        /// Split.
        #[arg(long, default_value = "train")]
        split: String,
        /// Samples per batch (1–4096).
        #[arg(long, default_value_t = 16, value_parser = count_in(1, 4096))]
        batch_size: usize,
        /// Background decoding threads (0: decode in the calling thread; 0–64).
        #[arg(long, default_value_t = 2, value_parser = count_in(0, 64))]
        workers: usize,
        /// Timed passes (1–100).
        #[arg(long, default_value_t = 3, value_parser = count_in(1, 100))]
        runs: usize,
    },
    /// What data-parallel training adds to a step: the all-reduce of the network's gradients
    /// (alone, and with flattening and putting back) over the ranks this runs as
    /// (`mpirun -np W trainer bench-ranks`; a build with `--features mpi`).
    BenchRanks {
        /// The network's widths: cpu-small or paper.
        #[arg(long, default_value = "paper")]
        widths: String,
        /// Its input side (16–1024; the paper: 256).
        #[arg(long, default_value_t = 256, value_parser = count_in(16, 1024), allow_negative_numbers = true)]
        size: usize,
        /// Timed repetitions (the median is printed; 1–1000).
        #[arg(long, default_value_t = 10, value_parser = count_in(1, 1000), allow_negative_numbers = true)]
        runs: usize,
    },
}

/// `LABEL=FOLDER` as (label, folder), or a folder (an existing path is never split, even with
/// an '=' in its name) as ("", folder).
fn labelled(arg: &str) -> (String, PathBuf) {
    match arg.split_once('=') {
        Some((label, folder)) if !std::path::Path::new(arg).exists() && !label.is_empty() => {
            (label.to_owned(), PathBuf::from(folder))
        }
        _ => (String::new(), PathBuf::from(arg)),
    }
}

/// Runs evaluation and writes `out` (JSON) and its `.md` tables; prints the tables.
fn eval_to(checkpoints: &[PathBuf], opts: &EvalOptions, out: &std::path::Path) -> Result<()> {
    let report = evaluate(checkpoints, opts)?;
    crate::eval::report::write_report(&report, out)?;
    let md = report.markdown();
    let md_path = out.with_extension("md");
    matedit_contract::io::write_atomically(&md_path, |p| Ok(std::fs::write(p, &md)?))?;
    println!("{md}");
    if let Some(last) = report.checkpoints.last() {
        match report.beats_baselines(&last.name) {
            Some(true) => println!("{}: O' beats the trivial baselines on L2 and SSIM.", last.name),
            Some(false) => println!("{}: O' does NOT beat the trivial baselines on L2 and SSIM.", last.name),
            None => {}
        }
    }
    eprintln!("wrote {} and {}", out.display(), md_path.display());
    Ok(())
}

/// `trainer bench-ranks`: one line from rank 0.
fn bench_ranks(widths: &str, size: usize, runs: usize) -> Result<()> {
    use crate::model::Widths;
    use crate::model::network::NetConfig;
    let ranks = Ranks::from_environment()?;
    let w =
        Widths::preset(widths).with_context(|| format!("--widths {widths:?}: unknown ({})", Widths::preset_names()))?;
    let device = burn::tensor::Device::flex();
    let net = NetConfig::new(size, w).init(&device);
    let r = crate::parallel::bench::measure(&ranks, &net, &device, runs);
    if ranks.is_root() && ranks.size() == 1 {
        println!(
            "1 rank, {widths} widths at {size}²: {} parameters; no all-reduce (one rank); flatten + put back median {:.2} ms; {runs} runs",
            r.parameters,
            r.step.median()
        );
    } else if ranks.is_root() {
        let mib = r.buffer as f64 * 4.0 / (1 << 20) as f64;
        let n = ranks.size() as f64;
        // A ring all-reduce moves 2(W−1)/W of the buffer through each rank's link.
        let moved = 2.0 * (n - 1.0) / n * r.buffer as f64 * 4.0;
        let gbps = moved / (r.all_reduce.median() * 1e-3) / 1e9;
        println!(
            "{} rank{}, {widths} widths at {size}²: {} parameters ({mib:.1} MiB of f32 gradients); all-reduce median {:.2} ms \
             (min {:.2}, max {:.2}; {gbps:.2} GB/s of ring traffic per rank); flatten + all-reduce + put back median {:.2} ms; {runs} runs",
            ranks.size(),
            if ranks.size() == 1 { "" } else { "s" },
            r.parameters,
            r.all_reduce.median(),
            r.all_reduce.ms.first().copied().unwrap_or(f64::NAN),
            r.all_reduce.ms.last().copied().unwrap_or(f64::NAN),
            r.step.median()
        );
    }
    Ok(())
}

/// `trainer gpu-info`: every adapter, the one the wgpu device takes, its runtime (the compiler,
/// f16, tensor cores: [`crate::device::runtime`]), and with
/// `require_hardware` an error unless that one is a hardware GPU.
#[cfg(feature = "wgpu")]
fn gpu_info(require_hardware: bool) -> Result<()> {
    use crate::device::adapter;
    let all = adapter::adapters();
    if all.is_empty() {
        println!("wgpu sees no adapter");
    }
    for a in &all {
        println!("adapter: {a}");
    }
    match adapter::preferred() {
        Some(a) if require_hardware && a.is_software() => {
            anyhow::bail!("the wgpu device would take {a}, a software rasteriser, not a GPU (--require-hardware)")
        }
        Some(a) => println!("the wgpu device takes: {a}"),
        None => anyhow::bail!("wgpu found no adapter: no Vulkan, DX12 or OpenGL driver is installed"),
    }
    let device = crate::device::wgpu_device().map_err(|e| anyhow::anyhow!(e))?;
    if let Some(r) = crate::device::runtime::Runtime::of(&device) {
        println!("{r}");
    }
    // Burn's reductions at the sizes of the quickstart, bench and paper configurations.
    for (batch, size) in [(8, 64), (16, 128), (16, 256)] {
        let wrong = adapter::inexact_reductions(&device, batch, size);
        if wrong.is_empty() {
            println!("Burn's reductions at batch {batch}, {size}²: exact");
        } else {
            println!(
                "Burn's reductions at batch {batch}, {size}²: WRONG: {}",
                wrong.join("; ")
            );
        }
    }
    Ok(())
}

#[cfg(not(feature = "wgpu"))]
fn gpu_info(_require_hardware: bool) -> Result<()> {
    anyhow::bail!("this trainer was built without GPU support: build it with `--features wgpu`")
}

fn run(cli: Cli, alloc: Option<&PeakAlloc>) -> Result<()> {
    match cli.command {
        Command::Run {
            manifest: path,
            out,
            resume,
            quiet,
            sets,
        } => {
            // A scheduler's notice (Slurm's --signal, Kubernetes' termination): checkpoint and stop.
            #[cfg(unix)]
            for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGUSR1] {
                signal_hook::flag::register(sig, stop_requested().clone())
                    .context("cannot install the SIGTERM/SIGUSR1 handler")?;
            }
            let ranks = std::rc::Rc::new(Ranks::from_environment()?);
            let threads = ranks.agree(crate::parallel::ranks::set_threads(&ranks))?;
            // Every rank reads the manifest; a rank that cannot is named on all of them.
            let plan = ranks.agree(manifest::load(&path, &sets).map_err(anyhow::Error::from))?;
            if ranks.size() > 1 && ranks.is_root() {
                eprintln!("{} ranks, {threads} threads each", ranks.size());
            }
            let out = out.unwrap_or_else(|| PathBuf::from(&plan.manifest.run.output));
            let summary = run_as(&ranks, &plan, &out, resume, &open_dataset_stream, quiet)?;
            if !ranks.is_root() {
                // Rank 0 alone evaluates and reports.
                return Ok(());
            }
            eprintln!(
                "{} steps run; checkpoints: {}",
                summary.steps_run,
                summary
                    .stage_checkpoints
                    .iter()
                    .map(|(_, p)| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            let e = &plan.manifest.eval;
            let checkpoints: Vec<PathBuf> = summary.stage_checkpoints.iter().map(|(_, p)| p.clone()).collect();
            let opts = EvalOptions {
                data: plan.dataset.clone(),
                split: e.split.clone(),
                train_data: None,
                batch: 8,
                max_samples: e.max_samples,
                categories: e.categories.clone(),
                progress: !quiet,
                sheet: Some((out.join("eval.png"), 8)),
                eq6: None,
                lombardi: None,
                names: Vec::new(),
            };
            eval_to(&checkpoints, &opts, &out.join("eval.json"))?;
        }
        Command::Eval {
            checkpoint,
            data,
            split,
            train_data,
            out,
            batch,
            max_samples,
            categories,
            sheet,
            eq6,
            eq6_a,
            eq6_b,
            eq6_rounds,
            eq6_iterations,
            eq6_coarse_pixels,
            lombardi,
            lombardi_material_weight,
            lombardi_light_weight,
            lombardi_rounds,
            lombardi_iterations,
            quiet,
        } => {
            let (names, checkpoint): (Vec<String>, Vec<PathBuf>) = checkpoint.iter().map(|c| labelled(c)).unzip();
            let opts = EvalOptions {
                data,
                split,
                train_data,
                batch,
                max_samples,
                categories,
                progress: !quiet,
                sheet: Some((out.with_extension("png"), sheet)),
                eq6: eq6.then(|| crate::post_optimisation::Eq6Config {
                    a: eq6_a,
                    b: eq6_b,
                    rounds: eq6_rounds,
                    iterations: eq6_iterations,
                    coarse_pixels: eq6_coarse_pixels,
                    ..Default::default()
                }),
                lombardi: lombardi.then(|| LombardiConfig {
                    material_weight: lombardi_material_weight,
                    light_weight: lombardi_light_weight,
                    rounds: lombardi_rounds,
                    iterations: lombardi_iterations,
                    ..Default::default()
                }),
                names,
            };
            eval_to(&checkpoint, &opts, &out)?;
        }
        Command::MaterialTarget { material } => {
            println!("{}", serde_json::to_string(&normalised_target(&material)?.to_vec())?);
        }
        Command::MaterialFromPrediction { prediction, out } => {
            let m = material_from_prediction(&prediction)?;
            std::fs::write(&out, m.to_json())?;
            eprintln!("wrote {}", out.display());
        }
        Command::GpuInfo { require_hardware } => gpu_info(require_hardware)?,
        Command::BenchRanks { widths, size, runs } => bench_ranks(&widths, size, runs)?,
        Command::BenchLoader {
            data,
            split,
            batch_size,
            workers,
            runs,
        } => {
            let (samples, rates) = crate::data::rate::loader_rates(&data, &split, batch_size, workers, runs)?;
            println!(
                "{}: split {split}, {samples} samples, batch {batch_size}, {workers} workers, checksums verified: median {:.1} samples/s over {runs} passes (min {:.1}, max {:.1})",
                data.display(),
                rates[rates.len() / 2],
                rates[0],
                rates[rates.len() - 1]
            );
        }
        Command::Export {
            checkpoint,
            safetensors,
        } => {
            let tensors = crate::model::export::export(&checkpoint, &safetensors)?;
            let values: usize = tensors.iter().map(|t| t.shape.iter().product::<usize>()).sum();
            eprintln!(
                "wrote {} ({} tensors, {values} parameters)",
                safetensors.display(),
                tensors.len()
            );
        }
        Command::DumpBatch {
            data,
            split,
            first,
            count,
            out,
        } => {
            let ids = crate::data::dump::dump_batch(&data, &split, first, count, &out)?;
            eprintln!("wrote {} ({} samples: {})", out.display(), ids.len(), ids.join(", "));
        }
        Command::Bench {
            batch,
            size,
            runs,
            no_reference,
            train,
            device,
            manifest,
            sets,
            stage,
            checkpoint,
            steps,
        } => {
            let opts = bench::Options {
                batch,
                size,
                runs,
                reference: !no_reference,
                train,
                manifest,
                sets,
                stage,
                checkpoint,
                steps: steps as usize,
            };
            // The report prints itself as it goes.
            bench::report(device.as_deref(), &opts, alloc)?;
        }
    }
    Ok(())
}

/// A line on stderr in one write, so that several ranks' lines reach a launcher's log whole.
fn say(line: &str) {
    use std::io::Write;
    let _ = std::io::stderr().write_all(format!("{line}\n").as_bytes());
}

/// `trainer run`'s status when it stopped on a signal after writing a checkpoint (EX_TEMPFAIL:
/// try again), which `scripts/train_slurm.sh` turns into a requeue.
pub const EXIT_PREEMPTED: u8 = 75;

/// Runs the command line of this process's arguments. `alloc`, the binary's global allocator
/// when it counts, gives `trainer bench` its peak-memory column.
pub fn main(alloc: Option<&PeakAlloc>) -> ExitCode {
    match run(Cli::parse(), alloc) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.downcast_ref::<Preempted>().is_some() => {
            say(&format!("{e:#}"));
            ExitCode::from(EXIT_PREEMPTED)
        }
        Err(e) => {
            say(&format!("error: {e:#}"));
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numeric_options_outside_their_ranges_are_refused_naming_the_option() {
        let eval = ["trainer", "eval", "--checkpoint", "c", "--data", "d", "--out", "o.json"];
        for (option, value) in [
            ("--batch", "0"),
            ("--eq6-a", "NaN"),
            ("--eq6-b", "-1"),
            ("--eq6-rounds", "0"),
            ("--eq6-iterations", "1001"),
            ("--lombardi-material-weight", "inf"),
            ("--lombardi-light-weight", "-1"),
            ("--lombardi-rounds", "0"),
            ("--lombardi-iterations", "0"),
        ] {
            let e = Cli::try_parse_from(eval.iter().chain(&[option, value]))
                .err()
                .unwrap_or_else(|| panic!("{option} {value} accepted"));
            assert!(e.to_string().contains(option), "{option} {value}: {e}");
        }
        assert!(Cli::try_parse_from(eval.iter().chain(&["--batch", "4", "--eq6-b", "10"])).is_ok());
        for (option, value) in [("--batch", "0"), ("--size", "0"), ("--runs", "0")] {
            let e = Cli::try_parse_from(["trainer", "bench", option, value])
                .err()
                .unwrap_or_else(|| panic!("bench {option} {value} accepted"));
            assert!(e.to_string().contains(option), "{option}: {e}");
        }
    }
}

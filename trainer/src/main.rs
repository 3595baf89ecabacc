//! `trainer`: the material-editing network's trainer (material targets for now).

use anyhow::Result;
use clap::{Parser, Subcommand};
use matedit_trainer::alloc::PeakAlloc;
use matedit_trainer::bench;
use matedit_trainer::model::Widths;
use matedit_trainer::targets::{material_from_prediction, normalised_target};
use std::path::PathBuf;
use std::process::ExitCode;

/// Counts heap bytes so that `trainer bench` can report peak memory.
#[global_allocator]
static ALLOC: PeakAlloc = PeakAlloc::new();

#[derive(Parser)]
#[command(name = "trainer", version, about = "Trainer for the material-editing network")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
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
    /// Rendering layer forward+backward time and peak memory (fused vs tensor reference), and
    /// training images/s per network configuration.
    Bench {
        /// Batch size of the rendering-layer measurement.
        #[arg(long, default_value_t = 8)]
        batch: usize,
        /// Image side of the rendering-layer measurement.
        #[arg(long, default_value_t = 128)]
        size: usize,
        /// Timed runs of the fused layer (the median is printed).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Skip the (slow) tensor reference.
        #[arg(long)]
        no_reference: bool,
        /// Training configurations to time: NAME:SIZE:BATCH with NAME cpu-small or paper.
        #[arg(long, value_delimiter = ',', default_value = "cpu-small:64:8,cpu-small:128:8")]
        train: Vec<String>,
    },
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::MaterialTarget { material } => {
            println!("{}", serde_json::to_string(&normalised_target(&material)?.to_vec())?);
        }
        Command::MaterialFromPrediction { prediction, out } => {
            let m = material_from_prediction(&prediction)?;
            std::fs::write(&out, m.to_json())?;
            eprintln!("wrote {}", out.display());
        }
        Command::Bench {
            batch,
            size,
            runs,
            no_reference,
            train,
        } => {
            println!("# trainer bench ({} threads)", rayon::current_num_threads());
            let (fused, reference) = if no_reference {
                let layer = bench::rendering_layer(batch, size, 64, runs, Some(&ALLOC));
                (layer?.0, None)
            } else {
                let (f, r) = bench::rendering_layer(batch, size, 64, runs, Some(&ALLOC))?;
                (f, Some(r))
            };
            println!("rendering layer, batch {batch} at {size}², 64x128 environment, forward+backward:");
            println!(
                "  fused             {:9.3} s  peak {:9.1} MB",
                fused.seconds,
                fused.peak_bytes as f64 / 1e6
            );
            if let Some(r) = reference {
                println!(
                    "  tensor reference  {:9.3} s  peak {:9.1} MB",
                    r.seconds,
                    r.peak_bytes as f64 / 1e6
                );
                println!(
                    "  ratio             {:9.1}x faster, {:.1}x less peak memory",
                    r.seconds / fused.seconds,
                    r.peak_bytes as f64 / fused.peak_bytes.max(1) as f64
                );
            }
            for spec in train {
                let parts: Vec<&str> = spec.split(':').collect();
                let [name, s, b] = parts.as_slice() else {
                    anyhow::bail!("--train {spec}: expected NAME:SIZE:BATCH");
                };
                let widths = match *name {
                    "cpu-small" => Widths::cpu_small(),
                    "paper" => Widths::paper(),
                    other => anyhow::bail!("--train {spec}: unknown configuration {other} (cpu-small, paper)"),
                };
                let (s, b): (usize, usize) = (s.parse()?, b.parse()?);
                let m = bench::training(name, widths, s, b, 3)?;
                println!(
                    "training (joint step) {:24} {:7.2} images/s ({:.3} s/step)",
                    m.name,
                    b as f64 / m.seconds,
                    m.seconds
                );
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

//! `trainer`: the material-editing network's trainer (material targets for now).

use anyhow::Result;
use clap::{Parser, Subcommand};
use matedit_trainer::targets::{material_from_prediction, normalised_target};
use std::path::PathBuf;
use std::process::ExitCode;

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

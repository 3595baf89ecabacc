//! Writes a checkpoint of an untrained network (for timing `matedit edit` at sizes no trained
//! model exists for yet; its edits are meaningless).
//!
//! `cargo run --release -p matedit-trainer --example untrained_checkpoint -- OUT SIZE [cpu-small|paper]`
use anyhow::{Result, bail};
use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, save};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(out), Some(size)) = (args.first(), args.get(1).and_then(|s| s.parse::<usize>().ok())) else {
        bail!("usage: untrained_checkpoint OUT SIZE [cpu-small|paper]");
    };
    let widths = match args.get(2).map(String::as_str) {
        None | Some("cpu-small") => Widths::cpu_small(),
        Some("paper") => Widths::paper(),
        Some(w) => bail!("widths {w}: cpu-small or paper"),
    };
    let device = Device::flex();
    let cfg = NetConfig::new(size, widths).with_env_height(64);
    let net = cfg.init(&device);
    let state = State::untrained(cfg, "untrained");
    let dir = save(
        std::path::Path::new(out),
        "untrained",
        &net,
        &AdamConfig::new().init(),
        state,
    )?;
    eprintln!("wrote {}", dir.display());
    Ok(())
}

//! Atomic, checksummed checkpoints: a folder per checkpoint with the network (`model.bpk`), the
//! optimiser state (`optimizer.bpk`) and `state.json` (where the run stood, and the blake3 of
//! both files). The folder is written under a temporary name and renamed into place, then
//! `latest.json` is replaced atomically, so a kill at any moment leaves either the previous or the
//! new checkpoint, never a partial one.

use crate::model::network::{Net, NetConfig};
use anyhow::{Context, Result, bail};
use burn::module::Module;
use burn::optim::ModuleOptimizer;
use burn::store::ModuleRecord;
use burn::tensor::Device;
use matedit_contract::io::write_atomically;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Format version of `state.json`.
pub const VERSION: u32 = 1;

/// Where a run stood when a checkpoint was written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct State {
    /// [`VERSION`].
    pub version: u32,
    /// blake3 of the training manifest (a resume refuses a changed manifest).
    pub manifest_hash: String,
    /// Index of the stage in the manifest.
    pub stage: usize,
    /// Its name.
    pub stage_name: String,
    /// Steps completed in this stage.
    pub step: usize,
    /// Steps completed in the whole run (= lines of `metrics.jsonl`).
    pub global_step: usize,
    /// Position of the next sample in the stage's data stream.
    pub data_position: u64,
    /// Whether the stage is finished.
    pub stage_done: bool,
    /// Network shape.
    pub net: NetConfig,
    /// `blake3:HEX` of `model.bpk`.
    pub model_checksum: String,
    /// `blake3:HEX` of `optimizer.bpk`.
    pub optimizer_checksum: String,
    /// The perceptual loss, where it is not the fallback: `vgg16 blake3:HEX` of the weights (a
    /// resume refuses another). Absent for the fallback, so such checkpoints keep their bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub perceptual: Option<String>,
    /// How many ranks trained the step that wrote the checkpoint (data parallelism); absent
    /// for one, so that one process's checkpoints keep their bytes.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub ranks: usize,
}

fn one() -> usize {
    1
}

fn is_one(n: &usize) -> bool {
    *n == 1
}

impl State {
    /// The state of a network no run trained (tools and tests write such checkpoints): one
    /// finished stage named `stage_name`, no manifest, no steps.
    pub fn untrained(net: NetConfig, stage_name: &str) -> Self {
        Self {
            version: VERSION,
            manifest_hash: String::new(),
            stage: 0,
            stage_name: stage_name.into(),
            step: 0,
            global_step: 0,
            data_position: 0,
            stage_done: true,
            net,
            model_checksum: String::new(),
            optimizer_checksum: String::new(),
            perceptual: None,
            ranks: 1,
        }
    }
}

/// `blake3:HEX` of a file (checkpoints, and the perceptual loss's weights a checkpoint records).
pub(crate) fn checksum(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    Ok(matedit_contract::records::checksum(&bytes))
}

/// Writes checkpoint `name` under `root/checkpoints/` and points `root/latest.json` at it.
pub fn save(root: &Path, name: &str, net: &Net, optim: &ModuleOptimizer, mut state: State) -> Result<PathBuf> {
    let fin = replace_folder(&root.join("checkpoints"), name, |tmp| {
        let model = tmp.join("model.bpk");
        net.clone()
            .into_record()
            .save(&model)
            .map_err(|e| anyhow::anyhow!("{}: {e}", model.display()))?;
        let opt = tmp.join("optimizer.bpk");
        optim
            .save(&opt)
            .map_err(|e| anyhow::anyhow!("{}: {e}", opt.display()))?;
        state.model_checksum = checksum(&model)?;
        state.optimizer_checksum = checksum(&opt)?;
        std::fs::write(tmp.join("state.json"), serde_json::to_string_pretty(&state)?)?;
        Ok(())
    })?;
    write_atomically(&root.join("latest.json"), |p| {
        std::fs::write(
            p,
            serde_json::to_string_pretty(&serde_json::json!({ "checkpoint": format!("checkpoints/{name}") }))?,
        )?;
        Ok(())
    })?;
    Ok(fin)
}

/// Writes folder `dir/name` whole or not at all: `write` fills `dir/.tmp-NAME-PID`, every file in
/// it is synced, and it takes the place of the previous `dir/name` (moved aside to
/// `.old-NAME-PID` first, as a rename cannot replace a folder, and removed once the new one is
/// in place). A kill leaves the previous folder or the new one; the temporaries are removed by
/// [`remove_stale_temporaries`]. Checkpoints and the best checkpoint are written with it.
pub fn replace_folder(dir: &Path, name: &str, write: impl FnOnce(&Path) -> Result<()>) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let fin = dir.join(name);
    let tmp = dir.join(format!(".tmp-{name}-{}", std::process::id()));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir_all(&tmp)?;
    removed_on_error(&tmp, || {
        write(&tmp)?;
        for e in std::fs::read_dir(&tmp)? {
            std::fs::File::open(e?.path())?.sync_all()?;
        }
        Ok(())
    })?;
    if fin.exists() {
        let old = dir.join(format!(".old-{name}-{}", std::process::id()));
        std::fs::rename(&fin, &old)?;
        std::fs::rename(&tmp, &fin).with_context(|| format!("cannot move {} to {}", tmp.display(), fin.display()))?;
        std::fs::remove_dir_all(&old)?;
    } else {
        std::fs::rename(&tmp, &fin).with_context(|| format!("cannot move {} to {}", tmp.display(), fin.display()))?;
    }
    Ok(fin)
}

/// Runs `write` into the folder `tmp`; when it fails (a full disk), removes `tmp` before
/// returning the error, so that a failed checkpoint leaves nothing behind.
fn removed_on_error<T>(tmp: &Path, write: impl FnOnce() -> Result<T>) -> Result<T> {
    let r = write();
    if r.is_err() {
        let _ = std::fs::remove_dir_all(tmp);
    }
    r
}

/// Removes the half-written (`.tmp-*`) and half-replaced (`.old-*`) checkpoint folders a killed
/// run can leave. Call only while holding the output's lock.
pub fn remove_stale_temporaries(root: &Path) -> Result<()> {
    let dir = root.join("checkpoints");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Ok(());
    };
    for e in entries {
        let p = e?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.starts_with(".tmp-") || name.starts_with(".old-") {
            std::fs::remove_dir_all(&p).with_context(|| format!("cannot remove {}", p.display()))?;
        }
    }
    Ok(())
}

/// Reads and checks a checkpoint folder's state.
pub fn read_state(dir: &Path) -> Result<State> {
    let p = dir.join("state.json");
    let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let mut v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not a checkpoint state", p.display()))?;
    // Checkpoints written before Baseline 1 existed have no such field: they hold none.
    if let Some(net) = v.get_mut("net").and_then(|n| n.as_object_mut()) {
        net.entry("encoder_decoder").or_insert(serde_json::Value::Bool(false));
    }
    let s: State = serde_json::from_value(v).with_context(|| format!("{}: not a checkpoint state", p.display()))?;
    if s.version != VERSION {
        bail!("{}: version {} (this trainer reads {VERSION})", p.display(), s.version);
    }
    s.net
        .validate()
        .map_err(|e| anyhow::anyhow!("{}: net: {e}", p.display()))?;
    for (f, want) in [
        ("model.bpk", &s.model_checksum),
        ("optimizer.bpk", &s.optimizer_checksum),
    ] {
        let got = checksum(&dir.join(f))?;
        if &got != want {
            bail!(
                "{}: checksum mismatch (state.json says {want}, the file has {got}): the checkpoint is corrupt",
                dir.join(f).display()
            );
        }
    }
    Ok(s)
}

/// The checkpoint `latest.json` points at, if any.
pub fn latest(root: &Path) -> Result<Option<PathBuf>> {
    let p = root.join("latest.json");
    if !p.exists() {
        return Ok(None);
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&p)?).with_context(|| format!("{}: not JSON", p.display()))?;
    let rel = v["checkpoint"]
        .as_str()
        .with_context(|| format!("{}: no \"checkpoint\" field", p.display()))?;
    Ok(Some(root.join(rel)))
}

/// The network stored in checkpoint folder `dir` (or a `model.bpk` file), on `device`.
pub fn load_net(dir: &Path, device: &Device) -> Result<(Net, State)> {
    let state = read_state(dir)?;
    let net = state.net.init(device);
    let model = dir.join("model.bpk");
    let record = ModuleRecord::load(&model).map_err(|e| anyhow::anyhow!("{}: {e}", model.display()))?;
    let net = net
        .try_load_record(record)
        .map_err(|e| anyhow::anyhow!("{}: {e}", model.display()))?;
    Ok((net, state))
}

/// Restores the optimiser state of checkpoint `dir` into a freshly configured optimiser.
pub fn load_optimizer(dir: &Path, fresh: ModuleOptimizer) -> Result<ModuleOptimizer> {
    let p = dir.join("optimizer.bpk");
    fresh.load(&p).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Widths;
    use burn::optim::AdamConfig;

    #[test]
    fn a_checkpoint_that_fails_to_write_leaves_no_temporary_folder() {
        let tmp = std::env::temp_dir().join(format!("matedit-checkpoint-fail-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).unwrap();
        std::fs::write(tmp.join("model.bpk"), b"half").unwrap();
        // A failed write (what a full disk gives) removes the folder and keeps the error.
        let e = removed_on_error(&tmp, || -> Result<()> { anyhow::bail!("No space left on device") }).unwrap_err();
        assert!(e.to_string().contains("No space"));
        assert!(!tmp.exists());
        // A write that succeeds keeps it.
        std::fs::create_dir_all(&tmp).unwrap();
        assert_eq!(removed_on_error(&tmp, || Ok(7)).unwrap(), 7);
        assert!(tmp.is_dir());
        std::fs::remove_dir_all(&tmp).unwrap();
    }

    #[test]
    fn checkpoints_from_before_baseline_1_still_load_and_both_kinds_round_trip() {
        let root = std::env::temp_dir().join(format!("matedit-checkpoint-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let device = Device::flex().autodiff();
        for with_b1 in [false, true] {
            let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8))
                .with_env_height(4)
                .with_encoder_decoder(with_b1);
            let net = cfg.init(&device);
            let optim = AdamConfig::new().init();
            let name = format!("b1-{with_b1}");
            let dir = save(&root, &name, &net, &optim, State::untrained(cfg.clone(), &name)).unwrap();
            let (back, state) = load_net(&dir, &device).unwrap();
            assert_eq!(state.net, cfg);
            assert_eq!(back.encoder_decoder.is_some(), with_b1);
        }
        // A state.json written before the field existed reads as a network without Baseline 1.
        let dir = root.join("checkpoints/b1-false");
        let p = dir.join("state.json");
        let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        assert!(v["net"].as_object_mut().unwrap().remove("encoder_decoder").is_some());
        std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
        let (net, state) = load_net(&dir, &device).unwrap();
        assert!(!state.net.encoder_decoder && net.encoder_decoder.is_none());
        let _ = std::fs::remove_dir_all(&root);
    }
}

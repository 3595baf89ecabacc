//! `trainer export CKPT --safetensors OUT`: a trained network as one safetensors file that any
//! framework reads (PyTorch, JAX and NumPy through the `safetensors` package), written by Burn's
//! own store.
//!
//! Every parameter is one float32 tensor named by its path in the network (`normal.scale1.0.weight`,
//! …; the table in docs/FORMAT.md, "A trained network"). Layouts are Burn's: a convolution's weight
//! is `[out, in, kh, kw]` (as PyTorch's), a transposed convolution's `[in, out, kh, kw]` (as
//! PyTorch's), but a linear layer's weight is `[in, out]` (PyTorch's is `[out, in]`: transpose it).
//! The metadata carries what is needed to rebuild the network: `matedit.format`
//! ([`FORMAT`]), `matedit.net` (the network's configuration as JSON: input size, environment
//! height, widths, exposure), and where it came from (`matedit.stage`, `matedit.step`,
//! `matedit.source`: the checkpoint's `model.bpk` checksum). [`load`] reads it back into the
//! same network, bit for bit.

use super::network::{Net, NetConfig};
use crate::train::checkpoint::{load_net, read_state};
use anyhow::{Context, Result, bail};
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;
use std::path::Path;

/// The format of the files [`export`] writes (the `matedit.format` metadata value).
pub const FORMAT: &str = "matedit-net/1";

/// One tensor of an exported network: its name, shape and element type.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorEntry {
    /// Its path in the network.
    pub name: String,
    /// Its shape.
    pub shape: Vec<usize>,
    /// Its element type (`F32`).
    pub dtype: String,
}

/// Every tensor of `net`, in the order Burn visits them.
pub fn tensors(net: &Net) -> Vec<TensorEntry> {
    net.collect(None, None, false)
        .iter()
        .map(|t| TensorEntry {
            name: t.name.clone(),
            shape: t.shape.to_vec(),
            dtype: format!("{:?}", t.dtype).to_uppercase(),
        })
        .collect()
}

/// Writes the network of checkpoint folder `ckpt` to `out` (atomically: a kill leaves the file
/// that was there, or the new one); returns its tensors.
pub fn export(ckpt: &Path, out: &Path) -> Result<Vec<TensorEntry>> {
    let device = Device::flex();
    let state = read_state(ckpt)?;
    let (net, _) = load_net(ckpt, &device)?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let mut store = SafetensorsStore::from_file(out)
        .overwrite(true)
        .metadata("matedit.format", FORMAT)
        .metadata("matedit.net", serde_json::to_string(&state.net)?)
        .metadata("matedit.stage", state.stage_name.clone())
        .metadata("matedit.step", state.step.to_string())
        .metadata("matedit.source", state.model_checksum.clone())
        .metadata(
            "matedit.layout",
            "float32; conv [out, in, kh, kw]; transposed conv [in, out, kh, kw]; linear [in, out] (PyTorch: [out, in])",
        );
    net.save_into(&mut store)
        .map_err(|e| anyhow::anyhow!("{}: {e}", out.display()))?;
    Ok(tensors(&net))
}

/// The metadata of an exported network's file.
pub fn metadata(path: &Path) -> Result<std::collections::HashMap<String, String>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let (_, meta) = safetensors::SafeTensors::read_metadata(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: not a safetensors file: {e}", path.display()))?;
    Ok(meta.metadata().clone().unwrap_or_default())
}

/// Reads a file [`export`] wrote back into its network on `device`: every tensor must be there
/// with its shape, and no other.
pub fn load(path: &Path, device: &Device) -> Result<(Net, NetConfig)> {
    let meta = metadata(path)?;
    match meta.get("matedit.format").map(String::as_str) {
        Some(FORMAT) => {}
        Some(other) => bail!("{}: format {other:?} (this trainer reads {FORMAT:?})", path.display()),
        None => bail!("{}: not a matedit network (no matedit.format metadata)", path.display()),
    }
    let config: NetConfig = serde_json::from_str(meta.get("matedit.net").map_or("", String::as_str))
        .with_context(|| format!("{}: matedit.net is not a network configuration", path.display()))?;
    config
        .validate()
        .map_err(|e| anyhow::anyhow!("{}: matedit.net: {e}", path.display()))?;
    let mut net = config.init(device);
    let mut store = SafetensorsStore::from_file(path);
    let result = net.load_from(&mut store).map_err(|e| {
        // Burn's message lists every mismatch: the first few say enough.
        let all = e.to_string();
        let short: String = all.chars().take(400).collect();
        let more = if short.len() < all.len() { " …" } else { "" };
        anyhow::anyhow!(
            "{}: does not match its network configuration: {short}{more}",
            path.display()
        )
    })?;
    if !result.errors.is_empty() || !result.missing.is_empty() || !result.unused.is_empty() {
        bail!(
            "{}: does not match its network configuration ({} missing, {} unexpected, {} wrong: {})",
            path.display(),
            result.missing.len(),
            result.unused.len(),
            result.errors.len(),
            result
                .missing
                .iter()
                .map(|(p, _)| p.clone())
                .chain(result.unused.iter().cloned())
                .chain(result.errors.iter().map(|e| format!("{e:?}")))
                .take(3)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    Ok((net, config))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Widths;
    use crate::model::network::Exposure;
    use crate::train::checkpoint::{State, save};
    use crate::train::run::adam;

    fn checkpoint(dir: &Path, config: &NetConfig) -> Net {
        let device = Device::flex();
        device.seed(11);
        let net = config.init(&device);
        let text =
            "[[stages]]\nname = \"s\"\nkind = \"pretrain\"\nsteps = 1\nbatch_size = 1\nlearning_rate = [[0, 1e-3]]\n";
        let stage: crate::train::manifest::StageSection = toml::from_str::<toml::Table>(text).unwrap()["stages"]
            .as_array()
            .unwrap()[0]
            .clone()
            .try_into()
            .unwrap();
        save(dir, "s", &net, &adam(&stage), State::untrained(config.clone(), "s")).unwrap();
        net
    }

    fn photo(s: usize) -> (Vec<f32>, Vec<f32>, Vec<u8>) {
        let p = s * s;
        let mask: Vec<f32> = (0..p).map(|k| f32::from(k % s >= 2 && k / s >= 3)).collect();
        let regions = mask.iter().map(|&m| m as u8).collect();
        let input = (0..3 * p).map(|k| 0.02 + ((k * 29) % 13) as f32 * 0.07).collect();
        (input, mask, regions)
    }

    #[test]
    fn an_exported_network_predicts_bit_for_bit_what_its_checkpoint_does() {
        let d = tempfile::tempdir().unwrap();
        for config in [
            NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(8),
            NetConfig::new(32, Widths::new(4, 16, 24, 8))
                .with_env_height(8)
                .with_exposure(Some(Exposure::Normalised)),
        ] {
            let ckpt = d.path().join(format!("run-{}", config.input_size));
            let net = checkpoint(&ckpt, &config);
            let out = d.path().join(format!("net-{}.safetensors", config.input_size));
            let listed = export(&ckpt.join("checkpoints/s"), &out).unwrap();
            assert_eq!(listed, tensors(&net));
            let device = Device::flex();
            let (back, got) = load(&out, &device).unwrap();
            assert_eq!(got, config);
            let (input, mask, regions) = photo(config.input_size);
            let a = net.predict_photo(&input, &mask, &regions, 1, &device).unwrap();
            let b = back.predict_photo(&input, &mask, &regions, 1, &device).unwrap();
            assert_eq!(a.normals, b.normals);
            assert_eq!(a.materials, b.materials);
            assert_eq!(a.env, b.env);
            // The file itself: every tensor float32, finite, named and shaped as listed.
            let bytes = std::fs::read(&out).unwrap();
            let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
            assert_eq!(st.len(), listed.len());
            for t in &listed {
                let v = st.tensor(&t.name).unwrap();
                assert_eq!(v.shape(), t.shape.as_slice(), "{}", t.name);
                assert_eq!(v.dtype(), safetensors::Dtype::F32, "{}", t.name);
                assert!(
                    v.data()
                        .chunks(4)
                        .all(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
                );
            }
            let meta = metadata(&out).unwrap();
            assert_eq!(meta["matedit.format"], FORMAT);
            assert_eq!(meta["matedit.stage"], "s");
        }
    }

    #[test]
    fn a_file_of_another_network_or_format_is_refused() {
        let d = tempfile::tempdir().unwrap();
        let config = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(8);
        checkpoint(d.path(), &config);
        let out = d.path().join("net.safetensors");
        export(&d.path().join("checkpoints/s"), &out).unwrap();
        let device = Device::flex();
        // Another network's configuration in the metadata: shapes do not match.
        let bytes = std::fs::read(&out).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut meta = metadata(&out).unwrap();
        let views: Vec<(String, safetensors::tensor::TensorView)> =
            st.tensors().into_iter().map(|(n, v)| (n.to_string(), v)).collect();
        let write = |meta: &std::collections::HashMap<String, String>, name: &str| {
            let p = d.path().join(name);
            std::fs::write(&p, safetensors::serialize(views.clone(), Some(meta.clone())).unwrap()).unwrap();
            p
        };
        meta.insert(
            "matedit.net".into(),
            serde_json::to_string(&NetConfig::new(16, Widths::new(8, 16, 32, 8)).with_env_height(8)).unwrap(),
        );
        let e = load(&write(&meta, "other.safetensors"), &device)
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not match its network configuration"), "{e}");
        meta.insert("matedit.format".into(), "matedit-net/9".into());
        let e = load(&write(&meta, "future.safetensors"), &device)
            .unwrap_err()
            .to_string();
        assert!(e.contains("format \"matedit-net/9\""), "{e}");
        meta.remove("matedit.format");
        let e = load(&write(&meta, "plain.safetensors"), &device)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a matedit network"), "{e}");
        std::fs::write(d.path().join("junk.safetensors"), b"not a file").unwrap();
        let e = load(&d.path().join("junk.safetensors"), &device)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a safetensors file"), "{e}");
    }

    #[test]
    fn the_documented_table_is_the_quickstarts_network() {
        let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/FORMAT.md")).unwrap();
        let table = doc
            .split("| name | shape |\n|---|---|\n")
            .nth(1)
            .expect("the table in docs/FORMAT.md");
        let rows: Vec<(String, String)> = table
            .lines()
            .take_while(|l| l.starts_with('|'))
            .map(|l| {
                let cells: Vec<&str> = l.split('|').map(str::trim).collect();
                (cells[1].trim_matches('`').to_string(), cells[2].to_string())
            })
            .collect();
        let net = NetConfig::new(64, Widths::preset("cpu-small").unwrap())
            .with_env_height(64)
            .init(&Device::flex());
        let live: Vec<(String, String)> = tensors(&net)
            .into_iter()
            .map(|t| (t.name, format!("{:?}", t.shape)))
            .collect();
        assert_eq!(rows, live);
        assert!(tensors(&net).iter().all(|t| t.dtype == "F32"));
    }
}

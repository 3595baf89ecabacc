//! OpenEXR writing and reading of named `f32` channels.

use super::write_atomically;
use anyhow::{Context, Result, bail};
use exr::prelude::*;
use matedit_physics::EnvMap;
use std::collections::BTreeMap;
use std::path::Path;

/// Writes one EXR part of `width × height` with the given named `f32` channels (ZIP compressed),
/// atomically. Names with a dot (`normal.X`) are layer-qualified, as tools such as Blender and
/// OpenImageIO expect.
pub fn write_exr_channels(path: &Path, width: usize, height: usize, channels: Vec<(&str, Vec<f32>)>) -> Result<()> {
    let bytes = encode_exr_channels(width, height, channels)
        .with_context(|| format!("refusing to write {}", path.display()))?;
    write_atomically(path, |tmp| {
        std::fs::write(tmp, &bytes).with_context(|| format!("cannot write {}", path.display()))
    })
}

/// Encodes one EXR part in memory (see [`write_exr_channels`]). Non-finite samples and
/// channels of the wrong length are errors. The bytes depend only on the data.
pub fn encode_exr_channels(width: usize, height: usize, channels: Vec<(&str, Vec<f32>)>) -> Result<Vec<u8>> {
    for (name, data) in &channels {
        if data.len() != width * height {
            bail!("channel {name}: {} samples for a {width}×{height} image", data.len());
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            bail!("channel {name}: sample {i} is not finite");
        }
    }
    let list: Vec<AnyChannel<FlatSamples>> = channels
        .into_iter()
        .map(|(name, data)| AnyChannel::new(name, FlatSamples::F32(data)))
        .collect();
    let layer = Layer::new(
        (width, height),
        LayerAttributes::default(),
        Encoding::SMALL_LOSSLESS,
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let image = Image::from_layer(layer);
    let mut buf = std::io::Cursor::new(Vec::new());
    // Callers encode many files in parallel already; the crate's parallel writer would spawn a
    // thread pool per file.
    image
        .write()
        .non_parallel()
        .to_buffered(&mut buf)
        .context("EXR encoding failed")?;
    Ok(buf.into_inner())
}

/// Writes an environment map as an RGB EXR.
pub fn write_env_exr(path: &Path, env: &EnvMap) -> Result<()> {
    write_exr_channels(path, env.width(), env.height(), env_channels(env))
}

/// Encodes an environment map as an RGB EXR in memory (see [`encode_exr_channels`]).
pub fn encode_env_exr(env: &EnvMap) -> Result<Vec<u8>> {
    encode_exr_channels(env.width(), env.height(), env_channels(env))
}

fn env_channels(env: &EnvMap) -> Vec<(&'static str, Vec<f32>)> {
    let t = env.texels();
    let ch = |c: usize| t.iter().map(|p| p[c]).collect::<Vec<f32>>();
    vec![("R", ch(0)), ("G", ch(1)), ("B", ch(2))]
}

/// Reads every channel of the first layer as `f32`, keyed by name, with the image size.
pub fn read_exr_channels(path: &Path) -> Result<(usize, usize, BTreeMap<String, Vec<f32>>)> {
    let image = read_first_flat_layer_from_file(path).with_context(|| format!("cannot read {}", path.display()))?;
    let size = image.layer_data.size;
    let mut out = BTreeMap::new();
    for ch in &image.layer_data.channel_data.list {
        out.insert(ch.name.to_string(), ch.sample_data.values_as_f32().collect());
    }
    Ok((size.width(), size.height(), out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_round_trip_bit_exactly_and_non_finite_is_refused() {
        let dir = std::env::temp_dir().join(format!("matedit-exr-{}", std::process::id()));
        let p = dir.join("t.exr");
        let r: Vec<f32> = (0..12).map(|i| i as f32 * 0.1 + 1e-7).collect();
        write_exr_channels(&p, 4, 3, vec![("R", r.clone()), ("normal.X", vec![-0.5; 12])]).unwrap();
        let (w, h, ch) = read_exr_channels(&p).unwrap();
        assert_eq!((w, h), (4, 3));
        assert_eq!(ch["R"], r);
        assert_eq!(ch["normal.X"], vec![-0.5; 12]);
        let mut bad = r.clone();
        bad[3] = f32::NAN;
        assert!(write_exr_channels(&p, 4, 3, vec![("R", bad)]).is_err());
        assert_eq!(read_exr_channels(&p).unwrap().2["R"], r, "previous file intact");
    }
}

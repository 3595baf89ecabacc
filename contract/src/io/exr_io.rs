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
    write_zip16(&image, &mut buf).context("EXR encoding failed")?;
    Ok(buf.into_inner())
}

/// Writes `image` as the exr crate's own writer does (same headers, blocks and offset tables),
/// but deflates each ZIP block with libdeflate instead of the crate's fixed miniz_oxide level 4:
/// the same size within a fraction of a percent at 1.6× the speed, and deflate is about a third
/// of a dataset sample's core time (docs/PERFORMANCE.md). The bytes depend only on the data and
/// the libdeflate version that `Cargo.lock` pins. One block at a time: callers encode many files
/// in parallel already.
fn write_zip16<'a, L>(image: &'a Image<L>, out: &mut std::io::Cursor<Vec<u8>>) -> exr::error::UnitResult
where
    L: exr::image::write::layers::WritableLayers<'a>,
{
    use exr::block::chunk::{Chunk, CompressedBlock, CompressedScanLineBlock};
    use exr::block::writer::ChunksWriter;
    use exr::image::write::layers::LayersWriter;
    use exr::meta::BlockDescription;
    let headers = image.write().infer_meta_data();
    let layers = image.layer_data.create_writer(&headers);
    exr::block::write(out, headers, true, move |meta, chunks| {
        let mut zip = ZipBlocks::new();
        let blocks = meta.collect_ordered_block_data(|index| layers.extract_uncompressed_block(&meta.headers, index));
        for (index_in_header, block) in blocks {
            let header = &meta.headers[block.index.layer];
            if header.compression != Compression::ZIP16 || header.blocks != BlockDescription::ScanLines {
                return Err(exr::error::Error::NotSupported(
                    "write_zip16: ZIP16 scan lines only".into(),
                ));
            }
            let y = i32::try_from(block.index.pixel_position.y())
                .map_err(|_| exr::error::Error::Invalid("image too tall".into()))?
                + header.own_attributes.layer_position.y();
            let chunk = Chunk {
                layer_index: block.index.layer,
                compressed_block: CompressedBlock::ScanLine(CompressedScanLineBlock {
                    y_coordinate: y,
                    compressed_pixels_le: zip.compress(block.data)?,
                }),
            };
            chunks.write_chunk(index_in_header, chunk)?;
        }
        Ok(())
    })
}

/// OpenEXR's ZIP block coding: the bytes of the (little-endian) samples split into even and odd
/// halves, then replaced by their differences (+128), then zlib; a block that would not shrink
/// is stored raw, as the format and the exr crate do.
struct ZipBlocks {
    deflate: libdeflater::Compressor,
    scratch: Vec<u8>,
}

impl ZipBlocks {
    /// Level 6 matches the exr crate's files in size (docs/PERFORMANCE.md, `exr_codecs`).
    const LEVEL: i32 = 6;

    fn new() -> Self {
        let level = libdeflater::CompressionLvl::new(Self::LEVEL).unwrap_or_default();
        Self {
            deflate: libdeflater::Compressor::new(level),
            scratch: Vec::new(),
        }
    }

    /// `raw`: the block's samples as the exr crate lays them out, native-endian.
    fn compress(&mut self, raw: Vec<u8>) -> exr::error::Result<Vec<u8>> {
        if cfg!(target_endian = "big") {
            return Err(exr::error::Error::NotSupported(
                "write_zip16 on a big-endian machine".into(),
            ));
        }
        let n = raw.len();
        self.scratch.clear();
        self.scratch.resize(n, 0);
        let (even, odd) = self.scratch.split_at_mut(n.div_ceil(2));
        for ((e, o), pair) in even.iter_mut().zip(odd.iter_mut()).zip(raw.chunks_exact(2)) {
            *e = pair[0];
            *o = pair[1];
        }
        if n % 2 == 1 {
            even[n / 2] = raw[n - 1];
        }
        let mut previous = self.scratch.first().copied().unwrap_or(0);
        for b in self.scratch.iter_mut().skip(1) {
            let current = *b;
            *b = current.wrapping_sub(previous).wrapping_add(128);
            previous = current;
        }
        let mut out = vec![0; self.deflate.zlib_compress_bound(n)];
        let size = self
            .deflate
            .zlib_compress(&self.scratch, &mut out)
            .map_err(|e| exr::error::Error::Invalid(format!("deflate: {e}").into()))?;
        out.truncate(size);
        Ok(if size < n { out } else { raw })
    }
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

/// The most decoded bytes an EXR may hold per byte of file. Deflate cannot expand beyond
/// 1032:1 (ZIP, ZIPS, PXR24, DWA's inner streams); RLE 64:1; B44 about 11:1; PIZ's Huffman runs
/// stay within a few hundred. A header claiming more than this is corrupt, and is refused
/// before the reader allocates for it (the exr crate sizes its buffers from the header).
pub const EXR_MAX_EXPANSION: u64 = 4096;

/// Refuses a file (`bytes`, read from `path`) whose headers declare more pixel data than
/// [`EXR_MAX_EXPANSION`] allows.
pub fn check_exr_size(path: &Path, bytes: &[u8]) -> Result<()> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false).with_context(|| {
        format!(
            "{}: cannot decode the EXR header (truncated or corrupt?)",
            path.display()
        )
    })?;
    let declared: u128 = meta
        .headers
        .iter()
        .map(|h| h.layer_size.area() as u128 * h.channels.bytes_per_pixel as u128)
        .sum();
    let allowed = (bytes.len() as u128 + 1024) * EXR_MAX_EXPANSION as u128;
    if declared > allowed {
        let size = meta.headers.first().map(|h| h.layer_size).unwrap_or_default();
        bail!(
            "{}: its header declares {}×{} pixels ({declared} bytes of samples), more than a {}-byte EXR can hold: the file is corrupt or truncated",
            path.display(),
            size.width(),
            size.height(),
            bytes.len()
        );
    }
    Ok(())
}

/// Every channel of an EXR layer as `f32`, keyed by name.
pub type ExrChannels = BTreeMap<String, Vec<f32>>;

/// Reads every channel of the first layer as `f32`, keyed by name, with the image size.
pub fn read_exr_channels(path: &Path) -> Result<(usize, usize, ExrChannels)> {
    // One read of the file serves the size check and the decoding.
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    check_exr_size(path, &bytes)?;
    decode_exr_channels(&bytes, true).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Decodes every channel of the first layer of an EXR file in memory as `f32`: (width, height,
/// channels), each channel checked to hold width × height samples. `parallel: false` decodes on
/// the calling thread (for callers that decode many files in parallel themselves: exr's own
/// pool per file would only add thread start-ups).
pub fn decode_exr_channels(bytes: &[u8], parallel: bool) -> std::result::Result<(usize, usize, ExrChannels), String> {
    let reader = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes();
    let cursor = std::io::Cursor::new(bytes);
    let image = if parallel {
        reader.from_buffered(cursor)
    } else {
        reader.non_parallel().from_buffered(cursor)
    }
    .map_err(|e| format!("cannot decode the EXR (truncated or corrupt?): {e}"))?;
    let size = image.layer_data.size;
    let (w, h) = (size.width(), size.height());
    let mut out = BTreeMap::new();
    for ch in &image.layer_data.channel_data.list {
        let v: Vec<f32> = ch.sample_data.values_as_f32().collect();
        if v.len() != w * h {
            return Err(format!("channel {}: {} samples for {w}×{h}", ch.name, v.len()));
        }
        out.insert(ch.name.to_string(), v);
    }
    Ok((w, h, out))
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

    /// Reads with the exr crate's pedantic checks (its decoder, zune-inflate, is independent of
    /// the libdeflate encoder).
    fn read_pedantic(bytes: &[u8]) -> (exr::meta::header::Header, BTreeMap<String, Vec<u32>>) {
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .pedantic()
            .from_buffered(std::io::Cursor::new(bytes))
            .unwrap();
        let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), true).unwrap();
        let channels = image
            .layer_data
            .channel_data
            .list
            .iter()
            .map(|c| {
                (
                    c.name.to_string(),
                    c.sample_data.values_as_f32().map(f32::to_bits).collect(),
                )
            })
            .collect();
        (meta.headers[0].clone(), channels)
    }

    /// What the exr crate's own writer makes of the same channels.
    fn encode_with_crate(width: usize, height: usize, channels: &[(&str, Vec<f32>)]) -> Vec<u8> {
        let list: Vec<AnyChannel<FlatSamples>> = channels
            .iter()
            .map(|(n, d)| AnyChannel::new(*n, FlatSamples::F32(d.clone())))
            .collect();
        let layer = Layer::new(
            (width, height),
            LayerAttributes::default(),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(SmallVec::from_vec(list)),
        );
        let mut buf = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .non_parallel()
            .to_buffered(&mut buf)
            .unwrap();
        buf.into_inner()
    }

    /// Channels of every kind the factory writes and the codec's corner cases: blocks that
    /// deflate well (constant, smooth), blocks that do not (noise: stored raw), special values,
    /// a last block shorter than 16 lines, widths of 1 and odd, names out of order.
    #[test]
    fn zip_blocks_decode_bit_exactly_with_the_crates_headers_and_size() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut noise = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            f32::from_bits((state as u32 & 0x807f_ffff) | 0x3f00_0000)
        };
        for (w, h) in [(1, 1), (1, 40), (33, 17), (64, 16), (256, 35)] {
            let n = w * h;
            let smooth: Vec<f32> = (0..n)
                .map(|i| ((i % w) as f32 * 0.01).sin() + (i / w) as f32 * 1e-3)
                .collect();
            let specials = [0.0, -0.0, f32::MIN_POSITIVE, 1e-45, f32::MAX, f32::MIN, 1.0, -1.0];
            let special: Vec<f32> = (0..n).map(|i| specials[i % specials.len()]).collect();
            let random: Vec<f32> = (0..n).map(|_| noise()).collect();
            let channels = vec![
                ("normal.Z", smooth.clone()),
                ("R", random),
                ("mask", vec![1.0; n]),
                ("B", special),
                ("A", vec![0.0; n]),
                ("G", smooth),
            ];
            let ours = encode_exr_channels(w, h, channels.clone()).unwrap();
            let theirs = encode_with_crate(w, h, &channels);
            let (header, decoded) = read_pedantic(&ours);
            let (their_header, their_decoded) = read_pedantic(&theirs);
            assert_eq!(header, their_header, "{w}×{h}: headers");
            assert_eq!(decoded, their_decoded, "{w}×{h}: samples");
            for (name, data) in &channels {
                let bits: Vec<u32> = data.iter().map(|v| v.to_bits()).collect();
                assert_eq!(decoded[*name], bits, "{w}×{h}: channel {name}");
            }
            let ratio = ours.len() as f64 / theirs.len() as f64;
            assert!(
                ratio < 1.03,
                "{w}×{h}: {} bytes against the crate's {}",
                ours.len(),
                theirs.len()
            );
        }
    }

    #[test]
    fn the_encoding_depends_only_on_the_data() {
        let data: Vec<f32> = (0..64 * 48).map(|i| (i as f32 * 0.37).cos()).collect();
        let a = encode_exr_channels(64, 48, vec![("R", data.clone()), ("G", data.clone())]).unwrap();
        let b =
            std::thread::spawn(move || encode_exr_channels(64, 48, vec![("G", data.clone()), ("R", data)]).unwrap())
                .join()
                .unwrap();
        assert_eq!(a, b);
    }
}

//! Size and encoding time of one dataset image under each EXR compression, with the exr crate's
//! writer, and with the factory's own ZIP16 writer (libdeflate; `io::encode_exr_channels`).
//! `cargo run --release -p matedit-contract --example exr_codecs -- FILE.exr`
use exr::prelude::*;
use std::time::Instant;

fn main() {
    let path = std::env::args().nth(1).expect("FILE.exr");
    let (w, h, ch) = matedit_contract::io::read_exr_channels(std::path::Path::new(&path)).unwrap();
    for (name, compression, blocks) in [
        ("ZIP16", Compression::ZIP16, Blocks::ScanLines),
        ("ZIP1", Compression::ZIP1, Blocks::ScanLines),
        ("RLE", Compression::RLE, Blocks::ScanLines),
        ("RLE tiles 64", Compression::RLE, Blocks::Tiles(Vec2(64, 64))),
        ("PIZ", Compression::PIZ, Blocks::ScanLines),
        ("none", Compression::Uncompressed, Blocks::ScanLines),
    ] {
        let mut times = Vec::new();
        let mut size = 0;
        for _ in 0..5 {
            let list: Vec<AnyChannel<FlatSamples>> = ch
                .iter()
                .map(|(n, d)| AnyChannel::new(n.as_str(), FlatSamples::F32(d.clone())))
                .collect();
            let layer = Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding {
                    compression,
                    blocks,
                    line_order: LineOrder::Increasing,
                },
                AnyChannels::sort(SmallVec::from_vec(list)),
            );
            let image = Image::from_layer(layer);
            let t = Instant::now();
            let mut buf = std::io::Cursor::new(Vec::new());
            image.write().non_parallel().to_buffered(&mut buf).unwrap();
            times.push(t.elapsed().as_secs_f64() * 1e3);
            size = buf.into_inner().len();
        }
        times.sort_by(|a, b| a.total_cmp(b));
        println!("{name:14} {size:8} bytes  {:.2} ms", times[2]);
    }
    let mut times = Vec::new();
    let mut size = 0;
    for _ in 0..5 {
        let list: Vec<(&str, Vec<f32>)> = ch.iter().map(|(n, d)| (n.as_str(), d.clone())).collect();
        let t = Instant::now();
        size = matedit_contract::io::encode_exr_channels(w, h, list).unwrap().len();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    println!("{:14} {size:8} bytes  {:.2} ms", "ZIP16 (ours)", times[2]);
}

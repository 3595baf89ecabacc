//! Seeds for the fuzz cases: files of the evaluation assets, hand-written Radiance files, a tiny
//! dataset, EXRs with unexpected channel sets.

use super::*;

/// The file at `path` if it exists (seeds from the eval assets are optional).
pub fn seed_file(path: &Path) -> Option<(String, Vec<u8>)> {
    // A real file can be megabytes: read under the lock, as every large seed is built.
    super::build_under_lock(|| std::fs::read(path).ok().map(|b| (path.display().to_string(), b)))
}

/// `../shared/eval-assets` (or `$MATEDIT_EVAL_ASSETS`), when present.
pub fn eval_assets() -> Option<PathBuf> {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let workspace = here
        .ancestors()
        .find(|a| a.join("Cargo.lock").is_file())
        .unwrap_or(here);
    let p = std::env::var_os("MATEDIT_EVAL_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace.join("../shared/eval-assets"));
    p.is_dir().then_some(p)
}

/// A Radiance file of `w × h` flat RGBE pixels, by hand (an independent writer).
pub fn radiance(w: usize, h: usize) -> Vec<u8> {
    let mut b = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y {h} +X {w}\n").into_bytes();
    for i in 0..w * h {
        b.extend_from_slice(&[(i * 7 % 256) as u8, 90, 200, 128 + (i % 3) as u8]);
    }
    b
}

/// A tiny dataset (16² images, DSBRDF files, no fitting), rendered once per process.
pub fn dataset() -> &'static Path {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        // Rendered in this process: under the lock, or its buffers would count against the
        // reader being fuzzed beside it (CI, 2026-11-27: 35 MB charged to a 92-byte .hdr).
        let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        let root = std::env::temp_dir().join(format!("matedit-fuzz-dataset-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let materials = [[0.8, 0.2, 0.1], [0.1, 0.5, 0.7], [0.4, 0.4, 0.4], [0.9, 0.9, 0.2]]
            .map(matedit_physics::brdf::Dsbrdf::near_lambertian);
        let manifest = include_str!("../../fixtures/manifests/fuzz.toml");
        let sources = matedit_fixtures::Sources {
            manifest,
            materials: &materials,
            objs: &[],
        };
        matedit_fixtures::render_dataset(&root, "m.toml", &sources, "dataset")
    })
}

#[allow(unused_imports)]
pub use matedit_fixtures::copy_dir as copy_tree;

/// EXRs of `w × h` whose channel sets a reader of RGB may not expect: R and G only, Y only,
/// RGB stored as f16 and as u32, RGB with an extra channel. Written with the exr crate
/// directly (the project's writer only writes f32).
pub fn odd_exrs(w: usize, h: usize) -> Vec<(String, Vec<u8>)> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage, f16,
    };
    let n = w * h;
    let ramp = |k: f32| (0..n).map(|i| (i as f32 * k).sin().abs()).collect::<Vec<f32>>();
    let f32s = |names: &[&str]| -> Vec<(String, FlatSamples)> {
        names
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), FlatSamples::F32(ramp(0.1 + k as f32 * 0.1))))
            .collect()
    };
    let sets: Vec<(&str, Vec<(String, FlatSamples)>)> = vec![
        ("R and G only", f32s(&["R", "G"])),
        ("Y only", f32s(&["Y"])),
        (
            "RGB as f16",
            ["R", "G", "B"]
                .iter()
                .map(|c| {
                    (
                        c.to_string(),
                        FlatSamples::F16(ramp(0.2).into_iter().map(f16::from_f32).collect()),
                    )
                })
                .collect(),
        ),
        (
            "RGB as u32",
            ["R", "G", "B"]
                .iter()
                .map(|c| (c.to_string(), FlatSamples::U32((0..n as u32).collect())))
                .collect(),
        ),
        ("RGB and Z", f32s(&["R", "G", "B", "Z"])),
    ];
    sets.into_iter()
        .map(|(label, channels)| {
            let list: Vec<AnyChannel<FlatSamples>> = channels
                .into_iter()
                .map(|(name, s)| AnyChannel::new(name.as_str(), s))
                .collect();
            let layer = Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding::SMALL_LOSSLESS,
                AnyChannels::sort(SmallVec::from_vec(list)),
            );
            let mut bytes = std::io::Cursor::new(Vec::new());
            Image::from_layer(layer)
                .write()
                .non_parallel()
                .to_buffered(&mut bytes)
                .expect("EXR");
            (format!("exr {label} {w}×{h}"), bytes.into_inner())
        })
        .collect()
}

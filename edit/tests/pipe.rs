//! `matedit edit | head -1`: a reader that closes the pipe early ends the output, not the
//! command; the edit is written all the same.

#![cfg(unix)]

use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, save};
use std::process::{Command, Stdio};

#[test]
fn an_edit_whose_reader_went_away_still_finishes_and_writes_everything() {
    let root = std::env::temp_dir().join(format!("matedit-pipe-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let device = Device::flex();
    let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(4);
    let net = cfg.init(&device);
    let model = save(
        &root.join("model"),
        "untrained",
        &net,
        &AdamConfig::new().init(),
        State::untrained(cfg, "untrained"),
    )
    .unwrap();
    let (w, h) = (48, 32);
    let inside = |x: u32, y: u32| {
        let (u, v) = ((x as f32 - 24.0) / 16.0, (y as f32 - 16.0) / 11.0);
        u * u + v * v < 1.0
    };
    let photo = image::RgbImage::from_fn(w, h, |x, y| {
        if inside(x, y) {
            image::Rgb([200, 120, 40])
        } else {
            image::Rgb([60, 90, 140])
        }
    });
    let mask = image::GrayImage::from_fn(w, h, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }]));
    photo.save(root.join("photo.png")).unwrap();
    mask.save(root.join("mask.png")).unwrap();
    let out = root.join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_matedit"))
        .args(["edit", "--material", "library:gold-polished", "--model"])
        .arg(&model)
        .arg("--image")
        .arg(root.join("photo.png"))
        .arg("--mask")
        .arg(root.join("mask.png"))
        .arg("--out")
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before the edit says anything.
    drop(child.stdout.take());
    let done = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&done.stderr);
    assert!(done.status.success(), "{:?}: {stderr}", done.status);
    assert!(!stderr.contains("panicked"), "{stderr}");
    for f in ["edited.png", "edited.exr", "report.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let _ = std::fs::remove_dir_all(&root);
}

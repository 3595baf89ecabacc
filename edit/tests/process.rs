//! `matedit` as a process: `serve` as a service manager runs it (SIGTERM ends the process within
//! its grace period, 10 s, even while a client holds an unfinished upload, and leaves no work
//! folder behind), and `edit | head -1` (a reader that closes the pipe early ends the output, not
//! the command; the edit is written all the same).

#![cfg(unix)]

use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, save};
use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// An untrained 16² checkpoint (4-row light) under `root`/model.
fn untrained_model(root: &Path) -> PathBuf {
    let device = Device::flex();
    let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(4);
    let net = cfg.init(&device);
    save(
        &root.join("model"),
        "untrained",
        &net,
        &AdamConfig::new().init(),
        State::untrained(cfg, "untrained"),
    )
    .unwrap()
}

#[test]
fn sigterm_ends_the_server_within_its_grace_period_whatever_clients_do() {
    let root = std::env::temp_dir().join(format!("matedit-sigterm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let model = untrained_model(&root);
    let tmp = root.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_matedit"))
        .args(["serve", "--port", "0", "--model"])
        .arg(&model)
        .env("TMPDIR", &tmp)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // "matedit serve: open http://127.0.0.1:PORT (Ctrl-C stops)"
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_string();
    // Two clients that stall: an upload that never ends, headers that never end.
    let mut upload = TcpStream::connect(&addr).unwrap();
    upload
        .write_all(
            b"POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\nx-matedit-page: 1\r\nContent-Length: 100000\r\n\r\n--b\r\n",
        )
        .unwrap();
    let mut headers = TcpStream::connect(&addr).unwrap();
    headers.write_all(b"GET /api/info HTTP/1.1\r\nHo").unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    let term = Command::new("kill")
        .arg("-TERM")
        .arg(child.id().to_string())
        .status()
        .unwrap();
    assert!(term.success());
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            panic!("still running {:?} after SIGTERM", t.elapsed());
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(status.success(), "{status:?}");
    assert!(t.elapsed() < Duration::from_secs(13), "took {:?}", t.elapsed());
    let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    drop((upload, headers));
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn an_edit_whose_reader_went_away_still_finishes_and_writes_everything() {
    let root = std::env::temp_dir().join(format!("matedit-pipe-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let model = untrained_model(&root);
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

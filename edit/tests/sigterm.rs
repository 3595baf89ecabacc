//! `matedit serve` as a service manager runs it: SIGTERM ends the process within its grace period
//! (10 s) even while a client holds an unfinished upload, and leaves no work folder behind.

#![cfg(unix)]

use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, save};
use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn sigterm_ends_the_server_within_its_grace_period_whatever_clients_do() {
    let root = std::env::temp_dir().join(format!("matedit-sigterm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
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

//! `matedit` as a process: `serve` as a service manager runs it (SIGTERM ends the process within
//! its grace period, 10 s, even while a client holds an unfinished upload, and leaves no work
//! folder behind, also when it comes while the model loads; at its open-file limit it waits
//! without spinning), and `edit | head -1` (a reader that closes the pipe early ends the output,
//! not the command; the edit is written all the same).

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
    let mut child = serve(&model, &tmp, None);
    let addr = address(&mut child);
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
    let status = wait_exit(&mut child, Duration::from_secs(20));
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
        // The photo as its own truth: scored, and the unchanged photo's scores are perfect.
        .arg("--truth")
        .arg(root.join("photo.png"))
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
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let t = &report["truth"];
    assert_eq!(
        (t["photo_l2"].as_f64(), t["photo_ssim"].as_f64()),
        (Some(0.0), Some(1.0)),
        "{t}"
    );
    assert!(t["l2"].as_f64().is_some_and(|v| v.is_finite() && v > 0.0), "{t}");
    let _ = std::fs::remove_dir_all(&root);
}

/// `matedit serve --port 0 --model MODEL` with `TMPDIR=tmp`, its open-file limit lowered to
/// `nofile` when given.
fn serve(model: &Path, tmp: &Path, nofile: Option<u64>) -> std::process::Child {
    use std::os::unix::process::CommandExt as _;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_matedit"));
    cmd.args(["serve", "--port", "0", "--model"])
        .arg(model)
        .env("TMPDIR", tmp)
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    if let Some(n) = nofile {
        // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
        unsafe {
            cmd.pre_exec(move || {
                let lim = libc::rlimit {
                    rlim_cur: n,
                    rlim_max: n,
                };
                if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    cmd.spawn().unwrap()
}

/// The address `matedit serve` says it listens on ("matedit serve: open http://127.0.0.1:PORT
/// (Ctrl-C stops)").
fn address(child: &mut std::process::Child) -> String {
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    line.split("http://")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_string()
}

fn wait_exit(child: &mut std::process::Child, limit: Duration) -> std::process::ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if t.elapsed() > limit {
            let _ = child.kill();
            panic!("still running {:?} after SIGTERM", t.elapsed());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn sigterm_at_any_moment_of_start_up_leaves_nothing_behind() {
    let root = std::env::temp_dir().join(format!("matedit-startup-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let model = untrained_model(&root);
    for delay_ms in [0, 5, 20, 50, 100, 200, 400] {
        let tmp = root.join(format!("tmp-{delay_ms}"));
        std::fs::create_dir_all(&tmp).unwrap();
        let mut child = serve(&model, &tmp, None);
        std::thread::sleep(Duration::from_millis(delay_ms));
        // SAFETY: a signal to our own child.
        assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
        let status = wait_exit(&mut child, Duration::from_secs(20));
        let left: Vec<_> = std::fs::read_dir(&tmp).unwrap().collect();
        assert!(
            left.is_empty(),
            "SIGTERM after {delay_ms} ms: left {left:?} ({status:?})"
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// Seconds of CPU the process `pid` has used (user and system).
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap();
    // After the command's name in parentheses: state is field 3, utime 14, stime 15.
    let rest = stat.rsplit(')').next().unwrap();
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap();
    // SAFETY: sysconf reads a constant.
    ticks / unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64
}

#[test]
fn at_its_open_file_limit_the_server_waits_without_spinning_and_serves_again() {
    let root = std::env::temp_dir().join(format!("matedit-emfile-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let model = untrained_model(&root);
    let tmp = root.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    let mut child = serve(&model, &tmp, Some(128));
    let addr = address(&mut child);
    // More idle connections than the process has descriptors.
    let idle: Vec<TcpStream> = (0..200).filter_map(|_| TcpStream::connect(&addr).ok()).collect();
    assert!(idle.len() >= 150, "{} connections", idle.len());
    std::thread::sleep(Duration::from_millis(500));
    let before = cpu_seconds(child.id());
    std::thread::sleep(Duration::from_secs(2));
    let used = cpu_seconds(child.id()) - before;
    assert!(
        used < 0.5,
        "the server used {used:.2} s of CPU in 2 s while out of descriptors"
    );
    drop(idle);
    let t = Instant::now();
    let mut s = TcpStream::connect(&addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    s.write_all(b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        .unwrap();
    let mut reply = String::new();
    let _ = std::io::Read::read_to_string(&mut s, &mut reply);
    assert!(reply.starts_with("HTTP/1.1 200"), "{reply:?}");
    assert!(t.elapsed() < Duration::from_secs(3), "served after {:?}", t.elapsed());
    // SAFETY: a signal to our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    wait_exit(&mut child, Duration::from_secs(20));
    let _ = std::fs::remove_dir_all(&root);
}

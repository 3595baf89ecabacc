//! The server with its default settings under the attacks of a hardening round: stalled and
//! slow uploads, a thin photo, malformed chunked bodies; its work folder's modes.

use super::*;

/// The defaults, on a free port.
fn defaults() -> ServeConfig {
    let mut cfg = ServeConfig::new(model().to_path_buf());
    cfg.port = 0;
    cfg
}

fn stall(addr: std::net::SocketAddr) -> TcpStream {
    let mut s = TcpStream::connect(addr).unwrap();
    let head = format!(
        "POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\n{PAGE_HEADER}: 1\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\nContent-Length: 1000000\r\n\r\n--{BOUNDARY}\r\n"
    );
    s.write_all(head.as_bytes()).unwrap();
    s
}

#[test]
fn with_the_defaults_stalled_uploads_delay_no_edit_and_are_closed_within_seconds() {
    let rt = runtime();
    let server = rt.block_on(start(defaults())).unwrap();
    let addr = server.addr;
    // 32 uploads that send their headers and a few bytes, and one that sends a byte a second.
    let stalled: Vec<TcpStream> = (0..32).map(|_| stall(addr)).collect();
    let mut dribbling = stall(addr);
    let dribble = std::thread::spawn(move || {
        for _ in 0..30 {
            if dribbling.write_all(b"x").is_err() {
                break;
            }
            std::thread::sleep(Duration::from_secs(1));
        }
        dribbling
    });
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    let (s, v) = post_gold_edit(addr);
    assert_eq!(s, 202, "{v}");
    assert!(t.elapsed() < Duration::from_secs(3), "accepted after {:?}", t.elapsed());
    // Every stalled upload is answered 408 (too slow) and closed within the grace period and
    // a second, not at the 60 s upload deadline.
    let t0 = Instant::now();
    for s in stalled {
        let mut s = s;
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        let text = String::from_utf8_lossy(&out);
        assert!(text.starts_with("HTTP/1.1 408"), "{text}");
        assert!(text.contains("slower than"), "{text}");
    }
    assert!(
        t0.elapsed() < Duration::from_secs(8),
        "stalled uploads held for {:?}",
        t0.elapsed()
    );
    let _ = dribble.join();
    let done = wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    rt.block_on(server.stop());
}

#[test]
fn with_the_defaults_a_thin_photo_is_answered_in_seconds() {
    // 4 × 1,000,000 pixels (4 MP, under the 25 MP limit): framing it once took hours.
    let (w, h) = (4u32, 1_000_000u32);
    let photo = png(image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 60) as u8, (y % 251) as u8, 90])
    }));
    let mask = png(image::GrayImage::from_fn(w, h, |_, y| {
        image::Luma([if y > 100 && y < h - 100 { 255 } else { 0 }])
    }));
    assert!(photo.len() < 4 << 20, "{} bytes", photo.len());
    let rt = runtime();
    let server = rt.block_on(start(defaults())).unwrap();
    let addr = server.addr;
    let t = Instant::now();
    let (s, v) = post_edit(addr, &Upload::gold(&photo, &mask).0);
    let ended = if s == 202 {
        wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"])
    } else {
        v
    };
    assert!(
        t.elapsed() < Duration::from_secs(20),
        "answered after {:?}: {ended}",
        t.elapsed()
    );
    let text = ended.to_string();
    assert!(text.contains("too small (or too thin)"), "{text}");
    assert!(!text.contains("matedit-serve-"), "a server path in {text}");
    rt.block_on(server.stop());
}

#[test]
fn a_malformed_chunked_body_is_the_requests_error() {
    let rt = runtime();
    let server = rt.block_on(start(defaults())).unwrap();
    for size in ["zz", "ffffffffffffffffffff"] {
        let mut s = TcpStream::connect(server.addr).unwrap();
        let req = format!(
            "POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\n{PAGE_HEADER}: 1\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\nTransfer-Encoding: chunked\r\n\r\n5\r\n--{BOUNDARY}\r\n{size}\r\nabc\r\n0\r\n\r\n"
        );
        s.write_all(req.as_bytes()).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut out = Vec::new();
        let _ = s.read_to_end(&mut out);
        let text = String::from_utf8_lossy(&out);
        assert!(text.starts_with("HTTP/1.1 400"), "chunk size {size}: {text}");
    }
    rt.block_on(server.stop());
}

#[cfg(unix)]
#[test]
fn the_work_folder_and_everything_in_it_is_this_users_alone() {
    use std::os::unix::fs::PermissionsExt as _;
    let rt = runtime();
    let work = dir("private-work").join("work");
    let mut cfg = defaults();
    cfg.work = Some(work.clone());
    let server = rt.block_on(start(cfg)).unwrap();
    let (s, v) = post_gold_edit(server.addr);
    assert_eq!(s, 202, "{v}");
    let done = wait_for(server.addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    let (dirs, files) = walk(&work);
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    for d in &dirs {
        assert_eq!(mode(d), 0o700, "{}", d.display());
    }
    for f in &files {
        assert_eq!(mode(f) & 0o077, 0, "{} is {:o}", f.display(), mode(f));
    }
    assert!(dirs.len() >= 3 && files.len() >= 5, "{dirs:?} {files:?}");
    // Another user (nobody, through setpriv where this runs as root) cannot list the folder or
    // read an upload.
    let upload = files.iter().find(|p| p.to_string_lossy().contains("/in/photo"));
    let setpriv = std::path::Path::new("/usr/bin/setpriv");
    // SAFETY: geteuid reads this process's id.
    if unsafe { libc::geteuid() } == 0 && setpriv.is_file() {
        let upload = upload.expect("the saved photo");
        for args in [
            vec!["ls".to_string(), work.display().to_string()],
            vec!["cat".to_string(), upload.display().to_string()],
        ] {
            let o = std::process::Command::new(setpriv)
                .args(["--reuid=65534", "--regid=65534", "--clear-groups", "--"])
                .args(&args)
                .output()
                .unwrap();
            assert!(!o.status.success(), "nobody could {args:?}");
            assert!(
                String::from_utf8_lossy(&o.stderr).contains("Permission denied"),
                "{o:?}"
            );
        }
    } else {
        eprintln!("not root (or no setpriv): the modes are checked, not another user's access");
    }
    rt.block_on(server.stop());
}

/// Every folder under `dir` (itself included) and every file.
fn walk(dir: &std::path::Path) -> (Vec<std::path::PathBuf>, Vec<std::path::PathBuf>) {
    let (mut dirs, mut files) = (Vec::new(), Vec::new());
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p);
            }
        }
        dirs.push(d);
    }
    (dirs, files)
}

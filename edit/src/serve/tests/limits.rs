//! The server's limits: a failed start leaves nothing, slow and stalled clients are cut off at
//! the deadlines, other hosts and origins are refused, kept edits stay within their disk budget,
//! edits are admitted by the memory their photos need.

use super::*;

#[test]
fn a_failed_start_leaves_no_work_folder_and_a_port_in_use_is_refused_first() {
    let rt = runtime();
    let temp = dir("failed-start");
    let empty = |what: &str| {
        let left: Vec<_> = std::fs::read_dir(&temp).unwrap().flatten().map(|e| e.path()).collect();
        assert!(left.is_empty(), "{what}: left {left:?}");
    };
    // A model folder that is no checkpoint.
    let mut bad = config(1);
    bad.model = temp.join("no-such-model");
    let e = rt.block_on(start_in(bad, &temp)).err().expect("a bad model starts");
    assert!(format!("{e:#}").contains("no-such-model"), "{e:#}");
    empty("bad model");
    // A port already in use: refused before the model loads, nothing left.
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let mut busy = config(1);
    busy.port = held.local_addr().unwrap().port();
    let e = rt.block_on(start_in(busy, &temp)).err().expect("a busy port starts");
    assert!(format!("{e:#}").contains("cannot listen"), "{e:#}");
    empty("port in use");
}

/// Reads whatever the server sends until it closes the connection (or `limit` passes); the
/// status of its response, if it sent one, and how long it took.
fn read_until_closed(mut s: TcpStream, limit: Duration) -> (Option<u16>, Duration) {
    let t = Instant::now();
    s.set_read_timeout(Some(limit)).unwrap();
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let status = String::from_utf8_lossy(&out)
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok());
    (status, t.elapsed())
}

#[test]
fn stalled_and_slow_clients_hold_nothing_for_longer_than_the_deadlines() {
    let rt = runtime();
    let mut cfg = config(4);
    cfg.deadlines = Deadlines {
        headers: Duration::from_secs(1),
        upload: Duration::from_secs(2),
        grace: Duration::from_secs(2),
        ..Deadlines::default()
    };
    let server = rt.block_on(start(cfg)).unwrap();
    let addr = server.addr;
    let t0 = Instant::now();
    // Six uploads that promise a megabyte, send a few bytes and go idle (more than the four
    // that are read at once); a client sending its headers a byte at a time; an idle one.
    let stalled: Vec<TcpStream> = (0..6)
        .map(|_| {
            let mut s = TcpStream::connect(addr).unwrap();
            let head = format!(
                "POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\n{PAGE_HEADER}: 1\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\nContent-Length: 1000000\r\n\r\n--{BOUNDARY}\r\n"
            );
            s.write_all(head.as_bytes()).unwrap();
            s
        })
        .collect();
    let dribble = std::thread::spawn(move || {
        let mut s = TcpStream::connect(addr).unwrap();
        let t = Instant::now();
        for b in b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" {
            if s.write_all(&[*b]).is_err() {
                break;
            }
            std::thread::sleep(Duration::from_millis(300));
        }
        (read_until_closed(s, Duration::from_secs(20)), t.elapsed())
    });
    let idle = TcpStream::connect(addr).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    // Meanwhile a real client is served: its edit is accepted at once (stalled uploads hold no
    // turn) and runs.
    let t = Instant::now();
    let (s, v) = post_gold_edit(addr);
    assert_eq!(s, 202, "{v}");
    assert!(t.elapsed() < Duration::from_secs(4), "accepted after {:?}", t.elapsed());
    let done = wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    // Every stalled upload is answered 408 and closed once its deadline is up; the idle
    // connection and the dribbling one are closed after the header deadline.
    for s in stalled {
        let (status, _) = read_until_closed(s, Duration::from_secs(20));
        assert_eq!(status, Some(408));
    }
    assert!(
        t0.elapsed() < Duration::from_secs(8),
        "stalled uploads held for {:?}",
        t0.elapsed()
    );
    let (_, idle_for) = read_until_closed(idle, Duration::from_secs(20));
    assert!(idle_for < Duration::from_secs(6), "an idle connection stayed open");
    let ((status, _), took) = dribble.join().unwrap();
    assert_ne!(status, Some(200), "headers a byte at a time were answered");
    assert!(
        took < Duration::from_secs(6),
        "a dribbling client held its connection {took:?}"
    );
    // Stopping with a stalled client connected ends within the grace period.
    let mut held = TcpStream::connect(addr).unwrap();
    held.write_all(b"POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100\r\n\r\nab")
        .unwrap();
    let t = Instant::now();
    rt.block_on(server.stop());
    assert!(t.elapsed() < Duration::from_secs(4), "stop took {:?}", t.elapsed());
}

#[test]
fn requests_naming_another_host_or_changes_from_another_origin_are_refused() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let addr = server.addr;
    let raw = |head: &str| {
        let mut s = TcpStream::connect(addr).unwrap();
        s.write_all(head.as_bytes()).unwrap();
        read_until_closed(s, Duration::from_secs(20)).0
    };
    // DNS rebinding: the attacker's name, resolving to 127.0.0.1.
    assert_eq!(
        raw("GET /api/info HTTP/1.1\r\nHost: evil.example:18080\r\nConnection: close\r\n\r\n"),
        Some(421)
    );
    assert_eq!(
        raw(&format!(
            "POST /api/jobs/x/cancel HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nOrigin: http://evil.example\r\n{PAGE_HEADER}: 1\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
            addr.port()
        )),
        Some(403)
    );
    assert_eq!(
        raw(&format!(
            "GET /api/info HTTP/1.1\r\nHost: localhost:{}\r\nConnection: close\r\n\r\n",
            addr.port()
        )),
        Some(200)
    );
    rt.block_on(server.stop());
}

#[test]
fn kept_edits_stay_within_their_disk_budget_the_newest_always_kept() {
    let rt = runtime();
    let work = dir("keep-bytes");
    let mut cfg = config(4);
    cfg.work = Some(work.clone());
    cfg.keep = 32;
    cfg.keep_bytes = 1; // smaller than any edit: only the newest stays
    let server = rt.block_on(start(cfg)).unwrap();
    let addr = server.addr;
    let mut urls = Vec::new();
    for _ in 0..3 {
        let (s, v) = post_gold_edit(addr);
        assert_eq!(s, 202, "{v}");
        let url = v["url"].as_str().unwrap().to_string();
        assert_eq!(wait_for(addr, &url, &["done", "failed"])["state"], "done");
        urls.push(url);
    }
    // The older edits and their folders are gone; the newest is served whole.
    for url in &urls[..2] {
        assert_eq!(http(addr, "GET", url, None, b"").0, 404, "{url}");
    }
    let (s, _) = http(addr, "GET", &format!("{}/files/edited.png", urls[2]), None, b"");
    assert_eq!(s, 200);
    let jobs: Vec<_> = std::fs::read_dir(&work)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_dir())
        .collect();
    assert_eq!(jobs.len(), 1, "{jobs:?}");
    rt.block_on(server.stop());
    let _ = std::fs::remove_dir_all(&work);
}

#[test]
fn edits_are_admitted_by_the_memory_their_photos_need() {
    let rt = runtime();
    let (photo, mask) = photo_and_mask();
    let parts = Upload::gold(&photo, &mask).0;
    let need = upload::memory_mb([photo.as_slice()], u64::MAX);
    assert_eq!(
        upload::memory_mb([photo.as_slice()], 100),
        64,
        "over the pixel limit: left to the pixel check"
    );
    assert_eq!(need, (60 * 40 * upload::EDIT_BYTES_PER_PIXEL).div_ceil(1 << 20) + 64);
    // A budget below one edit's need: refused by name, before decoding.
    let mut cfg = config(4);
    cfg.max_memory_mb = need - 1;
    let server = rt.block_on(start(cfg)).unwrap();
    let (s, v) = post_edit(server.addr, &parts);
    assert_eq!(s, 413, "{v}");
    assert!(v["error"].as_str().unwrap().contains("of memory"), "{v}");
    rt.block_on(server.stop());
    // A mask counts as a photo does, from its header: a large one is refused before decoding.
    let big_mask = png(image::GrayImage::new(4000, 4000));
    let mut cfg = config(4);
    cfg.max_pixels = 20_000_000;
    cfg.max_upload_bytes = 8 << 20;
    cfg.max_memory_mb = need + 10;
    let server = rt.block_on(start(cfg)).unwrap();
    let huge_mask = Upload::gold(&photo, &mask).with("mask", Some("huge-mask.png"), &big_mask);
    let (s, v) = post_edit(server.addr, &huge_mask.0);
    assert_eq!(s, 413, "{v}");
    assert!(v["error"].as_str().unwrap().contains("of memory"), "{v}");
    rt.block_on(server.stop());
    // A budget of one edit: edits one after another, each reservation given back at its end
    // (five in a row would wait forever otherwise).
    let mut cfg = config(4);
    cfg.max_memory_mb = need;
    let server = rt.block_on(start(cfg)).unwrap();
    for _ in 0..5 {
        let (s, v) = post_edit(server.addr, &parts);
        assert_eq!(s, 202, "{v}");
        let done = wait_for(server.addr, v["url"].as_str().unwrap(), &["done", "failed"]);
        assert_eq!(done["state"], "done", "{done}");
    }
    rt.block_on(server.stop());
}

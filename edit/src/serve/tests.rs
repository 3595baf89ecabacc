//! The server over real HTTP on 127.0.0.1: edits and transfers queue, run, report and serve
//! their files; the queue is bounded and shows places; waiting and running edits cancel; bad
//! uploads and hostile requests get their message and leave the server running.

use super::*;
use burn::optim::AdamConfig;
use burn::tensor::Device;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State as CkState, save};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("matedit-serve-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// An untrained 16² network with 4-row environments.
fn model() -> &'static Path {
    static M: OnceLock<PathBuf> = OnceLock::new();
    M.get_or_init(|| {
        let device = Device::flex();
        device.seed(5);
        let cfg = NetConfig::new(16, Widths::new(4, 16, 32, 8)).with_env_height(4);
        let net = cfg.init(&device);
        save(
            &dir("model"),
            "untrained",
            &net,
            &AdamConfig::new().init(),
            CkState::untrained(cfg, "untrained"),
        )
        .unwrap()
    })
}

fn png(img: impl Into<image::DynamicImage>) -> Vec<u8> {
    let mut v = Vec::new();
    img.into()
        .write_to(&mut std::io::Cursor::new(&mut v), image::ImageFormat::Png)
        .unwrap();
    v
}

/// A 60×40 photo with an orange ellipse, and its mask.
fn photo_and_mask() -> (Vec<u8>, Vec<u8>) {
    let inside = |x: u32, y: u32| {
        let (u, v) = ((x as f64 - 30.0) / 20.0, (y as f64 - 22.0) / 12.0);
        u * u + v * v <= 1.0
    };
    let photo = image::RgbImage::from_fn(60, 40, |x, y| {
        if inside(x, y) {
            image::Rgb([200, 120 + (x % 7) as u8, 40])
        } else {
            image::Rgb([(x * 4) as u8, 100, (y * 5) as u8])
        }
    });
    let mask = image::GrayImage::from_fn(60, 40, |x, y| image::Luma([if inside(x, y) { 255 } else { 0 }]));
    (png(photo), png(mask))
}

/// One request with `Connection: close`; the status and body.
fn http(addr: SocketAddr, method: &str, path: &str, content_type: Option<&str>, body: &[u8]) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let mut head = format!(
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nContent-Length: {}\r\n{PAGE_HEADER}: 1\r\n",
        body.len()
    );
    if let Some(t) = content_type {
        head += &format!("Content-Type: {t}\r\n");
    }
    head += "\r\n";
    s.write_all(head.as_bytes()).unwrap();
    // The server may answer (413) before reading everything.
    let _ = s.write_all(body);
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let text_end = out.windows(4).position(|w| w == b"\r\n\r\n").expect("an HTTP response");
    let head = String::from_utf8_lossy(&out[..text_end]).to_string();
    let status: u16 = head.split(' ').nth(1).unwrap().parse().unwrap();
    let mut body = out[text_end + 4..].to_vec();
    if head.to_ascii_lowercase().contains("transfer-encoding: chunked") {
        body = unchunk(&body);
    }
    (status, body)
}

fn unchunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let n = usize::from_str_radix(String::from_utf8_lossy(&b[..eol]).trim(), 16).unwrap_or(0);
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 2 + n + 2..];
    }
}

fn json_of(body: &[u8]) -> Value {
    serde_json::from_slice(body).unwrap_or_else(|_| panic!("not JSON: {}", String::from_utf8_lossy(body)))
}

/// Multipart parts: `(name, Some(file name), bytes)` for files, `(name, None, text)` for fields.
type Parts<'a> = Vec<(&'a str, Option<&'a str>, &'a [u8])>;

const BOUNDARY: &str = "matedit-test-boundary";

/// A multipart body: `(name, Some(file name), bytes)` for files, `(name, None, text)` for fields.
fn multipart(parts: &[(&str, Option<&str>, &[u8])]) -> Vec<u8> {
    let mut b = Vec::new();
    for (name, file, bytes) in parts {
        b.extend(format!("--{BOUNDARY}\r\n").as_bytes());
        match file {
            Some(f) => b.extend(
                format!("Content-Disposition: form-data; name=\"{name}\"; filename=\"{f}\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes(),
            ),
            None => b.extend(format!("Content-Disposition: form-data; name=\"{name}\"\r\n\r\n").as_bytes()),
        }
        b.extend(*bytes);
        b.extend(b"\r\n");
    }
    b.extend(format!("--{BOUNDARY}--\r\n").as_bytes());
    b
}

fn post_edit(addr: SocketAddr, parts: &[(&str, Option<&str>, &[u8])]) -> (u16, Value) {
    let (s, b) = http(
        addr,
        "POST",
        "/api/edit",
        Some(&format!("multipart/form-data; boundary={BOUNDARY}")),
        &multipart(parts),
    );
    (s, json_of(&b))
}

fn wait_for(addr: SocketAddr, url: &str, states: &[&str]) -> Value {
    let t = Instant::now();
    loop {
        let (s, b) = http(addr, "GET", url, None, b"");
        assert_eq!(s, 200);
        let v = json_of(&b);
        if states.contains(&v["state"].as_str().unwrap_or("")) {
            return v;
        }
        assert!(t.elapsed() < Duration::from_secs(120), "stuck: {v}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

fn config(queue: usize) -> ServeConfig {
    let mut cfg = ServeConfig::new(model().to_path_buf());
    cfg.port = 0;
    cfg.queue = queue;
    cfg.max_upload_bytes = 256 << 10;
    cfg.max_pixels = 1_000_000;
    cfg
}

#[test]
fn an_edit_matches_the_command_line_and_serves_only_its_own_files() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let addr = server.addr;
    let (photo, mask) = photo_and_mask();
    let (s, v) = post_edit(
        addr,
        &[
            ("photo", Some("car.png"), &photo),
            ("mask", Some("car-mask.png"), &mask),
            ("material", None, b"library:gold-polished"),
            ("optimize", None, b"on"),
        ],
    );
    assert_eq!(s, 202, "{v}");
    let url = v["url"].as_str().unwrap().to_string();
    let done = wait_for(addr, &url, &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    // Eq. 6 reported live: from the network's prediction, never increasing.
    let e: Vec<f64> = done["energies"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert!(e.len() > 1 && e.windows(2).all(|w| w[1] <= w[0]), "{e:?}");
    assert_eq!(
        done["report"]["photo"], "photo “car.png”",
        "the report names the upload, not the server's path"
    );
    // Byte for byte what `matedit edit` writes for the same inputs.
    let d = dir("cli");
    std::fs::write(d.join("p.png"), &photo).unwrap();
    std::fs::write(d.join("m.png"), &mask).unwrap();
    let req = EditRequest {
        photo: d.join("p.png"),
        mask: Some(d.join("m.png")),
        materials: vec![(None, "library:gold-polished".into())],
        optimize: Some(Eq6Config::default()),
        ..EditRequest::default()
    };
    crate::edit(model(), &req, &d.join("out")).unwrap();
    for f in [
        "edited.png",
        "o_prime.exr",
        "normals.exr",
        "env.exr",
        "material.dsbrdf.json",
    ] {
        let (s, b) = http(addr, "GET", &format!("{url}/files/{f}"), None, b"");
        assert_eq!(s, 200, "{f}");
        assert_eq!(
            b,
            std::fs::read(d.join("out").join(f)).unwrap(),
            "{f} differs from the command line's"
        );
    }
    let (s, b) = http(addr, "GET", &format!("{url}/files/report.json"), None, b"");
    assert_eq!((s, json_of(&b)["composite"].as_str()), (200, Some("detail")));
    // The page's information names the model by its run's part of the path only.
    let (s, b) = http(addr, "GET", "/api/info", None, b"");
    let info = json_of(&b);
    assert_eq!(s, 200);
    let shown = info["checkpoint"].as_str().unwrap();
    assert!(model().ends_with(shown) && shown.split('/').count() <= 3, "{shown}");
    let (s, b) = http(addr, "GET", &format!("{url}/files/report.json"), None, b"");
    assert_eq!(s, 200);
    // The report a user downloads names the uploads and the model's folder, no server path.
    let text = String::from_utf8_lossy(&b);
    let model_dir = model().display().to_string();
    assert!(
        !text.contains(&model_dir) && !text.contains("matedit-serve-") && !text.contains("/in/"),
        "{text}"
    );
    assert_eq!(json_of(&b)["photo"], "photo “car.png”");
    // Nothing else is reachable.
    for bad in [
        format!("{url}/files/..%2F..%2Fin%2Fphoto.png"),
        format!("{url}/files/%2Fetc%2Fpasswd"),
        format!("{url}/files/in"),
        format!("{url}/files/"),
        "/api/jobs/0123456789abcdef01234567/files/edited.png".to_string(),
        "/api/jobs/..%2F..%2F/files/edited.png".to_string(),
        "/etc/passwd".to_string(),
    ] {
        let (s, _) = http(addr, "GET", &bad, None, b"");
        assert_eq!(s, 404, "{bad}");
    }
    let (s, b) = http(addr, "GET", &format!("{url}/files/edited.png?download"), None, b"");
    assert_eq!(s, 200);
    assert!(b.starts_with(b"\x89PNG"));
    rt.block_on(server.stop());
}

#[test]
fn a_transfer_takes_the_material_of_the_other_photo() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let (photo, mask) = photo_and_mask();
    let (s, v) = post_edit(
        server.addr,
        &[
            ("photo", Some("to.png"), &photo),
            ("mask", Some("to-mask.png"), &mask),
            ("source", Some("from.png"), &photo),
            ("source_mask", Some("from-mask.png"), &mask),
        ],
    );
    assert_eq!(s, 202, "{v}");
    let done = wait_for(server.addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["report"]["regions"][0]["spec"], "m' of source “from.png”");
    rt.block_on(server.stop());
}

#[test]
fn the_queue_is_bounded_shows_places_and_cancels_waiting_and_running_edits() {
    let rt = runtime();
    let mut cfg = config(1);
    // An Eq. 6 long enough to be caught running.
    cfg.eq6.rounds = 1_000_000; // never ends by itself: only Cancel stops it
    cfg.eq6.iterations = 50;
    let server = rt.block_on(start(cfg)).unwrap();
    let addr = server.addr;
    let (photo, mask) = photo_and_mask();
    let parts: [(&str, Option<&str>, &[u8]); 4] = [
        ("photo", Some("p.png"), &photo),
        ("mask", Some("m.png"), &mask),
        ("material", None, b"lambert:0.2,0.5,0.8"),
        ("optimize", None, b"on"),
    ];
    let (_, a) = post_edit(addr, &parts);
    let a_url = a["url"].as_str().unwrap().to_string();
    // Running and past its first Eq. 6 iterations.
    let t = Instant::now();
    loop {
        let v = wait_for(addr, &a_url, &["running"]);
        if v["phase"] == "eq6" && v["energies"].as_array().unwrap().len() > 2 {
            break;
        }
        assert!(t.elapsed() < Duration::from_secs(60));
    }
    let (s, b) = post_edit(addr, &parts);
    assert_eq!((s, b["place"].as_u64()), (202, Some(1)), "{b}");
    let b_url = b["url"].as_str().unwrap().to_string();
    assert_eq!(wait_for(addr, &b_url, &["queued"])["place"], 1);
    let (s, c) = post_edit(addr, &parts);
    assert_eq!(s, 503, "{c}");
    assert!(c["error"].as_str().unwrap().contains("waiting already"), "{c}");
    // Cancelling the waiting one, then the running one.
    let (s, _) = http(addr, "POST", &format!("{b_url}/cancel"), None, b"");
    assert_eq!(s, 200);
    assert_eq!(wait_for(addr, &b_url, &["cancelled"])["state"], "cancelled");
    let t = Instant::now();
    let (s, _) = http(addr, "POST", &format!("{a_url}/cancel"), None, b"");
    assert_eq!(s, 200);
    assert_eq!(wait_for(addr, &a_url, &["cancelled", "done"])["state"], "cancelled");
    assert!(
        t.elapsed() < Duration::from_secs(10),
        "cancelling took {:?}",
        t.elapsed()
    );
    // The worker is free again.
    let (s, d) = post_edit(addr, &parts[..3]);
    assert_eq!(s, 202, "{d}");
    assert_eq!(
        wait_for(addr, d["url"].as_str().unwrap(), &["done", "failed"])["state"],
        "done"
    );
    rt.block_on(server.stop());
}

#[test]
fn bad_uploads_get_their_message_and_the_server_keeps_running() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let addr = server.addr;
    let (photo, mask) = photo_and_mask();
    let blank = png(image::GrayImage::new(60, 40));
    let full = png(image::GrayImage::from_pixel(60, 40, image::Luma([255])));
    let other_size = png(image::GrayImage::from_pixel(30, 20, image::Luma([255])));
    let exr_mask = {
        let p = dir("exr").join("m.exr");
        matedit_contract::io::write_exr_channels(&p, 60, 40, vec![("Y", vec![1.0; 2400])]).unwrap();
        std::fs::read(&p).unwrap()
    };
    // A small PNG whose header claims 100000 × 100000 pixels (ten gigapixels).
    let mut huge = photo.clone();
    huge[16..20].copy_from_slice(&100_000u32.to_be_bytes());
    huge[20..24].copy_from_slice(&100_000u32.to_be_bytes());
    let crc = crc32(&huge[12..29]);
    huge[29..33].copy_from_slice(&crc.to_be_bytes());
    let truncated = photo[..photo.len() / 2].to_vec();
    // An EXR photo of many channels (each would be decoded in full).
    let many = {
        let p = dir("exr").join("many.exr");
        let names: Vec<String> = (0..40).map(|k| format!("c{k:02}")).collect();
        let ch: Vec<(&str, Vec<f32>)> = names.iter().map(|n| (n.as_str(), vec![0.5; 2400])).collect();
        matedit_contract::io::write_exr_channels(&p, 60, 40, ch).unwrap();
        std::fs::read(&p).unwrap()
    };
    // The same photo as JPEG, EXR and HDR, each cut short (every photo format the page takes).
    let rgb = image::load_from_memory(&photo).unwrap().to_rgb8();
    let mut jpeg = Vec::new();
    image::DynamicImage::ImageRgb8(rgb.clone())
        .write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .unwrap();
    let linear = image::DynamicImage::ImageRgb8(rgb).to_rgb32f();
    let exr = {
        let p = dir("exr").join("photo.exr");
        let plane = |c: usize| linear.pixels().map(|px| px[c]).collect::<Vec<f32>>();
        matedit_contract::io::write_exr_channels(&p, 60, 40, vec![("R", plane(0)), ("G", plane(1)), ("B", plane(2))])
            .unwrap();
        std::fs::read(&p).unwrap()
    };
    let mut hdr = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut hdr)
        .encode(&linear.pixels().copied().collect::<Vec<_>>(), 60, 40)
        .unwrap();
    let cut = |b: &[u8]| b[..b.len() * 3 / 4].to_vec();
    let (cut_jpeg, cut_exr, cut_hdr) = (cut(&jpeg), cut(&exr), cut(&hdr));
    let gold: &[u8] = b"library:gold-polished";
    let mut cases: Vec<(Parts, u16, &str)> = vec![
        (vec![("material", None, gold)], 422, "no photo"),
        (
            vec![("photo", Some("a.png"), b"hello"), ("material", None, gold)],
            422,
            "“a.png”: not a PNG, JPEG, EXR or HDR image",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &blank),
                ("material", None, gold),
            ],
            422,
            "the mask is empty",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &full),
                ("material", None, gold),
            ],
            422,
            "covers the whole photo",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &other_size),
                ("material", None, gold),
            ],
            422,
            "must match pixel for pixel",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.exr"), &exr_mask),
                ("material", None, gold),
            ],
            422,
            "masks must be PNG or JPEG",
        ),
        (
            vec![("photo", Some("p.png"), &photo), ("material", None, gold)],
            422,
            "no mask given and the photo has no alpha channel",
        ),
        (
            vec![
                ("photo", Some("big.png"), &huge),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
            422,
            "100000×100000 is 10000.0 megapixels, more than this server's limit of 1.0",
        ),
        (
            vec![
                ("photo", Some("many.exr"), &many),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
            422,
            "with 40 channels",
        ),
        (
            vec![
                ("photo", Some("nothing.png"), b""),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
            422,
            "“nothing.png” is empty (0 bytes)",
        ),
        (
            vec![
                ("photo", Some("half.png"), &truncated),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
            422,
            "“half.png”",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &mask),
                ("material", None, b"dsbrdf:/etc/passwd"),
            ],
            422,
            "file specs are not accepted",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &mask),
                ("material", None, b"library:../../x"),
            ],
            422,
            "no such library material",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &mask),
                ("material", None, b"lambert:2,nan,0"),
            ],
            422,
            "lambert",
        ),
        (
            vec![("photo", Some("p.png"), &photo), ("mask", Some("m.png"), &mask)],
            422,
            "no material",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
                ("source", Some("s.png"), &photo),
            ],
            422,
            "not both",
        ),
        (
            vec![
                ("photo", Some("p.png"), &photo),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
                ("composite", None, b"blend"),
            ],
            400,
            "expected detail, shading, delta, render or ratio",
        ),
        (
            vec![("photo", Some("p.png"), &photo), ("path", None, b"/etc/passwd")],
            400,
            "unexpected field",
        ),
    ];
    for (name, bytes) in [("cut.jpg", &cut_jpeg), ("cut.exr", &cut_exr), ("cut.hdr", &cut_hdr)] {
        cases.push((
            vec![
                ("photo", Some(name), bytes),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
            422,
            name,
        ));
    }
    // The whole files are edited.
    for (name, bytes) in [("whole.jpg", &jpeg), ("whole.exr", &exr), ("whole.hdr", &hdr)] {
        let (s, v) = post_edit(
            addr,
            &[
                ("photo", Some(name), bytes),
                ("mask", Some("m.png"), &mask),
                ("material", None, gold),
            ],
        );
        assert_eq!(s, 202, "{name}: {v}");
        let done = wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"]);
        assert_eq!(done["state"], "done", "{name}: {done}");
    }
    for (parts, status, needle) in &cases {
        let (s, v) = post_edit(addr, parts);
        let msg = v["error"].as_str().unwrap_or_default();
        assert_eq!(s, *status, "{needle}: {v}");
        assert!(msg.contains(needle), "expected “{needle}” in: {msg}");
        assert!(
            !msg.contains("/tmp") && !msg.contains("matedit-serve"),
            "a server path leaked: {msg}"
        );
    }
    // Not multipart at all, a broken multipart body, and one over the size limit.
    let (s, _) = http(addr, "POST", "/api/edit", Some("text/plain"), b"photo=1");
    assert!((400..500).contains(&s), "{s}");
    let (s, _) = http(
        addr,
        "POST",
        "/api/edit",
        Some(&format!("multipart/form-data; boundary={BOUNDARY}")),
        b"--matedit-test-boundary\r\nContent-Disposition: form-data; name=\"photo\"\r\n\r\nabc",
    );
    assert_eq!(s, 400);
    let big = vec![0x89u8; 300 << 10];
    let (s, v) = post_edit(addr, &[("photo", Some("p.png"), &big)]);
    assert_eq!(s, 413, "{v}");
    assert!(v["error"].as_str().unwrap().contains("larger than this server accepts"));
    // Without the page's header (what another site's page would send): refused.
    let mut raw = TcpStream::connect(addr).unwrap();
    let body = multipart(&[
        ("photo", Some("p.png"), &photo),
        ("mask", Some("m.png"), &mask),
        ("material", None, gold),
    ]);
    write!(
        raw,
        "POST /api/edit HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\nContent-Type: multipart/form-data; boundary={BOUNDARY}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    let _ = raw.write_all(&body);
    let mut answer = String::new();
    let _ = raw.read_to_string(&mut answer);
    assert!(
        answer.starts_with("HTTP/1.1 403") && answer.contains(PAGE_HEADER),
        "{answer}"
    );
    let (s, _) = http(addr, "GET", "/api/jobs/nope", None, b"");
    assert_eq!(s, 404);
    let (s, _) = http(addr, "POST", "/api/jobs/nope/cancel", None, b"");
    assert_eq!(s, 404);
    let (s, _) = http(addr, "GET", "/api/library/no-such/sphere.png", None, b"");
    assert_eq!(s, 404);
    // Still serving.
    let (s, b) = http(addr, "GET", "/api/info", None, b"");
    assert_eq!(s, 200);
    assert_eq!(json_of(&b)["input_size"], 16);
    let (s, b) = http(addr, "GET", "/", None, b"");
    assert_eq!(s, 200);
    assert!(String::from_utf8_lossy(&b).contains("matedit — material editing"));
    rt.block_on(server.stop());
}

#[test]
fn library_spheres_are_rendered_once_and_shown_as_png() {
    let lib = library::Library::default();
    let a = lib.thumbnail("gold-polished").unwrap().unwrap();
    let b = lib.thumbnail("gold-polished").unwrap().unwrap();
    assert_eq!(a, b);
    let img = image::load_from_memory(&a).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (64, 64));
    // Gold: red above blue at the sphere's centre, transparent corners.
    let c = img.get_pixel(32, 32);
    assert!(c[0] > c[2] && c[3] == 255, "{c:?}");
    assert_eq!(img.get_pixel(0, 0)[3], 0);
    assert!(lib.thumbnail("no-such-material").is_none());
    let list = library::Library::list();
    assert!(list.as_array().unwrap().len() > 20);
}

#[test]
fn uploads_are_told_apart_by_content_not_name() {
    let (photo, _) = photo_and_mask();
    assert_eq!(upload::sniff(&photo), Some("png"));
    assert_eq!(upload::sniff(b"\xff\xd8\xff\xe0rest"), Some("jpg"));
    assert_eq!(upload::sniff(b"#?RADIANCE\n"), Some("hdr"));
    assert_eq!(upload::sniff(&[0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0]), Some("exr"));
    assert_eq!(upload::sniff(b"GIF89a"), None);
    assert_eq!(upload::sniff(b""), None);
    assert_eq!(upload::display_name("../../etc/passwd"), "passwd");
    assert_eq!(upload::display_name("C:\\photos\\car.jpg"), "car.jpg");
    assert_eq!(upload::display_name("\u{1b}[31m"), "[31m");
    assert_eq!(upload::display_name(""), "upload");
}

/// CRC-32 (PNG's) for the forged header.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

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
    // Meanwhile a real client is served: its edit is accepted within the upload deadline
    // (it waits for a reading turn at most that long) and runs.
    let (photo, mask) = photo_and_mask();
    let t = Instant::now();
    let (s, v) = post_edit(
        addr,
        &[
            ("photo", Some("car.png"), &photo),
            ("mask", Some("car-mask.png"), &mask),
            ("material", None, b"library:gold-polished"),
        ],
    );
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
    let (photo, mask) = photo_and_mask();
    let mut urls = Vec::new();
    for _ in 0..3 {
        let (s, v) = post_edit(
            addr,
            &[
                ("photo", Some("car.png"), &photo),
                ("mask", Some("car-mask.png"), &mask),
                ("material", None, b"library:gold-polished"),
            ],
        );
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
    let parts: [(&str, Option<&str>, &[u8]); 3] = [
        ("photo", Some("car.png"), &photo),
        ("mask", Some("car-mask.png"), &mask),
        ("material", None, b"library:gold-polished"),
    ];
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

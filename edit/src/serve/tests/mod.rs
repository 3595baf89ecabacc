//! The server over real HTTP on 127.0.0.1: edits and transfers queue, run, report and serve
//! their files; the queue is bounded and shows places; waiting and running edits cancel; bad
//! uploads and hostile requests get their message and leave the server running.

use super::*;
use crate::EditRequest;
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

mod defaults;
mod edits;
mod limits;
mod uploads;

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

/// An upload's parts, made from one of the requests here by putting a field in place (or at the
/// end), or leaving one out: what most tests send differs from these in a field or two.
#[derive(Clone)]
struct Upload<'a>(Parts<'a>);

impl<'a> Upload<'a> {
    /// `photo` (as p.png) inside `mask` (m.png) edited to polished gold.
    fn gold(photo: &'a [u8], mask: &'a [u8]) -> Self {
        Upload(vec![
            ("photo", Some("p.png"), photo),
            ("mask", Some("m.png"), mask),
            ("material", None, b"library:gold-polished"),
        ])
    }

    /// `photo` (to.png, inside `mask`) given the material of the same photo as the source
    /// (from.png): a transfer.
    fn transfer(photo: &'a [u8], mask: &'a [u8]) -> Self {
        Upload(vec![
            ("photo", Some("to.png"), photo),
            ("mask", Some("to-mask.png"), mask),
            ("source", Some("from.png"), photo),
            ("source_mask", Some("from-mask.png"), mask),
        ])
    }

    /// With `field` set to `bytes` (a file named `file`, or a text field where `None`).
    fn with(mut self, field: &'a str, file: Option<&'a str>, bytes: &'a [u8]) -> Self {
        match self.0.iter_mut().find(|p| p.0 == field) {
            Some(p) => *p = (field, file, bytes),
            None => self.0.push((field, file, bytes)),
        }
        self
    }

    /// The parts of this upload with `field` set to `bytes`.
    fn parts_with(&self, field: &'a str, file: Option<&'a str>, bytes: &'a [u8]) -> Parts<'a> {
        self.clone().with(field, file, bytes).0
    }

    /// Without `field`.
    fn without(mut self, field: &str) -> Self {
        self.0.retain(|p| p.0 != field);
        self
    }
}

/// The test photo and its mask edited to polished gold: the edit most tests queue.
fn post_gold_edit(addr: SocketAddr) -> (u16, Value) {
    let (photo, mask) = photo_and_mask();
    post_edit(addr, &Upload::gold(&photo, &mask).0)
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

//! Bad uploads get their message and the server keeps running.

use super::*;

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
    let gold = Upload::gold(&photo, &mask);
    let mut cases: Vec<(Parts, u16, &str)> = vec![
        (vec![("material", None, b"library:gold-polished")], 422, "no photo"),
        (
            gold.clone().without("mask").with("photo", Some("a.png"), b"hello").0,
            422,
            "“a.png”: not a PNG, JPEG, EXR or HDR image",
        ),
        (gold.parts_with("mask", Some("m.png"), &blank), 422, "the mask is empty"),
        (
            gold.parts_with("mask", Some("m.png"), &full),
            422,
            "covers the whole photo",
        ),
        (
            gold.parts_with("mask", Some("m.png"), &other_size),
            422,
            "must match pixel for pixel",
        ),
        (
            gold.parts_with("mask", Some("m.exr"), &exr_mask),
            422,
            "masks must be PNG or JPEG",
        ),
        (
            gold.clone().without("mask").0,
            422,
            "no mask given and the photo has no alpha channel",
        ),
        (
            gold.parts_with("normals", Some("n.png"), &other_size),
            422,
            "normals “n.png”: the normal map is 30×20, the photo 60×40",
        ),
        (
            gold.parts_with("normals", Some("n.png"), &photo),
            422,
            "face away from the camera",
        ),
        (
            gold.parts_with("normals", Some("n.exr"), &exr_mask),
            422,
            "needs channels X, Y, Z or R, G, B",
        ),
        (
            gold.parts_with("normals", Some("n.jpg"), &jpeg),
            422,
            "normal maps must be EXR or PNG images, this is JPG",
        ),
        (
            gold.clone()
                .without("material")
                .with("source", Some("s.png"), &photo)
                .with("normals", Some("n.png"), &other_size)
                .0,
            422,
            "n.png",
        ),
        (
            gold.parts_with("photo", Some("big.png"), &huge),
            422,
            "100000×100000 is 10000.0 megapixels, more than this server's limit of 1.0",
        ),
        (
            gold.parts_with("photo", Some("many.exr"), &many),
            422,
            "with 40 channels",
        ),
        (
            gold.parts_with("photo", Some("nothing.png"), b""),
            422,
            "“nothing.png” is empty (0 bytes)",
        ),
        (
            gold.parts_with("photo", Some("half.png"), &truncated),
            422,
            "“half.png”",
        ),
        (
            gold.parts_with("material", None, b"dsbrdf:/etc/passwd"),
            422,
            "file specs are not accepted",
        ),
        (
            gold.parts_with("material", None, b"library:../../x"),
            422,
            "no such library material",
        ),
        (gold.parts_with("material", None, b"lambert:2,nan,0"), 422, "lambert"),
        (gold.clone().without("material").0, 422, "no material"),
        (
            gold.parts_with("input_material", None, b"lambert:nope"),
            422,
            "the object's own material",
        ),
        (
            gold.clone()
                .with("input_material", None, b"lambert:0.2,0.2,0.2")
                .with("optimize", None, b"on")
                .0,
            422,
            "Eq. 6 would change it",
        ),
        (
            gold.clone()
                .without("material")
                .with("source", Some("s.png"), &photo)
                .with("input_material", None, b"lambert:0.2,0.2,0.2")
                .with("optimize", None, b"on")
                .0,
            422,
            "Eq. 6 would change it",
        ),
        (gold.parts_with("source", Some("s.png"), &photo), 422, "not both"),
        (
            gold.parts_with("composite", None, b"blend"),
            400,
            "expected structure, detail, shading, delta, render or ratio",
        ),
        (
            vec![("photo", Some("p.png"), &photo), ("path", None, b"/etc/passwd")],
            400,
            "unexpected field",
        ),
    ];
    for (name, bytes) in [("cut.jpg", &cut_jpeg), ("cut.exr", &cut_exr), ("cut.hdr", &cut_hdr)] {
        cases.push((gold.parts_with("photo", Some(name), bytes), 422, name));
    }
    // The whole files are edited.
    for (name, bytes) in [("whole.jpg", &jpeg), ("whole.exr", &exr), ("whole.hdr", &hdr)] {
        let (s, v) = post_edit(addr, &gold.parts_with("photo", Some(name), bytes));
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
    let body = multipart(&gold.0);
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

//! Edits and transfers over HTTP: the same result as the command line, only their own files
//! served; the queue bounded, places shown, waiting and running edits cancelled; library spheres
//! rendered once; uploads told apart by content.

use super::*;

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
    assert_eq!((s, json_of(&b)["composite"].as_str()), (200, Some("structure")));
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
    let (s, v) = post_edit(server.addr, &Upload::transfer(&photo, &mask).0);
    assert_eq!(s, 202, "{v}");
    let done = wait_for(server.addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    assert_eq!(done["report"]["regions"][0]["spec"], "m' of source “from.png”");
    rt.block_on(server.stop());
}

#[test]
fn a_transfer_takes_the_receiving_objects_own_material_and_normals() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let (photo, mask) = photo_and_mask();
    let facing = png(image::RgbImage::from_pixel(60, 40, image::Rgb([128, 128, 255])));
    let upload = Upload::transfer(&photo, &mask)
        .with("input_material", None, b"plastic:0.1:0.6,0.1,0.1")
        .with("normals", Some("to-normals.png"), &facing);
    let (s, v) = post_edit(server.addr, &upload.0);
    assert_eq!(s, 202, "{v}");
    let done = wait_for(server.addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    let report = &done["report"];
    assert_eq!(report["regions"][0]["spec"], "m' of source “from.png”", "{report}");
    assert_eq!(report["input_material"], "plastic:0.1:0.6,0.1,0.1", "{report}");
    assert_eq!(report["light_level"]["source"], "input material", "{report}");
    assert_eq!(report["composite"], "ratio", "{report}");
    assert_eq!(report["normals"]["detail_pixels_kept"], 0, "{report}");
    assert!(
        report["normals"]["path"].as_str().unwrap().contains("to-normals.png"),
        "{report}"
    );
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
    let parts = Upload::gold(&photo, &mask)
        .with("material", None, b"lambert:0.2,0.5,0.8")
        .with("optimize", None, b"on")
        .0;
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

#[test]
fn the_objects_normals_reach_the_edit() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let addr = server.addr;
    let (photo, mask) = photo_and_mask();
    let facing = png(image::RgbImage::from_pixel(60, 40, image::Rgb([128, 128, 255])));
    let upload = Upload::gold(&photo, &mask).with("normals", Some("car-normals.png"), &facing);
    let (s, v) = post_edit(addr, &upload.0);
    assert_eq!(s, 202, "{v}");
    let done = wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"]);
    assert_eq!(done["state"], "done", "{done}");
    let normals = &done["report"]["normals"];
    assert_eq!(normals["network_pixels_kept"], 0, "{normals}");
    assert_eq!(normals["detail_pixels_kept"], 0, "{normals}");
    // The report names the upload as the user did, not by where the server saved it.
    let path = normals["path"].as_str().unwrap();
    assert!(path.contains("car-normals.png") && !path.contains('/'), "{path}");
}

#[test]
fn the_objects_own_material_reaches_the_edit_and_picks_its_composite() {
    let rt = runtime();
    let server = rt.block_on(start(config(2))).unwrap();
    let addr = server.addr;
    let (photo, mask) = photo_and_mask();
    for (composite, want) in [(&b""[..], "ratio"), (&b"detail"[..], "detail")] {
        let upload = Upload::gold(&photo, &mask)
            .with("input_material", None, b"plastic:0.1:0.6,0.1,0.1")
            .with("composite", None, composite);
        let (s, v) = post_edit(addr, &upload.0);
        assert_eq!(s, 202, "{v}");
        let done = wait_for(addr, v["url"].as_str().unwrap(), &["done", "failed"]);
        assert_eq!(done["state"], "done", "{done}");
        let report = &done["report"];
        assert_eq!(report["input_material"], "plastic:0.1:0.6,0.1,0.1", "{report}");
        assert_eq!(report["light_level"]["source"], "input material", "{report}");
        assert_eq!(report["composite"], want, "{report}");
    }
}

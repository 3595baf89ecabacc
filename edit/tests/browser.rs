//! `matedit serve` driven by headless Chromium through chromedriver (Debian's `chromium` and
//! `chromium-driver`): the page loads, a photo and its mask from the test split of a small
//! dataset rendered like the quickstart's are uploaded, a library material is picked by its
//! sphere, and the edited photo the page shows is the one `matedit edit` writes for the same
//! inputs, pixel for pixel; bad uploads get their message on the page; a queued edit is
//! cancelled from the page.
//!
//! Without chromedriver on the PATH the test says so and passes, unless
//! `MATEDIT_REQUIRE_BROWSER=1` (set by `.ci/run`, which installs both). With
//! `MATEDIT_SCREENSHOTS=DIR` it saves screenshots of the page there (the README's).

use burn::optim::AdamConfig;
use burn::tensor::Device;
use fantoccini::actions::{InputSource, MOUSE_BUTTON_LEFT, MouseActions, PointerAction};
use fantoccini::{Client, ClientBuilder, Locator};
use matedit_edit::serve::{ServeConfig, start};
use matedit_edit::{EditRequest, edit};
use matedit_fixtures::{Sources, render_dataset};
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::tonemap::tonemap_u8;
use matedit_trainer::data::Dataset;
use matedit_trainer::model::Widths;
use matedit_trainer::model::network::NetConfig;
use matedit_trainer::train::checkpoint::{State, save};
use serde_json::Value;
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const DATASET: &str = r#"
[dataset]
name = "browser"
seed = 2017
output = "unused"
shard_size = 8

[render]
resolution = 96
env_resolution = "8x16"
quality = "fast"

[views]
azimuths = 8
elevation_deg = 20.0
per_combination = 1

[[shapes]]
source = "procedural"
category = "car"
count = 2

[[materials]]
source = "dsbrdf"
path = "mats"

[[environments]]
source = "procedural"
family = "sunsky"
count = 1

[[splits]]
name = "train"
shapes = { car = 1 }
materials = 2

[[splits]]
name = "test"
shapes = { car = 1 }
materials = 2
"#;

const MATERIAL: &str = "library:gold-polished";

fn root() -> PathBuf {
    std::env::temp_dir().join(format!("matedit-browser-{}", std::process::id()))
}

/// A test-split photo (8-bit sRGB PNG) and its mask, and an untrained network's checkpoint.
fn fixture() -> (PathBuf, PathBuf, PathBuf) {
    let materials = [
        Dsbrdf::near_lambertian([0.7, 0.25, 0.1]),
        Dsbrdf::near_lambertian([0.2, 0.4, 0.7]),
        Dsbrdf::near_lambertian([0.5, 0.5, 0.5]),
        Dsbrdf::near_lambertian([0.8, 0.7, 0.2]),
    ];
    let sources = Sources {
        manifest: DATASET,
        materials: &materials,
        objs: &[],
    };
    let out = render_dataset(&root(), "m.toml", &sources, "dataset");
    let ds = Dataset::open(&out).unwrap();
    let s = ds.load(&ds.records("test")[0], true).unwrap();
    let (n, hw) = (s.size, s.size * s.size);
    let photo = image::RgbImage::from_fn(n as u32, n as u32, |x, y| {
        let k = y as usize * n + x as usize;
        image::Rgb([0, 1, 2].map(|c| {
            if s.mask[k] > 0.0 {
                tonemap_u8(s.input[c * hw + k], 1.0)
            } else {
                [60, 70, 80][c]
            }
        }))
    });
    let mask = image::GrayImage::from_fn(n as u32, n as u32, |x, y| {
        image::Luma([if s.mask[y as usize * n + x as usize] > 0.0 {
            255
        } else {
            0
        }])
    });
    let (p, m) = (root().join("photo.png"), root().join("mask.png"));
    photo.save(&p).unwrap();
    mask.save(&m).unwrap();

    let device = Device::flex();
    device.seed(3);
    let cfg = NetConfig::new(32, Widths::new(4, 16, 32, 8)).with_env_height(8);
    let net = cfg.init(&device);
    let model = save(
        &root().join("model"),
        "untrained",
        &net,
        &AdamConfig::new().init(),
        State::untrained(cfg, "untrained"),
    )
    .unwrap();
    (p, m, model)
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// chromedriver as a child on a free port, killed when dropped.
struct Driver(Child, u16);

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        // The browsers chromedriver started outlive it when a test fails before closing them:
        // they are the ones with this process's profiles.
        let _ = Command::new("pkill")
            .arg("-f")
            .arg(format!("user-data-dir={}", root().join("chrome-").display()))
            .status();
    }
}

fn chromedriver() -> Option<Driver> {
    let port = free_port();
    let child = Command::new("chromedriver")
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .ok()?;
    let d = Driver(child, port);
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(20) {
        if std::net::TcpStream::connect(("127.0.0.1", port)).is_ok() {
            return Some(d);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("chromedriver did not listen on port {port} within 20 s");
}

async fn browser(driver: &Driver) -> Client {
    let profile = root().join(format!("chrome-{}", driver.1));
    let caps = serde_json::json!({
        "goog:chromeOptions": {
            "binary": "/usr/bin/chromium",
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                     "--window-size=1400,1250", format!("--user-data-dir={}", profile.display())]
        }
    });
    let Value::Object(caps) = caps else { unreachable!() };
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{}", driver.1))
        .await
        .expect("a session of headless Chromium")
}

async fn screenshot(c: &Client, name: &str) {
    if let Some(dir) = std::env::var_os("MATEDIT_SCREENSHOTS") {
        std::fs::create_dir_all(&dir).unwrap();
        c.execute("window.scrollTo(0, 0)", vec![]).await.unwrap();
        let png = c.screenshot().await.unwrap();
        std::fs::write(Path::new(&dir).join(name), png).unwrap();
    }
}

/// The bytes of the image `id` as the page loaded it.
async fn image_bytes(c: &Client, id: &str) -> Vec<u8> {
    let v = c
        .execute_async(
            "const [id, done] = arguments;
             fetch(document.getElementById(id).src).then(r => r.arrayBuffer())
               .then(b => done(Array.from(new Uint8Array(b)))).catch(e => done(String(e)));",
            vec![Value::String(id.into())],
        )
        .await
        .unwrap();
    let Value::Array(a) = v else {
        panic!("could not read #{id}: {v}")
    };
    a.iter().map(|x| x.as_u64().unwrap() as u8).collect()
}

async fn set_file(c: &Client, id: &str, path: &Path) {
    c.find(Locator::Id(id))
        .await
        .unwrap()
        .send_keys(&path.display().to_string())
        .await
        .unwrap();
}

async fn wait_state(c: &Client, states: &str, secs: u64) -> String {
    let t = Instant::now();
    loop {
        let s = c.execute("return document.body.dataset.state", vec![]).await.unwrap();
        let s = s.as_str().unwrap_or("").to_string();
        if states.split('|').any(|x| x == s) {
            return s;
        }
        assert!(
            t.elapsed() < Duration::from_secs(secs),
            "the page stayed in state {s} for {secs} s"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

async fn text(c: &Client, id: &str) -> String {
    c.find(Locator::Id(id)).await.unwrap().text().await.unwrap()
}

/// How the form is given the mask.
#[derive(Clone, Copy)]
enum Mask<'a> {
    File(&'a Path),
    Alpha,
    Brush,
}

/// Opens the page and fills the form as a user does: the photo, the mask, the library material
/// `spec` picked by its sphere, Eq. 6 or not.
async fn fill(c: &Client, url: &str, photo: &Path, mask: Mask<'_>, spec: &str, optimize: bool) {
    c.goto(url).await.unwrap();
    set_file(c, "photo", photo).await;
    let radio = match mask {
        Mask::File(m) => {
            set_file(c, "mask", m).await;
            None
        }
        Mask::Alpha => Some(r#"input[name="mask-mode"][value="alpha"]"#),
        Mask::Brush => Some(r#"input[name="mask-mode"][value="brush"]"#),
    };
    if let Some(r) = radio {
        c.find(Locator::Css(r)).await.unwrap().click().await.unwrap();
    }
    let pick = format!(r#".material[data-spec="{spec}"]"#);
    c.wait()
        .for_element(Locator::Css(&pick))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    if optimize {
        c.find(Locator::Id("optimize")).await.unwrap().click().await.unwrap();
    }
}

/// Clicks Edit and waits for the page to reach one of `states`; the state and the seconds.
async fn run_edit(c: &Client, states: &str, secs: u64) -> (String, f64) {
    let t = Instant::now();
    c.find(Locator::Id("run")).await.unwrap().click().await.unwrap();
    let s = wait_state(c, states, secs).await;
    (s, t.elapsed().as_secs_f64())
}

/// Submits an edit whose message must contain every one of `needles`.
async fn refused(c: &Client, url: &str, photo: &Path, mask: Mask<'_>, needles: &[&str]) {
    fill(c, url, photo, mask, MATERIAL, false).await;
    run_edit(c, "error", 30).await;
    let e = text(c, "error").await;
    assert!(needles.iter().all(|n| e.contains(n)), "expected {needles:?} in: {e}");
}

async fn energy_drawn(c: &Client) -> bool {
    c.execute(
        "return !document.getElementById('energy').classList.contains('hidden')",
        vec![],
    )
    .await
    .unwrap()
        == Value::Bool(true)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_edits_a_photo_as_matedit_edit_does_and_explains_bad_uploads() {
    let Some(driver) = chromedriver() else {
        assert!(
            std::env::var_os("MATEDIT_REQUIRE_BROWSER").is_none(),
            "MATEDIT_REQUIRE_BROWSER is set but chromedriver is not on the PATH (apt-get install chromium chromium-driver)"
        );
        eprintln!("skipped: no chromedriver on the PATH (apt-get install chromium chromium-driver)");
        return;
    };
    let _ = std::fs::remove_dir_all(root());
    let (photo, mask, model) = tokio::task::spawn_blocking(fixture).await.unwrap();
    // The README's screenshots: a trained model and a real photo (its alpha as the mask).
    let (photo, mask, model) = match (
        std::env::var_os("MATEDIT_BROWSER_MODEL"),
        std::env::var_os("MATEDIT_BROWSER_PHOTO"),
    ) {
        (Some(m), Some(p)) => (PathBuf::from(p), None, PathBuf::from(m)),
        _ => (photo, Some(mask), model),
    };
    let given = mask.as_deref().map_or(Mask::Alpha, Mask::File);

    // What the command line writes for the same inputs.
    let cli_out = root().join("cli");
    let req = EditRequest {
        photo: photo.clone(),
        mask: mask.clone(),
        materials: vec![(None, MATERIAL.into())],
        ..EditRequest::default()
    };
    let (m2, o2) = (model.clone(), cli_out.clone());
    let cli_report = tokio::task::spawn_blocking(move || edit(&m2, &req, &o2))
        .await
        .unwrap()
        .unwrap();
    let want = image::load_from_memory(&std::fs::read(cli_out.join("edited.png")).unwrap())
        .unwrap()
        .to_rgb8();

    let limit = (std::fs::metadata(&photo).unwrap().len() as usize + (1 << 20)).next_power_of_two();
    let mut cfg = ServeConfig::new(model.clone());
    cfg.port = 0;
    cfg.queue = 1;
    cfg.max_upload_bytes = limit;
    let server = start(cfg.clone()).await.unwrap();
    let url = format!("http://{}/", server.addr);
    let c = browser(&driver).await;

    // An upload and a library pick, as a user makes them.
    fill(&c, &url, &photo, given, MATERIAL, false).await;
    // The spheres are the project's renders: wait for the picked one to have loaded.
    let t = Instant::now();
    while c
        .execute(
            r#"const i = document.querySelector('.material.selected img'); return i.complete && i.naturalWidth"#,
            vec![],
        )
        .await
        .unwrap()
        .as_u64()
        .unwrap_or(0)
        != 64
    {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "the material's sphere never loaded"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let (s, secs) = run_edit(&c, "done|error", 300).await;
    assert_eq!(s, "done", "the edit failed: {}", text(&c, "error").await);
    eprintln!("upload to shown result: {secs:.2} s");
    screenshot(&c, "serve-result.png").await;
    let caption = c
        .execute("return document.getElementById('result-normals').alt", vec![])
        .await
        .unwrap();
    assert_eq!(caption, "n′", "no normals were given");
    // L′'s tile says what of it the checkpoint does not read, as the command line's report does.
    let env_caption = c
        .execute("return document.getElementById('result-env').alt", vec![])
        .await
        .unwrap();
    let e = cli_report.light_estimate.expect("L′ was the network's");
    let dropped: Vec<&str> = [
        (e.averaged_around_vertical, "averaged around the vertical axis"),
        (e.made_neutral, "made neutral"),
    ]
    .into_iter()
    .filter_map(|(d, what)| d.then_some(what))
    .collect();
    let expected = if dropped.is_empty() {
        "L′".to_string()
    } else {
        format!("L′ — {} (not read from a picture)", dropped.join(" and "))
    };
    assert_eq!(env_caption, expected);
    let got = image::load_from_memory(&image_bytes(&c, "result-edited").await)
        .unwrap()
        .to_rgb8();
    assert_eq!(
        got.dimensions(),
        want.dimensions(),
        "the composite is at the photo's resolution"
    );
    assert!(got == want, "the page's edited photo differs from `matedit edit`'s");
    let mut names = Vec::new();
    for a in c.find_all(Locator::Css("#downloads a")).await.unwrap() {
        names.push(a.text().await.unwrap());
    }
    for f in [
        "edited.png",
        "edited.exr",
        "i_prime.png",
        "o_prime.png",
        "normals.exr",
        "env.exr",
        "material.dsbrdf.json",
        "report.json",
    ] {
        assert!(names.iter().any(|n| n == f), "no download of {f} among {names:?}");
    }

    // With Eq. 6: its energy drawn live and its plot among the results.
    fill(&c, &url, &photo, given, MATERIAL, true).await;
    let (s, secs) = run_edit(&c, "done|error", 600).await;
    assert_eq!(s, "done", "the edit failed: {}", text(&c, "error").await);
    eprintln!("upload to shown result with Eq. 6: {secs:.2} s");
    assert!(
        c.find(Locator::Id("result-energy")).await.is_ok(),
        "no energy plot among the results"
    );
    assert!(energy_drawn(&c).await, "the live energy plot is not shown");
    screenshot(&c, "serve-eq6.png").await;
    let mask = mask.unwrap_or_else(|| alpha_mask(&photo));

    // A transfer from another photo, with the receiving object's normals given on the page: they
    // reach the transfer (report.json says none of n' was kept).
    let facing = root().join("facing-normals.png");
    let (w, h) = want.dimensions();
    image::RgbImage::from_pixel(w, h, image::Rgb([128, 128, 255]))
        .save(&facing)
        .unwrap();
    c.goto(&url).await.unwrap();
    set_file(&c, "photo", &photo).await;
    set_file(&c, "mask", &mask).await;
    c.find(Locator::Css(r#"input[name="target-mode"][value="transfer"]"#))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    set_file(&c, "source", &photo).await;
    set_file(&c, "source-mask", &mask).await;
    set_file(&c, "normals", &facing).await;
    let (s, _) = run_edit(&c, "done|error", 300).await;
    assert_eq!(s, "done", "the transfer failed: {}", text(&c, "error").await);
    screenshot(&c, "serve-transfer-normals.png").await;
    let caption = c
        .execute("return document.getElementById('result-normals').alt", vec![])
        .await
        .unwrap();
    assert_eq!(caption, "n — the given normals (n′ where they have none)");
    let report = c
        .execute_async(
            "const done = arguments[0];
             const a = [...document.querySelectorAll('#downloads a')].find(a => a.textContent === 'report.json');
             fetch(a.href).then(r => r.json()).then(done).catch(e => done(String(e)));",
            vec![],
        )
        .await
        .unwrap();
    assert_eq!(report["normals"]["detail_pixels_kept"], 0, "{report}");
    assert!(
        report["regions"][0]["spec"]
            .as_str()
            .unwrap_or("")
            .starts_with("m' of source"),
        "{report}"
    );

    // Bad uploads: a text file named like a photo, a mask of another size, nothing painted.
    let junk = root().join("not-a-photo.png");
    std::fs::write(&junk, "hello, I am text").unwrap();
    refused(
        &c,
        &url,
        &junk,
        Mask::File(&mask),
        &["not-a-photo.png", "not a PNG, JPEG, EXR or HDR image"],
    )
    .await;
    let small = root().join("small-mask.png");
    image::GrayImage::from_fn(10, 10, |x, _| image::Luma([if x < 5 { 255 } else { 0 }]))
        .save(&small)
        .unwrap();
    refused(
        &c,
        &url,
        &photo,
        Mask::File(&small),
        &["small-mask.png", "must match pixel for pixel"],
    )
    .await;
    screenshot(&c, "serve-error.png").await;
    refused(
        &c,
        &url,
        &photo,
        Mask::Brush,
        &["painted-mask.png", "the mask is empty"],
    )
    .await;

    // The brush: a stroke across the object edits.
    c.wait().for_element(Locator::Css("#view:not(.hidden)")).await.unwrap();
    let stroke = stroke_across(c.find(Locator::Id("brush-canvas")).await.unwrap());
    c.perform_actions(stroke).await.unwrap();
    let (s, _) = run_edit(&c, "done|error", 300).await;
    assert_eq!(s, "done", "the painted mask did not edit: {}", text(&c, "error").await);

    // A phone photo stored sideways with an EXIF orientation: the page shows it upright, the
    // brush paints on it upright, and the edit comes back upright.
    let turned = turned_photo(&photo);
    fill(&c, &url, &turned, Mask::Brush, MATERIAL, false).await;
    c.wait().for_element(Locator::Css("#view:not(.hidden)")).await.unwrap();
    let shown = c
        .execute(
            "const c = document.getElementById('photo-canvas'); return [c.width, c.height];",
            vec![],
        )
        .await
        .unwrap();
    let upright = image::open(&photo).unwrap();
    let want = [upright.width() + upright.width() / 2, upright.height()];
    assert_eq!(
        shown,
        serde_json::json!(want),
        "the page does not show the photo upright"
    );
    let stroke = stroke_across(c.find(Locator::Id("brush-canvas")).await.unwrap());
    c.perform_actions(stroke).await.unwrap();
    let (s, _) = run_edit(&c, "done|error", 300).await;
    assert_eq!(s, "done", "the turned photo did not edit: {}", text(&c, "error").await);
    let got = image::load_from_memory(&image_bytes(&c, "result-edited").await).unwrap();
    assert_eq!(
        [got.width(), got.height()],
        want,
        "the edit of the turned photo is not upright"
    );

    // Over the server's upload limit.
    let big = root().join("big.png");
    let side = ((limit as f64 / 2.5).sqrt() as u32).max(800);
    let noise = image::RgbImage::from_fn(side, side, |x, y| {
        let h = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)).wrapping_mul(2_246_822_519);
        image::Rgb([(h >> 8) as u8, (h >> 16) as u8, (h >> 24) as u8])
    });
    noise.save(&big).unwrap();
    refused(&c, &url, &big, Mask::File(&mask), &["larger than this server accepts"]).await;
    c.close().await.unwrap();
    server.stop().await;

    // A long Eq. 6: a second user waits and sees their place; both cancel from the page.
    cfg.eq6.rounds = 1_000_000; // never ends by itself: only Cancel stops it
    cfg.eq6.iterations = 50;
    let server = start(cfg).await.unwrap();
    let url = format!("http://{}/", server.addr);
    let c = browser(&driver).await;
    let first = c.window().await.unwrap();
    fill(&c, &url, &photo, Mask::File(&mask), MATERIAL, true).await;
    run_edit(&c, "running", 60).await;
    let t = Instant::now();
    while !(text(&c, "status").await.contains("post-optimising") && energy_drawn(&c).await) {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "never saw Eq. 6 running: {}",
            text(&c, "status").await
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let second = c.new_window(true).await.unwrap();
    c.switch_to_window(second.handle).await.unwrap();
    fill(&c, &url, &photo, Mask::File(&mask), MATERIAL, true).await;
    run_edit(&c, "queued", 30).await;
    let t = Instant::now();
    while !text(&c, "status").await.contains("place 1 in the queue") {
        assert!(t.elapsed() < Duration::from_secs(10), "{}", text(&c, "status").await);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    screenshot(&c, "serve-queued.png").await;
    c.find(Locator::Id("cancel")).await.unwrap().click().await.unwrap();
    wait_state(&c, "cancelled", 10).await;
    c.switch_to_window(first).await.unwrap();
    screenshot(&c, "serve-running.png").await;
    let t = Instant::now();
    c.find(Locator::Id("cancel")).await.unwrap().click().await.unwrap();
    wait_state(&c, "cancelled", 30).await;
    eprintln!(
        "a running Eq. 6 stopped {:.2} s after Cancel",
        t.elapsed().as_secs_f64()
    );
    c.close().await.unwrap();
    server.stop().await;
}

/// A brush stroke across the middle of `canvas`, 60 pixels wide.
fn stroke_across(canvas: fantoccini::elements::Element) -> MouseActions {
    MouseActions::new("mouse".into())
        .then(PointerAction::MoveToElement {
            element: canvas.clone(),
            duration: None,
            x: -30.0,
            y: 0.0,
        })
        .then(PointerAction::Down {
            button: MOUSE_BUTTON_LEFT,
        })
        .then(PointerAction::MoveToElement {
            element: canvas,
            duration: Some(Duration::from_millis(300)),
            x: 30.0,
            y: 5.0,
        })
        .then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        })
}

/// The photo's alpha channel as a mask file.
fn alpha_mask(photo: &Path) -> PathBuf {
    let img = image::open(photo).unwrap().to_rgba8();
    let m = image::GrayImage::from_fn(img.width(), img.height(), |x, y| image::Luma([img.get_pixel(x, y)[3]]));
    let p = root().join("alpha-mask.png");
    m.save(&p).unwrap();
    p
}

/// `photo` widened by half its width of flat background on the right (so a quarter turn changes
/// its size), stored a quarter turn anticlockwise in a JPEG whose EXIF orientation (6) says to
/// turn it back, as phones store portrait photos.
fn turned_photo(photo: &Path) -> PathBuf {
    let img = image::open(photo).unwrap().to_rgb8();
    let (w, h) = img.dimensions();
    let wide = image::RgbImage::from_fn(w + w / 2, h, |x, y| {
        if x < w {
            *img.get_pixel(x, y)
        } else {
            image::Rgb([60, 70, 80])
        }
    });
    let stored = image::DynamicImage::ImageRgb8(wide).rotate270().to_rgb8();
    let exif: Vec<u8> = [
        &b"MM\0\x2a\0\0\0\x08"[..],
        &[0, 1, 0x01, 0x12, 0, 3, 0, 0, 0, 1, 0, 6, 0, 0, 0, 0, 0, 0],
    ]
    .concat();
    let p = root().join("turned.jpg");
    let f = std::io::BufWriter::new(std::fs::File::create(&p).unwrap());
    let mut enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 95);
    image::ImageEncoder::set_exif_metadata(&mut enc, exif).unwrap();
    image::ImageEncoder::write_image(
        enc,
        stored.as_raw(),
        stored.width(),
        stored.height(),
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    p
}

//! `matedit serve`: material editing in the browser. One page ([`PAGE`]) uploads a photo and its
//! mask (a file, the photo's alpha, or painted on the page), picks a library material by its
//! sphere or a second photo to transfer from, and shows what `matedit edit` / `transfer` write,
//! which is what runs: the handlers only check uploads and queue jobs ([`jobs`]); one worker
//! that owns the network runs them in order through [`crate::edit_with`] and
//! [`crate::transfer_with`], showing Eq. 6's energy live and stopping when cancelled.
//!
//! | route | what |
//! |---|---|
//! | `GET /` | the page |
//! | `GET /api/info` | the model and the server's limits |
//! | `GET /api/library`, `GET /api/library/{name}/sphere.png` | library materials and their spheres |
//! | `POST /api/edit` (multipart) | queue an edit: `photo`, `mask`?, `material` or `source` (+ `source_mask`), `input_material`?, `normals`? (a file; both of `photo`, in a transfer too), `optimize`?, `composite`? |
//! | `GET /api/jobs/{id}` | its state: place in the queue, phase, Eq. 6 energies, files, report |
//! | `POST /api/jobs/{id}/cancel` | cancel it, waiting or running |
//! | `GET /api/jobs/{id}/files/{name}` | a file its report lists (`?download` to save it) |

mod form;
pub mod guard;
pub mod jobs;
pub mod library;
mod lifecycle;
pub mod rate;
mod submit;
#[cfg(test)]
mod tests;
pub mod upload;

use crate::Model;
use anyhow::{Context, Result};
use axum::Router;
use axum::extract::{DefaultBodyLimit, Path as UrlPath, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use jobs::Queue;
pub use lifecycle::CANCEL_WAIT;
use lifecycle::{Interrupt, WorkFolder, accept};
use matedit_trainer::post_optimisation::Eq6Config;
use serde_json::{Value, json};
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicU64;

/// The page: HTML, style and script in one file, served as is.
pub const PAGE: &str = include_str!("page.html");

/// How to serve.
#[derive(Clone, Debug)]
pub struct ServeConfig {
    /// A run folder (its latest checkpoint) or a checkpoint folder.
    pub model: PathBuf,
    /// Address to bind (127.0.0.1 unless asked otherwise).
    pub bind: IpAddr,
    /// Port (0: any free one).
    pub port: u16,
    /// Edits that may wait beyond the running one.
    pub queue: usize,
    /// Largest request body in bytes.
    pub max_upload_bytes: usize,
    /// Largest photo in pixels.
    pub max_pixels: u64,
    /// Finished jobs whose files are kept.
    pub keep: usize,
    /// The most disk the kept jobs may use together (the newest is kept whatever its size).
    pub keep_bytes: u64,
    /// The most memory the edits in the server (checked, queued and running) may need
    /// together, in MiB, estimated from their photos' sizes before anything is decoded.
    pub max_memory_mb: u64,
    /// Where jobs' uploads and outputs go (default: a fresh folder in the system's temp folder,
    /// removed when the server stops).
    pub work: Option<PathBuf>,
    /// Eq. 6's settings when a request asks for it.
    pub eq6: Eq6Config,
    /// Host names the server answers to beyond IP addresses and `localhost` (lower case, no
    /// port).
    pub allow_hosts: Vec<String>,
    /// How long a client may take to send a request's headers, and to send an upload whole.
    pub deadlines: Deadlines,
}

/// How long clients may take; no client holds the server longer than these.
#[derive(Clone, Copy, Debug)]
pub struct Deadlines {
    /// To send a request's headers (also how long an idle connection stays open).
    pub headers: std::time::Duration,
    /// To send an upload's body whole, from its headers on.
    pub upload: std::time::Duration,
    /// On SIGTERM or Ctrl-C: how long connections and the running edit get to finish before
    /// they are dropped (the edit cancelled).
    pub grace: std::time::Duration,
    /// The slowest an upload may arrive; a slower one is closed.
    pub min_rate: rate::MinRate,
}

impl Default for Deadlines {
    fn default() -> Self {
        Self {
            headers: std::time::Duration::from_secs(10),
            upload: std::time::Duration::from_secs(60),
            grace: std::time::Duration::from_secs(10),
            min_rate: rate::MinRate::default(),
        }
    }
}

impl ServeConfig {
    /// Defaults for `model`: 127.0.0.1:8080, 8 waiting, 32 MB uploads, 25 megapixels.
    pub fn new(model: PathBuf) -> Self {
        Self {
            model,
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 8080,
            queue: 8,
            max_upload_bytes: 32 << 20,
            max_pixels: 25_000_000,
            keep: 32,
            keep_bytes: 2 << 30,
            max_memory_mb: 4096,
            work: None,
            eq6: Eq6Config::default(),
            allow_hosts: Vec::new(),
            deadlines: Deadlines::default(),
        }
    }
}

struct App {
    queue: Arc<Queue>,
    library: library::Library,
    info: Value,
    work: PathBuf,
    max_pixels: u64,
    eq6: Eq6Config,
    counter: AtomicU64,
    secret: [u8; 32],
    /// Uploads being decoded and checked at once (each may hold a large photo in memory).
    checking: Arc<tokio::sync::Semaphore>,
    /// KiB the uploads being received may hold together ([`rate`]).
    receiving: rate::Receiving,
    /// How slowly an upload may arrive.
    min_rate: rate::MinRate,
    /// How long an upload may take.
    upload_deadline: std::time::Duration,
    /// MiB the edits in the server may still reserve ([`upload::memory_mb`] each, held from
    /// the upload's check until the edit ends).
    memory: Arc<tokio::sync::Semaphore>,
    /// All of it.
    max_memory_mb: u64,
}

impl App {
    /// The server's state for `cfg`, with the model's description and the job queue.
    fn new(cfg: &ServeConfig, info: Value, queue: Arc<Queue>, work: &std::path::Path) -> Self {
        Self {
            queue,
            library: library::Library::default(),
            info,
            work: work.to_path_buf(),
            max_pixels: cfg.max_pixels,
            eq6: cfg.eq6.clone(),
            counter: AtomicU64::new(0),
            checking: Arc::new(tokio::sync::Semaphore::new(2)),
            // Eight uploads of the largest size at once; stalled ones hold what they sent, which is
            // next to nothing, and are closed within seconds.
            receiving: Arc::new(tokio::sync::Semaphore::new(
                (8 * cfg.max_upload_bytes.div_ceil(1024)).min(tokio::sync::Semaphore::MAX_PERMITS),
            )),
            min_rate: cfg.deadlines.min_rate,
            upload_deadline: cfg.deadlines.upload,
            memory: Arc::new(tokio::sync::Semaphore::new(
                cfg.max_memory_mb.min(tokio::sync::Semaphore::MAX_PERMITS as u64) as usize,
            )),
            max_memory_mb: cfg.max_memory_mb,
            secret: *blake3::hash(format!("{}:{}:{:?}", std::process::id(), nanos(), work).as_bytes()).as_bytes(),
        }
    }

    /// A message as a client may see it: no path of the server's (the work folder's name holds
    /// the process id and the start time), uploads named as the browser named them.
    fn scrub(&self, message: &str, job: &std::path::Path) -> String {
        message
            .replace(&format!("{}/in/", job.display()), "")
            .replace(&job.display().to_string(), "the edit's folder")
            .replace(&self.work.display().to_string(), "the server's work folder")
    }
}

/// A running server.
pub struct Server {
    /// Where it listens.
    pub addr: SocketAddr,
    queue: Arc<Queue>,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    task: tokio::task::JoinHandle<()>,
    worker: Option<std::thread::JoinHandle<()>>,
    /// Held for its removal when the server is stopped (dropped).
    _work: WorkFolder,
    grace: std::time::Duration,
}

impl Server {
    /// Stops listening, gives open connections and the running edit the grace period to
    /// finish (then drops them and cancels the edit), and removes a temporary work folder.
    pub async fn stop(mut self) {
        let deadline = tokio::time::Instant::now() + self.grace;
        if let Some(s) = self.shutdown.take() {
            let _ = s.send(());
        }
        if tokio::time::timeout_at(deadline, &mut self.task).await.is_err() {
            self.task.abort();
        }
        self.queue.stop();
        if let Some(w) = self.worker.take() {
            let mut join = tokio::task::spawn_blocking(move || w.join());
            if tokio::time::timeout_at(deadline, &mut join).await.is_err() {
                // The running edit stops at its next phase or Eq. 6 iteration; an edit that
                // does not within CANCEL_WAIT is left to end with the process.
                self.queue.cancel_running();
                if tokio::time::timeout(CANCEL_WAIT, join).await.is_err() {
                    eprintln!(
                        "the running edit did not stop within {} s of its cancellation; leaving it",
                        CANCEL_WAIT.as_secs()
                    );
                }
            }
        }
        // The work folder goes with `self._work`, now.
    }

    /// Waits for Ctrl-C (SIGINT) or SIGTERM (what batch schedulers and service managers send),
    /// then [`stop`](Self::stop)s.
    pub async fn run_until_interrupted(self) {
        let mut interrupt = Interrupt::new();
        self.run_until(&mut interrupt).await;
    }

    async fn run_until(self, interrupt: &mut Interrupt) {
        interrupt.wait().await;
        eprintln!(
            "stopping: open requests and the running edit get {} s to finish",
            self.grace.as_secs_f64()
        );
        self.stop().await;
    }
}

/// Binds, loads the model, and serves in the background of the current tokio runtime. A start
/// that fails (port in use, bad model) leaves no temporary work folder behind.
pub async fn start(cfg: ServeConfig) -> Result<Server> {
    start_in(cfg, &std::env::temp_dir()).await
}

/// [`start`] with temporary work folders made in `temp`.
async fn start_in(cfg: ServeConfig, temp: &std::path::Path) -> Result<Server> {
    let work = match &cfg.work {
        Some(w) => WorkFolder::create(w.clone(), false)?,
        None => WorkFolder::create(
            temp.join(format!("matedit-serve-{}-{}", std::process::id(), nanos())),
            true,
        )?,
    };
    serve_from(cfg, work).await
}

/// The model, with its light probe run ([`Model::light_skill`]): once here, not in the first
/// user's edit.
fn load_measured(path: &std::path::Path) -> Result<Model> {
    let model = Model::load(path)?;
    model.light_skill()?;
    Ok(model)
}

/// What `GET /api/info` says of the model: the run's own part of its path
/// (run/checkpoints/stage; where the server keeps it is nobody else's business), its stage and
/// the sizes it works at.
fn describe(model: &Model) -> Value {
    let s = &model.state;
    let parts: Vec<_> = model.dir.components().rev().take(3).collect();
    let checkpoint: PathBuf = parts.into_iter().rev().collect();
    json!({
        "checkpoint": checkpoint.display().to_string(),
        "stage": s.stage_name,
        "input_size": s.net.input_size,
        "env_height": s.net.env_height,
    })
}

/// [`start`] once the work folder exists.
async fn serve_from(cfg: ServeConfig, work: WorkFolder) -> Result<Server> {
    // Bound first: a port in use is refused before the model is loaded and a worker started.
    let listener = tokio::net::TcpListener::bind((cfg.bind, cfg.port))
        .await
        .with_context(|| format!("cannot listen on {}:{}", cfg.bind, cfg.port))?;
    let queue = Arc::new(Queue::new(cfg.queue, cfg.keep, cfg.keep_bytes));
    // The network stays on the worker thread that loaded it.
    let (tx, rx) = std::sync::mpsc::channel::<Result<Value>>();
    let (q, path) = (queue.clone(), cfg.model.clone());
    let worker = std::thread::Builder::new()
        .name("matedit-edit".into())
        .spawn(move || match load_measured(&path) {
            Ok(model) => {
                let _ = tx.send(Ok(describe(&model)));
                jobs::work(&q, &model);
            }
            Err(e) => {
                let _ = tx.send(Err(e));
            }
        })
        .context("cannot start the edit worker")?;
    let mut info = tokio::task::spawn_blocking(move || rx.recv())
        .await
        .context("the edit worker stopped")?
        .context("the edit worker stopped")??;
    info["max_upload_mb"] = json!(cfg.max_upload_bytes as f64 / (1 << 20) as f64);
    info["max_megapixels"] = json!(cfg.max_pixels as f64 / 1e6);
    info["queue"] = json!(queue.capacity());
    info["eq6"] = json!(cfg.eq6);
    let app = Arc::new(App::new(&cfg, info, queue.clone(), &work.path));
    let hosts = guard::Hosts {
        names: cfg.allow_hosts.iter().map(|h| h.to_ascii_lowercase()).collect(),
    };
    let router = router(app, cfg.max_upload_bytes, hosts);
    let addr = listener.local_addr()?;
    let (stx, srx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(accept(listener, router, srx, cfg.deadlines.headers));
    Ok(Server {
        addr,
        queue,
        shutdown: Some(stx),
        task,
        worker: Some(worker),
        _work: work,
        grace: cfg.deadlines.grace,
    })
}

fn nanos() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

fn router(app: Arc<App>, max_upload: usize, hosts: guard::Hosts) -> Router {
    Router::new()
        .route("/", get(|| async { Html(PAGE) }))
        .route("/api/info", get(info))
        .route("/api/library", get(|| async { axum::Json(library::Library::list()) }))
        .route("/api/library/{name}/sphere.png", get(thumbnail))
        .route("/api/edit", post(submit::submit))
        .route("/api/jobs/{id}", get(status))
        .route("/api/jobs/{id}/cancel", post(cancel))
        .route("/api/jobs/{id}/files/{name}", get(file))
        .fallback(|| async { error(StatusCode::NOT_FOUND, "no such page") })
        .layer(DefaultBodyLimit::max(max_upload))
        .layer(axum::middleware::from_fn_with_state(Arc::new(hosts), guard::guard))
        .with_state(app)
}

fn error(status: StatusCode, message: impl Into<String>) -> Response {
    (status, axum::Json(json!({ "error": message.into() }))).into_response()
}

async fn info(State(app): State<Arc<App>>) -> Response {
    axum::Json(app.info.clone()).into_response()
}

async fn thumbnail(State(app): State<Arc<App>>, UrlPath(name): UrlPath<String>) -> Response {
    let app2 = app.clone();
    let r = tokio::task::spawn_blocking(move || app2.library.thumbnail(&name)).await;
    match r {
        Ok(Some(Ok(png))) => (
            [
                (header::CONTENT_TYPE, "image/png"),
                (header::CACHE_CONTROL, "max-age=86400"),
            ],
            png,
        )
            .into_response(),
        Ok(Some(Err(e))) => error(StatusCode::INTERNAL_SERVER_ERROR, e),
        Ok(None) => error(StatusCode::NOT_FOUND, "no such library material"),
        Err(_) => error(StatusCode::INTERNAL_SERVER_ERROR, "the thumbnail could not be rendered"),
    }
}

/// The header the page sends with every request that changes something. A page of another
/// origin cannot add it without a CORS preflight, which this server never grants, so other
/// sites the user visits cannot queue or cancel edits.
pub const PAGE_HEADER: &str = "x-matedit-page";

/// `None` when the request came from the page; otherwise the refusal.
fn from_the_page(headers: &HeaderMap) -> Option<Response> {
    (!headers.contains_key(PAGE_HEADER)).then(|| {
        error(
            StatusCode::FORBIDDEN,
            format!("requests that change something must carry the {PAGE_HEADER} header (the page sends it)"),
        )
    })
}

fn no_such_job() -> Response {
    error(
        StatusCode::NOT_FOUND,
        "no such edit (finished edits are kept for a while only)",
    )
}

async fn status(State(app): State<Arc<App>>, UrlPath(id): UrlPath<String>) -> Response {
    match app.queue.get(&id) {
        Some(j) => axum::Json(app.queue.status(&j, &format!("/api/jobs/{id}"))).into_response(),
        None => no_such_job(),
    }
}

async fn cancel(State(app): State<Arc<App>>, headers: HeaderMap, UrlPath(id): UrlPath<String>) -> Response {
    if let Some(r) = from_the_page(&headers) {
        return r;
    }
    if app.queue.cancel(&id).is_none() {
        return no_such_job();
    }
    match app.queue.get(&id) {
        Some(j) => axum::Json(app.queue.status(&j, &format!("/api/jobs/{id}"))).into_response(),
        // Retired at once: the queue keeps only the last few finished edits.
        None => axum::Json(json!({ "id": id, "state": "cancelled" })).into_response(),
    }
}

async fn file(
    State(app): State<Arc<App>>,
    UrlPath((id, name)): UrlPath<(String, String)>,
    Query(q): Query<HashMap<String, String>>,
) -> Response {
    let Some(j) = app.queue.get(&id) else {
        return no_such_job();
    };
    // Only names the job's report lists resolve to a path.
    let Some(path) = j.file(&name) else {
        return error(StatusCode::NOT_FOUND, "no such file in this edit");
    };
    let bytes = match tokio::fs::read(&path).await {
        Ok(b) => b,
        Err(_) => return error(StatusCode::NOT_FOUND, "the file is gone"),
    };
    let kind = match path.extension().and_then(|e| e.to_str()) {
        Some("png") => "image/png",
        Some("json") => "application/json",
        Some("exr") => "image/x-exr",
        _ => "application/octet-stream",
    };
    let mut r = ([(header::CONTENT_TYPE, kind)], bytes).into_response();
    if q.contains_key("download") {
        let v = format!("attachment; filename=\"{}\"", name.replace(['"', '\\'], "_"));
        if let Ok(v) = header::HeaderValue::from_str(&v) {
            r.headers_mut().insert(header::CONTENT_DISPOSITION, v);
        }
    }
    r
}

/// `matedit serve`: starts the server on a runtime of its own and runs until Ctrl-C.
pub fn serve(cfg: ServeConfig) -> Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the server's runtime")?;
    let served = rt.block_on(async move {
        // Listening for the signals before anything is made: a SIGTERM while the model loads
        // ends the start-up, and the work folder goes with it.
        let mut interrupt = Interrupt::new();
        eprintln!("loading {} …", cfg.model.display());
        let public = !cfg.bind.is_loopback();
        let server = tokio::select! {
            started = start(cfg) => started?,
            _ = interrupt.wait() => {
                eprintln!("stopped while starting");
                return Ok(());
            }
        };
        say!("matedit serve: open http://{} (Ctrl-C stops)", server.addr);
        if public {
            eprintln!("note: listening beyond this machine; anyone who reaches it may queue edits");
        }
        server.run_until(&mut interrupt).await;
        Ok(())
    });
    // A model still loading, or an edit left running (CANCEL_WAIT), is not waited for.
    rt.shutdown_timeout(std::time::Duration::from_millis(200));
    served
}

//! The edit queue: a bounded list of waiting edits, one worker that owns the network and runs
//! them in order through the same functions as `matedit edit` and `matedit transfer`, and what
//! every job did, kept for the last few so their files can be downloaded.

use super::upload::name_uploads;
use crate::progress::Progress;
use crate::{Composite, EditReport, EditRequest, Given, Look, Model, Pair, Watch, edit_with, transfer_with};
use matedit_trainer::post_optimisation::Eq6Config;
use matedit_trainer::post_optimisation::watcher::{Cancelled, Watcher as _};
use serde_json::{Value, json};
use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

/// What a job does.
#[derive(Clone, Debug)]
pub enum Work {
    /// `matedit edit`.
    Edit(EditRequest),
    /// `matedit transfer`: the material of `from` onto the object of `to`.
    Transfer {
        /// Photo and mask the material comes from.
        from: (PathBuf, Option<PathBuf>),
        /// Photo and mask that receive it.
        to: (PathBuf, Option<PathBuf>),
        /// The receiving object's own material, when known (a spec).
        to_material: Option<String>,
        /// The receiving object's normals, when known (a saved upload).
        to_normals: Option<PathBuf>,
        /// Eq. 6 on both, when asked for.
        optimize: Option<Eq6Config>,
        /// How O' goes back into the photo.
        composite: Composite,
    },
}

/// Where a job stands.
#[derive(Clone, Debug)]
pub enum State {
    /// Waiting for the worker.
    Queued,
    /// Being edited since this instant.
    Running(Instant),
    /// Finished: its report (whose `files` lie in the job's `out/`).
    Done(Box<EditReport>),
    /// Stopped by a bad input or an internal error, with the message for the user.
    Failed(String),
    /// Cancelled by its user.
    Cancelled,
}

/// One edit request.
#[derive(Debug)]
pub struct Job {
    /// Unguessable id (the only handle a request has on it).
    pub id: String,
    /// Its folder: `in/` the uploads, `out/` the outputs.
    pub dir: PathBuf,
    /// What to do.
    pub work: Work,
    /// Saved upload paths and how messages should name them (the user's file names).
    pub names: Vec<(PathBuf, String)>,
    /// Phase and Eq. 6 energies, live; the cancel flag.
    pub progress: Arc<Progress>,
    /// When it was submitted.
    pub submitted: Instant,
    state: Mutex<State>,
    finished_after: Mutex<Option<f64>>,
    /// Bytes its folder holds once finished.
    disk: Mutex<u64>,
    /// The server's memory it reserved, given back when it ends.
    reservation: Mutex<Option<tokio::sync::OwnedSemaphorePermit>>,
}

impl Job {
    /// A queued job.
    pub fn new(id: String, dir: PathBuf, work: Work, names: Vec<(PathBuf, String)>) -> Self {
        Self {
            id,
            dir,
            work,
            names,
            progress: Arc::new(Progress::default()),
            submitted: Instant::now(),
            state: Mutex::new(State::Queued),
            finished_after: Mutex::new(None),
            disk: Mutex::new(0),
            reservation: Mutex::new(None),
        }
    }

    /// Its state now.
    pub fn state(&self) -> State {
        lock(&self.state).clone()
    }

    fn set(&self, s: State) {
        if !matches!(s, State::Queued | State::Running(_)) {
            *lock(&self.finished_after) = Some(self.submitted.elapsed().as_secs_f64());
        }
        *lock(&self.state) = s;
    }

    /// The output folder.
    pub fn out(&self) -> PathBuf {
        self.dir.join("out")
    }

    /// A message with the job's internal paths replaced by the names the user gave.
    pub fn user_message(&self, text: &str) -> String {
        name_uploads(text, &self.names).replace(&self.dir.display().to_string(), "the job")
    }

    /// A report with the job's internal paths named as the user named the uploads.
    fn user_report(&self, r: &EditReport) -> Value {
        // Paths and names as JSON strings write them (escaped, without the quotes).
        let escaped = |s: String| {
            let q = json!(s).to_string();
            q[1..q.len() - 1].to_string()
        };
        let names: Vec<(PathBuf, String)> = self
            .names
            .iter()
            .map(|(p, n)| (PathBuf::from(escaped(p.display().to_string())), escaped(n.clone())))
            .collect();
        let text = name_uploads(&serde_json::to_string(r).unwrap_or_default(), &names);
        serde_json::from_str(&text).unwrap_or(Value::Null)
    }

    /// The job, holding `reservation` until it ends.
    pub fn holding(self, reservation: tokio::sync::OwnedSemaphorePermit) -> Self {
        *lock(&self.reservation) = Some(reservation);
        self
    }

    /// Rewrites the job's `report.json` as the user may download it: uploads named as the user
    /// named them, the server's folders (the job's, the model's) not at all.
    fn publish_report(&self, r: &EditReport) -> anyhow::Result<()> {
        let mut v = self.user_report(r);
        if let Some(c) = v.get_mut("checkpoint") {
            let name = Path::new(&r.checkpoint).file_name().map_or_else(
                || "the server's model".to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            *c = json!(name);
        }
        let text = serde_json::to_string_pretty(&v)?.replace(&self.dir.display().to_string(), "the job");
        let path = self.out().join("report.json");
        matedit_contract::io::write_atomically(&path, |tmp| Ok(std::fs::write(tmp, &text)?))
    }

    /// A finished job's file by the name its report lists (nothing else is reachable).
    pub fn file(&self, name: &str) -> Option<PathBuf> {
        match &*lock(&self.state) {
            State::Done(r) => r
                .files
                .iter()
                .map(String::as_str)
                .chain(["report.json"])
                .find(|f| *f == name)
                .map(|f| self.out().join(f)),
            _ => None,
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Why a job was not queued.
#[derive(Debug, thiserror::Error)]
#[error("{waiting} edits are waiting already, as many as this server queues; try again in a minute")]
pub struct Full {
    /// Jobs waiting.
    pub waiting: usize,
}

struct Inner {
    waiting: VecDeque<Arc<Job>>,
    jobs: HashMap<String, Arc<Job>>,
    finished: VecDeque<String>,
    stop: bool,
}

/// The queue, shared by the request handlers and the worker.
pub struct Queue {
    inner: Mutex<Inner>,
    ready: Condvar,
    capacity: usize,
    keep: usize,
    keep_bytes: u64,
}

/// Bytes of the files under `dir` (what a kept job holds on disk).
fn disk_use(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(Result::ok)
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => disk_use(&e.path()),
            Ok(_) => e.metadata().map_or(0, |m| m.len()),
            Err(_) => 0,
        })
        .sum()
}

impl Queue {
    /// At most `capacity` jobs waiting (beyond the one running); the last `keep` finished jobs
    /// (and their files) kept, as long as they hold at most `keep_bytes` on disk together.
    pub fn new(capacity: usize, keep: usize, keep_bytes: u64) -> Self {
        Self {
            inner: Mutex::new(Inner {
                waiting: VecDeque::new(),
                jobs: HashMap::new(),
                finished: VecDeque::new(),
                stop: false,
            }),
            ready: Condvar::new(),
            capacity: capacity.max(1),
            keep: keep.max(1),
            keep_bytes,
        }
    }

    /// How many may wait.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Whether a job could be queued now (checked before its upload is saved).
    pub fn has_room(&self) -> Result<(), Full> {
        let q = lock(&self.inner);
        if q.waiting.len() >= self.capacity {
            return Err(Full {
                waiting: q.waiting.len(),
            });
        }
        Ok(())
    }

    /// Queues `job`; returns its place (1: next).
    pub fn submit(&self, job: Job) -> Result<(Arc<Job>, usize), Full> {
        let mut q = lock(&self.inner);
        if q.waiting.len() >= self.capacity {
            return Err(Full {
                waiting: q.waiting.len(),
            });
        }
        let job = Arc::new(job);
        q.waiting.push_back(job.clone());
        q.jobs.insert(job.id.clone(), job.clone());
        let place = q.waiting.len();
        drop(q);
        self.ready.notify_all();
        Ok((job, place))
    }

    /// A job by id.
    pub fn get(&self, id: &str) -> Option<Arc<Job>> {
        lock(&self.inner).jobs.get(id).cloned()
    }

    /// 1 for the next job to run, 0 when not waiting.
    pub fn place(&self, id: &str) -> usize {
        lock(&self.inner)
            .waiting
            .iter()
            .position(|j| j.id == id)
            .map_or(0, |p| p + 1)
    }

    /// Cancels a job: a waiting one leaves the queue, a running one stops at its next check.
    pub fn cancel(&self, id: &str) -> Option<State> {
        let mut q = lock(&self.inner);
        let job = q.jobs.get(id).cloned()?;
        job.progress.cancel();
        if let Some(p) = q.waiting.iter().position(|j| j.id == id) {
            q.waiting.remove(p);
            job.set(State::Cancelled);
            lock(&job.reservation).take();
            self.retire(&mut q, &job);
        }
        Some(job.state())
    }

    /// Cancels the job that is running, if any (it stops at its next check).
    pub fn cancel_running(&self) {
        let q = lock(&self.inner);
        for job in q.jobs.values() {
            if matches!(job.state(), State::Running(_)) {
                job.progress.cancel();
            }
        }
    }

    /// Stops the worker after its current job.
    pub fn stop(&self) {
        lock(&self.inner).stop = true;
        self.ready.notify_all();
    }

    fn next(&self) -> Option<Arc<Job>> {
        let mut q = lock(&self.inner);
        loop {
            if q.stop {
                return None;
            }
            if let Some(j) = q.waiting.pop_front() {
                j.set(State::Running(Instant::now()));
                return Some(j);
            }
            q = self.ready.wait(q).unwrap_or_else(|p| p.into_inner());
        }
    }

    fn finish(&self, job: &Arc<Job>, state: State) {
        job.set(state);
        lock(&job.reservation).take();
        let mut q = lock(&self.inner);
        self.retire(&mut q, job);
    }

    /// Keeps the last `keep` finished jobs, and fewer when they hold more than `keep_bytes` on
    /// disk (the newest is always kept, whatever its size); older ones and their folders go.
    fn retire(&self, q: &mut Inner, job: &Arc<Job>) {
        *lock(&job.disk) = disk_use(&job.dir);
        q.finished.push_back(job.id.clone());
        let held = |q: &Inner| -> u64 {
            q.finished
                .iter()
                .filter_map(|id| q.jobs.get(id))
                .map(|j| *lock(&j.disk))
                .sum()
        };
        while q.finished.len() > self.keep || (q.finished.len() > 1 && held(q) > self.keep_bytes) {
            if let Some(old) = q.finished.pop_front()
                && let Some(j) = q.jobs.remove(&old)
            {
                let _ = std::fs::remove_dir_all(&j.dir);
            }
        }
    }

    /// A job's state for the page.
    pub fn status(&self, job: &Job, url: &str) -> Value {
        let progress = job.progress.snapshot();
        let mut v = json!({
            "id": job.id,
            "waited": job.submitted.elapsed().as_secs_f64(),
            "phase": progress.phase,
            "energies": progress.energies,
        });
        let state = job.state();
        let (name, extra) = match &state {
            State::Queued => ("queued", json!({ "place": self.place(&job.id) })),
            State::Running(t) => ("running", json!({ "running": t.elapsed().as_secs_f64() })),
            State::Done(r) => (
                "done",
                json!({
                    "files": r.files.iter().map(String::as_str).chain(["report.json"]).map(|f| json!({
                        "name": f, "url": format!("{url}/files/{f}")
                    })).collect::<Vec<_>>(),
                    "report": job.user_report(r),
                }),
            ),
            State::Failed(m) => ("failed", json!({ "error": m })),
            State::Cancelled => ("cancelled", json!({})),
        };
        v["state"] = json!(name);
        if let Some(s) = *lock(&job.finished_after) {
            v["seconds"] = json!(s);
        }
        if let (Value::Object(a), Value::Object(b)) = (&mut v, extra) {
            a.extend(b);
        }
        v
    }
}

/// The worker: runs queued jobs one after another until [`Queue::stop`]. A panic in a job fails
/// that job, not the server.
pub fn work(queue: &Queue, model: &Model) {
    while let Some(job) = queue.next() {
        let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(model, &job)));
        let state = match run {
            Ok(Ok(report)) => match job.publish_report(&report) {
                Ok(()) => State::Done(Box::new(report)),
                Err(e) => State::Failed(job.user_message(&format!("the report could not be written: {e:#}"))),
            },
            Ok(Err(e)) if e.downcast_ref::<Cancelled>().is_some() || job.progress.is_cancelled() => State::Cancelled,
            Ok(Err(e)) => State::Failed(job.user_message(&format!("{e:#}"))),
            Err(panic) => {
                let what = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                State::Failed(format!(
                    "internal error while editing ({what}); the server is still running"
                ))
            }
        };
        if matches!(state, State::Cancelled) {
            let _ = std::fs::remove_dir_all(job.out());
        }
        queue.finish(&job, state);
    }
}

fn run(model: &Model, job: &Job) -> anyhow::Result<EditReport> {
    let out = job.out();
    let watch = Watch {
        progress: Some(&job.progress),
        t0: Instant::now(),
    };
    match &job.work {
        Work::Edit(req) => edit_with(model, req, &out, watch),
        Work::Transfer {
            from,
            to,
            to_material,
            to_normals,
            optimize,
            composite,
        } => transfer_with(
            model,
            Pair {
                first: Given::photo(&from.0, from.1.as_deref()),
                second: Given {
                    material: to_material.as_deref(),
                    normals: to_normals.as_deref(),
                    ..Given::photo(&to.0, to.1.as_deref())
                },
                eq6: optimize.as_ref(),
                look: Look::chosen(Some(*composite), None, to_material.is_some()),
            },
            &out,
            watch,
        ),
    }
}

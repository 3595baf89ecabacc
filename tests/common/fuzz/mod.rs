//! Property-based fuzzing of the project's readers (shared by `tests/fuzz.rs`, `tests/fuzz_trainer.rs`
//! and `edit/tests/fuzz.rs`, which include this file by path).
//!
//! Every case takes a seed file (a real asset or one of the project's own outputs) and applies a
//! list of mutations drawn by proptest: bit flips, overwritten bytes, interesting binary values
//! (0, −1, 2³¹, NaN, ±Inf, huge counts; both byte orders), truncation, deletion, insertion,
//! repeated chunks (enormous counts and arrays), text tokens (NaN, 1e309, −1, 2³²…), numbers
//! replaced in place, deep nesting. The reader then runs on the mutated bytes, written to a file,
//! and must:
//! - not panic (proptest catches the panic and shrinks the case);
//! - finish within [`CASE_SECONDS`] (a watchdog aborts the process, writing the input, past
//!   [`HANG_SECONDS`]: a true hang cannot be caught any other way);
//! - not hold more memory than its input justifies: the peak of live heap bytes during the call,
//!   counted by this binary's allocator on every thread, stays under the reader's floor plus
//!   [`ALLOC_PER_INPUT_BYTE`] per input byte (a 1 KB file must not ask for gigabytes);
//! - return either a value that passes the reader's own validation or an error naming the file;
//! - leave the folder as it was (no partial output).
//!
//! A failing case is shrunk to a minimal mutation list, written to `target/fuzz-failures/`, and
//! reported; it then becomes a regression test. Cases per reader: the reader's CI count, times
//! `MATEDIT_FUZZ_SCALE` (the long run, docs/PERFORMANCE.md); the RNG seed is fixed unless
//! `MATEDIT_FUZZ_SEED` says otherwise, so CI runs the same cases every time. With
//! `MATEDIT_FUZZ_TRACE` set, every case's input is first written to
//! `target/fuzz-failures/NAME-last.bin`, for crashes that kill the process (stack overflows).
#![allow(dead_code)]

use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::{
    Config, FileFailurePersistence, RngAlgorithm, TestCaseError, TestError, TestRng, TestRunner,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

mod mutation;
mod seeds;
pub use mutation::*;
pub use seeds::*;

/// A case slower than this fails (release build; the readers take milliseconds).
pub const CASE_SECONDS: f64 = 20.0;
/// A case running this long is a hang: the process is aborted.
pub const HANG_SECONDS: u64 = 120;
/// Heap bytes a reader may hold per byte of input, above its floor, unless the reader says
/// otherwise.
pub const ALLOC_PER_INPUT_BYTE: usize = 64;
/// The same for EXR files, whose compression can legitimately expand a file up to
/// `EXR_MAX_EXPANSION` (4096) times; a reader holds up to three copies (samples, channels,
/// the caller's pixels).
pub const EXR_ALLOC_PER_INPUT_BYTE: usize = 3 * 4096;

/// Counts live heap bytes and their peak, on every thread (the fuzz tests of one binary run
/// one at a time, under [`SERIAL`]).
pub struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);
/// The largest single request seen since the last reset.
static LARGEST: AtomicUsize = AtomicUsize::new(0);
/// Requests beyond this are refused (the reader then aborts on allocation failure, loudly):
/// past it, overcommit would let a bad file take the machine down instead.
const REFUSE_BYTES: usize = 8 << 30;

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSE_BYTES {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded unchanged to the system allocator.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            note_alloc(layout.size());
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > REFUSE_BYTES {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded unchanged to the system allocator.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            note_alloc(layout.size());
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > REFUSE_BYTES {
            return std::ptr::null_mut();
        }
        // SAFETY: forwarded unchanged to the system allocator.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            note_alloc(new_size);
        }
        p
    }
}

fn note_alloc(size: usize) {
    let live = LIVE.fetch_add(size, Ordering::Relaxed) + size;
    PEAK.fetch_max(live, Ordering::Relaxed);
    LARGEST.fetch_max(size, Ordering::Relaxed);
}

/// One fuzz test at a time per binary, so that the heap counts belong to one reader.
pub static SERIAL: Mutex<()> = Mutex::new(());

/// Builds a test's inputs under [`SERIAL`]: a large seed built beside a running fuzz is charged
/// to the reader being fuzzed (CI, 2026-11-29: a 35 MB MERL table charged to a 676-byte EXR).
pub fn build_under_lock<T>(build: impl FnOnce() -> T) -> T {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    build()
}

/// What a reader made of one input: its validation's verdict.
pub type Verdict = Result<(), String>;

/// A reader under test.
pub struct Reader<'a> {
    /// Name for messages and for the failure file.
    pub name: &'static str,
    /// The file name the input is written under (its extension selects the format).
    pub file_name: &'a str,
    /// Seed files: (label, bytes).
    pub seeds: Vec<(String, Vec<u8>)>,
    /// Cases in CI.
    pub cases: u32,
    /// Heap bytes any input may use (the reader's fixed cost).
    pub floor_bytes: usize,
    /// Heap bytes per input byte above the floor (`None`: [`EXR_ALLOC_PER_INPUT_BYTE`] for a
    /// `.exr` file, else [`ALLOC_PER_INPUT_BYTE`]).
    pub per_input_byte: Option<usize>,
    /// The folder the input file is written into is prepared by this (e.g. a copy of a whole
    /// dataset) before every case; `None`: an empty folder.
    pub prepare: Option<&'a (dyn Fn(&Path) + Sync)>,
    /// Reads `path`; `Ok(Ok(()))` when the value passes the reader's own validation,
    /// `Ok(Err(why))` when it does not, `Err(message)` for the reader's error (which must name
    /// the file).
    pub read: &'a (dyn Fn(&Path) -> Result<Verdict, String> + Sync),
}

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

fn listing(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        if let Ok(rd) = std::fs::read_dir(&d) {
            for e in rd.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p.clone());
                }
                let len = e.metadata().map(|m| m.len()).unwrap_or(0);
                out.push((p, len));
            }
        }
    }
    out.sort();
    out
}

/// The outcome of a fuzz run, for the long-run record.
pub struct Summary {
    pub cases: u32,
    pub accepted: u32,
    pub refused: u32,
    pub seconds: f64,
}

/// Runs `reader` over its cases; panics with the minimal failing input (also written under
/// `target/fuzz-failures/`) if any case breaks a property.
pub fn fuzz(reader: &Reader<'_>) -> Summary {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let scale = env_u64("MATEDIT_FUZZ_SCALE").unwrap_or(1).max(1);
    let cases = (reader.cases as u64 * scale).min(u32::MAX as u64) as u32;
    let seed = env_u64("MATEDIT_FUZZ_SEED").unwrap_or(2017);
    let trace = std::env::var_os("MATEDIT_FUZZ_TRACE").is_some();
    let root = std::env::temp_dir().join(format!("matedit-fuzz-{}-{}", reader.name, std::process::id()));
    let case_dir = root.join("case");
    let manifest_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let workspace = manifest_dir
        .ancestors()
        .find(|a| a.join("Cargo.lock").is_file())
        .unwrap_or(manifest_dir);
    let failures = workspace.join("target/fuzz-failures");
    // Watchdog: the start of the running case (ms since `epoch`, 0: none) and its bytes.
    let epoch = Instant::now();
    let started = Arc::new(AtomicU64::new(0));
    let current: Arc<Mutex<Vec<u8>>> = Arc::new(Mutex::new(Vec::new()));
    let done = Arc::new(AtomicBool::new(false));
    let watchdog = {
        let (started, current, done) = (started.clone(), current.clone(), done.clone());
        let (name, failures) = (reader.name, failures.clone());
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(200));
                let s = started.load(Ordering::Relaxed);
                if s > 0 && epoch.elapsed().as_millis() as u64 > s + HANG_SECONDS * 1000 {
                    let _ = std::fs::create_dir_all(&failures);
                    let path = failures.join(format!("{name}-hang.bin"));
                    let bytes = current.lock().map(|b| b.clone()).unwrap_or_default();
                    let _ = std::fs::write(&path, bytes);
                    eprintln!(
                        "fuzz {name}: a case ran over {HANG_SECONDS} s; its input is in {}",
                        path.display()
                    );
                    std::process::abort();
                }
            }
        })
    };

    let config = Config {
        cases,
        failure_persistence: Some(Box::new(FileFailurePersistence::Off)),
        max_shrink_iters: 2048,
        ..Config::default()
    };
    let mut seed_bytes = [0u8; 32];
    seed_bytes[..8].copy_from_slice(&seed.to_le_bytes());
    let mut runner = TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &seed_bytes));
    let strategy = (0..reader.seeds.len(), prop::collection::vec(mutation(), 0..6));
    // proptest keeps each panic's message as the failure reason; the default hook would print
    // every one (with a backtrace) while the case shrinks.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let accepted = AtomicUsize::new(0);
    let refused = AtomicUsize::new(0);
    let t0 = Instant::now();
    let result = runner.run(&strategy, |(s, mutations)| {
        let bytes = apply(&reader.seeds[s].1, &mutations);
        if let Ok(mut c) = current.lock() {
            c.clone_from(&bytes);
        }
        if trace {
            // A crash that kills the process (a stack overflow) leaves its input here.
            let _ = std::fs::create_dir_all(&failures);
            let _ = std::fs::write(failures.join(format!("{}-last.bin", reader.name)), &bytes);
        }
        let watch = || started.store(epoch.elapsed().as_millis() as u64 + 1, Ordering::Relaxed);
        let accepted_case = check(reader, &case_dir, &bytes, &watch);
        started.store(0, Ordering::Relaxed);
        match accepted_case {
            Ok(true) => accepted.fetch_add(1, Ordering::Relaxed),
            Ok(false) => refused.fetch_add(1, Ordering::Relaxed),
            Err(why) => return Err(TestCaseError::fail(why)),
        };
        Ok(())
    });
    std::panic::set_hook(hook);
    done.store(true, Ordering::Relaxed);
    let _ = watchdog.join();
    let _ = std::fs::remove_dir_all(&root);
    match result {
        Ok(()) => {
            let s = Summary {
                cases,
                accepted: accepted.load(Ordering::Relaxed) as u32,
                refused: refused.load(Ordering::Relaxed) as u32,
                seconds: t0.elapsed().as_secs_f64(),
            };
            eprintln!(
                "fuzz {}: {} cases ({} accepted, {} refused) in {:.1} s, seed {seed}",
                reader.name, s.cases, s.accepted, s.refused, s.seconds
            );
            s
        }
        Err(TestError::Fail(why, (s, mutations))) => {
            let bytes = apply(&reader.seeds[s].1, &mutations);
            let _ = std::fs::create_dir_all(&failures);
            let path = failures.join(format!("{}.bin", reader.name));
            let _ = std::fs::write(&path, &bytes);
            panic!(
                "fuzz {}: {why}\nseed {} ({}), minimal mutations {mutations:?}\ninput written to {}",
                reader.name,
                s,
                reader.seeds[s].0,
                path.display()
            );
        }
        Err(TestError::Abort(why)) => panic!("fuzz {}: aborted: {why}", reader.name),
    }
}

/// One case: `bytes` written as the reader's file in `case_dir`, read, and every property
/// checked. `Ok(true)`: accepted, `Ok(false)`: refused with a good error; `Err`: a broken
/// property. `watch` is called as the read starts (the watchdog's clock).
fn check(reader: &Reader<'_>, case_dir: &Path, bytes: &[u8], watch: &dyn Fn()) -> Result<bool, String> {
    let _ = std::fs::remove_dir_all(case_dir);
    std::fs::create_dir_all(case_dir).map_err(|e| e.to_string())?;
    if let Some(prepare) = reader.prepare {
        prepare(case_dir);
    }
    let path = case_dir.join(reader.file_name);
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| e.to_string())?;
    }
    std::fs::write(&path, bytes).map_err(|e| e.to_string())?;
    let before = listing(case_dir);
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    LARGEST.store(0, Ordering::Relaxed);
    watch();
    let t = Instant::now();
    let outcome = (reader.read)(&path);
    let secs = t.elapsed().as_secs_f64();
    let held = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    let largest = LARGEST.load(Ordering::Relaxed);
    let per_byte = reader.per_input_byte.unwrap_or(if reader.file_name.ends_with(".exr") {
        EXR_ALLOC_PER_INPUT_BYTE
    } else {
        ALLOC_PER_INPUT_BYTE
    });
    let budget = reader.floor_bytes + per_byte * bytes.len();
    if secs >= CASE_SECONDS {
        return Err(format!("took {secs:.1} s on a {}-byte input", bytes.len()));
    }
    if held > budget || largest > budget {
        return Err(format!(
            "held {held} heap bytes (largest request {largest}) for a {}-byte input; budget {budget}",
            bytes.len()
        ));
    }
    let accepted = match outcome {
        Ok(Ok(())) => true,
        Ok(Err(why)) => return Err(format!("accepted a value its own validation refuses: {why}")),
        Err(message) => {
            let name = Path::new(reader.file_name)
                .file_name()
                .and_then(|n| n.to_str())
                .unwrap_or("");
            if !message.contains(name) && !message.contains(&*case_dir.to_string_lossy()) {
                return Err(format!("the error does not name the file: {message}"));
            }
            false
        }
    };
    if listing(case_dir) != before {
        return Err("the reader left files behind or changed them".into());
    }
    Ok(accepted)
}

/// A regression test: one input (a minimised failure of an earlier run) through every property.
/// Returns whether the reader accepted it.
pub fn regression(reader: &Reader<'_>, bytes: &[u8]) -> bool {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let dir = std::env::temp_dir().join(format!(
        "matedit-fuzz-regression-{}-{}",
        reader.name,
        std::process::id()
    ));
    let r = check(reader, &dir, bytes, &|| {});
    let _ = std::fs::remove_dir_all(&dir);
    r.unwrap_or_else(|why| panic!("fuzz regression {}: {why}", reader.name))
}

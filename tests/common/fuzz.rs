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

/// An interesting value written over bytes of the input.
#[derive(Clone, Copy, Debug)]
pub enum Value {
    U8(u8),
    U16(u16),
    U32(u32),
    U64(u64),
    F32(f32),
    F64(f64),
}

fn interesting() -> impl Strategy<Value = (Value, bool)> {
    let v = prop_oneof![
        prop::sample::select(vec![0u8, 1, 0x7f, 0x80, 0xff]).prop_map(Value::U8),
        prop::sample::select(vec![0u16, 1, 0x7fff, 0x8000, 0xffff]).prop_map(Value::U16),
        prop::sample::select(vec![
            0u32,
            1,
            2,
            0x7fff_ffff,
            0x8000_0000,
            0xffff_ffff,
            65_536,
            1 << 20,
            1 << 28
        ])
        .prop_map(Value::U32),
        prop::sample::select(vec![0u64, u64::MAX, 1 << 32, 1 << 40, i64::MAX as u64]).prop_map(Value::U64),
        prop::sample::select(vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -1.0,
            0.0,
            -0.0,
            f32::MAX,
            f32::MIN_POSITIVE,
            1e-45
        ])
        .prop_map(Value::F32),
        prop::sample::select(vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -1.0, f64::MAX, 1e-320])
            .prop_map(Value::F64),
    ];
    (v, any::<bool>())
}

fn value_bytes(v: Value, big_endian: bool) -> Vec<u8> {
    macro_rules! b {
        ($x:expr) => {
            if big_endian {
                $x.to_be_bytes().to_vec()
            } else {
                $x.to_le_bytes().to_vec()
            }
        };
    }
    match v {
        Value::U8(x) => vec![x],
        Value::U16(x) => b!(x),
        Value::U32(x) => b!(x),
        Value::U64(x) => b!(x),
        Value::F32(x) => b!(x),
        Value::F64(x) => b!(x),
    }
}

/// Tokens that text formats (OBJ, TOML, JSON, the Radiance header) must survive.
const TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e309",
    "-1e309",
    "-1",
    "-0",
    "0",
    "1e-320",
    "4294967296",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "99999999999999999999",
    "0x10",
    "\"",
    "'",
    "\\",
    "\n",
    "\r\n",
    "\t",
    "\0",
    "[",
    "]",
    "{",
    "}",
    ",",
    ":",
    "=",
    "#",
    "/",
    "//",
    "f",
    "v",
    "vn",
    "vt",
    "usemtl",
    "mtllib ../../../etc/passwd",
    "g",
    "o",
    "-Y +X 999999999",
    "FORMAT=32-bit_rle_rgbe",
    "é",
    "\u{feff}",
    "[[",
    "null",
    "true",
    "{}",
    "[]",
];

/// One change to the bytes of a seed.
#[derive(Clone, Debug)]
pub enum Mutation {
    Flip {
        at: Index,
        bit: u8,
    },
    Set {
        at: Index,
        byte: u8,
    },
    Overwrite {
        at: Index,
        value: Value,
        big_endian: bool,
    },
    Truncate {
        at: Index,
    },
    Delete {
        at: Index,
        len: u16,
    },
    Insert {
        at: Index,
        bytes: Vec<u8>,
    },
    /// A chunk of the input repeated many times in place: huge counts, enormous arrays.
    Repeat {
        at: Index,
        len: u8,
        times: u16,
    },
    Token {
        at: Index,
        token: Index,
    },
    /// The n-th run of ASCII digits (with sign, dot, exponent) replaced by a token.
    Number {
        nth: Index,
        token: Index,
    },
    /// An opening bracket repeated: deeply nested TOML/JSON.
    Nest {
        at: Index,
        open: u8,
        depth: u32,
    },
}

/// Positions drawn this way land in the first 512 bytes half of the time: headers are where
/// binary formats keep their sizes and counts.
fn position(len: usize, at: &Index, head_bias: bool) -> usize {
    if len == 0 {
        return 0;
    }
    if head_bias && at.index(2) == 0 {
        at.index(len.min(512))
    } else {
        at.index(len)
    }
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        3 => (any::<Index>(), 0u8..8).prop_map(|(at, bit)| Mutation::Flip { at, bit }),
        2 => (any::<Index>(), any::<u8>()).prop_map(|(at, byte)| Mutation::Set { at, byte }),
        3 => (any::<Index>(), interesting()).prop_map(|(at, (value, big_endian))| Mutation::Overwrite { at, value, big_endian }),
        1 => any::<Index>().prop_map(|at| Mutation::Truncate { at }),
        1 => (any::<Index>(), 1u16..512).prop_map(|(at, len)| Mutation::Delete { at, len }),
        1 => (any::<Index>(), prop::collection::vec(any::<u8>(), 1..16)).prop_map(|(at, bytes)| Mutation::Insert { at, bytes }),
        1 => (any::<Index>(), 1u8..64, 2u16..2000).prop_map(|(at, len, times)| Mutation::Repeat { at, len, times }),
        3 => (any::<Index>(), any::<Index>()).prop_map(|(at, token)| Mutation::Token { at, token }),
        3 => (any::<Index>(), any::<Index>()).prop_map(|(nth, token)| Mutation::Number { nth, token }),
        1 => (any::<Index>(), prop::sample::select(vec![b'[', b'{']), prop_oneof![1u32..64, 1000u32..200_000])
            .prop_map(|(at, open, depth)| Mutation::Nest { at, open, depth }),
    ]
}

/// Spans of ASCII numbers in `bytes`.
fn numbers(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i].is_ascii_digit() {
            let start = if i > 0 && bytes[i - 1] == b'-' { i - 1 } else { i };
            let mut j = i;
            while j < bytes.len() && (bytes[j].is_ascii_digit() || matches!(bytes[j], b'.' | b'e' | b'E' | b'+' | b'-'))
            {
                j += 1;
            }
            out.push((start, j));
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

/// The seed with the mutations applied in order.
pub fn apply(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for m in mutations {
        let len = b.len();
        match m {
            Mutation::Flip { at, bit } if len > 0 => {
                let i = position(len, at, true);
                b[i] ^= 1 << bit;
            }
            Mutation::Set { at, byte } if len > 0 => {
                let i = position(len, at, true);
                b[i] = *byte;
            }
            Mutation::Overwrite { at, value, big_endian } => {
                let v = value_bytes(*value, *big_endian);
                let i = position(len, at, true);
                for (k, x) in v.into_iter().enumerate() {
                    if i + k < b.len() {
                        b[i + k] = x;
                    } else {
                        b.push(x);
                    }
                }
            }
            Mutation::Truncate { at } => b.truncate(position(len, at, false)),
            Mutation::Delete { at, len: n } if len > 0 => {
                let i = position(len, at, false);
                let end = (i + *n as usize).min(len);
                b.drain(i..end);
            }
            Mutation::Insert { at, bytes } => {
                let i = position(len + 1, at, false);
                b.splice(i..i, bytes.iter().copied());
            }
            Mutation::Repeat { at, len: n, times } if len > 0 => {
                let i = position(len, at, false);
                let end = (i + *n as usize).min(len);
                let chunk = b[i..end].to_vec();
                let extra: Vec<u8> = chunk
                    .iter()
                    .copied()
                    .cycle()
                    .take(chunk.len() * *times as usize)
                    .collect();
                b.splice(end..end, extra);
            }
            Mutation::Token { at, token } => {
                let t = TOKENS[token.index(TOKENS.len())].as_bytes();
                let i = position(len + 1, at, false);
                b.splice(i..i, t.iter().copied());
            }
            Mutation::Number { nth, token } => {
                let spans = numbers(&b);
                if !spans.is_empty() {
                    let (s, e) = spans[nth.index(spans.len())];
                    let t = TOKENS[token.index(TOKENS.len())].as_bytes();
                    b.splice(s..e, t.iter().copied());
                }
            }
            Mutation::Nest { at, open, depth } => {
                let i = position(len + 1, at, false);
                b.splice(i..i, std::iter::repeat_n(*open, *depth as usize));
            }
            _ => {}
        }
    }
    b
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

/// The file at `path` if it exists (seeds from the eval assets are optional).
pub fn seed_file(path: &Path) -> Option<(String, Vec<u8>)> {
    std::fs::read(path).ok().map(|b| (path.display().to_string(), b))
}

/// `../shared/eval-assets` (or `$MATEDIT_EVAL_ASSETS`), when present.
pub fn eval_assets() -> Option<PathBuf> {
    let here = Path::new(env!("CARGO_MANIFEST_DIR"));
    let workspace = here
        .ancestors()
        .find(|a| a.join("Cargo.lock").is_file())
        .unwrap_or(here);
    let p = std::env::var_os("MATEDIT_EVAL_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace.join("../shared/eval-assets"));
    p.is_dir().then_some(p)
}

/// A Radiance file of `w × h` flat RGBE pixels, by hand (an independent writer).
pub fn radiance(w: usize, h: usize) -> Vec<u8> {
    let mut b = format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y {h} +X {w}\n").into_bytes();
    for i in 0..w * h {
        b.extend_from_slice(&[(i * 7 % 256) as u8, 90, 200, 128 + (i % 3) as u8]);
    }
    b
}

/// A tiny dataset (16² images, DSBRDF files, no fitting), rendered once per process.
pub fn dataset() -> &'static Path {
    static DIR: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        // Rendered in this process: under the lock, or its buffers would count against the
        // reader being fuzzed beside it (CI, 2026-11-27: 35 MB charged to a 92-byte .hdr).
        let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        let root = std::env::temp_dir().join(format!("matedit-fuzz-dataset-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let materials = [[0.8, 0.2, 0.1], [0.1, 0.5, 0.7], [0.4, 0.4, 0.4], [0.9, 0.9, 0.2]]
            .map(matedit_physics::brdf::Dsbrdf::near_lambertian);
        let manifest = include_str!("../fixtures/manifests/fuzz.toml");
        let sources = matedit_fixtures::Sources {
            manifest,
            materials: &materials,
            objs: &[],
        };
        matedit_fixtures::render_dataset(&root, "m.toml", &sources, "dataset")
    })
}

#[allow(unused_imports)]
pub use matedit_fixtures::copy_dir as copy_tree;

/// EXRs of `w × h` whose channel sets a reader of RGB may not expect: R and G only, Y only,
/// RGB stored as f16 and as u32, RGB with an extra channel. Written with the exr crate
/// directly (the project's writer only writes f32).
pub fn odd_exrs(w: usize, h: usize) -> Vec<(String, Vec<u8>)> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, SmallVec, WritableImage, f16,
    };
    let n = w * h;
    let ramp = |k: f32| (0..n).map(|i| (i as f32 * k).sin().abs()).collect::<Vec<f32>>();
    let f32s = |names: &[&str]| -> Vec<(String, FlatSamples)> {
        names
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), FlatSamples::F32(ramp(0.1 + k as f32 * 0.1))))
            .collect()
    };
    let sets: Vec<(&str, Vec<(String, FlatSamples)>)> = vec![
        ("R and G only", f32s(&["R", "G"])),
        ("Y only", f32s(&["Y"])),
        (
            "RGB as f16",
            ["R", "G", "B"]
                .iter()
                .map(|c| {
                    (
                        c.to_string(),
                        FlatSamples::F16(ramp(0.2).into_iter().map(f16::from_f32).collect()),
                    )
                })
                .collect(),
        ),
        (
            "RGB as u32",
            ["R", "G", "B"]
                .iter()
                .map(|c| (c.to_string(), FlatSamples::U32((0..n as u32).collect())))
                .collect(),
        ),
        ("RGB and Z", f32s(&["R", "G", "B", "Z"])),
    ];
    sets.into_iter()
        .map(|(label, channels)| {
            let list: Vec<AnyChannel<FlatSamples>> = channels
                .into_iter()
                .map(|(name, s)| AnyChannel::new(name.as_str(), s))
                .collect();
            let layer = Layer::new(
                (w, h),
                LayerAttributes::default(),
                Encoding::SMALL_LOSSLESS,
                AnyChannels::sort(SmallVec::from_vec(list)),
            );
            let mut bytes = std::io::Cursor::new(Vec::new());
            Image::from_layer(layer)
                .write()
                .non_parallel()
                .to_buffered(&mut bytes)
                .expect("EXR");
            (format!("exr {label} {w}×{h}"), bytes.into_inner())
        })
        .collect()
}

//! The source tree's shape: within each crate no module reaches itself through `crate::` and
//! `super::` paths (an import circle), so that each file can be read after the ones it uses.
//! Scans every crate's `src/`; a file's tests (from its first `#[cfg(test)]`) and `tests.rs`
//! files are left out, as are uses of an enclosing module (a child reading its parent's items).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// `a::b` for `src/a/b.rs` and `src/a/b/mod.rs`; `` for `lib.rs` and `main.rs`.
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap_or(file);
    let mut parts: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
    let last = parts.pop().unwrap_or_default();
    let stem = last.trim_end_matches(".rs");
    if !matches!(stem, "mod" | "lib" | "main") {
        parts.push(stem.to_string());
    }
    parts
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module paths named after `crate::` or `super::` in `code`, resolved from `module`.
fn referenced(module: &[String], code: &str) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    let bytes = code.as_bytes();
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut i = 0;
    while i < bytes.len() {
        let at_word = i == 0 || !ident(bytes[i - 1]);
        let (base, len) = if at_word && bytes[i..].starts_with(b"crate::") {
            (Vec::new(), 7)
        } else if at_word && bytes[i..].starts_with(b"super::") {
            let mut base = module.to_vec();
            let mut j = i;
            while bytes[j..].starts_with(b"super::") {
                base.pop();
                j += 7;
            }
            (base, j - i)
        } else {
            i += 1;
            continue;
        };
        i += len;
        i = paths(code, i, base, &mut found);
    }
    found
}

/// Parses `a::b::{c, d::e}` at `i`, pushing each full path onto `found`; returns where it ended.
fn paths(code: &str, mut i: usize, mut base: Vec<String>, found: &mut Vec<Vec<String>>) -> usize {
    let bytes = code.as_bytes();
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    loop {
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if i < bytes.len() && bytes[i] == b'{' {
            i += 1;
            loop {
                i = paths(code, i, base.clone(), found);
                while i < bytes.len() && (bytes[i].is_ascii_whitespace() || bytes[i] == b',') {
                    i += 1;
                }
                if i >= bytes.len() || bytes[i] == b'}' {
                    return i + 1;
                }
            }
        }
        let start = i;
        while i < bytes.len() && ident(bytes[i]) {
            i += 1;
        }
        if i > start {
            base.push(code[start..i].to_string());
        }
        if bytes[i..].starts_with(b"::") {
            i += 2;
        } else {
            found.push(base);
            return i;
        }
    }
}

/// Circles of `edges`, each as the modules on it (Tarjan's strongly connected components).
fn circles(edges: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    struct T<'a> {
        edges: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        out: Vec<Vec<String>>,
    }
    fn visit<'a>(t: &mut T<'a>, v: &'a str) {
        let n = t.index.len();
        t.index.insert(v, n);
        t.low.insert(v, n);
        t.stack.push(v);
        t.on.insert(v);
        if let Some(next) = t.edges.get(v) {
            for w in next {
                if !t.index.contains_key(w.as_str()) {
                    visit(t, w);
                    let l = t.low[w.as_str()].min(t.low[v]);
                    t.low.insert(v, l);
                } else if t.on.contains(w.as_str()) {
                    let l = t.index[w.as_str()].min(t.low[v]);
                    t.low.insert(v, l);
                }
            }
        }
        if t.low[v] == t.index[v] {
            let mut scc = Vec::new();
            while let Some(w) = t.stack.pop() {
                t.on.remove(w);
                scc.push(w.to_string());
                if w == v {
                    break;
                }
            }
            if scc.len() > 1 {
                scc.sort();
                t.out.push(scc);
            }
        }
    }
    let mut t = T {
        edges,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in edges.keys() {
        if !t.index.contains_key(v.as_str()) {
            visit(&mut t, v);
        }
    }
    t.out
}

/// The module graph of the crate whose sources are in `src`.
fn graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files.retain(|f| f.file_name().is_some_and(|n| n != "tests.rs"));
    let modules: BTreeSet<Vec<String>> = files.iter().map(|f| module_of(src, f)).collect();
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let code: String = text
            .lines()
            .take_while(|l| !l.trim_start().starts_with("#[cfg(test)]"))
            .filter(|l| !l.trim_start().starts_with("//"))
            .map(|l| l.split(" // ").next().unwrap_or(l))
            .collect::<Vec<_>>()
            .join("\n");
        let from = module_of(src, f);
        let entry = edges.entry(from.join("::")).or_default();
        for path in referenced(&from, &code) {
            // The longest prefix of the path that is a module file.
            let Some(to) = (0..=path.len())
                .rev()
                .map(|k| path[..k].to_vec())
                .find(|p| modules.contains(p))
            else {
                continue;
            };
            if to == from || from.starts_with(&to) {
                continue;
            }
            entry.insert(to.join("::"));
        }
    }
    edges
}

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn crate_sources() -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut dirs = vec![workspace()];
    while let Some(d) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else { continue };
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            if !p.is_dir()
                || name.starts_with('.')
                || matches!(name.as_str(), "target" | "out" | "shared" | "node_modules")
            {
                continue;
            }
            if name == "src" && d.join("Cargo.toml").is_file() {
                out.push(p);
            } else if p.strip_prefix(workspace()).map_or(0, |r| r.iter().count()) < 4 {
                dirs.push(p);
            }
        }
    }
    out.sort();
    out
}

#[test]
fn no_crate_has_an_import_circle() {
    let sources = crate_sources();
    for want in ["physics/src", "datagen/src", "trainer/src"] {
        assert!(
            sources.iter().any(|s| s.ends_with(want)),
            "{want} not found among {sources:?}"
        );
    }
    let mut found = Vec::new();
    for src in &sources {
        for c in circles(&graph(src)) {
            found.push(format!(
                "{}: {}",
                src.strip_prefix(workspace()).unwrap_or(src).display(),
                c.join(" → ")
            ));
        }
    }
    assert!(found.is_empty(), "import circles:\n{}", found.join("\n"));
}

/// The scanner itself, on a made-up crate: grouped imports, `super::super`, inline paths, a
/// parent's items, and tests left out.
#[test]
fn the_scanner_finds_a_circle_and_ignores_what_is_not_one() {
    let root = std::env::temp_dir().join(format!("matedit-structure-{}", std::process::id()));
    let src = root.join("src");
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(src.join("a/deep")).unwrap();
    let write = |p: &str, s: &str| std::fs::write(src.join(p), s).unwrap();
    write("lib.rs", "pub mod a;\npub mod b;\n");
    write("a/mod.rs", "pub mod x;\npub mod y;\npub mod deep;\npub struct Top;\n");
    write("a/x.rs", "use super::{Top, y::{Y, Z}};\n");
    write(
        "a/y.rs",
        "pub struct Y;\npub struct Z;\nfn f() { crate::a::deep::g::h(); }\n",
    );
    write("a/deep/mod.rs", "pub mod g;\n");
    write(
        "a/deep/g.rs",
        "use super::super::x::X; // x reaches y reaches deep::g reaches x\n",
    );
    write("b.rs", "#[cfg(test)]\nmod tests { use crate::a::x::X; }\n");
    let g = graph(&src);
    assert_eq!(g["a::x"], BTreeSet::from(["a::y".to_string()]));
    assert_eq!(g["a::y"], BTreeSet::from(["a::deep::g".to_string()]));
    assert!(g["b"].is_empty(), "{g:?}");
    assert_eq!(
        circles(&g),
        vec![vec!["a::deep::g".to_string(), "a::x".into(), "a::y".into()]]
    );
    // Break it: g no longer reaches x.
    write("a/deep/g.rs", "use crate::a::Top;\n");
    assert!(circles(&graph(&src)).is_empty());
    let _ = std::fs::remove_dir_all(&root);
}

#[test]
fn no_file_passes_700_lines() {
    let mut all = Vec::new();
    for src in crate_sources() {
        // The crate's sources, tests, examples and benches.
        for part in ["src", "tests", "examples", "benches"] {
            rust_files(&src.with_file_name(part), &mut all);
        }
    }
    all.sort();
    all.dedup();
    assert!(all.len() > 100, "only {} files found", all.len());
    let mut broken = Vec::new();
    for f in &all {
        let rel = f
            .strip_prefix(workspace())
            .unwrap_or(f)
            .to_string_lossy()
            .replace('\\', "/");
        let lines = std::fs::read_to_string(f).unwrap().lines().count();
        if lines > 700 {
            broken.push(format!("{rel}: {lines} lines (at most 700: split it along its seams)"));
        }
    }
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

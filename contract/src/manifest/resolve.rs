//! `extends` and `--set`: one manifest built from others, with every value traced to its line.
//!
//! A manifest may say `extends = "base.toml"` (relative to its own folder; the base may extend
//! another; a cycle is refused naming the files). The resolved manifest is the base with the file
//! laid over it: tables merged by key; arrays of tables whose entries all have a `name` (the
//! training manifests' `[[stages]]`) merged by name, an entry of a known name into that entry and
//! a new name appended; anything else replaced. Then each `--set PATH=VALUE`, in the order given.
//!
//! The result is rendered as TOML, one value per line (deeper tables inline), and each line keeps
//! where it came from, so that every later check, made on the resolved text as on any manifest,
//! still names the file and line that wrote the value, or the `--set` option. A manifest that
//! neither extends another nor is overridden resolves to its own text, byte for byte: its hash,
//! and the resume check of the runs made from it, are what they were before `extends`.

use super::{ManifestError, invalid, line_of, nested_too_deep};
use std::ops::Range;
use std::path::{Path, PathBuf};
use toml::de::{DeTable, DeValue};

/// The longest chain of `extends` followed (a chain this long is a mistake, not a design).
pub const MAX_EXTENDS: usize = 16;

/// Where a line of a resolved manifest came from.
#[derive(Clone, Debug, PartialEq)]
pub enum Origin {
    /// A manifest file, at a 1-based line.
    File {
        /// The file.
        path: PathBuf,
        /// Its line.
        line: usize,
    },
    /// A `--set` option, as given.
    Set(String),
}

/// One line of the rendered manifest: its origin and the field it writes (empty for headers).
#[derive(Clone, Debug)]
struct Line {
    origin: Origin,
    field: String,
}

/// A manifest, resolved: its `extends` chain followed and its `--set` options applied.
#[derive(Clone, Debug)]
pub struct Resolved {
    /// The manifest named on the command line.
    pub path: PathBuf,
    /// The resolved text (the file's own text when it neither extends nor is overridden).
    pub text: String,
    /// The files it was built from, the named one first.
    pub files: Vec<PathBuf>,
    /// The `--set` options applied, in order.
    pub sets: Vec<String>,
    /// Each line's origin; empty when `text` is the file's own.
    lines: Vec<Line>,
}

impl Resolved {
    /// A manifest's own text, as it is (no `extends` followed, no option applied).
    pub fn plain(path: &Path, text: String) -> Resolved {
        Resolved {
            path: path.to_path_buf(),
            text,
            files: vec![path.to_path_buf()],
            sets: Vec::new(),
            lines: Vec::new(),
        }
    }

    /// Reads `path`, follows its `extends` and applies `sets` (each `PATH=VALUE`).
    pub fn read(path: &Path, sets: &[String]) -> Result<Resolved, ManifestError> {
        let text = super::read_text(path)?;
        Self::resolve(path, text, sets)
    }

    /// [`Resolved::read`] of text already read from `path`.
    pub fn resolve(path: &Path, text: String, sets: &[String]) -> Result<Resolved, ManifestError> {
        // Text nested too deep or not TOML is left to the manifest's own parser, which says
        // where (and parses nothing first: the nesting guard protects the stack).
        if nested_too_deep(&text).is_some() {
            return Ok(Self::plain(path, text));
        }
        let extends = match DeTable::parse(&text) {
            Ok(t) => t.get_ref().contains_key("extends"),
            Err(_) => false,
        };
        if !extends && sets.is_empty() {
            return Ok(Self::plain(path, text));
        }
        let mut files = Vec::new();
        let mut root = read_chain(path, Some(text), &mut files)?;
        for option in sets {
            apply_set(&mut root, option)?;
        }
        let mut header = vec![format!(
            "# The resolved manifest of {}: written by `extends` and `--set`, not by hand.",
            path.display()
        )];
        if files.len() > 1 {
            let chain: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
            header.push(format!("# extends: {}", chain.join(" → ")));
        }
        for s in sets {
            header.push(format!("# --set {s}"));
        }
        let top = Origin::File {
            path: path.to_path_buf(),
            line: 1,
        };
        let mut out = Render::default();
        for h in header {
            out.line(h, &top, "");
        }
        out.document(&root, &top);
        Ok(Resolved {
            path: path.to_path_buf(),
            text: out.text,
            files,
            sets: sets.to_vec(),
            lines: out.lines,
        })
    }

    /// Whether the text is the file's own.
    pub fn is_plain(&self) -> bool {
        self.lines.is_empty()
    }

    /// Where byte `offset` of the text came from.
    pub fn origin(&self, offset: usize) -> Origin {
        let line = line_of(&self.text, offset);
        match self.lines.get(line - 1) {
            Some(l) => l.origin.clone(),
            None => Origin::File {
                path: self.path.clone(),
                line: if self.lines.is_empty() { line } else { 1 },
            },
        }
    }

    /// `FILE:LINE` or `--set OPTION`: where byte `offset` came from, for a message.
    pub fn place(&self, offset: usize) -> String {
        match self.origin(offset) {
            Origin::File { path, line } => format!("{}:{line}", path.display()),
            Origin::Set(s) => format!("--set {s}"),
        }
    }

    /// The folder a relative path written at `offset` is relative to: its file's (the working
    /// directory for a `--set` option).
    pub fn folder_of(&self, offset: usize) -> PathBuf {
        match self.origin(offset) {
            Origin::File { path, .. } => path.parent().map(Path::to_path_buf).unwrap_or_default(),
            Origin::Set(_) => PathBuf::new(),
        }
    }

    /// A [`ManifestError::Invalid`] (or [`ManifestError::Set`]) at `span` of the text, named by
    /// where that line came from.
    pub fn invalid(&self, span: Range<usize>, field: &str, message: impl Into<String>) -> ManifestError {
        if self.is_plain() {
            return invalid(&self.path, &self.text, span, field, message);
        }
        match self.origin(span.start) {
            Origin::File { path, line } => ManifestError::Invalid {
                file: path.display().to_string(),
                line,
                field: field.to_string(),
                message: message.into(),
            },
            Origin::Set(option) => ManifestError::Set {
                option,
                field: field.to_string(),
                message: message.into(),
            },
        }
    }

    /// The value of a named choice, or a located error listing the accepted names.
    pub fn choice<T: super::Named>(
        &self,
        value: &toml::Spanned<super::Choice<T>>,
        field: &str,
    ) -> Result<T, ManifestError> {
        match value.get_ref() {
            super::Choice::Known(v, _) => Ok(*v),
            super::Choice::Unknown(name) => Err(self.invalid(value.span(), field, T::refusal(name))),
        }
    }

    /// Parses the text into `T`: [`super::parse_toml`] for a file's own text; for a resolved one,
    /// a wrong type, a missing or an unknown field named by the line it came from.
    pub fn parse<T: serde::de::DeserializeOwned>(&self) -> Result<T, ManifestError> {
        if self.is_plain() {
            return super::parse_toml(&self.path, &self.text);
        }
        toml::from_str(&self.text).map_err(|e| {
            let at = e.span().map_or(0, |s| s.start);
            let field = self
                .lines
                .get(line_of(&self.text, at) - 1)
                .map(|l| l.field.clone())
                .unwrap_or_default();
            let field = if field.is_empty() { "(table)".to_string() } else { field };
            self.invalid(at..at, &field, e.message().trim_end())
        })
    }
}

/// A value node of the merged tree.
#[derive(Clone, Debug)]
enum Node {
    /// Anything but a table or an array of tables.
    Leaf(toml::Value),
    /// A table (a `[section]` or an inline table).
    Table(Table),
    /// An array of tables (`[[stages]]`), each entry an [`Item`] holding a [`Node::Table`].
    Tables(Vec<Item>),
}

/// A node and where it was written (its key's line; an array entry's header line).
#[derive(Clone, Debug)]
struct Item {
    node: Node,
    origin: Origin,
}

/// Keys in the order they were written (the base's first, then those a later file adds).
#[derive(Clone, Debug, Default)]
struct Table {
    entries: Vec<(String, Item)>,
}

impl Table {
    fn get_mut(&mut self, key: &str) -> Option<&mut Item> {
        self.entries.iter_mut().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    /// The `name` an array entry is merged by.
    fn name(&self) -> Option<&str> {
        self.entries
            .iter()
            .find(|(k, _)| k == "name")
            .and_then(|(_, v)| match &v.node {
                Node::Leaf(toml::Value::String(s)) => Some(s.as_str()),
                _ => None,
            })
    }
}

/// Reads `path` (its `text` when already read) and the files it extends, merged; `files`
/// collects the chain, the named file first.
fn read_chain(path: &Path, text: Option<String>, files: &mut Vec<PathBuf>) -> Result<Table, ManifestError> {
    let text = match text {
        Some(t) => t,
        None => super::read_text(path)?,
    };
    let syntax = |message: String| ManifestError::Syntax {
        file: path.display().to_string(),
        message,
    };
    if let Some(line) = nested_too_deep(&text) {
        return Err(syntax(format!(
            "line {line}: brackets and braces nested more than {} deep",
            super::MAX_NESTING
        )));
    }
    let doc = DeTable::parse(&text).map_err(|e| syntax(e.to_string().trim_end().to_string()))?;
    let mut table = convert(doc.get_ref(), path, &text)?;
    let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    files.push(path.to_path_buf());
    let Some(pos) = table.entries.iter().position(|(k, _)| k == "extends") else {
        return Ok(table);
    };
    let (_, item) = table.entries.remove(pos);
    let line = match &item.origin {
        Origin::File { line, .. } => *line,
        Origin::Set(_) => 1,
    };
    let bad = |message: String| ManifestError::Invalid {
        file: path.display().to_string(),
        line,
        field: "extends".into(),
        message,
    };
    let Node::Leaf(toml::Value::String(written)) = item.node else {
        return Err(bad("the path of one manifest, as a string".into()));
    };
    let base = path.parent().unwrap_or(Path::new("")).join(&written);
    let base_canonical =
        std::fs::canonicalize(&base).map_err(|e| bad(format!("{}: cannot read: {e}", base.display())))?;
    let seen: Vec<PathBuf> = files
        .iter()
        .map(|f| std::fs::canonicalize(f).unwrap_or_else(|_| f.clone()))
        .collect();
    if base_canonical == canonical || seen.contains(&base_canonical) {
        let chain: Vec<String> = files
            .iter()
            .map(|f| f.display().to_string())
            .chain([base.display().to_string()])
            .collect();
        return Err(bad(format!("a cycle: {}", chain.join(" → "))));
    }
    if files.len() >= MAX_EXTENDS {
        return Err(bad(format!("more than {MAX_EXTENDS} manifests in one extends chain")));
    }
    let mut merged = read_chain(&base, None, files)?;
    overlay(&mut merged, table);
    Ok(merged)
}

/// The merge tree of a parsed file, its keys in the order written.
fn convert(t: &DeTable, path: &Path, text: &str) -> Result<Table, ManifestError> {
    let mut entries: Vec<_> = t.iter().collect();
    entries.sort_by_key(|(k, _)| k.span().start);
    let mut out = Table::default();
    for (k, v) in entries {
        let origin = Origin::File {
            path: path.to_path_buf(),
            line: line_of(text, k.span().start),
        };
        let node = node(v, path, text)?;
        out.entries.push((k.get_ref().to_string(), Item { node, origin }));
    }
    Ok(out)
}

fn node(v: &toml::Spanned<DeValue>, path: &Path, text: &str) -> Result<Node, ManifestError> {
    Ok(match v.get_ref() {
        DeValue::Table(t) => Node::Table(convert(t, path, text)?),
        DeValue::Array(a) if !a.is_empty() && a.iter().all(|e| e.get_ref().is_table()) => {
            let mut items = Vec::new();
            for e in a.iter() {
                let DeValue::Table(t) = e.get_ref() else {
                    unreachable!("checked above")
                };
                items.push(Item {
                    node: Node::Table(convert(t, path, text)?),
                    origin: Origin::File {
                        path: path.to_path_buf(),
                        line: line_of(text, e.span().start),
                    },
                });
            }
            Node::Tables(items)
        }
        _ => {
            let written = text.get(v.span()).unwrap_or("");
            let value = written.parse::<toml::Value>().map_err(|e| ManifestError::Invalid {
                file: path.display().to_string(),
                line: line_of(text, v.span().start),
                field: String::new(),
                message: format!("cannot read the value {written:?}: {}", e.message()),
            })?;
            Node::Leaf(value)
        }
    })
}

/// Lays `over` over `base` (the module's rules).
fn overlay(base: &mut Table, over: Table) {
    for (key, item) in over.entries {
        let Some(b) = base.get_mut(&key) else {
            base.entries.push((key, item));
            continue;
        };
        match (&mut b.node, item.node) {
            (Node::Table(bt), Node::Table(ot)) => overlay(bt, ot),
            (Node::Tables(bs), Node::Tables(os)) if named(bs) && named(&os) => {
                for o in os {
                    let name = entry_table(&o).and_then(Table::name).map(str::to_owned);
                    match bs
                        .iter_mut()
                        .find(|e| entry_table(e).and_then(Table::name) == name.as_deref())
                    {
                        Some(existing) => {
                            if let (Node::Table(et), Node::Table(ot)) = (&mut existing.node, o.node) {
                                overlay(et, ot);
                            }
                        }
                        None => bs.push(o),
                    }
                }
            }
            (_, node) => {
                *b = Item {
                    node,
                    origin: item.origin,
                }
            }
        }
    }
}

fn entry_table(i: &Item) -> Option<&Table> {
    match &i.node {
        Node::Table(t) => Some(t),
        _ => None,
    }
}

fn named(items: &[Item]) -> bool {
    items.iter().all(|i| entry_table(i).and_then(Table::name).is_some())
}

/// The rendered text and each line's origin.
#[derive(Default)]
struct Render {
    text: String,
    lines: Vec<Line>,
}

impl Render {
    fn line(&mut self, s: String, origin: &Origin, field: &str) {
        self.text.push_str(&s);
        self.text.push('\n');
        self.lines.push(Line {
            origin: origin.clone(),
            field: field.to_string(),
        });
    }

    /// Top-level values first, then `[sections]`, then `[[arrays]]` (TOML's order).
    fn document(&mut self, root: &Table, top: &Origin) {
        for (k, item) in &root.entries {
            if let Node::Leaf(_) = item.node {
                self.line(format!("{} = {}", key(k), inline(&item.node)), &item.origin, k);
            }
        }
        for (k, item) in &root.entries {
            if let Node::Table(t) = &item.node {
                self.line(String::new(), top, "");
                self.line(format!("[{}]", key(k)), &item.origin, k);
                self.body(t, k);
            }
        }
        for (k, item) in &root.entries {
            if let Node::Tables(items) = &item.node {
                for (i, e) in items.iter().enumerate() {
                    let field = format!("{k}[{i}]");
                    self.line(String::new(), top, "");
                    self.line(format!("[[{}]]", key(k)), &e.origin, &field);
                    if let Node::Table(t) = &e.node {
                        self.body(t, &field);
                    }
                }
            }
        }
    }

    fn body(&mut self, t: &Table, at: &str) {
        for (k, item) in &t.entries {
            self.line(
                format!("{} = {}", key(k), inline(&item.node)),
                &item.origin,
                &format!("{at}.{k}"),
            );
        }
    }
}

/// A value on one line (toml's own writer gives a string with a line break as a multi-line
/// string, which would break the one-value-per-line map).
fn value_inline(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => quoted(s),
        toml::Value::Array(a) => format!("[{}]", a.iter().map(value_inline).collect::<Vec<_>>().join(", ")),
        toml::Value::Table(t) if t.is_empty() => "{}".into(),
        toml::Value::Table(t) => format!(
            "{{ {} }}",
            t.iter()
                .map(|(k, v)| format!("{} = {}", key(k), value_inline(v)))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        other => other.to_string(),
    }
}

/// A TOML basic string on one line.
fn quoted(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c if c.is_control() => out.push_str(&format!("\\u{:04X}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A key, bare where TOML allows.
fn key(k: &str) -> String {
    if !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        k.to_string()
    } else {
        quoted(k)
    }
}

/// A node on one line.
fn inline(n: &Node) -> String {
    match n {
        Node::Leaf(v) => value_inline(v),
        Node::Table(t) => {
            let parts: Vec<String> = t
                .entries
                .iter()
                .map(|(k, i)| format!("{} = {}", key(k), inline(&i.node)))
                .collect();
            if parts.is_empty() {
                "{}".into()
            } else {
                format!("{{ {} }}", parts.join(", "))
            }
        }
        Node::Tables(items) => {
            let parts: Vec<String> = items.iter().map(|i| inline(&i.node)).collect();
            format!("[{}]", parts.join(", "))
        }
    }
}

mod set;
use set::apply_set;

#[cfg(test)]
mod tests;

//! `--set PATH=VALUE`: one field of a resolved manifest overridden from the command line.

use super::super::{MAX_NESTING, ManifestError, nested_too_deep};
use super::{Item, Node, Origin, Table, entry_table, overlay};

/// One step of a `--set` path: `key`, `[N]` or `[NAME]`.
#[derive(Debug, PartialEq)]
enum Step {
    Key(String),
    Index(usize),
    Name(String),
}

/// `stages[1].steps`, `stages[joint].steps`, `model.widths`.
fn parse_path(p: &str) -> Result<Vec<Step>, String> {
    let mut steps = Vec::new();
    let mut rest = p;
    loop {
        let end = rest.find(['.', '[']).unwrap_or(rest.len());
        let key = &rest[..end];
        if key.is_empty() || !key.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
            return Err(format!(
                "{p:?} is not a field path (keys separated by dots, e.g. stages[1].steps)"
            ));
        }
        steps.push(Step::Key(key.to_string()));
        rest = &rest[end..];
        while let Some(r) = rest.strip_prefix('[') {
            let close = r.find(']').ok_or_else(|| format!("an unclosed [ in {p:?}"))?;
            let inner = &r[..close];
            if inner.is_empty() {
                return Err(format!("an empty [] in {p:?}"));
            }
            steps.push(match inner.parse::<usize>() {
                Ok(n) => Step::Index(n),
                Err(_) => Step::Name(inner.to_string()),
            });
            rest = &r[close + 1..];
        }
        match rest.strip_prefix('.') {
            Some(r) => rest = r,
            None if rest.is_empty() => return Ok(steps),
            None => return Err(format!("{p:?} is not a field path (expected . after ])")),
        }
    }
}

/// The value of a `--set`: TOML (`60`, `1e-4`, `"text"`, `[[0, 1e-4]]`, `{ a = 1 }`), or, where
/// it is not TOML and has no quote, bracket or brace, the text as a string (`--set
/// run.device=wgpu`).
fn parse_value(v: &str) -> Result<toml::Value, String> {
    if nested_too_deep(v).is_some() {
        return Err(format!("brackets and braces nested more than {MAX_NESTING} deep"));
    }
    match v.parse::<toml::Value>() {
        Ok(value) => Ok(value),
        Err(_) if !v.is_empty() && !v.contains(['"', '\'', '[', ']', '{', '}', '\n']) => {
            Ok(toml::Value::String(v.to_string()))
        }
        Err(e) => Err(format!("{v:?} is not a TOML value: {}", e.message())),
    }
}

/// Applies one `PATH=VALUE` option.
pub(super) fn apply_set(root: &mut Table, option: &str) -> Result<(), ManifestError> {
    // An option is echoed whole unless it is long (a value pasted by mistake).
    let shown: String = if option.chars().count() > 120 {
        option.chars().take(100).chain("…".chars()).collect()
    } else {
        option.to_string()
    };
    let fail = |field: &str, message: String| ManifestError::Set {
        option: shown.clone(),
        field: field.to_string(),
        message,
    };
    let Some((path, value)) = option.split_once('=') else {
        return Err(fail("", "expected PATH=VALUE (e.g. stages[1].steps=60)".into()));
    };
    let path = path.trim();
    let steps = parse_path(path).map_err(|e| fail(path, e))?;
    if steps.first() == Some(&Step::Key("extends".into())) {
        return Err(fail(
            path,
            "extends is the manifest's own; name another manifest instead".into(),
        ));
    }
    let value = parse_value(value.trim()).map_err(|e| fail(path, e))?;
    let origin = Origin::Set(option.to_string());
    let node = from_value(value, &origin);
    set_in(root, &steps, node, &origin).map_err(|e| fail(path, e))
}

/// A value given on the command line as a merge node (its tables merge-able like a file's).
fn from_value(v: toml::Value, origin: &Origin) -> Node {
    match v {
        toml::Value::Table(t) => Node::Table(Table {
            entries: t
                .into_iter()
                .map(|(k, v)| {
                    (
                        k,
                        Item {
                            node: from_value(v, origin),
                            origin: origin.clone(),
                        },
                    )
                })
                .collect(),
        }),
        toml::Value::Array(a) if !a.is_empty() && a.iter().all(toml::Value::is_table) => Node::Tables(
            a.into_iter()
                .map(|v| Item {
                    node: from_value(v, origin),
                    origin: origin.clone(),
                })
                .collect(),
        ),
        other => Node::Leaf(other),
    }
}

fn set_in(t: &mut Table, steps: &[Step], node: Node, origin: &Origin) -> Result<(), String> {
    let Some((Step::Key(key), rest)) = steps.split_first() else {
        return Err("a field path starts with a key".into());
    };
    match rest.first() {
        None => {
            match t.get_mut(key) {
                // A table given whole merges as a file's would.
                Some(Item {
                    node: Node::Table(existing),
                    ..
                }) if matches!(node, Node::Table(_)) => {
                    if let Node::Table(given) = node {
                        overlay(existing, given);
                    }
                }
                Some(item) => {
                    *item = Item {
                        node,
                        origin: origin.clone(),
                    }
                }
                None => t.entries.push((
                    key.clone(),
                    Item {
                        node,
                        origin: origin.clone(),
                    },
                )),
            }
            Ok(())
        }
        Some(Step::Key(_)) => {
            if t.get_mut(key).is_none() {
                t.entries.push((
                    key.clone(),
                    Item {
                        node: Node::Table(Table::default()),
                        origin: origin.clone(),
                    },
                ));
            }
            match t.get_mut(key).map(|i| &mut i.node) {
                Some(Node::Table(inner)) => set_in(inner, rest, node, origin),
                _ => Err(format!("{key} is a value, not a table")),
            }
        }
        Some(selector) => {
            let Some(Node::Tables(items)) = t.get_mut(key).map(|i| &mut i.node) else {
                return Err(format!("{key} is not an array of tables"));
            };
            let count = items.len();
            let entry = match selector {
                Step::Index(n) => items
                    .get_mut(*n)
                    .ok_or_else(|| format!("{key}[{n}]: there are {count} (numbered from 0)"))?,
                Step::Name(name) => {
                    let names: Vec<String> = items
                        .iter()
                        .filter_map(|i| entry_table(i).and_then(Table::name).map(str::to_owned))
                        .collect();
                    items
                        .iter_mut()
                        .find(|i| entry_table(i).and_then(Table::name) == Some(name.as_str()))
                        .ok_or_else(|| format!("no entry of {key} is named {name:?} ({})", names.join(", ")))?
                }
                Step::Key(_) => unreachable!("matched above"),
            };
            let Node::Table(inner) = &mut entry.node else {
                return Err(format!("{key} is not an array of tables"));
            };
            if rest.len() < 2 {
                return Err(format!("name a field of the entry of {key}, e.g. {key}[0].name"));
            }
            set_in(inner, &rest[1..], node, origin)
        }
    }
}

//! The manifest error kit both manifests use (datagen's dataset manifests and the trainer's):
//! reading, parsing with a guard on nesting, and problems located as `FILE:LINE: FIELD: message`.
//! Syntax and type errors come from the TOML parser with their line and column.

use serde::de::DeserializeOwned;
use std::path::Path;

/// A manifest problem, located in the file.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file cannot be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The manifest path.
        file: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// Not valid TOML, a wrong type, a missing or an unknown field (the parser's message
    /// names the line, the column and the field).
    #[error("{file}: {message}")]
    Syntax {
        /// The manifest path.
        file: String,
        /// The parser's message.
        message: String,
    },
    /// A value that parses but cannot be honoured.
    #[error("{file}:{line}: {field}: {message}")]
    Invalid {
        /// The manifest path.
        file: String,
        /// 1-based line of the field (or of its table).
        line: usize,
        /// Dotted field path, e.g. `splits[1].shapes.car`.
        field: String,
        /// What is wrong and what would be accepted.
        message: String,
    },
}

/// The deepest nesting of `[` and `{` a manifest may have (the shipped ones reach 2).
pub const MAX_NESTING: usize = 32;

/// The line where `[`/`{` first nest deeper than [`MAX_NESTING`], outside strings and comments
/// (a rough TOML lexer: enough to count brackets). The toml crate guards its parser's recursion,
/// but not every path: a file found by fuzzing (an unclosed inline table repeated 1,900 times,
/// which TOML 1.1's multi-line inline tables let run on) overflowed a 2 MB thread stack.
pub fn nested_too_deep(text: &str) -> Option<usize> {
    let (mut depth, mut line) = (0_usize, 1_usize);
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\n' => line += 1,
            '#' => {
                while chars.peek().is_some_and(|&c| c != '\n') {
                    chars.next();
                }
            }
            '"' | '\'' => {
                // Basic strings may escape the quote; literal strings may not. Multi-line strings
                // are skipped as consecutive strings, which is all the counting needs.
                while let Some(d) = chars.next() {
                    if d == '\n' {
                        line += 1;
                    } else if c == '"' && d == '\\' {
                        chars.next();
                    } else if d == c {
                        break;
                    }
                }
            }
            '[' | '{' => {
                depth += 1;
                if depth > MAX_NESTING {
                    return Some(line);
                }
            }
            ']' | '}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    None
}

/// Reads a manifest's text.
pub fn read_text(path: &Path) -> Result<String, ManifestError> {
    std::fs::read_to_string(path).map_err(|source| ManifestError::Io {
        file: path.display().to_string(),
        source,
    })
}

/// Parses manifest `text` that came from `path` into `T`, refusing nesting deeper than
/// [`MAX_NESTING`] first.
pub fn parse_toml<T: DeserializeOwned>(path: &Path, text: &str) -> Result<T, ManifestError> {
    if let Some(line) = nested_too_deep(text) {
        return Err(ManifestError::Syntax {
            file: path.display().to_string(),
            message: format!("line {line}: brackets and braces nested more than {MAX_NESTING} deep"),
        });
    }
    toml::from_str(text).map_err(|e| ManifestError::Syntax {
        file: path.display().to_string(),
        message: e.to_string().trim_end().to_string(),
    })
}

/// The 1-based line of byte `offset` in `text` (line 1 for defaults, which have no span).
pub fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() + 1
}

/// A [`ManifestError::Invalid`] at `span` of the manifest `text` read from `path`.
pub fn invalid(
    path: &Path,
    text: &str,
    span: std::ops::Range<usize>,
    field: &str,
    message: impl Into<String>,
) -> ManifestError {
    ManifestError::Invalid {
        file: path.display().to_string(),
        line: line_of(text, span.start),
        field: field.to_string(),
        message: message.into(),
    }
}

/// Expands `${NAME}` from the environment.
pub fn expand_vars(s: &str) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = s;
    while let Some(start) = rest.find("${") {
        out.push_str(&rest[..start]);
        let after = &rest[start + 2..];
        let end = after.find('}').ok_or_else(|| format!("unclosed ${{ in {s:?}"))?;
        let name = &after[..end];
        let value = std::env::var(name).map_err(|_| format!("environment variable {name} is not set"))?;
        out.push_str(&value);
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nesting_is_counted_outside_strings_and_comments() {
        for dir in ["../manifests", "../manifests/train", "../manifests/experiments"] {
            for e in std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(dir)).unwrap() {
                let p = e.unwrap().path();
                if p.extension().is_some_and(|x| x == "toml") {
                    assert_eq!(
                        nested_too_deep(&std::fs::read_to_string(&p).unwrap()),
                        None,
                        "{}",
                        p.display()
                    );
                }
            }
        }
        let deep = format!("a = 1\nb = {}1{}\n", "[".repeat(33), "]".repeat(33));
        assert_eq!(nested_too_deep(&deep), Some(2));
        assert_eq!(
            nested_too_deep(&format!("b = {}1{}", "[".repeat(32), "]".repeat(32))),
            None
        );
        let quoted = format!(
            "s = \"{}\"\nt = '{}'\n# {}\nu = \"\\\"{}\"",
            "[".repeat(99),
            "{".repeat(99),
            "[".repeat(99),
            "[".repeat(99)
        );
        assert_eq!(nested_too_deep(&quoted), None);
        // An unclosed inline table repeated: the shape of the file that overflowed the stack.
        let run_on = "[[splits]]\nshapes = { car = 1\n".repeat(40);
        assert_eq!(nested_too_deep(&run_on), Some(63), "the header of the 32nd repetition");
    }
}

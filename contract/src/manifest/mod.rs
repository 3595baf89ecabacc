//! The manifest error kit both manifests use (datagen's dataset manifests and the trainer's):
//! reading, parsing with a guard on nesting, and problems located as `FILE:LINE: FIELD: message`.
//! Syntax and type errors come from the TOML parser with their line and column. A manifest built
//! from others (`extends`, `--set`) is resolved first ([`resolve`]), and its problems are named
//! by the file and line, or the option, that wrote the value.

pub mod resolve;

pub use resolve::{Origin, Resolved};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::path::Path;
use toml::Spanned;

/// A manifest problem, located in the file.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file cannot be read.
    #[error("{file}: cannot read: {cause}")]
    Io {
        /// The manifest path.
        file: String,
        /// The underlying error.
        cause: std::io::Error,
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
    /// A `--set PATH=VALUE` option that cannot be applied, or that gave a value which cannot
    /// be honoured.
    #[error("--set {option}: {field}: {message}")]
    Set {
        /// The option as given.
        option: String,
        /// Dotted field path.
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
        cause: source,
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

/// Where `key = …` is written in the table that starts at `table` in `text` (toml gives an array
/// of tables' entry the span of its header): the line, up to the next table header; or the
/// table's own span when the key is not written there (a default).
pub fn key_span(text: &str, table: std::ops::Range<usize>, key: &str) -> std::ops::Range<usize> {
    let Some(body) = text.get(table.start..) else {
        return table;
    };
    let mut offset = table.start;
    for (n, line) in body.split_inclusive('\n').enumerate() {
        let t = line.trim_start();
        if n > 0 && t.starts_with('[') {
            break;
        }
        if let Some(rest) = t.strip_prefix(key)
            && rest.trim_start().starts_with('=')
        {
            let start = offset + (line.len() - t.len());
            return start..start + t.trim_end().len();
        }
        offset += line.len();
    }
    table
}

/// Where `key = …` is written in the top-level table `[table]` of `text` (for fields that keep
/// no span of their own); the header's line when the key is not written there, line 1 when the
/// table is not.
pub fn table_key_span(text: &str, table: &str, key: &str) -> std::ops::Range<usize> {
    let header = format!("[{table}]");
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let t = line.trim();
        if t == header || (t.starts_with(&header) && t[header.len()..].trim_start().starts_with('#')) {
            return key_span(text, offset..offset + line.len(), key);
        }
        offset += line.len();
    }
    0..0
}

/// An enum written as a name in a manifest: its names, in the one list everything else (the
/// parser, the messages, `FromStr` where there is one) reads.
pub trait Named: Copy + PartialEq + 'static {
    /// Every value with its name, in the order messages list them.
    const NAMES: &'static [(&'static str, Self)];

    /// For a name that was accepted once: why it is refused now and what to use instead.
    fn removed(_name: &str) -> Option<&'static str> {
        None
    }

    /// The name of a value.
    fn name(self) -> &'static str {
        Self::NAMES.iter().find(|(_, v)| *v == self).map_or("?", |(n, _)| n)
    }

    /// The value of a name.
    fn from_name(name: &str) -> Option<Self> {
        Self::NAMES.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
    }

    /// What a refused name gets: the removal note, or the accepted names.
    fn refusal(name: &str) -> String {
        match Self::removed(name) {
            Some(why) => format!("{name:?} was removed: {why}"),
            None => {
                let names: Vec<&str> = Self::NAMES.iter().map(|(n, _)| *n).collect();
                format!("{name:?}: expected {}", names.join(", "))
            }
        }
    }
}

/// A manifest field holding one of a [`Named`] enum's names. Any string deserializes, so that a
/// name outside the list is reported by [`choice`] as `FILE:LINE: FIELD: message` with the
/// accepted names, like every other checked value; it serializes as the name written (an
/// alias stays an alias, so a manifest's hash does not depend on which of a value's names it
/// uses being canonical).
#[derive(Clone, Debug, PartialEq)]
pub enum Choice<T> {
    /// One of the names: the value, and the name as written.
    Known(T, String),
    /// Anything else, as written.
    Unknown(String),
}

impl<T: Named> Choice<T> {
    /// A default: `value` with no span.
    pub fn default_to(value: T) -> Spanned<Choice<T>> {
        Spanned::new(0..0, Choice::Known(value, value.name().to_owned()))
    }
}

impl<'de, T: Named> Deserialize<'de> for Choice<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Ok(match T::from_name(&name) {
            Some(v) => Choice::Known(v, name),
            None => Choice::Unknown(name),
        })
    }
}

impl<T: Named> Serialize for Choice<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Choice::Known(_, name) | Choice::Unknown(name) => s.serialize_str(name),
        }
    }
}

/// The value of `field`, or a located error naming the accepted names.
pub fn choice<T: Named>(
    path: &Path,
    text: &str,
    field_value: &Spanned<Choice<T>>,
    field: &str,
) -> Result<T, ManifestError> {
    match field_value.get_ref() {
        Choice::Known(v, _) => Ok(*v),
        Choice::Unknown(name) => Err(invalid(path, text, field_value.span(), field, T::refusal(name))),
    }
}

/// The qualities of Eq. 2's implementations, from their one list in the physics crate.
impl Named for matedit_physics::shading::Quality {
    const NAMES: &'static [(&'static str, Self)] = &matedit_physics::shading::Quality::NAMES;
    fn removed(name: &str) -> Option<&'static str> {
        matedit_physics::shading::Quality::removed(name)
    }
}

/// Expands `${NAME}` from the environment, and `${NAME:-DEFAULT}` as a shell does (DEFAULT,
/// possibly empty, where NAME is unset or empty).
pub fn expand_vars(s: &str) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = s;
    while let Some(start) = rest.find("${") {
        out.push_str(&rest[..start]);
        let after = &rest[start + 2..];
        let end = after.find('}').ok_or_else(|| format!("unclosed ${{ in {s:?}"))?;
        let (name, default) = match after[..end].split_once(":-") {
            Some((name, default)) => (name, Some(default)),
            None => (&after[..end], None),
        };
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(format!("{:?} is not an environment variable's name (in {s:?})", name));
        }
        let value = match (std::env::var(name), default) {
            (Ok(v), Some(d)) if v.is_empty() => d.to_string(),
            (Ok(v), _) => v,
            (Err(_), Some(d)) => d.to_string(),
            (Err(_), None) => return Err(format!("environment variable {name} is not set")),
        };
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
    fn variables_take_shell_defaults() {
        // SAFETY of the test: variable names no other test uses.
        unsafe {
            std::env::set_var("MATEDIT_TEST_SET", "/w");
            std::env::set_var("MATEDIT_TEST_EMPTY", "");
        }
        assert_eq!(expand_vars("${MATEDIT_TEST_SET:-/d}/x").unwrap(), "/w/x");
        assert_eq!(expand_vars("${MATEDIT_TEST_EMPTY:-/d}/x").unwrap(), "/d/x");
        assert_eq!(expand_vars("${MATEDIT_TEST_UNSET_ANYWHERE:-}").unwrap(), "");
        assert_eq!(expand_vars("a${MATEDIT_TEST_UNSET_ANYWHERE:-b:-c}d").unwrap(), "ab:-cd");
        assert_eq!(expand_vars("${MATEDIT_TEST_EMPTY}").unwrap(), "");
        assert!(
            expand_vars("${MATEDIT_TEST_UNSET_ANYWHERE}")
                .unwrap_err()
                .contains("not set")
        );
        for bad in ["${}", "${:-x}", "${A B}", "${A-x}"] {
            assert!(
                expand_vars(bad).unwrap_err().contains("not an environment variable"),
                "{bad}"
            );
        }
        assert!(expand_vars("${MATEDIT_TEST_SET").unwrap_err().contains("unclosed"));
    }

    #[derive(Clone, Copy, Debug, PartialEq)]
    enum Colour {
        Red,
        Green,
    }

    impl Named for Colour {
        const NAMES: &'static [(&'static str, Self)] = &[
            ("red", Colour::Red),
            ("green", Colour::Green),
            ("+green", Colour::Green),
        ];
        fn removed(name: &str) -> Option<&'static str> {
            (name == "blue").then_some("use green")
        }
    }

    #[derive(Deserialize, Serialize)]
    struct Paint {
        colour: Spanned<Choice<Colour>>,
    }

    #[test]
    fn choices_parse_by_name_and_refuse_others_at_their_line() {
        let p = Path::new("paint.toml");
        let text = "# a comment\ncolour = \"green\"\n";
        let paint: Paint = parse_toml(p, text).unwrap();
        assert_eq!(choice(p, text, &paint.colour, "colour").unwrap(), Colour::Green);
        assert_eq!(toml::to_string(&paint).unwrap().trim(), "colour = \"green\"");
        for (bad, want) in [
            ("pink", "\"pink\": expected red, green, +green"),
            ("blue", "\"blue\" was removed: use green"),
        ] {
            let text = format!("\n\ncolour = \"{bad}\"\n");
            let paint: Paint = parse_toml(p, &text).unwrap();
            let e = choice(p, &text, &paint.colour, "colour").unwrap_err().to_string();
            assert_eq!(e, format!("paint.toml:3: colour: {want}"));
        }
        assert!(parse_toml::<Paint>(p, "colour = 3").is_err(), "not a string");
        assert_eq!(Colour::Red.name(), "red");
        assert_eq!(Colour::from_name("green"), Some(Colour::Green));
    }

    #[test]
    fn an_alias_parses_to_its_value_and_serialises_as_written() {
        let p = Path::new("paint.toml");
        let text = "colour = \"+green\"\n";
        let paint: Paint = parse_toml(p, text).unwrap();
        assert_eq!(choice(p, text, &paint.colour, "colour").unwrap(), Colour::Green);
        assert_eq!(
            toml::to_string(&paint).unwrap(),
            text,
            "the alias is kept: manifest hashes stay"
        );
        assert_eq!(Colour::Green.name(), "green", "a value's name is its first");
        let default = Choice::default_to(Colour::Green);
        assert_eq!(choice(p, "", &default, "colour").unwrap(), Colour::Green);
    }

    #[test]
    fn nesting_is_counted_outside_strings_and_comments() {
        for dir in [
            "manifests/datasets",
            "manifests/train",
            "manifests/datasets/experiments",
        ] {
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

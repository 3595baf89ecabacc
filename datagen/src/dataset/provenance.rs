//! What a dataset is made of and by what: the factory's build (version and git commit) and every
//! source of the manifest with its origin and licence, recorded in `plan.json` (and so in
//! `dataset.json`) and shown by the dataset card ([`super::card`]).
//!
//! Embedded sources (procedural shapes and environments, the material library, parametric
//! materials) are made by this project's code, so their origin is that code and their licence the
//! project's. A source read from a `path` has the `origin` and `licence` its manifest entry gives,
//! and `unknown` otherwise: a licence is never guessed from a folder's name or content.

use super::manifest::{EnvSourceToml, Manifest, MaterialSourceToml, ShapeSourceToml};
use matedit_contract::manifest::Choice;
use matedit_contract::records::{GeneratorRecord, SourceRecord};

/// The licence of this project's code, and so of what its generators make.
pub const PROJECT_LICENCE: &str = env!("CARGO_PKG_LICENSE");

/// What `origin` and `licence` say when a manifest does not.
pub const UNKNOWN: &str = "unknown";

/// This build of the factory.
pub fn generator() -> GeneratorRecord {
    GeneratorRecord {
        name: env!("CARGO_PKG_NAME").into(),
        version: env!("CARGO_PKG_VERSION").into(),
        commit: env!("MATEDIT_GIT_COMMIT").into(),
    }
}

/// Every source of `manifest`, shapes, then materials, then environments, each in manifest order.
pub fn sources(manifest: &Manifest) -> Vec<SourceRecord> {
    let shapes = manifest.shapes.iter().map(|e| shape(e.get_ref()));
    let materials = manifest.materials.iter().map(|e| material(e.get_ref()));
    let envs = manifest.environments.iter().map(|e| environment(e.get_ref()));
    shapes.chain(materials).chain(envs).collect()
}

/// Whether a recorded source was made by this project's generators (not read from a path).
pub fn is_embedded(s: &SourceRecord) -> bool {
    matches!(s.source.as_str(), "procedural" | "library" | "parametric")
}

fn name<T>(c: &Choice<T>) -> String {
    match c {
        Choice::Known(_, n) | Choice::Unknown(n) => n.clone(),
    }
}

/// A source made by this project's code: `origin` names the code.
fn embedded(kind: &str, source: String, provides: String, origin: &str) -> SourceRecord {
    SourceRecord {
        kind: kind.into(),
        source,
        provides,
        origin: origin.into(),
        licence: PROJECT_LICENCE.into(),
    }
}

/// A source read from a path: what its manifest entry says of it, else `unknown`.
fn from_path(
    kind: &str,
    source: String,
    provides: String,
    origin: &Option<String>,
    licence: &Option<String>,
) -> SourceRecord {
    let given = |v: &Option<String>| {
        v.as_deref()
            .map(str::trim)
            .filter(|v| !v.is_empty())
            .unwrap_or(UNKNOWN)
            .to_string()
    };
    SourceRecord {
        kind: kind.into(),
        source,
        provides,
        origin: given(origin),
        licence: given(licence),
    }
}

fn seeds(first: Option<u64>, count: Option<usize>) -> String {
    let first = first.unwrap_or(0);
    match count {
        Some(1) => format!("seed {first}"),
        Some(n) if n > 1 => format!("seeds {first}–{}", first + n as u64 - 1),
        _ => String::new(),
    }
}

fn join(parts: &[String]) -> String {
    parts
        .iter()
        .filter(|p| !p.is_empty())
        .cloned()
        .collect::<Vec<_>>()
        .join(", ")
}

fn shape(s: &ShapeSourceToml) -> SourceRecord {
    let source = name(s.source.get_ref());
    let category = s.category.clone().unwrap_or_default();
    if source == "procedural" {
        let provides = join(&[
            format!("{} × {category}", s.count.unwrap_or(0)),
            seeds(s.first_seed, s.count),
        ]);
        return embedded(
            "shapes",
            source,
            provides,
            "matedit's procedural shape generators (datagen/src/shapes/procedural)",
        );
    }
    let categories = s.categories.as_ref().map(|c| c.join(" ")).unwrap_or_default();
    let provides = join(&[s.path.clone().unwrap_or_default(), category, categories]);
    from_path("shapes", source, provides, &s.origin, &s.licence)
}

fn material(s: &MaterialSourceToml) -> SourceRecord {
    let source = name(s.source.get_ref());
    let list = |v: &Option<Vec<String>>, what: &str| {
        v.as_ref()
            .map(|v| format!("{what} {}", v.join(" ")))
            .unwrap_or_default()
    };
    let (names, families) = (list(&s.names, "names"), list(&s.families, "families"));
    match source.as_str() {
        "library" => embedded(
            "materials",
            source,
            join(&[names, families]),
            "matedit's library of analytic materials (assets/src/materials/library.rs), fitted to the DSBRDF",
        ),
        "parametric" => embedded(
            "materials",
            source,
            join(&[
                families,
                format!("{} per family", s.count.unwrap_or(0)),
                seeds(s.first_seed, s.count),
            ]),
            "matedit's parametric material families (assets/src/materials/parametric.rs), fitted to the DSBRDF",
        ),
        _ => from_path(
            "materials",
            source,
            s.path.clone().unwrap_or_default(),
            &s.origin,
            &s.licence,
        ),
    }
}

fn environment(s: &EnvSourceToml) -> SourceRecord {
    let source = name(s.source.get_ref());
    if source == "procedural" {
        let provides = join(&[
            format!("{} × {}", s.count.unwrap_or(0), s.family.clone().unwrap_or_default()),
            seeds(s.first_seed, s.count),
        ]);
        return embedded(
            "environments",
            source,
            provides,
            "matedit's procedural skies, studios and rooms (assets/src/envmaps.rs)",
        );
    }
    from_path(
        "environments",
        source,
        s.path.clone().unwrap_or_default(),
        &s.origin,
        &s.licence,
    )
}

//! The catalogue: every shape, material and environment a manifest's sources provide, each with
//! a stable id, sorted by id. Ids name things inside their source, never where it is mounted,
//! so two machines build identical datasets from the same manifest.

use super::manifest::{EnvSource, EnvSourceToml, IfMissing, ManifestFile, ShapeSource, ShapeSourceToml};
use crate::shapes::UpAxis;
use crate::shapes::procedural::Category;
use crate::shapes::sources;
use matedit_assets::envmaps::Family;
use matedit_contract::manifest::{Choice, ManifestError, Named};
use matedit_contract::records::Merge;
use matedit_physics::BrdfSpec;
use std::path::{Path, PathBuf};
use toml::Spanned;

mod materials;

use materials::materials_of;
pub use materials::merl_group;

/// A shape of the catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeItem {
    /// Stable id (`procedural:car:3`, `folder:chairs/a`, `shapenet:SYNSET/ID`).
    pub id: String,
    /// Category name.
    pub category: String,
    /// What [`Shape::load`](crate::shapes::Shape::load) accepts.
    pub spec: String,
    /// Up axis of the file.
    pub up: UpAxis,
    /// Content group (the id of its first member): identical or near-duplicate geometry
    /// (`content.rs`); all members go to the same split.
    pub group: String,
    /// Geometry fingerprint, `blake3:HEX` (`content.rs`; empty until the plan computes it).
    pub fingerprint: String,
    /// Index of the `[[shapes]]` entry that provides it (for messages).
    pub entry: usize,
    /// Its region names (`object` for the sphere; empty until the plan loads it).
    pub regions: Vec<String>,
}

/// Where a material's BRDF comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum MaterialSource {
    /// An analytic BRDF: a library material or a parametric family's draw.
    Analytic(BrdfSpec),
    /// A DSBRDF file (already the 108 parameters).
    Dsbrdf(PathBuf),
    /// A MERL measurement.
    Merl(PathBuf),
    /// A `*.nbrdf.json` neural BRDF (MERL's materials as Sztrajman et al.'s networks).
    Nbrdf(PathBuf),
}

/// A material of the catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialItem {
    /// Stable id (`library:gold-brushed`, `dsbrdf:NAME`, `merl:NAME`).
    pub id: String,
    /// Near-duplicate group: all members go to the same split.
    pub group: String,
    /// The source BRDF.
    pub source: MaterialSource,
    /// Parameter fingerprint, `blake3:HEX` (`content.rs`; empty until the plan computes it).
    pub fingerprint: String,
    /// Index of the `[[materials]]` entry that provides it (for messages).
    pub entry: usize,
}

/// An environment of the catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvItem {
    /// Stable id (`builtin:sunsky:3`, `file:NAME`).
    pub id: String,
    /// What [`load_env`](matedit_assets::envfile::load_env) accepts.
    pub spec: String,
    /// Content group (the id of its first member): identical pixels go to the same split.
    pub group: String,
    /// Pixel fingerprint, `blake3:HEX`, computed only when splits deal environments.
    pub fingerprint: String,
    /// Index of the `[[environments]]` entry that provides it (for messages).
    pub entry: usize,
}

/// Everything the sources provide.
#[derive(Clone, Debug, Default)]
pub struct Catalogue {
    /// Shapes, sorted by id.
    pub shapes: Vec<ShapeItem>,
    /// Materials, sorted by id.
    pub materials: Vec<MaterialItem>,
    /// Environments, sorted by id.
    pub envs: Vec<EnvItem>,
    /// Sources that were missing and replaced by embedded defaults (`if_missing`), as notes.
    pub substitutions: Vec<String>,
    /// Groups joined because their content is identical or nearly so (`content.rs`).
    pub merges: Vec<Merge>,
}

impl Catalogue {
    /// Lists every source of the manifest. Missing paths, unset variables, unknown names and
    /// duplicate ids are errors naming the entry.
    pub fn resolve(mf: &ManifestFile) -> Result<Catalogue, ManifestError> {
        let mut cat = Catalogue::default();
        for (i, entry) in mf.manifest.shapes.iter().enumerate() {
            let first = cat.shapes.len();
            shapes_of(mf, &mut cat, i, entry)?;
            cat.shapes[first..].iter_mut().for_each(|s| s.entry = i);
        }
        for (i, entry) in mf.manifest.materials.iter().enumerate() {
            let first = cat.materials.len();
            materials_of(mf, &mut cat, i, entry)?;
            cat.materials[first..].iter_mut().for_each(|m| m.entry = i);
        }
        for (i, entry) in mf.manifest.environments.iter().enumerate() {
            let first = cat.envs.len();
            envs_of(mf, &mut cat, i, entry)?;
            cat.envs[first..].iter_mut().for_each(|e| e.entry = i);
        }
        let m = &mf.manifest;
        dedup(mf, &mut cat.shapes, |s| &s.id, first_span(&m.shapes), "shapes")?;
        dedup(mf, &mut cat.materials, |m| &m.id, first_span(&m.materials), "materials")?;
        dedup(
            mf,
            &mut cat.envs,
            |e| &e.id,
            first_span(&m.environments),
            "environments",
        )?;
        Ok(cat)
    }
}

fn first_span<T>(list: &[Spanned<T>]) -> std::ops::Range<usize> {
    list.first().map(|s| s.span()).unwrap_or(0..0)
}

fn dedup<T>(
    mf: &ManifestFile,
    items: &mut [T],
    id: impl Fn(&T) -> &String,
    span: std::ops::Range<usize>,
    field: &str,
) -> Result<(), ManifestError> {
    items.sort_by(|a, b| id(a).cmp(id(b)));
    for w in items.windows(2) {
        if id(&w[0]) == id(&w[1]) {
            return Err(mf.invalid(
                span,
                field,
                format!(
                    "{} is provided by two sources; each id must come from one source",
                    id(&w[0])
                ),
            ));
        }
    }
    if items.is_empty() {
        return Err(mf.invalid(span, field, "the sources provide nothing"));
    }
    Ok(())
}

/// The most procedural shapes or environments one manifest entry may generate: far beyond any
/// dataset's need (the paper's has 520 shapes), and small enough that a mistyped count is an
/// error rather than an attempt to allocate the machine's memory.
pub const MAX_GENERATED: usize = 1_000_000;

/// One source entry of the manifest being resolved: its text's span and its field name
/// (`shapes[2]`), so that every error names the entry's file, line and field.
struct Entry<'m> {
    mf: &'m ManifestFile,
    span: std::ops::Range<usize>,
    field: String,
}

impl Entry<'_> {
    /// An error at the entry naming `FIELD.NAME`.
    fn invalid(&self, name: &str, message: impl Into<String>) -> ManifestError {
        self.mf
            .invalid(self.span.clone(), &format!("{}.{name}", self.field), message)
    }

    /// An error at the entry naming `FIELD` itself.
    fn invalid_entry(&self, message: impl Into<String>) -> ManifestError {
        self.mf.invalid(self.span.clone(), &self.field, message)
    }

    /// Refuses the first of `present`'s fields that is set: `source` does not use it.
    fn not_for(&self, source: &str, present: &[(&str, bool)]) -> Result<(), ManifestError> {
        match present.iter().find(|(_, set)| *set) {
            Some((name, _)) => Err(self.invalid(name, format!("not used by source = \"{source}\""))),
            None => Ok(()),
        }
    }

    /// `value`, or an error naming `FIELD.NAME` with `message` (why it is required).
    fn required<'a, T>(&self, name: &str, value: Option<&'a T>, message: &str) -> Result<&'a T, ManifestError> {
        value.ok_or_else(|| self.invalid(name, message))
    }

    /// A `count`-like field of generated items, starting at seed `first`: 1..=[`MAX_GENERATED`],
    /// and the seeds must not run past 2⁶⁴.
    fn generated_count(
        &self,
        name: &str,
        value: Option<&usize>,
        first: u64,
        message: &str,
    ) -> Result<usize, ManifestError> {
        let n = *self.required(name, value, message)?;
        if n == 0 || n > MAX_GENERATED {
            return Err(self.invalid(name, format!("{n}: must be 1 to {MAX_GENERATED}")));
        }
        if first.checked_add(n as u64).is_none() {
            return Err(self.invalid("first_seed", format!("{first} + {n} seeds run past 2^64")));
        }
        Ok(n)
    }

    /// The category called `name`, written in the entry's field `NAME`.
    fn category(&self, field: &str, name: &str) -> Result<Category, ManifestError> {
        name.parse::<Category>().map_err(|e| self.invalid(field, e))
    }

    /// Resolves the entry's `path`: `Ok(Some)` when it exists, `Ok(None)` when it is missing and
    /// `if_missing` allows `substitute`, an error otherwise.
    fn existing_path(
        &self,
        path: Option<&String>,
        if_missing: Option<&Spanned<Choice<IfMissing>>>,
        substitute: IfMissing,
    ) -> Result<Option<PathBuf>, ManifestError> {
        let Some(written) = path else {
            return Err(self.invalid("path", "this source needs a path"));
        };
        let allowed = match if_missing {
            None => false,
            Some(value) => match self.mf.choice(value, &format!("{}.if_missing", self.field))? {
                IfMissing::Error => false,
                v if v == substitute => true,
                other => {
                    return Err(self.mf.invalid(
                        value.span(),
                        &format!("{}.if_missing", self.field),
                        format!("{:?}: expected \"error\" or \"{}\"", other.name(), substitute.name()),
                    ));
                }
            },
        };
        // Relative to the file that wrote the path (a base manifest's own folder).
        let at = matedit_contract::manifest::key_span(self.mf.text(), self.span.clone(), "path").start;
        let resolved = match self.mf.resolve_path(written, at) {
            Ok(p) if p.exists() => return Ok(Some(p)),
            Ok(p) => format!("{} does not exist", p.display()),
            Err(e) => e,
        };
        if allowed {
            Ok(None)
        } else {
            Err(self.invalid(
                "path",
                format!(
                    "{resolved} (set if_missing = \"{}\" to use the embedded defaults instead)",
                    substitute.name()
                ),
            ))
        }
    }

    /// The files of `dir` ending in `suffix` (an unreadable folder is an error at `path`).
    fn files_with(&self, dir: &Path, suffix: &str) -> Result<Vec<PathBuf>, ManifestError> {
        files_with(dir, suffix).map_err(|e| self.invalid("path", format!("{}: {e}", dir.display())))
    }

    /// The entry's `fallback_count` once its path is missing and a substitute is allowed.
    fn fallback_count(&self, value: Option<&usize>) -> Result<usize, ManifestError> {
        self.generated_count("fallback_count", value, 0, "required with if_missing = \"procedural\"")
    }
}

fn shapes_of(
    mf: &ManifestFile,
    cat: &mut Catalogue,
    i: usize,
    entry: &Spanned<ShapeSourceToml>,
) -> Result<(), ManifestError> {
    let s = entry.get_ref();
    let e = Entry {
        mf,
        span: entry.span(),
        field: format!("shapes[{i}]"),
    };
    let up = match &s.up {
        Some(u) => mf.choice(u, &format!("{}.up", e.field))?,
        None => UpAxis::PosY,
    };
    let procedural = |cat: &mut Catalogue, c: Category, first: u64, count: usize| {
        for e in sources::procedural(c, first, count) {
            cat.shapes.push(ShapeItem {
                group: e.id.clone(),
                id: e.id,
                category: c.name().into(),
                spec: e.spec,
                up: UpAxis::PosY,
                fingerprint: String::new(),
                entry: i,
                regions: Vec::new(),
            });
        }
    };
    let kind = mf.choice(&s.source, &format!("{}.source", e.field))?;
    match kind {
        ShapeSource::Procedural => {
            e.not_for(
                "procedural",
                &[
                    ("origin", s.origin.is_some()),
                    ("licence", s.licence.is_some()),
                    ("path", s.path.is_some()),
                    ("categories", s.categories.is_some()),
                    ("if_missing", s.if_missing.is_some()),
                    ("fallback_count", s.fallback_count.is_some()),
                ],
            )?;
            let c = e.category("category", e.required("category", s.category.as_ref(), "required")?)?;
            let first = s.first_seed.unwrap_or(0);
            let count = e.generated_count("count", s.count.as_ref(), first, "required")?;
            procedural(cat, c, first, count);
        }
        ShapeSource::Folder | ShapeSource::Shapenet => {
            e.not_for(
                kind.name(),
                &[("count", s.count.is_some()), ("first_seed", s.first_seed.is_some())],
            )?;
            let cats: Vec<Category> = if kind == ShapeSource::Folder {
                e.not_for("folder", &[("categories", s.categories.is_some())])?;
                let name = e.required(
                    "category",
                    s.category.as_ref(),
                    "required: the split counts shapes per category",
                )?;
                vec![e.category("category", name)?]
            } else {
                e.not_for("shapenet", &[("category", s.category.is_some())])?;
                match &s.categories {
                    Some(list) => list
                        .iter()
                        .map(|n| e.category("categories", n))
                        .collect::<Result<_, _>>()?,
                    None => Category::ALL.to_vec(),
                }
            };
            match e.existing_path(s.path.as_ref(), s.if_missing.as_ref(), IfMissing::Procedural)? {
                Some(path) => {
                    let found = if kind == ShapeSource::Folder {
                        sources::folder(&path, Some(cats[0]))
                    } else {
                        sources::shapenet(&path, &cats)
                    }
                    .map_err(|err| e.invalid("path", format!("{err:#}")))?;
                    for f in found {
                        let category = f.category.map(|c| c.name()).unwrap_or("uncategorised");
                        cat.shapes.push(ShapeItem {
                            group: f.id.clone(),
                            id: f.id,
                            category: category.into(),
                            spec: f.spec,
                            up,
                            fingerprint: String::new(),
                            entry: i,
                            regions: Vec::new(),
                        });
                    }
                }
                None => {
                    let n = e.fallback_count(s.fallback_count.as_ref())?;
                    for c in &cats {
                        procedural(cat, *c, 0, n);
                    }
                    cat.substitutions.push(format!(
                        "{}: {} is missing; using {n} procedural shapes per category ({})",
                        e.field,
                        s.path.as_deref().unwrap_or(""),
                        cats.iter().map(|c| c.name()).collect::<Vec<_>>().join(", ")
                    ));
                }
            }
        }
    }
    Ok(())
}

fn files_with(dir: &Path, suffix: &str) -> std::io::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    if dir.is_file() {
        out.push(dir.to_path_buf());
        return Ok(out);
    }
    for e in std::fs::read_dir(dir)? {
        let p = e?.path();
        if p.is_file()
            && p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with(suffix))
        {
            out.push(p);
        }
    }
    out.sort();
    Ok(out)
}

fn procedural_envs(family: &str, first: u64, count: usize) -> Result<Vec<EnvItem>, String> {
    let families: Vec<Family> = if family == "all" {
        Family::ALL.to_vec()
    } else {
        vec![
            Family::ALL
                .into_iter()
                .find(|f| f.name() == family)
                .ok_or_else(|| format!("unknown family {family:?} (sunsky, overcast, softbox, window or all)"))?,
        ]
    };
    Ok(families
        .into_iter()
        .flat_map(|f| {
            (first..first + count as u64).map(move |seed| {
                let spec = format!("builtin:{}:{seed}", f.name());
                EnvItem {
                    id: spec.clone(),
                    group: spec.clone(),
                    spec,
                    fingerprint: String::new(),
                    entry: 0,
                }
            })
        })
        .collect())
}

fn envs_of(
    mf: &ManifestFile,
    cat: &mut Catalogue,
    i: usize,
    entry: &Spanned<EnvSourceToml>,
) -> Result<(), ManifestError> {
    let s = entry.get_ref();
    let e = Entry {
        mf,
        span: entry.span(),
        field: format!("environments[{i}]"),
    };
    let kind = mf.choice(&s.source, &format!("{}.source", e.field))?;
    match kind {
        EnvSource::Procedural => {
            e.not_for(
                "procedural",
                &[
                    ("origin", s.origin.is_some()),
                    ("licence", s.licence.is_some()),
                    ("path", s.path.is_some()),
                    ("if_missing", s.if_missing.is_some()),
                    ("fallback_count", s.fallback_count.is_some()),
                ],
            )?;
            let family = e.required("family", s.family.as_ref(), "required")?;
            let first = s.first_seed.unwrap_or(0);
            let count = e.generated_count("count", s.count.as_ref(), first, "required")?;
            let items = procedural_envs(family, first, count).map_err(|err| e.invalid("family", err))?;
            cat.envs.extend(items);
        }
        EnvSource::File | EnvSource::Folder => {
            e.not_for(
                kind.name(),
                &[
                    ("family", s.family.is_some()),
                    ("count", s.count.is_some()),
                    ("first_seed", s.first_seed.is_some()),
                ],
            )?;
            match e.existing_path(s.path.as_ref(), s.if_missing.as_ref(), IfMissing::Procedural)? {
                Some(path) => {
                    let mut files = Vec::new();
                    if path.is_file() {
                        files.push(path.clone());
                    } else {
                        for ext in [".hdr", ".exr"] {
                            files.extend(e.files_with(&path, ext)?);
                        }
                    }
                    if files.is_empty() {
                        return Err(e.invalid("path", format!("{} holds no .hdr or .exr file", path.display())));
                    }
                    for f in files {
                        let ext_ok = f
                            .extension()
                            .and_then(|x| x.to_str())
                            .is_some_and(|x| x.eq_ignore_ascii_case("hdr") || x.eq_ignore_ascii_case("exr"));
                        if !ext_ok {
                            return Err(e.invalid(
                                "path",
                                format!("{}: environment maps must be .hdr or .exr", f.display()),
                            ));
                        }
                        let name = f
                            .file_name()
                            .map(|n| n.to_string_lossy().into_owned())
                            .unwrap_or_default();
                        let spec = f
                            .to_str()
                            .map(str::to_string)
                            .ok_or_else(|| e.invalid("path", "path is not valid UTF-8"))?;
                        let id = format!("file:{name}");
                        cat.envs.push(EnvItem {
                            group: id.clone(),
                            id,
                            spec,
                            fingerprint: String::new(),
                            entry: i,
                        });
                    }
                }
                None => {
                    let n = e.fallback_count(s.fallback_count.as_ref())?;
                    let items = procedural_envs("all", 0, n).map_err(|err| e.invalid_entry(err))?;
                    cat.substitutions.push(format!(
                        "{}: {} is missing; using {} procedural environments",
                        e.field,
                        s.path.as_deref().unwrap_or(""),
                        items.len()
                    ));
                    cat.envs.extend(items);
                }
            }
        }
    }
    Ok(())
}

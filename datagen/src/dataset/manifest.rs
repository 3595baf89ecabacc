//! The dataset manifest: a TOML file that, with its seed, defines a dataset completely.
//!
//! Every table rejects unknown fields, so a typo is an error rather than a silently ignored
//! setting. Syntax and type errors come from the TOML parser with their line and column;
//! everything checked afterwards (paths, counts, splits) is reported as
//! `FILE:LINE: FIELD: message` through [`ManifestError`]. The field-by-field reference is
//! `manifests/README.md`.

use crate::accel::Accel;
use crate::preview::Shadows;
use crate::shapes::UpAxis;
use matedit_contract::manifest::{Choice, ManifestError, Named, Resolved, expand_vars, line_of};
use matedit_physics::shading::Quality;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// `[[shapes]] source`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShapeSource {
    /// Generated shapes of a category.
    Procedural,
    /// A folder of OBJ files.
    Folder,
    /// A ShapeNet tree.
    Shapenet,
}

impl Named for ShapeSource {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("procedural", ShapeSource::Procedural),
        ("folder", ShapeSource::Folder),
        ("shapenet", ShapeSource::Shapenet),
    ];
}

/// `[[materials]] source`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaterialSource {
    /// The material library.
    Library,
    /// DSBRDF files.
    Dsbrdf,
    /// MERL measurements.
    Merl,
    /// MERL's materials as neural BRDFs (`*.nbrdf.json`).
    Nbrdf,
    /// Materials drawn per seed from continuous families (`matedit_assets::materials::parametric`).
    Parametric,
}

impl Named for MaterialSource {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("library", MaterialSource::Library),
        ("dsbrdf", MaterialSource::Dsbrdf),
        ("merl", MaterialSource::Merl),
        ("nbrdf", MaterialSource::Nbrdf),
        ("parametric", MaterialSource::Parametric),
    ];
}

/// `[[environments]] source`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EnvSource {
    /// Procedural families.
    Procedural,
    /// One `.hdr` or `.exr` file.
    File,
    /// A folder of them.
    Folder,
}

impl Named for EnvSource {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("procedural", EnvSource::Procedural),
        ("file", EnvSource::File),
        ("folder", EnvSource::Folder),
    ];
}

/// `if_missing` of a source with a `path`: what to do when the path does not exist.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IfMissing {
    /// Stop with an error naming the path (the default).
    Error,
    /// Substitute procedural shapes or environments.
    Procedural,
    /// Substitute library materials.
    Library,
}

impl Named for IfMissing {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("error", IfMissing::Error),
        ("procedural", IfMissing::Procedural),
        ("library", IfMissing::Library),
    ];
}

/// `environment_rotation.mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RotationKind {
    /// Uniform in [0°, 360°).
    Random,
    /// Always 0°.
    None,
    /// Drawn from `values`.
    List,
}

impl Named for RotationKind {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("random", RotationKind::Random),
        ("none", RotationKind::None),
        ("list", RotationKind::List),
    ];
}

/// `sampling.mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SamplingMode {
    /// Every shape × material × environment of a split (the paper).
    Cross,
    /// `combinations` random combinations per split.
    Sampled,
}

impl Named for SamplingMode {
    const NAMES: &'static [(&'static str, Self)] =
        &[("cross", SamplingMode::Cross), ("sampled", SamplingMode::Sampled)];
}

/// `target.policy`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TargetPolicy {
    /// Another material of the same split, per region.
    Random,
    /// m_t = m.
    Same,
}

impl Named for TargetPolicy {
    const NAMES: &'static [(&'static str, Self)] = &[("random", TargetPolicy::Random), ("same", TargetPolicy::Same)];
}

/// `multi_material.mode`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MaterialsPerObject {
    /// One material per object.
    Single,
    /// One per semantic region of the mesh.
    PerRegion,
}

impl Named for MaterialsPerObject {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("single", MaterialsPerObject::Single),
        ("per_region", MaterialsPerObject::PerRegion),
    ];
}

/// The whole manifest as written (see `manifests/README.md`).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Name, seed, output directory, shard size.
    pub dataset: DatasetSection,
    /// Image formation settings.
    #[serde(default)]
    pub render: RenderSection,
    /// Camera placement.
    #[serde(default)]
    pub views: ViewsSection,
    /// How the environment is turned about the vertical axis per combination.
    #[serde(default)]
    pub environment_rotation: RotationSection,
    /// Full cross product or sampled combinations.
    #[serde(default)]
    pub sampling: SamplingSection,
    /// How the target material m_t is chosen.
    #[serde(default)]
    pub target: TargetSection,
    /// One material per object or one per semantic region.
    #[serde(default)]
    pub multi_material: MultiMaterialSection,
    /// Shape sources.
    pub shapes: Vec<Spanned<ShapeSourceToml>>,
    /// Material sources.
    pub materials: Vec<Spanned<MaterialSourceToml>>,
    /// Environment map sources.
    pub environments: Vec<Spanned<EnvSourceToml>>,
    /// The splits, in order (e.g. train, test).
    pub splits: Vec<Spanned<SplitToml>>,
}

/// `[dataset]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetSection {
    /// Dataset name (recorded in `dataset.json`).
    pub name: String,
    /// Seed of every random choice.
    pub seed: u64,
    /// Output directory, relative to the working directory (`--out` overrides it).
    pub output: String,
    /// Samples per shard.
    #[serde(default = "default_shard_size")]
    pub shard_size: Spanned<usize>,
    /// Render only these splits (all when absent). The deal still sees every split, so
    /// manifests that differ only here agree on who gets which shape and material.
    #[serde(default)]
    pub render_splits: Option<Spanned<Vec<String>>>,
}

fn default_shard_size() -> Spanned<usize> {
    Spanned::new(0..0, 64)
}

/// `[render]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSection {
    /// Image side in pixels.
    #[serde(default = "default_resolution")]
    pub resolution: Spanned<usize>,
    /// Environment resolution, `HxW` with W = 2H.
    #[serde(default = "default_env_resolution")]
    pub env_resolution: Spanned<String>,
    /// `exact`, `fast` or `zonal` (see `docs/PERFORMANCE.md` for speed against error).
    #[serde(default = "default_quality")]
    pub quality: Spanned<Choice<Quality>>,
    /// `off`, `on` or `auto` (on for shapes that can shadow themselves).
    #[serde(default = "default_shadows")]
    pub shadows: Spanned<Choice<ShadowPolicy>>,
    /// `dsbrdf` (render the fitted 108-parameter material) or `measured` (render the source).
    #[serde(default = "default_ground_truth")]
    pub ground_truth: Spanned<Choice<GroundTruth>>,
    /// Ray queries: `obvhs` or `embree` (a build with `--features embree`).
    #[serde(default = "default_accel")]
    pub accel: Spanned<Choice<Accel>>,
}

fn default_resolution() -> Spanned<usize> {
    Spanned::new(0..0, 256)
}
fn default_env_resolution() -> Spanned<String> {
    Spanned::new(0..0, "64x128".into())
}
fn default_quality() -> Spanned<Choice<Quality>> {
    Choice::default_to(Quality::Zonal)
}
fn default_shadows() -> Spanned<Choice<ShadowPolicy>> {
    Choice::default_to(ShadowPolicy::Off)
}
fn default_ground_truth() -> Spanned<Choice<GroundTruth>> {
    Choice::default_to(GroundTruth::Dsbrdf)
}
fn default_accel() -> Spanned<Choice<Accel>> {
    Choice::default_to(Accel::Obvhs)
}

impl Default for RenderSection {
    fn default() -> Self {
        Self {
            resolution: default_resolution(),
            env_resolution: default_env_resolution(),
            quality: default_quality(),
            shadows: default_shadows(),
            ground_truth: default_ground_truth(),
            accel: default_accel(),
        }
    }
}

/// `[views]`: `azimuths` preset viewpoints evenly spaced around the object at one elevation;
/// each combination is rendered from `per_combination` of them, drawn without replacement.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ViewsSection {
    /// Number of preset azimuths (the paper: 24).
    #[serde(default = "default_azimuths")]
    pub azimuths: Spanned<usize>,
    /// Camera elevation in degrees (positive looks down on the object).
    #[serde(default = "default_elevation")]
    pub elevation_deg: Spanned<f64>,
    /// Views drawn per combination (the paper: 5).
    #[serde(default = "default_per_combination")]
    pub per_combination: Spanned<usize>,
}

fn default_azimuths() -> Spanned<usize> {
    Spanned::new(0..0, 24)
}
fn default_elevation() -> Spanned<f64> {
    Spanned::new(0..0, 20.0)
}
fn default_per_combination() -> Spanned<usize> {
    Spanned::new(0..0, 5)
}

impl Default for ViewsSection {
    fn default() -> Self {
        Self {
            azimuths: default_azimuths(),
            elevation_deg: default_elevation(),
            per_combination: default_per_combination(),
        }
    }
}

/// `[environment_rotation]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RotationSection {
    /// `random` (uniform in [0°, 360°)), `none`, or `list` (drawn from `values`).
    #[serde(default = "default_rotation_mode")]
    pub mode: Spanned<Choice<RotationKind>>,
    /// Angles in degrees for `list`.
    #[serde(default)]
    pub values: Vec<f64>,
}

fn default_rotation_mode() -> Spanned<Choice<RotationKind>> {
    Choice::default_to(RotationKind::Random)
}

impl Default for RotationSection {
    fn default() -> Self {
        Self {
            mode: default_rotation_mode(),
            values: Vec::new(),
        }
    }
}

/// `[sampling]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingSection {
    /// `cross` (every shape × material × environment of a split, as in the paper) or
    /// `sampled` (`combinations` random combinations per split).
    #[serde(default = "default_sampling_mode")]
    pub mode: Spanned<Choice<SamplingMode>>,
    /// Combinations per split for `sampled`.
    #[serde(default)]
    pub combinations: Option<Spanned<usize>>,
}

fn default_sampling_mode() -> Spanned<Choice<SamplingMode>> {
    Choice::default_to(SamplingMode::Cross)
}

impl Default for SamplingSection {
    fn default() -> Self {
        Self {
            mode: default_sampling_mode(),
            combinations: None,
        }
    }
}

/// `[target]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSection {
    /// `random` (another material of the same split, per region) or `same` (m_t = m).
    #[serde(default = "default_target_policy")]
    pub policy: Spanned<Choice<TargetPolicy>>,
}

fn default_target_policy() -> Spanned<Choice<TargetPolicy>> {
    Choice::default_to(TargetPolicy::Random)
}

impl Default for TargetSection {
    fn default() -> Self {
        Self {
            policy: default_target_policy(),
        }
    }
}

/// `[multi_material]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MultiMaterialSection {
    /// `single` (one material per object) or `per_region` (each semantic region of the mesh
    /// gets its own material; the combination's material goes to region 0, the others are
    /// drawn from the split).
    #[serde(default = "default_mm_mode")]
    pub mode: Spanned<Choice<MaterialsPerObject>>,
}

fn default_mm_mode() -> Spanned<Choice<MaterialsPerObject>> {
    Choice::default_to(MaterialsPerObject::Single)
}

impl Default for MultiMaterialSection {
    fn default() -> Self {
        Self {
            mode: default_mm_mode(),
        }
    }
}

/// A `[[shapes]]` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeSourceToml {
    /// `procedural`, `folder` or `shapenet`.
    pub source: Spanned<Choice<ShapeSource>>,
    /// Category (procedural and folder).
    pub category: Option<String>,
    /// Categories to take from a ShapeNet tree (all four when absent).
    pub categories: Option<Vec<String>>,
    /// Number of procedural shapes.
    pub count: Option<usize>,
    /// First procedural seed (default 0).
    pub first_seed: Option<u64>,
    /// Folder or ShapeNet root; `${VAR}` is expanded, relative paths are relative to the manifest.
    pub path: Option<String>,
    /// Up axis of the files (`y`, `z`, `-y`, ...; default `y`).
    pub up: Option<Spanned<Choice<UpAxis>>>,
    /// `error` (default) or `procedural`: what to do when `path` does not exist.
    pub if_missing: Option<Spanned<Choice<IfMissing>>>,
    /// Procedural shapes per category used when `if_missing = "procedural"` applies.
    pub fallback_count: Option<usize>,
    /// Where the data at `path` comes from (recorded in the dataset card; `unknown` if absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The licence of the data at `path` (e.g. `CC0-1.0`; recorded in the dataset card,
    /// `unknown` if absent: a licence is never guessed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub licence: Option<String>,
}

/// A `[[materials]]` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSourceToml {
    /// `library`, `dsbrdf` (a file or a folder of `.dsbrdf.json`), `merl` (a folder of
    /// `.binary` files), `nbrdf` (a folder of `.nbrdf.json`) or `parametric` (drawn per seed).
    pub source: Spanned<Choice<MaterialSource>>,
    /// Library names (`["*"]` for all).
    pub names: Option<Vec<String>>,
    /// Library families (metal, carpaint, plastic, rubber, ceramic, fabric, wood), or parametric
    /// ones (plastic, metal).
    pub families: Option<Vec<String>>,
    /// Parametric: materials per family (seeds `first_seed ..`).
    pub count: Option<usize>,
    /// Parametric: the first seed (default 0).
    pub first_seed: Option<u64>,
    /// File or folder for `dsbrdf` and `merl`.
    pub path: Option<String>,
    /// `error` (default) or `library`: what to do when `path` does not exist.
    pub if_missing: Option<Spanned<Choice<IfMissing>>>,
    /// Where the data at `path` comes from (recorded in the dataset card; `unknown` if absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The licence of the data at `path` (e.g. `CC0-1.0`; recorded in the dataset card,
    /// `unknown` if absent: a licence is never guessed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub licence: Option<String>,
}

/// An `[[environments]]` entry.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EnvSourceToml {
    /// `procedural`, `file` or `folder` (`.hdr` and `.exr`).
    pub source: Spanned<Choice<EnvSource>>,
    /// Procedural family: sunsky, overcast, softbox, window, or `all`.
    pub family: Option<String>,
    /// Procedural maps per family.
    pub count: Option<usize>,
    /// First procedural seed (default 0).
    pub first_seed: Option<u64>,
    /// File or folder.
    pub path: Option<String>,
    /// `error` (default) or `procedural`: what to do when `path` does not exist.
    pub if_missing: Option<Spanned<Choice<IfMissing>>>,
    /// Procedural maps per family used when `if_missing = "procedural"` applies.
    pub fallback_count: Option<usize>,
    /// Where the data at `path` comes from (recorded in the dataset card; `unknown` if absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<String>,
    /// The licence of the data at `path` (e.g. `CC0-1.0`; recorded in the dataset card,
    /// `unknown` if absent: a licence is never guessed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub licence: Option<String>,
}

/// A `[[splits]]` entry: counts (drawn with the seed) or explicit id lists.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SplitToml {
    /// Split name (`train`, `test`, ...).
    pub name: String,
    /// `train`, `val` or `test` (default: `test` for names starting with "test", `val` for
    /// names starting with "val", else `train`). Splits of one role may share materials
    /// (`materials_from`); never across roles.
    pub role: Option<String>,
    /// Use the materials of this earlier split of the same role instead of drawing new ones
    /// (the paper's pretraining and finetuning share their 60 training materials).
    pub materials_from: Option<String>,
    /// Shapes per category.
    #[serde(default)]
    pub shapes: BTreeMap<String, Spanned<usize>>,
    /// Explicit shape ids.
    #[serde(default)]
    pub shape_ids: Vec<String>,
    /// Number of materials (whole near-duplicate groups are kept together).
    pub materials: Option<Spanned<usize>>,
    /// Explicit material ids.
    #[serde(default)]
    pub material_ids: Vec<String>,
    /// Number of environments; when no split gives one, every split uses every environment.
    pub environments: Option<Spanned<usize>>,
    /// Explicit environment ids (in addition to the count), e.g. `file:city.exr`. Not echoed
    /// into `dataset.json` when empty, so datasets of manifests without it keep their bytes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub environment_ids: Vec<String>,
}

/// A loaded manifest: its resolved source (for line numbers and the files values came from) and
/// its parsed form.
#[derive(Clone, Debug)]
pub struct ManifestFile {
    /// The manifest, resolved (`extends` followed, `--set` applied).
    pub source: Resolved,
    /// Parsed content.
    pub manifest: Manifest,
}

impl ManifestFile {
    /// Reads and parses `path`, its `extends` followed and `sets` (`PATH=VALUE`) applied.
    pub fn load(path: &Path, sets: &[String]) -> Result<ManifestFile, ManifestError> {
        Self::from_source(Resolved::read(path, sets)?)
    }

    /// Parses manifest text that came from `path` (its `extends` followed from there).
    pub fn parse(path: &Path, text: String) -> Result<ManifestFile, ManifestError> {
        Self::from_source(Resolved::resolve(path, text, &[])?)
    }

    /// Parses a resolved manifest.
    pub fn from_source(source: Resolved) -> Result<ManifestFile, ManifestError> {
        let manifest: Manifest = source.parse()?;
        Ok(ManifestFile { source, manifest })
    }

    /// The manifest named on the command line.
    pub fn path(&self) -> &Path {
        &self.source.path
    }

    /// The resolved text (the file's own for a manifest that neither extends nor is overridden).
    pub fn text(&self) -> &str {
        &self.source.text
    }

    /// The 1-based line of a byte offset in the resolved text (line 1 for defaults, which have
    /// no span).
    pub fn line_of(&self, offset: usize) -> usize {
        line_of(&self.source.text, offset)
    }

    /// The value of a named choice, or a located error listing the accepted names.
    pub fn choice<T: Named>(&self, value: &Spanned<Choice<T>>, field: &str) -> Result<T, ManifestError> {
        self.source.choice(value, field)
    }

    /// An [`ManifestError::Invalid`] at `span`, named by the file and line that wrote it.
    pub fn invalid(&self, span: std::ops::Range<usize>, field: &str, message: impl Into<String>) -> ManifestError {
        self.source.invalid(span, field, message)
    }

    /// Resolves a path written at byte `at` of the manifest: `${VAR}` expanded, relative to the
    /// folder of the file that wrote it (the working directory for a `--set` option). `Err`
    /// names an unset variable.
    pub fn resolve_path(&self, written: &str, at: usize) -> Result<PathBuf, String> {
        let expanded = expand_vars(written)?;
        let p = PathBuf::from(expanded);
        if p.is_absolute() {
            return Ok(p);
        }
        Ok(self.source.folder_of(at).join(p))
    }
}

impl Named for ShadowPolicy {
    const NAMES: &'static [(&'static str, Self)] = &[
        ("off", ShadowPolicy::Off),
        ("on", ShadowPolicy::On),
        ("auto", ShadowPolicy::Auto),
    ];
}

impl Named for GroundTruth {
    const NAMES: &'static [(&'static str, Self)] =
        &[("dsbrdf", GroundTruth::Dsbrdf), ("measured", GroundTruth::Measured)];
}

/// Shadow policy of the manifest.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum ShadowPolicy {
    /// Never trace shadow rays (the paper's rendering layer).
    Off,
    /// Always (except the analytic sphere).
    On,
    /// Only for meshes that can shadow themselves (not convex).
    Auto,
}

impl ShadowPolicy {
    /// Whether a shape with this convexity gets shadow rays.
    pub fn for_shape(self, convex: bool) -> Shadows {
        match self {
            ShadowPolicy::Off => Shadows::Off,
            ShadowPolicy::On => Shadows::On,
            ShadowPolicy::Auto if convex => Shadows::Off,
            ShadowPolicy::Auto => Shadows::On,
        }
    }
}

/// Which BRDF produces the pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum GroundTruth {
    /// The fitted 108-parameter DSBRDF (what the network's rendering layer can reproduce).
    Dsbrdf,
    /// The source BRDF (analytic or measured), as in the paper's renders.
    Measured,
}

#[cfg(test)]
#[path = "manifest_tests.rs"]
mod tests;

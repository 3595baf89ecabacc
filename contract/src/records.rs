//! What a dataset records: the lines of `index.jsonl` and `shard.json`, `plan.json`,
//! `dataset.json` with its material table, and the checksums that bind them to the files.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// `blake3:HEX` of some bytes.
pub fn checksum(bytes: &[u8]) -> String {
    format!("blake3:{}", blake3::hash(bytes).to_hex())
}

/// One line of `index.jsonl` (and of a shard's `shard.json`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SampleRecord {
    /// Unique id, `SPLIT-NNNNNNN`.
    pub id: String,
    /// Split name.
    pub split: String,
    /// Index within the split.
    pub index: usize,
    /// Shape category.
    pub category: String,
    /// Shape id.
    pub shape_id: String,
    /// Region names; the EXR's `region` channel indexes this list.
    pub regions: Vec<String>,
    /// Material id per region (m).
    pub material_ids: Vec<String>,
    /// Target material id per region (m_t).
    pub target_material_ids: Vec<String>,
    /// Environment id.
    pub env_id: String,
    /// Rotation of the environment about +y, degrees.
    pub env_rotation_deg: f64,
    /// Camera azimuth, degrees.
    pub view_azimuth_deg: f64,
    /// Camera elevation, degrees.
    pub view_elevation_deg: f64,
    /// Whether shadow rays were traced.
    pub shadows: bool,
    /// Pixels covered by the object.
    pub covered_pixels: usize,
    /// Shard directory, relative to the dataset root.
    pub shard: String,
    /// Files of the sample, relative to the dataset root: `image` (EXR: R, G, B = I; O.R, O.G,
    /// O.B = O; normal.X/Y/Z; mask; region) and `env` (EXR, camera-space environment).
    pub files: BTreeMap<String, String>,
    /// `blake3:HEX` of each file, same keys as `files`.
    pub checksums: BTreeMap<String, String>,
}

/// Format tag of `plan.json` and `dataset.json`.
pub const FORMAT: &str = "matedit-dataset-1";

/// A split's membership, as recorded.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SplitRecord {
    /// Name.
    pub name: String,
    /// `train` or `test`.
    pub role: String,
    /// Shape ids.
    pub shapes: Vec<String>,
    /// Material ids.
    pub materials: Vec<String>,
    /// Near-duplicate group of each of its materials.
    pub material_groups: BTreeMap<String, String>,
    /// Environment ids.
    pub environments: Vec<String>,
    /// Combinations.
    pub combinations: usize,
    /// Samples.
    pub samples: usize,
    /// Shard names.
    pub shards: Vec<String>,
}

/// `plan.json`: everything `join` and `verify` need without the manifest's source folders.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlanRecord {
    /// [`FORMAT`].
    pub format: String,
    /// Dataset name.
    pub name: String,
    /// Seed.
    pub seed: u64,
    /// `blake3:HEX` of the resolved manifest (output directory excluded).
    pub manifest_hash: String,
    /// The manifest as parsed, defaults filled in.
    pub manifest: serde_json::Value,
    /// Validated settings.
    pub settings: serde_json::Value,
    /// Splits in manifest order.
    pub splits: Vec<SplitRecord>,
    /// Missing sources replaced by embedded defaults.
    pub substitutions: Vec<String>,
    /// Content fingerprints and groups of every split member (empty in datasets made before
    /// fingerprints existed).
    #[serde(default)]
    pub content: ContentRecord,
    /// The program that planned the dataset (absent in datasets made before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<GeneratorRecord>,
    /// Every source of the manifest with its origin and licence, in manifest order (empty in
    /// datasets made before they were recorded).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sources: Vec<SourceRecord>,
}

/// Which build of the factory planned a dataset.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GeneratorRecord {
    /// `matedit-datagen`.
    pub name: String,
    /// Its version.
    pub version: String,
    /// The git commit it was built from, or `unknown`.
    pub commit: String,
}

/// One `[[shapes]]`, `[[materials]]` or `[[environments]]` entry of the manifest: what it is,
/// where its data comes from and under which licence.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SourceRecord {
    /// `shapes`, `materials` or `environments`.
    pub kind: String,
    /// The entry's `source` (`procedural`, `folder`, `merl`, ...).
    pub source: String,
    /// What it provides, as the manifest writes it (category, families, `path` unexpanded).
    pub provides: String,
    /// Where its data comes from: the generator for embedded sources, the manifest's `origin`
    /// for a path, else `unknown`.
    pub origin: String,
    /// Its licence: the project's for embedded sources, the manifest's `licence` for a path,
    /// else `unknown` (never guessed).
    pub licence: String,
}

/// A shape's, material's or environment's content, as recorded.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ContentEntry {
    /// `blake3:HEX` of its geometry, parameters or pixels (`content.rs`).
    pub fingerprint: String,
    /// Content group: the id of the group's first member. One group never spans a training and a
    /// test split (shapes and environments: never two splits).
    pub group: String,
}

/// The content analysis of the plan, for audits and `datagen verify`.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ContentRecord {
    /// Fingerprint definitions ([`content::SCHEME`](super::content::SCHEME)).
    pub scheme: String,
    /// By shape id.
    pub shapes: BTreeMap<String, ContentEntry>,
    /// By material id (the group is the dealing group, as in `materials[ID].group`).
    pub materials: BTreeMap<String, ContentEntry>,
    /// By environment id; empty when splits do not deal environments.
    pub environments: BTreeMap<String, ContentEntry>,
    /// Groups joined because of their content.
    pub merges: Vec<Merge>,
}

/// A material as recorded in `dataset.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MaterialRecord {
    /// Near-duplicate group.
    pub group: String,
    /// The 108 raw parameters (order of `docs/CONVENTIONS.md`).
    pub raw: Vec<f64>,
    /// The same, normalised to the network's [−0.95, 0.95].
    pub normalised: Vec<f64>,
    /// RMS of the fit's weighted log residuals (0 for DSBRDF files).
    pub fit_log_rmse: f64,
}

/// `dataset.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DatasetRecord {
    /// The plan.
    #[serde(flatten)]
    pub plan: PlanRecord,
    /// Material table, by id.
    pub materials: BTreeMap<String, MaterialRecord>,
    /// Samples per split.
    pub counts: BTreeMap<String, usize>,
    /// `blake3:HEX` of `index.jsonl`.
    pub index_checksum: String,
    /// Channels of the image files.
    pub image_channels: Vec<String>,
}

/// Channels of every sample's image EXR, in file order.
pub const IMAGE_CHANNELS: [&str; 11] = [
    "B", "G", "O.B", "O.G", "O.R", "R", "mask", "normal.X", "normal.Y", "normal.Z", "region",
];

/// A shard's `shard.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ShardRecord {
    /// [`FORMAT`].
    pub format: String,
    /// Shard name.
    pub shard: String,
    /// Its samples.
    pub samples: Vec<SampleRecord>,
}

/// `blake3:HEX` of the manifest as parsed, without its output directory (moving a dataset with
/// `--out` does not change what it is).
pub fn manifest_hash(manifest: &serde_json::Value) -> String {
    let mut m = manifest.clone();
    if let Some(d) = m.get_mut("dataset").and_then(|d| d.as_object_mut()) {
        d.remove("output");
    }
    checksum(m.to_string().as_bytes())
}

/// One merge the content analysis made: `ids[1..]` joined the group of `ids[0]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Merge {
    /// `shape`, `material` or `environment`.
    pub kind: String,
    /// The ids, the group's first member first.
    pub ids: Vec<String>,
    /// `identical geometry`, `near-duplicate geometry (L1 0.012)`, `identical parameters`,
    /// `identical pixels`.
    pub reason: String,
}

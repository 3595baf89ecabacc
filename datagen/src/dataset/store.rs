//! The dataset on disk.
//!
//! ```text
//! DIR/
//!   plan.json            what the run will produce (written first; lets workers and `join` agree)
//!   materials/           ID.dsbrdf.json + ID.fit.json for every material
//!   shards/SPLIT-NNNNN/  SPLIT-NNNNNNN.exr, SPLIT-NNNNNNN.env.exr per sample, then shard.json
//!   index.jsonl          one SampleRecord per line, splits in manifest order (written last)
//!   dataset.json         resolved manifest, its hash, split membership, counts, material table
//! ```
//!
//! A shard is built in `shards/.tmp-SPLIT-NNNNN` and renamed into place after its `shard.json`
//! is written, so a shard directory either does not exist or is complete: readers never see a
//! partial shard, and a killed run leaves only temporary directories, which the next run deletes.

use super::materials::MaterialEntry;
use super::plan::{Plan, Settings, ShardRef};
use super::sample::{Renderer, SampleRecord, checksum, encode};
use crate::io::write_atomically;
use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
    pub merges: Vec<super::content::Merge>,
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

impl PlanRecord {
    /// The record of a plan.
    pub fn of(plan: &Plan, manifest: &super::manifest::Manifest) -> Result<PlanRecord> {
        let manifest = serde_json::to_value(manifest)?;
        let cat = &plan.catalogue;
        let splits = plan
            .splits
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let groups = s
                    .materials
                    .iter()
                    .map(|&m| (cat.materials[m].id.clone(), cat.materials[m].group.clone()))
                    .collect();
                SplitRecord {
                    name: s.name.clone(),
                    role: s.role.clone(),
                    shapes: s.shapes.iter().map(|&k| cat.shapes[k].id.clone()).collect(),
                    materials: s.materials.iter().map(|&k| cat.materials[k].id.clone()).collect(),
                    material_groups: groups,
                    environments: s.envs.iter().map(|&k| cat.envs[k].id.clone()).collect(),
                    combinations: s.combinations.len(),
                    samples: s.samples,
                    shards: plan
                        .shards
                        .iter()
                        .filter(|r| r.split == i)
                        .map(|r| r.name(plan))
                        .collect(),
                }
            })
            .collect();
        Ok(PlanRecord {
            format: FORMAT.into(),
            name: plan.name.clone(),
            seed: plan.seed,
            manifest_hash: manifest_hash(&manifest),
            manifest,
            settings: serde_json::to_value::<&Settings>(&plan.settings)?,
            splits,
            substitutions: cat.substitutions.clone(),
            content: ContentRecord::of(plan),
        })
    }
}

impl ContentRecord {
    /// The fingerprints and groups of every member of the plan's splits.
    pub fn of(plan: &Plan) -> ContentRecord {
        let cat = &plan.catalogue;
        let entry = |fingerprint: &str, group: &str| ContentEntry {
            fingerprint: fingerprint.to_string(),
            group: group.to_string(),
        };
        let mut r = ContentRecord {
            scheme: super::content::SCHEME.into(),
            merges: cat.merges.clone(),
            ..Default::default()
        };
        for s in &plan.splits {
            for &k in &s.shapes {
                let it = &cat.shapes[k];
                r.shapes.insert(it.id.clone(), entry(&it.fingerprint, &it.group));
            }
            for &k in &s.materials {
                let it = &cat.materials[k];
                r.materials.insert(it.id.clone(), entry(&it.fingerprint, &it.group));
            }
            for &k in &s.envs {
                let it = &cat.envs[k];
                if !it.fingerprint.is_empty() {
                    r.environments.insert(it.id.clone(), entry(&it.fingerprint, &it.group));
                }
            }
        }
        r
    }
}

/// `DIR/shards`.
pub fn shards_dir(dir: &Path) -> PathBuf {
    dir.join("shards")
}

/// Whether shard `name` is complete in `dir`.
pub fn shard_done(dir: &Path, name: &str) -> bool {
    shards_dir(dir).join(name).join("shard.json").is_file()
}

/// Renders and writes one shard atomically. `on_sample` is called after each sample.
pub fn write_shard(
    dir: &Path,
    plan: &Plan,
    renderer: &Renderer<'_>,
    shard: &ShardRef,
    on_sample: &(dyn Fn() + Sync),
) -> Result<()> {
    let name = shard.name(plan);
    let root = shards_dir(dir);
    let tmp = root.join(format!(".tmp-{name}"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("cannot remove stale {}", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let records: Vec<SampleRecord> = (shard.first..shard.first + shard.len)
        .into_par_iter()
        .map(|index| {
            let px = renderer.render(shard.split, index)?;
            let (mut rec, image, env) = encode(px)?;
            let rel = format!("shards/{name}");
            let files = [
                ("image", format!("{}.exr", rec.id), image),
                ("env", format!("{}.env.exr", rec.id), env),
            ];
            for (key, file, bytes) in files {
                std::fs::write(tmp.join(&file), &bytes)
                    .with_context(|| format!("cannot write {}", tmp.join(&file).display()))?;
                rec.files.insert(key.into(), format!("{rel}/{file}"));
                rec.checksums.insert(key.into(), checksum(&bytes));
            }
            rec.shard = rel;
            on_sample();
            Ok(rec)
        })
        .collect::<Result<_>>()?;
    let record = ShardRecord {
        format: FORMAT.into(),
        shard: name.clone(),
        samples: records,
    };
    std::fs::write(tmp.join("shard.json"), serde_json::to_vec_pretty(&record)?)
        .with_context(|| format!("cannot write {}", tmp.join("shard.json").display()))?;
    let dest = root.join(&name);
    std::fs::rename(&tmp, &dest).with_context(|| format!("cannot move {} to {}", tmp.display(), dest.display()))?;
    Ok(())
}

/// Reads a complete shard's record.
pub fn read_shard(dir: &Path, name: &str) -> Result<ShardRecord> {
    let p = shards_dir(dir).join(name).join("shard.json");
    let text = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let rec: ShardRecord =
        serde_json::from_str(&text).with_context(|| format!("{}: not a shard record", p.display()))?;
    if rec.shard != name || rec.format != FORMAT {
        bail!("{}: names shard {:?} (format {:?})", p.display(), rec.shard, rec.format);
    }
    Ok(rec)
}

/// Reads `plan.json`.
pub fn read_plan(dir: &Path) -> Result<PlanRecord> {
    let p = dir.join("plan.json");
    let text = std::fs::read_to_string(&p)
        .with_context(|| format!("cannot read {} (is {} a dataset?)", p.display(), dir.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{}: not a plan record", p.display()))
}

/// Writes `plan.json` atomically.
pub fn write_plan(dir: &Path, rec: &PlanRecord) -> Result<()> {
    let json = serde_json::to_vec_pretty(rec)?;
    write_atomically(&dir.join("plan.json"), |t| Ok(std::fs::write(t, json)?))
}

/// Joins complete shards into `index.jsonl` and `dataset.json`. With `from`, shards are first
/// moved (or copied, across file systems) from the workers' directories into `dir`. Every shard
/// of the plan must be present.
pub fn join(dir: &Path, from: &[PathBuf], materials: Option<&[Option<MaterialEntry>]>) -> Result<DatasetRecord> {
    let plan = read_plan(dir)?;
    for w in from {
        let wp = read_plan(w)?;
        if wp.manifest_hash != plan.manifest_hash {
            bail!(
                "{} was made from a different manifest ({} against {} in {})",
                w.display(),
                wp.manifest_hash,
                plan.manifest_hash,
                dir.display()
            );
        }
        for s in plan.splits.iter().flat_map(|s| &s.shards) {
            if shard_done(dir, s) || !shard_done(w, s) {
                continue;
            }
            let (src, dst) = (shards_dir(w).join(s), shards_dir(dir).join(s));
            std::fs::create_dir_all(shards_dir(dir))?;
            if std::fs::rename(&src, &dst).is_err() {
                copy_shard(&src, &dst)?;
            }
        }
        copy_materials(w, dir)?;
    }
    let missing: Vec<&String> = plan
        .splits
        .iter()
        .flat_map(|s| &s.shards)
        .filter(|s| !shard_done(dir, s))
        .collect();
    if !missing.is_empty() {
        bail!(
            "{}: {} of {} shards are missing (first: {}); run the remaining workers first",
            dir.display(),
            missing.len(),
            plan.splits.iter().map(|s| s.shards.len()).sum::<usize>(),
            missing[0]
        );
    }
    let mut index = Vec::new();
    let mut counts = BTreeMap::new();
    for s in &plan.splits {
        let mut n = 0;
        for name in &s.shards {
            for rec in read_shard(dir, name)?.samples {
                serde_json::to_writer(&mut index, &rec)?;
                index.push(b'\n');
                n += 1;
            }
        }
        if n != s.samples {
            bail!(
                "split {}: {n} samples in its shards, the plan says {}",
                s.name,
                s.samples
            );
        }
        counts.insert(s.name.clone(), n);
    }
    let index_checksum = checksum(&index);
    write_atomically(&dir.join("index.jsonl"), |t| Ok(std::fs::write(t, &index)?))?;
    let table = match materials {
        Some(m) => material_table(m),
        None => read_material_table(dir, &plan)?,
    };
    let rec = DatasetRecord {
        plan,
        materials: table,
        counts,
        index_checksum,
        image_channels: IMAGE_CHANNELS.iter().map(|s| s.to_string()).collect(),
    };
    let json = serde_json::to_vec_pretty(&rec)?;
    write_atomically(&dir.join("dataset.json"), |t| Ok(std::fs::write(t, json)?))?;
    Ok(rec)
}

fn material_table(m: &[Option<MaterialEntry>]) -> BTreeMap<String, MaterialRecord> {
    m.iter()
        .flatten()
        .map(|e| {
            (
                e.id.clone(),
                MaterialRecord {
                    group: e.group.clone(),
                    raw: e.dsbrdf.params().to_vec(),
                    normalised: e.dsbrdf.to_normalised().to_vec(),
                    fit_log_rmse: e.fit_log_rmse,
                },
            )
        })
        .collect()
}

fn read_material_table(dir: &Path, plan: &PlanRecord) -> Result<BTreeMap<String, MaterialRecord>> {
    let mut out = BTreeMap::new();
    for s in &plan.splits {
        for id in &s.materials {
            let stem = super::materials::file_stem(id);
            let p = dir.join("materials").join(format!("{stem}.dsbrdf.json"));
            let m = matedit_physics::brdf::Dsbrdf::load(&p).with_context(|| format!("material {id}"))?;
            let stamp: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(dir.join("materials").join(format!("{stem}.fit.json")))
                    .with_context(|| format!("material {id}: no fit record"))?,
            )?;
            let group = plan_group(plan, id);
            out.insert(
                id.clone(),
                MaterialRecord {
                    group,
                    raw: m.params().to_vec(),
                    normalised: m.to_normalised().to_vec(),
                    fit_log_rmse: stamp["brdf_log_rmse"].as_f64().unwrap_or(0.0),
                },
            );
        }
    }
    Ok(out)
}

fn plan_group(plan: &PlanRecord, id: &str) -> String {
    plan.splits
        .iter()
        .find_map(|s| s.material_groups.get(id).cloned())
        .unwrap_or_else(|| id.to_string())
}

fn copy_shard(src: &Path, dst: &Path) -> Result<()> {
    let tmp = dst.with_file_name(format!(
        ".tmp-{}",
        dst.file_name().map(|n| n.to_string_lossy()).unwrap_or_default()
    ));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir_all(&tmp)?;
    for e in std::fs::read_dir(src)? {
        let p = e?.path();
        if let Some(n) = p.file_name() {
            std::fs::copy(&p, tmp.join(n)).with_context(|| format!("cannot copy {}", p.display()))?;
        }
    }
    std::fs::rename(&tmp, dst)?;
    Ok(())
}

fn copy_materials(from: &Path, to: &Path) -> Result<()> {
    let src = from.join("materials");
    if !src.is_dir() {
        return Ok(());
    }
    std::fs::create_dir_all(to.join("materials"))?;
    for e in std::fs::read_dir(&src)? {
        let p = e?.path();
        if let Some(n) = p.file_name() {
            let d = to.join("materials").join(n);
            if !d.exists() {
                let bytes = std::fs::read(&p)?;
                write_atomically(&d, |t| Ok(std::fs::write(t, &bytes)?))?;
            }
        }
    }
    Ok(())
}

//! Writing the dataset: shards built in a temporary folder and renamed into place, `plan.json`
//! first, `index.jsonl` and `dataset.json` last, from the shards' own records; joining the
//! shards of several workers. The layout and the records are `matedit_contract::{layout,
//! records}`.

use super::materials::MaterialEntry;
use super::plan::{Plan, Settings};
use anyhow::{Context, Result, bail};
use matedit_contract::io::write_atomically;
use matedit_contract::layout::{read_plan, read_shard, shard_done, shards_dir};
use matedit_contract::records::{
    ContentEntry, ContentRecord, DatasetRecord, FORMAT, IMAGE_CHANNELS, MaterialRecord, PlanRecord, SampleRecord,
    ShardRecord, SplitRecord, checksum, manifest_hash,
};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The record of a plan.
pub fn plan_record(plan: &Plan, toml: &super::manifest::Manifest) -> Result<PlanRecord> {
    let manifest = serde_json::to_value(toml)?;
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
        content: content_record(plan),
        generator: Some(super::provenance::generator()),
        sources: super::provenance::sources(toml),
    })
}

/// The fingerprints and groups of every member of the plan's splits.
pub fn content_record(plan: &Plan) -> ContentRecord {
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

/// An encoded sample: its record (files and checksums not yet filled in), the image EXR and
/// the environment EXR.
pub type EncodedSample = (SampleRecord, Vec<u8>, Vec<u8>);

/// Writes shard `name` atomically from the samples `indices` of its split, which `produce`
/// renders and encodes (in parallel); `on_sample` is called after each sample is written.
pub fn write_shard(
    dir: &Path,
    name: &str,
    indices: std::ops::Range<usize>,
    produce: &(dyn Fn(usize) -> Result<EncodedSample> + Sync),
    on_sample: &(dyn Fn() + Sync),
) -> Result<()> {
    let root = shards_dir(dir);
    let tmp = root.join(format!(".tmp-{name}"));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).with_context(|| format!("cannot remove stale {}", tmp.display()))?;
    }
    std::fs::create_dir_all(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let records: Vec<SampleRecord> = indices
        .into_par_iter()
        .map(|index| {
            let (mut rec, image, env) = produce(index)?;
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
        shard: name.to_string(),
        samples: records,
    };
    std::fs::write(tmp.join("shard.json"), serde_json::to_vec_pretty(&record)?)
        .with_context(|| format!("cannot write {}", tmp.join("shard.json").display()))?;
    let dest = root.join(name);
    std::fs::rename(&tmp, &dest).with_context(|| format!("cannot move {} to {}", tmp.display(), dest.display()))?;
    Ok(())
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

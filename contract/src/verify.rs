//! `datagen verify DIR`: checksums, schema and split integrity of a finished dataset, read only
//! from what is on disk (never from the manifest).

use crate::layout::{check_record, read_dataset_record, read_index};
use crate::records::{ContentEntry, DatasetRecord, IMAGE_CHANNELS, SampleRecord, SplitRecord, checksum};
use anyhow::{Context, Result};
use rayon::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// What verification found.
#[derive(Clone, Debug, Default)]
pub struct Report {
    /// Samples checked.
    pub samples: usize,
    /// Files whose checksum was recomputed.
    pub files: usize,
    /// Every problem, one line each, naming the sample or file.
    pub problems: Vec<String>,
}

impl Report {
    /// True when nothing is wrong.
    pub fn ok(&self) -> bool {
        self.problems.is_empty()
    }
}

/// Verifies `dir`. Problems are collected, not returned as errors; an error means the dataset
/// could not be read at all.
pub fn verify(dir: &Path) -> Result<Report> {
    let ds = read_dataset_record(dir)?;
    let (index, lines) = read_index(dir)?;
    let mut r = Report::default();
    if checksum(&index) != ds.index_checksum {
        r.problems
            .push("index.jsonl: checksum differs from dataset.json's index_checksum".to_string());
    }
    let mut records = Vec::new();
    for (n, rec) in lines {
        match rec {
            Ok(rec) => {
                if let Err(e) = check_record(&rec, |id| ds.materials.contains_key(id)) {
                    r.problems.push(format!("index.jsonl:{n}: sample {}: {e}", rec.id));
                }
                records.push(rec);
            }
            Err(e) => r.problems.push(format!("index.jsonl:{n}: {e}")),
        }
    }
    r.samples = records.len();

    // Counts and ids.
    let mut counts: BTreeMap<&str, usize> = BTreeMap::new();
    let mut ids = BTreeSet::new();
    for rec in &records {
        *counts.entry(rec.split.as_str()).or_default() += 1;
        if !ids.insert(rec.id.as_str()) {
            r.problems.push(format!("{}: id appears twice", rec.id));
        }
    }
    for (split, &n) in &ds.counts {
        let got = counts.get(split.as_str()).copied().unwrap_or(0);
        if got != n {
            r.problems.push(format!(
                "split {split}: {got} samples in index.jsonl, dataset.json says {n}"
            ));
        }
    }
    for s in &ds.plan.splits {
        if ds.counts.get(&s.name) != Some(&s.samples) {
            r.problems.push(format!(
                "split {}: the plan has {} samples, the counts differ",
                s.name, s.samples
            ));
        }
    }

    integrity(&ds, &records, &mut r.problems);

    // Files: existence, checksums, channels.
    let file_problems: Vec<Vec<String>> = records
        .par_iter()
        .map(|rec| {
            let mut p = Vec::new();
            for key in ["image", "env"] {
                let (Some(rel), Some(sum)) = (rec.files.get(key), rec.checksums.get(key)) else {
                    p.push(format!("{}: no {key} file recorded", rec.id));
                    continue;
                };
                let path = dir.join(rel);
                let bytes = match std::fs::read(&path) {
                    Ok(b) => b,
                    Err(e) => {
                        p.push(format!("{}: {rel}: {e}", rec.id));
                        continue;
                    }
                };
                if checksum(&bytes) != *sum {
                    p.push(format!("{}: {rel}: checksum mismatch (corrupt or modified)", rec.id));
                    continue;
                }
                if key == "image" {
                    match exr_channels(&bytes) {
                        Ok((w, h, ch)) => {
                            let want: Vec<String> = IMAGE_CHANNELS.iter().map(|s| s.to_string()).collect();
                            if ch != want {
                                p.push(format!("{}: {rel}: channels {ch:?}, expected {want:?}", rec.id));
                            }
                            if w != h {
                                p.push(format!("{}: {rel}: {w}×{h} is not square", rec.id));
                            }
                        }
                        Err(e) => p.push(format!("{}: {rel}: {e}", rec.id)),
                    }
                }
            }
            p
        })
        .collect();
    r.files = records.len() * 2;
    r.problems.extend(file_problems.into_iter().flatten());
    Ok(r)
}

fn exr_channels(bytes: &[u8]) -> Result<(usize, usize, Vec<String>)> {
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(bytes), false)?;
    let header = meta.headers.first().context("no EXR header")?;
    let size = header.layer_size;
    let names = header.channels.list.iter().map(|c| c.name.to_string()).collect();
    Ok((size.width(), size.height(), names))
}

/// No shape in two splits, no material (nor a near-duplicate group) in a training and a test
/// split, and every sample uses only its split's members.
fn integrity(ds: &DatasetRecord, records: &[SampleRecord], problems: &mut Vec<String>) {
    let mut shape_split: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    let mut material_split: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    let mut group_split: BTreeMap<&str, BTreeSet<&str>> = BTreeMap::new();
    let members: BTreeMap<&str, (BTreeSet<&str>, BTreeSet<&str>)> = ds
        .plan
        .splits
        .iter()
        .map(|s| {
            (
                s.name.as_str(),
                (
                    s.shapes.iter().map(String::as_str).collect(),
                    s.materials.iter().map(String::as_str).collect(),
                ),
            )
        })
        .collect();
    for rec in records {
        shape_split.entry(&rec.shape_id).or_default().insert(&rec.split);
        let Some((shapes, mats)) = members.get(rec.split.as_str()) else {
            problems.push(format!("{}: split {:?} is not in dataset.json", rec.id, rec.split));
            continue;
        };
        if !shapes.contains(rec.shape_id.as_str()) {
            problems.push(format!(
                "{}: shape {} is not a member of split {}",
                rec.id, rec.shape_id, rec.split
            ));
        }
        if rec.material_ids.len() != rec.regions.len() || rec.target_material_ids.len() != rec.regions.len() {
            problems.push(format!("{}: one material and one target per region expected", rec.id));
        }
        for m in rec.material_ids.iter().chain(&rec.target_material_ids) {
            material_split.entry(m).or_default().insert(&rec.split);
            if !mats.contains(m.as_str()) {
                problems.push(format!(
                    "{}: material {m} is not a member of split {}",
                    rec.id, rec.split
                ));
            }
            match ds.materials.get(m) {
                Some(t) => {
                    group_split.entry(&t.group).or_default().insert(&rec.split);
                }
                None => problems.push(format!("{}: material {m} is not in the material table", rec.id)),
            }
        }
    }
    // Membership lists themselves must be disjoint too (a split could list a shape no sample
    // happens to use).
    for s in &ds.plan.splits {
        for id in &s.shapes {
            shape_split.entry(id).or_default().insert(&s.name);
        }
        for (id, g) in &s.material_groups {
            material_split.entry(id).or_default().insert(&s.name);
            group_split.entry(g).or_default().insert(&s.name);
        }
    }
    let role: BTreeMap<&str, &str> = ds
        .plan
        .splits
        .iter()
        .map(|s| (s.name.as_str(), s.role.as_str()))
        .collect();
    let mut leak = |what: &str, map: BTreeMap<&str, BTreeSet<&str>>, by_role: bool| {
        for (id, splits) in map {
            let roles: BTreeSet<&str> = splits.iter().map(|s| role.get(s).copied().unwrap_or("?")).collect();
            let leaked = if by_role { roles.len() > 1 } else { splits.len() > 1 };
            if leaked {
                let list: Vec<&str> = splits.into_iter().collect();
                problems.push(format!("split leak: {what} {id} is in splits {}", list.join(" and ")));
            }
        }
    };
    leak("shape", shape_split, false);
    leak("material", material_split, true);
    leak("material group", group_split, true);
    content_leaks(ds, problems);
}

/// Content shared across the boundary: two *different* ids with the same recorded fingerprint
/// or content group in splits that may not share it (shapes and environments: any two splits;
/// materials: a training and a test split). Datasets made before fingerprints existed record
/// none and are not checked here.
pub fn content_leaks(ds: &DatasetRecord, problems: &mut Vec<String>) {
    let c = &ds.plan.content;
    if c.scheme.is_empty() {
        return;
    }
    let splits = &ds.plan.splits;
    type Members<'a> = fn(&'a SplitRecord) -> &'a Vec<String>;
    let kinds: [(&str, &BTreeMap<String, ContentEntry>, Members<'_>, bool); 3] = [
        ("shape", &c.shapes, |s| &s.shapes, false),
        ("material", &c.materials, |s| &s.materials, true),
        ("environment", &c.environments, |s| &s.environments, false),
    ];
    for (kind, table, members, by_role) in kinds {
        // Environments are recorded only when splits deal them.
        if kind == "environment" && table.is_empty() {
            continue;
        }
        // (id, split, role) of every member, with its entry.
        let mut all: Vec<(&str, &str, &str, &ContentEntry)> = Vec::new();
        for s in splits {
            for id in members(s) {
                match table.get(id) {
                    Some(e) => all.push((id, &s.name, &s.role, e)),
                    None => problems.push(format!(
                        "{kind} {id} (split {}): no fingerprint recorded in dataset.json",
                        s.name
                    )),
                }
            }
        }
        let mut reported = BTreeSet::new();
        for key in [Key::Fingerprint, Key::Group] {
            let mut by: BTreeMap<&str, Vec<usize>> = BTreeMap::new();
            for (n, (_, _, _, e)) in all.iter().enumerate() {
                let k = match key {
                    Key::Fingerprint => e.fingerprint.as_str(),
                    Key::Group => e.group.as_str(),
                };
                by.entry(k).or_default().push(n);
            }
            for (k, list) in by {
                for (x, &a) in list.iter().enumerate() {
                    for &b in &list[x + 1..] {
                        let (ia, sa, ra, _) = all[a];
                        let (ib, sb, rb, _) = all[b];
                        let clash = if by_role { ra != rb } else { sa != sb };
                        if ia == ib || !clash || !reported.insert((ia.min(ib), ia.max(ib))) {
                            continue;
                        }
                        let what = match (key, kind) {
                            (Key::Fingerprint, "shape") => format!("identical geometry ({k})"),
                            (Key::Fingerprint, "material") => format!("identical parameters ({k})"),
                            (Key::Fingerprint, _) => format!("identical pixels ({k})"),
                            (Key::Group, _) => format!("one content group ({k})"),
                        };
                        problems.push(format!(
                            "content leak: {kind} {ia} (split {sa}) and {kind} {ib} (split {sb}) share {what}"
                        ));
                    }
                }
            }
        }
    }
}

#[derive(Clone, Copy)]
enum Key {
    Fingerprint,
    Group,
}

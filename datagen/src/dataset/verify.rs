//! `datagen verify DIR --sources MANIFEST`: the dataset's recorded content against what its
//! sources give today. The checks that need only the files on disk are
//! [`matedit_contract::verify`].

use anyhow::Result;
use matedit_contract::layout::read_dataset_record;
use matedit_contract::records::ContentEntry;
use matedit_contract::verify::content_leaks;
use std::collections::BTreeMap;
use std::path::Path;

/// Recomputes the content of every split member from the sources of `manifest` (which must be
/// the dataset's own: same manifest hash) and checks it against `dataset.json`: a recorded
/// fingerprint or group that its source no longer gives, and content that the recomputed
/// fingerprints find on both sides of a boundary, are problems.
pub fn verify_sources(dir: &Path, manifest: &Path) -> Result<Vec<String>> {
    let mut ds = read_dataset_record(dir)?;
    let l = super::run::load(manifest)?;
    let fresh = super::store::plan_record(&l.plan, &l.file.manifest)?;
    let mut problems = Vec::new();
    if fresh.manifest_hash != ds.plan.manifest_hash {
        problems.push(format!(
            "{}: not the manifest of this dataset ({} ≠ {})",
            manifest.display(),
            fresh.manifest_hash,
            ds.plan.manifest_hash
        ));
        return Ok(problems);
    }
    let cat = &l.plan.catalogue;
    let entry = |f: &String, g: &String| ContentEntry {
        fingerprint: f.clone(),
        group: g.clone(),
    };
    let shapes: BTreeMap<&str, ContentEntry> = cat
        .shapes
        .iter()
        .map(|s| (s.id.as_str(), entry(&s.fingerprint, &s.group)))
        .collect();
    let materials: BTreeMap<&str, ContentEntry> = cat
        .materials
        .iter()
        .map(|m| (m.id.as_str(), entry(&m.fingerprint, &m.group)))
        .collect();
    let envs: BTreeMap<&str, ContentEntry> = cat
        .envs
        .iter()
        .filter(|e| !e.fingerprint.is_empty())
        .map(|e| (e.id.as_str(), entry(&e.fingerprint, &e.group)))
        .collect();
    let recomputed = |kind: &str, id: &str| -> Option<ContentEntry> {
        match kind {
            "shape" => shapes.get(id),
            "material" => materials.get(id),
            _ => envs.get(id),
        }
        .cloned()
    };
    let c = &mut ds.plan.content;
    for (kind, table) in [
        ("shape", &mut c.shapes),
        ("material", &mut c.materials),
        ("environment", &mut c.environments),
    ] {
        for (id, rec) in table.iter_mut() {
            let Some(now) = recomputed(kind, id) else {
                problems.push(format!(
                    "{kind} {id}: not provided by the sources of {}",
                    manifest.display()
                ));
                continue;
            };
            if now.fingerprint != rec.fingerprint {
                problems.push(format!(
                    "{kind} {id}: recorded fingerprint {} but its source gives {} (source changed or record edited)",
                    rec.fingerprint, now.fingerprint
                ));
            }
            if now.group != rec.group {
                problems.push(format!(
                    "{kind} {id}: recorded group {} but the sources give {}",
                    rec.group, now.group
                ));
            }
            *rec = now;
        }
    }
    content_leaks(&ds, &mut problems);
    Ok(problems)
}

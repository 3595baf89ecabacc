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

use crate::io::write_atomically;
use crate::records::{DatasetRecord, FORMAT, PlanRecord, SampleRecord, ShardRecord};
use anyhow::{Context, Result, bail};
use std::path::{Component, Path, PathBuf};

/// `DIR/shards`.
pub fn shards_dir(dir: &Path) -> PathBuf {
    dir.join("shards")
}

/// Whether shard `name` is complete in `dir`.
pub fn shard_done(dir: &Path, name: &str) -> bool {
    shards_dir(dir).join(name).join("shard.json").is_file()
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

/// Reads `DIR/dataset.json`, written last by `datagen join`.
pub fn read_dataset_record(dir: &Path) -> Result<DatasetRecord> {
    let p = dir.join("dataset.json");
    let text = std::fs::read_to_string(&p).with_context(|| {
        format!(
            "cannot read {} (not a dataset, or an unfinished run: `datagen join`)",
            p.display()
        )
    })?;
    serde_json::from_str(&text).with_context(|| format!("{}: not a dataset record", p.display()))
}

/// `DIR/index.jsonl` as bytes (for its checksum) and its records with their 1-based line
/// numbers; blank lines are skipped, a line that is not a record is kept as its error.
pub fn read_index(dir: &Path) -> Result<(Vec<u8>, IndexLines)> {
    let p = dir.join("index.jsonl");
    let bytes = std::fs::read(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let lines = bytes
        .split(|&b| b == b'\n')
        .enumerate()
        .filter(|(_, line)| !line.iter().all(u8::is_ascii_whitespace))
        .map(|(n, line)| (n + 1, serde_json::from_slice::<SampleRecord>(line)))
        .collect();
    Ok((bytes, lines))
}

/// The records of `index.jsonl`, each with its line number.
pub type IndexLines = Vec<(usize, serde_json::Result<SampleRecord>)>;

/// What every record must satisfy for its sample to be loadable: 1 to 255 regions, one
/// material and one target per region, each known to `is_material`, and an image and an
/// environment file with checksums at plain relative paths inside the dataset (a record comes
/// from a file anyone can edit).
pub fn check_record(rec: &SampleRecord, is_material: impl Fn(&str) -> bool) -> Result<(), String> {
    let r = rec.regions.len();
    if r == 0 || r > u8::MAX as usize {
        return Err(format!("{r} regions: expected 1 to {}", u8::MAX));
    }
    if rec.material_ids.len() != r || rec.target_material_ids.len() != r {
        return Err(format!("one material and one target per region expected ({r} regions)"));
    }
    for id in rec.material_ids.iter().chain(&rec.target_material_ids) {
        if !is_material(id) {
            return Err(format!("material {id} is not in dataset.json's material table"));
        }
    }
    for key in ["image", "env"] {
        let (Some(rel), Some(_)) = (rec.files.get(key), rec.checksums.get(key)) else {
            return Err(format!("no {key} file or checksum recorded"));
        };
        if rel.is_empty() || !Path::new(rel).components().all(|c| matches!(c, Component::Normal(_))) {
            return Err(format!("{key} file {rel:?} is not a plain path inside the dataset"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn record(regions: usize) -> SampleRecord {
        let files =
            |v: &str| BTreeMap::from([("image".to_string(), v.to_string()), ("env".to_string(), v.to_string())]);
        SampleRecord {
            id: "train-0000000".into(),
            split: "train".into(),
            index: 0,
            category: "car".into(),
            shape_id: "procedural:car:0".into(),
            regions: (0..regions).map(|r| format!("r{r}")).collect(),
            material_ids: vec!["m".into(); regions],
            target_material_ids: vec!["m".into(); regions],
            env_id: "e".into(),
            env_rotation_deg: 0.0,
            view_azimuth_deg: 0.0,
            view_elevation_deg: 20.0,
            shadows: false,
            covered_pixels: 1,
            shard: "shards/train-00000".into(),
            files: files("shards/train-00000/train-0000000.exr"),
            checksums: files("blake3:00"),
        }
    }

    #[test]
    fn records_are_checked_over_the_whole_region_range_and_against_hostile_paths() {
        let known = |id: &str| id == "m";
        for r in [1, 2, 255] {
            assert_eq!(check_record(&record(r), known), Ok(()), "{r} regions");
        }
        for r in [0, 256] {
            assert!(
                check_record(&record(r), known).unwrap_err().contains("regions"),
                "{r} regions"
            );
        }
        let mut short = record(3);
        short.target_material_ids.pop();
        assert!(
            check_record(&short, known)
                .unwrap_err()
                .contains("one material and one target")
        );
        let mut unknown = record(2);
        unknown.target_material_ids[1] = "nope".into();
        assert!(check_record(&unknown, known).unwrap_err().contains("material nope"));
        let mut no_sum = record(1);
        no_sum.checksums.remove("env");
        assert!(
            check_record(&no_sum, known)
                .unwrap_err()
                .contains("no env file or checksum")
        );
        for hostile in [
            "../outside.exr",
            "/etc/passwd",
            "shards/../../x.exr",
            "./shards/x.exr",
            "",
        ] {
            let mut r = record(1);
            r.files.insert("image".into(), hostile.into());
            let refused = check_record(&r, known);
            assert!(refused.unwrap_err().contains("not a plain path"), "{hostile:?}");
        }
    }

    #[test]
    fn the_index_keeps_line_numbers_skips_blank_lines_and_keeps_bad_lines_as_errors() {
        let dir = std::env::temp_dir().join(format!("matedit-layout-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = serde_json::to_string(&record(1)).unwrap();
        let text = format!("{good}\n\n   \n{{\"id\": 3}}\n{good}\n");
        std::fs::write(dir.join("index.jsonl"), &text).unwrap();
        let (bytes, lines) = read_index(&dir).unwrap();
        assert_eq!(bytes, text.as_bytes());
        let numbers: Vec<usize> = lines.iter().map(|(n, _)| *n).collect();
        assert_eq!(numbers, [1, 4, 5]);
        assert!(lines[0].1.is_ok() && lines[1].1.is_err() && lines[2].1.is_ok());
        let e = read_dataset_record(&dir).unwrap_err().to_string();
        assert!(e.contains("dataset.json") && e.contains("datagen join"), "{e}");
        std::fs::write(dir.join("dataset.json"), "{}").unwrap();
        assert!(
            read_dataset_record(&dir)
                .unwrap_err()
                .to_string()
                .contains("not a dataset record")
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}

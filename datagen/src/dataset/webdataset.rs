//! `datagen export --webdataset OUT DIR`: a finished dataset as WebDataset tar shards, the form
//! streaming loaders (`webdataset`, `torchdata`, Hugging Face's `datasets`) read.
//!
//! ```text
//! OUT/SPLIT-NNNNNN.tar   whole samples in index order; one key per sample, its id:
//!                        ID.exr (the image EXR), ID.env.exr (the environment EXR), ID.json
//! OUT/dataset.json       the source dataset's, byte for byte (manifest, splits, material table)
//! OUT/shards.json        format, the source's index checksum, the limits, every tar's samples,
//!                        size and blake3 checksum (written last: an export without it is unfinished)
//! ```
//!
//! The EXR members are the dataset's files unchanged (checked against the index's checksums as
//! they are packed, which the JSON member repeats), so a sample read from a tar is the sample
//! read from the folder. `ID.json` is the index record plus each region's m and m_t (`raw` and
//! `normalised`, from the material table), so a sample is whole without `dataset.json`.
//!
//! A shard holds at most `max_samples` samples and `max_bytes` bytes (a sample larger than that
//! alone gets a shard of its own). Tar headers carry no time, owner or mode of the machine, so
//! one dataset always exports to the same bytes. Each tar is written under a temporary name and
//! renamed when complete, and `.export-progress.json` lists the finished ones with their
//! checksums: a rerun after a kill checks those and writes only the rest.

use anyhow::{Context, Result, bail};
use matedit_contract::io::write_atomically;
use matedit_contract::layout::{check_record, read_dataset_record, read_index};
use matedit_contract::lock::{Worker, lock_output};
use matedit_contract::progress::Progress;
use matedit_contract::records::{MaterialRecord, SampleRecord, checksum};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// Format tag of `shards.json`.
pub const FORMAT: &str = "matedit-webdataset-1";

/// `shards.json`, the export's record.
pub const RECORD: &str = "shards.json";

const PROGRESS: &str = ".export-progress.json";

/// How large a shard may grow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Limits {
    /// Samples per shard.
    pub max_samples: usize,
    /// Bytes per shard (tar headers included).
    pub max_bytes: u64,
}

impl Default for Limits {
    /// 1,000 samples or 1 GiB: WebDataset's advice is shards of a few hundred MB to a few GB.
    fn default() -> Self {
        Limits {
            max_samples: 1000,
            max_bytes: 1 << 30,
        }
    }
}

/// One tar of the export.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TarRecord {
    /// File name, `SPLIT-NNNNNN.tar`.
    pub name: String,
    /// Samples.
    pub samples: usize,
    /// Size in bytes.
    pub bytes: u64,
    /// `blake3:HEX` of the file.
    pub checksum: String,
    /// Ids of its first and last sample.
    pub first: String,
    /// See `first`.
    pub last: String,
}

/// A split of the export.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitShards {
    /// Split name.
    pub name: String,
    /// `train` or `test`.
    pub role: String,
    /// Samples.
    pub samples: usize,
    /// Its tars in index order.
    pub shards: Vec<TarRecord>,
}

/// `shards.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExportRecord {
    /// [`FORMAT`].
    pub format: String,
    /// The dataset's name.
    pub dataset: String,
    /// `index_checksum` of the dataset exported.
    pub source_index_checksum: String,
    /// The limits the shards were cut by.
    pub limits: Limits,
    /// Splits in manifest order.
    pub splits: Vec<SplitShards>,
}

/// `.export-progress.json`: the tars finished so far.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProgressRecord {
    source_index_checksum: String,
    limits: Limits,
    done: BTreeMap<String, TarRecord>,
}

/// A region's material in a sample's JSON member.
#[derive(Clone, Debug, Serialize)]
struct RegionMaterial<'a> {
    id: &'a str,
    raw: &'a [f64],
    normalised: &'a [f64],
}

/// A sample's JSON member: the index record and its materials.
#[derive(Serialize)]
struct SampleJson<'a> {
    #[serde(flatten)]
    record: &'a SampleRecord,
    materials: Vec<RegionMaterial<'a>>,
    target_materials: Vec<RegionMaterial<'a>>,
}

/// One planned tar: its name and samples.
struct Planned<'a> {
    name: String,
    samples: Vec<&'a SampleRecord>,
}

/// What an export did.
#[derive(Debug)]
pub struct Summary {
    /// The record written.
    pub record: ExportRecord,
    /// Tars written now.
    pub written: usize,
    /// Tars a previous run had finished.
    pub resumed: usize,
}

/// Bytes a tar member of `len` bytes takes: a 512-byte header and the data padded to 512.
fn member_bytes(len: u64) -> u64 {
    512 + len.div_ceil(512) * 512
}

/// The end of a tar: two zero blocks.
const TAR_END: u64 = 1024;

/// Exports the dataset in `dir` to `out`.
pub fn export(dir: &Path, out: &Path, limits: Limits, progress: bool) -> Result<Summary> {
    if limits.max_samples == 0 || limits.max_bytes == 0 {
        bail!("shard limits must be positive ({limits:?})");
    }
    if inside(out, dir) {
        bail!(
            "{}: the export must go outside the dataset {}",
            out.display(),
            dir.display()
        );
    }
    let rec = read_dataset_record(dir)?;
    let index_path = dir.join("index.jsonl");
    let (bytes, lines) = read_index(dir)?;
    if checksum(&bytes) != rec.index_checksum {
        bail!(
            "{}: checksum differs from dataset.json's index_checksum (modified or from another run)",
            index_path.display()
        );
    }
    let mut by_split: BTreeMap<String, Vec<SampleRecord>> = BTreeMap::new();
    for (n, r) in lines {
        let r = r.with_context(|| format!("{}:{n}: bad record", index_path.display()))?;
        check_record(&r, |id| rec.materials.contains_key(id))
            .map_err(|e| anyhow::anyhow!("{}:{n}: sample {}: {e}", index_path.display(), r.id))?;
        by_split.entry(r.split.clone()).or_default().push(r);
    }
    let _lock = lock_output(out, Worker::ALL)?;
    let progress_path = out.join(PROGRESS);
    let done = resume(out, &rec.index_checksum, limits)?;

    // The plan of every tar, split by split.
    let mut planned = Vec::new();
    let mut splits = Vec::new();
    for sp in &rec.plan.splits {
        let records = by_split.get(&sp.name).map(Vec::as_slice).unwrap_or(&[]);
        let tars = cut(dir, &sp.name, records, limits)?;
        splits.push((sp, records.len(), tars.len(), planned.len()));
        planned.extend(tars);
    }
    let state = Mutex::new(ProgressRecord {
        source_index_checksum: rec.index_checksum.clone(),
        limits,
        done: done.clone(),
    });
    let todo: Vec<&Planned> = planned.iter().filter(|p| !done.contains_key(&p.name)).collect();
    let bar = Progress::new(
        progress,
        todo.iter().map(|p| p.samples.len() as u64).sum(),
        "samples",
        "{msg} [{bar:40}] {pos}/{len} ({per_sec}), {elapsed} elapsed, ETA {eta}",
    );
    todo.par_iter().try_for_each(|p| -> Result<()> {
        let tar = write_tar(dir, out, p, &rec.materials)?;
        bar.inc(p.samples.len() as u64);
        let mut s = state.lock().map_err(|_| anyhow::anyhow!("a shard writer panicked"))?;
        s.done.insert(tar.name.clone(), tar);
        let json = serde_json::to_vec_pretty(&*s)?;
        write_atomically(&progress_path, |t| Ok(std::fs::write(t, &json)?))
    })?;
    bar.finish_and_clear();

    let state = state
        .into_inner()
        .map_err(|_| anyhow::anyhow!("a shard writer panicked"))?;
    let record = ExportRecord {
        format: FORMAT.into(),
        dataset: rec.plan.name.clone(),
        source_index_checksum: rec.index_checksum.clone(),
        limits,
        splits: splits
            .iter()
            .map(|(sp, samples, count, first)| SplitShards {
                name: sp.name.clone(),
                role: sp.role.clone(),
                samples: *samples,
                shards: planned[*first..first + count]
                    .iter()
                    .map(|p| state.done[&p.name].clone())
                    .collect(),
            })
            .collect(),
    };
    let ds = std::fs::read(dir.join("dataset.json"))?;
    write_atomically(&out.join("dataset.json"), |t| Ok(std::fs::write(t, &ds)?))?;
    let json = serde_json::to_vec_pretty(&record)?;
    write_atomically(&out.join(RECORD), |t| Ok(std::fs::write(t, &json)?))?;
    let _ = std::fs::remove_file(&progress_path);
    Ok(Summary {
        record,
        written: todo.len(),
        resumed: planned.len() - todo.len(),
    })
}

/// Whether `path` (which need not exist yet) is `dir` or inside it, symbolic links resolved.
fn inside(path: &Path, dir: &Path) -> bool {
    let Ok(dir) = dir.canonicalize() else { return false };
    let mut rest = Vec::new();
    let mut at = path.to_path_buf();
    loop {
        if let Ok(real) = at.canonicalize() {
            let full = rest.iter().rev().fold(real, |p: PathBuf, c| p.join(c));
            return full.starts_with(&dir);
        }
        match (at.file_name().map(|n| n.to_os_string()), at.parent()) {
            (Some(name), Some(parent)) => {
                rest.push(name);
                at = if parent.as_os_str().is_empty() {
                    PathBuf::from(".")
                } else {
                    parent.to_path_buf()
                };
            }
            _ => return false,
        }
    }
}

/// The tars a previous run of this export finished (checked against their checksums); refuses
/// an `out` that holds the export of another dataset or of other limits.
fn resume(out: &Path, source: &str, limits: Limits) -> Result<BTreeMap<String, TarRecord>> {
    // What a previous run left: a finished export's record, else the progress of an unfinished
    // one, read as one kind of record.
    let (finished, partial) = (out.join(RECORD), out.join(PROGRESS));
    let previous = if finished.is_file() {
        let r: ExportRecord = serde_json::from_slice(&std::fs::read(&finished)?)
            .with_context(|| format!("{}: not an export record", finished.display()))?;
        Some(ProgressRecord {
            source_index_checksum: r.source_index_checksum,
            limits: r.limits,
            done: r
                .splits
                .into_iter()
                .flat_map(|s| s.shards)
                .map(|t| (t.name.clone(), t))
                .collect(),
        })
    } else if partial.is_file() {
        Some(
            serde_json::from_slice(&std::fs::read(&partial)?)
                .with_context(|| format!("{}: not an export's progress", partial.display()))?,
        )
    } else {
        None
    };
    if let Some(p) = &previous
        && (p.source_index_checksum != source || p.limits != limits)
    {
        bail!(
            "{} holds an export of another dataset or with other shard limits: choose another OUT or delete it",
            out.display()
        );
    }
    // Temporary files of a killed run.
    for e in std::fs::read_dir(out)? {
        let p = e?.path();
        if p.file_name().is_some_and(|n| n.to_string_lossy().contains(".tmp-")) {
            let _ = std::fs::remove_file(&p);
        }
    }
    let Some(previous) = previous else {
        return Ok(BTreeMap::new());
    };
    Ok(previous
        .done
        .into_iter()
        .filter(|(name, t)| {
            let bytes = std::fs::read(out.join(name)).unwrap_or_default();
            bytes.len() as u64 == t.bytes && checksum(&bytes) == t.checksum
        })
        .collect())
}

/// A sample's JSON member.
fn sample_json(r: &SampleRecord, materials: &BTreeMap<String, MaterialRecord>) -> Result<Vec<u8>> {
    let j = SampleJson {
        record: r,
        materials: regions(r, &r.material_ids, materials)?,
        target_materials: regions(r, &r.target_material_ids, materials)?,
    };
    Ok(serde_json::to_vec(&j)?)
}

/// The materials of `ids`, from the table.
fn regions<'a>(
    r: &SampleRecord,
    ids: &'a [String],
    materials: &'a BTreeMap<String, MaterialRecord>,
) -> Result<Vec<RegionMaterial<'a>>> {
    ids.iter()
        .map(|id| {
            let m = materials
                .get(id)
                .with_context(|| format!("sample {}: material {id} is not in the table", r.id))?;
            Ok(RegionMaterial {
                id,
                raw: &m.raw,
                normalised: &m.normalised,
            })
        })
        .collect()
}

/// The JSON member's size is not known before it is made; at most this much is assumed when
/// cutting (a record of 255 regions with two 108-vectors each is about 1 MB).
fn json_estimate(r: &SampleRecord) -> u64 {
    4096 + r.regions.len() as u64 * 2 * 2 * 108 * 26
}

/// Cuts a split's records into tars under the limits.
fn cut<'a>(dir: &Path, split: &str, records: &'a [SampleRecord], limits: Limits) -> Result<Vec<Planned<'a>>> {
    let mut out: Vec<Planned> = Vec::new();
    let mut size = TAR_END;
    for r in records {
        let mut bytes = member_bytes(json_estimate(r));
        for key in ["image", "env"] {
            let p = dir.join(&r.files[key]);
            let len = std::fs::metadata(&p)
                .with_context(|| format!("{}: cannot read (sample {})", p.display(), r.id))?
                .len();
            bytes += member_bytes(len);
        }
        let open = out
            .last()
            .is_some_and(|t| t.samples.len() < limits.max_samples && size + bytes <= limits.max_bytes);
        if !open {
            out.push(Planned {
                name: format!("{split}-{:06}.tar", out.len()),
                samples: Vec::new(),
            });
            size = TAR_END;
        }
        size += bytes;
        if let Some(t) = out.last_mut() {
            t.samples.push(r);
        }
    }
    Ok(out)
}

/// A writer that hashes and counts what passes through it.
struct Hashing<W> {
    inner: W,
    hash: blake3::Hasher,
    bytes: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Appends one member with a header that says nothing of this machine.
fn append<W: Write>(tar: &mut tar::Builder<W>, name: &str, data: &[u8]) -> Result<()> {
    let mut h = tar::Header::new_ustar();
    h.set_path(name).with_context(|| format!("member name {name:?}"))?;
    h.set_size(data.len() as u64);
    h.set_entry_type(tar::EntryType::Regular);
    h.set_mode(0o644);
    h.set_mtime(0);
    h.set_uid(0);
    h.set_gid(0);
    h.set_cksum();
    tar.append(&h, data)?;
    Ok(())
}

/// Reads a sample file and checks it against the index.
fn read_checked(dir: &Path, r: &SampleRecord, key: &str) -> Result<Vec<u8>> {
    let p: PathBuf = dir.join(&r.files[key]);
    let bytes = std::fs::read(&p).with_context(|| format!("{}: cannot read (sample {})", p.display(), r.id))?;
    let got = checksum(&bytes);
    if got != r.checksums[key] {
        bail!(
            "{}: checksum mismatch (corrupt or modified): {got}, the index says {}; nothing of it was exported",
            p.display(),
            r.checksums[key]
        );
    }
    Ok(bytes)
}

/// Writes one tar atomically and returns its record.
fn write_tar(dir: &Path, out: &Path, p: &Planned, materials: &BTreeMap<String, MaterialRecord>) -> Result<TarRecord> {
    let path = out.join(&p.name);
    let mut result = None;
    write_atomically(&path, |t| {
        let file = std::fs::File::create(t).with_context(|| format!("cannot create {}", t.display()))?;
        let mut tar = tar::Builder::new(Hashing {
            inner: std::io::BufWriter::new(file),
            hash: blake3::Hasher::new(),
            bytes: 0,
        });
        for r in &p.samples {
            append(&mut tar, &format!("{}.exr", r.id), &read_checked(dir, r, "image")?)?;
            append(&mut tar, &format!("{}.env.exr", r.id), &read_checked(dir, r, "env")?)?;
            append(&mut tar, &format!("{}.json", r.id), &sample_json(r, materials)?)?;
        }
        let mut w = tar.into_inner()?;
        w.flush()?;
        w.inner
            .into_inner()
            .map_err(|e| e.into_error())?
            .sync_all()
            .with_context(|| format!("cannot write {}", t.display()))?;
        result = Some((format!("blake3:{}", w.hash.finalize().to_hex()), w.bytes));
        Ok(())
    })?;
    let (checksum, bytes) = result.context("tar not written")?;
    Ok(TarRecord {
        name: p.name.clone(),
        samples: p.samples.len(),
        bytes,
        checksum,
        first: p.samples.first().map(|r| r.id.clone()).unwrap_or_default(),
        last: p.samples.last().map(|r| r.id.clone()).unwrap_or_default(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_members_size_is_its_header_and_its_data_padded_to_whole_blocks() {
        assert_eq!(member_bytes(0), 512);
        assert_eq!(member_bytes(1), 1024);
        assert_eq!(member_bytes(512), 1024);
        assert_eq!(member_bytes(513), 1536);
        let mut tar = tar::Builder::new(Vec::new());
        for (name, len) in [("a.exr", 0usize), ("a.env.exr", 1), ("a.json", 513)] {
            append(&mut tar, name, &vec![7; len]).unwrap();
        }
        let bytes = tar.into_inner().unwrap();
        assert_eq!(
            bytes.len() as u64,
            member_bytes(0) + member_bytes(1) + member_bytes(513) + TAR_END
        );
        let mut back = tar::Archive::new(bytes.as_slice());
        let names: Vec<(String, u64, u64)> = back
            .entries()
            .unwrap()
            .map(|e| {
                let e = e.unwrap();
                let h = e.header();
                (
                    e.path().unwrap().display().to_string(),
                    h.mtime().unwrap(),
                    h.uid().unwrap(),
                )
            })
            .collect();
        assert_eq!(
            names[1],
            ("a.env.exr".to_string(), 0, 0),
            "no time or owner of this machine"
        );
    }
}

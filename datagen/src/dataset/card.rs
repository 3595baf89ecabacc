//! `datagen card DIR` (also written by `datagen run`): the dataset card, `DIR/README.md`, in the
//! Hugging Face dataset-card form. YAML front matter (licences, size category, splits with their
//! counts, source datasets) that the Hub and its tools read, then what a person needs: what the
//! dataset is, its splits and the rules they were dealt by, every source with its origin and
//! licence, a contact sheet (`DIR/inspect.png`, written when missing), how it was made (the
//! generator's version and commit, the resolved manifest, the command) and how to load it from
//! Python. Everything comes from `dataset.json`, so the card of one dataset is always the same
//! file, byte for byte.

use super::inspect;
use anyhow::Result;
use matedit_contract::io::write_atomically;
use matedit_contract::layout::read_dataset_record;
use matedit_contract::records::{DatasetRecord, SourceRecord};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The contact sheet the card shows, beside it.
pub const SHEET: &str = "inspect.png";

/// Samples in that sheet.
const SHEET_SAMPLES: usize = 6;

/// Writes `DIR/README.md` (and `DIR/inspect.png` when it is missing). Returns the card's path.
pub fn write_card(dir: &Path) -> Result<PathBuf> {
    let rec = read_dataset_record(dir)?;
    if !dir.join(SHEET).is_file() {
        inspect::inspect(dir, &dir.join(SHEET), SHEET_SAMPLES, None)?;
    }
    let text = card(&rec);
    let path = dir.join("README.md");
    write_atomically(&path, |t| Ok(std::fs::write(t, text.as_bytes())?))?;
    Ok(path)
}

/// The Hub's size category of a dataset of `n` samples.
pub fn size_category(n: usize) -> &'static str {
    const STEPS: [(u64, &str); 10] = [
        (1_000, "n<1K"),
        (10_000, "1K<n<10K"),
        (100_000, "10K<n<100K"),
        (1_000_000, "100K<n<1M"),
        (10_000_000, "1M<n<10M"),
        (100_000_000, "10M<n<100M"),
        (1_000_000_000, "100M<n<1B"),
        (10_000_000_000, "1B<n<10B"),
        (100_000_000_000, "10B<n<100B"),
        (1_000_000_000_000, "100B<n<1T"),
    ];
    STEPS
        .iter()
        .find(|(limit, _)| (n as u64) < *limit)
        .map_or("n>1T", |(_, c)| c)
}

/// The Hub's licence identifier for a licence as recorded: the SPDX ids the Hub lists, `unknown`,
/// and `other` for anything else (an expression such as `MIT OR Apache-2.0`, or free text).
pub fn hub_licence(licence: &str) -> String {
    const HUB: [&str; 14] = [
        "apache-2.0",
        "mit",
        "cc0-1.0",
        "cc-by-4.0",
        "cc-by-sa-4.0",
        "cc-by-nc-4.0",
        "cc-by-nc-sa-4.0",
        "cc-by-3.0",
        "cc-by-nc-3.0",
        "odc-by",
        "odbl",
        "pddl",
        "openrail",
        "unknown",
    ];
    let l = licence.trim().to_ascii_lowercase();
    if HUB.contains(&l.as_str()) { l } else { "other".into() }
}

/// A YAML double-quoted scalar.
fn yaml(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"\"".into())
}

/// A Markdown table cell.
fn cell(s: &str) -> String {
    let s = s.replace('|', "\\|").replace('\n', " ");
    if s.is_empty() { "–".into() } else { s }
}

fn distinct(items: impl IntoIterator<Item = String>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for i in items {
        if !out.contains(&i) {
            out.push(i);
        }
    }
    out
}

/// The card's text.
pub fn card(rec: &DatasetRecord) -> String {
    let plan = &rec.plan;
    let total: usize = rec.counts.values().sum();
    let mut s = String::new();
    front_matter(&mut s, rec, total);
    let by = match &plan.generator {
        Some(g) => format!("{} {} (commit `{}`)", g.name, g.version, g.commit),
        None => "an unrecorded build of matedit-datagen".into(),
    };
    let _ = writeln!(
        s,
        "# {name}\n\nA synthetic dataset for material editing (Liu et al. 2017, *Material Editing Using a Physically \
         Based Rendering Network*): {total} samples in {} splits, each an object rendered twice under one \
         environment map — with its material m (I) and with a target material m_t (O) — with its camera-space \
         normals, mask, material regions, the environment as the camera sees it, and the 108 DSBRDF parameters of \
         m and m_t. Made by {by} from the manifest below with seed {}.\n",
        plan.splits.len(),
        plan.seed,
        name = plan.name
    );
    splits(&mut s, rec);
    sources(&mut s, &plan.sources, &plan.substitutions);
    let _ = writeln!(
        s,
        "## Samples\n\n![samples of the dataset]({SHEET})\n\nColumns: {} (`datagen inspect`; HDR images \
         tone-mapped, normals as RGB).\n",
        inspect::COLUMNS.join(", ")
    );
    made(&mut s, rec);
    loading(&mut s);
    s
}

fn front_matter(s: &mut String, rec: &DatasetRecord, total: usize) {
    let plan = &rec.plan;
    let licences = distinct(plan.sources.iter().map(|x| x.licence.clone()));
    // An SPDX choice (`MIT OR Apache-2.0`) is each of its licences, at the user's choice.
    let mut hub = distinct(licences.iter().flat_map(|l| {
        let choices: Vec<String> = l.split(" OR ").map(hub_licence).collect();
        if choices.len() > 1 && choices.iter().all(|c| c != "other") {
            choices
        } else {
            vec![hub_licence(l)]
        }
    }));
    if hub.is_empty() {
        hub.push("unknown".into());
    }
    s.push_str("---\nlicense:\n");
    for l in &hub {
        let _ = writeln!(s, "- {l}");
    }
    if hub.iter().any(|l| l == "other") {
        let _ = writeln!(
            s,
            "license_details: {}",
            yaml(&format!("by source: {}", licences.join("; ")))
        );
    }
    let _ = writeln!(
        s,
        "pretty_name: {}",
        yaml(&format!("matedit synthetic dataset {}", plan.name))
    );
    let _ = writeln!(s, "size_categories:\n- {}", size_category(total));
    s.push_str("task_categories:\n- image-to-image\ntags:\n- synthetic\n- material-editing\n- inverse-rendering\n- brdf\n- hdr\n");
    // `original` for what this project's generators made, then the origin of every source read
    // from a path (`unknown` when its manifest entry names none).
    let mut origins = Vec::new();
    if plan.sources.iter().any(super::provenance::is_embedded) {
        origins.push("original".to_string());
    }
    origins.extend(distinct(
        plan.sources
            .iter()
            .filter(|x| !super::provenance::is_embedded(x))
            .map(|x| yaml(&x.origin)),
    ));
    if !origins.is_empty() {
        s.push_str("source_datasets:\n");
        for o in &origins {
            let _ = writeln!(s, "- {o}");
        }
    }
    s.push_str("dataset_info:\n  splits:\n");
    for sp in &plan.splits {
        let n = rec.counts.get(&sp.name).copied().unwrap_or(0);
        let _ = writeln!(s, "  - name: {}\n    num_examples: {n}", yaml(&sp.name));
    }
    s.push_str("---\n\n");
}

fn splits(s: &mut String, rec: &DatasetRecord) {
    s.push_str("## Splits\n\n| split | role | samples | shapes | materials | environments | shards |\n|---|---|--:|--:|--:|--:|--:|\n");
    for sp in &rec.plan.splits {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} |",
            sp.name,
            sp.role,
            rec.counts.get(&sp.name).copied().unwrap_or(0),
            sp.shapes.len(),
            sp.materials.len(),
            sp.environments.len(),
            sp.shards.len()
        );
    }
    let merges = rec.plan.content.merges.len();
    let _ = writeln!(
        s,
        "\nThe splits were dealt before anything was rendered: no shape is in two splits, and no material or \
         near-duplicate material group is in both a training and a test split. The rules hold by content as well \
         as by name: shapes of identical or near-duplicate geometry, materials of identical parameters and \
         identical environment maps are one group, dealt whole ({merges} such merge{} in this dataset, listed in \
         `dataset.json` → `content.merges`). `datagen verify DIR` checks every rule and every checksum again.\n",
        if merges == 1 { "" } else { "s" }
    );
}

fn sources(s: &mut String, list: &[SourceRecord], substitutions: &[String]) {
    s.push_str("## Sources and licences\n\n| kind | source | provides | origin | licence |\n|---|---|---|---|---|\n");
    for x in list {
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} |",
            x.kind,
            x.source,
            cell(&x.provides),
            cell(&x.origin),
            cell(&x.licence)
        );
    }
    if list.is_empty() {
        s.push_str("| – | – | not recorded (a dataset made before sources were recorded) | unknown | unknown |\n");
    }
    s.push_str(
        "\nA source read from a folder has the origin and licence its manifest entry gives (`origin`, \
         `licence`), and `unknown` where it gives none: check the terms of that data before you publish.\n",
    );
    for note in substitutions {
        let _ = writeln!(s, "\n- Substituted: {note}");
    }
    s.push('\n');
}

fn made(s: &mut String, rec: &DatasetRecord) {
    let plan = &rec.plan;
    s.push_str("## How it was made\n\n");
    if let Some(settings) = plan.settings.as_object() {
        let list: Vec<String> = settings.iter().map(|(k, v)| format!("`{k}` = {v}")).collect();
        let _ = writeln!(s, "Render settings: {}.\n", list.join(", "));
    }
    let _ = writeln!(
        s,
        "The resolved manifest (defaults filled in; hash `{}`). Saved as `manifest.toml`, `datagen run manifest.toml` \
         makes this dataset again, byte for byte, on any number of threads or workers; `datagen verify DIR` checks \
         a copy.\n\n```toml\n{}```\n\n`index.jsonl` checksum: `{}`.\n",
        plan.manifest_hash,
        manifest_toml(&plan.manifest),
        rec.index_checksum
    );
}

/// The manifest as TOML (nulls, which TOML cannot hold, are the absent fields' defaults).
pub fn manifest_toml(manifest: &serde_json::Value) -> String {
    fn strip(v: &serde_json::Value) -> Option<serde_json::Value> {
        use serde_json::Value;
        match v {
            Value::Null => None,
            Value::Object(m) => Some(Value::Object(
                m.iter().filter_map(|(k, v)| strip(v).map(|v| (k.clone(), v))).collect(),
            )),
            Value::Array(a) => Some(Value::Array(a.iter().filter_map(strip).collect())),
            other => Some(other.clone()),
        }
    }
    strip(manifest)
        .and_then(|v| toml::to_string(&v).ok())
        .unwrap_or_else(|| "# (the manifest could not be written as TOML; see dataset.json → manifest)\n".into())
}

fn loading(s: &mut String) {
    s.push_str(
        "## Loading it\n\nFrom Python (`pip install ./python` in the matedit repository; numpy and OpenEXR):\n\n```python\n\
         from matedit_data import open_dataset\n\
         ds = open_dataset(\"path/to/this/folder\")\n\
         for sample in ds.split(\"train\"):\n    \
         print(sample.id, sample.I.shape, sample.normals.shape, sample.m.shape)\n```\n\n\
         In PyTorch, `matedit_data.torch.SampleDataset(DIR, \"train\")` with `collate_fn=matedit_data.torch.collate` \
         gives the batches the Rust trainer reads, value for value. `datagen export --webdataset OUT DIR` writes the \
         same samples as WebDataset tar shards. Every channel, unit and coordinate frame is described in the \
         repository's `docs/FORMAT.md`.\n",
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn size_categories_cover_the_whole_range_at_their_edges() {
        assert_eq!(size_category(0), "n<1K");
        assert_eq!(size_category(999), "n<1K");
        assert_eq!(size_category(1_000), "1K<n<10K");
        assert_eq!(size_category(99_999), "10K<n<100K");
        assert_eq!(size_category(100_000), "100K<n<1M");
        assert_eq!(size_category(usize::MAX), "n>1T");
    }

    #[test]
    fn licences_map_to_the_hubs_ids_or_other_never_a_guess() {
        assert_eq!(hub_licence("CC0-1.0"), "cc0-1.0");
        assert_eq!(hub_licence(" MIT "), "mit");
        assert_eq!(hub_licence("unknown"), "unknown");
        assert_eq!(hub_licence("MIT OR Apache-2.0"), "other");
        assert_eq!(hub_licence("MERL BRDF database terms"), "other");
        assert_eq!(hub_licence(""), "other");
    }

    #[test]
    fn cells_and_yaml_scalars_cannot_break_their_table_or_front_matter() {
        assert_eq!(cell("a|b\nc"), "a\\|b c");
        assert_eq!(cell(""), "–");
        assert_eq!(yaml("x: \"y\"\n- z"), r#""x: \"y\"\n- z""#);
    }
}

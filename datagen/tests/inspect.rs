//! `datagen inspect`: the samples on the sheet cover the dataset's shapes, materials and
//! environments, the same dataset always gives the same sheet, and the sheet names its columns
//! and captions its rows.

use matedit_contract::io::SheetLabels;
use matedit_contract::lock::Worker;
use matedit_contract::records::SampleRecord;
use matedit_datagen::dataset::inspect::{COLUMNS, TILE, caption, inspect, pick};
use matedit_datagen::dataset::run::{RunOptions, load, run};
use std::collections::BTreeSet;
use std::path::Path;

/// A scratch folder of one test, removed when the test ends.
fn scratch(name: &str) -> tempfile::TempDir {
    tempfile::Builder::new()
        .prefix(&format!("matedit-inspect-{name}-"))
        .tempdir()
        .unwrap()
}

/// Two shapes × two materials × three environments × two views per split. The index lists
/// environments innermost (after shape and material), and 24 train samples over 4 rows put
/// every 6th sample on the sheet: all with the first environment.
const MANIFEST: &str = include_str!("../../tests/fixtures/manifests/inspect.toml");

fn dataset(dir: &Path) -> Vec<SampleRecord> {
    let manifest = dir.join("m.toml");
    std::fs::write(&manifest, MANIFEST).unwrap();
    let data = dir.join("data");
    run(
        &load(&manifest).unwrap(),
        &RunOptions {
            out: Some(data.clone()),
            worker: Worker::ALL,
            progress: false,
        },
    )
    .unwrap();
    std::fs::read_to_string(data.join("index.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// Distinct shapes, materials, environments, splits and views among `picks`.
fn coverage(records: &[SampleRecord], picks: &[usize]) -> [usize; 5] {
    let distinct = |f: &dyn Fn(&SampleRecord) -> Vec<String>| {
        picks
            .iter()
            .flat_map(|&k| f(&records[k]))
            .collect::<BTreeSet<_>>()
            .len()
    };
    [
        distinct(&|r| vec![r.shape_id.clone()]),
        distinct(&|r| r.material_ids.clone()),
        distinct(&|r| vec![r.env_id.clone()]),
        distinct(&|r| vec![r.split.clone()]),
        distinct(&|r| vec![format!("{}/{}", r.view_azimuth_deg, r.view_elevation_deg)]),
    ]
}

/// The rule `inspect` used before: every k-th sample of the index.
fn every_kth(n: usize, count: usize) -> Vec<usize> {
    (0..count).map(|k| k * n / count).collect()
}

#[test]
fn the_sheet_covers_more_shapes_materials_and_environments_than_every_kth_sample_and_is_deterministic() {
    let tmp = scratch("coverage");
    let dir = tmp.path();
    let all = dataset(dir);
    let train: Vec<SampleRecord> = all.iter().filter(|r| r.split == "train").cloned().collect();
    let envs = all.iter().map(|r| &r.env_id).collect::<BTreeSet<_>>().len();
    assert!(envs >= 3, "the manifest should give several environments, got {envs}");

    // Over the train split the old rule shows one environment on every row; over the whole
    // index it happens to cover everything, and the greedy pick must not do worse there.
    for (records, count, strictly_more) in [(&train, 4, true), (&all, 6, false)] {
        let greedy = pick(records, count);
        let old = every_kth(records.len(), count);
        let (g, o) = (coverage(records, &greedy), coverage(records, &old));
        let what = format!("{count} of {}: greedy covers {g:?}, every k-th {o:?}", records.len());
        assert_eq!(greedy.len(), count);
        assert!(
            greedy.windows(2).all(|w| w[0] < w[1]),
            "picks in index order: {greedy:?}"
        );
        assert!((0..5).all(|d| g[d] >= o[d]), "{what}");
        if strictly_more {
            assert!(g[..3].iter().sum::<usize>() > o[..3].iter().sum::<usize>(), "{what}");
        }
        assert_eq!(pick(records, count), greedy, "same index, same picks");
    }
    assert_eq!(coverage(&train, &every_kth(train.len(), 4))[2], 1);
    assert_eq!(coverage(&train, &pick(&train, 4))[2], 3);
    // Both splits appear, and six rows show six views.
    assert_eq!(coverage(&all, &pick(&all, 6))[3..], [2, 6]);
    // Asking for more rows than samples shows every sample once.
    assert_eq!(pick(&train, 1000), (0..train.len()).collect::<Vec<_>>());
}

#[test]
fn inspect_writes_the_same_labelled_sheet_twice_and_names_the_rows_it_shows() {
    let tmp = scratch("sheet");
    let dir = tmp.path();
    let records = dataset(dir);
    let data = dir.join("data");
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    let ids = inspect(&data, &a, 5, None).unwrap();
    assert_eq!(inspect(&data, &b, 5, None).unwrap(), ids);
    assert_eq!(
        std::fs::read(&a).unwrap(),
        std::fs::read(&b).unwrap(),
        "same dataset, same sheet"
    );
    let shown: Vec<&SampleRecord> = pick(&records, 5).into_iter().map(|k| &records[k]).collect();
    assert_eq!(ids, shown.iter().map(|r| r.id.clone()).collect::<Vec<_>>());

    // Each row is captioned with the ids that make it differ from the others.
    let captions: Vec<String> = shown.iter().map(|r| caption(r)).collect();
    for (r, c) in shown.iter().zip(&captions) {
        for id in [&r.id, &r.shape_id, &r.env_id].into_iter().chain(&r.material_ids) {
            assert!(c.contains(id.as_str()), "caption {c:?} lacks {id}");
        }
    }
    // The sheet is the grid plus a header row and a caption strip per row.
    let labels = SheetLabels {
        columns: &COLUMNS,
        rows: &captions,
    };
    let img = image::open(&a).unwrap().to_rgba8();
    assert_eq!(img.width() as usize, COLUMNS.len() * TILE);
    assert_eq!(
        img.height() as usize,
        labels.header_height() + ids.len() * (labels.caption_height() + TILE)
    );
    let background = *img.get_pixel(0, 0);
    for (c, name) in COLUMNS.iter().enumerate() {
        let lit = (0..labels.header_height())
            .flat_map(|y| (c * TILE..(c + 1) * TILE).map(move |x| (x, y)))
            .filter(|&(x, y)| *img.get_pixel(x as u32, y as u32) != background)
            .count();
        assert!(lit > 0, "column {c} ({name}) has no name in the header");
    }
}

//! `datagen inspect DIR`: a contact sheet of samples, one row each: I, O, normals, mask,
//! regions and the camera-space environment, each row captioned with its sample's ids. The
//! samples are chosen to cover as many shapes, materials and environments as the rows allow
//! ([`pick`]): the index is ordered shape, material, environment, view, so every k-th sample tends
//! to repeat one environment.

use anyhow::{Context, Result, bail};
use matedit_assets::envfile::load_env;
use matedit_assets::envmaps::thumbnail;
use matedit_contract::io::{SheetLabels, normal_to_u8, read_exr_channels, write_labelled_contact_sheet};
use matedit_contract::records::SampleRecord;
use matedit_physics::tonemap::tonemap_u8;
use std::collections::HashMap;
use std::path::Path;

/// Tile side in the sheet.
pub const TILE: usize = 128;
/// Columns per sample.
pub const COLUMNS: [&str; 6] = ["I", "O", "normals", "mask", "regions", "environment"];

/// Distinct colours for region ids.
const PALETTE: [[u8; 3]; 6] = [
    [230, 159, 0],
    [86, 180, 233],
    [0, 158, 115],
    [240, 228, 66],
    [0, 114, 178],
    [213, 94, 0],
];

/// Writes a sheet of `count` samples of the index (or of `split`) chosen by [`pick`], in index
/// order. Returns the ids shown.
pub fn inspect(dir: &Path, out: &Path, count: usize, split: Option<&str>) -> Result<Vec<String>> {
    let index_path = dir.join("index.jsonl");
    let text = std::fs::read_to_string(&index_path).with_context(|| format!("cannot read {}", index_path.display()))?;
    let records: Vec<SampleRecord> = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.is_empty())
        .map(|(n, l)| {
            serde_json::from_str::<SampleRecord>(l).with_context(|| format!("{}:{}", index_path.display(), n + 1))
        })
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .filter(|r| split.is_none_or(|s| r.split == s))
        .collect();
    if records.is_empty() {
        bail!(
            "{}: no samples{}",
            index_path.display(),
            split.map(|s| format!(" in split {s}")).unwrap_or_default()
        );
    }
    let picks: Vec<&SampleRecord> = pick(&records, count).into_iter().map(|k| &records[k]).collect();
    let mut tiles = Vec::new();
    for rec in &picks {
        tiles.extend(sample_tiles(dir, rec)?);
    }
    let captions: Vec<String> = picks.iter().map(|r| caption(r)).collect();
    let labels = SheetLabels {
        columns: &COLUMNS,
        rows: &captions,
    };
    write_labelled_contact_sheet(out, &tiles, TILE, TILE, COLUMNS.len(), &labels)?;
    Ok(picks.iter().map(|r| r.id.clone()).collect())
}

// The recorded ids [`pick`] tries to vary, most important first: indices into `facets`.
const FACETS: usize = 5;
const SHAPE: usize = 0;
const MATERIAL: usize = 1;
const ENVIRONMENT: usize = 2;
const SPLIT: usize = 3;
const VIEW: usize = 4;

fn facets(r: &SampleRecord) -> [Vec<String>; FACETS] {
    let mut materials = r.material_ids.clone();
    materials.sort();
    materials.dedup();
    [
        vec![r.shape_id.clone()],
        materials,
        vec![r.env_id.clone()],
        vec![r.split.clone()],
        vec![format!("{}/{}", r.view_azimuth_deg, r.view_elevation_deg)],
    ]
}

/// Chooses `count` (at least 1, at most all) of `records` and returns their positions in
/// ascending order. Greedy: each pick is the sample adding the most facets not yet shown among
/// shape, materials and environment, then the most new material ids, then a new split or view;
/// ties go to the earlier sample, so the same index always gives the same sheet. Once every
/// value of a facet has been shown, that facet starts over, so later rows spread again instead
/// of bunching at the start of the index.
pub fn pick(records: &[SampleRecord], count: usize) -> Vec<usize> {
    if records.is_empty() {
        return Vec::new();
    }
    let count = count.clamp(1, records.len());
    // Facet values as small integers, so scoring a candidate is cheap on large indexes.
    let mut ids: [HashMap<String, usize>; FACETS] = Default::default();
    let values: Vec<[Vec<usize>; FACETS]> = records
        .iter()
        .map(|r| {
            let f = facets(r);
            std::array::from_fn(|d| {
                f[d].iter()
                    .map(|v| {
                        let next = ids[d].len();
                        *ids[d].entry(v.clone()).or_insert(next)
                    })
                    .collect()
            })
        })
        .collect();
    let mut shown: [Vec<bool>; FACETS] = std::array::from_fn(|d| vec![false; ids[d].len()]);
    let mut taken = vec![false; records.len()];
    let mut out = Vec::with_capacity(count);
    for _ in 0..count {
        let mut best: Option<((usize, usize, usize), usize)> = None;
        for (k, v) in values.iter().enumerate().filter(|(k, _)| !taken[*k]) {
            let new = |d: usize| v[d].iter().filter(|&&i| !shown[d][i]).count();
            let score = (
                [SHAPE, MATERIAL, ENVIRONMENT]
                    .into_iter()
                    .filter(|&d| new(d) > 0)
                    .count(),
                new(MATERIAL),
                [SPLIT, VIEW].into_iter().filter(|&d| new(d) > 0).count(),
            );
            // Strictly greater: an equal score keeps the earlier sample.
            if best.is_none_or(|(s, _)| score > s) {
                best = Some((score, k));
            }
        }
        let Some((_, k)) = best else { break };
        taken[k] = true;
        out.push(k);
        for d in 0..FACETS {
            for &i in &values[k][d] {
                shown[d][i] = true;
            }
            if shown[d].iter().all(|&s| s) {
                shown[d].fill(false);
            }
        }
    }
    out.sort_unstable();
    out
}

/// A row's caption: the sample, its split, shape, environment and view, then the materials (m)
/// and the targets (m_t) per region.
pub fn caption(r: &SampleRecord) -> String {
    format!(
        "{} ({})  shape {}  env {} @{:.0}\u{b0}  view {:.0}\u{b0},{:.0}\u{b0}\nm   {}\nm_t {}",
        r.id,
        r.split,
        r.shape_id,
        r.env_id,
        r.env_rotation_deg,
        r.view_azimuth_deg,
        r.view_elevation_deg,
        r.material_ids.join(","),
        r.target_material_ids.join(","),
    )
}

fn sample_tiles(dir: &Path, rec: &SampleRecord) -> Result<Vec<Vec<[u8; 4]>>> {
    let image = rec.files.get("image").context("no image file recorded")?;
    let (w, h, ch) = read_exr_channels(&dir.join(image))?;
    let get = |name: &str| ch.get(name).with_context(|| format!("{image}: no channel {name}"));
    let (r, g, b) = (get("R")?, get("G")?, get("B")?);
    let (or, og, ob) = (get("O.R")?, get("O.G")?, get("O.B")?);
    let (nx, ny, nz) = (get("normal.X")?, get("normal.Y")?, get("normal.Z")?);
    let (mask, region) = (get("mask")?, get("region")?);
    // One exposure for I and O (from I's median), so the edit's brightness change is visible.
    let mut lum: Vec<f32> = (0..w * h)
        .filter(|&p| mask[p] > 0.0)
        .map(|p| (r[p] + g[p] + b[p]) / 3.0)
        .collect();
    lum.sort_by(|a, b| a.total_cmp(b));
    let exposure = lum.get(lum.len() / 2).map_or(1.0, |m| 0.18 / m.max(1e-6));
    let tile = |f: &dyn Fn(usize) -> [u8; 4]| -> Vec<[u8; 4]> {
        (0..TILE * TILE)
            .map(|t| {
                let (x, y) = ((t % TILE) * w / TILE, (t / TILE) * h / TILE);
                f(y * w + x)
            })
            .collect()
    };
    fn rgb<'a>(c: [&'a Vec<f32>; 3], mask: &'a [f32], exposure: f32) -> impl Fn(usize) -> [u8; 4] + 'a {
        move |p: usize| {
            let a = if mask[p] > 0.0 { 255 } else { 0 };
            [
                tonemap_u8(c[0][p], exposure),
                tonemap_u8(c[1][p], exposure),
                tonemap_u8(c[2][p], exposure),
                a,
            ]
        }
    }
    let mut out = vec![
        tile(&rgb([r, g, b], mask, exposure)),
        tile(&rgb([or, og, ob], mask, exposure)),
    ];
    out.push(tile(&|p| {
        if mask[p] > 0.0 {
            [normal_to_u8(nx[p]), normal_to_u8(ny[p]), normal_to_u8(nz[p]), 255]
        } else {
            [0; 4]
        }
    }));
    out.push(tile(&|p| if mask[p] > 0.0 { [255; 4] } else { [0, 0, 0, 255] }));
    out.push(tile(&|p| {
        if mask[p] > 0.0 {
            let c = PALETTE[region[p] as usize % PALETTE.len()];
            [c[0], c[1], c[2], 255]
        } else {
            [0; 4]
        }
    }));
    let env_file = rec.files.get("env").context("no env file recorded")?;
    let env_path = dir.join(env_file);
    let (map, _) = load_env(
        env_path
            .to_str()
            .with_context(|| format!("{env_file}: path is not UTF-8"))?,
    )?;
    let thumb = thumbnail(&map, TILE / 2);
    let mut env_tile = vec![[0u8; 4]; TILE * TILE];
    let top = TILE / 4;
    for (k, px) in thumb.iter().enumerate() {
        let (x, y) = (k % TILE, k / TILE);
        env_tile[(y + top) * TILE + x] = *px;
    }
    out.push(env_tile);
    Ok(out)
}

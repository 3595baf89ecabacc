//! `datagen inspect DIR`: a contact sheet of samples, one row each: I, O, normals, mask,
//! regions and the camera-space environment.

use super::sample::SampleRecord;
use crate::assets::envmaps::thumbnail;
use crate::io::{load_env, normal_to_u8, read_exr_channels, write_contact_sheet};
use anyhow::{Context, Result, bail};
use matedit_physics::tonemap::tonemap_u8;
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

/// Writes a sheet of `count` samples spread evenly over the index (or those of `split`).
/// Returns the ids shown.
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
    let count = count.clamp(1, records.len());
    let picks: Vec<&SampleRecord> = (0..count).map(|k| &records[k * records.len() / count]).collect();
    let mut tiles = Vec::new();
    for rec in &picks {
        tiles.extend(sample_tiles(dir, rec)?);
    }
    write_contact_sheet(out, &tiles, TILE, TILE, COLUMNS.len())?;
    Ok(picks.iter().map(|r| r.id.clone()).collect())
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

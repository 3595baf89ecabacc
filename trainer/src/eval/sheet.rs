//! The contact sheet of `trainer eval`: one row per shown sample, columns I, I', O, O', n, n',
//! L, L' (the final checkpoint's predictions). Each pair shares the ground truth's exposure (the
//! metrics' rule, [`super::metrics::metric_exposure`]), so a brightness error shows as one.

use super::metrics::metric_exposure;
use anyhow::Result;
use matedit_datagen::io::{normal_to_u8, write_contact_sheet};
use matedit_physics::tonemap::tonemap_u8;
use std::path::Path;

/// Tile side in pixels.
pub const TILE: usize = 96;
/// Column titles, in order.
pub const COLUMNS: [&str; 8] = ["I", "I'", "O", "O'", "n", "n'", "L", "L'"];

/// The images of one shown sample, channel-first.
#[derive(Clone, Debug, Default)]
pub struct Shown {
    /// Image side.
    pub size: usize,
    /// Environment rows.
    pub env_height: usize,
    /// Object mask `[S, S]`.
    pub mask: Vec<f32>,
    /// I, I', O, O' (`[3, S, S]` each).
    pub images: [Vec<f32>; 4],
    /// n, n' (`[3, S, S]`).
    pub normals: [Vec<f32>; 2],
    /// L, L' (`[3, He, 2He]`).
    pub env: [Vec<f32>; 2],
}

type Tile = Vec<[u8; 4]>;

/// A `[3, H, W]` image scaled into a tile (nearest), letterboxed to keep its aspect.
fn tile(h: usize, w: usize, px: impl Fn(usize) -> [u8; 4]) -> Tile {
    let scale = (TILE as f64 / h as f64).min(TILE as f64 / w as f64);
    let (th, tw) = ((h as f64 * scale) as usize, (w as f64 * scale) as usize);
    let (oy, ox) = ((TILE - th) / 2, (TILE - tw) / 2);
    (0..TILE * TILE)
        .map(|t| {
            let (y, x) = (t / TILE, t % TILE);
            if y < oy || y >= oy + th || x < ox || x >= ox + tw {
                return [0; 4];
            }
            let (sy, sx) = ((y - oy) * h / th.max(1), (x - ox) * w / tw.max(1));
            px(sy.min(h - 1) * w + sx.min(w - 1))
        })
        .collect()
}

fn radiance<'a>(img: &'a [f32], mask: Option<&'a [f32]>, hw: usize, exposure: f32) -> impl Fn(usize) -> [u8; 4] + 'a {
    move |p| {
        if mask.is_some_and(|m| m[p] <= 0.5) {
            return [0; 4];
        }
        let c = |k: usize| tonemap_u8(img[k * hw + p], exposure);
        [c(0), c(1), c(2), 255]
    }
}

fn normal<'a>(n: &'a [f32], mask: &'a [f32], hw: usize) -> impl Fn(usize) -> [u8; 4] + 'a {
    move |p| {
        if mask[p] <= 0.5 {
            return [0; 4];
        }
        [
            normal_to_u8(n[p]),
            normal_to_u8(n[hw + p]),
            normal_to_u8(n[2 * hw + p]),
            255,
        ]
    }
}

/// The tiles of one sample, in [`COLUMNS`] order.
pub fn tiles(s: &Shown) -> Vec<Tile> {
    let (n, hw) = (s.size, s.size * s.size);
    let mut out = Vec::new();
    for pair in [[0, 1], [2, 3]] {
        let e = metric_exposure(&s.images[pair[0]], &s.mask);
        for k in pair {
            out.push(tile(n, n, radiance(&s.images[k], Some(&s.mask), hw, e)));
        }
    }
    for k in 0..2 {
        out.push(tile(n, n, normal(&s.normals[k], &s.mask, hw)));
    }
    let (he, we) = (s.env_height, 2 * s.env_height);
    let all = vec![1.0f32; he * we];
    let e = metric_exposure(&s.env[0], &all);
    for k in 0..2 {
        out.push(tile(he, we, radiance(&s.env[k], None, he * we, e)));
    }
    out
}

/// Writes the sheet of `shown` to `path` (PNG, atomically).
pub fn write(path: &Path, shown: &[Shown]) -> Result<()> {
    let tiles: Vec<Tile> = shown.iter().flat_map(tiles).collect();
    write_contact_sheet(path, &tiles, TILE, TILE, COLUMNS.len())
}

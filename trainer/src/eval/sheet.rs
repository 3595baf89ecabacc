//! The contact sheet of `trainer eval`: one row per shown sample, columns I, I', O, O', n, n',
//! L, L' (the final checkpoint's predictions) under a header row naming them; and, when several
//! methods are scored, the methods sheet: I, O and every method's O' side by side. Each pair shares
//! the ground truth's exposure (the metrics' rule, [`crate::metrics::metric_exposure`]), so a
//! brightness error shows as one.

use crate::metrics::metric_exposure;
use anyhow::Result;
use matedit_contract::io::{SheetLabels, contact_sheet, normal_to_u8, write_labelled_contact_sheet};
use matedit_physics::tonemap::tonemap_u8;
use std::path::Path;

/// Tile side in pixels.
pub const TILE: usize = 96;
/// Column titles, in order: the sheet's header row shows them. Ground truth and prediction
/// alternate; I' is the input re-rendered from the predictions, O' the edit (the predicted
/// normals and light with the target material m_t).
pub const COLUMNS: [&str; 8] = [
    "I (input)",
    "I' (pred)",
    "O (truth)",
    "O' (pred)",
    "n (truth)",
    "n' (pred)",
    "L (truth)",
    "L' (pred)",
];

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

/// An image of RGBA pixels, row-major.
pub type Tile = Vec<[u8; 4]>;

/// A `[3, H, W]` image scaled into a tile (nearest), letterboxed to keep its aspect.
fn tile(h: usize, w: usize, px: impl Fn(usize) -> [u8; 4]) -> Tile {
    letterboxed(TILE, h, w, [0; 4], px)
}

/// An `h × w` image (pixel `k` from `px(k)`) scaled into a `side`² tile (nearest), letterboxed
/// with `background` to keep its aspect.
pub fn letterboxed(side: usize, h: usize, w: usize, background: [u8; 4], px: impl Fn(usize) -> [u8; 4]) -> Tile {
    let scale = (side as f64 / h as f64).min(side as f64 / w as f64);
    let (th, tw) = ((h as f64 * scale) as usize, (w as f64 * scale) as usize);
    let (oy, ox) = ((side - th) / 2, (side - tw) / 2);
    (0..side * side)
        .map(|t| {
            let (y, x) = (t / side, t % side);
            if y < oy || y >= oy + th || x < ox || x >= ox + tw {
                return background;
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

const LABELS: SheetLabels<'static> = SheetLabels {
    columns: &COLUMNS,
    rows: &[],
};

/// The sheet of `shown`, header row included.
pub fn sheet_image(shown: &[Shown]) -> image::RgbaImage {
    let tiles: Vec<Tile> = shown.iter().flat_map(tiles).collect();
    contact_sheet(&tiles, TILE, TILE, COLUMNS.len(), &LABELS)
}

/// One shown sample of the methods sheet: I, O and each method's O' (`[3, S, S]` each).
#[derive(Clone, Debug, Default)]
pub struct Compared {
    /// Image side.
    pub size: usize,
    /// Object mask `[S, S]`.
    pub mask: Vec<f32>,
    /// I.
    pub input: Vec<f32>,
    /// O.
    pub target: Vec<f32>,
    /// Each method's O', in the order of the names.
    pub edits: Vec<Vec<f32>>,
}

/// Tile side of the methods sheet (wider than [`TILE`]: its column names are longer).
pub const METHOD_TILE: usize = 160;

/// The methods sheet: per sample I, O and every method's O' (the edits at O's exposure, so that
/// a brightness error shows), under a header row naming them.
pub fn methods_image(names: &[String], compared: &[Compared]) -> image::RgbaImage {
    let mut columns: Vec<&str> = vec!["I (input)", "O (truth)"];
    columns.extend(names.iter().map(String::as_str));
    let mut tiles: Vec<Tile> = Vec::new();
    for c in compared {
        let (n, hw) = (c.size, c.size * c.size);
        let at = |img: &[f32], e: f32| letterboxed(METHOD_TILE, n, n, [0; 4], radiance(img, Some(&c.mask), hw, e));
        tiles.push(at(&c.input, metric_exposure(&c.input, &c.mask)));
        let e = metric_exposure(&c.target, &c.mask);
        for img in std::iter::once(&c.target).chain(&c.edits) {
            tiles.push(at(img, e));
        }
    }
    let labels = SheetLabels {
        columns: &columns,
        rows: &[],
    };
    contact_sheet(&tiles, METHOD_TILE, METHOD_TILE, columns.len(), &labels)
}

/// Writes the methods sheet to `path` (PNG, atomically).
pub fn write_methods(path: &Path, names: &[String], compared: &[Compared]) -> Result<()> {
    let img = methods_image(names, compared);
    matedit_contract::io::write_atomically(path, |tmp| {
        img.save_with_format(tmp, image::ImageFormat::Png)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))
    })
}

/// Writes the sheet of `shown` to `path` (PNG, atomically).
pub fn write(path: &Path, shown: &[Shown]) -> Result<()> {
    let tiles: Vec<Tile> = shown.iter().flat_map(tiles).collect();
    write_labelled_contact_sheet(path, &tiles, TILE, TILE, COLUMNS.len(), &LABELS)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lit sphere (prediction a little darker) under a sky-to-ground gradient.
    fn sphere(size: usize, env_height: usize) -> Shown {
        let hw = size * size;
        let (mut mask, mut n) = (vec![0.0f32; hw], vec![0.0f32; 3 * hw]);
        for p in 0..hw {
            let x = 2.0 * ((p % size) as f32 + 0.5) / size as f32 - 1.0;
            let y = 1.0 - 2.0 * ((p / size) as f32 + 0.5) / size as f32;
            let z2 = 1.0 - x * x - y * y;
            if z2 > 0.0 {
                mask[p] = 1.0;
                [n[p], n[hw + p], n[2 * hw + p]] = [x, y, z2.sqrt()];
            }
        }
        let shade = |gain: f32| -> Vec<f32> {
            let z = &n[2 * hw..];
            (0..3)
                .flat_map(|c| z.iter().map(move |z| (0.3 + 0.2 * c as f32) * gain * z))
                .collect()
        };
        let (he, we) = (env_height, 2 * env_height);
        let env: Vec<f32> = (0..3)
            .flat_map(|c| (0..he * we).map(move |t| (1.0 - (t / we) as f32 / he as f32) * (0.4 + 0.3 * c as f32)))
            .collect();
        Shown {
            size,
            env_height,
            mask,
            images: [shade(1.0), shade(0.8), shade(0.6), shade(0.5)],
            normals: [n.clone(), n],
            env: [env.clone(), env.iter().map(|v| v * 0.7).collect()],
        }
    }

    #[test]
    fn the_sheet_has_a_header_row_naming_each_column_from_the_column_list() {
        let shown = [sphere(64, 8), sphere(32, 4)];
        let img = sheet_image(&shown);
        let path = std::env::temp_dir().join(format!("matedit-eval-sheet-{}.png", std::process::id()));
        write(&path, &shown).unwrap();
        let written = ::image::open(&path).unwrap().to_rgba8();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(written, img, "the written sheet is the one drawn");
        let header = LABELS.header_height();
        assert!(header > 0);
        assert_eq!(img.width() as usize, COLUMNS.len() * TILE);
        assert_eq!(
            img.height() as usize,
            header + shown.len() * TILE,
            "taller by the header"
        );
        assert_eq!(tiles(&shown[0]).len(), COLUMNS.len(), "one tile per named column");

        // Column c's header cell is exactly the header of a one-column sheet titled COLUMNS[c]:
        // the names come from the column list, in its order.
        let background = *img.get_pixel(0, 0);
        for (c, name) in COLUMNS.iter().enumerate() {
            let alone = contact_sheet(
                &[],
                TILE,
                TILE,
                1,
                &SheetLabels {
                    columns: &[name],
                    rows: &[],
                },
            );
            let mut lit = 0;
            for y in 0..header as u32 {
                for x in 0..TILE as u32 {
                    let px = *img.get_pixel(c as u32 * TILE as u32 + x, y);
                    assert_eq!(
                        px,
                        *alone.get_pixel(x, y),
                        "column {c}'s header is not {name:?} at ({x}, {y})"
                    );
                    lit += usize::from(px != background);
                }
            }
            assert!(lit > 0, "column {c} ({name}) has no header text");
        }
    }
}

//! A labelled figure of photos and their edits: one row per photo, one column per image.
//!
//! `cargo run --release -p matedit-edit --example edit_figure -- OUT.png|OUT.jpg "COL1,COL2,..." ROW...`
//! where each ROW is the comma-separated image files of one row, optionally after a label and
//! `::` (`"car-1 ratio::a.png,b.png"`; see `scripts/edit_cars.sh`).
use anyhow::{Context, Result, bail};
use matedit_contract::io::{SheetLabels, contact_sheet, write_atomically, write_labelled_contact_sheet};

/// Tile size: photos are letterboxed into it.
const TILE: (usize, usize) = (320, 240);

fn tile(path: &str) -> Result<Vec<[u8; 4]>> {
    let img = image::open(path)
        .with_context(|| format!("cannot read {path}"))?
        .to_rgba8();
    let s = (TILE.0 as f64 / img.width() as f64).min(TILE.1 as f64 / img.height() as f64);
    let (w, h) = (
        ((img.width() as f64 * s) as u32).max(1),
        ((img.height() as f64 * s) as u32).max(1),
    );
    let small = image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
    let (ox, oy) = ((TILE.0 - w as usize) / 2, (TILE.1 - h as usize) / 2);
    let mut out = vec![[0, 0, 0, 255]; TILE.0 * TILE.1];
    for (x, y, p) in small.enumerate_pixels() {
        out[(oy + y as usize) * TILE.0 + ox + x as usize] = [p[0], p[1], p[2], 255];
    }
    Ok(out)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        bail!("usage: edit_figure OUT.png \"COL1,COL2,...\" ROW... (each ROW: comma-separated image files)");
    }
    let columns: Vec<&str> = args[1].split(',').collect();
    let mut tiles = Vec::new();
    let mut row_labels = Vec::new();
    for row in &args[2..] {
        let (label, row) = row.split_once("::").unwrap_or(("", row));
        row_labels.push(label.to_string());
        let files: Vec<&str> = row.split(',').collect();
        if files.len() != columns.len() {
            bail!("row {row}: {} images for {} columns", files.len(), columns.len());
        }
        for f in files {
            tiles.push(tile(f)?);
        }
    }
    let labels = SheetLabels {
        columns: &columns,
        rows: if row_labels.iter().any(|l| !l.is_empty()) {
            &row_labels
        } else {
            &[]
        },
    };
    let out = std::path::Path::new(&args[0]);
    if out.extension().is_some_and(|e| e == "jpg" || e == "jpeg") {
        // A smaller file for the README.
        let img =
            image::DynamicImage::ImageRgba8(contact_sheet(&tiles, TILE.0, TILE.1, columns.len(), &labels)).to_rgb8();
        write_atomically(out, |tmp| {
            let f = std::io::BufWriter::new(std::fs::File::create(tmp)?);
            image::codecs::jpeg::JpegEncoder::new_with_quality(f, 85)
                .encode_image(&img)
                .with_context(|| format!("cannot write {}", out.display()))
        })?;
    } else {
        write_labelled_contact_sheet(out, &tiles, TILE.0, TILE.1, columns.len(), &labels)?;
    }
    eprintln!("wrote {}", args[0]);
    Ok(())
}

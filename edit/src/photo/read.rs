//! The first stage of an edit: the photo, its mask (or alpha) and region labels read and checked
//! before the network runs.

use super::{Photo, orientation};
use crate::target;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// A photo with its mask and region labels, read and checked.
pub struct ReadPhoto {
    /// The photo.
    pub photo: Photo,
    /// Its path.
    pub path: PathBuf,
    /// Soft object coverage per photo pixel.
    pub coverage: Vec<f32>,
    /// What the report calls the mask.
    pub mask_name: String,
    /// Region label per photo pixel and the number of regions.
    pub labels: Option<(Vec<u8>, usize)>,
    /// How the photo was turned to stand as viewers show it, where its EXIF said to.
    pub orientation: Option<orientation::OrientationReport>,
    /// The horizontal field of view its EXIF gives (degrees), where it gives one.
    pub exif_fov_deg: Option<f64>,
}

/// Reads a photo, its mask (or alpha) and region labels, checking everything before the
/// network runs.
pub fn read_photo(photo_path: &Path, mask: Option<&Path>, regions: Option<&Path>) -> Result<ReadPhoto> {
    let (p, file) = super::load_photo_shown(photo_path)?;
    let turn = file.orientation;
    let mut orientation = orientation::OrientationReport::new(turn, orientation::shown_size((p.width, p.height), turn));
    let (coverage, mask_name) = match mask {
        Some(m) => {
            let (coverage, fit) = super::load_mask(m, p.width, p.height, turn)?;
            orientation.mask = Some(fit);
            (coverage, m.display().to_string())
        }
        None => (
            p.alpha.clone().with_context(|| {
                format!(
                    "{}: no mask given and the photo has no alpha channel; give the object's mask",
                    photo_path.display()
                )
            })?,
            "alpha of the photo".to_string(),
        ),
    };
    super::check_mask_shape(mask.unwrap_or(photo_path), &coverage, p.width)?;
    let labels = match regions {
        Some(r) => {
            let (labels, n, fit) = target::load_regions(r, p.width, p.height, turn, &coverage)?;
            orientation.regions = Some(fit);
            Some((labels, n))
        }
        None => None,
    };
    Ok(ReadPhoto {
        photo: p,
        path: photo_path.to_path_buf(),
        coverage,
        mask_name,
        labels,
        orientation: orientation.matters().then_some(orientation),
        exif_fov_deg: file.fov_deg,
    })
}

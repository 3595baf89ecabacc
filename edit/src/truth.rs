//! `matedit edit --truth T`: the edit scored against the picture it should have made (a render
//! of the same object, view and light with the target material), with the paper's image metrics
//! (`matedit_trainer::metrics`: L2 of the tone-mapped images at the truth's exposure, SSIM) over
//! the object, and beside them the unchanged photo's scores against the same truth: an edit is
//! worth something where it beats the photo it started from.

use crate::photo::{Photo, load_mask, load_photo_shown};
use anyhow::{Context, Result, bail};
use matedit_trainer::metrics::{l2_tonemapped, ssim};
use serde::Serialize;
use std::path::Path;

/// The scores of an edit against its truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthScore {
    /// The truth's file.
    pub file: String,
    /// Object pixels scored.
    pub object_pixels: usize,
    /// L2 of the edit (`edited.exr`) against the truth.
    pub l2: f64,
    /// SSIM of the edit against the truth.
    pub ssim: f64,
    /// L2 of the unchanged photo against the truth.
    pub photo_l2: f64,
    /// SSIM of the unchanged photo against the truth.
    pub photo_ssim: f64,
}

impl TruthScore {
    /// One line for the terminal.
    pub fn line(&self) -> String {
        format!(
            "against the truth {}: L2 {:.1}, SSIM {:.4} (the unchanged photo: L2 {:.1}, SSIM {:.4}; {} object pixels)",
            self.file, self.l2, self.ssim, self.photo_l2, self.photo_ssim, self.object_pixels
        )
    }
}

/// Channel-first `[3, H, W]` of a photo's pixels.
fn planar(p: &Photo) -> Vec<f32> {
    (0..3).flat_map(|c| p.rgb.iter().map(move |px| px[c])).collect()
}

/// Scores the edit written to `out` (its `edited.exr`) and the photo against `truth`, over the
/// photo's object (`mask`, or the photo's alpha): the truth must have the photo's size.
pub fn score(photo_path: &Path, mask: Option<&Path>, truth: &Path, out: &Path) -> Result<TruthScore> {
    let (photo, file) = load_photo_shown(photo_path)?;
    let (t, _) = load_photo_shown(truth).with_context(|| format!("--truth {}", truth.display()))?;
    let (edited, _) = load_photo_shown(&out.join("edited.exr"))?;
    let (w, h) = (photo.width, photo.height);
    if (t.width, t.height) != (w, h) {
        bail!(
            "--truth {}: {}×{} pixels, the photo {}×{}: the truth is the same picture with the target material",
            truth.display(),
            t.width,
            t.height,
            w,
            h
        );
    }
    let coverage = match mask {
        Some(m) => load_mask(m, w, h, file.orientation)?.0,
        None => photo
            .alpha
            .clone()
            .with_context(|| format!("{}: no mask and no alpha to score the object by", photo_path.display()))?,
    };
    let m: Vec<f32> = coverage.iter().map(|&c| f32::from(c > 0.5)).collect();
    let object_pixels = m.iter().filter(|&&v| v > 0.0).count();
    if object_pixels == 0 {
        bail!("{}: the mask covers no pixel: nothing to score", photo_path.display());
    }
    let (pt, pe, pp) = (planar(&t), planar(&edited), planar(&photo));
    Ok(TruthScore {
        file: truth.display().to_string(),
        object_pixels,
        l2: l2_tonemapped(&pe, &pt, &m, h, w),
        ssim: ssim(&pe, &pt, &m, h, w),
        photo_l2: l2_tonemapped(&pp, &pt, &m, h, w),
        photo_ssim: ssim(&pp, &pt, &m, h, w),
    })
}

/// Adds `score` to `out/report.json` as its `truth` field (the file replaced atomically).
pub fn add_to_report(out: &Path, score: &TruthScore) -> Result<()> {
    let path = out.join("report.json");
    let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut report: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    report["truth"] = serde_json::to_value(score)?;
    matedit_contract::io::write_atomically(&path, |p| {
        Ok(std::fs::write(p, serde_json::to_string_pretty(&report)?)?)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png(path: &Path, w: u32, h: u32, px: impl Fn(u32, u32) -> [u8; 4]) {
        image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(px(x, y)))
            .save(path)
            .unwrap();
    }

    fn exr(path: &Path, w: usize, h: usize, px: impl Fn(usize, usize) -> [f32; 3]) {
        let mut ch: Vec<(&str, Vec<f32>)> = vec![("R", Vec::new()), ("G", Vec::new()), ("B", Vec::new())];
        for y in 0..h {
            for x in 0..w {
                let v = px(x, y);
                for (c, (_, values)) in ch.iter_mut().enumerate() {
                    values.push(v[c]);
                }
            }
        }
        matedit_contract::io::write_exr_channels(path, w, h, ch).unwrap();
    }

    #[test]
    fn an_edit_equal_to_its_truth_scores_perfect_and_the_photo_does_not() {
        let d = tempfile::tempdir().unwrap();
        let inside = |x: u32, y: u32| (4..28).contains(&x) && (6..26).contains(&y);
        png(&d.path().join("photo.png"), 32, 32, |x, y| {
            if inside(x, y) {
                [200, 40, 40, 255]
            } else {
                [20, 20, 20, 0]
            }
        });
        let truth_px = |x: usize, y: usize| [0.05, 0.1 + 0.01 * (x % 7) as f32, 0.6 + 0.005 * y as f32];
        exr(&d.path().join("truth.exr"), 32, 32, truth_px);
        exr(&d.path().join("edited.exr"), 32, 32, truth_px);
        let s = score(&d.path().join("photo.png"), None, &d.path().join("truth.exr"), d.path()).unwrap();
        assert_eq!(s.object_pixels, 24 * 20);
        assert!(s.l2.abs() < 1e-9 && (s.ssim - 1.0).abs() < 1e-9, "{s:?}");
        assert!(s.photo_l2 > 100.0 && s.photo_ssim < 0.9, "{s:?}");
        assert!(s.line().contains("the unchanged photo"));
        std::fs::write(d.path().join("report.json"), "{\"stage\": \"x\"}").unwrap();
        add_to_report(d.path(), &s).unwrap();
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.path().join("report.json")).unwrap()).unwrap();
        assert_eq!(r["stage"], "x");
        assert_eq!(r["truth"]["object_pixels"], 480);
    }

    #[test]
    fn a_truth_of_another_size_or_a_photo_without_object_is_refused() {
        let d = tempfile::tempdir().unwrap();
        png(&d.path().join("photo.png"), 16, 16, |_, _| [100, 100, 100, 255]);
        png(&d.path().join("empty.png"), 16, 16, |_, _| [100, 100, 100, 0]);
        exr(&d.path().join("truth.exr"), 16, 8, |_, _| [0.5; 3]);
        exr(&d.path().join("edited.exr"), 16, 16, |_, _| [0.5; 3]);
        let e = score(&d.path().join("photo.png"), None, &d.path().join("truth.exr"), d.path()).unwrap_err();
        assert!(format!("{e:#}").contains("16×8 pixels, the photo 16×16"), "{e:#}");
        exr(&d.path().join("truth.exr"), 16, 16, |_, _| [0.5; 3]);
        let e = score(&d.path().join("empty.png"), None, &d.path().join("truth.exr"), d.path()).unwrap_err();
        assert!(format!("{e:#}").contains("covers no pixel"), "{e:#}");
        let e = score(
            &d.path().join("photo.png"),
            None,
            &d.path().join("missing.exr"),
            d.path(),
        )
        .unwrap_err();
        assert!(format!("{e:#}").contains("--truth"), "{e:#}");
    }
}

//! Normals given with the photo (`matedit edit --normals`).
//!
//! The network's n' is a 64² guess from a model trained on synthetic shapes; a person may have
//! better normals of the object (a depth sensor, a dedicated normal estimator, or, on the photo
//! benchmark, the renderer's own). A given normal map replaces n' at the network's resolution
//! and at the photo's, each square pixel the mean of the map's normals whose pixel centres fall
//! in it, renormalised. Where the map has no usable normal (non-finite, or too short to have a
//! direction) the network's n' stays, and the report counts those pixels.

use super::photo::{Prepared, decode, extension};
use anyhow::{Context, Result, bail};
use std::path::Path;

/// A normal shorter than this carries no direction (a PNG's mid-grey 128/255 encodes 0.004).
const MIN_LENGTH: f32 = 0.1;

/// A normal whose z is below this faces away from the camera: more than perspective's grazing
/// views give (the photo benchmark's path-traced normals reach −0.11 at their silhouettes).
pub const AWAY_Z: f32 = -0.25;

/// The share of the object's normals that may face away before a map is refused.
pub const MAX_AWAY_SHARE: f64 = 0.05;

/// A normal map at the photo's resolution: camera space, +x right, +y up, +z towards the
/// camera (docs/CONVENTIONS.md), as `matedit edit` writes `normals.exr`.
#[derive(Clone, Debug)]
pub struct GivenNormals {
    /// The file, for the report.
    pub path: String,
    /// Width of the map (the photo's).
    pub width: usize,
    /// Height of the map (the photo's).
    pub height: usize,
    /// Unit normals per photo pixel, `None` where the map has none.
    pub normals: Vec<Option<[f32; 3]>>,
}

/// How a given normal map was used, for `report.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct NormalsReport {
    /// The file.
    pub path: String,
    /// Object pixels of the network's square that kept n' (the map had no normal there).
    pub network_pixels_kept: usize,
    /// Object pixels of the photo-resolution square that kept the upsampled n'.
    pub detail_pixels_kept: usize,
}

/// Reads the normal map of a `width`×`height` photo whose object is `coverage`: EXR (channels X,
/// Y, Z as `normals.exr` is written, or R, G, B; values as stored) or PNG (8- or 16-bit,
/// n = 2v − 1, as `normals.png` is written). Non-finite and near-zero normals are "no normal
/// here"; the map is refused as [`GivenNormals::check_covers`] says.
pub fn load_normals(path: &Path, width: usize, height: usize, coverage: &[f32]) -> Result<GivenNormals> {
    let what = path.display();
    let (w, h, raw): (usize, usize, Vec<[f32; 3]>) = match extension(path).as_str() {
        "exr" => {
            let (w, h, mut ch) = matedit_contract::io::read_exr_channels(path)?;
            let names = [["X", "Y", "Z"], ["R", "G", "B"]]
                .into_iter()
                .find(|names| names.iter().all(|n| ch.contains_key(*n)))
                .with_context(|| format!("{what}: a normal map needs channels X, Y, Z or R, G, B"))?;
            let [x, y, z] = names.map(|n| ch.remove(n).unwrap_or_default());
            (w, h, (0..w * h).map(|k| [x[k], y[k], z[k]]).collect())
        }
        "png" => {
            let img = decode(path)?;
            let (w, h) = (img.width() as usize, img.height() as usize);
            let rgb = img.into_rgb32f();
            (
                w,
                h,
                rgb.pixels().map(|p| [0, 1, 2].map(|c| 2.0 * p[c] - 1.0)).collect(),
            )
        }
        other => {
            bail!("{what}: normal maps must be EXR (X, Y, Z or R, G, B as stored) or PNG ((n + 1) / 2), not .{other}")
        }
    };
    if (w, h) != (width, height) {
        bail!(
            "{what}: the normal map is {w}×{h}, the photo {width}×{height} as viewers show it; they must match pixel for pixel (a normal map is read as stored: no EXIF turn)"
        );
    }
    let given = GivenNormals {
        path: what.to_string(),
        width,
        height,
        normals: raw.into_iter().map(unit).collect(),
    };
    given.check_covers(coverage)?;
    Ok(given)
}

/// `n` at unit length, or `None` where it has no direction: a non-finite component, or a length
/// under [`MIN_LENGTH`]. Scaled by its largest component first, so that finite normals beyond
/// f32's square root (1e20 and up) keep their direction.
fn unit(n: [f32; 3]) -> Option<[f32; 3]> {
    let m = n.iter().fold(0.0_f32, |m, v| m.max(v.abs()));
    if !m.is_finite() || m == 0.0 || n.iter().any(|v| v.is_nan()) {
        return None;
    }
    let u = n.map(|v| v / m);
    let len = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    (m * len >= MIN_LENGTH).then(|| u.map(|v| v / len))
}

impl GivenNormals {
    /// Refuses a map with no usable normal on any of the object's photo pixels, or one where
    /// more than [`MAX_AWAY_SHARE`] of them face away from the camera (z < [`AWAY_Z`]): a
    /// visible surface faces the camera, so such a map is in another convention (OpenCV's
    /// camera looks down +z with y down) or is not a normal map.
    pub fn check_covers(&self, coverage: &[f32]) -> Result<()> {
        let on: Vec<[f32; 3]> = coverage
            .iter()
            .zip(&self.normals)
            .filter_map(|(&c, n)| if c > 0.0 { *n } else { None })
            .collect();
        if on.is_empty() {
            bail!(
                "{}: no usable normal on the object (every one non-finite or of length under {MIN_LENGTH})",
                self.path
            );
        }
        let away = on.iter().filter(|n| n[2] < AWAY_Z).count();
        if away as f64 > MAX_AWAY_SHARE * on.len() as f64 {
            bail!(
                "{}: {away} of the object's {} normals face away from the camera (z < {AWAY_Z}); normals \
                 must be in camera space with +x right, +y up and +z towards the camera (from OpenCV's \
                 convention, negate y and z)",
                self.path,
                on.len()
            );
        }
        Ok(())
    }

    /// The map on `prep`'s square (`[3, S, S]`, zero off the object): each object pixel the
    /// renormalised mean of the usable normals in it, or `fallback`'s where there is none.
    /// Returns the normals and how many object pixels kept `fallback`'s.
    pub fn framed(&self, prep: &Prepared, fallback: &[f32]) -> (Vec<f32>, usize) {
        let sums = prep
            .framing
            .area_average(self.width, self.height, |k| match self.normals[k] {
                Some(n) => [n[0], n[1], n[2], 1.0],
                None => [0.0; 4],
            });
        let p2 = prep.size * prep.size;
        let mut out = vec![0.0_f32; 3 * p2];
        let mut kept = 0;
        for (k, s) in sums.iter().enumerate().filter(|&(k, _)| prep.mask[k] > 0.0) {
            let len = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
            if s[3] > 0.0 && len.is_finite() && len > 1e-6 {
                for c in 0..3 {
                    out[c * p2 + k] = s[c] / len;
                }
            } else {
                kept += 1;
                for c in 0..3 {
                    out[c * p2 + k] = fallback[c * p2 + k];
                }
            }
        }
        (out, kept)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photo::{Photo, prepare};

    fn photo(w: usize, h: usize) -> (Photo, Vec<f32>) {
        let coverage: Vec<f32> = (0..w * h)
            .map(|k| {
                let (x, y) = (k % w, k / w);
                if (4..w - 4).contains(&x) && (4..h - 4).contains(&y) {
                    1.0
                } else {
                    0.0
                }
            })
            .collect();
        let p = Photo {
            width: w,
            height: h,
            rgb: vec![[0.3, 0.2, 0.1]; w * h],
            alpha: None,
            encoding: crate::photo::Encoding::Linear,
        };
        (p, coverage)
    }

    #[test]
    fn a_given_map_replaces_the_network_normals_and_unusable_pixels_keep_them() {
        let (w, h) = (48, 40);
        let (p, coverage) = photo(w, h);
        let prep = prepare(&p, &coverage, None, 16).expect("prepared");
        let tilt = [0.6_f32, 0.0, 0.8];
        // The left half of the map has a tilted normal (stored unnormalised: 2× its length),
        // the right half nothing usable (NaN, zero, or too short).
        let normals: Vec<Option<[f32; 3]>> = (0..w * h)
            .map(|k| if k % w < w / 2 { Some(tilt) } else { None })
            .collect();
        let map = GivenNormals {
            path: "n.exr".into(),
            width: w,
            height: h,
            normals,
        };
        map.check_covers(&coverage).expect("covers");
        let p2 = 16 * 16;
        let mut fallback = vec![0.0_f32; 3 * p2];
        fallback[2 * p2..].iter_mut().for_each(|v| *v = 1.0);
        let (n, kept) = map.framed(&prep, &fallback);
        let on: Vec<usize> = (0..p2).filter(|&k| prep.mask[k] > 0.0).collect();
        assert!(kept > 0 && kept < on.len(), "{kept} of {}", on.len());
        let mut tilted = 0;
        for &k in &on {
            let v = [n[k], n[p2 + k], n[2 * p2 + k]];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5, "{v:?}");
            if (v[0] - 0.6).abs() < 1e-5 && (v[2] - 0.8).abs() < 1e-5 {
                tilted += 1;
            } else {
                assert_eq!(v, [0.0, 0.0, 1.0], "pixel {k}: neither the map's nor the fallback");
            }
        }
        assert_eq!(tilted + kept, on.len());
        // Off the object: zero.
        assert!(
            (0..p2)
                .filter(|&k| prep.mask[k] == 0.0)
                .all(|k| n[k] == 0.0 && n[2 * p2 + k] == 0.0)
        );
    }

    #[test]
    fn a_normal_has_a_direction_at_any_finite_scale_and_none_otherwise() {
        for k in [-30, -1, 0, 1, 10, 20, 30, 38] {
            let s = 10f32.powi(k);
            let v = [s * (3.0 / 13.0), s * (-4.0 / 13.0), s * (12.0 / 13.0)];
            match unit(v) {
                Some(n) => {
                    assert!(s >= MIN_LENGTH * 0.99, "scale {s}: {n:?}");
                    for (a, b) in n.iter().zip([3.0 / 13.0, -4.0 / 13.0, 12.0 / 13.0]) {
                        assert!((a - b).abs() < 1e-6, "scale {s}: {n:?}");
                    }
                }
                None => assert!(s < MIN_LENGTH, "scale {s} lost its direction"),
            }
        }
        assert_eq!(
            unit([f32::MAX, f32::MAX, 0.0]).map(|n| (n[0] * 1e6).round()),
            Some(707_107.0)
        );
        for bad in [
            [f32::NAN, 0.0, 1.0],
            [f32::INFINITY, 0.0, 1.0],
            [0.0; 3],
            [0.01, 0.0, 0.05],
        ] {
            assert_eq!(unit(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn files_are_read_checked_and_refused_by_name() {
        let dir = std::env::temp_dir().join(format!("matedit-normals-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let (w, h) = (12, 10);
        let object = vec![1.0_f32; w * h];
        // PNG: (n + 1) / 2; a mid-grey pixel is no normal, (255, 128, 128) is +x.
        let png = dir.join("n.png");
        let img = image::RgbImage::from_fn(w as u32, h as u32, |x, _| {
            if x < 6 {
                image::Rgb([255, 128, 128])
            } else {
                image::Rgb([128, 128, 128])
            }
        });
        img.save(&png).expect("png");
        let m = load_normals(&png, w, h, &object).expect("png read");
        let n = m.normals[0].expect("a normal");
        assert!(
            (n[0] - 1.0).abs() < 1e-3 && n[1].abs() < 0.01 && n[2].abs() < 0.01,
            "{n:?}"
        );
        assert!(m.normals[7].is_none(), "mid-grey is no normal");
        // EXR: values as stored, negative and non-finite ones too.
        let exr_path = dir.join("n.exr");
        let pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|k| match k % 3 {
                0 => [0.0, -2.0, 0.0],
                1 => [f32::NAN, 0.0, 1.0],
                _ => [0.0, 0.0, 0.0],
            })
            .collect();
        exr::prelude::write_rgb_file(&exr_path, w, h, |x, y| {
            let p = pixels[y * w + x];
            (p[0], p[1], p[2])
        })
        .expect("exr");
        let m = load_normals(&exr_path, w, h, &object).expect("exr read");
        assert_eq!(m.normals[0], Some([0.0, -1.0, 0.0]));
        assert!(m.normals[1].is_none() && m.normals[2].is_none());
        // X, Y, Z channels (as `matedit edit` writes normals.exr) are read before R, G, B.
        let xyz_path = dir.join("xyz.exr");
        let ones = vec![1.0_f32; w * h];
        matedit_contract::io::write_exr_channels(
            &xyz_path,
            w,
            h,
            vec![("X", vec![0.0; w * h]), ("Y", vec![0.0; w * h]), ("Z", ones.clone())],
        )
        .expect("xyz exr");
        assert_eq!(
            load_normals(&xyz_path, w, h, &object).expect("xyz read").normals[5],
            Some([0.0, 0.0, 1.0])
        );
        let lone = dir.join("lone.exr");
        matedit_contract::io::write_exr_channels(&lone, w, h, vec![("X", ones)]).expect("lone exr");
        let e = load_normals(&lone, w, h, &object).expect_err("one channel accepted");
        assert!(e.to_string().contains("needs channels X, Y, Z or R, G, B"), "{e}");
        let all = vec![1.0_f32; w * h];
        m.check_covers(&all).expect("some usable normal");
        let none = GivenNormals {
            normals: vec![None; w * h],
            ..m.clone()
        };
        let e = none.check_covers(&all).expect_err("no usable normal accepted");
        assert!(e.to_string().contains("no usable normal"), "{e}");
        // Facing away: refused past 5 % of the object, accepted up to it.
        let facing = |away: usize| GivenNormals {
            normals: (0..100)
                .map(|k| Some(if k < away { [0.0, 0.6, -0.8] } else { [0.0, 0.0, 1.0] }))
                .collect(),
            ..m.clone()
        };
        let hundred = vec![1.0_f32; 100];
        facing(5).check_covers(&hundred).expect("5 of 100 facing away");
        let e = facing(6)
            .check_covers(&hundred)
            .expect_err("6 of 100 facing away accepted");
        assert!(e.to_string().contains("face away from the camera"), "{e}");
        // Another size, another format: refused by name.
        let e = load_normals(&png, w + 1, h, &object).expect_err("size mismatch accepted");
        assert!(e.to_string().contains("must match pixel for pixel"), "{e}");
        let jpg = dir.join("n.jpg");
        std::fs::write(&jpg, b"not read").expect("jpg");
        let e = load_normals(&jpg, w, h, &object).expect_err(".jpg accepted");
        assert!(e.to_string().contains("normal maps must be EXR"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}

//! The edit kept within the photo's range.
//!
//! An 8- or 16-bit photo has a white that its exposure was chosen for, and shows little of its
//! object there. The edit's level comes from the network's light, which errs by about ×2 either
//! way (the input's albedo and the light's brightness look alike in a masked photo;
//! docs/PERFORMANCE.md, "The light's level"). The two errors do not cost the same: an edit twice
//! too dark keeps its hue and shading, while one twice too bright is clipped at white channel by
//! channel when it is written — a gold turns cream, a chrome white, and the shading that tells
//! the object's shape is gone. So, by default ([`Range::Photo`]), the edited object is scaled
//! down until no larger share of it exceeds white than the photo itself shows (at least
//! [`MIN_SHARE`]), and what still exceeds white is brought into range with its hue kept (the
//! pixel divided by its largest channel), not clipped per channel. A linear photo (EXR, HDR) has
//! no white: its edit is left as rendered.

use crate::photo::{Encoding, Photo, srgb_decode};

/// The share of the object an edit may leave above white however little of the photo's object
/// is there: a mirror's reflection of the sun is a few pixels, not the object.
pub const MIN_SHARE: f64 = 0.02;

/// The smallest scale [`fit`] applies: the network's level errs by ×2–4, and an edit that one
/// pixel in a handful of object pixels would otherwise darken to black is better left to the hue
/// step.
pub const MIN_SCALE: f64 = 1.0 / 16.0;

/// What the edited object's level is held to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Range {
    /// The photo's: the edit scaled down until no more of the object exceeds white than in the
    /// photo (at least 2 %), what still does scaled into range with its hue (the default with
    /// the network's light level; the best measured on the photo benchmark).
    #[default]
    Photo,
    /// The edit as rendered; each channel clipped at white when an 8- or 16-bit photo is written
    /// (the default when the light's level is known).
    Clip,
}

impl Range {
    /// The range measured best on the photo benchmark: the photo's while the edit's level is the
    /// network's guess, the rendered one when it is known — the object's own material or the
    /// scene's light given — since a known level that puts a mirror's sky above white is right
    /// (docs/PERFORMANCE.md, "The photo's range").
    pub fn best_for(level_known: bool) -> Self {
        if level_known { Self::Clip } else { Self::Photo }
    }
}

/// What [`fit`] found and did, for `report.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RangeReport {
    /// Which composited image: `edited` or `relit`.
    pub image: String,
    /// Whether the edit was changed: not with `--range clip`, a linear photo, or an edit already
    /// within range.
    pub applied: bool,
    /// The share of the photo's object pixels at white (stored as the largest value).
    pub photo_share_at_white: f64,
    /// The share of the edit's object pixels allowed above white: the photo's, at least
    /// [`MIN_SHARE`].
    pub allowed_share: f64,
    /// The share of the edit's object pixels above white as rendered.
    pub rendered_share_above_white: f64,
    /// What the edited object's values were multiplied by (1: unchanged).
    pub scale: f64,
}

/// The level a photo's pixel is stored at white from: what 254.5/255 decodes to (16-bit photos
/// are held to the same level, a hair under their own white).
fn photo_white() -> f32 {
    srgb_decode(254.5 / 255.0)
}

/// Whether pixel `k` counts as the object's for the shares (its coverage at least ½: soft edge
/// pixels are half background).
fn counted(coverage: &[f32], k: usize) -> bool {
    coverage[k] >= 0.5
}

/// The largest channel of a finite pixel.
fn largest(v: [f32; 3]) -> Option<f32> {
    v.iter().all(|c| c.is_finite()).then(|| v[0].max(v[1]).max(v[2]))
}

/// How `values` (the edit's object pixels in the photo's linear units, non-finite where the photo
/// is kept: [`crate::composite::object_values`]) are held to the photo's range; `image` names
/// them in the report.
pub fn fit(p: &Photo, coverage: &[f32], values: &[[f32; 3]], range: Range, image: &str) -> RangeReport {
    let white = photo_white();
    let display_referred = matches!(p.encoding, Encoding::Srgb8 | Encoding::Srgb16);
    let held = range == Range::Photo && display_referred;
    let (mut at_white, mut object, mut rendered, mut above) = (0_usize, 0_usize, 0_usize, 0_usize);
    // The edit's largest channels, kept only where they are to be held.
    let mut edit: Vec<f32> = Vec::new();
    for (k, &v) in values.iter().enumerate() {
        if !counted(coverage, k) {
            continue;
        }
        object += 1;
        at_white += usize::from(largest(p.rgb[k]).is_some_and(|m| m >= white));
        if let Some(m) = largest(v) {
            rendered += 1;
            above += usize::from(m > 1.0);
            if held {
                edit.push(m);
            }
        }
    }
    let share = |k: usize, of: usize| if of > 0 { k as f64 / of as f64 } else { 0.0 };
    let allowed = share(at_white, object).max(MIN_SHARE);
    let mut report = RangeReport {
        image: image.to_string(),
        applied: false,
        photo_share_at_white: share(at_white, object),
        allowed_share: allowed,
        rendered_share_above_white: share(above, rendered),
        scale: 1.0,
    };
    if edit.is_empty() {
        return report;
    }
    // At most ⌊allowed·n⌋ pixels may stay above white: the next brightest is brought to it (a
    // photo whose whole object is at white allows the whole edit there).
    let n = edit.len();
    let keep_above = (allowed * n as f64).floor() as usize;
    if keep_above < n {
        let (_, &mut bound, _) = edit.select_nth_unstable_by(n - 1 - keep_above, f32::total_cmp);
        if bound > 1.0 {
            report.scale = (1.0 / bound as f64).max(MIN_SCALE);
        }
    }
    report.applied = report.scale < 1.0 || above > 0;
    report
}

/// An edited pixel held to the range [`fit`] found: scaled, then, where a channel still exceeds
/// white, divided by its largest channel (its hue kept). Unchanged where nothing was applied.
pub fn apply(v: [f32; 3], report: &RangeReport) -> [f32; 3] {
    if !report.applied {
        return v;
    }
    let s = report.scale as f32;
    let v = v.map(|c| c * s);
    match largest(v) {
        Some(m) if m > 1.0 => v.map(|c| c / m),
        _ => v,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A photo of `n` object pixels with `white` of them stored at white, the rest mid-grey.
    fn photo(n: usize, white: usize, encoding: Encoding) -> (Photo, Vec<f32>) {
        let rgb = (0..n)
            .map(|k| if k < white { [1.0, 0.8, 1.0] } else { [0.2; 3] })
            .collect();
        let p = Photo {
            width: n,
            height: 1,
            rgb,
            alpha: None,
            encoding,
        };
        (p, vec![1.0; n])
    }

    fn values(levels: &[f32]) -> Vec<[f32; 3]> {
        levels.iter().map(|&m| [m, m * 0.6, m * 0.2]).collect()
    }

    fn above(vals: &[[f32; 3]], r: &RangeReport) -> usize {
        vals.iter().filter(|&&v| apply(v, r).iter().any(|&c| c > 1.0)).count()
    }

    #[test]
    fn an_edit_within_range_is_left_as_it_is() {
        let (p, cov) = photo(100, 0, Encoding::Srgb8);
        let vals = values(&(0..100).map(|k| k as f32 / 100.0).collect::<Vec<_>>());
        let r = fit(&p, &cov, &vals, Range::Photo, "edited");
        assert!(!r.applied);
        assert_eq!(r.scale, 1.0);
        for v in vals.iter() {
            assert_eq!(apply(*v, &r), *v);
        }
    }

    #[test]
    fn an_edit_too_bright_is_scaled_until_the_allowed_share_is_above_white_and_keeps_its_hue() {
        let (p, cov) = photo(1000, 0, Encoding::Srgb8);
        // Largest channels 0.004 … 4: three quarters above white.
        let levels: Vec<f32> = (1..=1000).map(|k| k as f32 * 0.004).collect();
        let vals = values(&levels);
        let r = fit(&p, &cov, &vals, Range::Photo, "edited");
        assert!(r.applied);
        assert!((r.rendered_share_above_white - 0.75).abs() < 1e-9);
        assert_eq!(r.allowed_share, MIN_SHARE);
        // The 21st brightest (3.92) is brought to white: 20 of 1000 stay above, before the hue
        // step.
        assert!((r.scale - 1.0 / 3.92).abs() < 1e-6, "{}", r.scale);
        let scaled_above = levels.iter().filter(|&&m| m * r.scale as f32 > 1.0).count();
        assert_eq!(scaled_above, 20);
        assert_eq!(above(&vals, &r), 0, "nothing is written above white");
        for v in vals.iter() {
            let o = apply(*v, &r);
            // The hue is kept: the channels' ratios are the input's.
            assert!(
                (o[1] / o[0] - 0.6).abs() < 1e-5 && (o[2] / o[0] - 0.2).abs() < 1e-5,
                "{o:?}"
            );
        }
    }

    #[test]
    fn a_photo_that_shows_more_of_its_object_at_white_allows_as_much_of_the_edit() {
        let (p, cov) = photo(100, 30, Encoding::Srgb8);
        let levels: Vec<f32> = (1..=100).map(|k| k as f32 * 0.02).collect(); // 0.02 … 2
        let r = fit(&p, &cov, &values(&levels), Range::Photo, "edited");
        assert!((r.photo_share_at_white - 0.3).abs() < 1e-9);
        assert!((r.allowed_share - 0.3).abs() < 1e-9);
        // 30 may stay above: the 31st brightest (1.40) comes to white.
        assert!((r.scale - 1.0 / 1.4).abs() < 1e-6, "{}", r.scale);
    }

    #[test]
    fn a_photo_all_at_white_allows_the_whole_edit_there_in_its_hue() {
        let (p, cov) = photo(10, 10, Encoding::Srgb8);
        let vals = values(&[2.0; 10]);
        let r = fit(&p, &cov, &vals, Range::Photo, "edited");
        assert_eq!((r.allowed_share, r.scale, r.applied), (1.0, 1.0, true));
        assert_eq!(apply(vals[0], &r), [1.0, 0.6, 0.2]);
    }

    #[test]
    fn the_photo_given_back_is_left_as_it_is() {
        let (p, cov) = photo(50, 10, Encoding::Srgb8);
        let vals = p.rgb.clone();
        let r = fit(&p, &cov, &vals, Range::Photo, "edited");
        assert!(!r.applied);
        for (v, q) in vals.iter().zip(&p.rgb) {
            assert_eq!(apply(*v, &r), *q);
        }
    }

    #[test]
    fn linear_photos_and_clip_leave_the_edit_as_rendered() {
        let levels: Vec<f32> = (1..=100).map(|k| k as f32 * 0.1).collect();
        let vals = values(&levels);
        for (encoding, range) in [
            (Encoding::Linear, Range::Photo),
            (Encoding::Srgb8, Range::Clip),
            (Encoding::Srgb16, Range::Clip),
        ] {
            let (p, cov) = photo(100, 0, encoding);
            let r = fit(&p, &cov, &vals, range, "edited");
            assert!(!r.applied, "{encoding:?} {range:?}");
            assert_eq!(r.scale, 1.0);
            assert!((r.rendered_share_above_white - 0.9).abs() < 1e-9);
        }
        let (p, cov) = photo(100, 0, Encoding::Srgb16);
        assert!(fit(&p, &cov, &vals, Range::Photo, "edited").applied);
    }

    #[test]
    fn hard_values_neither_break_the_fit_nor_come_out_non_finite() {
        let (p, cov) = photo(8, 0, Encoding::Srgb8);
        let vals = vec![
            [f32::NAN, 0.5, 0.5],
            [f32::INFINITY, 1.0, 1.0],
            [3e38, 3e38, 1.0],
            [0.0; 3],
            [1e-30, 0.0, 0.0],
            crate::composite::KEEP,
            [2.0, 1.0, 0.5],
            [0.5; 3],
        ];
        let r = fit(&p, &cov, &vals, Range::Photo, "edited");
        assert!(r.scale.is_finite() && r.scale >= MIN_SCALE && r.scale <= 1.0, "{r:?}");
        for v in vals.iter() {
            let o = apply(*v, &r);
            if v.iter().all(|c| c.is_finite()) {
                assert!(
                    o.iter().all(|c| c.is_finite() && (0.0..=1.0).contains(c)),
                    "{v:?} → {o:?}"
                );
            }
        }
        // No object at all: nothing to hold.
        let (p, _) = photo(8, 0, Encoding::Srgb8);
        let r = fit(&p, &[0.0; 8], &vals, Range::Photo, "edited");
        assert!(!r.applied && r.scale == 1.0);
    }
}

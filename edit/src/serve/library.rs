//! The material library as the page shows it: every library material with a sphere rendered by
//! the rendering layer under the studio environment, fitted and rendered on first request and
//! kept (the fit is shared with edits through the memo in [`crate::target`]).

use crate::output::spheres;
use crate::target::dsbrdf_of;
use anyhow::{Context, Result};
use matedit_assets::materials::library::{Split, library};
use matedit_physics::tonemap::tonemap_u8;
use matedit_trainer::metrics::metric_exposure;
use serde_json::{Value, json};
use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

/// Thumbnail side in pixels.
const SIDE: usize = 64;
/// Environment rows of the thumbnails' light.
const ENV_HEIGHT: usize = 16;

/// A thumbnail, rendered once: the PNG or why it could not be made.
type Thumbnail = Arc<OnceLock<Result<Vec<u8>, String>>>;

/// The library's entries and the thumbnails made so far.
#[derive(Default)]
pub struct Library {
    thumbs: Mutex<HashMap<String, Thumbnail>>,
}

impl Library {
    /// Every library material: spec, name, family and split.
    pub fn list() -> Value {
        json!(
            library()
                .iter()
                .map(|m| json!({
                    "spec": format!("library:{}", m.name),
                    "name": m.name,
                    "family": m.family,
                    "split": match m.split() { Split::Train => "train", Split::Test => "test" },
                }))
                .collect::<Vec<_>>()
        )
    }

    /// The PNG thumbnail of library material `name` (`None`: no such material). Concurrent
    /// requests for one material render it once.
    pub fn thumbnail(&self, name: &str) -> Option<Result<Vec<u8>, String>> {
        let m = library().into_iter().find(|m| m.name == name)?;
        let cell = {
            let mut t = self.thumbs.lock().unwrap_or_else(|p| p.into_inner());
            t.entry(m.name.clone()).or_default().clone()
        };
        Some(
            cell.get_or_init(|| render(&m.name).map_err(|e| format!("{e:#}")))
                .clone(),
        )
    }
}

fn render(name: &str) -> Result<Vec<u8>> {
    let (material, _) = dsbrdf_of(&format!("library:{name}"))?;
    let params: Vec<f32> = material.to_normalised().iter().map(|&v| v as f32).collect();
    let env = crate::target::relight_env("builtin:studio", ENV_HEIGHT)?;
    let sph = spheres(&[&params], &env, ENV_HEIGHT, SIDE)?;
    let (img, mask) = sph.first().context("no sphere rendered")?;
    let e = metric_exposure(img, mask);
    let hw = SIDE * SIDE;
    let rgba = image::RgbaImage::from_fn(SIDE as u32, SIDE as u32, |x, y| {
        let k = y as usize * SIDE + x as usize;
        if mask[k] > 0.0 {
            let c = |ch: usize| tonemap_u8(img[ch * hw + k], e);
            image::Rgba([c(0), c(1), c(2), 255])
        } else {
            image::Rgba([0, 0, 0, 0])
        }
    });
    let mut png = Vec::new();
    rgba.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .context("encoding the thumbnail")?;
    Ok(png)
}

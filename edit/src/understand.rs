//! A photo understood: the stages between reading it and rendering its edit, in order —
//! the network (n', m', L', [`crate::predict`]), what is known instead of its estimates (a normal
//! map, the object's material, the light: [`crate::light`]), the photo's resolution
//! ([`crate::detail`]), Eq. 6 ([`crate::eq6`]) and the light's level ([`crate::light`]).

use crate::light::{self, LightOptions, background, estimate};
use crate::photo::read::ReadPhoto;
use crate::photo::{Photo, orientation};
use crate::progress::Watch;
use crate::{Eq6Report, Model, Prepared, detail, eq6, network_prediction, normals, prepare};
use anyhow::{Context, Result};
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::post_optimisation::Eq6Config;
use std::path::PathBuf;
use std::time::Instant;

/// A photo read, framed and understood: n*, m*, L* (the network's, what is known instead, or
/// after Eq. 6).
pub struct Understood {
    /// The photo.
    pub photo: Photo,
    /// Its path.
    pub path: PathBuf,
    /// Soft object coverage per photo pixel.
    pub coverage: Vec<f32>,
    /// What the report calls the mask.
    pub mask_name: String,
    /// How the photo was turned to stand as viewers show it, where its EXIF said to.
    pub orientation: Option<orientation::OrientationReport>,
    /// The network input.
    pub prep: Prepared,
    /// n*, m*, L* at the network's resolution.
    pub point: Prediction,
    /// The object at the photo's resolution and n* there.
    pub detail: detail::Detail,
    /// Eq. 6, when asked for.
    pub eq6: Option<Eq6Report>,
    /// What of L' was kept; none when a light was given.
    pub light_estimate: Option<estimate::LightEstimateReport>,
    /// How L*'s level was set (L* above is at that level).
    pub light_level: background::LightLevel,
    /// The object's own material's spec, when it was given instead of m'.
    pub input_material: Option<String>,
    /// The normal map given instead of n', when one was.
    pub normals: Option<normals::NormalsReport>,
    /// Seconds the network took.
    pub network_seconds: f64,
}

/// How a photo is understood: what is known of it, and whether Eq. 6 refines the estimates.
#[derive(Clone, Copy)]
pub struct Understanding<'a> {
    /// The light, and what is known instead of the network's estimates.
    pub light: &'a LightOptions,
    /// Eq. 6's weights and lengths, when it is asked for.
    pub eq6: Option<&'a Eq6Config>,
}

/// Frames a read photo and runs the stages, showing their phases to `watch`.
pub fn understand(model: &Model, read: ReadPhoto, how: Understanding, watch: Watch) -> Result<Understood> {
    let light = how.light;
    let labels = read.labels.as_ref().map(|(l, n)| (l.as_slice(), *n));
    let prep = prepare(&read.photo, &read.coverage, labels, model.state.net.input_size)
        .with_context(|| read.path.display().to_string())?;
    watch.enter("network")?;
    let t = Instant::now();
    let mut x = network_prediction(&model.net, &prep)?;
    let light_estimate = match light.given {
        Some(_) => None,
        None => Some(
            light
                .estimate
                .apply(|| model.light_skill(), &mut x.env, model.state.net.env_height)?,
        ),
    };
    let mut normals = given_normals(light, &prep, &mut x);
    light::known_light(model, light, &prep, &mut x)?;
    let network_seconds = t.elapsed().as_secs_f64();
    let mut detail = detail::detail(&read.photo, &read.coverage, labels, &prep, &x.normals)
        .with_context(|| read.path.display().to_string())?;
    if let (Some(g), Some(r)) = (&light.normals, normals.as_mut()) {
        let (n, kept) = g.framed(&detail.prep, &detail.normals);
        detail.normals = n;
        r.detail_pixels_kept = kept;
    }
    let eq6 = match how.eq6 {
        Some(cfg) => {
            watch.enter("eq6")?;
            let estimates = eq6::Estimates {
                coarse: &mut x,
                fine: &mut detail,
            };
            Some(eq6::refine(model, &prep, estimates, cfg, watch.progress)?)
        }
        None => None,
    };
    let light_level = light::level(model, &read, &prep, &mut x.env, light);
    Ok(Understood {
        photo: read.photo,
        path: read.path,
        coverage: read.coverage,
        mask_name: read.mask_name,
        orientation: read.orientation,
        prep,
        point: x,
        detail,
        eq6,
        light_estimate,
        light_level,
        input_material: light.input_material.as_ref().map(|(spec, _)| spec.clone()),
        normals,
        network_seconds,
    })
}

/// A given normal map in place of n' at the network's resolution, and its report.
fn given_normals(light: &LightOptions, prep: &Prepared, x: &mut Prediction) -> Option<normals::NormalsReport> {
    let g = light.normals.as_ref()?;
    let (n, kept) = g.framed(prep, &x.normals);
    x.normals = n;
    Some(normals::NormalsReport {
        path: g.path.clone(),
        network_pixels_kept: kept,
        detail_pixels_kept: 0,
    })
}

//! What an edit is asked to do, as the command line (or the editing page) gives it, and the
//! checks made before anything is read.

use crate::light::{LevelFrom, estimate, relight};
use crate::{Composite, Range, output};
use anyhow::{Result, bail};
use matedit_trainer::post_optimisation;
use std::path::{Path, PathBuf};

/// What to edit, as the command line gives it.
#[derive(Clone, Debug, Default)]
pub struct EditRequest {
    /// The photo.
    pub photo: PathBuf,
    /// The mask image (default: the photo's alpha channel).
    pub mask: Option<PathBuf>,
    /// A label image: value k > 0 marks region k (Sec. 3.4's multi-material objects).
    pub regions: Option<PathBuf>,
    /// Target materials: `(None, SPEC)` for every region, `(Some(k), SPEC)` for region k.
    pub materials: Vec<(Option<u8>, String)>,
    /// Another illumination for the predicted material (an environment spec, Fig. 4).
    pub relight: Option<String>,
    /// The photo's illumination, when known (an environment spec): used instead of L'.
    pub light: Option<String>,
    /// What sets the light's level.
    pub light_level: LevelFrom,
    /// What sets `relight`'s level ([`relight`]).
    pub relight_level: relight::RelightLevel,
    /// What of the network's L' is kept ([`estimate`]).
    pub light_estimate: estimate::LightEstimate,
    /// The photo's horizontal field of view in degrees (default [`crate::light::background::DEFAULT_FOV_DEG`]).
    pub fov_deg: Option<f64>,
    /// The object's own material, when known (a spec, as `--material` takes): used instead of
    /// m', and it sets the light's level ([`crate::LightOptions::input_material`]).
    pub input_material: Option<String>,
    /// The object's normals at the photo's resolution, when known (EXR or PNG, camera space):
    /// used instead of n' ([`crate::normals`]).
    pub normals: Option<PathBuf>,
    /// How to composite; `None`: [`Composite::best_for`] what `input_material` and `light` make
    /// known.
    pub composite: Option<Composite>,
    /// What the edited object's level is held to ([`crate::range`]; `None`: [`Range::best_for`] the
    /// request, the rendered level where `input_material` or `light` makes it known).
    pub range: Option<Range>,
    /// Refine n', m', L' with Eq. 6 before rendering.
    pub optimize: Option<post_optimisation::Eq6Config>,
}

/// Refuses a request with nothing to do, or whose output folder holds one of its inputs.
pub(crate) fn check_request(req: &EditRequest, out: &Path) -> Result<()> {
    if req.materials.is_empty() && req.relight.is_none() {
        bail!("nothing to do: give --material (the edit) and/or --relight (another illumination)");
    }
    // Every file the edit reads, the ones named inside specs too.
    let specs: Vec<PathBuf> = req
        .materials
        .iter()
        .map(|(_, m)| m)
        .chain(&req.input_material)
        .filter_map(|m| output::material_file(m))
        .chain(req.light.iter().chain(&req.relight).filter_map(|l| output::env_file(l)))
        .collect();
    let inputs: Vec<Option<&Path>> = [
        Some(req.photo.as_path()),
        req.mask.as_deref(),
        req.regions.as_deref(),
        req.normals.as_deref(),
    ]
    .into_iter()
    .chain(specs.iter().map(|p| Some(p.as_path())))
    .collect();
    output::refuse_overwriting_inputs(out, &inputs)
}

/// The light options a request asks for, its given light and normal map read.
pub(crate) fn light_options(
    req: &EditRequest,
    read: &crate::ReadPhoto,
    env_height: usize,
) -> Result<crate::LightOptions> {
    Ok(crate::LightOptions {
        given: req
            .light
            .as_ref()
            .map(|spec| crate::target::relight_env(spec, env_height))
            .transpose()?,
        level: req.light_level,
        estimate: req.light_estimate,
        fov_deg: req.fov_deg,
        input_material: crate::light::known_material(req.input_material.as_deref(), "--input-material")?,
        normals: req
            .normals
            .as_deref()
            .map(|n| crate::normals::load_normals(n, read.photo.width, read.photo.height, &read.coverage))
            .transpose()?,
    })
}

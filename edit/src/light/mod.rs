//! The photo's illumination for an edit: the network's L' or a given map, and what sets its
//! level (the network's fit through m', the object's known material, or the photo's background,
//! [`crate::light::background`]).

pub mod background;
pub mod estimate;
pub mod relight;
#[cfg(test)]
mod tests;

use crate::Prepared;
use anyhow::{Context, Result, bail};
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::rendering_layer::{LayerInput, MAX_RADIANCE, RenderingLayer};

/// What sets the level of the light the edit is rendered under.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LevelFrom {
    /// The background with a given light (`--light`), the network's otherwise: the levels
    /// measured best on the photo benchmark (docs/PERFORMANCE.md, "Editing photos").
    #[default]
    Auto,
    /// The photo's background, where it shows enough unclipped surroundings; the network's level
    /// otherwise.
    // How: `light::background`.
    Background,
    /// The network's: the level at which I' = R(n', m', L') matches the photo (the paper's).
    Network,
    /// A given light's own level (`--light` only): its values are radiance in the photo's linear
    /// units, as a light probe captured with the photo's exposure would be.
    Given,
}

/// What set the level of the light an edit was rendered under (report.json's
/// `light_level.source`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum LevelSource {
    /// The photo's surroundings ([`background`]).
    #[serde(rename = "background")]
    Background,
    /// The level at which I' = R(n', m', L') matches the photo, as predicted.
    #[serde(rename = "network")]
    Network,
    /// A given map's own values (`--light-level given`).
    #[serde(rename = "given")]
    Given,
    /// The level at which the object's known material explains the photo (`--input-material`).
    #[serde(rename = "input material")]
    InputMaterial,
}

impl LevelSource {
    /// Its name in report.json.
    pub fn as_str(self) -> &'static str {
        match self {
            LevelSource::Background => "background",
            LevelSource::Network => "network",
            LevelSource::Given => "given",
            LevelSource::InputMaterial => "input material",
        }
    }

    /// Whether the level is known rather than fitted: the photo's background or a given map's
    /// own.
    pub fn known(self) -> bool {
        matches!(self, LevelSource::Background | LevelSource::Given)
    }
}

/// How the photo's illumination is found: the network's L' (or a given map) and its level.
#[derive(Clone, Debug, Default)]
pub struct LightOptions {
    /// A known illumination (`[3, He, 2He]`, camera space) used instead of L'.
    pub given: Option<Vec<f32>>,
    /// What sets its level.
    pub level: LevelFrom,
    /// What of the network's L' is kept ([`crate::light::estimate`]).
    pub estimate: crate::light::estimate::LightEstimate,
    /// The photo's horizontal field of view in degrees (default
    /// [`crate::light::background::DEFAULT_FOV_DEG`]).
    pub fov_deg: Option<f64>,
    /// The object's own material when it is known (`--input-material`): its spec and its
    /// normalised DSBRDF (`[108]`). It replaces m' in every region, and the light's level becomes
    /// the one at which it explains the photo: the albedo that a masked object does not tell the
    /// network apart from the light's brightness (docs/PERFORMANCE.md, "The light's level").
    pub input_material: Option<(String, Vec<f32>)>,
    /// The object's normals when they are known (`--normals`): they replace n' at both
    /// resolutions, before the light's level is set ([`crate::normals`]).
    pub normals: Option<crate::normals::GivenNormals>,
}

impl LightOptions {
    /// What sets the level here: `Background`, `Network` or `Given`, never `Auto` (which is the
    /// background with a given light, the network otherwise) and `Given` only with a given light.
    pub(crate) fn level_from(&self) -> LevelFrom {
        match (self.level, self.given.is_some()) {
            (LevelFrom::Background, _) | (LevelFrom::Auto, true) => LevelFrom::Background,
            (LevelFrom::Given, true) => LevelFrom::Given,
            _ => LevelFrom::Network,
        }
    }

    /// Whether the light is given and came at a known level, its own or the background's, as
    /// `level` (what set it) says: not where the network's fit scaled it, asked for or because
    /// the background was too small or clipped. It picks the composite
    /// ([`crate::Composite::best_for`]) and, with the object's own material, the range
    /// ([`crate::Range::best_for`]).
    pub(crate) fn light_known(&self, level: &crate::light::background::LightLevel) -> bool {
        self.given.is_some() && level.source.known()
    }
}

/// What is known instead of the network's estimates, in place: the object's own material (and,
/// without a given light, L' at the level at which it explains the photo), and a given light at
/// its own level or at the one that explains the photo.
pub(crate) fn known_light(
    model: &crate::Model,
    light: &LightOptions,
    prep: &Prepared,
    x: &mut Prediction,
) -> Result<()> {
    if let Some((spec, m)) = &light.input_material {
        x.materials = m.repeat(prep.regions);
        if light.given.is_none() {
            let l = std::mem::take(&mut x.env);
            x.env =
                light_at_photo_level(&model.layer, prep, x, &l).with_context(|| format!("--input-material {spec}"))?;
        }
    }
    if let Some(l) = &light.given {
        x.env = if light.level_from() == LevelFrom::Given {
            light_at_own_level(l, prep.exposure)?
        } else {
            light_at_photo_level(&model.layer, prep, x, l)?
        };
    }
    Ok(())
}

/// The light's level, last of the understanding stages: the photo's background scales `env`
/// (L*) where it is asked to set it, and the report says what set it. The field of view is the
/// given one, else the photo's EXIF's, else [`background::DEFAULT_FOV_DEG`].
pub(crate) fn level(
    model: &crate::Model,
    read: &crate::photo::read::ReadPhoto,
    prep: &Prepared,
    env: &mut [f32],
    light: &LightOptions,
) -> background::LightLevel {
    let (deg, from) = match (light.fov_deg, read.exif_fov_deg) {
        (Some(f), _) => (f, "given"),
        (None, Some(f)) => (f, "exif"),
        (None, None) => (background::DEFAULT_FOV_DEG, "default"),
    };
    let fov = background::FieldOfView { deg, from };
    let level_from = light.level_from();
    if level_from == LevelFrom::Background {
        let light = background::NetworkLight {
            env,
            height: model.state.net.env_height,
            exposure: prep.exposure,
        };
        let level = background::light_level(&read.photo, &read.coverage, light, fov);
        let k = level.scale as f32;
        env.iter_mut().for_each(|v| *v *= k);
        return level;
    }
    background::LightLevel {
        source: match (level_from, &light.input_material) {
            (LevelFrom::Given, _) => LevelSource::Given,
            (_, Some(_)) => LevelSource::InputMaterial,
            _ => LevelSource::Network,
        },
        scale: 1.0,
        pixels: 0,
        fov_deg: fov.deg,
        fov_from: fov.from.into(),
        note: None,
    }
}

/// `l` times `k`, in f64.
pub(crate) fn scaled_by(l: &[f32], k: f64) -> Vec<f32> {
    l.iter().map(|&v| (v as f64 * k) as f32).collect()
}

/// Whether the rendering layer renders `l` as it is: its brightest texel (the error) is finite
/// and at most [`MAX_RADIANCE`], which the layer caps texels at.
pub(crate) fn renderable(l: &[f32]) -> Result<(), f32> {
    let brightest = l.iter().fold(0.0_f32, |m, &v| m.max(v));
    if brightest.is_finite() && brightest <= MAX_RADIANCE {
        Ok(())
    } else {
        Err(brightest)
    }
}

/// A given illumination `l` (`[3, He, 2He]`, radiance in the photo's linear units) at its own
/// level: in the network's units, the photo's linear values times `exposure`. A light brighter
/// there than the rendering layer renders ([`MAX_RADIANCE`], which it caps texels at) is refused:
/// its edit would be silently dimmer than the light asked for.
pub fn light_at_own_level(l: &[f32], exposure: f64) -> Result<Vec<f32>> {
    let scaled = scaled_by(l, exposure);
    if let Err(brightest) = renderable(&scaled) {
        bail!(
            "the given light at its own level (--light-level given) is too bright for this photo: \
             its brightest texel times the photo's exposure ({exposure:.3e}) is {brightest:.3e}, \
             above the {MAX_RADIANCE:.0e} the rendering layer renders; give it in the photo's \
             linear units, or let the photo set its level (--light-level auto)"
        );
    }
    Ok(scaled)
}

/// The inverse of [`light_at_own_level`]: `env` (network units) in the photo's linear units,
/// divided by the edit's `exposure`, as `env.exr` holds it. Refused where that is not a finite
/// map (a photo so bright that its L' passes f32), never written as infinity.
pub fn light_in_photo_units(env: &[f32], exposure: f64) -> Result<Vec<f32>> {
    if !(exposure.is_finite() && exposure > 0.0) {
        bail!("the edit's exposure {exposure} cannot bring L' to the photo's units");
    }
    let l: Vec<f32> = env.iter().map(|&v| (v as f64 / exposure) as f32).collect();
    if let Some(v) = env.iter().zip(&l).find(|(_, w)| !w.is_finite()) {
        bail!(
            "L' in the photo's linear units (a texel of {:.3e} divided by the exposure {exposure:.3e}) \
             is beyond what an EXR holds: the photo is too bright to write its light",
            v.0
        );
    }
    Ok(l)
}

/// An illumination `l` (`[3, He, 2He]`) at the level that explains the photo best through
/// `x`'s normals and material: the scale k minimising Σ (k·R(n', m', l) − I)² over the object (a
/// map's exposure is arbitrary). Refused where no light explains the photo: a black render, or
/// a light brighter than the layer renders.
pub fn light_at_photo_level(layer: &RenderingLayer, prep: &Prepared, x: &Prediction, l: &[f32]) -> Result<Vec<f32>> {
    let s = prep.size;
    let rendered = layer.forward(&LayerInput {
        batch: 1,
        size: (s, s),
        regions: prep.regions,
        normals: &x.normals,
        region_map: &prep.region_map,
        materials: &x.materials,
        env: l,
    })?;
    let (mut ri, mut rr) = (0.0_f64, 0.0_f64);
    for (k, (&r, &i)) in rendered.iter().zip(&prep.input).enumerate() {
        if prep.mask[k % (s * s)] > 0.0 {
            ri += r as f64 * i as f64;
            rr += r as f64 * r as f64;
        }
    }
    let k = ri / rr;
    if !(k.is_finite() && k > 0.0) {
        bail!(
            "the light leaves the object black under the predicted normals and the material: it cannot explain the photo"
        );
    }
    let scaled = scaled_by(l, k);
    // A material that reflects almost nothing (a black input material) asks for a light the layer
    // would cap: its edit would be silently darker than the photo says.
    if let Err(brightest) = renderable(&scaled) {
        bail!(
            "the material is too dark for the photo: the light that explains it has a texel of \
             {brightest:.3e}, above the {MAX_RADIANCE:.0e} the rendering layer renders"
        );
    }
    Ok(scaled)
}

/// The object's own material from its spec (`--input-material` and its kin), named `option` in
/// errors: the spec and its normalised DSBRDF, for [`LightOptions::input_material`].
pub fn known_material(spec: Option<&str>, option: &str) -> Result<Option<(String, Vec<f32>)>> {
    spec.map(|spec| {
        let (m, _) = crate::target::dsbrdf_of(spec).with_context(|| option.to_string())?;
        Ok((spec.to_string(), m.to_normalised().map(|v| v as f32).to_vec()))
    })
    .transpose()
}

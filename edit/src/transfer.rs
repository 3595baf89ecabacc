//! Material transfer (Fig. 4) and swap (Fig. 10): one photo's predicted material rendered on
//! another photo's object, under that photo's light, through the same steps as [`crate::edit`].

use super::{
    Clock, Edit, EditReport, LightOptions, Look, Model, ReadPhoto, Understanding, Understood, finish, known_material,
    normals, output, read_photo, target, understand,
};
use crate::progress::Watch;
use anyhow::{Context, Result, bail};
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_trainer::post_optimisation;
use std::path::{Path, PathBuf};

/// A photo given to [`transfer`] or [`swap`], with what is known of its object.
#[derive(Clone, Copy, Debug)]
pub struct Given<'a> {
    /// The photo.
    pub photo: &'a Path,
    /// Its mask (default: its alpha channel).
    pub mask: Option<&'a Path>,
    /// The object's own material when it is known (a spec, as `edit --input-material`): it
    /// replaces that photo's m' (what the other photo receives, and what sets this one's light's
    /// level).
    pub material: Option<&'a str>,
    /// The object's normals at the photo's resolution when they are known (as `edit --normals`):
    /// they replace that photo's n'.
    pub normals: Option<&'a Path>,
    /// What of that photo's L' is kept (as `edit --light-estimate`).
    pub light_estimate: crate::light::estimate::LightEstimate,
}

impl<'a> Given<'a> {
    /// A photo and its mask, nothing else known of its object.
    pub fn photo(photo: &'a Path, mask: Option<&'a Path>) -> Self {
        Given {
            photo,
            mask,
            material: None,
            normals: None,
            light_estimate: Default::default(),
        }
    }

    /// The paths this photo reads, which no output may overwrite.
    fn inputs(&self) -> [Option<&'a Path>; 3] {
        [Some(self.photo), self.mask, self.normals]
    }
}

/// Two photos and how the edit between them is made: [`transfer`]'s `from` (`first`) and `to`
/// (`second`), [`swap`]'s `a` and `b`.
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// The first photo.
    pub first: Given<'a>,
    /// The second photo.
    pub second: Given<'a>,
    /// Eq. 6's weights and lengths, when it refines each photo's estimates.
    pub eq6: Option<&'a post_optimisation::Eq6Config>,
    /// The composite and range of the result.
    pub look: Look,
}

/// Material transfer (Fig. 4): the material predicted from photo `first` (its first region)
/// rendered on the object of photo `second`, under that photo's predicted light; outputs as
/// [`crate::edit`]'s. What is known of either object ([`Given`]) replaces that photo's estimate.
pub fn transfer(model: &Path, photos: Pair, out: &Path) -> Result<EditReport> {
    let watch = Watch::unwatched();
    refuse_overwriting(out, [&photos.first, &photos.second])?;
    transfer_with(&Model::load(model)?, photos, out, watch)
}

/// Refuses an output folder that holds any input of the two photos.
fn refuse_overwriting(out: &Path, photos: [&Given; 2]) -> Result<()> {
    let files: Vec<PathBuf> = photos
        .iter()
        .filter_map(|g| g.material.and_then(output::material_file))
        .collect();
    let inputs: Vec<Option<&Path>> = photos
        .iter()
        .flat_map(|g| g.inputs())
        .chain(files.iter().map(|p| Some(p.as_path())))
        .collect();
    output::refuse_overwriting_inputs(out, &inputs)
}

/// [`transfer`] with a loaded model, watched as [`crate::edit_with`].
pub fn transfer_with(model: &Model, photos: Pair, out: &Path, watch: Watch) -> Result<EditReport> {
    refuse_overwriting(out, [&photos.first, &photos.second])?;
    let (from, to, optimize) = (photos.first, photos.second, photos.eq6);
    watch.enter("reading")?;
    let read_from = read_photo(from.photo, from.mask, None)?;
    let read_to = read_photo(to.photo, to.mask, None)?;
    let [light_from, light_to] = light_options([(&from, &read_from), (&to, &read_to)], optimize, ["from", "to"])?;
    let clock = Clock::inputs_read(watch);
    let source = understand(model, read_from, understanding(&light_from, optimize), watch)?;
    let target = source_material(&source)?;
    let u = understand(model, read_to, understanding(&light_to, optimize), watch)?;
    finish(model, u, &onto(&[target], photos.look), out, clock)
}

/// How each photo is understood: its light options, and Eq. 6 when asked for.
fn understanding<'a>(light: &'a LightOptions, eq6: Option<&'a post_optimisation::Eq6Config>) -> Understanding<'a> {
    Understanding { light, eq6 }
}

/// One photo's material onto the other's object: its first region's, in every region.
fn onto(target: &[(Dsbrdf, target::RegionTarget)], look: Look) -> Edit<'_> {
    Edit {
        targets: target,
        relight: None,
        light_spec: None,
        look,
    }
}

/// Each photo's light options with what is known of its object (its options named
/// `--{side}-material` in errors; a normal map by its path, as `edit --normals` names it). A
/// known material is refused with Eq. 6, which would change it; known normals are Eq. 6's start,
/// as in `edit`.
fn light_options(
    photos: [(&Given, &ReadPhoto); 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    sides: [&str; 2],
) -> Result<[LightOptions; 2]> {
    if optimize.is_some()
        && let Some(k) = photos.iter().position(|(g, _)| g.material.is_some())
    {
        bail!(
            "--{}-material holds an object's material as given: Eq. 6 would change it; give one or the other",
            sides[k]
        );
    }
    let side = |k: usize| -> Result<LightOptions> {
        let (given, read) = photos[k];
        Ok(LightOptions {
            input_material: known_material(given.material, &format!("--{}-material", sides[k]))?,
            normals: given
                .normals
                .map(|n| normals::load_normals(n, read.photo.width, read.photo.height, &read.coverage))
                .transpose()?,
            estimate: given.light_estimate,
            ..LightOptions::default()
        })
    };
    Ok([side(0)?, side(1)?])
}

/// The DSBRDF predicted for a photo's first region (or its own material, when it was given), as
/// a target for another photo.
fn source_material(u: &Understood) -> Result<(Dsbrdf, target::RegionTarget)> {
    let m: Vec<f64> = u.point.materials[..PARAMS].iter().map(|&v| v as f64).collect();
    let material =
        Dsbrdf::from_normalised(&m).with_context(|| format!("the material predicted from {}", u.path.display()))?;
    let (spec, source) = match (&u.input_material, u.eq6.is_some()) {
        (Some(spec), _) => (spec.clone(), "given as its own material"),
        (None, true) => (format!("m' of {}", u.path.display()), "predicted, Eq. 6"),
        (None, false) => (format!("m' of {}", u.path.display()), "predicted"),
    };
    let record = target::RegionTarget {
        region: 1,
        spec,
        source: source.into(),
    };
    Ok((material, record))
}

/// Material swap (Fig. 10): each photo's object (`first` is a, `second` b) with the other's
/// predicted material (or its own, where [`Given`] holds it), into `out/a` and `out/b`.
pub fn swap(model: &Path, photos: Pair, out: &Path) -> Result<[EditReport; 2]> {
    let (a, b, optimize, how) = (photos.first, photos.second, photos.eq6, photos.look);
    let watch = Watch::unwatched();
    let (out_a, out_b) = (out.join("a"), out.join("b"));
    for o in [&out_a, &out_b] {
        refuse_overwriting(o, [&a, &b])?;
    }
    let model = Model::load(model)?;
    let (read_a, read_b) = (read_photo(a.photo, a.mask, None)?, read_photo(b.photo, b.mask, None)?);
    let [light_a, light_b] = light_options([(&a, &read_a), (&b, &read_b)], optimize, ["a", "b"])?;
    let clock = Clock::inputs_read(watch);
    let ua = understand(&model, read_a, understanding(&light_a, optimize), watch)?;
    let ub = understand(&model, read_b, understanding(&light_b, optimize), watch)?;
    let (ta, tb) = (source_material(&ua)?, source_material(&ub)?);
    let ra = finish(&model, ua, &onto(&[tb], how), &out_a, clock)?;
    let rb = finish(&model, ub, &onto(&[ta], how), &out_b, clock)?;
    Ok([ra, rb])
}

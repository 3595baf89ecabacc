//! Material transfer (Fig. 4) and swap (Fig. 10): one photo's predicted material rendered on
//! another photo's object, under that photo's light, through the same steps as [`crate::edit`].

use super::{
    Composite, EditReport, LightOptions, Model, Understood, finish, known_material, output, read_photo, target,
    understand,
};
use crate::progress::{Progress, enter};
use anyhow::{Context, Result, bail};
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::PARAMS;
use matedit_trainer::post_optimisation;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// Material transfer (Fig. 4): the material predicted from photo `from` (its first region)
/// rendered on the object of photo `to`, under `to`'s predicted light; outputs as [`crate::edit`]'s.
/// `known` holds either object's own material when it is known (specs, as
/// `--input-material`): it replaces that photo's m' (what `to` receives, or what sets `to`'s
/// light's level).
#[allow(clippy::too_many_arguments)]
pub fn transfer(
    model: &Path,
    from: (&Path, Option<&Path>),
    to: (&Path, Option<&Path>),
    known: [Option<&str>; 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    how: Composite,
    out: &Path,
) -> Result<EditReport> {
    let t0 = Instant::now();
    output::refuse_overwriting_inputs(out, &[Some(from.0), from.1, Some(to.0), to.1])?;
    let model = Model::load(model)?;
    transfer_checked(&model, from, to, known, optimize, how, out, None, t0)
}

/// [`transfer`] with a loaded model, watched as [`crate::edit_with`].
#[allow(clippy::too_many_arguments)]
pub fn transfer_with(
    model: &Model,
    from: (&Path, Option<&Path>),
    to: (&Path, Option<&Path>),
    known: [Option<&str>; 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    how: Composite,
    out: &Path,
    watcher: Option<&Arc<Progress>>,
    t0: Instant,
) -> Result<EditReport> {
    output::refuse_overwriting_inputs(out, &[Some(from.0), from.1, Some(to.0), to.1])?;
    transfer_checked(model, from, to, known, optimize, how, out, watcher, t0)
}

/// [`transfer_with`] once the output folder was checked.
#[allow(clippy::too_many_arguments)]
fn transfer_checked(
    model: &Model,
    from: (&Path, Option<&Path>),
    to: (&Path, Option<&Path>),
    known: [Option<&str>; 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    how: Composite,
    out: &Path,
    watcher: Option<&Arc<Progress>>,
    t0: Instant,
) -> Result<EditReport> {
    enter(watcher.map(|w| w.as_ref()), "reading")?;
    let read_from = read_photo(from.0, from.1, None)?;
    let read_to = read_photo(to.0, to.1, None)?;
    let [light_from, light_to] = own_materials(known, optimize, ["--from-material", "--to-material"])?;
    let t_load = t0.elapsed().as_secs_f64();
    let source = understand(model, read_from, from.0, optimize, &light_from, watcher)?;
    let target = source_material(&source)?;
    let u = understand(model, read_to, to.0, optimize, &light_to, watcher)?;
    finish(
        model,
        u,
        &[target],
        None,
        None,
        how,
        out,
        t0,
        t_load,
        watcher.map(|w| w.as_ref()),
    )
}

/// Each photo's light options with its own material, where known (named `options` in errors);
/// refused with Eq. 6, which would change them.
fn own_materials(
    known: [Option<&str>; 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    options: [&str; 2],
) -> Result<[LightOptions; 2]> {
    if optimize.is_some()
        && let Some(k) = known.iter().position(Option::is_some)
    {
        bail!(
            "{} holds an object's material as given: Eq. 6 would change it; give one or the other",
            options[k]
        );
    }
    let side = |k: usize| -> Result<LightOptions> {
        Ok(LightOptions {
            input_material: known_material(known[k], options[k])?,
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

/// Material swap (Fig. 10): each photo's object with the other's predicted material, into
/// `out/a` and `out/b`; `known` as [`transfer`]'s, for `a` and `b`.
#[allow(clippy::too_many_arguments)]
pub fn swap(
    model: &Path,
    a: (&Path, Option<&Path>),
    b: (&Path, Option<&Path>),
    known: [Option<&str>; 2],
    optimize: Option<&post_optimisation::Eq6Config>,
    how: Composite,
    out: &Path,
) -> Result<[EditReport; 2]> {
    let t0 = Instant::now();
    let (out_a, out_b) = (out.join("a"), out.join("b"));
    for o in [&out_a, &out_b] {
        output::refuse_overwriting_inputs(o, &[Some(a.0), a.1, Some(b.0), b.1])?;
    }
    let model = Model::load(model)?;
    let (read_a, read_b) = (read_photo(a.0, a.1, None)?, read_photo(b.0, b.1, None)?);
    let [light_a, light_b] = own_materials(known, optimize, ["--a-material", "--b-material"])?;
    let t_load = t0.elapsed().as_secs_f64();
    let ua = understand(&model, read_a, a.0, optimize, &light_a, None)?;
    let ub = understand(&model, read_b, b.0, optimize, &light_b, None)?;
    let (ta, tb) = (source_material(&ua)?, source_material(&ub)?);
    let ra = finish(&model, ua, &[tb], None, None, how, &out_a, t0, t_load, None)?;
    let rb = finish(&model, ub, &[ta], None, None, how, &out_b, t0, t_load, None)?;
    Ok([ra, rb])
}

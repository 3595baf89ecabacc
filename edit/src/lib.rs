//! # matedit-edit
//!
//! Material editing of a photo (Sec. 3.4 and Fig. 2 applied to a real picture): the network
//! predicts normals n', a DSBRDF m' per region and the illumination L' from the framed photo
//! ([`photo`]); the rendering layer renders I' = R(n', m', L') and the edit O' = R(n', m_t, L')
//! with the target material m_t (or R(n', m', L_new) under another illumination, Fig. 4); O'
//! goes back into the photo at its original resolution inside the mask ([`composite`]).
//!
//! [`prepare`] ([`photo`]), [`network_prediction`] and [`render_all`] ([`predict`]) work in
//! memory; [`edit`] adds reading the inputs and writing every output ([`output`]) after all of
//! them succeeded, so a bad input writes nothing. [`detail`] carries n' to the photo's
//! resolution and [`background`] sets a light's level from the photo's surroundings.
//! [`transfer`](fn@transfer) and [`swap`] ([`transfer`](mod@transfer)) are Fig. 4 and Fig. 10; [`serve`] is the editing web page over the
//! same functions; [`cli`] is their command line, the `matedit` binary. The network, the rendering
//! layer and Eq. 6 ([`matedit_trainer::post_optimisation`]) come from the trainer; target
//! materials by name ([`target`]) from the material library, fitted on the fly.

#![warn(missing_docs)]

/// `println!` that lets the reader go: output piped into `head` that closes early ends the
/// output, not the command (whose files are written all the same) with a panic. For every line
/// `matedit` writes to stdout ([`cli`], [`serve`]).
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout().lock(), $($t)*);
    }};
}

pub mod background;
pub mod camera;
pub mod cli;
pub mod composite;
pub mod detail;
#[cfg(test)]
mod input_tests;
pub mod light;
pub mod light_estimate;
#[cfg(test)]
mod light_tests;
pub mod normals;
pub mod orientation;
pub mod output;
pub mod photo;
pub mod predict;
pub mod progress;
pub mod range;
pub mod relight;
pub use photo::{Prepared, prepare, prepare_framed};
pub use predict::{Predicted, network_prediction, render_all};
pub use range::{Look, Range};
pub mod serve;
pub mod target;
#[cfg(test)]
mod tests;
pub mod transfer;
pub mod truth;

pub use composite::Composite;
pub use light::{LevelFrom, LightOptions, known_material, light_at_own_level, light_at_photo_level};
pub use output::{EditReport, Eq6Report};
pub use transfer::{Given, swap, transfer, transfer_with};

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use matedit_physics::brdf::Dsbrdf;
use matedit_trainer::model::network::Net;
use matedit_trainer::model::prediction::Prediction;
use matedit_trainer::post_optimisation;
use matedit_trainer::render::RenderingLayer;
use matedit_trainer::train::checkpoint;
use photo::{Photo, TRAINING_MEAN_LUMINANCE};
use progress::{Progress, enter};
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Instant;

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
    /// What of the network's L' is kept ([`light_estimate`]).
    pub light_estimate: light_estimate::LightEstimate,
    /// The photo's horizontal field of view in degrees (default [`background::DEFAULT_FOV_DEG`]).
    pub fov_deg: Option<f64>,
    /// The object's own material, when known (a spec, as `--material` takes): used instead of
    /// m', and it sets the light's level ([`LightOptions::input_material`]).
    pub input_material: Option<String>,
    /// The object's normals at the photo's resolution, when known (EXR or PNG, camera space):
    /// used instead of n' ([`normals`]).
    pub normals: Option<PathBuf>,
    /// How to composite; `None`: [`Composite::best_for`] what `input_material` and `light` make
    /// known.
    pub composite: Option<Composite>,
    /// What the edited object's level is held to ([`range`]; `None`: [`Range::best_for`] the
    /// request, the rendered level where `input_material` or `light` makes it known).
    pub range: Option<Range>,
    /// Refine n', m', L' with Eq. 6 before rendering.
    pub optimize: Option<post_optimisation::Eq6Config>,
}

/// The network of a checkpoint folder, or of a run folder's latest checkpoint.
pub fn load_model(path: &Path) -> Result<(Net, checkpoint::State, PathBuf)> {
    let dir = if path.join("latest.json").is_file() {
        checkpoint::latest(path)?.with_context(|| format!("{}: no checkpoint yet", path.display()))?
    } else {
        path.to_path_buf()
    };
    if !dir.join("state.json").is_file() {
        bail!(
            "{}: not a checkpoint folder (no state.json) nor a run folder (no latest.json)",
            path.display()
        );
    }
    let (net, state) =
        checkpoint::load_net(&dir, &Device::flex()).with_context(|| format!("checkpoint {}", dir.display()))?;
    Ok((net, state, dir))
}

/// A photo read, framed and understood: n', m', L' (refined by Eq. 6 when asked).
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
    /// n*, m*, L* (the network's, or after Eq. 6) at the network's resolution.
    pub point: Prediction,
    /// The object at the photo's resolution and n* there.
    pub detail: detail::Detail,
    /// Eq. 6, when asked for.
    pub eq6: Option<Eq6Report>,
    /// What of L' was kept; none when a light was given.
    pub light_estimate: Option<light_estimate::LightEstimateReport>,
    /// How L*'s level was set (L* above is at that level).
    pub light_level: background::LightLevel,
    /// The object's own material's spec, when it was given instead of m'.
    pub input_material: Option<String>,
    /// The normal map given instead of n', when one was.
    pub normals: Option<normals::NormalsReport>,
    /// Seconds the network took.
    pub network_seconds: f64,
}

/// A loaded network and what it was trained for.
pub struct Model {
    /// The network.
    pub net: Net,
    /// Its checkpoint's state (shape).
    pub state: checkpoint::State,
    /// The checkpoint folder.
    pub dir: PathBuf,
    /// A rendering layer for its environment size.
    pub layer: RenderingLayer,
    /// What its L' reads from a picture ([`light_estimate`]), measured when first asked.
    light_skill: OnceLock<light_estimate::LightSkill>,
}

impl Model {
    /// [`load_model`] and its layer.
    pub fn load(path: &Path) -> Result<Self> {
        let (net, state, dir) = load_model(path)?;
        let layer = RenderingLayer::new(state.net.env_height);
        let light_skill = OnceLock::new();
        Ok(Self {
            net,
            state,
            dir,
            layer,
            light_skill,
        })
    }

    /// What its L' reads from a picture, measured once ([`light_estimate::LightSkill::measure`]).
    pub fn light_skill(&self) -> Result<light_estimate::LightSkill> {
        if let Some(s) = self.light_skill.get() {
            return Ok(*s);
        }
        let (size, h) = (self.state.net.input_size, self.state.net.env_height);
        let s = light_estimate::LightSkill::measure(&self.net, size, h).with_context(|| {
            format!(
                "checkpoint {}: the light probe (--light-estimate network does without it)",
                self.dir.display()
            )
        })?;
        Ok(*self.light_skill.get_or_init(|| s))
    }
}

/// A photo with its mask and region labels, read and checked.
pub struct ReadPhoto {
    /// The photo.
    pub photo: Photo,
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
    let (p, file) = photo::load_photo_shown(photo_path)?;
    let turn = file.orientation;
    let mut orientation = orientation::OrientationReport::new(turn, orientation::shown_size((p.width, p.height), turn));
    let (coverage, mask_name) = match mask {
        Some(m) => {
            let (coverage, fit) = photo::load_mask(m, p.width, p.height, turn)?;
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
    photo::check_mask_shape(mask.unwrap_or(photo_path), &coverage, p.width)?;
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
        coverage,
        mask_name,
        labels,
        orientation: orientation.matters().then_some(orientation),
        exif_fov_deg: file.fov_deg,
    })
}

/// Frames a read photo and runs the network (and Eq. 6 with `optimize`), showing its phases to
/// `watcher`.
pub fn understand(
    model: &Model,
    read: ReadPhoto,
    path: &Path,
    optimize: Option<&post_optimisation::Eq6Config>,
    light: &LightOptions,
    watcher: Option<&Arc<Progress>>,
) -> Result<Understood> {
    let w = watcher.map(|w| w.as_ref());
    let ReadPhoto {
        photo: p,
        coverage,
        mask_name,
        labels,
        orientation,
        exif_fov_deg,
    } = read;
    let prep = prepare(
        &p,
        &coverage,
        labels.as_ref().map(|(l, n)| (l.as_slice(), *n)),
        model.state.net.input_size,
    )
    .with_context(|| path.display().to_string())?;
    enter(w, "network")?;
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
    let mut normals_report = None;
    if let Some(g) = &light.normals {
        let (n, kept) = g.framed(&prep, &x.normals);
        x.normals = n;
        normals_report = Some(normals::NormalsReport {
            path: g.path.clone(),
            network_pixels_kept: kept,
            detail_pixels_kept: 0,
        });
    }
    let level_from = light.level_from();
    if let Some((spec, m)) = &light.input_material {
        x.materials = m.repeat(prep.regions);
        if light.given.is_none() {
            let l = std::mem::take(&mut x.env);
            x.env = light_at_photo_level(&model.layer, &prep, &x, &l)
                .with_context(|| format!("--input-material {spec}"))?;
        }
    }
    if let Some(l) = &light.given {
        x.env = if level_from == LevelFrom::Given {
            light_at_own_level(l, prep.exposure)?
        } else {
            light_at_photo_level(&model.layer, &prep, &x, l)?
        };
    }
    let network_seconds = t.elapsed().as_secs_f64();
    let labels = labels.as_ref().map(|(l, n)| (l.as_slice(), *n));
    let mut detail = detail::detail(
        &p,
        &coverage,
        labels,
        &prep,
        &x.normals,
        detail::MAX_DETAIL_OBJECT_PIXELS,
    )
    .with_context(|| path.display().to_string())?;
    if let (Some(g), Some(r)) = (&light.normals, normals_report.as_mut()) {
        let (n, kept) = g.framed(&detail.prep, &detail.normals);
        detail.normals = n;
        r.detail_pixels_kept = kept;
    }
    let eq6 = match optimize {
        None => None,
        Some(cfg) => {
            enter(w, "eq6")?;
            let t = Instant::now();
            let fine = &detail.prep;
            // Eq. 6 on the photo's own pixels: its image and normal terms sum over F² pixels
            // where the weights were chosen for S², so the light prior's weight grows with them
            // (the same balance per unit of the object's area).
            let area = (fine.size * fine.size) as f64 / (prep.size * prep.size) as f64;
            let prior = Prediction {
                normals: detail.normals.clone(),
                materials: x.materials.clone(),
                env: x.env.clone(),
            };
            let problem = post_optimisation::Problem::eq6(
                &model.layer,
                fine.size,
                fine.regions,
                &fine.input,
                &fine.region_map,
                &prior,
                cfg.a,
                cfg.b * area,
            );
            let watcher = watcher.map(|w| Arc::clone(w) as Arc<dyn post_optimisation::watcher::Watcher>);
            let r = post_optimisation::post_optimise_watched(&problem, prior.clone(), cfg, watcher.as_ref())?;
            x.normals = detail::downsample_normals(&detail.prep, &r.point.normals, &prep, &x.normals);
            x.materials = r.point.materials;
            x.env = r.point.env;
            detail.normals = r.point.normals;
            Some(Eq6Report {
                config: cfg.clone(),
                light_weight: cfg.b * area,
                start: r.start,
                end: r.end,
                steps: r.steps,
                evaluations: r.evaluations,
                stride: r.stride,
                seconds: t.elapsed().as_secs_f64(),
            })
        }
    };
    let (fov_deg, fov_from) = match (light.fov_deg, exif_fov_deg) {
        (Some(f), _) => (f, "given"),
        (None, Some(f)) => (f, "exif"),
        (None, None) => (background::DEFAULT_FOV_DEG, "default"),
    };
    let light_level = if level_from == LevelFrom::Background {
        let level = background::light_level(
            &p,
            &coverage,
            &x.env,
            model.state.net.env_height,
            prep.exposure,
            (fov_deg, fov_from),
        );
        let k = level.scale as f32;
        x.env.iter_mut().for_each(|v| *v *= k);
        level
    } else {
        background::LightLevel {
            source: match (level_from, &light.input_material) {
                (LevelFrom::Given, _) => "given",
                (_, Some(_)) => "input material",
                _ => "network",
            }
            .into(),
            scale: 1.0,
            pixels: 0,
            fov_deg,
            fov_from: fov_from.into(),
            note: None,
        }
    };
    Ok(Understood {
        photo: p,
        path: path.to_path_buf(),
        coverage,
        mask_name,
        orientation,
        prep,
        point: x,
        detail,
        eq6,
        light_estimate,
        light_level,
        input_material: light.input_material.as_ref().map(|(spec, _)| spec.clone()),
        normals: normals_report,
        network_seconds,
    })
}

/// Renders an understood photo with `targets` (and `relight`), composites, and writes every
/// output into `out`.
#[allow(clippy::too_many_arguments)]
fn finish(
    model: &Model,
    u: Understood,
    targets: &[(Dsbrdf, target::RegionTarget)],
    relight: Option<(&str, Vec<f32>, relight::RelightLevel)>,
    light_spec: Option<&str>,
    look: Look,
    out: &Path,
    t0: Instant,
    t_load: f64,
    watcher: Option<&Progress>,
) -> Result<EditReport> {
    enter(watcher, "render")?;
    let t1 = Instant::now();
    let target_params: Option<Vec<f32>> = (!targets.is_empty()).then(|| {
        targets
            .iter()
            .flat_map(|(m, _)| m.to_normalised().map(|v| v as f32))
            .collect()
    });
    let env_height = model.state.net.env_height;
    let Understood {
        photo: p,
        path,
        coverage,
        mask_name,
        orientation,
        prep,
        point,
        detail,
        eq6,
        light_estimate,
        light_level,
        input_material,
        normals,
        network_seconds,
    } = u;
    // The relighting map at its level, now that L* is known.
    let relight = relight
        .map(|(spec, l, level)| {
            relight::at_level(&l, &point.env, env_height, level, prep.exposure)
                .with_context(|| format!("--relight {spec}"))
                .map(|(l, r)| (spec, l, r))
        })
        .transpose()?;
    let relight_env = relight.as_ref().map(|(_, l, _)| l.as_slice());
    let fine_point = Prediction {
        normals: detail.normals,
        materials: point.materials.clone(),
        env: point.env.clone(),
    };
    let fine = render_all(
        &model.layer,
        &detail.prep,
        fine_point,
        env_height,
        target_params.as_deref(),
        relight_env,
    )?;
    let pred = render_all(
        &model.layer,
        &prep,
        point,
        env_height,
        target_params.as_deref(),
        relight_env,
    )?;
    let t_render = t1.elapsed().as_secs_f64();
    let t_eq6 = eq6.as_ref().map_or(0.0, |e| e.seconds);
    let t2 = Instant::now();
    let mut composites = Vec::new();
    let mut ranges = Vec::new();
    for (name, img, how) in [
        ("edited", &fine.o_prime, look.composite),
        ("relit", &fine.relit, look.relit),
    ] {
        if let Some(img) = img {
            let values = composite::object_values(&p, &coverage, &detail.prep, img, &fine.i_prime, how);
            let held = range::fit(&p, &coverage, &values, look.range, name);
            composites.push((
                name,
                composite::blend(&p, &coverage, values, |v| range::apply(v, &held)),
            ));
            ranges.push(held);
        }
    }
    let t_composite = t2.elapsed().as_secs_f64();
    let mut report = EditReport {
        photo: path.display().to_string(),
        photo_size: [p.width, p.height],
        encoding: p.encoding,
        orientation,
        mask: mask_name,
        object_pixels: coverage.iter().filter(|&&c| c > 0.0).count(),
        checkpoint: model.dir.display().to_string(),
        stage: model.state.stage_name.clone(),
        input_size: model.state.net.input_size,
        env_height,
        framing: prep.framing,
        exposure: prep.exposure,
        training_mean_luminance: TRAINING_MEAN_LUMINANCE,
        regions: targets.iter().map(|(_, r)| r.clone()).collect(),
        relight: relight.as_ref().map(|(spec, _, _)| spec.to_string()),
        relight_level: relight.map(|(_, _, r)| r),
        light: light_spec.map(str::to_string),
        input_material,
        normals,
        light_estimate,
        light_level,
        composite: look.composite,
        relit_composite: fine.relit.is_some().then_some(look.relit),
        range: ranges,
        eq6,
        seconds: output::Timings {
            load: t_load,
            network: network_seconds,
            eq6: t_eq6,
            render: t_render,
            composite: t_composite,
            write: 0.0,
            total: 0.0,
        },
        files: Vec::new(),
    };
    enter(watcher, "write")?;
    let t3 = Instant::now();
    let mats: Vec<Dsbrdf> = targets.iter().map(|(m, _)| m.clone()).collect();
    // Every file goes to a staging folder first: a full disk or a failed write leaves `out` as
    // it was, never an edited.png without its report.
    let stage = output::Staging::new(out)?;
    report.files = output::write_all(stage.path(), &p, &prep, &pred, &composites, &mats)?;
    if let Some(e) = &report.eq6 {
        output::energy_plot(&stage.path().join("energy.png"), e)?;
        report.files.push("energy.png".into());
    }
    report.seconds.write = t3.elapsed().as_secs_f64();
    report.seconds.total = t0.elapsed().as_secs_f64();
    output::write_report(stage.path(), &report)?;
    stage.publish()?;
    Ok(report)
}

/// Reads the inputs, edits, and writes every output into `out` (see [`output`]). Nothing is
/// written when any input is bad.
pub fn edit(model: &Path, req: &EditRequest, out: &Path) -> Result<EditReport> {
    let t0 = Instant::now();
    check_request(req, out)?;
    let model = Model::load(model)?;
    edit_checked(&model, req, out, None, t0)
}

/// Refuses a request with nothing to do, or whose output folder holds one of its inputs.
fn check_request(req: &EditRequest, out: &Path) -> Result<()> {
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

/// [`edit`] with a loaded model (what `matedit serve` runs for every request), its phases and
/// Eq. 6's energies shown to `watcher`; `t0` is when the request began.
pub fn edit_with(
    model: &Model,
    req: &EditRequest,
    out: &Path,
    watcher: Option<&Arc<Progress>>,
    t0: Instant,
) -> Result<EditReport> {
    check_request(req, out)?;
    edit_checked(model, req, out, watcher, t0)
}

/// [`edit_with`] once the request and the output folder were checked.
fn edit_checked(
    model: &Model,
    req: &EditRequest,
    out: &Path,
    watcher: Option<&Arc<Progress>>,
    t0: Instant,
) -> Result<EditReport> {
    enter(watcher.map(|w| w.as_ref()), "reading")?;
    let read = read_photo(&req.photo, req.mask.as_deref(), req.regions.as_deref())?;
    let regions = read.labels.as_ref().map_or(1, |l| l.1);
    let targets: Vec<(Dsbrdf, target::RegionTarget)> =
        target::resolve_targets(&req.materials, regions, req.regions.as_deref())?
            .into_iter()
            .map(|t| (t.material, t.record))
            .collect();
    let relight = req
        .relight
        .as_ref()
        .map(|spec| {
            let l = target::relight_env(spec, model.state.net.env_height)?;
            relight::check(&l, model.state.net.env_height).with_context(|| format!("--relight {spec}"))?;
            Ok::<_, anyhow::Error>((spec.as_str(), l, req.relight_level))
        })
        .transpose()?;
    let light = LightOptions {
        given: req
            .light
            .as_ref()
            .map(|spec| target::relight_env(spec, model.state.net.env_height))
            .transpose()?,
        level: req.light_level,
        estimate: req.light_estimate,
        fov_deg: req.fov_deg,
        input_material: light::known_material(req.input_material.as_deref(), "--input-material")?,
        normals: req
            .normals
            .as_deref()
            .map(|n| normals::load_normals(n, read.photo.width, read.photo.height, &read.coverage))
            .transpose()?,
    };
    let t_load = t0.elapsed().as_secs_f64();
    let u = understand(model, read, &req.photo, req.optimize.as_ref(), &light, watcher)?;
    let look = Look::for_known(
        req.composite,
        req.range,
        light.input_material.is_some(),
        light.light_known(&u.light_level),
    );
    finish(
        model,
        u,
        &targets,
        relight,
        req.light.as_deref(),
        look,
        out,
        t0,
        t_load,
        watcher.map(|w| w.as_ref()),
    )
}

//! The last stages of an edit: an understood photo rendered with its targets (and under another
//! light, when asked), composited into the photo and held to its range ([`crate::look`]), and
//! every output written ([`crate::output`]).

use crate::light::relight::{self, Relight, RelightLevelReport};
use crate::output::{self, EditReport, Timings};
use crate::photo::TRAINING_MEAN_LUMINANCE;
use crate::progress::Watch;
use crate::understand::Understood;
use crate::{Look, Model, Predicted, composite, range, render_all, target};
use anyhow::{Context, Result};
use matedit_physics::brdf::Dsbrdf;
use matedit_trainer::model::prediction::Prediction;
use std::path::Path;
use std::time::Instant;

/// What an understood photo is rendered with.
pub struct Edit<'a> {
    /// Target materials, one per region (none: relighting alone).
    pub targets: &'a [(Dsbrdf, target::RegionTarget)],
    /// Another illumination for the object's own material.
    pub relight: Option<Relight>,
    /// The given light's spec, for the report.
    pub light_spec: Option<&'a str>,
    /// The composite and range.
    pub look: Look,
}

/// When an edit began, what watches it, and how long reading its inputs took.
#[derive(Clone, Copy)]
pub struct Clock<'a> {
    /// When the request began, and what watches it.
    pub watch: Watch<'a>,
    /// Seconds reading its inputs and loading took.
    pub t_load: f64,
}

impl<'a> Clock<'a> {
    /// The clock of a request whose inputs were read just now.
    pub fn inputs_read(watch: Watch<'a>) -> Self {
        Clock {
            watch,
            t_load: watch.t0.elapsed().as_secs_f64(),
        }
    }
}

/// What rendering and compositing made of an understood photo.
struct Made {
    /// At the network's resolution (the sheet and the EXRs).
    pred: Predicted,
    /// The composites into the photo, by output name.
    composites: Vec<(&'static str, Vec<[f32; 3]>)>,
    /// The range each was held to.
    ranges: Vec<range::RangeReport>,
    /// Whether a relit image was rendered.
    relit: bool,
    /// The relighting map's spec and level.
    relight: Option<(String, RelightLevelReport)>,
    render_seconds: f64,
    composite_seconds: f64,
}

/// Renders an understood photo as `edit` asks, composites, and writes every output into `out`.
pub fn finish(model: &Model, mut u: Understood, edit: &Edit, out: &Path, clock: Clock) -> Result<EditReport> {
    clock.watch.enter("render")?;
    let made = render_and_composite(model, &mut u, edit)?;
    let mut report = report(model, &u, edit, &made, clock);
    clock.watch.enter("write")?;
    let t3 = Instant::now();
    let mats: Vec<Dsbrdf> = edit.targets.iter().map(|(m, _)| m.clone()).collect();
    // Every file goes to a staging folder first: a full disk or a failed write leaves `out` as
    // it was, never an edited.png without its report.
    let stage = output::Staging::new(out)?;
    let edited = output::EditedPhotos {
        photo: &u.photo,
        composites: &made.composites,
    };
    report.files = output::write_all(stage.path(), edited, &u.prep, &made.pred, &mats)?;
    if let Some(e) = &report.eq6 {
        output::energy_plot(&stage.path().join("energy.png"), e)?;
        report.files.push("energy.png".into());
    }
    report.seconds.write = t3.elapsed().as_secs_f64();
    report.seconds.total = clock.watch.t0.elapsed().as_secs_f64();
    output::write_report(stage.path(), &report)?;
    stage.publish()?;
    Ok(report)
}

/// The renders at the photo's and the network's resolution, then the composites.
fn render_and_composite(model: &Model, u: &mut Understood, edit: &Edit) -> Result<Made> {
    let t1 = Instant::now();
    let env_height = model.state.net.env_height;
    let target_params: Option<Vec<f32>> = (!edit.targets.is_empty()).then(|| {
        edit.targets
            .iter()
            .flat_map(|(m, _)| m.to_normalised().map(|v| v as f32))
            .collect()
    });
    // The relighting map at its level, now that L* is known.
    let relight = edit
        .relight
        .as_ref()
        .map(|r| {
            relight::at_level(&r.env, &u.point.env, env_height, r.level, u.prep.exposure)
                .with_context(|| format!("--relight {}", r.spec))
                .map(|(l, level)| (r.spec.clone(), l, level))
        })
        .transpose()?;
    let relight_env = relight.as_ref().map(|(_, l, _)| l.as_slice());
    let fine_point = Prediction {
        normals: std::mem::take(&mut u.detail.normals),
        materials: u.point.materials.clone(),
        env: u.point.env.clone(),
    };
    let targets = target_params.as_deref();
    let fine = render_all(&model.layer, &u.detail.prep, fine_point, targets, relight_env)?;
    let point = Prediction {
        normals: std::mem::take(&mut u.point.normals),
        materials: std::mem::take(&mut u.point.materials),
        env: std::mem::take(&mut u.point.env),
    };
    let pred = render_all(&model.layer, &u.prep, point, targets, relight_env)?;
    let render_seconds = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let mut composites = Vec::new();
    let mut ranges = Vec::new();
    for (name, img, how) in [
        ("edited", &fine.o_prime, edit.look.composite),
        ("relit", &fine.relit, edit.look.relit),
    ] {
        if let Some(img) = img {
            let values = composite::object_values(
                &u.photo,
                &u.coverage,
                &u.detail.prep,
                composite::Renders {
                    render: img,
                    i_prime: &fine.i_prime,
                },
                how,
            );
            let held = range::fit(&u.photo, &u.coverage, &values, edit.look.range, name);
            composites.push((
                name,
                composite::blend(&u.photo, &u.coverage, values, |v| range::apply(v, &held)),
            ));
            ranges.push(held);
        }
    }
    Ok(Made {
        pred,
        composites,
        ranges,
        relit: fine.relit.is_some(),
        relight: relight.map(|(spec, _, level)| (spec, level)),
        render_seconds,
        composite_seconds: t2.elapsed().as_secs_f64(),
    })
}

/// The edit's report.json, its files and its last timings still to come.
fn report(model: &Model, u: &Understood, edit: &Edit, made: &Made, clock: Clock) -> EditReport {
    let p = &u.photo;
    EditReport {
        photo: u.path.display().to_string(),
        photo_size: [p.width, p.height],
        encoding: p.encoding,
        orientation: u.orientation.clone(),
        mask: u.mask_name.clone(),
        object_pixels: u.coverage.iter().filter(|&&c| c > 0.0).count(),
        checkpoint: model.dir.display().to_string(),
        stage: model.state.stage_name.clone(),
        input_size: model.state.net.input_size,
        env_height: model.state.net.env_height,
        framing: u.prep.framing,
        exposure: u.prep.exposure,
        training_mean_luminance: TRAINING_MEAN_LUMINANCE,
        regions: edit.targets.iter().map(|(_, r)| r.clone()).collect(),
        relight: made.relight.as_ref().map(|(spec, _)| spec.clone()),
        relight_level: made.relight.as_ref().map(|(_, r)| r.clone()),
        light: edit.light_spec.map(str::to_string),
        input_material: u.input_material.clone(),
        normals: u.normals.clone(),
        light_estimate: u.light_estimate,
        light_level: u.light_level.clone(),
        composite: edit.look.composite,
        relit_composite: made.relit.then_some(edit.look.relit),
        range: made.ranges.clone(),
        eq6: u.eq6.clone(),
        seconds: Timings {
            load: clock.t_load,
            network: u.network_seconds,
            eq6: u.eq6.as_ref().map_or(0.0, |e| e.seconds),
            render: made.render_seconds,
            composite: made.composite_seconds,
            write: 0.0,
            total: 0.0,
        },
        files: Vec::new(),
    }
}

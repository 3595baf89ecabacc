//! The plan: which shapes, materials and environments each split gets, every combination and
//! every sample, and how samples are grouped into shards. A pure function of the manifest, the
//! catalogue and the seed; nothing here renders. The deal itself is `deal.rs`.
//!
//! **Splits never share a shape or a material.** Shapes are dealt per category from a seeded
//! shuffle; materials are dealt by near-duplicate *group*, so variants of one material (the
//! library's `gold-polished` / `gold-brushed`, MERL's `paint` / `paint2`) can never sit on both
//! sides. Explicit id lists are checked for the same two rules.
//!
//! **Nor content.** Shapes, materials and dealt environments are fingerprinted first
//! (`content.rs`); identical (and, for shapes, near-duplicate) content forms one group, and
//! groups are dealt whole. Groups of one member are dealt exactly as single items were, so a
//! catalogue without duplicates gets the same deal as before fingerprints existed.

use super::catalogue::Catalogue;
use super::deal::{deal_envs, deal_materials, deal_shapes, stream_of};
use super::manifest::{
    GroundTruth, ManifestFile, MaterialsPerObject, RotationKind, SamplingMode, ShadowPolicy, TargetPolicy,
};
use crate::accel::Accel;
use matedit_assets::random::Draw;
use matedit_contract::manifest::{ManifestError, Named};
use matedit_physics::shading::Quality;
use serde::Serialize;
use std::collections::BTreeSet;

/// How the environment is turned per combination.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub enum RotationMode {
    /// Uniform in [0°, 360°).
    Random,
    /// Always 0°.
    None,
    /// Drawn from a list.
    List(Vec<f64>),
}

/// The settings every sample shares, validated.
#[derive(Clone, Debug, Serialize)]
pub struct Settings {
    /// Image side.
    pub resolution: usize,
    /// Environment rows (width is twice).
    pub env_rows: usize,
    /// Eq. 2 implementation.
    #[serde(serialize_with = "ser_quality")]
    pub quality: Quality,
    /// Shadow policy.
    pub shadows: ShadowPolicy,
    /// Which BRDF renders.
    pub ground_truth: GroundTruth,
    /// Ray-query backend (recorded only when not the default, so obvhs datasets keep their bytes).
    #[serde(skip_serializing_if = "is_obvhs")]
    pub accel: Accel,
    /// Preset azimuths.
    pub azimuths: usize,
    /// Camera elevation, degrees.
    pub elevation_deg: f64,
    /// Views per combination.
    pub views_per_combination: usize,
    /// Environment rotation.
    pub rotation: RotationMode,
    /// m_t = m (`false`: another material of the split).
    pub target_same: bool,
    /// One material per region.
    pub per_region: bool,
    /// Samples per shard.
    pub shard_size: usize,
}

fn is_obvhs(a: &Accel) -> bool {
    *a == Accel::Obvhs
}

fn ser_quality<S: serde::Serializer>(q: &Quality, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(match q {
        Quality::Exact => "exact",
        Quality::Fast => "fast",
        Quality::Zonal => "zonal",
    })
}

/// One (shape, material, environment) combination of a split.
#[derive(Clone, Debug, PartialEq)]
pub struct Combination {
    /// Index into the catalogue's shapes.
    pub shape: usize,
    /// Index into the catalogue's materials (region 0's material).
    pub material: usize,
    /// Index into the catalogue's environments.
    pub env: usize,
    /// Seed stream of every random choice inside the combination.
    pub stream: u64,
}

/// A split's membership and combinations.
#[derive(Clone, Debug)]
pub struct SplitPlan {
    /// Name.
    pub name: String,
    /// `train` or `test`.
    pub role: String,
    /// Catalogue indices of its shapes (sorted).
    pub shapes: Vec<usize>,
    /// Catalogue indices of its materials (sorted).
    pub materials: Vec<usize>,
    /// Catalogue indices of its environments (sorted).
    pub envs: Vec<usize>,
    /// Combinations in sample order.
    pub combinations: Vec<Combination>,
    /// Samples (combinations × views).
    pub samples: usize,
}

/// One shard: consecutive samples of one split.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShardRef {
    /// Position in the dataset's shard list (decides the worker).
    pub ordinal: usize,
    /// Split index.
    pub split: usize,
    /// Shard number within the split.
    pub number: usize,
    /// First sample index within the split.
    pub first: usize,
    /// Number of samples.
    pub len: usize,
}

impl ShardRef {
    /// Directory name, e.g. `train-00003`.
    pub fn name(&self, plan: &Plan) -> String {
        format!("{}-{:05}", plan.splits[self.split].name, self.number)
    }
}

/// The whole plan.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Dataset name.
    pub name: String,
    /// Seed.
    pub seed: u64,
    /// Validated settings.
    pub settings: Settings,
    /// Everything the sources provide.
    pub catalogue: Catalogue,
    /// Splits in manifest order.
    pub splits: Vec<SplitPlan>,
    /// Every shard, in order.
    pub shards: Vec<ShardRef>,
}

fn settings(mf: &ManifestFile) -> Result<Settings, ManifestError> {
    let m = &mf.manifest;
    let r = &m.render;
    let resolution = *r.resolution.get_ref();
    if !(8..=4096).contains(&resolution) {
        return Err(mf.invalid(
            r.resolution.span(),
            "render.resolution",
            format!("{resolution}: expected 8 to 4096"),
        ));
    }
    let env_res: crate::preview::EnvRes = r.env_resolution.get_ref().parse().map_err(|e: String| {
        mf.invalid(
            r.env_resolution.span(),
            "render.env_resolution",
            e.replace("--env-res ", ""),
        )
    })?;
    let env_rows = match env_res {
        crate::preview::EnvRes::Rows(h) if (4..=1024).contains(&h) => h,
        _ => {
            return Err(mf.invalid(
                r.env_resolution.span(),
                "render.env_resolution",
                "expected HxW with 4 ≤ H ≤ 1024 and W = 2H (the paper: 64x128)",
            ));
        }
    };
    let quality = mf.choice(&r.quality, "render.quality")?;
    let shadows = mf.choice(&r.shadows, "render.shadows")?;
    let ground_truth = mf.choice(&r.ground_truth, "render.ground_truth")?;
    let accel = mf.choice(&r.accel, "render.accel")?;
    if let Some(why) = accel.unavailable_reason() {
        return Err(mf.invalid(r.accel.span(), "render.accel", format!("\"{}\": {why}", accel.name())));
    }
    let v = &m.views;
    let azimuths = *v.azimuths.get_ref();
    if !(1..=3600).contains(&azimuths) {
        return Err(mf.invalid(v.azimuths.span(), "views.azimuths", "expected 1 to 3600"));
    }
    let per = *v.per_combination.get_ref();
    if per == 0 || per > azimuths {
        return Err(mf.invalid(
            v.per_combination.span(),
            "views.per_combination",
            format!("{per}: expected 1 to views.azimuths ({azimuths}); views are drawn without replacement"),
        ));
    }
    let elevation_deg = *v.elevation_deg.get_ref();
    if !(-89.0..=89.0).contains(&elevation_deg) {
        return Err(mf.invalid(v.elevation_deg.span(), "views.elevation_deg", "expected −89° to 89°"));
    }
    let rot = &m.environment_rotation;
    let rotation = match mf.choice(&rot.mode, "environment_rotation.mode")? {
        RotationKind::Random => RotationMode::Random,
        RotationKind::None => RotationMode::None,
        RotationKind::List => {
            if rot.values.is_empty() || rot.values.iter().any(|x| !x.is_finite()) {
                return Err(mf.invalid(
                    rot.mode.span(),
                    "environment_rotation.values",
                    "mode = \"list\" needs a non-empty list of finite angles",
                ));
            }
            RotationMode::List(rot.values.clone())
        }
    };
    if !matches!(rotation, RotationMode::List(_)) && !rot.values.is_empty() {
        return Err(mf.invalid(
            rot.mode.span(),
            "environment_rotation.values",
            "only used with mode = \"list\"",
        ));
    }
    let target_same = mf.choice(&m.target.policy, "target.policy")? == TargetPolicy::Same;
    let per_region = mf.choice(&m.multi_material.mode, "multi_material.mode")? == MaterialsPerObject::PerRegion;
    let shard_size = *m.dataset.shard_size.get_ref();
    if !(1..=100_000).contains(&shard_size) {
        return Err(mf.invalid(
            m.dataset.shard_size.span(),
            "dataset.shard_size",
            "expected 1 to 100000",
        ));
    }
    Ok(Settings {
        resolution,
        env_rows,
        quality,
        shadows,
        ground_truth,
        accel,
        azimuths,
        elevation_deg,
        views_per_combination: per,
        rotation,
        target_same,
        per_region,
        shard_size,
    })
}

impl Plan {
    /// Builds the plan; every impossible request is an error naming its field and line.
    pub fn new(mf: &ManifestFile, mut catalogue: Catalogue) -> Result<Plan, ManifestError> {
        let settings = settings(mf)?;
        let m = &mf.manifest;
        let seed = m.dataset.seed;
        if m.splits.is_empty() {
            return Err(mf.invalid(0..0, "splits", "at least one [[splits]] entry is needed"));
        }
        let mut names = BTreeSet::new();
        for (i, s) in m.splits.iter().enumerate() {
            let n = &s.get_ref().name;
            let ok = !n.is_empty() && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !ok {
                return Err(mf.invalid(
                    s.span(),
                    &format!("splits[{i}].name"),
                    format!("{n:?}: use letters, digits and _ (it names files)"),
                ));
            }
            if !names.insert(n.clone()) {
                return Err(mf.invalid(s.span(), &format!("splits[{i}].name"), format!("{n:?} is used twice")));
            }
        }
        let roles: Vec<String> = m
            .splits
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let s2 = s.get_ref();
                // `val` (validation while training) is dealt as `test` is: it shares no shape,
                // material or material group with a training split, nor with a test split.
                match s2.role.as_deref() {
                    Some(r @ ("train" | "val" | "test")) => Ok(r.to_string()),
                    Some(other) => Err(mf.invalid(
                        matedit_contract::manifest::key_span(mf.text(), s.span(), "role"),
                        &format!("splits[{i}].role"),
                        format!("{other:?}: expected train, val or test"),
                    )),
                    None if s2.name.starts_with("test") => Ok("test".into()),
                    None if s2.name.starts_with("val") => Ok("val".into()),
                    None => Ok("train".into()),
                }
            })
            .collect::<Result<_, _>>()?;
        let envs_dealt = m
            .splits
            .iter()
            .any(|s| s.get_ref().environments.is_some() || !s.get_ref().environment_ids.is_empty());
        super::content::analyse(mf, &mut catalogue, envs_dealt)?;
        let shapes = deal_shapes(mf, &catalogue, seed)?;
        let materials = deal_materials(mf, &catalogue, seed, &roles)?;
        let envs = deal_envs(mf, &catalogue, seed)?;

        let render: Option<Vec<String>> = match &m.dataset.render_splits {
            Some(list) => {
                for n in list.get_ref() {
                    if !names.contains(n) {
                        return Err(mf.invalid(
                            list.span(),
                            "dataset.render_splits",
                            format!("no split is named {n:?}"),
                        ));
                    }
                }
                Some(list.get_ref().clone())
            }
            None => None,
        };
        let mut splits = Vec::new();
        for (i, s) in m.splits.iter().enumerate() {
            let name = s.get_ref().name.clone();
            if render.as_ref().is_some_and(|r| !r.contains(&name)) {
                continue;
            }
            let (sh, ma, en) = (shapes[i].clone(), materials[i].clone(), envs[i].clone());
            let field = |f: &str| format!("splits[{i}].{f}");
            if sh.is_empty() {
                return Err(mf.invalid(s.span(), &field("shapes"), "the split has no shape"));
            }
            if ma.is_empty() {
                return Err(mf.invalid(s.span(), &field("materials"), "the split has no material"));
            }
            if en.is_empty() {
                return Err(mf.invalid(s.span(), &field("environments"), "the split has no environment"));
            }
            let needs_two = !settings.target_same || settings.per_region;
            if needs_two && ma.len() < 2 {
                return Err(mf.invalid(
                    s.span(),
                    &field("materials"),
                    "a random target material (or per-region materials) needs at least 2 materials in the split",
                ));
            }
            let combinations = combinations_of(mf, &catalogue, &name, &sh, &ma, &en, seed)?;
            let samples = combinations.len() * settings.views_per_combination;
            splits.push(SplitPlan {
                name,
                role: roles[i].clone(),
                shapes: sh,
                materials: ma,
                envs: en,
                combinations,
                samples,
            });
        }
        let mut shards = Vec::new();
        for (si, s) in splits.iter().enumerate() {
            for (number, first) in (0..s.samples).step_by(settings.shard_size).enumerate() {
                shards.push(ShardRef {
                    ordinal: shards.len(),
                    split: si,
                    number,
                    first,
                    len: settings.shard_size.min(s.samples - first),
                });
            }
        }
        Ok(Plan {
            name: m.dataset.name.clone(),
            seed,
            settings,
            catalogue,
            splits,
            shards,
        })
    }

    /// Total samples.
    pub fn samples(&self) -> usize {
        self.splits.iter().map(|s| s.samples).sum()
    }

    /// The catalogue indices of the materials that `splits` (indices into [`Plan::splits`])
    /// deal, sorted, each once.
    pub fn materials_of(&self, splits: impl IntoIterator<Item = usize>) -> Vec<usize> {
        let mut used: Vec<usize> = splits
            .into_iter()
            .flat_map(|s| self.splits[s].materials.iter().copied())
            .collect();
        used.sort_unstable();
        used.dedup();
        used
    }
}

fn combinations_of(
    mf: &ManifestFile,
    cat: &Catalogue,
    split: &str,
    shapes: &[usize],
    materials: &[usize],
    envs: &[usize],
    seed: u64,
) -> Result<Vec<Combination>, ManifestError> {
    let s = &mf.manifest.sampling;
    let mode = mf.choice(&s.mode, "sampling.mode")?;
    let mut out = Vec::new();
    if mode == SamplingMode::Cross {
        if s.combinations.is_some() {
            return Err(mf.invalid(
                s.mode.span(),
                "sampling.combinations",
                "only used with mode = \"sampled\"",
            ));
        }
        for &sh in shapes {
            for &ma in materials {
                for &en in envs {
                    let stream = stream_of(&[split, &cat.shapes[sh].id, &cat.materials[ma].id, &cat.envs[en].id]);
                    out.push(Combination {
                        shape: sh,
                        material: ma,
                        env: en,
                        stream,
                    });
                }
            }
        }
    } else {
        let n = s.combinations.as_ref().ok_or_else(|| {
            mf.invalid(
                s.mode.span(),
                "sampling.combinations",
                "mode = \"sampled\" needs a number of combinations per split",
            )
        })?;
        let mut d = Draw::new(seed, stream_of(&[split, "sampled"]));
        for k in 0..*n.get_ref() {
            let sh = shapes[d.int(0, shapes.len() - 1)];
            let ma = materials[d.int(0, materials.len() - 1)];
            let en = envs[d.int(0, envs.len() - 1)];
            out.push(Combination {
                shape: sh,
                material: ma,
                env: en,
                stream: stream_of(&[split, "sampled", &k.to_string()]),
            });
        }
    }
    Ok(out)
}

//! The dataset's material table: every catalogue material as its 108 DSBRDF parameters (the
//! labels m and m_t) and as the BRDF that renders it (the ground truth the manifest chose).
//!
//! Fits are stored in `DIR/materials/` (`ID.dsbrdf.json` plus `ID.fit.json` with the source
//! fingerprint, the assets' stored-fit format), so a resumed or repeated run fits nothing twice, and the dataset carries its
//! own labels. Fitting is deterministic (sequential Levenberg–Marquardt per material), so the
//! same manifest gives the same labels on any machine and thread count.

use super::catalogue::{MaterialItem, MaterialSource};
use super::manifest::GroundTruth;
use anyhow::{Context, Result};
use matedit_assets::materials::cache::{FIT_VERSION, Fingerprinted, store_fit, stored_fit};
use matedit_assets::materials::fit::fit_dsbrdf;
use matedit_physics::BrdfModel;
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::{MerlBrdf, NeuralBrdf};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;

/// A ready material.
#[derive(Clone, Debug)]
pub struct MaterialEntry {
    /// Catalogue id.
    pub id: String,
    /// Near-duplicate group.
    pub group: String,
    /// The 108 parameters (the label).
    pub dsbrdf: Dsbrdf,
    /// The BRDF that renders the pixels.
    pub render: BrdfModel,
    /// BRDF-space error of the fit (0 for DSBRDF files).
    pub fit_log_rmse: f64,
}

/// What `ID.fit.json` records.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
struct FitStamp {
    id: String,
    fingerprint: String,
    brdf_log_rmse: f64,
}

impl Fingerprinted for FitStamp {
    fn fingerprint(&self) -> &str {
        &self.fingerprint
    }
}

/// File-name form of an id (`library:gold-brushed` → `library_gold-brushed`).
pub fn file_stem(id: &str) -> String {
    id.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

fn fingerprint(item: &MaterialItem) -> String {
    match &item.source {
        MaterialSource::Analytic(spec) => format!("{FIT_VERSION}|{spec:?}"),
        MaterialSource::Dsbrdf(_) => "dsbrdf-file".into(),
        MaterialSource::Merl(p) => {
            let size = std::fs::metadata(p).map(|m| m.len()).unwrap_or(0);
            // Fits made while MERL lookups took the nearest bin must not be reused.
            format!("{FIT_VERSION}|merl-trilinear|{size}")
        }
        MaterialSource::Nbrdf(p) => {
            // The network's own bytes: a changed file is a changed material.
            let bytes = std::fs::read(p).unwrap_or_default();
            format!("{FIT_VERSION}|nbrdf|{}", blake3::hash(&bytes).to_hex())
        }
    }
}

fn source_model(item: &MaterialItem) -> Result<BrdfModel> {
    Ok(match &item.source {
        MaterialSource::Analytic(spec) => spec.build().with_context(|| item.id.clone())?,
        MaterialSource::Dsbrdf(p) => BrdfModel::Dsbrdf(Box::new(Dsbrdf::load(p)?)),
        MaterialSource::Merl(p) => BrdfModel::Measured(Arc::new(MerlBrdf::read(p)?)),
        MaterialSource::Nbrdf(p) => BrdfModel::Neural(Arc::new(NeuralBrdf::read(p)?)),
    })
}

/// The BRDF that renders `item`, if it is known without fitting anything (a stored fit in `dir`
/// with a matching fingerprint, a DSBRDF file, a measured ground truth): what `datagen plan`
/// can say about a material without doing `datagen run`'s work.
pub fn peek_render(dir: &Path, item: &MaterialItem, truth: GroundTruth) -> Option<BrdfModel> {
    if truth == GroundTruth::Measured || matches!(item.source, MaterialSource::Dsbrdf(_)) {
        return source_model(item).ok();
    }
    let (m, _) = stored_fit::<FitStamp>(dir, &file_stem(&item.id), &fingerprint(item))?;
    Some(BrdfModel::Dsbrdf(Box::new(m)))
}

fn prepare(dir: &Path, item: &MaterialItem, truth: GroundTruth) -> Result<MaterialEntry> {
    let stem = file_stem(&item.id);
    let fp = fingerprint(item);
    let cached = stored_fit::<FitStamp>(dir, &stem, &fp).map(|(m, s)| (m, s.brdf_log_rmse));
    let source = source_model(item)?;
    let (dsbrdf, err) = match cached {
        Some(c) => c,
        None => {
            let (m, err) = match (&item.source, &source) {
                (MaterialSource::Dsbrdf(_), BrdfModel::Dsbrdf(m)) => ((**m).clone(), 0.0),
                _ => fit_dsbrdf(&source),
            };
            let stamp = FitStamp {
                id: item.id.clone(),
                fingerprint: fp,
                brdf_log_rmse: err,
            };
            store_fit(dir, &stem, &m, &stamp)?;
            (m, err)
        }
    };
    let render = match truth {
        GroundTruth::Dsbrdf => BrdfModel::Dsbrdf(Box::new(dsbrdf.clone())),
        GroundTruth::Measured => source,
    };
    Ok(MaterialEntry {
        id: item.id.clone(),
        group: item.group.clone(),
        dsbrdf,
        render,
        fit_log_rmse: err,
    })
}

/// Prepares the materials with `needed[k]` (in parallel, fitting what is not stored yet), in
/// catalogue order; the others (provided by a source but dealt to no split) stay `None`.
/// `on_done` is called once per prepared material.
pub fn prepare_all(
    dir: &Path,
    items: &[MaterialItem],
    needed: &[bool],
    truth: GroundTruth,
    on_done: &(dyn Fn() + Sync),
) -> Result<Vec<Option<MaterialEntry>>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    items
        .par_iter()
        .zip(needed)
        .map(|(m, &need)| {
            if !need {
                return Ok(None);
            }
            let r = prepare(dir, m, truth).with_context(|| format!("material {}", m.id));
            on_done();
            r.map(Some)
        })
        .collect()
}

/// Which catalogue materials a plan's splits use.
pub fn needed(plan: &super::plan::Plan) -> Vec<bool> {
    let mut need = vec![false; plan.catalogue.materials.len()];
    for s in &plan.splits {
        for &m in &s.materials {
            need[m] = true;
        }
    }
    need
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_become_safe_file_names() {
        assert_eq!(file_stem("library:gold-brushed"), "library_gold-brushed");
        assert_eq!(file_stem("merl:a/b c"), "merl_a_b_c");
    }
}

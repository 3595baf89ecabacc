//! Fitted library materials on disk: `NAME.dsbrdf.json` (the material) and `NAME.fit.json`
//! (source, fingerprint, split and errors), refitted only when the source or the fitting
//! method changes (the fingerprint).

use super::fit::fit_and_report;
use super::library::{LibraryMaterial, Split, library};
use anyhow::{Context, Result};
use matedit_contract::io::write_atomically;
use matedit_physics::brdf::Dsbrdf;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Changes whenever the fitting method changes, invalidating every cached fit.
pub const FIT_VERSION: &str = "dsbrdf-fit-1";

/// What `NAME.fit.json` records.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct FitRecord {
    /// Material name.
    pub name: String,
    /// Family.
    pub family: String,
    /// Near-duplicate group.
    pub group: String,
    /// `train` or `test`.
    pub split: String,
    /// The source BRDF.
    pub source: String,
    /// Source + method fingerprint; a mismatch means refit.
    pub fingerprint: String,
    /// BRDF-space error of the fit.
    pub brdf_log_rmse: f64,
    /// Rendered relative RMSE per judging environment.
    pub rendered_rel_rmse: BTreeMap<String, f64>,
}

impl FitRecord {
    /// Mean rendered error over the environments.
    pub fn mean_rendered(&self) -> f64 {
        self.rendered_rel_rmse.values().sum::<f64>() / self.rendered_rel_rmse.len().max(1) as f64
    }
}

/// The fingerprint of a material's fit.
pub fn fingerprint(m: &LibraryMaterial) -> String {
    format!("{FIT_VERSION}|{:?}", m.spec)
}

/// Default cache directory: `$MATEDIT_MATERIALS`, else `out/materials`.
pub fn default_dir() -> PathBuf {
    std::env::var_os("MATEDIT_MATERIALS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("out/materials"))
}

fn read_record(dir: &Path, name: &str) -> Option<FitRecord> {
    serde_json::from_str(&std::fs::read_to_string(dir.join(format!("{name}.fit.json"))).ok()?).ok()
}

/// The cached record and fit of `m`, if both are there and up to date.
fn cached(dir: &Path, m: &LibraryMaterial) -> Option<(FitRecord, Dsbrdf)> {
    let rec = read_record(dir, &m.name)?;
    if rec.fingerprint != fingerprint(m) {
        return None;
    }
    let fit = Dsbrdf::load(&dir.join(format!("{}.dsbrdf.json", m.name))).ok()?;
    Some((rec, fit))
}

/// The cached fit of `m` if it is up to date.
pub fn load_cached(dir: &Path, m: &LibraryMaterial) -> Option<Dsbrdf> {
    cached(dir, m).map(|(_, fit)| fit)
}

fn fit_one(dir: &Path, m: &LibraryMaterial) -> Result<(FitRecord, bool)> {
    if let Some((rec, _)) = cached(dir, m) {
        return Ok((rec, false));
    }
    let source = m.spec.build().with_context(|| m.name.clone())?;
    let (fit, report) = fit_and_report(&source);
    let rec = FitRecord {
        name: m.name.clone(),
        family: m.family.to_string(),
        group: m.group.clone(),
        split: if m.split() == Split::Test { "test" } else { "train" }.into(),
        source: format!("{:?}", m.spec),
        fingerprint: fingerprint(m),
        brdf_log_rmse: report.brdf_log_rmse,
        rendered_rel_rmse: report.rendered.into_iter().collect(),
    };
    // Material first, record last: a record only exists next to a complete material.
    write_atomically(&dir.join(format!("{}.dsbrdf.json", m.name)), |t| {
        Ok(std::fs::write(t, fit.to_json())?)
    })?;
    let json = serde_json::to_string_pretty(&rec)?;
    write_atomically(&dir.join(format!("{}.fit.json", m.name)), |t| {
        Ok(std::fs::write(t, json)?)
    })?;
    Ok((rec, true))
}

/// Fits every library material whose cached fit is missing or stale, in parallel. Returns the
/// records in library order and how many were (re)fitted.
pub fn fit_library(dir: &Path, on_done: &(dyn Fn() + Sync)) -> Result<(Vec<FitRecord>, usize)> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let results: Vec<Result<(FitRecord, bool)>> = library()
        .par_iter()
        .map(|m| {
            let r = fit_one(dir, m);
            on_done();
            r
        })
        .collect();
    let mut records = Vec::new();
    let mut fitted = 0;
    for r in results {
        let (rec, new) = r?;
        fitted += new as usize;
        records.push(rec);
    }
    Ok((records, fitted))
}

/// Median rendered error over every (material, environment) pair.
pub fn median_rendered(records: &[FitRecord]) -> f64 {
    let mut all: Vec<f64> = records
        .iter()
        .flat_map(|r| r.rendered_rel_rmse.values().copied())
        .collect();
    all.sort_by(|a, b| a.total_cmp(b));
    all.get(all.len() / 2).copied().unwrap_or(0.0)
}

/// Writes `report.md`: every material's errors, the median and the worst cases.
pub fn write_report(dir: &Path, records: &[FitRecord]) -> Result<PathBuf> {
    use std::fmt::Write as _;
    let median = median_rendered(records);
    let envs: Vec<String> = records
        .first()
        .map(|r| r.rendered_rel_rmse.keys().cloned().collect())
        .unwrap_or_default();
    let mut s = format!(
        "# DSBRDF fits of the material library\n\n{} materials, fitting method `{FIT_VERSION}`. Rendered error: relative RMSE of a\n64² sphere rendered with the fit against the source BRDF. **Median rendered error: {:.2} %** (over all\nmaterials and environments).\n\n",
        records.len(),
        100.0 * median
    );
    let mut worst: Vec<&FitRecord> = records.iter().collect();
    worst.sort_by(|a, b| b.mean_rendered().total_cmp(&a.mean_rendered()));
    let _ = writeln!(
        s,
        "Worst five (mean over environments): {}\n",
        worst
            .iter()
            .take(5)
            .map(|r| format!("{} {:.2} %", r.name, 100.0 * r.mean_rendered()))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        s,
        "| material | family | split | BRDF log RMSE | {} |",
        envs.join(" | ")
    );
    let _ = writeln!(s, "|---|---|---|---|{}", "---|".repeat(envs.len()));
    for r in records {
        let errs: Vec<String> = r
            .rendered_rel_rmse
            .values()
            .map(|v| format!("{:.2} %", 100.0 * v))
            .collect();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.4} | {} |",
            r.name,
            r.family,
            r.split,
            r.brdf_log_rmse,
            errs.join(" | ")
        );
    }
    let path = dir.join("report.md");
    write_atomically(&path, |t| Ok(std::fs::write(t, s)?))?;
    Ok(path)
}

/// Resolves any `--brdf` spec, including `library:NAME` and `fit:NAME` (from the cache in
/// `dir` when up to date, otherwise fitted now without writing).
pub fn resolve(spec: &matedit_physics::BrdfSpec, dir: &Path) -> Result<matedit_physics::BrdfModel> {
    use matedit_physics::{BrdfModel, BrdfSpec};
    match spec {
        BrdfSpec::Library(name) => Ok(super::library::find(name)?.spec.build()?),
        BrdfSpec::Fit(name) => {
            let m = super::library::find(name)?;
            let fit = match load_cached(dir, &m) {
                Some(f) => f,
                None => super::fit::fit_dsbrdf(&m.spec.build()?).0,
            };
            Ok(BrdfModel::Dsbrdf(Box::new(fit)))
        }
        other => Ok(other.build()?),
    }
}

/// `datagen fit`: fits `spec` (resolved with the cache in `dir`), writes the material to `out`
/// and its errors to `out` with the extension `fit.json`, both atomically; returns the report
/// lines.
pub fn fit_to_file(spec: &matedit_physics::BrdfSpec, dir: &Path, out: &Path) -> Result<String> {
    let source = resolve(spec, dir)?;
    let t = std::time::Instant::now();
    let (m, report) = fit_and_report(&source);
    let rendered: Vec<String> = report
        .rendered
        .iter()
        .map(|(e, v)| format!("{e} {:.2}%", 100.0 * v))
        .collect();
    let mut lines = format!(
        "fit in {:.1} s: BRDF-space log RMSE {:.4}; rendered relative RMSE: {}\n",
        t.elapsed().as_secs_f64(),
        report.brdf_log_rmse,
        rendered.join(", ")
    );
    write_atomically(out, |tmp| Ok(std::fs::write(tmp, m.to_json())?))?;
    let json = serde_json::json!({
        "source": format!("{spec:?}"),
        "brdf_log_rmse": report.brdf_log_rmse,
        "rendered_rel_rmse": report.rendered.iter().map(|(e, v)| (e.clone(), *v)).collect::<BTreeMap<_, _>>(),
    });
    let report_path = out.with_extension("fit.json");
    write_atomically(&report_path, |tmp| Ok(std::fs::write(tmp, format!("{json:#}\n"))?))?;
    lines += &format!("wrote {} and {}\n", out.display(), report_path.display());
    Ok(lines)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cached_fits_are_reused_until_the_source_changes() {
        let dir = std::env::temp_dir().join(format!("matedit-cache-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let m = super::super::library::find("rubber-red").unwrap();
        let (rec, new) = fit_one(&dir, &m).unwrap();
        assert!(new);
        assert!(rec.mean_rendered() < 0.05, "{rec:?}");
        let (_, new) = fit_one(&dir, &m).unwrap();
        assert!(!new, "an up-to-date fit is not recomputed");
        let mut changed = m.clone();
        changed.spec = matedit_physics::BrdfSpec::Plastic {
            alpha: 0.5,
            albedo: [0.3, 0.04, 0.03],
        };
        assert!(
            load_cached(&dir, &changed).is_none(),
            "a changed source invalidates the fit"
        );
        let (_, new) = fit_one(&dir, &changed).unwrap();
        assert!(new);
        let fit = resolve(&"fit:rubber-red".parse().unwrap(), &dir).unwrap();
        assert!(matches!(fit, matedit_physics::BrdfModel::Dsbrdf(_)));
        let lib = resolve(&"library:gold-polished".parse().unwrap(), &dir).unwrap();
        assert!(matches!(lib, matedit_physics::BrdfModel::Ggx(_)));
        assert!(
            resolve(&"library:nope".parse().unwrap(), &dir)
                .unwrap_err()
                .to_string()
                .contains("no such material")
        );
    }
}

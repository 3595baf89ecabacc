//! Fitted materials on disk and any spec as a DSBRDF. A stored fit is two files, `STEM.dsbrdf.json`
//! (the material) and `STEM.fit.json` (a record with the source's fingerprint), written material
//! first, record last; it is reused only while the fingerprint matches, so a changed source or
//! fitting method refits. The library's cache (`out/materials`, [`fit_library`]) and a dataset's
//! material table (`DIR/materials/`) are both stored this way ([`stored_fit`], [`store_fit`]).

use super::fit::fit_and_report;
use super::library::{LibraryMaterial, Split, library};
use anyhow::{Context, Result};
use matedit_contract::io::write_atomically;
use matedit_physics::brdf::Dsbrdf;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

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

/// A fit record that names the fingerprint of what it was fitted from.
pub trait Fingerprinted: serde::de::DeserializeOwned {
    /// The source's fingerprint when the fit was made.
    fn fingerprint(&self) -> &str;
}

impl Fingerprinted for FitRecord {
    fn fingerprint(&self) -> &str {
        &self.fingerprint
    }
}

/// The fit stored in `dir` as `STEM.dsbrdf.json` with its record `STEM.fit.json`, when both are
/// readable and the record's fingerprint is `fingerprint`.
pub fn stored_fit<R: Fingerprinted>(dir: &Path, stem: &str, fingerprint: &str) -> Option<(Dsbrdf, R)> {
    let text = std::fs::read_to_string(dir.join(format!("{stem}.fit.json"))).ok()?;
    let record: R = serde_json::from_str(&text).ok()?;
    if record.fingerprint() != fingerprint {
        return None;
    }
    let fit = Dsbrdf::load(&dir.join(format!("{stem}.dsbrdf.json"))).ok()?;
    Some((fit, record))
}

/// Stores `fit` and its `record` in `dir` (see [`stored_fit`]): the material first, the record
/// last, each atomically, so a record only ever exists next to a complete material.
pub fn store_fit(dir: &Path, stem: &str, fit: &Dsbrdf, record: &impl Serialize) -> Result<()> {
    write_atomically(&dir.join(format!("{stem}.dsbrdf.json")), |t| {
        Ok(std::fs::write(t, fit.to_json())?)
    })?;
    let json = serde_json::to_string_pretty(record)?;
    write_atomically(&dir.join(format!("{stem}.fit.json")), |t| Ok(std::fs::write(t, json)?))
}

/// The cached record and fit of `m`, if both are there and up to date.
fn cached(dir: &Path, m: &LibraryMaterial) -> Option<(FitRecord, Dsbrdf)> {
    stored_fit::<FitRecord>(dir, &m.name, &fingerprint(m)).map(|(fit, rec)| (rec, fit))
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
    store_fit(dir, &m.name, &fit, &rec)?;
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

/// Resolves any `--brdf` spec, including `library:NAME` (the analytic model) and `fit:NAME`
/// (its DSBRDF fit, see [`dsbrdf_of`]).
pub fn resolve(spec: &matedit_physics::BrdfSpec, dir: &Path) -> Result<matedit_physics::BrdfModel> {
    use matedit_physics::{BrdfModel, BrdfSpec};
    match spec {
        BrdfSpec::Library(name) => Ok(super::library::find(name)?.spec.build()?),
        BrdfSpec::Fit(_) => Ok(BrdfModel::Dsbrdf(Box::new(dsbrdf_of(spec, dir)?.0))),
        other => Ok(other.build()?),
    }
}

/// How [`dsbrdf_of`] obtained a DSBRDF.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Obtained {
    /// The spec is a DSBRDF file.
    DsbrdfFile,
    /// A library material's up-to-date fit in the cache folder.
    CachedFit,
    /// A library material fitted before by this process.
    FittedEarlier,
    /// Fitted now.
    FittedNow,
}

impl Obtained {
    /// The words a report uses.
    pub fn describe(self) -> &'static str {
        match self {
            Obtained::DsbrdfFile => "dsbrdf file",
            Obtained::CachedFit => "cached fit",
            Obtained::FittedEarlier => "fitted earlier in this process",
            Obtained::FittedNow => "fitted now",
        }
    }
}

/// Any spec as a DSBRDF (what the rendering layer renders): a library material (`library:` or
/// `fit:`) from its up-to-date fit in `dir`, else fitted once per process (a long-lived server
/// fits each material once; nothing is written); a DSBRDF file as it is; any other spec fitted.
pub fn dsbrdf_of(spec: &matedit_physics::BrdfSpec, dir: &Path) -> Result<(Dsbrdf, Obtained)> {
    use matedit_physics::{BrdfModel, BrdfSpec};
    if let BrdfSpec::Library(name) | BrdfSpec::Fit(name) = spec {
        let m = super::library::find(name)?;
        if let Some(f) = load_cached(dir, &m) {
            return Ok((f, Obtained::CachedFit));
        }
        static FITTED: OnceLock<Mutex<HashMap<String, Dsbrdf>>> = OnceLock::new();
        let memo = FITTED.get_or_init(Default::default);
        if let Some(f) = memo.lock().ok().and_then(|m| m.get(name).cloned()) {
            return Ok((f, Obtained::FittedEarlier));
        }
        let (f, _) = super::fit::fit_dsbrdf(&m.spec.build()?);
        if let Ok(mut memo) = memo.lock() {
            memo.insert(name.clone(), f.clone());
        }
        return Ok((f, Obtained::FittedNow));
    }
    match spec.build()? {
        BrdfModel::Dsbrdf(d) => Ok((*d, Obtained::DsbrdfFile)),
        other => Ok((super::fit::fit_dsbrdf(&other).0, Obtained::FittedNow)),
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
        // Any spec as a DSBRDF, and how. The stored fit is `changed`'s, so `fit:rubber-red` above
        // was fitted in this process, and is not fitted again; once the cache is up to date, its
        // fit is the one given (fitting is deterministic: the same parameters).
        let rubber: matedit_physics::BrdfSpec = "library:rubber-red".parse().unwrap();
        let (earlier, how) = dsbrdf_of(&rubber, &dir).unwrap();
        assert_eq!(how, Obtained::FittedEarlier);
        assert!(
            fit_one(&dir, &m).unwrap().1,
            "refitted: the stored fit was another source's"
        );
        let (cached_fit, how) = dsbrdf_of(&rubber, &dir).unwrap();
        assert_eq!(how, Obtained::CachedFit);
        assert_eq!(cached_fit, Dsbrdf::load(&dir.join("rubber-red.dsbrdf.json")).unwrap());
        assert_eq!(cached_fit, earlier);
        let (fitted, how) = dsbrdf_of(&"lambert:0.2,0.5,0.1".parse().unwrap(), &dir).unwrap();
        assert_eq!(how, Obtained::FittedNow);
        let file = dir.join("own.dsbrdf.json");
        std::fs::write(&file, fitted.to_json()).unwrap();
        let spec = format!("dsbrdf:{}", file.display()).parse().unwrap();
        assert_eq!(dsbrdf_of(&spec, &dir).unwrap(), (fitted, Obtained::DsbrdfFile));
        // A record whose fingerprint does not match, or whose material is missing, is no fit.
        assert!(stored_fit::<FitRecord>(&dir, "rubber-red", "another source").is_none());
        std::fs::remove_file(dir.join("rubber-red.dsbrdf.json")).unwrap();
        assert!(stored_fit::<FitRecord>(&dir, "rubber-red", &fingerprint(&m)).is_none());
    }
}

//! `datagen plan` and `datagen run`: loading a manifest, locking the output, resuming, workers.

use super::catalogue::Catalogue;
use super::manifest::ManifestFile;
use super::materials::{needed, peek_render, prepare_all};
use super::plan::Plan;
use super::sample::{Renderer, ZonalStatus, encode};
use super::store::{join, plan_record, write_shard};
use anyhow::{Context, Result, bail};
use matedit_contract::layout::{read_plan, shard_done, shards_dir, write_plan};
use matedit_contract::lock::{Worker, lock_output};
use matedit_contract::progress::Progress;
use matedit_contract::records::GeneratorRecord;
use matedit_physics::BrdfModel;
use matedit_physics::shading::Quality;
use matedit_physics::shading::zonal::{ZonalPlan, ZonalRefusal};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A manifest, resolved and planned.
pub struct Loaded {
    /// The file.
    pub file: ManifestFile,
    /// The plan.
    pub plan: Plan,
}

/// Reads, resolves and plans a manifest; any problem names the file, line and field.
pub fn load(path: &Path) -> Result<Loaded> {
    load_with(path, &[])
}

/// [`load`] with `--set PATH=VALUE` overrides, applied after the manifest's `extends`.
pub fn load_with(path: &Path, sets: &[String]) -> Result<Loaded> {
    let file = ManifestFile::load(path, sets)?;
    let catalogue = Catalogue::resolve(&file)?;
    let plan = Plan::new(&file, catalogue)?;
    Ok(Loaded { file, plan })
}

/// Encoded bytes of the sample EXR per image pixel: `datagen run manifests/datasets/bench-256.toml`
/// writes 379,608 bytes per 256² sample in all (docs/PERFORMANCE.md), 5.2 per pixel once the
/// environment EXR and the records below are taken off. Estimates only.
pub const BYTES_PER_PIXEL_ESTIMATE: f64 = 5.2;

/// Encoded bytes of the camera-space environment EXR per 64×128 texel (31 to 34 KB per file in
/// the quickstart and bench-256 datasets). Estimates only.
pub const ENV_BYTES_PER_TEXEL_ESTIMATE: f64 = 4.0;
/// The sample's share of `shard.json` and `index.jsonl` (1.7 KB in the quickstart).
pub const RECORD_BYTES_ESTIMATE: f64 = 1_700.0;
/// Estimated seconds per sample on the reference machine (2 cores, both busy), DSBRDF ground
/// truth, no shadows: a fixed part plus a part per image pixel, from the measurements in
/// `docs/PERFORMANCE.md` (`zonal`: `datagen run` of `manifests/datasets/bench-256.toml` and of the 64²
/// quickstart; the others: `datagen bench` at 256², all of whose cost grows with the pixels).
/// Estimates only: shapes, materials and maps change it.
pub fn seconds_per_sample(quality: Quality, pixels: f64) -> f64 {
    let at_256 = 65536.0;
    match quality {
        // Part of a zonal sample's time does not grow with the image (environment spectra,
        // per-material tables, the environment file): interpolate between the two measured
        // rates, 170 samples/s at 64² and 37 at 256² (2026-11-24, afternoon, docs/PERFORMANCE.md; 42 at
        // 256² since the libdeflate EXR writer, kept at 37 as the cautious figure).
        Quality::Zonal => {
            let (t64, t256) = (1.0 / 170.0, 1.0 / 37.0);
            t64 + (t256 - t64) * (pixels - 4096.0) / (at_256 - 4096.0)
        }
        Quality::Fast => pixels / at_256 / 0.30,
        Quality::Exact => pixels / at_256 / 0.021,
    }
}

/// The run log's account of the `zonal` quality: which materials are shaded per pixel in every
/// sample, why, and what that costs.
pub fn zonal_log(report: &[(String, ZonalStatus)], resolution: usize) -> String {
    use std::fmt::Write;
    let pixels = (resolution * resolution) as f64;
    let ratio = seconds_per_sample(Quality::Fast, pixels) / seconds_per_sample(Quality::Zonal, pixels);
    let off: Vec<String> = report
        .iter()
        .filter_map(|(id, r)| r.as_ref().err().map(|e| format!("{id} ({e})")))
        .collect();
    let mut s = String::new();
    if !off.is_empty() {
        let _ = writeln!(
            s,
            "note: zonal: {} of {} materials are shaded per pixel (fast path) in every sample, about {ratio:.0}× the cost of a zonal shading at {resolution}²: {}",
            off.len(),
            report.len(),
            off.join(", ")
        );
    }
    s
}

/// What `datagen plan` can say of a material before its kernel is built: refused by lobe width
/// (or measured), or headed for the grid (rows from the widths; the run's check may refine them).
fn planned_status(brdf: &BrdfModel) -> ZonalStatus {
    match ZonalPlan::for_brdf(brdf) {
        ZonalPlan::Grid(g) => Ok(g.rows),
        ZonalPlan::Unresolved { rows_needed, max_rows } => Err(ZonalRefusal::TooSharp { rows_needed, max_rows }),
        ZonalPlan::Measured => Err(ZonalRefusal::Measured),
    }
}

/// Prints what a manifest would produce.
pub fn describe(l: &Loaded) -> String {
    use std::fmt::Write;
    let p = &l.plan;
    let st = &p.settings;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "dataset {:?} (seed {}), from {}",
        p.name,
        p.seed,
        l.file.path().display()
    );
    for note in &p.catalogue.substitutions {
        let _ = writeln!(s, "  note: {note}");
    }
    let _ = writeln!(
        s,
        "catalogue: {} shapes, {} materials, {} environments",
        p.catalogue.shapes.len(),
        p.catalogue.materials.len(),
        p.catalogue.envs.len()
    );
    // Merges change which items can go where, so each one is shown, with its reason.
    for m in &p.catalogue.merges {
        let _ = writeln!(
            s,
            "  merged {}s {} into one group: {}",
            m.kind,
            m.ids.join(" and "),
            m.reason
        );
    }
    for sp in &p.splits {
        let mut per_cat = std::collections::BTreeMap::<&str, usize>::new();
        for &k in &sp.shapes {
            *per_cat.entry(p.catalogue.shapes[k].category.as_str()).or_default() += 1;
        }
        let cats: Vec<String> = per_cat.iter().map(|(c, n)| format!("{n} {c}")).collect();
        let shards = p.shards.iter().filter(|r| p.splits[r.split].name == sp.name).count();
        let _ = writeln!(
            s,
            "split {:<8} shapes: {} ({}); materials: {}; environments: {}; combinations: {}; samples: {}; shards: {}",
            sp.name,
            sp.shapes.len(),
            cats.join(", "),
            sp.materials.len(),
            sp.envs.len(),
            sp.combinations.len(),
            sp.samples,
            shards
        );
    }
    let n = p.samples();
    let pixels = (st.resolution * st.resolution) as f64;
    let texels = (2 * st.env_rows * st.env_rows) as f64;
    let bytes =
        n as f64 * (pixels * BYTES_PER_PIXEL_ESTIMATE + texels * ENV_BYTES_PER_TEXEL_ESTIMATE + RECORD_BYTES_ESTIMATE);
    let secs = n as f64 * seconds_per_sample(st.quality, pixels);
    let _ = writeln!(
        s,
        "total: {n} samples in {} shards of up to {}; {}×{} images, {}×{} environment, quality {:?}, shadows {:?}, ground truth {:?}",
        p.shards.len(),
        st.shard_size,
        st.resolution,
        st.resolution,
        st.env_rows,
        2 * st.env_rows,
        st.quality,
        st.shadows,
        st.ground_truth
    );
    let _ = writeln!(
        s,
        "estimate: {} on disk, {} on 2 cores at the measured rate of this quality without shadows (docs/PERFORMANCE.md); scale by cores; shadows cost far more",
        human_bytes(bytes),
        human_duration(secs)
    );
    if st.quality == Quality::Zonal {
        // Which materials leave the zonal grid depends on their fits: report what is known
        // without fitting (the output's stored fits, DSBRDF files); `datagen run` logs the rest.
        let dir = Path::new(&l.file.manifest.dataset.output).join("materials");
        let need = needed(p);
        let known: Vec<(String, ZonalStatus)> = p
            .catalogue
            .materials
            .iter()
            .zip(&need)
            .filter(|(_, n)| **n)
            .filter_map(|(item, _)| {
                let brdf = peek_render(&dir, item, st.ground_truth)?;
                Some((item.id.clone(), planned_status(&brdf)))
            })
            .collect();
        let wanted = need.iter().filter(|&&n| n).count();
        s.push_str(&zonal_log(&known, st.resolution));
        if known.len() < wanted {
            let _ = writeln!(
                s,
                "zonal: {} materials are not fitted yet; `datagen run` checks them once fitted and logs any that leave the grid",
                wanted - known.len()
            );
        }
    }
    s
}

fn human_bytes(bytes: f64) -> String {
    if bytes < 1e9 {
        format!("{:.0} MB", bytes / 1e6)
    } else {
        format!("{:.1} GB", bytes / 1e9)
    }
}

fn human_duration(secs: f64) -> String {
    if secs < 120.0 {
        format!("{secs:.0} s")
    } else if secs < 7200.0 {
        format!("{:.0} min", secs / 60.0)
    } else {
        format!("{:.1} h", secs / 3600.0)
    }
}

/// Options of `datagen run`.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Overrides the manifest's output directory.
    pub out: Option<PathBuf>,
    /// Part of the job to render.
    pub worker: Worker,
    /// Show progress bars.
    pub progress: bool,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// Output directory.
    pub dir: PathBuf,
    /// Shards rendered now.
    pub rendered_shards: usize,
    /// Shards found complete from an earlier run.
    pub resumed_shards: usize,
    /// Samples rendered now.
    pub rendered_samples: usize,
    /// Seconds spent rendering shards.
    pub render_s: f64,
    /// Whether `index.jsonl` and `dataset.json` were written.
    pub joined: bool,
}

impl RunSummary {
    /// What `datagen run` reports when it ends: shards and samples rendered and their rate,
    /// and what was written (or, for one of several workers, how to join).
    pub fn report(&self, worker: Worker) -> String {
        let rate = if self.render_s > 0.0 {
            self.rendered_samples as f64 / self.render_s
        } else {
            0.0
        };
        let mut out = format!(
            "{}: rendered {} shards ({} samples, {:.1} samples/s), {} already complete\n",
            self.dir.display(),
            self.rendered_shards,
            self.rendered_samples,
            rate,
            self.resumed_shards
        );
        if self.joined {
            out += &format!(
                "wrote {} and {}\n",
                self.dir.join("index.jsonl").display(),
                self.dir.join("dataset.json").display()
            );
        } else {
            out += &format!(
                "worker {}/{} done; when every worker has finished: datagen join {}\n",
                worker.index,
                worker.count,
                self.dir.display()
            );
        }
        out
    }
}

fn bar(progress: bool, len: u64, what: &str) -> Progress {
    Progress::new(
        progress,
        len,
        what,
        "{msg} [{bar:40}] {pos}/{len} ({per_sec}), {elapsed} elapsed, ETA {eta}",
    )
}

/// Renders the shards of `worker` that are not complete yet; the whole job (one worker) then
/// joins the index. Rerunning after an interruption continues where it stopped.
pub fn run(l: &Loaded, opts: &RunOptions) -> Result<RunSummary> {
    let plan = &l.plan;
    let dir = opts
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(&l.file.manifest.dataset.output));
    let _lock = lock_output(&dir, opts.worker)?;
    let record = plan_record(plan, &l.file.manifest)?;
    if dir.join("plan.json").exists() {
        let old = read_plan(&dir)?;
        if old.manifest_hash != record.manifest_hash {
            bail!(
                "{} holds a dataset of another manifest ({} ≠ {}): choose another --out or delete it",
                dir.display(),
                old.manifest_hash,
                record.manifest_hash
            );
        }
        if old.generator != record.generator {
            let commit =
                |g: &Option<GeneratorRecord>| g.as_ref().map_or("an unrecorded build".into(), |g| g.commit.clone());
            eprintln!(
                "note: {} was planned by {}, this build is {}: plan.json keeps the first",
                dir.display(),
                commit(&old.generator),
                commit(&record.generator)
            );
        }
    } else {
        write_plan(&dir, &record)?;
    }
    std::fs::create_dir_all(shards_dir(&dir))?;

    let need = needed(plan);
    let mbar = bar(opts.progress, need.iter().filter(|&&n| n).count() as u64, "materials");
    let materials = prepare_all(
        &dir.join("materials"),
        &plan.catalogue.materials,
        &need,
        plan.settings.ground_truth,
        &|| mbar.inc(1),
    )?;
    mbar.finish_and_clear();

    let mine: Vec<_> = plan.shards.iter().filter(|s| opts.worker.owns(s.ordinal)).collect();
    let todo: Vec<_> = mine
        .iter()
        .filter(|s| !shard_done(&dir, &s.name(plan)))
        .copied()
        .collect();
    let resumed = mine.len() - todo.len();
    let samples: usize = todo.iter().map(|s| s.len).sum();
    let sbar = bar(opts.progress, samples as u64, "samples");
    let renderer = Renderer::new(plan, &materials);
    // Per-material set-up of the `zonal` quality, for every material the remaining shards' splits
    // deal (built in parallel now rather than one at a time on first use).
    let used = plan.materials_of(todo.iter().map(|s| s.split));
    let kbar = bar(
        opts.progress && plan.settings.quality == Quality::Zonal,
        used.len() as u64,
        "kernels",
    );
    renderer.prepare_zonal(&used, &|| kbar.inc(1))?;
    kbar.finish_and_clear();
    if plan.settings.quality == Quality::Zonal {
        eprint!(
            "{}",
            zonal_log(&renderer.zonal_report(&used)?, plan.settings.resolution)
        );
    }
    let t0 = Instant::now();
    // Shards in parallel as well as their samples: with one shard at a time, every shard's
    // slowest samples left the other threads idle at its end.
    todo.par_iter().try_for_each(|shard| {
        let produce = |index| encode(renderer.render(&plan.sample(shard.split, index))?);
        let indices = shard.first..shard.first + shard.len;
        write_shard(&dir, &shard.name(plan), indices, &produce, &|| sbar.inc(1))
            .with_context(|| format!("shard {}", shard.name(plan)))
    })?;
    sbar.finish_and_clear();
    let render_s = t0.elapsed().as_secs_f64();
    let joined = opts.worker.count == 1;
    if joined {
        join(&dir, &[], Some(&materials))?;
    }
    Ok(RunSummary {
        dir,
        rendered_shards: todo.len(),
        resumed_shards: resumed,
        rendered_samples: samples,
        render_s,
        joined,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_specs_parse_and_partition() {
        assert_eq!("3/16".parse::<Worker>(), Ok(Worker { index: 3, count: 16 }));
        assert!("16/16".parse::<Worker>().is_err());
        assert!("1/0".parse::<Worker>().is_err());
        assert!("x".parse::<Worker>().is_err());
        let ws: Vec<Worker> = (0..3).map(|i| Worker { index: i, count: 3 }).collect();
        for ordinal in 0..20 {
            assert_eq!(ws.iter().filter(|w| w.owns(ordinal)).count(), 1);
        }
    }

    #[test]
    fn a_second_run_on_the_same_output_is_refused() {
        let dir = std::env::temp_dir().join(format!("matedit-lock-{}", std::process::id()));
        let first = lock_output(&dir, Worker::ALL).unwrap();
        let e = lock_output(&dir, Worker::ALL).err().unwrap().to_string();
        assert!(e.contains("another datagen run"), "{e}");
        let e = lock_output(&dir, Worker { index: 0, count: 2 })
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("another worker layout"), "{e}");
        drop(first);
        assert!(lock_output(&dir, Worker::ALL).is_ok());
    }
}

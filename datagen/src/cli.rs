//! The `datagen` command line: the synthetic-dataset factory's commands over this library. The
//! binary's `main` only calls [`main`].

use crate::accel::Accel;
use crate::preview::{EnvRes, RenderOptions, Shadows, render};
use crate::shapes::UpAxis;
use anyhow::Result;
use clap::{Parser, Subcommand};
use matedit_contract::args::{count_in, finite_in};
use matedit_contract::lock::Worker;
use matedit_physics::BrdfSpec;
use matedit_physics::shading::Quality;
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "datagen",
    version,
    about = "Synthetic dataset factory for physically based material editing"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render one object under an environment map (preview and check renderer).
    Render(RenderArgs),
    /// Fit the 108-parameter DSBRDF to a BRDF (analytic, dsbrdf or merl) and report the error.
    Fit {
        /// The source: lambert:R,G,B | ggx:ALPHA:F0R,F0G,F0B | plastic:ALPHA:R,G,B | dsbrdf:PATH | merl:PATH | nbrdf:PATH (a MERL neural BRDF, *.nbrdf.json) | library:NAME.
        #[arg(long)]
        brdf: BrdfSpec,
        /// Output material file (JSON); the report goes beside it as FILE.fit.json.
        #[arg(long)]
        out: PathBuf,
    },
    /// Generate the embedded procedural assets as files, with contact sheets.
    #[command(subcommand)]
    Assets(AssetsCommand),
    /// Check a manifest and print what it would produce: counts per split, disk and time
    /// estimates. Renders nothing.
    Plan {
        /// The manifest (TOML).
        manifest: PathBuf,
        /// Override a manifest field, `PATH=VALUE` (e.g. `render.resolution=128`,
        /// `splits[test].materials=8`); repeatable, applied in order after `extends`.
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
    /// Render a manifest's dataset (resumable: a rerun continues where it stopped).
    Run {
        /// The manifest (TOML).
        manifest: PathBuf,
        /// Output directory (overrides the manifest's dataset.output).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Render only worker I of N's shards (for job arrays); then `datagen join`.
        #[arg(long, default_value = "0/1")]
        worker: Worker,
        /// Override a manifest field, `PATH=VALUE`, as for `datagen plan`; the dataset records
        /// the result (and a resumed run must be given the same).
        #[arg(long = "set", value_name = "PATH=VALUE")]
        sets: Vec<String>,
    },
    /// Join the shards of all workers into index.jsonl and dataset.json.
    Join {
        /// The dataset directory (holds plan.json).
        dir: PathBuf,
        /// Workers' output directories to gather shards from (when they did not share DIR).
        #[arg(long, num_args = 1..)]
        from: Vec<PathBuf>,
    },
    /// Check a dataset: checksums, schema, counts and split integrity (exit status 1 on any
    /// problem, each named).
    Verify {
        /// The dataset directory.
        dir: PathBuf,
        /// Also recompute every member's content fingerprint from this manifest's sources (the
        /// dataset's own manifest) and check the recorded ones and the split boundary with them.
        #[arg(long, value_name = "MANIFEST")]
        sources: Option<PathBuf>,
    },
    /// Write a contact sheet of samples (I, O, normals, mask, regions, environment).
    Inspect {
        /// The dataset directory.
        dir: PathBuf,
        /// Output PNG (default DIR/inspect.png).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Number of samples (rows; 1–10000), chosen to cover the most shapes, materials and
        /// environments.
        #[arg(long, default_value_t = 6, value_parser = count_in(1, 10_000))]
        samples: usize,
        /// Only samples of this split.
        #[arg(long)]
        split: Option<String>,
    },
    /// Write the dataset card, DIR/README.md (Hugging Face's form: licences, splits with counts,
    /// sources with origins, how it was made, how to load it), and DIR/inspect.png when missing.
    /// `datagen run` writes it too.
    Card {
        /// The dataset directory.
        dir: PathBuf,
    },
    /// Export a finished dataset in another form: `--webdataset OUT` writes WebDataset tar
    /// shards (one key per sample: ID.exr, ID.env.exr, ID.json), checksummed in OUT/shards.json;
    /// a rerun continues where a killed one stopped.
    Export {
        /// The dataset directory.
        dir: PathBuf,
        /// Output directory of the tar shards.
        #[arg(long, value_name = "OUT")]
        webdataset: PathBuf,
        /// Samples per shard at most (1–1000000).
        #[arg(long, default_value_t = 1000, value_parser = count_in(1, 1_000_000))]
        shard_samples: usize,
        /// Megabytes (MiB) per shard at most (1–1048576); a larger sample gets a shard alone.
        #[arg(long, default_value_t = 1024, value_parser = count_in(1, 1 << 20))]
        shard_mb: usize,
    },
    /// Speed against error of shading options on a manifest's own samples (nothing written).
    Bench {
        /// The manifest (TOML).
        manifest: PathBuf,
        /// Samples, spread over the plan (1–100000).
        #[arg(long, default_value_t = 8, value_parser = count_in(1, 100_000))]
        samples: usize,
        /// Reference the errors are measured against: a quality (exact, fast, zonal: the
        /// manifest's ground truth), or measured (every material's source BRDF itself, e.g. a
        /// MERL neural BRDF rather than its DSBRDF fit).
        #[arg(long, default_value = "exact")]
        reference: crate::dataset::bench::Shading,
        /// Options to time, comma-separated (the same names).
        #[arg(long, default_value = "zonal,fast", value_delimiter = ',')]
        options: Vec<crate::dataset::bench::Shading>,
        /// Override the image side (1–16384).
        #[arg(long, value_parser = count_in(1, 16_384))]
        res: Option<usize>,
        /// Also print every sample's error per option.
        #[arg(long)]
        per_sample: bool,
    },
}

#[derive(Subcommand)]
enum AssetsCommand {
    /// The material library: fit every material's DSBRDF (cached; refitted only when its source
    /// changes) and write DIR/report.md with every fit's errors.
    Materials {
        /// Cache and report directory (default: $MATEDIT_MATERIALS or out/materials).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Only list the materials (name, family, group, split) and exit.
        #[arg(long)]
        list: bool,
    },
    /// List the shapes of a source with their stable ids (id, category, path), sorted by id.
    ListShapes {
        /// A ShapeNet v2 tree (<synset>/<model_id>/models/model_normalized.obj).
        #[arg(long, conflicts_with = "folder")]
        shapenet: Option<PathBuf>,
        /// A folder of OBJ files (searched recursively).
        #[arg(long)]
        folder: Option<PathBuf>,
        /// Only this category (car, chair, sofa, monitor); for a folder, the category it holds.
        #[arg(long)]
        category: Option<crate::shapes::procedural::Category>,
    },
    /// Procedural shapes: COUNT seeds of each category (car, chair, sofa, monitor) as OBJ + MTL
    /// (one material per semantic region), plus shapes.png, a contact sheet with both regions
    /// coloured (one row per category).
    Shapes {
        #[command(flatten)]
        set: SeededSet,
    },
    /// Procedural environment maps: COUNT seeds of each family (sunsky, overcast, softbox,
    /// window) as EXR, plus envmaps.png, a tone-mapped contact sheet (one row per family).
    Envmaps {
        #[command(flatten)]
        set: SeededSet,
        /// Rows of each map (width is twice this).
        #[arg(long, default_value_t = 256)]
        height: usize,
    },
}

/// A set of seeded procedural assets: COUNT per kind from seed SEED, written to OUT.
#[derive(clap::Args)]
struct SeededSet {
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Assets per category or family.
    #[arg(long, default_value_t = 4)]
    count: usize,
    /// First seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

fn report_set(paths: &[PathBuf], out: &std::path::Path, sheet: &str) {
    eprintln!(
        "wrote {} files to {} (contact sheet: {})",
        paths.len(),
        out.display(),
        out.join(sheet).display()
    );
}

fn run_fit(spec: BrdfSpec, out: PathBuf) -> Result<()> {
    let dir = matedit_assets::materials::cache::default_dir();
    eprint!("{}", matedit_assets::materials::cache::fit_to_file(&spec, &dir, &out)?);
    Ok(())
}

fn run_assets(c: AssetsCommand) -> Result<()> {
    match c {
        AssetsCommand::ListShapes {
            shapenet,
            folder,
            category,
        } => {
            use crate::shapes::sources;
            let entries = match (shapenet, folder) {
                (Some(root), _) => sources::shapenet(&root, category.as_slice())?,
                (None, Some(dir)) => sources::folder(&dir, category)?,
                (None, None) => anyhow::bail!("give --shapenet DIR or --folder DIR"),
            };
            for e in &entries {
                println!("{}\t{}\t{}", e.id, e.category.map_or("-", |c| c.name()), e.spec);
            }
            eprintln!("{} shapes", entries.len());
        }
        AssetsCommand::Materials { out, list } => {
            use matedit_assets::materials::{cache, library};
            if list {
                for m in library::library() {
                    println!("{}\t{}\t{}\t{:?}", m.name, m.family, m.group, m.split());
                }
                return Ok(());
            }
            let dir = out.unwrap_or_else(cache::default_dir);
            let lib = library::library();
            let bar = matedit_contract::progress::Progress::new(
                true,
                lib.len() as u64,
                "fitting",
                "fitting [{bar:40}] {pos}/{len}, ETA {eta}",
            );
            let (records, fitted) = cache::fit_library(&dir, &|| bar.inc(1))?;
            bar.finish_and_clear();
            let report = cache::write_report(&dir, &records)?;
            eprintln!(
                "{} materials ({} fitted now, {} cached); median rendered error {:.2} %; report {}",
                records.len(),
                fitted,
                records.len() - fitted,
                100.0 * cache::median_rendered(&records),
                report.display()
            );
        }
        AssetsCommand::Shapes { set } => {
            let paths = crate::shapes::sets::write_category_set(&set.out, set.count, set.seed)?;
            report_set(&paths, &set.out, "shapes.png");
        }
        AssetsCommand::Envmaps { set, height } => {
            if height == 0 || height > 8192 {
                anyhow::bail!("--height {height}: expected 1 to 8192 rows");
            }
            let paths = matedit_assets::envmaps::write_family_set(&set.out, set.count, set.seed, height)?;
            report_set(&paths, &set.out, "envmaps.png");
        }
    }
    Ok(())
}

#[derive(clap::Args)]
struct RenderArgs {
    /// `sphere` (analytic unit sphere), `procedural:car|chair|sofa|monitor:SEED`, or an OBJ path.
    #[arg(long, default_value = "sphere")]
    shape: String,
    /// Object yaw about +y, degrees (−360–360).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_in(-360.0, 360.0))]
    yaw: f64,
    /// Object pitch about +x, degrees (−360–360; positive tips the top towards the camera).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true, value_parser = finite_in(-360.0, 360.0))]
    pitch: f64,
    /// Which axis of the mesh file points up (x, -x, y, -y, z, -z); it becomes +y.
    #[arg(long, default_value = "y")]
    up: UpAxis,
    /// Material: lambert:R,G,B | ggx:ALPHA:F0R,F0G,F0B | plastic:ALPHA:R,G,B | dsbrdf:PATH | merl:PATH | nbrdf:PATH
    /// | library:NAME (a library material's source BRDF) | fit:NAME (its fitted DSBRDF).
    #[arg(long)]
    brdf: BrdfSpec,
    /// Environment map: a .hdr or .exr file, or builtin:sky | builtin:studio | builtin:constant:V.
    #[arg(long)]
    env: String,
    /// Rotation of the environment about +y, degrees.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    env_rotation: f64,
    /// Environment resolution used for shading: HxW with W = 2H, or `full`.
    #[arg(long, default_value = "64x128")]
    env_res: EnvRes,
    /// Image side in pixels.
    #[arg(long, default_value_t = 256)]
    res: usize,
    /// Shadow rays towards every texel (meshes only; the sphere is convex).
    #[arg(long, default_value = "off")]
    shadows: Shadows,
    /// Eq. 2 implementation: fast (f32, vectorised), exact (f64 reference, slow), or zonal
    /// (convolution about the view axis; with shadows, the blocked light is taken off per pixel;
    /// materials it cannot resolve use fast); see docs/PERFORMANCE.md for their speed and error.
    #[arg(long, default_value = "fast")]
    quality: Quality,
    /// Ray queries: obvhs, or embree in a build with `--features embree`.
    #[arg(long, value_enum, default_value_t = Accel::Obvhs)]
    accel: Accel,
    /// Output EXR: R, G, B radiance, normal.X/Y/Z (camera space), mask and region id.
    #[arg(long)]
    out: PathBuf,
    /// Also write a tone-mapped PNG (exposure, clamp to [0, 1], sRGB; alpha = mask).
    #[arg(long)]
    png: Option<PathBuf>,
    /// Exposure multiplier for the PNG (1e-6–1e6).
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true, value_parser = finite_in(1e-6, 1e6))]
    exposure: f64,
    /// Also write the environment as used (rotated, resampled) as EXR.
    #[arg(long)]
    env_out: Option<PathBuf>,
}

fn run_render(a: RenderArgs) -> Result<()> {
    // The image is an EXR whatever the name: a `.png` name would hold EXR bytes no viewer opens.
    if let Some(ext) = a.out.extension().and_then(|e| e.to_str())
        && ["png", "jpg", "jpeg"].contains(&ext.to_ascii_lowercase().as_str())
    {
        anyhow::bail!(
            "--out {}: the render is written as EXR (radiance, normals, mask); name it .exr, and ask for a tone-mapped preview with --png FILE",
            a.out.display()
        );
    }
    let opts = RenderOptions {
        shape: a.shape,
        up: a.up,
        yaw_deg: a.yaw as f32,
        pitch_deg: a.pitch as f32,
        brdf: a.brdf,
        env: a.env,
        env_rotation_deg: a.env_rotation,
        env_res: a.env_res,
        res: a.res,
        shadows: a.shadows,
        quality: a.quality,
        progress: std::io::stderr().is_terminal(),
        accel: a.accel,
    };
    let r = render(&opts)?;
    r.write_exr(&a.out)?;
    if let Some(p) = &a.png {
        r.write_png(p, a.exposure as f32)?;
    }
    if let Some(p) = &a.env_out {
        r.write_env(p)?;
    }
    eprint!("{}", r.report(&opts));
    eprintln!("wrote {}", a.out.display());
    Ok(())
}

mod dataset {
    //! The dataset commands.
    use super::*;
    use crate::dataset::{inspect as ins, run as r, store, verify as v};

    pub fn plan(manifest: &std::path::Path, sets: &[String]) -> Result<()> {
        let l = r::load_with(manifest, sets)?;
        print!("{}", r::describe(&l));
        Ok(())
    }

    pub fn run(manifest: &std::path::Path, sets: &[String], out: Option<PathBuf>, worker: Worker) -> Result<()> {
        let l = r::load_with(manifest, sets)?;
        for note in &l.plan.catalogue.substitutions {
            eprintln!("note: {note}");
        }
        // A bar on a terminal, a plain line every MATEDIT_PROGRESS_SECS in a batch log.
        let opts = r::RunOptions {
            out,
            worker,
            progress: true,
        };
        let summary = r::run(&l, &opts)?;
        eprint!("{}", summary.report(worker));
        if summary.joined {
            let card = crate::dataset::card::write_card(&summary.dir)?;
            eprintln!("wrote {} (the dataset card)", card.display());
        }
        Ok(())
    }

    pub fn card(dir: &std::path::Path) -> Result<()> {
        let card = crate::dataset::card::write_card(dir)?;
        eprintln!(
            "wrote {} and {}",
            card.display(),
            dir.join(crate::dataset::card::SHEET).display()
        );
        Ok(())
    }

    pub fn export(dir: &std::path::Path, out: &std::path::Path, max_samples: usize, shard_mb: usize) -> Result<()> {
        use crate::dataset::webdataset::{Limits, RECORD, export};
        let limits = Limits {
            max_samples,
            max_bytes: shard_mb as u64 * (1 << 20),
        };
        let s = export(dir, out, limits, true)?;
        let samples: usize = s.record.splits.iter().map(|sp| sp.samples).sum();
        let tars: usize = s.record.splits.iter().map(|sp| sp.shards.len()).sum();
        eprintln!(
            "wrote {samples} samples in {tars} tar shards to {} ({} written now, {} finished before); record: {}",
            out.display(),
            s.written,
            s.resumed,
            out.join(RECORD).display()
        );
        Ok(())
    }

    pub fn join(dir: &std::path::Path, from: &[PathBuf]) -> Result<()> {
        let rec = store::join(dir, from, None)?;
        let total: usize = rec.counts.values().sum();
        eprintln!("{}: joined {total} samples ({:?})", dir.display(), rec.counts);
        let card = crate::dataset::card::write_card(dir)?;
        eprintln!("wrote {} (the dataset card)", card.display());
        Ok(())
    }

    pub fn verify(dir: &std::path::Path, sources: Option<&std::path::Path>) -> ExitCode {
        let report = matedit_contract::verify::verify(dir).and_then(|mut rep| {
            if let Some(m) = sources {
                rep.problems.extend(v::verify_sources(dir, m)?);
            }
            Ok(rep)
        });
        match report {
            Ok(rep) => {
                for p in &rep.problems {
                    println!("{p}");
                }
                if rep.ok() {
                    eprintln!(
                        "{}: OK ({} samples, {} files checked)",
                        dir.display(),
                        rep.samples,
                        rep.files
                    );
                    ExitCode::SUCCESS
                } else {
                    eprintln!("{}: {} problems", dir.display(), rep.problems.len());
                    ExitCode::FAILURE
                }
            }
            Err(e) => {
                eprintln!("error: {e:#}");
                ExitCode::FAILURE
            }
        }
    }

    pub fn inspect(dir: &std::path::Path, out: Option<PathBuf>, samples: usize, split: Option<String>) -> Result<()> {
        let out = out.unwrap_or_else(|| dir.join("inspect.png"));
        let ids = ins::inspect(dir, &out, samples, split.as_deref())?;
        eprintln!(
            "wrote {} ({} samples: {}; columns: {})",
            out.display(),
            ids.len(),
            ids.join(", "),
            ins::COLUMNS.join(", ")
        );
        Ok(())
    }
}

/// Runs the command line of this process's arguments.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(a) => run_render(a),
        Command::Assets(c) => run_assets(c),
        Command::Fit { brdf, out } => run_fit(brdf, out),
        Command::Plan { manifest, sets } => dataset::plan(&manifest, &sets),
        Command::Run {
            manifest,
            out,
            worker,
            sets,
        } => dataset::run(&manifest, &sets, out, worker),
        Command::Join { dir, from } => dataset::join(&dir, &from),
        Command::Verify { dir, sources } => return dataset::verify(&dir, sources.as_deref()),
        Command::Inspect {
            dir,
            out,
            samples,
            split,
        } => dataset::inspect(&dir, out, samples, split),
        Command::Card { dir } => dataset::card(&dir),
        Command::Export {
            dir,
            webdataset,
            shard_samples,
            shard_mb,
        } => dataset::export(&dir, &webdataset, shard_samples, shard_mb),
        Command::Bench {
            manifest,
            samples,
            reference,
            options,
            res,
            per_sample,
        } => crate::dataset::bench::bench_manifest(&manifest, samples, reference, &options, res, per_sample)
            .map(|table| print!("{table}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numeric_options_outside_their_ranges_are_refused_naming_the_option() {
        let render = [
            "datagen",
            "render",
            "--brdf",
            "lambert:0.5,0.5,0.5",
            "--env",
            "builtin:sky",
            "--out",
            "r.exr",
        ];
        for (option, value) in [
            ("--yaw", "NaN"),
            ("--yaw", "1e300"),
            ("--pitch", "inf"),
            ("--exposure", "-1"),
            ("--exposure", "NaN"),
            ("--exposure", "0"),
        ] {
            let e = Cli::try_parse_from(render.iter().chain(&[option, value]))
                .err()
                .unwrap_or_else(|| panic!("{option} {value} accepted"));
            assert!(e.to_string().contains(option), "{option} {value}: {e}");
        }
        assert!(Cli::try_parse_from(render.iter().chain(&["--yaw", "-90", "--exposure", "2"])).is_ok());
        for args in [
            &["datagen", "inspect", "d", "--samples", "0"][..],
            &["datagen", "bench", "m.toml", "--samples", "0"],
            &["datagen", "bench", "m.toml", "--res", "0"],
        ] {
            let e = Cli::try_parse_from(args)
                .err()
                .unwrap_or_else(|| panic!("{args:?} accepted"));
            assert!(e.to_string().contains(args[3]), "{args:?}: {e}");
        }
    }
}

//! The `matedit` command line: material editing of photos with a trained network (Sec. 3.4 of
//! the paper). The binary's `main` only calls [`main`].

use crate::light::estimate::LightEstimate;
use crate::light::relight::RelightLevel;
use crate::serve::{ServeConfig, serve};
use crate::target::parse_material_arg;
use crate::{Composite, EditRequest, Given, LevelFrom, Look, Pair, Range, edit, swap, transfer};
use anyhow::Result;
use clap::{Parser, Subcommand};
use matedit_contract::args::{count_in, finite_in};
use matedit_trainer::post_optimisation::Eq6Config;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "matedit",
    version,
    about = "Material editing of photos with a trained network"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Edit the material of the masked object in a photo: predict n', m', L', render it with the
    /// target material and put it back into the photo at its own resolution.
    #[command(after_help = "Examples:
  matedit edit --model out/train/quickstart --image car.jpg --mask car-mask.png \\
      --material library:gold-polished --out out/edit/
  matedit edit --model M --image car.out.png --material 1=library:oak --material 2=library:rubber-black \\
      --regions parts.png --out out/edit-parts/
  matedit edit --model M --image car.jpg --mask car-mask.png --relight sunset.hdr --out out/relit/
  matedit edit ... --eq6               # refine with Eq. 6 first (a = 1, b = 0.1: see --eq6-b)

Outputs (written only when every input is good): edited.png/.exr at the photo's resolution,
I, I', O' at the network's, n', L', m' as material.dsbrdf.json, sheet.png and report.json.")]
    Edit(EditArgs),
    /// Material transfer (Fig. 4): the material predicted from one photo's object rendered on
    /// another photo's object, under that photo's predicted light.
    #[command(after_help = "Example:
  matedit transfer --model out/train/quickstart --from a.jpg --from-mask a-mask.png \
      --to b.jpg --to-mask b-mask.png --out out/transfer/")]
    Transfer(TransferArgs),
    /// Material swap (Fig. 10): each photo's object with the other's predicted material, into
    /// OUT/a and OUT/b.
    #[command(after_help = "Example:
  matedit swap --model out/train/quickstart --a a.jpg --a-mask a-mask.png --b b.jpg --b-mask b-mask.png --out out/swap/")]
    Swap(SwapArgs),
    /// Material editing in the browser: a page to upload a photo and its mask (or paint it),
    /// pick a library material by its sphere or a photo to transfer from, optionally refine with
    /// Eq. 6 (live energy, cancellable), and see and download everything `edit` writes.
    #[command(after_help = "Example:
  matedit serve --model out/train/quickstart        # then open http://127.0.0.1:8080

Edits run one at a time through the same code as `matedit edit`; others wait in a bounded queue
and see their place. Uploads are checked by decoding them; nothing a request names reaches the
file system. Binds to 127.0.0.1 unless --bind says otherwise.")]
    Serve(ServeArgs),
}

// `matedit edit`'s arguments (its help is the variant's doc comment).
#[derive(clap::Args)]
struct EditArgs {
    /// A run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long)]
    model: PathBuf,
    /// The photo: PNG or JPEG (sRGB), EXR or HDR (linear).
    #[arg(long)]
    image: PathBuf,
    /// The object mask (any non-zero pixel is object; alpha where it has one). Default: the
    /// photo's alpha channel.
    #[arg(long)]
    mask: Option<PathBuf>,
    /// Region labels (grey levels 1..=N on the object) for per-region materials.
    #[arg(long)]
    regions: Option<PathBuf>,
    /// Target material: SPEC for every region, or K=SPEC for region K (repeatable). SPEC is
    /// anything `datagen render --brdf` takes: library:NAME, dsbrdf:FILE, merl:FILE,
    /// lambert:R,G,B, ggx:ALPHA:F0, plastic:ALPHA:R,G,B.
    #[arg(long = "material", value_parser = parse_material_arg)]
    materials: Vec<(Option<u8>, String)>,
    /// Also render the predicted material under another illumination (.hdr, .exr or
    /// builtin:NAME; its +z faces the camera), written as relit.png: composited by `ratio`
    /// unless --composite says (measured best for relighting, docs/PERFORMANCE.md).
    #[arg(long)]
    relight: Option<String>,
    /// What sets --relight's level: `light` scales the map to the mean radiance of the
    /// photo's light as the edit finds it (the object's exposure kept, its light and shade
    /// moved); `given` takes the map's values as radiance in the photo's linear units.
    #[arg(long, value_enum, default_value_t, requires = "relight")]
    relight_level: RelightLevel,
    /// The photo's own illumination when it is known (.hdr, .exr or builtin:NAME; its +z
    /// faces the camera): used instead of the predicted L', at the level that best explains
    /// the photo.
    #[arg(long)]
    light: Option<String>,
    /// What sets the light's level: `background` (the photo's surroundings, where enough of
    /// them is seen unclipped), `network` (the paper's: I' matches the photo), `given` (a
    /// --light map's own values, radiance in the photo's linear units) or `auto`
    /// (background with --light, network otherwise: the best measured).
    #[arg(long, value_enum, default_value_t = LevelFrom::default())]
    light_level: LevelFrom,
    /// What of the predicted L' to keep: `auto` keeps what the checkpoint reads from a
    /// picture (measured once, about 0.1 s, by a probe the first edit runs; report.json's
    /// light_estimate) and replaces the rest by its expectation (L' averaged around the
    /// vertical axis, its colour neutral); `network` keeps L' as the network gives it (the
    /// paper's), and runs no probe.
    #[arg(long, value_enum, default_value_t = LightEstimate::default())]
    light_estimate: LightEstimate,
    /// The photo's horizontal field of view in degrees (1–170), for the directions its
    /// background is seen along. Default: what the photo's EXIF 35 mm equivalent focal
    /// length gives, else 40.
    #[arg(long, value_parser = finite_in(1.0, 170.0), allow_negative_numbers = true)]
    fov: Option<f64>,
    /// The object's own material when it is known (a SPEC as --material takes, for every
    /// region): used instead of the predicted m', and the light's level becomes the one at
    /// which it explains the photo (a masked object does not tell its albedo from the light's
    /// brightness). Not with --eq6, which would change it.
    #[arg(long, conflicts_with = "optimize")]
    input_material: Option<String>,
    /// The object's normals when they are known (a depth sensor, a normal estimator): a map
    /// of the photo's size, EXR (channels X, Y, Z or R, G, B, as stored) or PNG ((n + 1) / 2),
    /// camera space (+x right, +y up, +z towards the camera). Used instead of the predicted
    /// n' at both resolutions; pixels without a usable normal keep n'. A map facing away from
    /// the camera (another convention) is refused.
    #[arg(long)]
    normals: Option<PathBuf>,
    /// How the render goes back into the photo. Default: `ratio` with --input-material,
    /// `detail` with --light (not with --light-level network), `structure` otherwise (the
    /// best measured for each, docs/PERFORMANCE.md).
    #[arg(long, value_enum)]
    composite: Option<Composite>,
    /// What the edited object's level is held to in an 8- or 16-bit photo: `photo` scales it
    /// down until no more of the object is above white than in the photo (at least 2 %) and
    /// brings what still is into range with its hue; `clip` keeps the rendered level and
    /// clips each channel at white. Default: `clip` with --input-material or --light (the
    /// level is known; not with --light-level network), `photo` otherwise
    /// (docs/PERFORMANCE.md, "The photo's range").
    #[arg(long, value_enum)]
    range: Option<Range>,
    /// Refine n', m', L' with the paper's post-optimisation (Eq. 6) first; `--optimize` is the
    /// same flag (its earlier name).
    #[arg(long = "eq6", visible_alias = "optimize")]
    optimize: bool,
    /// Eq. 6's weight a of the normal prior (0–1e6).
    #[arg(long, default_value_t = Eq6Config::default().a, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
    eq6_a: f64,
    /// Eq. 6's weight b of the light prior (0–1e6; the paper's 10 is for its units: see
    /// docs/PERFORMANCE.md).
    #[arg(long, default_value_t = Eq6Config::default().b, value_parser = finite_in(0.0, 1e6), allow_negative_numbers = true)]
    eq6_b: f64,
    /// Rounds of (light, material, normals) (1–100).
    #[arg(long, default_value_t = Eq6Config::default().rounds, value_parser = count_in(1, 100), allow_negative_numbers = true)]
    eq6_rounds: usize,
    /// L-BFGS iterations per property and round (1–1000).
    #[arg(long, default_value_t = Eq6Config::default().iterations, value_parser = count_in(1, 1000), allow_negative_numbers = true)]
    eq6_iterations: usize,
    /// Objects of more pixels run Eq. 6's alternation on every k-th pixel (0: never).
    #[arg(long, default_value_t = Eq6Config::default().coarse_pixels)]
    eq6_coarse_pixels: usize,
    /// The picture the edit should make, where it is known (the same object, view and light
    /// with the target material, e.g. a render): the edit and the unchanged photo are then
    /// scored against it (the paper's L2 and SSIM over the object), said and written to
    /// report.json's `truth`.
    #[arg(long)]
    truth: Option<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

// `matedit transfer`'s arguments (its help is the variant's doc comment).
#[derive(clap::Args)]
struct TransferArgs {
    /// A run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long)]
    model: PathBuf,
    /// The photo whose material is taken.
    #[arg(long)]
    from: PathBuf,
    /// Its mask (default: its alpha channel).
    #[arg(long)]
    from_mask: Option<PathBuf>,
    /// The photo whose object receives it.
    #[arg(long)]
    to: PathBuf,
    /// Its mask (default: its alpha channel).
    #[arg(long)]
    to_mask: Option<PathBuf>,
    /// The first object's own material when it is known (a SPEC, as `edit
    /// --input-material`): what is transferred instead of its m'.
    #[arg(long, conflicts_with = "optimize")]
    from_material: Option<String>,
    /// The receiving object's own material when it is known: it sets its light's level (as
    /// `edit --input-material`; the composite is then `ratio` unless --composite says).
    #[arg(long, conflicts_with = "optimize")]
    to_material: Option<String>,
    /// The first object's normals when they are known (a map of its photo, as `edit
    /// --normals`): used instead of its n' (they matter to its m' only with --optimize).
    #[arg(long)]
    from_normals: Option<PathBuf>,
    /// The receiving object's normals when they are known (as `edit --normals`): it is
    /// rendered with them instead of its n'.
    #[arg(long)]
    to_normals: Option<PathBuf>,
    #[command(flatten)]
    finish: Finish,
}

// `matedit swap`'s arguments (its help is the variant's doc comment).
#[derive(clap::Args)]
struct SwapArgs {
    /// A run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long)]
    model: PathBuf,
    /// The first photo.
    #[arg(long)]
    a: PathBuf,
    /// Its mask (default: its alpha channel).
    #[arg(long)]
    a_mask: Option<PathBuf>,
    /// The second photo.
    #[arg(long)]
    b: PathBuf,
    /// Its mask (default: its alpha channel).
    #[arg(long)]
    b_mask: Option<PathBuf>,
    /// The first object's own material when it is known (a SPEC, as `edit
    /// --input-material`): the second receives it, and it sets the first's light's level.
    #[arg(long, conflicts_with = "optimize")]
    a_material: Option<String>,
    /// The second object's own material when it is known (the same, the other way).
    #[arg(long, conflicts_with = "optimize")]
    b_material: Option<String>,
    /// The first object's normals when they are known (a map of its photo, as `edit
    /// --normals`): it is rendered with them instead of its n'.
    #[arg(long)]
    a_normals: Option<PathBuf>,
    /// The second object's normals when they are known (the same, the other way).
    #[arg(long)]
    b_normals: Option<PathBuf>,
    #[command(flatten)]
    finish: Finish,
}

// `matedit serve`'s arguments (its help is the variant's doc comment).
#[derive(clap::Args)]
struct ServeArgs {
    /// A run folder (its latest checkpoint) or a checkpoint folder.
    #[arg(long)]
    model: PathBuf,
    /// Port (0: any free one, printed).
    #[arg(long, default_value_t = 8080)]
    port: u16,
    /// Address to listen on (e.g. 0.0.0.0 for every interface).
    #[arg(long, default_value = "127.0.0.1")]
    bind: std::net::IpAddr,
    /// Edits that may wait beyond the running one (1–1024: an edit waits in the queue
    /// until the worker takes it).
    #[arg(long, default_value_t = 8, value_parser = count_in(1, 1024))]
    queue: usize,
    /// Largest upload in MB (photo, mask and transfer photo together; 1–4096).
    #[arg(long, default_value_t = 32, value_parser = count_in(1, 4096))]
    max_upload_mb: usize,
    /// Largest photo in megapixels (0.01–1000).
    #[arg(long, default_value_t = 25.0, value_parser = finite_in(0.01, 1000.0), allow_negative_numbers = true)]
    max_megapixels: f64,
    /// Finished edits whose files are kept for download (1–10000).
    #[arg(long, default_value_t = 32, value_parser = count_in(1, 10000), allow_negative_numbers = true)]
    keep: usize,
    /// The most disk the kept edits may use together, in MB (1–1000000); the oldest go
    /// first.
    #[arg(long, default_value_t = 2048, value_parser = count_in(1, 1_000_000), allow_negative_numbers = true)]
    keep_mb: usize,
    /// The most memory the edits in the server may need together, in MB (256–1000000),
    /// estimated from each photo's size before it is decoded; a photo that needs more is
    /// refused, others wait for memory (within --upload-seconds).
    #[arg(long, default_value_t = 4096, value_parser = count_in(256, 1_000_000), allow_negative_numbers = true)]
    max_memory_mb: usize,
    /// Folder for uploads and outputs (default: a temporary one, removed on exit).
    #[arg(long)]
    work: Option<PathBuf>,
    /// A host name the server answers to besides IP addresses and localhost (repeatable):
    /// requests naming any other host are refused, which stops DNS rebinding.
    #[arg(long = "allow-host", value_parser = host_name)]
    allow_hosts: Vec<String>,
    /// Seconds a client may take to send an upload whole (1–3600). Uploads also have to
    /// keep to 8 KiB/s after their first 5 s, or are closed (408): stalled clients hold
    /// nothing another upload waits for.
    #[arg(long, default_value_t = 60, value_parser = count_in(1, 3600), allow_negative_numbers = true)]
    upload_seconds: usize,
}

/// What `transfer` and `swap` take after their two photos.
#[derive(clap::Args)]
struct Finish {
    /// Refine both photos' predictions with Eq. 6 first.
    #[arg(long)]
    optimize: bool,
    /// How the render goes back into the photo. Default: `ratio` where every receiving object's
    /// own material is given, `structure` otherwise (the best measured for each).
    #[arg(long, value_enum)]
    composite: Option<Composite>,
    /// What the edited object's level is held to (as `edit --range`). Default: `clip` where
    /// every receiving object's own material is given, `photo` otherwise.
    #[arg(long, value_enum)]
    range: Option<Range>,
    /// What of each photo's predicted L' to keep (as `edit --light-estimate`).
    #[arg(long, value_enum, default_value_t = LightEstimate::default())]
    light_estimate: LightEstimate,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

fn host_name(s: &str) -> Result<String, String> {
    match crate::serve::guard::host_of(s) {
        Some(h) if h == s.trim().to_ascii_lowercase() => Ok(h),
        _ => Err(format!("{s:?} is not a host name (give it without a port or scheme)")),
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Edit(args) => edit_command(args),
        Command::Transfer(args) => transfer_command(args),
        Command::Swap(args) => swap_command(args),
        Command::Serve(args) => serve_command(args),
    }
}

/// `matedit serve`.
fn serve_command(args: ServeArgs) -> Result<()> {
    let ServeArgs {
        model,
        port,
        bind,
        queue,
        max_upload_mb,
        max_megapixels,
        keep,
        keep_mb,
        max_memory_mb,
        work,
        allow_hosts,
        upload_seconds,
    } = args;
    let mut cfg = ServeConfig::new(model);
    cfg.port = port;
    cfg.bind = bind;
    cfg.queue = queue;
    cfg.max_upload_bytes = max_upload_mb.saturating_mul(1 << 20);
    cfg.max_pixels = (max_megapixels * 1e6) as u64;
    cfg.keep = keep;
    cfg.keep_bytes = keep_mb as u64 * (1 << 20);
    cfg.max_memory_mb = max_memory_mb as u64;
    cfg.work = work;
    cfg.allow_hosts = allow_hosts;
    cfg.deadlines.upload = std::time::Duration::from_secs(upload_seconds as u64);
    serve(cfg)
}

impl EditArgs {
    /// The edit these options ask for.
    fn request(&self) -> EditRequest {
        EditRequest {
            photo: self.image.clone(),
            mask: self.mask.clone(),
            regions: self.regions.clone(),
            materials: self.materials.clone(),
            relight: self.relight.clone(),
            relight_level: self.relight_level,
            light: self.light.clone(),
            light_level: self.light_level,
            light_estimate: self.light_estimate,
            fov_deg: self.fov,
            composite: self.composite,
            range: self.range,
            input_material: self.input_material.clone(),
            normals: self.normals.clone(),
            optimize: self.optimize.then(|| Eq6Config {
                a: self.eq6_a,
                b: self.eq6_b,
                rounds: self.eq6_rounds,
                iterations: self.eq6_iterations,
                coarse_pixels: self.eq6_coarse_pixels,
                ..Eq6Config::default()
            }),
        }
    }
}

/// `matedit edit`.
fn edit_command(args: EditArgs) -> Result<()> {
    let req = args.request();
    let report = edit(&args.model, &req, &args.out)?;
    if let Some(t) = &args.truth {
        let s = crate::truth::score(&req.photo, args.mask.as_deref(), t, &args.out)?;
        crate::truth::add_to_report(&args.out, &s)?;
        say!("{}", s.line());
    }
    say_edit(&report, &args.out);
    Ok(())
}

/// What `matedit edit` says of an edit it wrote into `out`.
fn say_edit(report: &crate::EditReport, out: &Path) {
    if let Some(o) = &report.orientation {
        say!("{}", o.line());
    }
    if let Some(line) = report.light_estimate.as_ref().and_then(|e| e.describe()) {
        let eq6 = if report.eq6.is_some() {
            " (Eq. 6 started from it)"
        } else {
            ""
        };
        say!("{line}{eq6}");
    }
    for r in report.range.iter().filter(|r| r.applied) {
        say!(
            "{}: held to the photo's range: × {:.2} ({:.0} % of the object was above white as rendered; --range clip keeps it)",
            r.image,
            r.scale,
            100.0 * r.rendered_share_above_white
        );
    }
    if let Some(e) = &report.eq6 {
        say!(
            "Eq. 6: E {:.4e} → {:.4e} ({:.0} % lower) in {:.2} s, {} L-BFGS iterations (energy.png)",
            e.start.total,
            e.end.total,
            100.0 * (1.0 - e.end.total / e.start.total.max(1e-300)),
            e.seconds,
            e.steps.len()
        );
    }
    say!(
        "{}: edited in {:.2} s (network {:.2} s, rendering layer {:.2} s); {} files, report.json",
        out.display(),
        report.seconds.total,
        report.seconds.network,
        report.seconds.render,
        report.files.len() + 1
    );
}

/// One photo of `transfer` or `swap` and what its options say of its object.
fn given<'a>(
    photo: &'a Path,
    mask: &'a Option<PathBuf>,
    material: &'a Option<String>,
    normals: &'a Option<PathBuf>,
    light_estimate: LightEstimate,
) -> Given<'a> {
    Given {
        material: material.as_deref(),
        normals: normals.as_deref(),
        light_estimate,
        ..Given::photo(photo, mask.as_deref())
    }
}

impl Finish {
    /// The two photos with what these options say of the result; `known`: every receiving
    /// object's own material is given.
    fn pair<'a>(&self, photos: [Given<'a>; 2], eq6: Option<&'a Eq6Config>, known: bool) -> Pair<'a> {
        let [first, second] = photos;
        Pair {
            first,
            second,
            eq6,
            look: Look::chosen(self.composite, self.range, known),
        }
    }
}

/// `matedit transfer`.
fn transfer_command(args: TransferArgs) -> Result<()> {
    let f = &args.finish;
    let cfg = f.optimize.then(Eq6Config::default);
    let le = f.light_estimate;
    let from = given(&args.from, &args.from_mask, &args.from_material, &args.from_normals, le);
    let to = given(&args.to, &args.to_mask, &args.to_material, &args.to_normals, le);
    let known = args.to_material.is_some();
    let r = transfer(&args.model, f.pair([from, to], cfg.as_ref(), known), &f.out)?;
    say!(
        "{}: transferred in {:.2} s; report.json",
        f.out.display(),
        r.seconds.total
    );
    Ok(())
}

/// `matedit swap`.
fn swap_command(args: SwapArgs) -> Result<()> {
    let f = &args.finish;
    let cfg = f.optimize.then(Eq6Config::default);
    let le = f.light_estimate;
    let a = given(&args.a, &args.a_mask, &args.a_material, &args.a_normals, le);
    let b = given(&args.b, &args.b_mask, &args.b_material, &args.b_normals, le);
    let known = args.a_material.is_some() && args.b_material.is_some();
    let [_, rb] = swap(&args.model, f.pair([a, b], cfg.as_ref(), known), &f.out)?;
    say!(
        "{}: swapped in {:.2} s; a/ and b/ with report.json each",
        f.out.display(),
        rb.seconds.total
    );
    Ok(())
}

/// Runs the command line of this process's arguments.
pub fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
#[path = "cli_tests.rs"]
mod tests;

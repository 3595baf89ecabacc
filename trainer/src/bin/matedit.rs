//! `matedit`: material editing of photos with a trained network (Sec. 3.4 of the paper).

use anyhow::Result;
use clap::{Parser, Subcommand};
use matedit_trainer::edit::target::parse_material_arg;
use matedit_trainer::edit::{Composite, EditRequest, edit};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "matedit", version, about = "Material editing of photos with a trained network")]
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

Outputs (written only when every input is good): edited.png/.exr at the photo's resolution,
I, I', O' at the network's, n', L', m' as material.dsbrdf.json, sheet.png and report.json.")]
    Edit {
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
        /// builtin:NAME; its +z faces the camera).
        #[arg(long)]
        relight: Option<String>,
        /// How the render goes back into the photo.
        #[arg(long, value_enum, default_value_t = Composite::Render)]
        composite: Composite,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
    },
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Edit {
            model,
            image,
            mask,
            regions,
            materials,
            relight,
            composite,
            out,
        } => {
            let req = EditRequest {
                photo: image,
                mask,
                regions,
                materials,
                relight,
                composite,
            };
            let report = edit(&model, &req, &out)?;
            println!(
                "{}: edited in {:.2} s (network and layer {:.2} s); {} files, report.json",
                out.display(),
                report.seconds.total,
                report.seconds.predict_and_render,
                report.files.len() + 1
            );
            Ok(())
        }
    }
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

//! # matedit-edit
//!
//! Material editing of a photo (Sec. 3.4 and Fig. 2 applied to a real picture). An edit goes
//! through these stages, each a module, in order:
//!
//! 1. [`photo`]: the photo, its mask and region labels read and checked ([`photo::read`]), then
//!    framed for the network ([`prepare`]);
//! 2. [`predict`]: the network's n', m' per region and L' ([`model`] loads it);
//! 3. [`light`]: what of L' is kept ([`light::estimate`]), what is known instead (a given light,
//!    the object's own material, a normal map: [`normals`]), and the light's level
//!    ([`light::background`], [`light::LevelSource`]);
//! 4. [`detail`]: n' carried to the photo's resolution;
//! 5. [`eq6`]: the post-optimisation of Eq. 6, when asked for;
//! 6. [`finish`]: I' = R(n', m', L') and the edit O' = R(n', m_t, L') with the target material
//!    m_t (or R(n', m', L_new) under another light, Fig. 4: [`light::relight`]), composited into
//!    the photo ([`composite`]) and held to its range ([`range`]), as [`look`] chooses;
//! 7. [`output`]: every file written, after all of them succeeded, so a bad input writes nothing.
//!
//! [`understand`] runs stages 1–5 and [`finish`] 6–7. [`edit`] (a [`request`]), and
//! [`transfer`](fn@transfer) and [`swap`] ([`transfer`](mod@transfer), Fig. 4 and Fig. 10), go
//! through them; [`serve`] is the editing web page over the same functions; [`cli`] is their
//! command line, the `matedit` binary; [`truth`] scores an edit against the picture it should
//! make. The network, the rendering layer and Eq. 6 ([`matedit_trainer::post_optimisation`]) come
//! from the trainer; target materials by name ([`target`]) from the material library, fitted on
//! the fly.

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

pub mod blur;
pub mod cli;
pub mod composite;
pub mod detail;
pub mod eq6;
pub mod finish;
pub mod light;
pub mod look;
pub mod model;
pub mod normals;
pub mod output;
pub mod photo;
pub mod predict;
pub mod progress;
pub mod range;
pub mod request;
pub mod serve;
pub mod target;
#[cfg(test)]
mod tests;
pub mod transfer;
pub mod truth;
pub mod understand;

pub use composite::Composite;
pub use eq6::Eq6Report;
pub use finish::{Clock, Edit, finish};
pub use light::relight::Relight;
pub use light::{LevelFrom, LevelSource, LightOptions, known_material, light_at_own_level, light_at_photo_level};
pub use look::Look;
pub use model::{Model, load_model};
pub use output::EditReport;
pub use photo::read::{ReadPhoto, read_photo};
pub use photo::{Prepared, prepare, prepare_framed};
pub use predict::{Predicted, network_prediction, render_all};
pub use progress::Watch;
pub use range::Range;
pub use request::EditRequest;
pub use transfer::{Given, Pair, swap, transfer, transfer_with};
pub use understand::{Understanding, Understood, understand};

use anyhow::Result;
use matedit_physics::brdf::Dsbrdf;
use std::path::Path;

/// Reads the inputs, edits, and writes every output into `out` (see [`output`]). Nothing is
/// written when any input is bad.
pub fn edit(model: &Path, req: &EditRequest, out: &Path) -> Result<EditReport> {
    let watch = Watch::unwatched();
    // Before the model's load, so that a bad request costs nothing.
    request::check_request(req, out)?;
    edit_with(&Model::load(model)?, req, out, watch)
}

/// [`edit`] with a loaded model (what `matedit serve` runs for every request), its phases and
/// Eq. 6's energies shown to `watch`: the stages in order.
pub fn edit_with(model: &Model, req: &EditRequest, out: &Path, watch: Watch) -> Result<EditReport> {
    request::check_request(req, out)?;
    watch.enter("reading")?;
    let read = read_photo(&req.photo, req.mask.as_deref(), req.regions.as_deref())?;
    let regions = read.labels.as_ref().map_or(1, |l| l.1);
    let targets: Vec<(Dsbrdf, target::RegionTarget)> =
        target::resolve_targets(&req.materials, regions, req.regions.as_deref())?
            .into_iter()
            .map(|t| (t.material, t.record))
            .collect();
    let env_height = model.state.net.env_height;
    let relight = req
        .relight
        .as_ref()
        .map(|spec| Relight::read(spec, req.relight_level, env_height))
        .transpose()?;
    let light = request::light_options(req, &read, env_height)?;
    let clock = Clock::inputs_read(watch);
    let how = Understanding {
        light: &light,
        eq6: req.optimize.as_ref(),
    };
    let u = understand(model, read, how, watch)?;
    let look = Look::for_known(
        req.composite,
        req.range,
        light.input_material.is_some(),
        light.light_known(&u.light_level),
    );
    let edit = Edit {
        targets: &targets,
        relight,
        light_spec: req.light.as_deref(),
        look,
    };
    finish(model, u, &edit, out, clock)
}

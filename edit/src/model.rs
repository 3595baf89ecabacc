//! The trained network an edit runs: a checkpoint folder (or a run folder's latest), its
//! rendering layer, and what its L' reads from a picture.

use crate::light;
use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use matedit_trainer::model::network::Net;
use matedit_trainer::rendering_layer::RenderingLayer;
use matedit_trainer::train::checkpoint;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The network of a checkpoint folder, or of a run folder's latest checkpoint.
pub fn load_model(path: &Path) -> Result<(Net, checkpoint::State, PathBuf)> {
    let dir = if path.join("latest.json").is_file() {
        checkpoint::latest(path)?.with_context(|| format!("{}: no checkpoint yet", path.display()))?
    } else {
        path.to_path_buf()
    };
    if !dir.join("state.json").is_file() {
        bail!(
            "{}: not a checkpoint folder (no state.json) nor a run folder (no latest.json)",
            path.display()
        );
    }
    let (net, state) =
        checkpoint::load_net(&dir, &Device::flex()).with_context(|| format!("checkpoint {}", dir.display()))?;
    Ok((net, state, dir))
}

/// A loaded network and what it was trained for.
pub struct Model {
    /// The network.
    pub net: Net,
    /// Its checkpoint's state (shape).
    pub state: checkpoint::State,
    /// The checkpoint folder.
    pub dir: PathBuf,
    /// A rendering layer for its environment size.
    pub layer: RenderingLayer,
    /// What its L' reads from a picture ([`light_estimate`]), measured when first asked.
    pub(crate) light_skill: OnceLock<light::estimate::LightSkill>,
}

impl Model {
    /// [`load_model`] and its layer.
    pub fn load(path: &Path) -> Result<Self> {
        let (net, state, dir) = load_model(path)?;
        let layer = RenderingLayer::new(state.net.env_height);
        let light_skill = OnceLock::new();
        Ok(Self {
            net,
            state,
            dir,
            layer,
            light_skill,
        })
    }

    /// What its L' reads from a picture, measured once ([`light::estimate::LightSkill::measure`]).
    pub fn light_skill(&self) -> Result<light::estimate::LightSkill> {
        if let Some(s) = self.light_skill.get() {
            return Ok(*s);
        }
        let (size, h) = (self.state.net.input_size, self.state.net.env_height);
        let s = light::estimate::LightSkill::measure(&self.net, size, h).with_context(|| {
            format!(
                "checkpoint {}: the light probe (--light-estimate network does without it)",
                self.dir.display()
            )
        })?;
        Ok(*self.light_skill.get_or_init(|| s))
    }
}

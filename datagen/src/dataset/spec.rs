//! One sample, fully described before anything is rendered (as Kubric describes a scene): the
//! shape, the environment and its rotation, the view, the regions and each region's material
//! m and target m_t. Every random choice of a sample is made here, from its combination's seed
//! stream in a fixed order (environment rotation, the views, then per-region materials and
//! targets), so all views of a combination agree and a sample never depends on which thread or
//! worker renders it. The renderer ([`super::sample::Renderer`]) renders a description and
//! decides nothing.

use super::plan::{Plan, RotationMode, SplitPlan};
use matedit_assets::random::Draw;

/// A sample of the plan, with every choice made.
#[derive(Clone, Debug, PartialEq)]
pub struct SampleSpec {
    /// Split (index into the plan's splits).
    pub split: usize,
    /// Index within the split.
    pub index: usize,
    /// `SPLIT-NNNNNNN`.
    pub id: String,
    /// Shape (index into the catalogue).
    pub shape: usize,
    /// Environment (index into the catalogue).
    pub env: usize,
    /// Rotation of the environment about +y, degrees.
    pub env_rotation_deg: f64,
    /// Camera azimuth, degrees.
    pub view_azimuth_deg: f64,
    /// Camera elevation, degrees.
    pub view_elevation_deg: f64,
    /// Region names: the shape's regions with `multi_material = "per_region"`, else one.
    pub regions: Vec<String>,
    /// Material m per region (indices into the catalogue).
    pub materials: Vec<usize>,
    /// Target material m_t per region.
    pub targets: Vec<usize>,
}

impl Plan {
    /// Describes sample `index` of split `split`.
    pub fn sample(&self, split: usize, index: usize) -> SampleSpec {
        let st = &self.settings;
        let sp: &SplitPlan = &self.splits[split];
        let combo = &sp.combinations[index / st.views_per_combination];
        let slot = index % st.views_per_combination;
        let mut draw = Draw::new(self.seed, combo.stream);
        let rotation = match &st.rotation {
            RotationMode::Random => draw.uniform(0.0, 360.0),
            RotationMode::None => 0.0,
            RotationMode::List(v) => v[draw.int(0, v.len() - 1)],
        };
        // Partial Fisher–Yates: the first `per_combination` of a shuffled list of azimuths.
        let mut views: Vec<usize> = (0..st.azimuths).collect();
        for i in 0..st.views_per_combination {
            let j = draw.int(i, st.azimuths - 1);
            views.swap(i, j);
        }
        let azimuth = views[slot] as f64 * 360.0 / st.azimuths as f64;

        let regions = if st.per_region {
            self.catalogue.shapes[combo.shape].regions.clone()
        } else {
            vec!["object".into()]
        };
        let pick_other = |draw: &mut Draw, not: usize| -> usize {
            let others: Vec<usize> = sp.materials.iter().copied().filter(|&m| m != not).collect();
            if others.is_empty() {
                not
            } else {
                others[draw.int(0, others.len() - 1)]
            }
        };
        let mut materials = vec![combo.material];
        for _ in 1..regions.len() {
            let m = pick_other(&mut draw, combo.material);
            materials.push(m);
        }
        let targets: Vec<usize> = materials
            .iter()
            .map(|&m| if st.target_same { m } else { pick_other(&mut draw, m) })
            .collect();
        SampleSpec {
            split,
            index,
            id: format!("{}-{index:07}", sp.name),
            shape: combo.shape,
            env: combo.env,
            env_rotation_deg: rotation,
            view_azimuth_deg: azimuth,
            view_elevation_deg: st.elevation_deg,
            regions,
            materials,
            targets,
        }
    }
}

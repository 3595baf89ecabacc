//! Material targets: raw DSBRDF files ↔ the network's normalised 108-vectors.

use anyhow::{Context, Result, bail};
use matedit_physics::brdf::Dsbrdf;
use matedit_physics::brdf::dsbrdf::PARAMS;
use std::path::Path;

/// The normalised target of a material file (what the material module is trained towards).
pub fn normalised_target(material: &Path) -> Result<[f64; PARAMS]> {
    Ok(Dsbrdf::load(material)?.to_normalised())
}

/// A material from a network prediction: a JSON array of 108 numbers in the tanh range.
/// Values beyond ±1 are clamped; NaN is an error naming the index.
pub fn material_from_prediction(prediction: &Path) -> Result<Dsbrdf> {
    let text = std::fs::read_to_string(prediction).with_context(|| format!("cannot read {}", prediction.display()))?;
    let v: Vec<f64> = serde_json::from_str(&text)
        .with_context(|| format!("{}: expected a JSON array of numbers", prediction.display()))?;
    if v.len() != PARAMS {
        bail!("{}: expected {PARAMS} values, got {}", prediction.display(), v.len());
    }
    Dsbrdf::from_normalised(&v).with_context(|| prediction.display().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn target_and_prediction_round_trip_through_files() {
        let d = std::env::temp_dir().join(format!("matedit-trainer-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let m = Dsbrdf::near_lambertian([0.3, 0.6, 0.9]);
        std::fs::write(d.join("m.json"), m.to_json()).unwrap();
        let t = normalised_target(&d.join("m.json")).unwrap();
        assert!(t.iter().all(|x| (-0.95..=0.95).contains(x)));
        std::fs::write(d.join("p.json"), serde_json::to_string(&t.to_vec()).unwrap()).unwrap();
        let back = material_from_prediction(&d.join("p.json")).unwrap();
        for (a, b) in back.params().iter().zip(m.params()) {
            assert!((a - b).abs() <= 1e-9 * b.abs());
        }
        std::fs::write(d.join("short.json"), "[0.1, 0.2]").unwrap();
        assert!(
            material_from_prediction(&d.join("short.json"))
                .unwrap_err()
                .to_string()
                .contains("expected 108")
        );
        std::fs::write(d.join("bad.json"), "{}").unwrap();
        assert!(
            material_from_prediction(&d.join("bad.json"))
                .unwrap_err()
                .to_string()
                .contains("bad.json")
        );
    }
}

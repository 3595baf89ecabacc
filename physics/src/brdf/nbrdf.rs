//! MERL's measured materials as neural BRDFs (Sztrajman et al., "Neural BRDF Representation and
//! Importance Sampling", CGF 2021): the `nbrdf:FILE` spec, a `*.nbrdf.json` file holding a
//! 6 → 21 → 21 → 3 perceptron per material (the format of `eval-assets/brdfs/merl-nbrdf/`).
//!
//! The network reads the Rusinkiewicz half/difference angles as MERL's own reader forms them
//! ([`directions_to_half_diff`]): x = (sin θ_h, 0, cos θ_h, sin θ_d cos φ_d, sin θ_d sin φ_d,
//! cos θ_d); a1 = relu(x·W1 + b1), a2 = relu(a1·W2 + b2), y = a2·W3 + b3; f_r = max(eᵞ − 1, 0)
//! per RGB channel, per steradian. It was fitted only to pairs with both directions above the
//! surface, so below it the BRDF is 0, as every [`Brdf`] here. The weights are float32 values;
//! they are evaluated in f64.

use super::Brdf;
use super::merl::directions_to_half_diff;
use glam::DVec3;
use std::path::Path;

/// The one format this reader takes.
pub const FORMAT: &str = "nbrdf-mlp-v1";
/// The network's inputs, in order, as the files name them.
pub const INPUTS: [&str; 6] = [
    "sin(theta_h)",
    "0",
    "cos(theta_h)",
    "sin(theta_d)cos(phi_d)",
    "sin(theta_d)sin(phi_d)",
    "cos(theta_d)",
];
/// The activations after each layer.
pub const ACTIVATIONS: [&str; 3] = ["relu", "relu", "exp_minus_1_clamped_at_0"];
/// Widths of the layers: inputs, two hidden layers, RGB.
const WIDTHS: [usize; 4] = [6, 21, 21, 3];
/// Largest value returned (1/sr). MERL's brightest entries are in the thousands; a network
/// evaluated far from its training range could overflow, and no Inf may reach an image.
pub const MAX_VALUE: f64 = 1e6;

/// A `*.nbrdf.json` file that cannot be used, naming the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum NbrdfError {
    /// The file could not be read.
    #[error("cannot read neural BRDF {path}: {cause}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        cause: std::io::Error,
    },
    /// Not JSON, or not the expected structure (serde's message names line and column).
    #[error("{path}: {cause}")]
    Json {
        /// File.
        path: String,
        /// Cause.
        cause: serde_json::Error,
    },
    /// A field with the wrong value or shape.
    #[error("{path}: {field}: {message}")]
    Field {
        /// File.
        path: String,
        /// JSON path of the field, e.g. `layers[1].weight[4]`.
        field: String,
        /// What is wrong.
        message: String,
    },
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    format: String,
    name: String,
    input: Vec<String>,
    activations: Vec<String>,
    layers: Vec<Layer>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Layer {
    weight: Vec<Vec<f64>>,
    bias: Vec<f64>,
}

/// One material's network.
#[derive(Clone, Debug, PartialEq)]
pub struct NeuralBrdf {
    /// The material's name (`name` in the file).
    pub name: String,
    /// Per layer: weights row-major `in × out`, then biases.
    layers: [(Vec<f64>, Vec<f64>); 3],
}

impl NeuralBrdf {
    /// Reads and checks a `*.nbrdf.json` file.
    pub fn read(path: &Path) -> Result<Self, NbrdfError> {
        let bytes = std::fs::read(path).map_err(|cause| NbrdfError::Io {
            path: path.display().to_string(),
            cause,
        })?;
        Self::from_json(&bytes, &path.display().to_string())
    }

    /// Parses and checks the file's bytes; `origin` names it in errors.
    pub fn from_json(bytes: &[u8], origin: &str) -> Result<Self, NbrdfError> {
        let file: File = serde_json::from_slice(bytes).map_err(|cause| NbrdfError::Json {
            path: origin.to_string(),
            cause,
        })?;
        let field = |field: String, message: String| NbrdfError::Field {
            path: origin.to_string(),
            field,
            message,
        };
        if file.format != FORMAT {
            return Err(field("format".into(), format!("{:?} is not {FORMAT:?}", file.format)));
        }
        if file.input != INPUTS {
            return Err(field("input".into(), format!("{:?}, expected {INPUTS:?}", file.input)));
        }
        if file.activations != ACTIVATIONS {
            return Err(field(
                "activations".into(),
                format!("{:?}, expected {ACTIVATIONS:?}", file.activations),
            ));
        }
        if file.layers.len() != 3 {
            return Err(field(
                "layers".into(),
                format!("{} layers, expected 3", file.layers.len()),
            ));
        }
        let mut layers: [(Vec<f64>, Vec<f64>); 3] = Default::default();
        for (l, layer) in file.layers.into_iter().enumerate() {
            let (rows, cols) = (WIDTHS[l], WIDTHS[l + 1]);
            if layer.weight.len() != rows {
                return Err(field(
                    format!("layers[{l}].weight"),
                    format!("{} rows, expected {rows} (stored in × out)", layer.weight.len()),
                ));
            }
            let mut w = Vec::with_capacity(rows * cols);
            for (r, row) in layer.weight.iter().enumerate() {
                if row.len() != cols {
                    return Err(field(
                        format!("layers[{l}].weight[{r}]"),
                        format!("{} values, expected {cols}", row.len()),
                    ));
                }
                w.extend_from_slice(row);
            }
            if layer.bias.len() != cols {
                return Err(field(
                    format!("layers[{l}].bias"),
                    format!("{} values, expected {cols}", layer.bias.len()),
                ));
            }
            // serde_json reads no NaN or infinity from JSON text, but a number beyond f64's range
            // would not parse either; magnitudes are bounded so that the network stays finite.
            if let Some(v) = w.iter().chain(&layer.bias).find(|v| v.abs() > 1e6) {
                return Err(field(format!("layers[{l}]"), format!("value {v} is beyond ±1e6")));
            }
            layers[l] = (w, layer.bias);
        }
        Ok(Self {
            name: file.name,
            layers,
        })
    }

    /// The network's output y (before eʸ − 1) for the half/difference angles. Evaluated per
    /// texel and pixel on the exact path, so on the stack.
    pub fn log_value(&self, th: f64, td: f64, pd: f64) -> [f64; 3] {
        let x = [
            th.sin(),
            0.0,
            th.cos(),
            td.sin() * pd.cos(),
            td.sin() * pd.sin(),
            td.cos(),
        ];
        // out = b + input·W (W row-major in × out), then relu where asked.
        fn dense(input: &[f64], (w, b): &(Vec<f64>, Vec<f64>), relu: bool, out: &mut [f64]) {
            let cols = b.len();
            out.copy_from_slice(b);
            for (i, &xi) in input.iter().enumerate() {
                for (o, wv) in out.iter_mut().zip(&w[i * cols..(i + 1) * cols]) {
                    *o += xi * wv;
                }
            }
            if relu {
                out.iter_mut().for_each(|v| *v = v.max(0.0));
            }
        }
        let (mut a1, mut a2, mut y) = ([0.0; WIDTHS[1]], [0.0; WIDTHS[2]], [0.0; WIDTHS[3]]);
        dense(&x, &self.layers[0], true, &mut a1);
        dense(&a1, &self.layers[1], true, &mut a2);
        dense(&a2, &self.layers[2], false, &mut y);
        y
    }

    /// A file of this format whose weights are `weight(layer, row, column)` and biases
    /// `bias(layer, column)`: synthetic networks for tests and fixtures.
    pub fn json_of(
        name: &str,
        weight: impl Fn(usize, usize, usize) -> f64,
        bias: impl Fn(usize, usize) -> f64,
    ) -> String {
        let layers: Vec<serde_json::Value> = (0..3)
            .map(|l| {
                let w: Vec<Vec<f64>> = (0..WIDTHS[l])
                    .map(|r| (0..WIDTHS[l + 1]).map(|c| weight(l, r, c)).collect())
                    .collect();
                let b: Vec<f64> = (0..WIDTHS[l + 1]).map(|c| bias(l, c)).collect();
                serde_json::json!({ "weight": w, "bias": b })
            })
            .collect();
        serde_json::json!({
            "format": FORMAT, "name": name, "input": INPUTS, "activations": ACTIVATIONS, "layers": layers
        })
        .to_string()
    }
}

impl Brdf for NeuralBrdf {
    fn eval(&self, wi: DVec3, wo: DVec3) -> [f64; 3] {
        if !(wi.z > 0.0 && wo.z > 0.0 && wi.is_finite() && wo.is_finite()) {
            return [0.0; 3];
        }
        let (th, _, td, pd) = directions_to_half_diff(wi, wo);
        self.log_value(th, td, pd).map(|y| {
            let f = y.exp_m1().max(0.0);
            if f.is_finite() { f.min(MAX_VALUE) } else { 0.0 }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::brdf::testing;

    /// A file of the format with every weight and bias set by `value(layer, index)`.
    pub(crate) fn file_with(value: impl Fn(usize, usize) -> f64) -> String {
        NeuralBrdf::json_of(
            "test",
            |l, r, c| value(l, r * WIDTHS[l + 1] + c),
            |l, c| value(l, 1000 + c),
        )
    }

    /// Hand-computed: with W1 = 0 and b1 = 1 every hidden unit of layer 1 is 1; with W2 = 0.1 and
    /// b2 = 0, each of layer 2 is 2.1; with W3 = 0.01, b3 = (0, 0.1, −1): y = 0.441 + b3.
    #[test]
    fn a_hand_computed_network_gives_its_values_at_any_angles() {
        let text = file_with(|l, i| match (l, i >= 1000) {
            (0, false) => 0.0,
            (0, true) => 1.0,
            (1, false) => 0.1,
            (1, true) => 0.0,
            (2, false) => 0.01,
            (_, true) => [0.0, 0.1, -1.0][i - 1000],
            _ => unreachable!(),
        });
        let b = NeuralBrdf::from_json(text.as_bytes(), "hand").unwrap();
        let want = [0.441f64, 0.541, -0.559].map(|y| y.exp_m1().max(0.0));
        for (wi, wo) in [
            (DVec3::Z, DVec3::Z),
            (DVec3::new(0.6, 0.0, 0.8), DVec3::new(-0.28, 0.96, 0.0001)),
        ] {
            let got = b.eval(wi.normalize(), wo.normalize());
            for c in 0..3 {
                assert!((got[c] - want[c]).abs() < 1e-6, "{got:?} vs {want:?}");
            }
        }
        assert_eq!(want[2], 0.0, "max(eʸ − 1, 0) clamps");
    }

    #[test]
    fn below_the_surface_and_non_finite_directions_give_zero() {
        let b = NeuralBrdf::from_json(file_with(|_, _| 0.5).as_bytes(), "t").unwrap();
        assert_eq!(b.eval(DVec3::new(0.0, 0.6, -0.8), DVec3::Z), [0.0; 3]);
        assert_eq!(b.eval(DVec3::Z, DVec3::new(1.0, 0.0, 0.0)), [0.0; 3]);
        assert_eq!(b.eval(DVec3::new(f64::NAN, 0.0, 1.0), DVec3::Z), [0.0; 3]);
        assert_eq!(b.eval(DVec3::Z, DVec3::new(0.0, f64::INFINITY, 1.0)), [0.0; 3]);
        // Finite and ≥ 0 at grazing angles. Not reciprocal: the network is not exactly
        // symmetric in φ_d (the files' README), so `testing::check_basic` does not apply.
        for &wi in &testing::hard_directions() {
            for &wo in &testing::hard_directions() {
                let f = b.eval(wi, wo);
                assert!(f.iter().all(|v| v.is_finite() && *v >= 0.0), "{wi} {wo}: {f:?}");
            }
        }
    }

    #[test]
    fn a_network_that_would_overflow_is_held_finite() {
        // All weights 1e5: y is astronomically large, eʸ overflows.
        let b = NeuralBrdf::from_json(file_with(|_, _| 1e5).as_bytes(), "big").unwrap();
        let v = b.eval(DVec3::Z, DVec3::new(0.6, 0.0, 0.8));
        assert!(
            v.iter().all(|x| x.is_finite() && (0.0..=MAX_VALUE).contains(x)),
            "{v:?}"
        );
    }

    #[test]
    fn bad_files_are_refused_naming_the_field() {
        let good = file_with(|_, _| 0.1);
        let err = |text: &str| {
            NeuralBrdf::from_json(text.as_bytes(), "m.nbrdf.json")
                .unwrap_err()
                .to_string()
        };
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["format"] = "nbrdf-mlp-v2".into();
        assert!(
            err(&v.to_string()).contains("m.nbrdf.json: format"),
            "{}",
            err(&v.to_string())
        );
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["layers"][1]["weight"][4] = serde_json::json!([1.0, 2.0]);
        let e = err(&v.to_string());
        assert!(
            e.contains("layers[1].weight[4]") && e.contains("2 values, expected 21"),
            "{e}"
        );
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["layers"][2]["bias"] = serde_json::json!([1.0]);
        assert!(err(&v.to_string()).contains("layers[2].bias"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["layers"][0]["weight"].as_array_mut().unwrap().pop();
        assert!(err(&v.to_string()).contains("5 rows, expected 6"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["layers"].as_array_mut().unwrap().pop();
        assert!(err(&v.to_string()).contains("2 layers, expected 3"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["input"][1] = "1".into();
        assert!(err(&v.to_string()).contains(": input:"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["activations"][2] = "exp".into();
        assert!(err(&v.to_string()).contains(": activations:"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["layers"][0]["bias"][3] = serde_json::json!(1e300);
        assert!(err(&v.to_string()).contains("beyond"));
        let mut v: serde_json::Value = serde_json::from_str(&good).unwrap();
        v["extra"] = 1.into();
        assert!(err(&v.to_string()).contains("unknown field"));
        // Not JSON, truncated, NaN spelled out: serde names line and column.
        assert!(err("{\"format\": ").contains("line 1"));
        assert!(err(&good[..good.len() / 2]).contains("m.nbrdf.json"));
        assert!(err(&good.replacen("0.1", "NaN", 1)).contains("line"));
        let e = NeuralBrdf::read(Path::new("/nonexistent/x.nbrdf.json"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot read neural BRDF /nonexistent/x.nbrdf.json"), "{e}");
    }
}

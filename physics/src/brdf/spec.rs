//! The `--brdf SPEC` strings: `lambert:R,G,B`, `ggx:ALPHA:F0R,F0G,F0B`, `plastic:ALPHA:R,G,B`,
//! `dsbrdf:PATH`, `merl:PATH`, `nbrdf:PATH`, `library:NAME`, `fit:NAME`.

use super::{BrdfModel, Dsbrdf, Fresnel, Ggx, Lambert, Plastic, dsbrdf::DsbrdfError};
use std::path::PathBuf;

/// A parsed `--brdf` argument.
#[derive(Clone, Debug, PartialEq)]
pub enum BrdfSpec {
    /// `lambert:R,G,B`.
    Lambert([f64; 3]),
    /// `ggx:ALPHA:F0R,F0G,F0B`.
    Ggx {
        /// Roughness.
        alpha: f64,
        /// Schlick F0 (1,1,1 = no Fresnel falloff).
        f0: [f64; 3],
    },
    /// `plastic:ALPHA:R,G,B`.
    Plastic {
        /// Coat roughness.
        alpha: f64,
        /// Base albedo.
        albedo: [f64; 3],
    },
    /// `dsbrdf:PATH`: a 108-parameter material file.
    Dsbrdf(PathBuf),
    /// `merl:PATH`: a measured MERL `.binary` file.
    Merl(PathBuf),
    /// `nbrdf:PATH`: a measured material as a neural BRDF (`*.nbrdf.json`).
    Nbrdf(PathBuf),
    /// `library:NAME`: a material of the dataset factory's library, with its source BRDF.
    Library(String),
    /// `fit:NAME`: the fitted DSBRDF of a library material.
    Fit(String),
}

/// A `--brdf` string that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum SpecError {
    /// Syntax or value error, with the offending part named.
    #[error(
        "--brdf {spec:?}: {message} (expected lambert:R,G,B | ggx:ALPHA:F0R,F0G,F0B | plastic:ALPHA:R,G,B | dsbrdf:PATH | merl:PATH | nbrdf:PATH | library:NAME | fit:NAME)"
    )]
    Invalid {
        /// The whole string.
        spec: String,
        /// What is wrong.
        message: String,
    },
    /// The material file could not be loaded.
    #[error(transparent)]
    Material(#[from] DsbrdfError),
    /// The MERL file could not be loaded.
    #[error(transparent)]
    Merl(#[from] super::merl::MerlError),
    /// The neural BRDF file could not be loaded.
    #[error(transparent)]
    Nbrdf(#[from] super::nbrdf::NbrdfError),
    /// `library:`/`fit:` names are resolved by the dataset factory, which owns the library.
    #[error("{0}: library materials are resolved by matedit-datagen (materials::resolve)")]
    NeedsLibrary(String),
}

impl std::str::FromStr for BrdfSpec {
    type Err = SpecError;

    fn from_str(spec: &str) -> Result<Self, SpecError> {
        let bad = |message: String| SpecError::Invalid {
            spec: spec.to_string(),
            message,
        };
        let (kind, rest) = spec
            .split_once(':')
            .ok_or_else(|| bad("missing ':' after the model name".into()))?;
        let number = |s: &str, what: &str, lo: f64, hi: f64| -> Result<f64, SpecError> {
            let v: f64 = s
                .trim()
                .parse()
                .map_err(|_| bad(format!("{what} {s:?} is not a number")))?;
            if !(lo..=hi).contains(&v) {
                // As written (at most 24 characters), not as Display writes the value: 1e-300
                // would come back with 300 digits.
                let shown: String = s.trim().chars().take(24).collect();
                return Err(bad(format!("{what} {shown} is outside [{lo}, {hi}]")));
            }
            Ok(v)
        };
        let rgb = |s: &str, what: &str| -> Result<[f64; 3], SpecError> {
            let parts: Vec<&str> = s.split(',').collect();
            if parts.len() != 3 {
                return Err(bad(format!("{what} needs three comma-separated values, got {s:?}")));
            }
            Ok([
                number(parts[0], what, 0.0, 1.0)?,
                number(parts[1], what, 0.0, 1.0)?,
                number(parts[2], what, 0.0, 1.0)?,
            ])
        };
        let alpha_and = |rest: &str, what: &str| -> Result<(f64, [f64; 3]), SpecError> {
            let (a, c) = rest
                .split_once(':')
                .ok_or_else(|| bad(format!("expected ALPHA:{what}")))?;
            Ok((number(a, "ALPHA", super::ggx::ALPHA_MIN, 1.0)?, rgb(c, what)?))
        };
        match kind {
            "lambert" => Ok(BrdfSpec::Lambert(rgb(rest, "albedo")?)),
            "ggx" => alpha_and(rest, "F0").map(|(alpha, f0)| BrdfSpec::Ggx { alpha, f0 }),
            "plastic" => alpha_and(rest, "albedo").map(|(alpha, albedo)| BrdfSpec::Plastic { alpha, albedo }),
            "dsbrdf" if !rest.is_empty() => Ok(BrdfSpec::Dsbrdf(PathBuf::from(rest))),
            "dsbrdf" => Err(bad("missing material file path".into())),
            "merl" if !rest.is_empty() => Ok(BrdfSpec::Merl(PathBuf::from(rest))),
            "merl" => Err(bad("missing MERL file path".into())),
            "nbrdf" if !rest.is_empty() => Ok(BrdfSpec::Nbrdf(PathBuf::from(rest))),
            "nbrdf" => Err(bad("missing neural BRDF file path (*.nbrdf.json)".into())),
            "library" if !rest.is_empty() => Ok(BrdfSpec::Library(rest.to_string())),
            "fit" if !rest.is_empty() => Ok(BrdfSpec::Fit(rest.to_string())),
            "library" | "fit" => Err(bad("missing material name".into())),
            other => Err(bad(format!("unknown model {other:?}"))),
        }
    }
}

impl BrdfSpec {
    /// Builds the BRDF, loading the material file if there is one.
    pub fn build(&self) -> Result<BrdfModel, SpecError> {
        Ok(match self {
            BrdfSpec::Lambert(albedo) => BrdfModel::Lambert(Lambert { albedo: *albedo }),
            BrdfSpec::Ggx { alpha, f0 } => BrdfModel::Ggx(Ggx::new(*alpha, Fresnel::Schlick(*f0))),
            BrdfSpec::Plastic { alpha, albedo } => BrdfModel::Plastic(Plastic::new(*alpha, *albedo)),
            BrdfSpec::Dsbrdf(path) => BrdfModel::Dsbrdf(Box::new(Dsbrdf::load(path)?)),
            BrdfSpec::Library(n) => return Err(SpecError::NeedsLibrary(format!("library:{n}"))),
            BrdfSpec::Fit(n) => return Err(SpecError::NeedsLibrary(format!("fit:{n}"))),
            BrdfSpec::Merl(path) => BrdfModel::Measured(std::sync::Arc::new(super::MerlBrdf::read(path)?)),
            BrdfSpec::Nbrdf(path) => BrdfModel::Neural(std::sync::Arc::new(super::NeuralBrdf::read(path)?)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse() {
        assert_eq!(
            "lambert:0.5,0.5,0.5".parse::<BrdfSpec>().unwrap(),
            BrdfSpec::Lambert([0.5; 3])
        );
        assert_eq!(
            "ggx:0.3:1,1,1".parse::<BrdfSpec>().unwrap(),
            BrdfSpec::Ggx {
                alpha: 0.3,
                f0: [1.0; 3]
            }
        );
        assert_eq!(
            "plastic:0.2:0.8, 0.1,0.1".parse::<BrdfSpec>().unwrap(),
            BrdfSpec::Plastic {
                alpha: 0.2,
                albedo: [0.8, 0.1, 0.1]
            }
        );
        let b = "ggx:0.3:1,1,1".parse::<BrdfSpec>().unwrap().build().unwrap();
        assert!(matches!(
            b,
            BrdfModel::Ggx(Ggx {
                fresnel: Fresnel::None,
                ..
            })
        ));
    }

    #[test]
    fn bad_specs_say_what_is_wrong() {
        for (s, needle) in [
            ("lambert", "missing ':'"),
            ("lambert:0.5,0.5", "three"),
            ("lambert:0.5,x,0.5", "\"x\" is not a number"),
            ("lambert:0.5,NaN,0.5", "outside"),
            ("ggx:0:1,1,1", "ALPHA 0 is outside"),
            ("ggx:1e-300:1,1,1", "ALPHA 1e-300 is outside"),
            ("lambert:0.5,1e300,0.5", "1e300 is outside"),
            ("ggx:0.3", "expected ALPHA:F0"),
            ("phong:1", "unknown model"),
            ("dsbrdf:", "missing material file"),
        ] {
            let e = s.parse::<BrdfSpec>().unwrap_err().to_string();
            assert!(e.contains(needle), "{s}: {e}");
            assert!(e.len() < 300, "{s}: numbers echoed in short form: {e}");
        }
        let e = "dsbrdf:/nonexistent/m.json"
            .parse::<BrdfSpec>()
            .unwrap()
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("/nonexistent/m.json"));
    }
}

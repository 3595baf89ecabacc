//! Procedural environment maps embedded in the binary.

use anyhow::{Result, bail};
use glam::DVec3;
use matedit_physics::EnvMap;

/// Names accepted by [`builtin`].
pub const BUILTIN_NAMES: &str = "sky, studio, constant:V, constant:R,G,B";

/// Resolution of the procedural maps (rows).
const HEIGHT: usize = 256;

/// A procedural map by name:
/// * `sky`: clear sky (zenith blue to pale horizon), a sun of 2.5° radius with radiance 800 at
///   40° elevation, and a dark ground;
/// * `studio`: dim grey surround with a large overhead softbox and a smaller side softbox;
/// * `constant:V` or `constant:R,G,B`: uniform radiance (the furnace test's environment).
pub fn builtin(name: &str) -> Result<EnvMap> {
    if let Some(v) = name.strip_prefix("constant:") {
        let parts: Vec<f32> = v
            .split(',')
            .map(|s| s.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| anyhow::anyhow!("builtin:constant:{v}: expected a radiance V or R,G,B"))?;
        let rgb = match parts[..] {
            [x] => [x; 3],
            [r, g, b] => [r, g, b],
            _ => bail!("builtin:constant:{v}: expected one or three values"),
        };
        if rgb.iter().any(|x| !x.is_finite() || *x < 0.0) {
            bail!("builtin:constant:{v}: radiance must be finite and non-negative");
        }
        return Ok(EnvMap::constant(HEIGHT, rgb));
    }
    match name {
        "sky" => Ok(EnvMap::from_fn(HEIGHT, sky)),
        "studio" => Ok(EnvMap::from_fn(HEIGHT, studio)),
        _ => bail!("builtin:{name}: unknown builtin environment (known: {BUILTIN_NAMES})"),
    }
}

fn sky(d: DVec3) -> [f32; 3] {
    let sun_dir = DVec3::new(0.5, 40f64.to_radians().sin(), 0.7).normalize();
    if d.dot(sun_dir) > 2.5f64.to_radians().cos() {
        return [800.0, 760.0, 700.0];
    }
    if d.y < 0.0 {
        return [0.12, 0.1, 0.08];
    }
    let t = d.y.powf(0.5);
    let horizon = [1.1, 1.15, 1.2];
    let zenith = [0.25, 0.45, 0.95];
    std::array::from_fn(|c| (horizon[c] * (1.0 - t) + zenith[c] * t) as f32)
}

fn studio(d: DVec3) -> [f32; 3] {
    let top = DVec3::new(0.0, 1.0, 0.3).normalize();
    let side = DVec3::new(-0.8, 0.2, 0.5).normalize();
    if d.dot(top) > 30f64.to_radians().cos() {
        [2.0; 3]
    } else if d.dot(side) > 12f64.to_radians().cos() {
        [6.0, 5.7, 5.4]
    } else {
        [0.15; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtins_exist_and_bad_names_are_explained() {
        for n in ["sky", "studio", "constant:1", "constant:0.5,1,2"] {
            let m = builtin(n).unwrap();
            assert_eq!(m.height(), HEIGHT);
            assert!(m.texels().iter().flatten().all(|v| v.is_finite() && *v >= 0.0));
        }
        assert!(builtin("nope").unwrap_err().to_string().contains("sky"));
        assert!(builtin("constant:x").is_err());
        assert!(builtin("constant:-1").is_err());
        assert!(builtin("constant:1,2").is_err());
    }
}

//! Priors on m* and L* beyond Eq. 6's: a Gaussian over the material's parameters and a
//! natural-illumination prior on the light (the Lombardi-style baseline uses them).

/// A Gaussian over the normalised DSBRDF parameters: w Σ_r Σ_j (m*_rj − μ_j)² / σ_j², every
/// region slot alike.
#[derive(Clone, Copy, Debug)]
pub struct MaterialPrior<'a> {
    /// w.
    pub weight: f64,
    /// μ, 108 values.
    pub mean: &'a [f64],
    /// 1/σ², 108 values.
    pub inv_var: &'a [f64],
}

/// A natural-illumination prior: w Σ ρ(ln L*_a − ln L*_b) over every pair of neighbouring texels
/// of one channel (along a row, wrapping at the seam, and along a column), with the
/// heavy-tailed ρ(d) = √(d² + ε²) − ε that natural light's log-gradients follow.
#[derive(Clone, Copy, Debug)]
pub struct LightPrior {
    /// w.
    pub weight: f64,
    /// ε: below it ρ is quadratic, above it linear.
    pub epsilon: f64,
}

/// Priors on m* and L*. Eq. 6 has none: its priors are the network's n' and L'
/// ([`Problem::a`], [`Problem::b`]). The Lombardi-style baseline (`crate::baseline::lombardi`)
/// has both.
#[derive(Clone, Copy, Debug, Default)]
pub struct Priors<'a> {
    /// On m*.
    pub material: Option<MaterialPrior<'a>>,
    /// On L*.
    pub light: Option<LightPrior>,
}

impl Priors<'_> {
    /// No prior (Eq. 6).
    pub const NONE: Priors<'static> = Priors {
        material: None,
        light: None,
    };
}

/// Texels darker than this count as this in the light prior's logarithm.
const LOG_FLOOR: f64 = 1e-30;

impl MaterialPrior<'_> {
    /// The term at `m` (`[R, 108]`), and its gradient added into `grad` when given.
    pub(super) fn energy(&self, m: &[f32], mut grad: Option<&mut [f64]>) -> f64 {
        let n = self.mean.len().max(1);
        let mut e = 0.0;
        for (i, &v) in m.iter().enumerate() {
            let d = v as f64 - self.mean[i % n];
            e += d * d * self.inv_var[i % n];
            if let Some(g) = grad.as_deref_mut() {
                g[i] += 2.0 * self.weight * d * self.inv_var[i % n];
            }
        }
        self.weight * e
    }
}

impl LightPrior {
    /// The term at `env` (`[3, He, 2He]`), and its gradient added into `grad` when given.
    pub(super) fn energy(&self, env: &[f32], he: usize, mut grad: Option<&mut [f64]>) -> f64 {
        let we = 2 * he;
        let eps = self.epsilon;
        let ln = |v: f32| (v as f64).max(LOG_FLOOR).ln();
        let mut e = 0.0;
        let mut pair = |a: usize, b: usize, grad: &mut Option<&mut [f64]>| {
            let d = ln(env[a]) - ln(env[b]);
            let r = (d * d + eps * eps).sqrt();
            e += r - eps;
            if let Some(g) = grad.as_deref_mut() {
                let dr = self.weight * d / r;
                if env[a] as f64 > LOG_FLOOR {
                    g[a] += dr / env[a] as f64;
                }
                if env[b] as f64 > LOG_FLOOR {
                    g[b] -= dr / env[b] as f64;
                }
            }
        };
        for c in 0..3 {
            for y in 0..he {
                for x in 0..we {
                    let k = (c * he + y) * we + x;
                    pair(k, (c * he + y) * we + (x + 1) % we, &mut grad);
                    if y + 1 < he {
                        pair(k, k + we, &mut grad);
                    }
                }
            }
        }
        self.weight * e
    }
}

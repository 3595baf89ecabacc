//! The probe: a material's zonal error measured against the exact path on small test maps
//! ([`probe_error`]), which decides whether a grid resolves it.

use super::*;

/// Small maps shaped like the hard real ones: a sky whose sun carries 60 % of the power (real
/// sunny HDRIs put up to 60 % in their brightest texel at 64×128) in front of the object, to its
/// side and behind it (150° and 168° from the view: the rim light where θ_d nears grazing and
/// fitted lobes switch on between the last two knots), and a studio of two sharp-edged panels
/// over a dark room. Camera space: +z towards the viewer.
pub fn probe_maps() -> Vec<(&'static str, EnvMap)> {
    ProbeParts::new().composed()
}

/// The [`probe_maps`] as smooth bases shared by several probes plus a sparse part each (a sun,
/// two panels). The fast path is linear in the map and skips black texels, so its reference
/// images cost one full pass per base and a few texels per probe, not a full pass per probe.
pub(super) struct ProbeParts {
    pub(super) bases: Vec<EnvMap>,
    pub(super) probes: Vec<ProbePart>,
}

pub(super) struct ProbePart {
    pub(super) name: &'static str,
    pub(super) base: usize,
    /// What the probe adds to its base: black but for a few texels.
    pub(super) sparse: EnvMap,
}

impl ProbeParts {
    /// Each probe's whole map: its base plus its sparse part.
    pub(super) fn composed(&self) -> Vec<(&'static str, EnvMap)> {
        self.probes
            .iter()
            .map(|p| {
                let base = self.bases[p.base].texels();
                let texels = base
                    .iter()
                    .zip(p.sparse.texels())
                    .map(|(b, s)| [0, 1, 2].map(|c| b[c] + s[c]))
                    .collect();
                let env = EnvMap::from_texels(p.sparse.width(), p.sparse.height(), texels)
                    .map_or_else(|_| self.bases[p.base].clone(), |(e, _)| e);
                (p.name, env)
            })
            .collect()
    }

    pub(super) fn new() -> Self {
        let sky = EnvMap::from_fn(PROBE_MAP_ROWS, |d| {
            if d.y >= 0.0 {
                let t = (0.3 + 0.7 * d.y) as f32;
                [0.6 * t, 0.8 * t, t]
            } else {
                [0.15, 0.13, 0.1]
            }
        });
        let (w, h) = (sky.width(), sky.height());
        let sparse = |texels: Vec<[f32; 3]>| EnvMap::from_texels(w, h, texels).map(|(e, _)| e);
        let sky_power: f64 = sky.power().iter().sum::<f64>() / 3.0;
        let sun = |dir: DVec3| {
            let (col, row) = crate::envmap::direction_to_texel(dir.normalize(), w, h);
            // Sun power 1.5× the sky's: 60 % of the total. The sparse part replaces the sky's texel.
            let l = (1.5 * sky_power / texel_solid_angle(row, w, h)) as f32;
            let under = sky.texel(col, row);
            let mut texels = vec![[0.0_f32; 3]; w * h];
            texels[row * w + col] = [l - under[0], 0.95 * l - under[1], 0.85 * l - under[2]];
            sparse(texels)
        };
        let room = [0.05_f32; 3];
        let dark_room = EnvMap::from_fn(PROBE_MAP_ROWS, |_| room);
        let panel = |d: DVec3, centre: DVec3| d.dot(centre.normalize()) > 0.97;
        let panels = EnvMap::from_fn(PROBE_MAP_ROWS, |d| {
            if panel(d, DVec3::new(0.5, 0.5, 0.7)) || panel(d, DVec3::new(-0.8, 0.3, -0.5)) {
                [20.0 - room[0], 20.0 - room[1], 19.0 - room[2]]
            } else {
                [0.0; 3]
            }
        });
        let suns = [
            ("sun in front", DVec3::new(0.3, 0.45, 0.85)),
            ("sun to the side", DVec3::new(-0.9, 0.4, 0.1)),
            ("sun behind", DVec3::new(0.3, 0.4, -0.866)),
            ("sun straight behind", DVec3::new(-0.15, 0.15, -0.98)),
        ];
        let mut probes: Vec<ProbePart> = suns
            .iter()
            .filter_map(|&(name, dir)| sun(dir).ok().map(|sparse| ProbePart { name, base: 0, sparse }))
            .collect();
        probes.push(ProbePart {
            name: "studio",
            base: 1,
            sparse: panels,
        });
        Self {
            bases: vec![sky, dark_room],
            probes,
        }
    }
}

/// The fast path's images of the check's sphere under every [`probe_maps`] map, made once per
/// material: the check of each finer grid compares against the same images.
pub struct ProbeReference {
    pub(super) normals: Vec<[f32; 3]>,
    pub(super) mask: Vec<f32>,
    pub(super) pixels: PolarNormals,
    pub(super) probes: Vec<(&'static str, EnvMap, Vec<[f32; 3]>)>,
}

impl ProbeReference {
    /// `None` for a measured BRDF (no fast path). Single-threaded, like the kernel build (see
    /// [`ZonalKernel::with_tail`]).
    pub fn new(brdf: &BrdfModel) -> Option<Self> {
        let (normals, mask) = crate::camera::unit_sphere_normals(PROBE_RES);
        let polar: Vec<(f32, f32)> = normals.iter().zip(&mask).map(|(n, &m)| polar(n, m)).collect();
        let pixels = PolarNormals {
            theta: polar.iter().map(|p| p.0).collect(),
            phi: polar.iter().map(|p| p.1).collect(),
        };
        let image = |env: &EnvMap| -> Option<Vec<[f32; 3]>> {
            let fast = crate::shading::fast::FastShader::new(brdf, env)?;
            Some(
                normals
                    .iter()
                    .zip(&mask)
                    .map(|(n, &m)| {
                        if m > 0.0 {
                            crate::shading::Shader::shade(&fast, *n, None)
                        } else {
                            [0.0; 3]
                        }
                    })
                    .collect(),
            )
        };
        let parts = ProbeParts::new();
        let bases: Vec<Vec<[f32; 3]>> = parts.bases.iter().map(image).collect::<Option<_>>()?;
        let mut probes = Vec::with_capacity(parts.probes.len());
        for (part, (name, env)) in parts.probes.iter().zip(parts.composed()) {
            let extra = image(&part.sparse)?;
            let sum = bases[part.base]
                .iter()
                .zip(extra)
                .map(|(b, e)| [0, 1, 2].map(|c| b[c] + e[c]))
                .collect();
            probes.push((name, env, sum));
        }
        Some(Self {
            normals,
            mask,
            pixels,
            probes,
        })
    }
}

/// The kernel's largest relative RMSE against the fast path on a [`PROBE_RES`]² sphere under the
/// [`probe_maps`], and the map that showed it.
pub fn probe_error(kernel: &ZonalKernel, reference: &ProbeReference) -> (f64, &'static str) {
    let ProbeReference {
        normals,
        mask,
        pixels,
        probes,
    } = reference;
    let need = pixels.rows_needed(&kernel.grid, mask);
    let mut worst = (0.0_f64, "none");
    for (name, env, fast) in probes {
        let spectra = ZonalEnv::new(env, kernel.grid);
        let lit = lit_points(&kernel.brdf, &spectra.points);
        let table = Padded::new(&normal_table_with(kernel, &spectra, &need, false), &kernel.grid);
        let (mut err, mut norm) = (0.0_f64, 0.0_f64);
        for p in 0..normals.len() {
            let (t, ph) = (pixels.theta[p], pixels.phi[p]);
            if mask[p] <= 0.0 || t.is_nan() {
                continue;
            }
            let z = pixel_radiance(&table, &kernel.grid, &kernel.brdf, &lit, t, ph);
            let f = fast[p];
            for c in 0..3 {
                err += ((z[c] - f[c]) as f64).powi(2);
                norm += (f[c] as f64).powi(2);
            }
        }
        let e = if norm > 0.0 { (err / norm).sqrt() } else { 0.0 };
        // A non-finite error is a failed check.
        let e = if e.is_finite() { e } else { f64::INFINITY };
        if e > worst.0 {
            worst = (e, *name);
        }
    }
    worst
}

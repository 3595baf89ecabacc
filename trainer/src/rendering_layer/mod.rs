//! The differentiable rendering layer (Sec. 3.1, Eq. 2): re-renders an object from per-pixel
//! normals **n**, a DSBRDF material **m** per region and a 64×128 HDR environment **L**,
//!
//! ```text
//! I_p = Σ_t f(ω_t, ω_o; n_p, m) · L(ω_t) · max(0, n_p·ω_t) · dω_t
//! ```
//!
//! * [`RenderingLayer`] is the fused CPU operation: forward and its analytic vector–Jacobian
//!   product ([`RenderingLayer::backward`]) in one pass over pixels × texels each, with no
//!   pixel × texel intermediate ([`kernel`]).
//! * [`reference`] is a plain Burn tensor implementation of the same formula, differentiated by
//!   Burn's autodiff: the independent check of the fused gradients.
//! * [`op`] connects the fused layer to Burn's autodiff graph.
//!
//! Tensor layouts (row-major, channel-first like Burn's convolutions): normals `[B, 3, H, W]`
//! (camera space, unit), region map `[B, H, W]` (0 = background, r = material r − 1), materials
//! `[B, R, 108]` (normalised to the tanh range), environment `[B, 3, He, 2·He]` (camera space,
//! linear radiance), output `[B, 3, H, W]`.
//!
//! Non-finite inputs never propagate: a non-finite or back-facing normal renders black, non-finite
//! or negative radiance counts as 0, a NaN material parameter as 0, and a non-finite upstream
//! gradient as 0; radiance is capped at [`MAX_RADIANCE`].

#[cfg(feature = "wgpu")]
pub mod gpu;
pub mod kernel;
pub mod material;
pub mod op;
pub mod reference;
mod simd;
#[cfg(test)]
mod tests;

pub mod texels;

use kernel::TexelGrads;
pub use kernel::Wanted;
use matedit_physics::brdf::dsbrdf::PARAMS;
use material::MaterialTexels;
use rayon::prelude::*;
pub use texels::TexelTable;

/// Radiance above this counts as this (the brightest real probes here peak at 7e4): it keeps
/// L·ρ·dω sums within `f32` even for the largest lobes (expm1(29.3) ≈ 5e12, κ's largest at the
/// normalised parameters' clamp).
pub const MAX_RADIANCE: f32 = 1e6;

/// Pixels per tile: one texel group's constants are reused by this many pixels.
const TILE: usize = 32;
/// Backward groups per (image, region): fixed, so that the summation order, and therefore every
/// bit of the gradients, does not depend on the thread count.
const GROUPS: usize = 16;

/// The rendering layer on a GPU device ([`gpu::DeviceLayer`]; builds with `--features wgpu`).
#[cfg(feature = "wgpu")]
pub use gpu::DeviceLayer as DeviceRendering;

/// No GPU layer in this build: [`on_device`] never returns one.
#[cfg(not(feature = "wgpu"))]
pub enum DeviceRendering {}

#[cfg(not(feature = "wgpu"))]
impl DeviceRendering {
    /// Uncallable: there is no value of this type.
    pub fn render(
        &self,
        _normals: burn::tensor::Tensor<4>,
        _region_map: &[u8],
        _materials: burn::tensor::Tensor<3>,
        _env: burn::tensor::Tensor<4>,
    ) -> Result<burn::tensor::Tensor<4>, RenderError> {
        match *self {}
    }
}

/// The rendering layer on `device` when it is a GPU device this build has kernels for; `None`
/// means the fused CPU layer renders (on the host, whatever the device of the network).
pub fn on_device(device: &burn::tensor::Device, env_height: usize) -> Option<DeviceRendering> {
    #[cfg(feature = "wgpu")]
    {
        use std::sync::Mutex;
        if !crate::device::on_cube(device) {
            return None;
        }
        let inner = device.clone().inner();
        // The texel table is uploaded once per device and environment height.
        static LAYERS: Mutex<Vec<(burn::tensor::Device, DeviceRendering)>> = Mutex::new(Vec::new());
        let mut layers = LAYERS.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, l)) = layers.iter().find(|(d, l)| *d == inner && l.env_height() == env_height) {
            return Some(l.clone());
        }
        let layer = DeviceRendering::new(env_height, &inner);
        layers.push((inner, layer.clone()));
        Some(layer)
    }
    #[cfg(not(feature = "wgpu"))]
    {
        let _ = (device, env_height);
        None
    }
}

/// Why a batch cannot be rendered.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum RenderError {
    /// A buffer's length does not match the declared shape.
    #[error("{name}: expected {expected} values for shape {shape}, got {got}")]
    Shape {
        /// Which input.
        name: &'static str,
        /// Shape in words.
        shape: String,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// A region index exceeds the number of materials.
    #[error("region map: pixel {pixel} of image {image} has region {region}, but only {regions} materials were given")]
    Region {
        /// Image in the batch.
        image: usize,
        /// Pixel index.
        pixel: usize,
        /// Region value.
        region: u8,
        /// Materials per image.
        regions: usize,
    },
    /// The environment's height does not match the layer's.
    #[error("environment: the layer was built for height {layer}, got {got}")]
    EnvHeight {
        /// The layer's.
        layer: usize,
        /// The batch's.
        got: usize,
    },
}

impl RenderError {
    /// `Ok` when `got` values are the `expected` of the input `name` of shape `shape`.
    pub(crate) fn expect(name: &'static str, shape: String, expected: usize, got: usize) -> Result<(), RenderError> {
        if expected == got {
            Ok(())
        } else {
            Err(RenderError::Shape {
                name,
                shape,
                expected,
                got,
            })
        }
    }
}

/// One batch of rendering-layer inputs (layouts in the module docs).
#[derive(Clone, Copy, Debug)]
pub struct LayerInput<'a> {
    /// Images.
    pub batch: usize,
    /// Image height and width in pixels.
    pub size: (usize, usize),
    /// Materials (regions) per image.
    pub regions: usize,
    /// `[B, 3, H, W]`.
    pub normals: &'a [f32],
    /// `[B, H, W]`.
    pub region_map: &'a [u8],
    /// `[B, R, 108]`.
    pub materials: &'a [f32],
    /// `[B, 3, He, 2·He]`.
    pub env: &'a [f32],
}

impl<'a> LayerInput<'a> {
    /// One `n`×`n` image of one material: `region_map` 1 on the object, 0 elsewhere.
    pub fn one_region(n: usize, normals: &'a [f32], region_map: &'a [u8], material: &'a [f32], env: &'a [f32]) -> Self {
        LayerInput {
            batch: 1,
            size: (n, n),
            regions: 1,
            normals,
            region_map,
            materials: material,
            env,
        }
    }
}

/// Gradients of a loss with respect to the layer's inputs, in the inputs' layouts.
#[derive(Clone, Debug)]
pub struct Gradients {
    /// `[B, 3, H, W]`; zero on background and unusable pixels.
    pub normals: Vec<f32>,
    /// `[B, R, 108]`.
    pub materials: Vec<f32>,
    /// `[B, 3, He, 2·He]`.
    pub env: Vec<f32>,
}

/// `sums[i] += group[i]` in `f64`, over the shorter of the two (the group is padded).
fn add_f64(sums: &mut [f64], group: &[f32]) {
    for (s, &g) in sums.iter_mut().zip(group) {
        *s += g as f64;
    }
}

/// The fused rendering layer for one environment resolution.
#[derive(Clone, Debug)]
pub struct RenderingLayer {
    tex: TexelTable,
}

/// Pixels of one (image, region), in tiles.
struct Part {
    image: usize,
    region: usize,
    pixels: Vec<usize>,
}

impl RenderingLayer {
    /// A layer for `2·env_height × env_height` environment maps (the paper: 64).
    pub fn new(env_height: usize) -> Self {
        Self {
            tex: TexelTable::new(env_height),
        }
    }

    /// The texel constants.
    pub fn texels(&self) -> &TexelTable {
        &self.tex
    }

    /// Validates the batch's shapes and region indices.
    pub fn check(&self, b: &LayerInput) -> Result<(), RenderError> {
        let (h, w) = b.size;
        let p = h * w;
        let t = self.tex.count();
        let shape = RenderError::expect;
        shape(
            "normals",
            format!("[{}, 3, {h}, {w}]", b.batch),
            b.batch * 3 * p,
            b.normals.len(),
        )?;
        shape(
            "region map",
            format!("[{}, {h}, {w}]", b.batch),
            b.batch * p,
            b.region_map.len(),
        )?;
        shape(
            "materials",
            format!("[{}, {}, {PARAMS}]", b.batch, b.regions),
            b.batch * b.regions * PARAMS,
            b.materials.len(),
        )?;
        if b.env.len() != b.batch * 3 * t {
            let got_h = ((b.env.len() / (3 * b.batch.max(1))) as f64 / 2.0).sqrt() as usize;
            if got_h != self.tex.height() && b.batch > 0 {
                return Err(RenderError::EnvHeight {
                    layer: self.tex.height(),
                    got: got_h,
                });
            }
            shape(
                "environment",
                format!("[{}, 3, {}, {}]", b.batch, self.tex.height(), 2 * self.tex.height()),
                b.batch * 3 * t,
                b.env.len(),
            )?;
        }
        for (i, &r) in b.region_map.iter().enumerate() {
            if r as usize > b.regions {
                return Err(RenderError::Region {
                    image: i / p,
                    pixel: i % p,
                    region: r,
                    regions: b.regions,
                });
            }
        }
        Ok(())
    }

    fn parts(b: &LayerInput) -> Vec<Part> {
        let p = b.size.0 * b.size.1;
        let mut parts = Vec::new();
        for image in 0..b.batch {
            for region in 0..b.regions {
                let pixels: Vec<usize> = (0..p)
                    .filter(|&i| b.region_map[image * p + i] as usize == region + 1)
                    .collect();
                if !pixels.is_empty() {
                    parts.push(Part { image, region, pixels });
                }
            }
        }
        parts
    }

    fn normal(b: &LayerInput, image: usize, pixel: usize) -> [f32; 3] {
        let p = b.size.0 * b.size.1;
        std::array::from_fn(|a| b.normals[(image * 3 + a) * p + pixel])
    }

    /// L·dω per texel of image `i`, non-finite and negative radiance as 0.
    fn light(&self, b: &LayerInput, i: usize) -> [Vec<f32>; 3] {
        let t = self.tex.count();
        std::array::from_fn(|c| {
            let mut v = vec![0.0; self.tex.padded()];
            for (k, out) in v.iter_mut().enumerate().take(t) {
                let l = b.env[(i * 3 + c) * t + k];
                *out = if l.is_finite() && l > 0.0 {
                    l.min(MAX_RADIANCE) * self.tex.sa[k]
                } else {
                    0.0
                };
            }
            v
        })
    }

    fn prepare(&self, b: &LayerInput, parts: &[Part]) -> (Vec<MaterialTexels>, Vec<[Vec<f32>; 3]>) {
        let mats = parts
            .par_iter()
            .map(|part| {
                let o = (part.image * b.regions + part.region) * PARAMS;
                MaterialTexels::new(&b.materials[o..o + PARAMS], &self.tex)
            })
            .collect();
        let lights = (0..b.batch).into_par_iter().map(|i| self.light(b, i)).collect();
        (mats, lights)
    }

    /// Renders the batch: `[B, 3, H, W]`, zero on the background.
    pub fn forward(&self, b: &LayerInput) -> Result<Vec<f32>, RenderError> {
        self.check(b)?;
        let parts = Self::parts(b);
        let (mats, lights) = self.prepare(b, &parts);
        let tiles: Vec<(usize, &[usize])> = parts
            .iter()
            .enumerate()
            .flat_map(|(k, part)| part.pixels.chunks(TILE).map(move |c| (k, c)))
            .collect();
        let shaded: Vec<Vec<[f32; 3]>> = tiles
            .par_iter()
            .map(|&(k, pixels)| {
                let part = &parts[k];
                let normals: Vec<[f32; 3]> = pixels.iter().map(|&p| Self::normal(b, part.image, p)).collect();
                let mut out = vec![[0.0; 3]; pixels.len()];
                kernel::forward_tile(&normals, &self.tex, &mats[k], &lights[part.image], &mut out);
                out
            })
            .collect();
        let p = b.size.0 * b.size.1;
        let mut out = vec![0.0; b.batch * 3 * p];
        for (&(k, pixels), rgb) in tiles.iter().zip(&shaded) {
            let i = parts[k].image;
            for (&px, v) in pixels.iter().zip(rgb) {
                for (c, v) in v.iter().enumerate() {
                    out[(i * 3 + c) * p + px] = *v;
                }
            }
        }
        Ok(out)
    }

    /// Gradients of a loss with respect to every input, given ∂loss/∂output (`upstream`,
    /// `[B, 3, H, W]`).
    pub fn backward(&self, b: &LayerInput, upstream: &[f32]) -> Result<Gradients, RenderError> {
        self.backward_wanted(b, upstream, Wanted::ALL)
    }

    /// [`RenderingLayer::backward`] for the gradients `want` asks for only; the others come back
    /// as zeros.
    pub fn backward_wanted(&self, b: &LayerInput, upstream: &[f32], want: Wanted) -> Result<Gradients, RenderError> {
        self.check(b)?;
        let (h, w) = b.size;
        let p = h * w;
        if upstream.len() != b.batch * 3 * p {
            return Err(RenderError::Shape {
                name: "upstream gradient",
                shape: format!("[{}, 3, {h}, {w}]", b.batch),
                expected: b.batch * 3 * p,
                got: upstream.len(),
            });
        }
        let parts = Self::parts(b);
        let (mats, lights) = self.prepare(b, &parts);
        let t = self.tex.count();
        let mut grads = Gradients {
            normals: vec![0.0; b.batch * 3 * p],
            materials: vec![0.0; b.batch * b.regions * PARAMS],
            env: vec![0.0; b.batch * 3 * t],
        };
        let mut light_acc: Vec<Vec<Vec<f64>>> = vec![vec![vec![0.0; t]; 3]; b.batch];
        for (k, part) in parts.iter().enumerate() {
            let per_group = part.pixels.len().div_ceil(GROUPS).max(1);
            let groups: Vec<(Vec<[f32; 3]>, TexelGrads)> = part
                .pixels
                .par_chunks(per_group)
                .map(|pixels| {
                    let mut acc = TexelGrads::zeros(self.tex.padded());
                    let mut gn = vec![[0.0f32; 3]; pixels.len()];
                    for (tile, gn) in pixels.chunks(TILE).zip(gn.chunks_mut(TILE)) {
                        let normals: Vec<[f32; 3]> = tile.iter().map(|&px| Self::normal(b, part.image, px)).collect();
                        let up: Vec<[f32; 3]> = tile
                            .iter()
                            .map(|&px| {
                                std::array::from_fn(|c| {
                                    let g = upstream[(part.image * 3 + c) * p + px];
                                    if g.is_finite() { g } else { 0.0 }
                                })
                            })
                            .collect();
                        kernel::backward_tile(
                            &normals,
                            &up,
                            &self.tex,
                            &mats[k],
                            &lights[part.image],
                            gn,
                            &mut acc,
                            want,
                        );
                    }
                    (gn, acc)
                })
                .collect();
            let mut gk = vec![vec![0.0f64; t]; material::MEMBERS];
            let mut gg = vec![vec![0.0f64; t]; material::MEMBERS];
            for ((gn, acc), pixels) in groups.iter().zip(part.pixels.chunks(per_group)) {
                for (&px, g) in pixels.iter().zip(gn) {
                    for (c, g) in g.iter().enumerate() {
                        grads.normals[(part.image * 3 + c) * p + px] = *g;
                    }
                }
                if want.materials {
                    for (sums, group) in gk.iter_mut().zip(&acc.kappa).chain(gg.iter_mut().zip(&acc.gamma)) {
                        add_f64(sums, group);
                    }
                }
                if want.env {
                    for (sums, group) in light_acc[part.image].iter_mut().zip(&acc.light) {
                        add_f64(sums, group);
                    }
                }
            }
            if want.materials {
                let o = (part.image * b.regions + part.region) * PARAMS;
                let gm = material::knot_gradient(&b.materials[o..o + PARAMS], &gk, &gg, &self.tex);
                grads.materials[o..o + PARAMS].copy_from_slice(&gm);
            }
        }
        for (i, acc) in light_acc.iter().enumerate() {
            for (c, acc) in acc.iter().enumerate() {
                let o = (i * 3 + c) * t;
                let (env, out) = (&b.env[o..o + t], &mut grads.env[o..o + t]);
                for (((g, &l), &a), &sa) in out.iter_mut().zip(env).zip(acc).zip(&self.tex.sa) {
                    // Radiance clamped to 0 (negative or non-finite) receives no gradient.
                    *g = if l.is_finite() && (0.0..=MAX_RADIANCE).contains(&l) {
                        (a * sa as f64) as f32
                    } else {
                        0.0
                    };
                }
            }
        }
        Ok(grads)
    }
}

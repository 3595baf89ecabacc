//! # matedit-physics
//!
//! The image-formation model of Liu et al. 2017 ("Material Editing Using a Physically Based
//! Rendering Network"), Eq. 2: the radiance leaving pixel `p` towards the orthographic camera is a
//! sum over the texels of an HDR environment map,
//!
//! ```text
//! I_p = Σ_texels f(ω_i, ω_o; m) · L(ω_i) · max(0, n_p·ω_i) · dω_i
//! ```
//!
//! The crate is laid out like the physics it models (after pbrt-v4):
//!
//! * [`camera`]: the orthographic camera and pixel-centre convention;
//! * [`envmap`]: equirectangular environment maps, texel directions and solid angles, rotation and
//!   power-preserving resampling;
//! * [`brdf`]: the [`brdf::Brdf`] trait and the reference BRDFs (Lambert, GGX, plastic) and the
//!   108-parameter Directional Statistics BRDF ([`brdf::dsbrdf`]);
//! * [`shading`]: Eq. 2 itself, three ways: an exact `f64` reference path, a fast `f32` path
//!   (SIMD over texels), and the zonal path (a convolution about the view axis, without shadows);
//! * [`tonemap`]: the display transform used for PNG previews and image metrics;
//! * [`fastmath`]: branch-free `exp`/`ln`/`expm1` that vectorise, used by the fast path.
//!
//! Every convention is written down in `docs/CONVENTIONS.md` and tested.

#![warn(missing_docs)]

pub mod brdf;
pub mod camera;
pub mod envmap;
pub mod fastmath;
pub mod frame;
mod memo;
pub mod shading;
pub mod tonemap;

pub use brdf::{Brdf, BrdfModel, BrdfSpec};
pub use envmap::EnvMap;

/// Rec. 709 luminance weights of linear RGB: the one measure of brightness of the factory's
/// drawn materials, the network's exposure and `matedit edit`'s photo exposure.
pub const LUMINANCE_WEIGHTS: [f64; 3] = [0.2126, 0.7152, 0.0722];

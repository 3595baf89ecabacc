//! Materials for the dataset: the named library, the parametric families drawn per seed, fitting the paper's 108-parameter DSBRDF to any
//! BRDF (analytic, tabulated or measured) with errors in BRDF space and in rendered images, and
//! the on-disk cache of fits.

pub mod cache;
pub mod fit;
pub mod library;
pub mod parametric;

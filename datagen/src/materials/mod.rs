//! Materials for the dataset: fitting the paper's 108-parameter DSBRDF to any BRDF (analytic,
//! tabulated or measured), with errors reported in BRDF space and in rendered images.

pub mod fit;

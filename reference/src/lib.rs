//! Ground truth for penumbra: the CPU reference renderer and image metrics. No GPU.
//!
//! - [`metrics`]: PSNR (linear radiance, peak = max of the reference), RMSE, relative RMSE,
//!   mean/max absolute error, FLIP (LDR, after a stated tone mapping) and a false-colour
//!   difference PNG between two linear RGB images ([`compare`], [`compare_files`]); the result
//!   [`Comparison`] serializes to JSON (infinite PSNR of identical images is `null`).
//! - [`image`]: [`Image`] (linear RGB float) with EXR read/write; errors name the file.
//! - [`render`](mod@render): Monte Carlo direct lighting with exact visibility ([`render()`]), see its module
//!   docs for the estimator; [`brdf`] defines the BRDFs, [`sampling`] the environment importance
//!   sampling, [`lights`] the local lights, [`geometry`] the `obvhs` BVH.
//! - [`cli`]: the `penumbra reference` / `penumbra compare` argument structs and actions.
//!
//! Conventions shared with the GPU renderer: the scene at frame K is `scene.at(K / fps, None)`
//! (fps 30 by default, or an explicit time); the camera is `Camera::proj(aspect) * view()`
//! (Vulkan clip space, y down) and pixel (0, 0) is the top-left; environment lookups match
//! `Environment::radiance` (nearest texel, rotation about +Y, intensity applied).

pub mod brdf;
pub mod cli;
pub mod converge;
pub mod geometry;
pub mod image;
pub mod lights;
pub mod metrics;
pub mod render;
pub mod sampling;

pub use image::{Image, ImageError};
pub use metrics::{compare, compare_files, Comparison};
pub use render::{render, Mode, NoiseStats, ReferenceImage, ReferenceOptions, RenderError};

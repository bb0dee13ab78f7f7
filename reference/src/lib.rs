//! Ground truth for penumbra: the CPU reference renderer and image metrics.
//!
//! - [`metrics`]: PSNR, RMSE, relative RMSE, absolute errors, FLIP and a false-colour difference
//!   image between two linear RGB EXR images ([`compare_files`]).
//! - [`render`]: Monte Carlo direct lighting with exact visibility ([`render::render`]).

pub mod brdf;
pub mod cli;
pub mod geometry;
pub mod image;
pub mod lights;
pub mod metrics;
pub mod render;
pub mod sampling;

pub use image::{Image, ImageError};
pub use metrics::{compare, compare_files, Comparison};
pub use render::{render, Mode, NoiseStats, ReferenceImage, ReferenceOptions, RenderError};

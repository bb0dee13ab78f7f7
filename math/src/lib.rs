//! Spherical math shared by penumbra's techniques and the CPU reference renderer.
//! Pure CPU code, no Vulkan: it builds and tests fast.
//!
//! * [`sg`]: spherical Gaussians (f64 [`sg::Sg`], f32 [`sg::Sg32`]; GLSL mirror in
//!   `glsl/include/sg.glsl`).
//! * [`sh`]: real spherical harmonics of any order (rotation, double and triple products).
//! * [`quad`]: quadrature rules used to validate the closed forms.
//! * [`nnls`]: non-negative least squares.
//! * [`envmap`]: lat-long environment maps, SG fitting and SG-prefiltered maps (`Gamma_L`).
//! * [`brdf`]: SG fits of Blinn-Phong, Cook-Torrance and Ashikhmin-Shirley lobes.
//! * [`vv`]: vectorized visibility and its spherical-Voronoi correspondence (offline data).

#![warn(missing_docs)]

pub mod avs_maps;
pub mod avs_sampling;
pub mod brdf;
pub mod dfg;
pub mod envmap;
pub mod hsdt;
pub mod isg;
pub mod nnls;
pub mod quad;
pub mod ray;
pub mod sg;
pub mod sh;
pub mod shadow_field;
pub mod special;
pub mod sphereset;
pub mod ssdf_integrate;
pub mod vv;
pub mod vv_sat;

//! One module per render-graph pass. Each pass owns its shaders (under `glsl/`), its parameters
//! with documented defaults, and its tests. A pass is created once (pipelines) and added to each
//! frame's graph with `add`, which declares every resource use and returns the new handles.

pub mod avs;
pub mod blit;
pub mod effect;
pub mod env;
pub mod gbuffer;
pub mod hsdt;
pub mod hud;
pub mod isg;
pub mod kdtree;
pub mod kernels;
pub mod lighting;
pub mod mc;
pub mod raster;
pub mod readback;
pub mod registry;
pub mod scene_gpu;
pub mod shade_env;
pub mod shadow_fields;
pub mod shadowmaps;
pub mod technique;
pub mod textures;
pub mod tonemap;
pub mod trace;
pub mod trace_bench;
pub mod util;
pub mod volumetric;
pub mod vv;

pub use env::EnvMapGpu;
pub use gbuffer::{GBuffer, GBufferPass};
pub use scene_gpu::{FrameConstants, SceneGpu};
pub use shade_env::ShadeEnvPass;
pub use tonemap::TonemapPass;

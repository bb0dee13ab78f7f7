//! penumbra: a Vulkan rendering engine for dynamic scenes under all-frequency lighting.
//!
//! This crate is the embeddable facade. It owns the SPIR-V compiled by `build.rs` and builds
//! each frame's render graph from the scene's requirements:
//!
//! ```text
//! env_upload (first frame) -> gbuffer -> <technique passes> -> tonemap -> readback
//!
//! The technique (`passes::technique`) is the scene's `technique` or `RenderSettings::technique`.
//! ```
//!
//! Embedding: create a [`Renderer`] on penumbra's own device ([`Renderer::new_headless`]) or on
//! the application's (`Context::from_external`), then render into an imported image
//! ([`Renderer::render`] with a `target`). See `examples/embed.rs`.

pub use penumbra_engine as engine;
pub use penumbra_passes as passes;
pub use penumbra_scene as scene;

use anyhow::{bail, Result};
use glam::Mat4;
use penumbra_engine::graph::compile::CompiledGraph;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Context, ContextDesc, Engine, FrameOutput, Graph, ImportedImage};
use penumbra_passes::env::EnvMapGpu;
use penumbra_passes::scene_gpu::FrameConstants;
use penumbra_passes::tonemap::TonemapParams;
use penumbra_passes::technique::{Technique, TechniqueInputs};
use penumbra_passes::{GBufferPass, SceneGpu, TonemapPass};
use penumbra_scene::{Frame, Scene};
use std::path::PathBuf;
use std::sync::Arc;

include!(concat!(env!("OUT_DIR"), "/shaders.rs"));

/// The embedded shader library (sources in `glsl/` for hot reload).
pub fn shader_library() -> ShaderLibrary {
    ShaderLibrary::from_embedded(SHADERS, Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("glsl")))
}

/// Render settings.
#[derive(Clone, Debug)]
pub struct RenderSettings {
    pub width: u32,
    pub height: u32,
    pub tonemap: TonemapParams,
    /// Frames the GPU may work on at once (readbacks arrive that many frames later).
    pub frames_in_flight: usize,
    /// Overrides the scene's `technique` (an unimplemented name is then an error).
    pub technique: Option<String>,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings { width: 640, height: 480, tonemap: TonemapParams::default(), frames_in_flight: 2, technique: None }
    }
}

/// The images of a finished frame, decoded from its readbacks.
#[derive(Clone, Debug)]
pub struct FrameImages {
    pub frame: u64,
    pub width: u32,
    pub height: u32,
    /// Linear radiance, RGBA f32, row 0 at the top.
    pub hdr: Vec<[f32; 4]>,
    /// Tone-mapped sRGB-encoded RGBA8.
    pub ldr: Vec<u8>,
    pub gpu_ms: Vec<(String, f64)>,
}

/// Builds and runs penumbra's frame graph for one scene.
pub struct Renderer {
    // Passes hold pipelines on the context: drop them before the engine.
    gbuffer: GBufferPass,
    technique: Box<dyn Technique>,
    tonemap: TonemapPass,
    scene_gpu: SceneGpu,
    env: EnvMapGpu,
    pub engine: Engine,
    pub settings: RenderSettings,
    prev_view_proj: Option<Mat4>,
    /// The last compiled graph (for dumps).
    pub last_graph: Option<CompiledGraph>,
}

impl Renderer {
    /// A renderer on a device of its own (no window).
    pub fn new_headless(scene: &Scene, settings: RenderSettings, validation: bool) -> Result<Self> {
        let ctx = Context::new(&ContextDesc { validation, ..Default::default() })?;
        Self::new(ctx, scene, settings)
    }

    /// A renderer on an existing context (own or the application's).
    pub fn new(ctx: Arc<Context>, scene: &Scene, settings: RenderSettings) -> Result<Self> {
        if settings.width == 0 || settings.height == 0 || settings.width > 16384 || settings.height > 16384 {
            bail!("image size {}x{} is out of range (1..16384)", settings.width, settings.height);
        }
        let shaders = shader_library();
        let engine = Engine::new(ctx.clone(), settings.frames_in_flight)?;
        let name = settings.technique.clone().unwrap_or_else(|| scene.technique.clone());
        let technique = match penumbra_passes::technique::create(&name, &ctx, &shaders, scene)? {
            Some(t) => t,
            None if settings.technique.is_some() => bail!(
                "technique '{name}' is not implemented (implemented: {})",
                penumbra_passes::technique::IMPLEMENTED.join(", ")
            ),
            // A scene naming a technique still to come renders with the default (reported by
            // `Renderer::limitations`).
            None => penumbra_passes::technique::create(penumbra_scene::DEFAULT_TECHNIQUE, &ctx, &shaders, scene)?
                .expect("the default technique exists"),
        };
        Ok(Renderer {
            gbuffer: GBufferPass::new(&ctx, &shaders)?,
            technique,
            tonemap: TonemapPass::new(&ctx, &shaders)?,
            scene_gpu: SceneGpu::new(&ctx, scene)?,
            env: EnvMapGpu::new(scene.environment.as_ref()),
            engine,
            settings,
            prev_view_proj: None,
            last_graph: None,
        })
    }

    /// What this renderer does not (yet) do for `scene`, to be shown to the user rather than
    /// silently ignored.
    pub fn limitations(scene: &Scene) -> Vec<String> {
        let req = scene.requirements();
        let mut v = Vec::new();
        if !penumbra_passes::technique::IMPLEMENTED.contains(&scene.technique.as_str()) {
            v.push(format!(
                "technique '{}' is not implemented yet; rendering with '{}' (environment and local lights, no shadows)",
                scene.technique,
                penumbra_scene::DEFAULT_TECHNIQUE
            ));
        }
        if req.spatially_varying_materials {
            v.push("albedo/roughness texture maps are not applied yet; materials use their base values".into());
        }
        if req.medium {
            v.push("the participating medium is not rendered yet (no volumetric passes)".into());
        }
        if req.local_lights || req.environment_light {
            v.push("no shadows yet: visibility techniques are separate passes still to come".into());
        }
        v
    }

    pub fn context(&self) -> &Arc<Context> {
        &self.engine.ctx
    }

    pub fn scene_gpu(&self) -> &SceneGpu {
        &self.scene_gpu
    }

    /// Environment texels replaced because they were NaN, Inf or negative.
    pub fn repaired_env_texels(&self) -> usize {
        self.env.repaired_texels
    }

    /// Builds the frame graph. With `target`, tone-mapped output goes into that imported image
    /// (it needs STORAGE usage, and TRANSFER_SRC when `readback`); with `readback`, the HDR and
    /// LDR images are copied to host memory and returned by [`Renderer::render`].
    pub fn build_graph(&mut self, frame: &Frame, target: Option<ImportedImage>, readback: bool) -> Result<Graph> {
        let (w, h) = (self.settings.width, self.settings.height);
        let mut g = Graph::new();
        let mut constants = FrameConstants::new(frame, self.prev_view_proj, w, h);
        constants.params[2] = self.env.mips.len() as f32;
        constants.params[3] = self.env.intensity;
        constants.env_rot = [self.env.rotation.cos(), self.env.rotation.sin(), self.settings.tonemap.exposure, 0.0];
        for (i, c) in self.env.sh.iter().enumerate() {
            constants.sh[i] = [c[0], c[1], c[2], 0.0];
        }
        self.prev_view_proj = Some(constants.view_proj());
        let env = self.env.add(&mut self.engine, &mut g);
        let (scene, draws) = self.scene_gpu.add(&mut g, frame, &constants);
        let gb = self.gbuffer.add(&mut g, &scene, draws, w, h);
        let inputs = TechniqueInputs { frame, scene: &scene, gbuffer: &gb, env, env_data: &self.env };
        let hdr = self.technique.add(&mut self.engine, &mut g, &inputs)?;
        let target = target.map(|t| g.import_image("target", t));
        let ldr = self.tonemap.add(&mut g, hdr, target, self.settings.tonemap);
        if readback {
            penumbra_passes::readback::add(&mut g, "readback", &[(hdr, "hdr_readback"), (ldr, "ldr_readback")]);
        } else if target.is_none() {
            g.mark_output(ldr);
        }
        Ok(g)
    }

    /// Builds, compiles and submits one frame; returns the frames that finished meanwhile.
    pub fn render(&mut self, frame: &Frame, target: Option<ImportedImage>, readback: bool) -> Result<Vec<FrameImages>> {
        let g = self.build_graph(frame, target, readback)?;
        let (compiled, done) = self.engine.submit(g)?;
        self.last_graph = Some(compiled);
        Ok(done.into_iter().map(|o| self.decode(o)).collect())
    }

    /// Waits for every frame in flight.
    pub fn finish(&mut self) -> Result<Vec<FrameImages>> {
        let done = self.engine.drain()?;
        Ok(done.into_iter().map(|o| self.decode(o)).collect())
    }

    fn decode(&self, o: FrameOutput) -> FrameImages {
        let (w, h) = (self.settings.width, self.settings.height);
        let hdr = o
            .readbacks
            .get("hdr_readback")
            .map(|b| {
                b.chunks_exact(16)
                    .map(|c| {
                        let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                        [f(0), f(4), f(8), f(12)]
                    })
                    .collect()
            })
            .unwrap_or_default();
        let ldr = o.readbacks.get("ldr_readback").cloned().unwrap_or_default();
        FrameImages { frame: o.frame, width: w, height: h, hdr, ldr, gpu_ms: o.gpu_ms }
    }
}

/// An imported image description for a tone-mapped target the application owns
/// (`R8G8B8A8_UNORM`, usage STORAGE | TRANSFER_SRC), left ready for a transfer read.
pub fn target_image(image: vk::Image, view: vk::ImageView, width: u32, height: u32, usage: vk::ImageUsageFlags) -> ImportedImage {
    ImportedImage {
        image,
        view,
        desc: penumbra_engine::ImageDesc::new_2d(penumbra_passes::tonemap::LDR_FORMAT, width, height),
        usage,
        initial: None,
        initial_layout: vk::ImageLayout::UNDEFINED,
        final_access: Some(Access::TransferSrc),
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        // Pipelines and scene buffers are destroyed by the fields' drops: the GPU must be done.
        let _ = self.engine.ctx.wait_idle();
    }
}

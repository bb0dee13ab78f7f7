//! penumbra: a Vulkan rendering engine for dynamic scenes under all-frequency lighting.
//!
//! This crate is the embeddable facade. It owns the SPIR-V compiled by `build.rs` and builds
//! each frame's render graph from the scene's requirements:
//!
//! ```text
//! env_upload, textures_upload (first frame) -> gbuffer -> <technique passes> -> tonemap -> readback
//!
//! The technique (`passes::technique`) is the scene's `technique` or `RenderSettings::technique`.
//! ```
//!
//! Embedding: create a [`Renderer`] on penumbra's own device ([`Renderer::new_headless`]) or on
//! the application's (`Context::from_external`), then render into an imported image
//! ([`Renderer::render`] with a `target`). See `examples/embed.rs`.

mod error;
pub use error::{Error, ErrorKind};

pub use penumbra_engine as engine;
pub use penumbra_passes as passes;
pub use penumbra_scene as scene;

use anyhow::Result;
use glam::Mat4;
use penumbra_engine::graph::compile::CompiledGraph;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{
    vk, Access, Context, ContextDesc, Engine, FrameOutput, Graph, HostSignal, ImportedImage, SubmitSync,
};
use penumbra_passes::effect::{Effect, EffectOverrides};
use penumbra_passes::env::EnvMapGpu;
use penumbra_passes::scene_gpu::FrameConstants;
use penumbra_passes::technique::{Technique, TechniqueInputs};
use penumbra_passes::tonemap::TonemapParams;
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
    /// Overrides the scene's `technique` (any name not in `passes::registry` is an error).
    pub technique: Option<String>,
    /// The technique's parameters. `None`: the scene file's `[technique_params]` when the
    /// technique is the scene's own, none otherwise (a scene's parameters belong to its
    /// technique); `Some`: exactly these (`--param`s merged over the scene's by the CLI).
    pub technique_params: Option<penumbra_passes::registry::Params>,
    /// Also read back every G-buffer and intermediate image ([`FrameImages::dumps`]).
    pub dump_passes: bool,
    /// Overrides of the scene's effect choices.
    pub effects: EffectOverrides,
}

impl RenderSettings {
    /// `width x height` frames of `technique` with exactly `params` (a scene's own
    /// `[technique_params]`, or others), every other setting at its default.
    pub fn with_technique(
        width: u32,
        height: u32,
        technique: &str,
        params: &penumbra_passes::registry::Params,
    ) -> Self {
        RenderSettings {
            width,
            height,
            technique: Some(technique.into()),
            technique_params: Some(params.clone()),
            ..Default::default()
        }
    }
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            width: 640,
            height: 480,
            tonemap: TonemapParams::default(),
            frames_in_flight: 2,
            technique: None,
            technique_params: None,
            dump_passes: false,
            effects: EffectOverrides::default(),
        }
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
    /// With `RenderSettings::dump_passes`: every intermediate image as linear RGBA f32
    /// (name, pixels), e.g. `gb_normal`, `gb_depth`, `hdr`.
    pub dumps: Vec<(String, Vec<[f32; 4]>)>,
    /// With readback and a target that is blitted into (not written as RGBA8 storage): the
    /// target's texels as left by the blit, tightly packed in its format (e.g. BGRA8).
    pub target: Option<TargetTexels>,
    /// Where the frame's time went: the renderer's and the engine's CPU spans, the passes' GPU
    /// intervals (`render --trace` writes them as a Chrome trace).
    pub timeline: penumbra_engine::FrameTimeline,
}

/// A read-back application target (see [`FrameImages::target`]).
#[derive(Clone, Debug)]
pub struct TargetTexels {
    pub format: vk::Format,
    pub width: u32,
    pub height: u32,
    /// Tightly packed texels, row 0 at the top.
    pub bytes: Vec<u8>,
}

/// IEEE half to f32.
fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let man = (h & 0x3ff) as f32;
    match exp {
        0 => sign * man * 2f32.powi(-24),
        31 => {
            if man == 0.0 {
                sign * f32::INFINITY
            } else {
                f32::NAN
            }
        }
        e => sign * (1.0 + man / 1024.0) * 2f32.powi(e - 15),
    }
}

/// Decodes a tightly packed image readback of `format` to RGBA f32 (missing channels 0, alpha 1).
pub fn decode_texels(format: vk::Format, bytes: &[u8]) -> Option<Vec<[f32; 4]>> {
    let f32_at = |c: &[u8], i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
    let f16_at = |c: &[u8], i: usize| f16_to_f32(u16::from_le_bytes([c[i], c[i + 1]]));
    Some(match format {
        vk::Format::R32G32B32A32_SFLOAT => {
            bytes.chunks_exact(16).map(|c| [f32_at(c, 0), f32_at(c, 4), f32_at(c, 8), f32_at(c, 12)]).collect()
        }
        vk::Format::R16G16B16A16_SFLOAT => {
            bytes.chunks_exact(8).map(|c| [f16_at(c, 0), f16_at(c, 2), f16_at(c, 4), f16_at(c, 6)]).collect()
        }
        vk::Format::R16G16_SFLOAT => bytes.chunks_exact(4).map(|c| [f16_at(c, 0), f16_at(c, 2), 0.0, 1.0]).collect(),
        vk::Format::D32_SFLOAT | vk::Format::R32_SFLOAT => {
            bytes.chunks_exact(4).map(|c| [f32_at(c, 0), f32_at(c, 0), f32_at(c, 0), 1.0]).collect()
        }
        vk::Format::R8G8B8A8_UNORM => bytes
            .chunks_exact(4)
            .map(|c| [c[0] as f32 / 255.0, c[1] as f32 / 255.0, c[2] as f32 / 255.0, c[3] as f32 / 255.0])
            .collect(),
        _ => return None,
    })
}

/// The technique `settings` choose for `scene` and its parameters: `settings.technique` or the
/// scene's; `settings.technique_params`, or the scene file's when the technique is the scene's
/// own. An unregistered name is an error naming the scene file it came from.
pub fn resolve_technique(
    scene: &Scene,
    settings: &RenderSettings,
) -> Result<(String, penumbra_passes::registry::Params), Error> {
    resolve_technique_why(scene, settings, true).map(|(n, p, _)| (n, p))
}

/// [`resolve_technique`] on a device that can (`layered_rendering`, `Context::shader_output_layer`)
/// or cannot run shadowmaps, and for `auto` the line saying what it chose and why.
pub fn resolve_technique_why(
    scene: &Scene,
    settings: &RenderSettings,
    layered_rendering: bool,
) -> Result<(String, penumbra_passes::registry::Params, Option<String>), Error> {
    let name = settings.technique.clone().unwrap_or_else(|| scene.technique.clone());
    if let Err(e) = penumbra_passes::registry::check_name(&name) {
        // the name came from the scene file unless the settings override it
        let file = if settings.technique.is_none() { scene.source.as_deref() } else { None };
        return Err(Error::bad_input(file, e.to_string()));
    }
    if name == penumbra_passes::registry::AUTO {
        let (chosen, mut params, why) = penumbra_passes::registry::choose_auto(scene, layered_rendering);
        if let Some(p) = &settings.technique_params {
            params = p.clone();
        }
        return Ok((chosen.to_string(), params, Some(why)));
    }
    let params = match &settings.technique_params {
        Some(p) => p.clone(),
        None if name == scene.technique => scene.technique_params.clone(),
        None => Default::default(),
    };
    Ok((name, params, None))
}

/// Builds and runs penumbra's frame graph for one scene.
pub struct Renderer {
    // Passes hold pipelines on the context: drop them before the engine.
    gbuffer: GBufferPass,
    technique: Box<dyn Technique>,
    effects: Vec<Box<dyn Effect>>,
    /// The scene as loaded (effects read its medium, lights, ...).
    scene: Scene,
    tonemap: TonemapPass,
    hud: penumbra_passes::hud::HudPass,
    /// Drawn over the tone-mapped image of every frame while set ([`Renderer::set_overlay`]).
    overlay: Option<penumbra_passes::hud::Overlay>,
    scene_gpu: SceneGpu,
    env: EnvMapGpu,
    pub engine: Engine,
    pub settings: RenderSettings,
    prev_view_proj: Option<Mat4>,
    /// The last compiled graph (for dumps).
    pub last_graph: Option<CompiledGraph>,
    dump_formats: Vec<(String, vk::Format)>,
    /// Format of the blitted target of the last built frame (see [`FrameImages::target`]).
    target_format: Option<(vk::Format, u32, u32)>,
    /// CPU milliseconds the technique spent declaring its passes in the last built frame
    /// (`Technique::add`: its CPU work, uploads it prepares, and any readback it waits for).
    pub technique_cpu_ms: f64,
    /// When the technique started declaring its passes in the last built frame.
    technique_started: Option<std::time::Instant>,
    /// The renderer's CPU spans of frames in flight, by frame number (joined to the engine's
    /// timeline when the frame's output arrives).
    pending_spans: std::collections::BTreeMap<u64, Vec<penumbra_engine::CpuSpan>>,
    /// `technique = "auto"`: what it chose and why (the first of [`Renderer::notes`]).
    auto_choice: Option<String>,
    /// The renderer's own notes on its setup: the environment map downsampled for the device, a
    /// volumetric method asked for that the technique does not use (it integrates the medium).
    setup_notes: Vec<String>,
}

impl Renderer {
    /// A renderer on a device of its own (no window).
    pub fn new_headless(scene: &Scene, settings: RenderSettings, validation: bool) -> Result<Self, Error> {
        let ctx =
            Context::new(&ContextDesc { validation, ..Default::default() }).map_err(|e| Error::classify(e, None))?;
        Self::new(ctx, scene, settings)
    }

    /// A renderer on an existing context (own or the application's).
    pub fn new(ctx: Arc<Context>, scene: &Scene, settings: RenderSettings) -> Result<Self, Error> {
        Self::new_with_shaders(ctx, scene, settings, &shader_library())
    }

    /// [`Renderer::new`] with another shader library, e.g. one recompiled from `glsl/` at run
    /// time ([`ShaderLibrary::reload_all`], the viewer's hot reload).
    pub fn new_with_shaders(
        ctx: Arc<Context>,
        scene: &Scene,
        settings: RenderSettings,
        shaders: &ShaderLibrary,
    ) -> Result<Self, Error> {
        if settings.width == 0 || settings.height == 0 || settings.width > 16384 || settings.height > 16384 {
            return Err(Error::bad_input(
                None,
                format!("image size {}x{} is out of range (1..16384)", settings.width, settings.height),
            ));
        }
        let (name, params, chosen) = resolve_technique_why(scene, &settings, ctx.shader_output_layer)?;
        let mut r = Self::create(ctx, scene, settings, shaders, &name, &params)
            .map_err(|e| Error::classify(e, scene.source.as_deref()))?;
        r.auto_choice = chosen;
        Ok(r)
    }

    fn create(
        ctx: Arc<Context>,
        scene: &Scene,
        settings: RenderSettings,
        shaders: &ShaderLibrary,
        name: &str,
        params: &penumbra_passes::registry::Params,
    ) -> Result<Self> {
        // Bad environment texels (NaN, infinite, negative: possible in a scene built in code;
        // the loader repairs files) are black for every technique, not only for the GPU map.
        let repaired;
        let bad_texels = scene.environment.as_ref().map_or(0, |e| e.bad_texels());
        let scene = match &scene.environment {
            Some(e) if e.bad_texels() > 0 => {
                let mut s = scene.clone();
                if let Some(e) = s.environment.as_mut() {
                    e.repair_texels();
                }
                repaired = s;
                &repaired
            }
            _ => scene,
        };
        let engine = Engine::new(ctx.clone(), settings.frames_in_flight)?;
        let technique = penumbra_passes::registry::create(name, &ctx, shaders, scene, params)?;
        let mut effects = penumbra_passes::effect::create_for(scene, &ctx, shaders, &settings.effects)?;
        // a technique that integrates the medium itself (mc) gets no volumetric effect on top
        let mut setup_notes = Vec::new();
        if technique.renders_medium() {
            effects.retain(|e| e.name() != "volumetric");
            if let Some(m) = &settings.effects.volumetric {
                setup_notes.push(format!(
                    "{} integrates the medium itself (attenuation and single scattering, as the reference): the volumetric method '{m}' is not used",
                    technique.name()
                ));
            }
        }
        // An environment map over the device's largest image side is halved until it fits, and
        // the user is told (the loader's own limit, 16384, is what lavapipe allows).
        let fitted =
            scene.environment.as_ref().and_then(|e| penumbra_passes::env::fit_to_device(e, ctx.max_image_dimension_2d));
        setup_notes.extend(fitted.as_ref().zip(scene.environment.as_ref()).map(|(f, e)| {
            format!(
                "the environment map ({}x{}) is larger than this device's largest image side ({}): shown downsampled to {}x{}",
                e.width, e.height, ctx.max_image_dimension_2d, f.width, f.height
            )
        }));
        let mut env = EnvMapGpu::new(fitted.as_ref().or(scene.environment.as_ref()));
        env.repaired_texels = bad_texels;
        Ok(Renderer {
            gbuffer: GBufferPass::new(&ctx, shaders)?,
            technique,
            effects,
            scene: scene.clone(),
            tonemap: TonemapPass::new(&ctx, shaders)?,
            hud: penumbra_passes::hud::HudPass::new(&ctx, shaders)?,
            overlay: None,
            scene_gpu: SceneGpu::new(&ctx, scene)?,
            env,
            setup_notes,
            engine,
            settings,
            prev_view_proj: None,
            last_graph: None,
            dump_formats: Vec::new(),
            target_format: None,
            technique_cpu_ms: 0.0,
            technique_started: None,
            pending_spans: Default::default(),
            auto_choice: None,
        })
    }

    /// What this renderer does not do for `scene`, to be shown to the user rather than
    /// silently ignored.
    pub fn limitations(scene: &Scene) -> Vec<String> {
        let req = scene.requirements();
        let mut v = Vec::new();
        if scene.technique == "env" && (req.local_lights || req.environment_light) {
            v.push("technique 'env' renders no shadows (try --technique mc, shadowmaps, isg, ...)".into());
        }
        v
    }

    /// What this renderer does not do for its scene, with the technique actually used
    /// (`RenderSettings::technique` overrides the scene's): [`Renderer::limitations`] plus what
    /// the technique reports ([`Technique::limitations`]).
    pub fn notes(&self) -> Vec<String> {
        let mut scene = self.scene.clone();
        if let Some(t) = &self.settings.technique {
            scene.technique = t.clone();
        }
        let mut v: Vec<String> = self.auto_choice.iter().cloned().collect();
        v.extend(self.setup_notes.iter().cloned());
        v.extend(Self::limitations(&scene));
        v.extend(self.technique.limitations(&self.scene));
        v.extend(self.technique.notes(&self.scene));
        v.extend(self.effects.iter().flat_map(|e| e.notes()));
        v
    }

    /// The registered name of the technique this renderer runs (what `auto` chose, if asked).
    pub fn technique_name(&self) -> &'static str {
        self.technique.name()
    }

    /// The technique's limitations for this renderer's scene ([`Technique::limitations`]): what
    /// it ignores or approximates, without the renderer-level notes of [`Renderer::notes`].
    pub fn technique_limitations(&self) -> Vec<String> {
        self.technique.limitations(&self.scene)
    }

    /// The technique's statistics of its last frame as its own type `T` (e.g.
    /// `passes::avs::AvsStats`, `passes::vv::VvStats`); `None` when the technique keeps none or
    /// keeps another type.
    pub fn technique_stats<T: 'static>(&self) -> Option<T> {
        self.technique.stats()?.downcast::<T>().ok().map(|b| *b)
    }

    /// For a Monte Carlo technique, the samples per pixel of its last image.
    pub fn technique_samples_per_pixel(&self) -> Option<u32> {
        self.technique.samples_per_pixel()
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

    /// Sets (or clears) an overlay drawn over the tone-mapped image of the frames built from
    /// now on (a heads-up display: `penumbra view`'s H key); the HDR image is not touched.
    pub fn set_overlay(&mut self, overlay: Option<penumbra_passes::hud::Overlay>) {
        self.overlay = overlay;
    }

    /// Builds the frame graph (first the technique's `prepare`, the one step that may wait on the
    /// GPU: avs's adaptation rounds). With `target`, tone-mapped output goes into that imported image
    /// (written as a storage image when it is `R8G8B8A8_UNORM` with STORAGE usage, else blitted
    /// into: it then needs TRANSFER_DST usage and a blittable colour format); with `readback`, the HDR and
    /// LDR images are copied to host memory and returned by [`Renderer::render`].
    pub fn build_graph(
        &mut self,
        frame: &Frame,
        target: Option<ImportedImage>,
        readback: bool,
    ) -> Result<Graph, Error> {
        self.build_graph_outputs(frame, target.into(), readback)
    }

    /// [`Renderer::build_graph`] writing every image of `outputs` (tone-mapped, HDR, depth).
    pub fn build_graph_outputs(&mut self, frame: &Frame, outputs: Outputs, readback: bool) -> Result<Graph, Error> {
        let (w, h) = (self.settings.width, self.settings.height);
        for (what, img, fits) in [
            (
                "HDR",
                &outputs.hdr,
                "a colour format with blit support (a float one keeps the radiance: R32G32B32A32_SFLOAT exactly) and TRANSFER_DST usage",
            ),
            ("depth", &outputs.depth, "D32_SFLOAT with TRANSFER_DST usage"),
        ] {
            let Some(img) = img else { continue };
            let d = &img.desc;
            let format_ok = if what == "depth" {
                d.format == penumbra_passes::gbuffer::DEPTH_FORMAT
            } else {
                d.aspect() == vk::ImageAspectFlags::COLOR
            };
            if (d.width, d.height) != (w, h) || !format_ok || !img.usage.contains(vk::ImageUsageFlags::TRANSFER_DST) {
                return Err(Error::bad_input(
                    None,
                    format!(
                        "the {what} output is {}x{} {:?} with usage {:?}: it must be the render size {w}x{h}, {fits}",
                        d.width, d.height, d.format, img.usage
                    ),
                ));
            }
        }
        self.build_graph_inner(frame, outputs, readback).map_err(|e| Error::classify(e, None))
    }

    fn build_graph_inner(&mut self, frame: &Frame, outputs: Outputs, readback: bool) -> Result<Graph> {
        let Outputs { ldr: target, hdr: hdr_out, depth: depth_out } = outputs;
        let (w, h) = (self.settings.width, self.settings.height);
        // collect the frames the GPU has finished (never waits): their late readbacks reach this
        // frame's technique
        self.engine.poll()?;
        // the technique's setup, which may wait on the GPU (avs's adaptation rounds); everything
        // after declares the frame through a FrameStore, which cannot submit
        let t0 = std::time::Instant::now();
        self.technique
            .prepare(&mut self.engine, &penumbra_passes::technique::PrepareInputs { frame, width: w, height: h })?;
        let prepare_ms = t0.elapsed().as_secs_f64() * 1e3;
        let mut store = penumbra_engine::FrameStore::new(&mut self.engine);
        let mut g = Graph::new();
        let mut constants = FrameConstants::new(frame, self.prev_view_proj, w, h);
        constants.params[2] = self.env.mips.len() as f32;
        constants.env_rot[2] = self.settings.tonemap.exposure;
        self.prev_view_proj = Some(constants.view_proj());
        let env = self.env.add(&mut store, &mut g);
        let (scene, draws) = self.scene_gpu.add(&mut g, frame, &constants);
        let gb = self.gbuffer.add(&mut g, &scene, draws.clone(), w, h);
        // one set of frame inputs for the technique and the effects
        let inputs = TechniqueInputs {
            scene: &self.scene,
            frame,
            handles: &scene,
            draws: &draws,
            gbuffer: &gb,
            env,
            env_data: &self.env,
        };
        let t1 = std::time::Instant::now();
        let mut hdr = self.technique.add(&mut store, &mut g, &inputs)?;
        self.technique_cpu_ms = prepare_ms + t1.elapsed().as_secs_f64() * 1e3;
        self.technique_started = Some(t0);
        for e in &mut self.effects {
            hdr = e.add(&mut store, &mut g, &inputs, hdr)?;
        }
        // The tone map writes a storage image: straight into an RGBA8 target with STORAGE usage,
        // else into a transient image blitted into the target (a BGRA8/sRGB swapchain image).
        let direct = target.as_ref().is_some_and(|t| {
            t.desc.format == penumbra_passes::tonemap::LDR_FORMAT && t.usage.contains(vk::ImageUsageFlags::STORAGE)
        });
        let target = target.map(|t| g.import_image("target", t));
        // the host's HDR and depth images: copies of the frame's (same size; the blit converts
        // the float format, depth must match)
        if let Some(o) = hdr_out {
            let o = g.import_image("output_hdr", o);
            penumbra_passes::blit::add(&mut g, "output_hdr", hdr, o);
        }
        if let Some(o) = depth_out {
            let o = g.import_image("output_depth", o);
            penumbra_passes::blit::add(&mut g, "output_depth", gb.depth, o);
        }
        let mut ldr = self.tonemap.add(&mut g, hdr, target.filter(|_| direct), self.settings.tonemap);
        if let Some(o) = &self.overlay {
            ldr = self.hud.add(&mut g, ldr, o);
        }
        let mut blitted = None;
        if let (Some(t), false) = (target, direct) {
            blitted = Some(penumbra_passes::blit::add(&mut g, "blit_target", ldr, t));
        }
        if self.settings.dump_passes {
            let dumps: Vec<(penumbra_engine::ImageHandle, String)> = [
                (gb.position, "gb_position"),
                (gb.normal, "gb_normal"),
                (gb.uv_mat, "gb_uv_mat"),
                (gb.motion, "gb_motion"),
                (gb.depth, "gb_depth"),
                (hdr, "hdr"),
            ]
            .into_iter()
            .map(|(h, n)| (h, format!("dump:{n}")))
            .collect();
            let refs: Vec<_> = dumps.iter().map(|(h, n)| (*h, n.as_str())).collect();
            penumbra_passes::readback::add(&mut g, "dump_passes", &refs);
            self.dump_formats = dumps.iter().map(|(h, n)| (n.clone(), g.image_desc(*h).format)).collect();
        }
        self.target_format = blitted.map(|t| {
            let d = g.image_desc(t);
            (d.format, d.width, d.height)
        });
        if let (true, Some(t)) = (readback, blitted) {
            // What the blit left in the application's (e.g. swapchain) image, in its format.
            penumbra_passes::readback::add(&mut g, "readback_target", &[(t, "target_readback")]);
        }
        if readback {
            penumbra_passes::readback::add(&mut g, "readback", &[(hdr, "hdr_readback"), (ldr, "ldr_readback")]);
        } else if target.is_none() {
            g.mark_output(ldr);
        }
        Ok(g)
    }

    /// Builds, compiles and submits one frame; returns the frames that finished meanwhile.
    pub fn render(
        &mut self,
        frame: &Frame,
        target: Option<ImportedImage>,
        readback: bool,
    ) -> Result<Vec<FrameImages>, Error> {
        self.render_with(frame, target, readback, &SubmitSync::default())
    }

    /// [`Renderer::render`] whose submission waits on and signals semaphores (a window's
    /// swapchain: see `penumbra view`).
    pub fn render_with(
        &mut self,
        frame: &Frame,
        target: Option<ImportedImage>,
        readback: bool,
        sync: &SubmitSync,
    ) -> Result<Vec<FrameImages>, Error> {
        self.render_outputs(frame, target.into(), readback, sync)
    }

    /// [`Renderer::render_with`] writing every image of `outputs`: the tone-mapped target, and
    /// copies of the frame's HDR radiance and G-buffer depth into the host's images.
    pub fn render_outputs(
        &mut self,
        frame: &Frame,
        outputs: Outputs,
        readback: bool,
        sync: &SubmitSync,
    ) -> Result<Vec<FrameImages>, Error> {
        Ok(self
            .run_frame(frame, outputs, readback, |engine, g| engine.submit_with(g, sync).map(|(c, d)| (c, d, ())))?
            .0)
    }

    /// Records the frame into the host's command buffer `cmd` instead of submitting it (the
    /// host's frame loop or frame graph runs penumbra's passes in its own submission): the
    /// `outputs` (a tone-mapped target, or [`Outputs`] with HDR and depth) enter and leave in the
    /// states their [`ImportedImage`]s declare, as when penumbra submits.
    /// `cmd` must be begun, outside a render pass, for the context's queue family; pipeline,
    /// descriptor and push-constant state bound before is not kept. The host submits `cmd` once,
    /// signalling the returned [`HostFrame::signal`] in that same submission
    /// ([`HostSignal::submit_info`]); penumbra never waits on the device for it, and the frame's
    /// images come back from a later `render`/`record_into`/[`Renderer::finish`]. `cmd` must be
    /// submitted (the renderer's resources already count the frame as run): a host that cannot
    /// signals the value itself (`vkSignalSemaphore`) and drops the renderer. Needs the
    /// `timelineSemaphore` feature ([`penumbra_engine::ExternalFeatures::timeline_semaphore`]).
    pub fn record_into(
        &mut self,
        frame: &Frame,
        outputs: impl Into<Outputs>,
        readback: bool,
        cmd: vk::CommandBuffer,
    ) -> Result<HostFrame, Error> {
        let (done, signal) = self.run_frame(frame, outputs.into(), readback, |engine, g| engine.record_into(g, cmd))?;
        Ok(HostFrame { signal, done })
    }

    /// Builds the frame's graph and hands it to `go` (submit, or record into the host's command
    /// buffer); keeps the CPU spans for the frame's timeline.
    fn run_frame<T>(
        &mut self,
        frame: &Frame,
        outputs: Outputs,
        readback: bool,
        go: impl FnOnce(&mut Engine, Graph) -> anyhow::Result<(CompiledGraph, Vec<FrameOutput>, T)>,
    ) -> Result<(Vec<FrameImages>, T), Error> {
        let tb = std::time::Instant::now();
        let g = self.build_graph_outputs(frame, outputs, readback)?;
        let mut spans =
            vec![penumbra_engine::CpuSpan { name: "build graph", start: tb, ms: tb.elapsed().as_secs_f64() * 1e3 }];
        if let Some(t) = self.technique_started.take() {
            spans.push(penumbra_engine::CpuSpan { name: "technique", start: t, ms: self.technique_cpu_ms });
        }
        let frame_no = self.engine.next_frame();
        let (compiled, done, extra) = match go(&mut self.engine, g) {
            Ok(r) => r,
            Err(e) => {
                // One-time uploads declared in the failed frame must be declared again.
                self.scene_gpu.invalidate_uploads();
                return Err(Error::classify(e, None));
            }
        };
        self.last_graph = Some(compiled);
        self.pending_spans.insert(frame_no, spans);
        Ok((self.decode_all(done), extra))
    }

    fn decode_all(&mut self, done: Vec<FrameOutput>) -> Vec<FrameImages> {
        let mut out = Vec::with_capacity(done.len());
        for mut o in done {
            if let Some(mut spans) = self.pending_spans.remove(&o.frame) {
                spans.append(&mut o.timeline.cpu_spans);
                o.timeline.cpu_spans = spans;
            }
            out.push(self.decode(o));
        }
        out
    }

    /// Waits for every frame in flight.
    pub fn finish(&mut self) -> Result<Vec<FrameImages>, Error> {
        let done = self.engine.drain().map_err(|e| Error::classify(e, None))?;
        Ok(self.decode_all(done))
    }

    fn decode(&self, o: FrameOutput) -> FrameImages {
        let (w, h) = (self.settings.width, self.settings.height);
        let hdr = o
            .readbacks
            .get("hdr_readback")
            .and_then(|b| decode_texels(vk::Format::R32G32B32A32_SFLOAT, b))
            .unwrap_or_default();
        let ldr = o.readbacks.get("ldr_readback").cloned().unwrap_or_default();
        let dumps = self
            .dump_formats
            .iter()
            .filter_map(|(name, fmt)| {
                let bytes = o.readbacks.get(name)?;
                Some((name.trim_start_matches("dump:").to_string(), decode_texels(*fmt, bytes)?))
            })
            .collect();
        let target = self
            .target_format
            .zip(o.readbacks.get("target_readback").cloned())
            .map(|((format, width, height), bytes)| TargetTexels { format, width, height, bytes });
        FrameImages {
            frame: o.frame,
            width: w,
            height: h,
            hdr,
            ldr,
            gpu_ms: o.gpu_ms,
            dumps,
            target,
            timeline: o.timeline,
        }
    }
}

/// The host's images a frame writes ([`Renderer::render_outputs`], [`Renderer::record_into`]):
/// `ldr`, the tone-mapped image (as `target` elsewhere); `hdr`, a copy of the linear radiance
/// (a float colour format, blitted: R32G32B32A32_SFLOAT exact, R16G16B16A16_SFLOAT rounded);
/// `depth`, a copy of the G-buffer's depth (`D32_SFLOAT`, the camera's projection, 1 = far).
/// HDR and depth images are the render size with TRANSFER_DST usage; each enters and leaves in
/// the states its [`ImportedImage`] declares.
#[derive(Clone, Debug, Default)]
pub struct Outputs {
    pub ldr: Option<ImportedImage>,
    pub hdr: Option<ImportedImage>,
    pub depth: Option<ImportedImage>,
}

impl From<Option<ImportedImage>> for Outputs {
    fn from(ldr: Option<ImportedImage>) -> Self {
        Outputs { ldr, ..Default::default() }
    }
}

/// A frame recorded into a host's command buffer ([`Renderer::record_into`]).
#[derive(Debug)]
pub struct HostFrame {
    /// What the host's submission of the command buffer must signal.
    pub signal: HostSignal,
    /// Frames that completed meanwhile (as [`Renderer::render`] returns them).
    pub done: Vec<FrameImages>,
}

/// An imported image description for a tone-mapped target the application owns
/// (`R8G8B8A8_UNORM`, usage STORAGE | TRANSFER_SRC), left ready for a transfer read.
pub fn target_image(
    image: vk::Image,
    view: vk::ImageView,
    width: u32,
    height: u32,
    usage: vk::ImageUsageFlags,
) -> ImportedImage {
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
        // Pipelines and scene buffers are destroyed by the fields' drops: the GPU must be done
        // with every frame of this renderer (its own frames only: a host's device keeps running
        // the host's work); a frame that does not finish within the engine's timeout (a hung
        // GPU, a host that never submitted) leaves only the device-wide wait
        if self.engine.drain().is_err() {
            let _ = self.engine.ctx.wait_idle();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_floats_decode() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert!(f16_to_f32(0x7c00).is_infinite());
        assert!(f16_to_f32(0x7e00).is_nan());
        let t = decode_texels(vk::Format::R16G16_SFLOAT, &[0x00, 0x3c, 0x00, 0xc0]).unwrap();
        assert_eq!(t, vec![[1.0, -2.0, 0.0, 1.0]]);
        assert!(decode_texels(vk::Format::BC1_RGB_UNORM_BLOCK, &[0; 8]).is_none());
    }
}

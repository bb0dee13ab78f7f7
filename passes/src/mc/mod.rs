//! The GPU Monte Carlo baseline, technique `mc` (`glsl/mc/mc.comp`): the "GPU-based Monte Carlo ray
//! tracing" the papers compare against, on the compute tracer of [`crate::trace`].
//!
//! Per pixel and frame, [`McTechnique::spp`] samples of the CPU reference's estimator
//! (`penumbra_reference::render`): a primary ray through a uniformly jittered position in the
//! pixel (from the near plane, closest hit through the kd-tree), and at the hit one environment
//! sample (texel chosen with probability proportional to luminance x texel solid angle, as the
//! reference's alias table, here by marginal/conditional CDFs), one sample per local light
//! (point, spot, sphere: `penumbra_reference::lights`) and one BRDF sample (the reference's
//! diffuse/specular mixture), combined by the power heuristic (sphere lights and the environment;
//! delta lights unweighted), each with an any-hit shadow ray through the tree. Same BRDFs (`penumbra_reference::brdf`), two-sided surfaces
//! (geometric normal towards the viewer, directions below it blocked), shading normals and
//! tangent frames, shadow-ray offset `3e-5 (1 + max |p|)` along the geometric normal, and
//! `casts_shadow = false` objects ignored by shadow rays. Primary rays that miss see the
//! environment.
//!
//! Progressive: a persistent RGBA32F image sums the samples (alpha counts them) and the output is
//! the mean; it restarts when the camera, an object, a deformation, a light, a material or the
//! environment's rotation or intensity changed, when the tree was rebuilt, or when the image is
//! new (first frame, resize).
//!
//! Texture maps (albedo multiplies, roughness G channel multiplies roughness and sets Phong-type
//! exponents to `2 / r^2 - 2`) are sampled bilinearly from the scene's texture array
//! ([`crate::textures`], layers resampled to 256^2, so slightly smoother than the reference's
//! texels). Materials are the scene's one material model (`glsl/include/material.glsl`), with
//! anisotropic Ashikhmin-Shirley exponents. The participating medium as the reference has it
//! (session 33): camera rays attenuated from the eye, single scattering with one distance sample
//! per strategy (the transmittance and equiangular sampling per positional light, balance
//! heuristic) lit by the environment, the local lights and a Henyey-Greenstein phase sample
//! (power heuristic); `mc` then replaces the volumetric effect ([`crate::technique::Technique::renders_medium`]).
//! `mc-denoised` keeps the effect (its ratio estimator is of surface light).
//!
//! [`denoise`]: the variant `mc-denoised`, a few samples per frame filtered spatio-temporally.

pub mod denoise;

use crate::env::EnvTables;
use crate::kdtree::{world_triangles_shading, KdTreeBuilder, KdTreeHandles};
use crate::scene_gpu::FrameConstants;
use crate::shade_env::HDR_FORMAT;
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline};
use anyhow::Result;
use glam::Vec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_scene::{Frame, Scene};
use std::sync::Arc;

/// Local lights as `penumbra_reference::lights::LocalLight::new` keeps them (lights that cannot
/// emit are dropped): 4 vec4 each, the layout of `lights` in `glsl/mc/mc.comp`; the fourth
/// holds the medium's extinction `sigma_t` in yzw (zero without a medium), by which local light
/// is attenuated on its way in.
pub fn light_table(lights: &[penumbra_scene::LightInstance], sigma_t: Vec3) -> Vec<[f32; 4]> {
    use penumbra_scene::LightKind;
    let mut out = Vec::new();
    for l in lights {
        let p = l.power;
        if !p.is_finite() || p.max_element() <= 0.0 || !l.position.is_finite() {
            continue;
        }
        let power = p.max(Vec3::ZERO);
        let pos = l.position;
        match l.kind {
            LightKind::Point => {
                out.extend([
                    [pos.x, pos.y, pos.z, 0.0],
                    [0.0; 4],
                    [power.x, power.y, power.z, 0.0],
                    [0.0, sigma_t.x, sigma_t.y, sigma_t.z],
                ]);
            }
            LightKind::Spot { inner_deg, outer_deg } => {
                let axis = l.direction.normalize_or_zero();
                if axis == Vec3::ZERO || !axis.is_finite() {
                    continue;
                }
                let ci = inner_deg.clamp(0.0, 180.0).to_radians().cos();
                let co = outer_deg.clamp(0.0, 180.0).to_radians().cos();
                out.extend([
                    [pos.x, pos.y, pos.z, 1.0],
                    [axis.x, axis.y, axis.z, co],
                    [power.x, power.y, power.z, ci],
                    [0.0, sigma_t.x, sigma_t.y, sigma_t.z],
                ]);
            }
            LightKind::Directional => {
                let d = l.direction.normalize_or_zero();
                if d == Vec3::ZERO || !d.is_finite() {
                    continue;
                }
                out.extend([
                    [0.0, 0.0, 0.0, 3.0],
                    [d.x, d.y, d.z, 0.0],
                    [power.x, power.y, power.z, 0.0],
                    [0.0, sigma_t.x, sigma_t.y, sigma_t.z],
                ]);
            }
            LightKind::Sphere { radius } => {
                if !(radius.is_finite() && radius > 0.0) {
                    continue;
                }
                out.extend([
                    [pos.x, pos.y, pos.z, 2.0],
                    [0.0; 4],
                    [power.x, power.y, power.z, 0.0],
                    [radius, sigma_t.x, sigma_t.y, sigma_t.z],
                ]);
            }
        }
    }
    out
}

/// What [`McTechnique::add_frame`] declared.
pub struct McFrame {
    /// The frame's radiance (the accumulated mean when progressive).
    pub hdr: ImageHandle,
    /// The frame's material table.
    pub materials: BufferHandle,
    /// The same samples' unshadowed estimate ([`McTechnique::unshadowed`]).
    pub unshadowed: Option<ImageHandle>,
}

/// Technique `mc`.
pub struct McTechnique {
    pipeline: Pipeline,
    textures: crate::textures::MaterialTextures,
    /// The renderer's texture array for the frame being declared (see `Technique::add`).
    scene_textures: Option<ImageHandle>,
    repeat: crate::util::Sampler,
    extras: Vec<penumbra_scene::MaterialExtra>,
    pub builder: KdTreeBuilder,
    scene: Scene,
    env: EnvTables,
    /// Samples per pixel per frame (default 4).
    pub spp: u32,
    /// Primary rays jittered over the pixel (anti-aliased, like the CPU reference's default);
    /// `false`: through the pixel centre, where rasterizing techniques sample (the accuracy
    /// matrix's pixel-grid references).
    pub aa: bool,
    /// Accumulate over frames while nothing changes (`mc`); `false`: every frame's image holds
    /// only its own `spp` samples (`mc-denoised` accumulates with reprojection instead).
    pub progressive: bool,
    /// Also write each frame's unshadowed estimate (the same samples, every shadow ray taken as
    /// unoccluded: the denominator of `mc-denoised`'s ratio estimator). Only with `progressive =
    /// false` and at most [`MAX_SPP_PER_DISPATCH`] samples per frame.
    pub unshadowed: bool,
    frame_index: u32,
    /// The scene's medium (sigma_t, sigma_s, Henyey-Greenstein g), integrated by `mc` itself
    /// (attenuation from the eye and single scattering, as the reference) unless the unshadowed
    /// estimate is asked (`mc-denoised`, whose volumetric effect then adds it).
    medium: Option<(Vec3, Vec3, f32)>,
    /// The frame index that started the accumulation: the seed of its sample sequence.
    sequence_seed: u32,
    /// Samples per pixel accumulated in the image after the last frame.
    pub accumulated: u32,
    tri_count: Option<usize>,
}

/// Samples per pixel per frame unless `spp` says otherwise. 8: at 4, through one position per
/// pixel (the matrix's 40x30 cells), the noise in the shadows of a moving scene (no accumulation)
/// still hid more than half of the shadow (`shadow_recovered` 0.30-0.47 on bunny, coarse and
/// sf_bowling; 0.61-0.68 at 8). README "mc's samples per pixel (session 48)".
pub const DEFAULT_SPP: u32 = 8;

/// Most samples per pixel in one dispatch: a frame with more is split into several.
pub const MAX_SPP_PER_DISPATCH: u32 = 256;

/// Most samples per pixel per frame.
pub const MAX_SPP: u32 = 16384;

impl McTechnique {
    /// Sets one `[technique_params]` entry (`spp` 1..=16384, `aa`); any other key is an error.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("mc", key, value);
        match p.key() {
            "spp" => self.spp = p.int(1, MAX_SPP as u64)? as u32,
            "aa" => self.aa = p.flag()?,
            _ => return Err(p.unknown("spp, aa")),
        }
        Ok(())
    }

    /// Whether this technique integrates the scene's medium itself (a medium, and no unshadowed
    /// estimate asked): then the renderer adds no volumetric effect.
    pub fn renders_medium(&self) -> bool {
        self.medium.is_some() && !self.unshadowed
    }

    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene) -> Result<Self> {
        let pipeline = compute_pipeline(ctx, shaders, "mc/mc.comp", 112)?;
        Ok(McTechnique {
            pipeline,
            textures: crate::textures::MaterialTextures::new(ctx, &scene.textures)?,
            scene_textures: None,
            repeat: crate::util::Sampler::repeat(ctx)?,
            extras: (0..scene.materials.len()).map(|i| scene.material_extra(i)).collect(),
            medium: scene.medium.map(|m| (m.sigma_t().max(Vec3::ZERO), m.sigma_s.max(Vec3::ZERO), m.g)),
            builder: KdTreeBuilder::new(ctx, shaders)?,
            scene: scene.clone(),
            env: EnvTables::new(scene.environment.as_ref()),
            spp: DEFAULT_SPP,
            aa: true,
            progressive: true,
            unshadowed: false,
            frame_index: 0,
            sequence_seed: 0,
            accumulated: 0,
            tri_count: None,
        })
    }

    /// Declares the tree (rebuilt when geometry changed) and the `mc` pass; returns the HDR image,
    /// the frame's material table (uploaded once for the passes that follow, `mc-denoised`'s
    /// demodulation) and, with [`McTechnique::unshadowed`], the unshadowed estimate.
    pub fn add_frame(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        frame: &Frame,
        width: u32,
        height: u32,
    ) -> Result<McFrame> {
        anyhow::ensure!(
            !self.unshadowed || (!self.progressive && self.spp <= MAX_SPP_PER_DISPATCH),
            "mc: the unshadowed estimate is written per frame by one dispatch (progressive off, at most {MAX_SPP_PER_DISPATCH} samples per pixel)"
        );
        let geometry_changed = frame.any_moved() || frame.any_deformed();
        let kept =
            if geometry_changed || self.tri_count.is_none() { None } else { self.builder.add_kept(engine, graph) };
        // Triangle shading data lives beside the tree (same triangle order).
        let (tree, tridata, rebuilt): (KdTreeHandles, BufferHandle, bool) = match kept {
            Some(t) => {
                let n = self.tri_count.unwrap_or(0);
                let td = engine.persistent_buffer(graph, "mc.tridata", (n as u64 * 96).max(16));
                if graph.persistent_is_new(td) {
                    let (_, data, _) = world_triangles_shading(&self.scene, frame)?;
                    let td = Self::persistent_upload_into(graph, td, bytes_of(&data));
                    (t, td, true)
                } else {
                    (t, td, false)
                }
            }
            None => {
                let (tris, data, no_shadow) = world_triangles_shading(&self.scene, frame)?;
                let t = self.builder.add_triangles_flagged(engine, graph, &tris, Some(&no_shadow), true)?;
                let td = crate::util::persistent_upload(engine, graph, "mc.tridata", bytes_of(&data), true);
                self.tri_count = Some(tris.len());
                (t, td, true)
            }
        };
        let env_texels =
            crate::util::persistent_upload(engine, graph, "mc.env_texels", bytes_of(&self.env.texels), false);
        let env_cdf = crate::util::persistent_upload(engine, graph, "mc.env_cdf", bytes_of(&self.env.cdf), false);
        let materials =
            graph.create_buffer_init("mc.materials", crate::scene_gpu::material_table(&frame.materials, &self.extras));
        // Inside the renderer the scene's texture array is already in the graph; standalone
        // (tests, benches) the technique imports its own copy.
        let textures = match self.scene_textures.take() {
            Some(t) => t,
            None => self.textures.add(graph),
        };
        // the medium's extinction (zero without one) attenuates local light on its way in
        let light_data = light_table(&frame.lights, self.medium.map_or(Vec3::ZERO, |m| m.0));
        let light_count = (light_data.len() / 4) as u32;
        let lights = graph
            .create_buffer_init("mc.lights", if light_data.is_empty() { vec![0u8; 64] } else { bytes_of(&light_data) });
        let accum = engine.persistent_image(graph, "mc.accum", ImageDesc::new_2d(HDR_FORMAT, width, height));
        // the environment turned and scaled to this frame's state (the tables stay as built)
        let env_changed = self.env.set_state(frame.environment);
        let reset = graph.persistent_is_new(accum)
            || env_changed
            || rebuilt
            || geometry_changed
            || frame.camera_moved
            || !frame.materials_changed.is_empty()
            || frame.lights.iter().any(|l| l.moved)
            || self.accumulated == 0
            || !self.progressive;
        if reset {
            self.accumulated = 0;
        }
        let hdr = graph.create_image("mc.hdr", ImageDesc::new_2d(HDR_FORMAT, width, height));
        // the unshadowed estimate, or a 1 x 1 stand-in the shader does not write
        let (uw, uh) = if self.unshadowed { (width, height) } else { (1, 1) };
        let mut unshadowed = graph.create_image("mc.unshadowed", ImageDesc::new_2d(HDR_FORMAT, uw, uh));
        let inv_vp = FrameConstants::new(frame, None, width, height).inv_view_proj;
        // the medium: (sigma_t, on), (sigma_s, g), (eye, 0) (glsl/mc/mc.comp `medium`)
        let (st, ss, g) = self.medium.unwrap_or((Vec3::ZERO, Vec3::ZERO, 0.0));
        let on = self.renders_medium() as u32 as f32;
        let eye = frame.camera.eye;
        let medium_data: [[f32; 4]; 3] = [[st.x, st.y, st.z, on], [ss.x, ss.y, ss.z, g], [eye.x, eye.y, eye.z, 0.0]];
        let medium = graph.create_buffer_init("mc.medium", bytes_of(&medium_data));
        // Long frames are split into dispatches of at most MAX_SPP_PER_DISPATCH samples (one
        // pass each, the accumulator carried between them): no single dispatch runs long
        // enough for a desktop driver's watchdog.
        let chunks = self.spp.div_ceil(MAX_SPP_PER_DISPATCH).max(1);
        let mut accum = accum;
        let mut hdr = hdr;
        for chunk in 0..chunks {
            let spp = (self.spp - chunk * MAX_SPP_PER_DISPATCH).min(MAX_SPP_PER_DISPATCH);
            let mut push: Vec<u8> = Vec::with_capacity(112);
            for c in inv_vp {
                push.extend(bytes_of(&c));
            }
            // the sample sequence's seed: the frame that started the accumulation (a progressive
            // image continues one scrambled sequence, its index the accumulator's count)
            if reset && chunk == 0 {
                self.sequence_seed = self.frame_index;
            }
            push.extend(bytes_of(&[width, height, spp, self.sequence_seed]));
            push.extend(bytes_of(&[
                self.env.width,
                self.env.height,
                (reset && chunk == 0) as u32
                    | (self.env.can_sample as u32) << 1
                    | (!self.aa as u32) << 2
                    | (self.unshadowed as u32) << 3,
                light_count,
            ]));
            push.extend(bytes_of(&[self.env.cos_rot, self.env.sin_rot, self.env.intensity, 0.0]));
            self.frame_index = self.frame_index.wrapping_add(1);
            let name = if chunk == 0 { "mc".to_string() } else { format!("mc.{chunk}") };
            let mut p = graph.pass(&name, PassKind::Compute);
            let kd = tree.read(&mut p);
            let [td, mats, et, ec] =
                [tridata, materials, env_texels, env_cdf].map(|h| p.read(h, Access::ComputeShaderReadStorage));
            let acc = p.write(accum, Access::ComputeShaderReadWriteStorage);
            let out = p.write(hdr, Access::ComputeShaderWriteStorage);
            let un = p.write(unshadowed, Access::ComputeShaderWriteStorage);
            let lt = p.read(lights, Access::ComputeShaderReadStorage);
            let md = p.read(medium, Access::ComputeShaderReadStorage);
            let tex = p.read(textures, Access::ComputeShaderReadSampled);
            let repeat = self.repeat.sampler;
            let pipe = self.pipeline.handle();
            p.record(move |rc| {
                let images = [
                    Bind::StorageImage(acc),
                    Bind::StorageImage(out),
                    Bind::StorageBuffer(lt),
                    Bind::SampledImage(tex, repeat),
                    Bind::StorageImage(un),
                    Bind::StorageBuffer(md),
                ];
                let binds = [kd.binds().as_slice(), &crate::util::storage([td, mats, et, ec]), &images].concat();
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(width, 8), groups(height, 8), 1])
            });
            accum = acc;
            hdr = out;
            unshadowed = un;
        }
        self.accumulated += self.spp;
        Ok(McFrame { hdr, materials, unshadowed: self.unshadowed.then_some(unshadowed) })
    }

    fn persistent_upload_into(graph: &mut Graph, h: BufferHandle, data: Vec<u8>) -> BufferHandle {
        crate::util::upload_into(graph, "upload_mc.tridata", "mc.tridata.upload", data, h)
    }
}

impl crate::technique::Technique for McTechnique {
    fn samples_per_pixel(&self) -> Option<u32> {
        Some(self.accumulated)
    }

    fn renders_medium(&self) -> bool {
        McTechnique::renders_medium(self)
    }

    fn name(&self) -> &'static str {
        "mc"
    }
    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        self.scene_textures = Some(inputs.handles.textures);
        let r = self.add_frame(engine, graph, inputs.frame, inputs.gbuffer.width, inputs.gbuffer.height).map(|f| f.hdr);
        self.scene_textures = None;
        r
    }
}

//! The shadow-map baseline, technique `shadowmaps` (`glsl/shadowmaps/shadowmaps_depth.vert`,
//! `glsl/shadowmaps/shadowmaps_shade.comp`): the comparison of the ISG and adaptive-visibility papers.
//!
//! The environment is replaced by [`ShadowMapsSettings::count`] directional lights at stratified
//! importance samples of it (the distribution of [`crate::env::EnvTables`]: luminance x solid
//! angle), each weighted `L / (K pdf)` so that without shadows the sum estimates the environment
//! integral. Every light has an orthographic depth map of [`ShadowMapsSettings::size`]^2 texels
//! over the scene's bounding sphere; every local light a cube of six perspective maps at its
//! position ([`ShadowMapsSettings::light_size`]^2 texels each). The maps are layers of two D32
//! array images (environment, local lights), each rasterized in one pass (each draw instanced
//! once per layer, `gl_Layer` from the vertex shader: Vulkan 1.2 `shaderOutputLayer`),
//! kept across frames and re-rendered only when geometry moved or deformed or a light moved.
//! Objects with `casts_shadow = false` are not drawn into the maps.
//!
//! Shading per G-buffer pixel, with the material model's BRDF (`glsl/include/brdf_ref.glsl`,
//! texture maps applied): `shading = "lights"` is the papers' baseline, the sum over the K lights
//! of BRDF x cosine x lit fraction x weight (3x3 PCF, slope-scaled bias of 1.5 texels + 1.5 texels
//! x tan(theta), theta the light's angle to the face: the G-buffer's geometric normal, whose
//! slope the interpolated normal misrepresents on coarse meshes: vol_buddha's crown 0.235 -> 0.067
//! at 160x120); `shading = "ratio"` (default) is a ratio estimator on the `env` technique's
//! unshadowed environment lighting (`glsl/include/env_shade.glsl`), so that glossy surfaces keep
//! the environment's reflection (K delta lights alone render a glossy dish near black): its
//! diffuse part (the irradiance map) times the cosine- and weight-weighted lit fraction over the K
//! directions, its glossy part (prefiltered reflection) times the lobe-weighted lit fraction,
//! trusted as far as the directions hold the lobe's light (their estimate of its unshadowed light
//! against the prefiltered one) and four effective directions. A lobe between the directions
//! takes the darker of (a) the lit fraction under the sharpest of four von Mises-Fisher kernels
//! around the mirror direction (sharpness 128, 32, 8, 2) that they cover (so the glossy share
//! converges as K grows: balls_on_dish 160x120 0.172 at K = 32, 0.080 at K = 512, where the
//! diffuse fallback alone gave 0.204 and 0.148), then the diffuse fraction, and (b)
//! [`ShadowMapsSettings::march`] rays around the mirror direction marched through the visual hull
//! of the K maps (blocked where every map sees a point behind its depth: inside a closed
//! occluder), which finds the occluders no map looks along (balls_on_dish 0.075 at K = 32). Local
//! lights: BRDF x cosine x intensity / d^2 x lit fraction (3x3 PCF; sphere lights as points of
//! intensity L pi r^2 with PCSS soft shadows from the cube of their centre). Sky pixels show the
//! environment.

use crate::env::EnvTables;
use crate::gbuffer::DEPTH_FORMAT;
use crate::raster::{raster_pipeline, DepthState, RasterDesc, VertexInput};
use crate::shade_env::{ShadingIo, HDR_FORMAT};
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{bail, Result};
use glam::{Mat4, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_scene::{Frame, LightKind, Scene};
use std::sync::Arc;

/// How the environment's K shadowed lights make the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SmShading {
    /// The sum over the K lights (the papers' baseline).
    Lights,
    /// The unshadowed environment lighting times the lights' shadowed / unshadowed ratio.
    Ratio,
}

/// Parameters of `shadowmaps` (`[technique_params]`, see the registry).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShadowMapsSettings {
    /// Directional lights (and orthographic maps) for the environment, 1..=1024.
    pub count: u32,
    /// Resolution of the environment directions' maps (texels per side), 16..=4096 (the ISG
    /// paper's baseline: 256).
    pub size: u32,
    /// Resolution of the local lights' maps (cube faces, a directional light's map), 16..=4096:
    /// their hard shadows fall on whatever the scene holds, not on a bounding-sphere overview
    /// (vol_big and vol_complex at 160x120: 0.113 and 0.138 with 256 texels, 0.045 and 0.057 with
    /// 1024).
    pub light_size: u32,
    pub shading: SmShading,
    /// `shading = ratio`: rays around the mirror direction marched through the visual hull of the
    /// K maps where the directions do not cover a glossy lobe, 0..=16 (0: off).
    pub march: u32,
}

impl Default for ShadowMapsSettings {
    fn default() -> Self {
        ShadowMapsSettings { count: 32, size: 256, light_size: 1024, shading: SmShading::Ratio, march: 4 }
    }
}

impl ShadowMapsSettings {
    /// Sets one parameter from its scene-file text.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("shadowmaps", key, value);
        match p.key() {
            "count" => self.count = p.int(1, 1024)? as u32,
            "size" => self.size = p.int(16, 4096)? as u32,
            "light_size" => self.light_size = p.int(16, 4096)? as u32,
            "shading" => self.shading = p.choice(&[("lights", SmShading::Lights), ("ratio", SmShading::Ratio)])?,
            "march" => self.march = p.int(0, 16)? as u32,
            _ => return Err(p.unknown("count, size, light_size, shading, march")),
        }
        Ok(())
    }

    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> Result<Self> {
        crate::technique::settings_from_params(params, Self::set)
    }
}

/// Technique `shadowmaps`.
pub struct ShadowMapsTechnique {
    depth_pipe: Pipeline,
    shade_pipe: Pipeline,
    nearest: Sampler,
    latlong: Sampler,
    repeat: Sampler,
    env: EnvTables,
    settings: ShadowMapsSettings,
    /// Shadow tests on (false: unshadowed, for comparisons).
    pub visibility: bool,
    /// Per environment light: (direction to the light, K pdf), (weight, 0).
    env_lights: Vec<[f32; 4]>,
    /// Per object: drawn into the maps (`casts_shadow`).
    casts: Vec<bool>,
    /// Per mesh: object-space bounds (min, max).
    mesh_bounds: Vec<(Vec3, Vec3)>,
    /// Layers (5 vec4 each) the maps were last rendered with.
    rendered_layers: Option<Vec<[f32; 4]>>,
}

/// Object-space bounds of `positions` (a point at the origin when empty).
fn bounds_of(positions: &[Vec3]) -> (Vec3, Vec3) {
    positions.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
}

impl ShadowMapsTechnique {
    pub fn new(
        ctx: &Arc<Context>,
        shaders: &ShaderLibrary,
        scene: &Scene,
        settings: ShadowMapsSettings,
    ) -> Result<Self> {
        if !ctx.shader_output_layer {
            bail!(
                "shadowmaps: the device ({}) lacks Vulkan 1.2 shaderOutputLayer (or it was not enabled), which the layered shadow-map pass needs",
                ctx.device_name
            );
        }
        let depth_pipe = raster_pipeline(
            ctx,
            shaders,
            &RasterDesc {
                name: "shadowmaps_depth",
                shaders: &["shadowmaps/shadowmaps_depth.vert"],
                push_constant_bytes: 8,
                vertex_input: VertexInput::Position,
                depth: Some(DepthState { format: DEPTH_FORMAT, write: true, compare: vk::CompareOp::LESS }),
                ..Default::default()
            },
        )?;
        let shade_pipe = compute_pipeline(ctx, shaders, "shadowmaps/shadowmaps_shade.comp", 32)?;
        let mut t = ShadowMapsTechnique {
            depth_pipe,
            shade_pipe,
            nearest: Sampler::nearest(ctx)?,
            latlong: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            env: EnvTables::new(scene.environment.as_ref()),
            settings,
            visibility: true,
            env_lights: Vec::new(),
            casts: (0..scene.objects.len()).map(|i| scene.object_info(i).casts_shadow).collect(),
            mesh_bounds: scene.meshes.iter().map(|m| bounds_of(&m.positions)).collect(),
            rendered_layers: None,
        };
        t.set_count(settings.count);
        Ok(t)
    }

    pub fn settings(&self) -> ShadowMapsSettings {
        self.settings
    }

    /// Chooses `k` light directions (stratified over the environment's sampling distribution).
    pub fn set_count(&mut self, k: u32) {
        let k = k.clamp(1, 1024);
        self.settings.count = k;
        self.env_lights.clear();
        let nx = (k as f32).sqrt().ceil() as u32;
        let ny = k.div_ceil(nx);
        for i in 0..k {
            let u = [((i % nx) as f32 + 0.5) / nx as f32, ((i / nx) as f32 + 0.5) / ny as f32, 0.5, 0.5];
            let (d, w, kpdf) = match self.env.sample(u) {
                Some((d, l, pdf)) => (d, l / (k as f32 * pdf), k as f32 * pdf),
                None => (Vec3::Y, Vec3::ZERO, 0.0),
            };
            self.env_lights.push([d.x, d.y, d.z, kpdf]);
            self.env_lights.push([w.x, w.y, w.z, 0.0]);
        }
        self.rendered_layers = None;
    }

    /// The scene's bounding sphere at `frame` (instance bounds of the shadow casters).
    fn bounding_sphere(&self, frame: &Frame) -> (Vec3, f32) {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for inst in &frame.instances {
            if !self.casts.get(inst.object).copied().unwrap_or(true) {
                continue;
            }
            let (blo, bhi) = match &inst.deformed_mesh {
                Some(m) => bounds_of(&m.positions),
                None => match self.mesh_bounds.get(inst.mesh) {
                    Some(b) => *b,
                    None => continue,
                },
            };
            if blo.x > bhi.x {
                continue;
            }
            for i in 0..8 {
                let c = Vec3::new(
                    if i & 1 == 0 { blo.x } else { bhi.x },
                    if i & 2 == 0 { blo.y } else { bhi.y },
                    if i & 4 == 0 { blo.z } else { bhi.z },
                );
                let w = inst.world.transform_point3(c);
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
        if lo.x > hi.x {
            return (Vec3::ZERO, 1.0);
        }
        (0.5 * (lo + hi), (0.5 * (hi - lo).length()).max(1e-3))
    }

    /// Per layer: view-projection columns and (kind, near, far, texel size): the K environment
    /// maps (orthographic over the bounding sphere, `size` texels), then per local light 6 cube
    /// faces, or one orthographic map for a directional light (`light_size` texels).
    fn layers(&self, frame: &Frame, size: u32, light_size: u32) -> Vec<[f32; 4]> {
        let (c, r) = self.bounding_sphere(frame);
        let mut out = Vec::new();
        let mut push = |vp: Mat4, info: [f32; 4]| {
            for col in vp.to_cols_array_2d() {
                out.push(col);
            }
            out.push(info);
        };
        // an orthographic map over the bounding sphere, seen from direction d (towards the light)
        let ortho = |d: Vec3, size: u32| {
            let up = if d.y.abs() < 0.99 { Vec3::Y } else { Vec3::X };
            let eye = c + d * (1.01 * r);
            let view = Mat4::look_to_rh(eye, -d, up);
            let (near, far) = (0.0, 2.02 * r);
            let proj = Mat4::orthographic_rh(-r, r, -r, r, near, far);
            (proj * view, [0.0, near, far, 2.0 * r / size as f32])
        };
        for k in 0..self.settings.count as usize {
            let (vp, info) = ortho(Vec3::from_slice(&self.env_lights[2 * k][..3]), size);
            push(vp, info);
        }
        // +X, -X, +Y, -Y, +Z, -Z (the face the shader picks for the direction from the light)
        let faces = [
            (Vec3::X, Vec3::Y),
            (-Vec3::X, Vec3::Y),
            (Vec3::Y, Vec3::Z),
            (-Vec3::Y, Vec3::Z),
            (Vec3::Z, Vec3::Y),
            (-Vec3::Z, Vec3::Y),
        ];
        for l in &frame.lights {
            if l.kind == LightKind::Directional {
                // one orthographic layer (the shader counts 1 layer for it, 6 for the others)
                let (vp, info) = ortho(-l.direction.normalize_or(Vec3::NEG_Y), light_size);
                push(vp, info);
                continue;
            }
            let radius = match l.kind {
                LightKind::Sphere { radius } => radius,
                _ => 0.0,
            };
            let near = radius.max(1e-3 * r).max(1e-5);
            let far = ((l.position - c).length() + r).max(near * 2.0) * 1.01;
            for (dir, up) in faces {
                let view = Mat4::look_to_rh(l.position, dir, up);
                let proj = Mat4::perspective_rh(std::f32::consts::FRAC_PI_2, 1.0, near, far);
                push(proj * view, [1.0, near, far, 0.0]);
            }
        }
        out
    }

    /// The depth pass of layers `first .. first + count` into the layered `depth` image of
    /// `size`^2 texels (each draw instanced once per layer, `gl_Layer` = instance).
    #[allow(clippy::too_many_arguments)]
    fn add_depth_pass(
        &self,
        graph: &mut Graph,
        scene: &crate::scene_gpu::SceneHandles,
        depth: ImageHandle,
        layer_buf: penumbra_engine::BufferHandle,
        draws: &[crate::scene_gpu::Draw],
        first: u32,
        count: u32,
        size: u32,
        name: &str,
    ) -> ImageHandle {
        let mut p = graph.pass(name, PassKind::Raster);
        let dw = p.write(depth, Access::DepthAttachmentWrite);
        let instances = p.read(scene.instances, Access::VertexShaderReadStorage);
        let lb = p.read(layer_buf, Access::VertexShaderReadStorage);
        let meshes = crate::raster::MeshBuffers::declare(&mut p, scene);
        let draws = draws.to_vec();
        let layout = self.depth_pipe.handle();
        p.record(move |rc| {
            let d = rc.device();
            let depth_att = crate::util::depth_attachment(rc.image(dw)?.view, true);
            let area =
                vk::Rect2D { offset: vk::Offset2D::default(), extent: vk::Extent2D { width: size, height: size } };
            let info = vk::RenderingInfo::default().render_area(area).layer_count(count).depth_attachment(&depth_att);
            crate::raster::begin(
                rc,
                &info,
                size,
                size,
                &layout,
                &[Bind::StorageBuffer(instances), Bind::StorageBuffer(lb)],
            )?;
            crate::raster::draw_meshes(rc, &meshes, &draws, |dr| unsafe {
                d.cmd_push_constants(
                    rc.cmd,
                    layout.layout,
                    vk::ShaderStageFlags::VERTEX,
                    0,
                    &bytes_of(&[dr.instance, first]),
                );
                let m = dr.mesh;
                d.cmd_draw_indexed(rc.cmd, m.index_count, count, m.first_index, m.vertex_offset, 0);
            })?;
            unsafe { d.cmd_end_rendering(rc.cmd) };
            Ok(())
        });
        dw
    }

    /// Declares the depth maps (when something changed) and the shading pass; returns the HDR
    /// image.
    pub fn add_frame(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        inputs: &crate::technique::FrameInputs,
    ) -> Result<ImageHandle> {
        let frame = inputs.frame;
        let scene = inputs.handles;
        let gb = inputs.gbuffer;
        // an animated environment: the same K texels, turned and scaled to this frame's state
        // (new directions, so the maps are rendered again)
        if self.env.set_state(frame.environment) {
            self.set_count(self.settings.count);
        }
        let (k, s, ls) = (self.settings.count, self.settings.size, self.settings.light_size);
        let layers = self.layers(frame, s, ls);
        let layer_count = (layers.len() / 5) as u32;
        // the environment's K layers at `size`, the local lights' at `light_size`: two images
        let light_layers = layer_count - k;
        let geometry_changed = frame.any_moved() || frame.any_deformed();
        let rerender = geometry_changed || self.rendered_layers.as_ref() != Some(&layers);
        let layer_buf = graph.create_buffer_init("shadowmaps.layers", bytes_of(&layers));
        let env_lights = graph.create_buffer_init("shadowmaps.env_lights", bytes_of(&self.env_lights));
        let env_depth = engine.persistent_image(
            graph,
            &format!("shadowmaps.depth.{s}x{k}"),
            ImageDesc::new_2d(DEPTH_FORMAT, s, s).with_layers(k),
        );
        let light_depth = (light_layers > 0).then(|| {
            engine.persistent_image(
                graph,
                &format!("shadowmaps.light_depth.{ls}x{light_layers}"),
                ImageDesc::new_2d(DEPTH_FORMAT, ls, ls).with_layers(light_layers),
            )
        });
        let fresh = graph.persistent_is_new(env_depth) || light_depth.is_some_and(|d| graph.persistent_is_new(d));
        let (env_depth, light_depth) = if rerender || fresh {
            let draws: Vec<_> = inputs
                .draws
                .iter()
                .filter(|d| {
                    let object = frame.instances.get(d.instance as usize).map(|i| i.object);
                    object.and_then(|o| self.casts.get(o).copied()).unwrap_or(true)
                })
                .copied()
                .collect();
            let env = self.add_depth_pass(graph, scene, env_depth, layer_buf, &draws, 0, k, s, "shadowmaps_depth");
            let light = light_depth.map(|d| {
                self.add_depth_pass(graph, scene, d, layer_buf, &draws, k, light_layers, ls, "shadowmaps_light_depth")
            });
            self.rendered_layers = Some(layers);
            (env, light)
        } else {
            (env_depth, light_depth)
        };
        let (w, h) = (gb.width, gb.height);
        let hdr = graph.create_image("shadowmaps.hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let mut push: Vec<u8> = Vec::with_capacity(32);
        let shading = match self.settings.shading {
            SmShading::Lights => 0u32,
            SmShading::Ratio => 1,
        };
        push.extend(bytes_of(&[k, scene.light_count, self.visibility as u32, shading]));
        push.extend(bytes_of(&[s, ls, self.settings.march, 0]));
        let mut p = graph.pass("shadowmaps_shade", PassKind::Compute);
        let io = ShadingIo::declare(&mut p, scene, gb, inputs.env, hdr);
        let lb = p.read(layer_buf, Access::ComputeShaderReadStorage);
        let el = p.read(env_lights, Access::ComputeShaderReadStorage);
        let dp = p.read(env_depth, Access::ComputeShaderReadSampled);
        // no local light: the environment's image stands in (never read)
        let lp = light_depth.map(|d| p.read(d, Access::ComputeShaderReadSampled)).unwrap_or(dp);
        let lights = p.read(scene.lights, Access::ComputeShaderReadStorage);
        let tex = p.read(scene.textures, Access::ComputeShaderReadSampled);
        let pipe = self.shade_pipe.handle();
        let (nearest, latlong, repeat) = (self.nearest.sampler, self.latlong.sampler, self.repeat.sampler);
        let hdr = io.hdr;
        p.record(move |rc| {
            let binds = [
                io.binds(nearest, latlong),
                vec![
                    Bind::StorageBuffer(lb),
                    Bind::StorageBuffer(el),
                    Bind::SampledImage(dp, nearest),
                    Bind::StorageBuffer(lights),
                    Bind::SampledImage(tex, repeat),
                    Bind::SampledImage(lp, nearest),
                ],
            ]
            .concat();
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
        });
        Ok(hdr)
    }
}

impl crate::technique::Technique for ShadowMapsTechnique {
    fn name(&self) -> &'static str {
        "shadowmaps"
    }
    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        self.add_frame(engine, graph, inputs)
    }
}

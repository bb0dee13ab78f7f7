//! The shadow-map baseline, technique `shadowmaps` (`glsl/shadowmaps/shadowmaps_depth.comp`,
//! `glsl/shadowmaps/shadowmaps_shade.comp`): the comparison of the ISG and adaptive-visibility papers.
//!
//! The environment is replaced by [`ShadowMapsTechnique::count`] directional lights at stratified
//! importance samples of it (the distribution of [`crate::env::EnvTables`]: luminance x solid
//! angle), each weighted `L / (K pdf)` so that without shadows the sum estimates the environment
//! integral. Every light has an orthographic depth map of [`ShadowMapsTechnique::size`]^2
//! texels over the scene's bounding sphere. Shading per G-buffer pixel: the sum over lights of
//! BRDF (the reference's, `glsl/include/brdf_ref.glsl`) x cosine x lit fraction (3x3 PCF,
//! slope-scaled bias of 1.5 texels + 1.5 texels x tan(theta)) x weight; sky pixels show the
//! environment.
//!
//! Depth maps are rendered by casting one closest-hit ray per texel centre through the kd-tree
//! (the same samples a rasterizer takes), in compute; they are kept in a persistent buffer and
//! re-rendered only when the tree is rebuilt (geometry moved or deformed). Not handled: local
//! lights, texture maps, the medium, `casts_shadow = false` (every triangle casts).

use crate::kdtree::{world_triangles, KdTreeBuilder, KdTreeHandles};
use crate::env::EnvTables;
use crate::scene_gpu::FrameConstants;
use crate::shade_env::HDR_FORMAT;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::Result;
use glam::Vec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Engine, Graph, ImageHandle, PassKind};
use penumbra_scene::{Frame, Scene};
use std::sync::Arc;


/// Technique `shadowmaps`.
pub struct ShadowMapsTechnique {
    depth_pipe: Pipeline,
    shade_pipe: Pipeline,
    nearest: Sampler,
    pub builder: KdTreeBuilder,
    scene: Scene,
    env: EnvTables,
    /// Number of directional lights / shadow maps (default 32).
    pub count: u32,
    /// Shadow-map resolution (default 256).
    pub size: u32,
    /// Shadow tests on (false: unshadowed, for comparisons).
    pub visibility: bool,
    /// Per map: (direction to the light, 0), (weight, 0), (right, 0), (up, 0).
    maps: Vec<[f32; 4]>,
    sphere: [f32; 4],
    built: bool,
    extras: Vec<penumbra_scene::MaterialExtra>,
    repeat: Sampler,
}

impl ShadowMapsTechnique {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene) -> Result<Self> {
        use vk::DescriptorType as T;
        let depth_pipe = compute_pipeline(ctx, shaders, "shadowmaps/shadowmaps_depth.comp", &[T::STORAGE_BUFFER; 6], 32)?;
        let shade_pipe = compute_pipeline(
            ctx,
            shaders,
            "shadowmaps/shadowmaps_shade.comp",
            &[
                T::COMBINED_IMAGE_SAMPLER,
                T::COMBINED_IMAGE_SAMPLER,
                T::COMBINED_IMAGE_SAMPLER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_IMAGE,
                T::COMBINED_IMAGE_SAMPLER,
            ],
            128,
        )?;
        let mut t = ShadowMapsTechnique {
            depth_pipe,
            shade_pipe,
            nearest: Sampler::nearest(ctx)?,
            builder: KdTreeBuilder::new(ctx, shaders)?,
            scene: scene.clone(),
            env: EnvTables::new(scene.environment.as_ref()),
            count: 32,
            size: 256,
            visibility: true,
            maps: Vec::new(),
            sphere: [0.0, 0.0, 0.0, 1.0],
            extras: (0..scene.materials.len()).map(|i| scene.material_extra(i)).collect(),
            repeat: Sampler::repeat(ctx)?,
            built: false,
        };
        t.set_count(32);
        Ok(t)
    }

    /// Chooses `k` light directions (stratified over the environment's sampling distribution).
    pub fn set_count(&mut self, k: u32) {
        let k = k.clamp(1, 1024);
        self.count = k;
        self.maps.clear();
        let nx = (k as f32).sqrt().ceil() as u32;
        let ny = k.div_ceil(nx);
        for i in 0..k {
            let u = [((i % nx) as f32 + 0.5) / nx as f32, ((i / nx) as f32 + 0.5) / ny as f32, 0.5, 0.5];
            let (d, w) = match self.env.sample(u) {
                Some((d, l, pdf)) => (d, l / (k as f32 * pdf)),
                None => (Vec3::Y, Vec3::ZERO),
            };
            let right = if d.y.abs() < 0.99 { Vec3::Y.cross(d).normalize() } else { Vec3::X.cross(d).normalize() };
            let up = d.cross(right);
            self.maps.push([d.x, d.y, d.z, 0.0]);
            self.maps.push([w.x, w.y, w.z, 0.0]);
            self.maps.push([right.x, right.y, right.z, 0.0]);
            self.maps.push([up.x, up.y, up.z, 0.0]);
        }
        self.built = false;
    }

    pub fn add_frame(
        &mut self,
        engine: &mut Engine,
        graph: &mut Graph,
        frame: &Frame,
        gb: &crate::gbuffer::GBuffer,
        textures: ImageHandle,
    ) -> Result<ImageHandle> {
        let (k, s) = (self.count, self.size.clamp(16, 4096));
        let geometry_changed = frame.any_moved() || frame.any_deformed();
        let kept = if geometry_changed || !self.built { None } else { self.builder.add_kept(engine, graph) };
        let (tree, rebuilt): (KdTreeHandles, bool) = match kept {
            Some(t) => (t, false),
            None => {
                let tris = world_triangles(&self.scene, frame)?;
                let (lo, hi) = crate::kdtree::bounds(&tris);
                let c = 0.5 * (lo + hi);
                let r = (0.5 * (hi - lo).length()).max(1e-3);
                self.sphere = [c.x, c.y, c.z, r];
                self.built = true;
                (self.builder.add_triangles(engine, graph, &tris, true)?, true)
            }
        };
        let maps = graph.create_buffer_init("shadowmaps.maps", bytes_of(&self.maps));
        let depth = engine.persistent_buffer(graph, "shadowmaps.depth", k as u64 * s as u64 * s as u64 * 4);
        let depth = if rebuilt || graph.persistent_is_new(depth) {
            let mut p = graph.pass("shadowmaps_depth", PassKind::Compute);
            let kd = tree.read(&mut p);
            let mp = p.read(maps, Access::ComputeShaderReadStorage);
            let dp = p.write(depth, Access::ComputeShaderWriteStorage);
            let mut push = Vec::new();
            push.extend(bytes_of(&[s, k, 0, 0]));
            push.extend(bytes_of(&self.sphere));
            let pipe = self.depth_pipe.handle();
            p.record(move |rc| {
                let binds = [kd.binds().as_slice(), &[Bind::StorageBuffer(mp), Bind::StorageBuffer(dp)]].concat();
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(s, 8), groups(s, 8), k])
            });
            dp
        } else {
            depth
        };
        let env_texels =
            crate::util::persistent_upload(engine, graph, "shadowmaps.env_texels", bytes_of(&self.env.texels), false);
        let materials =
            graph.create_buffer_init("shadowmaps.materials", crate::scene_gpu::material_table(&frame.materials, &self.extras));
        let (w, h) = (gb.width, gb.height);
        let hdr = graph.create_image("shadowmaps.hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let inv_vp = FrameConstants::new(frame, None, w, h).inv_view_proj;
        let mut push: Vec<u8> = Vec::with_capacity(128);
        for c in inv_vp {
            push.extend(bytes_of(&c));
        }
        push.extend(bytes_of(&[w, h, k, s]));
        push.extend(bytes_of(&[self.env.width, self.env.height, self.visibility as u32, 0]));
        push.extend(bytes_of(&[self.env.cos_rot, self.env.sin_rot, 0.0, 0.0]));
        push.extend(bytes_of(&self.sphere));
        let mut p = graph.pass("shadowmaps_shade", PassKind::Compute);
        let g = gb.read_sampled(&mut p);
        let mats = p.read(materials, Access::ComputeShaderReadStorage);
        let mp = p.read(maps, Access::ComputeShaderReadStorage);
        let dp = p.read(depth, Access::ComputeShaderReadStorage);
        let et = p.read(env_texels, Access::ComputeShaderReadStorage);
        let hdr = p.write(hdr, Access::ComputeShaderWriteStorage);
        let tex = p.read(textures, Access::ComputeShaderReadSampled);
        let pipe = self.shade_pipe.handle();
        let nearest = self.nearest.sampler;
        let repeat = self.repeat.sampler;
        p.record(move |rc| {
            let storage = crate::util::storage([mats, mp, dp, et]);
            let binds = [&g.binds(nearest)[..], &storage, &[Bind::StorageImage(hdr), Bind::SampledImage(tex, repeat)]].concat();
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
        });
        Ok(hdr)
    }
}

impl crate::technique::Technique for ShadowMapsTechnique {
    fn name(&self) -> &'static str {
        "shadowmaps"
    }
    fn limitations(&self, scene: &Scene) -> Vec<String> {
        let req = scene.requirements();
        let mut v = Vec::new();
        if req.local_lights {
            v.push(format!(
                "shadowmaps: the {} local light(s) are not rendered (only the environment, as {} shadowed directional lights)",
                scene.lights.len(),
                self.count
            ));
        }
        if (0..scene.objects.len()).any(|i| !scene.object_info(i).casts_shadow) {
            v.push("shadowmaps: objects with casts_shadow = false still cast shadows".into());
        }
        v
    }
    fn add(
        &mut self,
        engine: &mut Engine,
        graph: &mut Graph,
        inputs: &crate::technique::TechniqueInputs,
    ) -> Result<ImageHandle> {
        self.add_frame(engine, graph, inputs.frame, inputs.gbuffer, inputs.handles.textures)
    }
}

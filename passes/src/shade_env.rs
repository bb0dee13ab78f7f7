//! Environment- and local-light shading without shadows (`glsl/frame/shade_env.comp`): diffuse from SH
//! irradiance, glossy from the mip-filtered environment map with an analytic environment BRDF,
//! plus unshadowed point/spot/sphere lights with the material's BRDF.

use crate::gbuffer::{GBuffer, GBufferReads};
use crate::scene_gpu::SceneHandles;
use crate::technique::TechniqueInputs;
use crate::util::{compute_pipeline, groups, Pipeline, Sampler};
use anyhow::Result;
use penumbra_engine::graph::{ImageDesc, PassBuilder};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Graph, ImageHandle, PassKind};
use std::sync::Arc;

pub const HDR_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

/// Bindings 0-6 of every compute shading pass (`shade_env`, `isg_shade`, `avs_shade`,
/// `sf_shade`): camera (uniform), materials (storage), the G-buffer (position, normal,
/// uv + material; nearest), the lat-long environment (linear) and the HDR output (storage
/// write). Declared once by [`ShadingIo::declare`], bound by [`ShadingIo::binds`].
#[derive(Clone, Copy, Debug)]
pub struct ShadingIo {
    pub camera: penumbra_engine::BufferHandle,
    pub materials: penumbra_engine::BufferHandle,
    pub gbuffer: GBufferReads,
    pub env: ImageHandle,
    pub hdr: ImageHandle,
}

impl ShadingIo {
    /// Declares the reads of `scene`'s camera and materials, of `gb` and `env`, and the write of
    /// `hdr` on compute pass `p`.
    pub fn declare(
        p: &mut PassBuilder<'_>,
        scene: &SceneHandles,
        gb: &GBuffer,
        env: ImageHandle,
        hdr: ImageHandle,
    ) -> Self {
        ShadingIo {
            camera: p.read(scene.camera, Access::AnyShaderReadUniform),
            materials: p.read(scene.materials, Access::ComputeShaderReadStorage),
            gbuffer: gb.read_sampled(p),
            env: p.read(env, Access::ComputeShaderReadSampled),
            hdr: p.write(hdr, Access::ComputeShaderWriteStorage),
        }
    }

    /// Bindings 0-6; passes append theirs.
    pub fn binds(&self, nearest: vk::Sampler, latlong: vk::Sampler) -> Vec<Bind> {
        let mut b = vec![Bind::UniformBuffer(self.camera), Bind::StorageBuffer(self.materials)];
        b.extend(self.gbuffer.binds(nearest));
        b.extend([Bind::SampledImage(self.env, latlong), Bind::StorageImage(self.hdr)]);
        b
    }
}

pub struct ShadeEnvPass {
    pipeline: Pipeline,
    nearest: Sampler,
    linear: Sampler,
    repeat: Sampler,
}

impl crate::technique::Technique for ShadeEnvPass {
    fn name(&self) -> &'static str {
        "env"
    }
    fn add(
        &mut self,
        _engine: &mut penumbra_engine::FrameStore<'_>,
        graph: &mut Graph,
        inputs: &TechniqueInputs,
    ) -> Result<ImageHandle> {
        Ok(ShadeEnvPass::add(self, graph, inputs.handles, inputs.gbuffer, inputs.env))
    }
}

impl ShadeEnvPass {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let pipeline = compute_pipeline(ctx, shaders, "frame/shade_env.comp", 4)?;
        Ok(ShadeEnvPass {
            pipeline,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
        })
    }

    /// Adds the `shade_env` pass; returns the linear HDR radiance image.
    pub fn add(&self, graph: &mut Graph, scene: &SceneHandles, gb: &GBuffer, env: ImageHandle) -> ImageHandle {
        let (w, h) = (gb.width, gb.height);
        let hdr = graph.create_image("hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let mut p = graph.pass("shade_env", PassKind::Compute);
        let io = ShadingIo::declare(&mut p, scene, gb, env, hdr);
        let hdr = io.hdr;
        let lights = p.read(scene.lights, Access::ComputeShaderReadStorage);
        let light_count = scene.light_count;
        let textures = p.read(scene.textures, Access::ComputeShaderReadSampled);
        let pipe = self.pipeline.handle();
        let (nearest, linear, repeat) = (self.nearest.sampler, self.linear.sampler, self.repeat.sampler);
        p.record(move |rc| {
            let binds =
                [io.binds(nearest, linear), vec![Bind::StorageBuffer(lights), Bind::SampledImage(textures, repeat)]]
                    .concat();
            crate::util::dispatch(rc, pipe, &binds, &light_count.to_le_bytes(), [groups(w, 8), groups(h, 8), 1])
        });
        hdr
    }
}

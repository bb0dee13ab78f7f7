//! The raster G-buffer pass: world position and the face's geometric normal (packed in `.w`, see
//! `gb_pack_geometric_normal` in `glsl/include/common.glsl`; > 0 on covered pixels), octahedral normal and tangent
//! (local frame), uv + material index + instance id, motion vectors in pixels, and depth.

use crate::raster::{raster_pipeline, DepthState, RasterDesc, VertexInput};
use crate::scene_gpu::{DrawList, SceneHandles};
use crate::util::Pipeline;
use anyhow::Result;
use penumbra_engine::graph::{ImageDesc, PassBuilder};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Graph, ImageHandle, PassKind};
use std::sync::Arc;

pub const POSITION_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
pub const NORMAL_FORMAT: vk::Format = vk::Format::R16G16B16A16_SFLOAT;
pub const UV_MAT_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
pub const MOTION_FORMAT: vk::Format = vk::Format::R16G16_SFLOAT;
pub const DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

/// The G-buffer images of one frame.
#[derive(Clone, Copy, Debug)]
pub struct GBuffer {
    pub position: ImageHandle,
    pub normal: ImageHandle,
    pub uv_mat: ImageHandle,
    pub motion: ImageHandle,
    pub depth: ImageHandle,
    pub width: u32,
    pub height: u32,
}

/// The G-buffer images a shading pass samples (nearest), declared by [`GBuffer::read_sampled`].
/// Every compute shading pass binds them consecutively in this order: position, normal,
/// uv + material ([`GBufferReads::binds`]).
#[derive(Clone, Copy, Debug)]
pub struct GBufferReads {
    pub position: ImageHandle,
    pub normal: ImageHandle,
    pub uv_mat: ImageHandle,
}

impl GBuffer {
    /// Declares position, normal and uv + material as sampled reads of compute pass `p`.
    pub fn read_sampled(&self, p: &mut PassBuilder<'_>) -> GBufferReads {
        GBufferReads {
            position: p.read(self.position, Access::ComputeShaderReadSampled),
            normal: p.read(self.normal, Access::ComputeShaderReadSampled),
            uv_mat: p.read(self.uv_mat, Access::ComputeShaderReadSampled),
        }
    }
}

impl GBufferReads {
    /// The three images as consecutive sampled-image bindings with `sampler`.
    pub fn binds(&self, sampler: vk::Sampler) -> [Bind; 3] {
        [
            Bind::SampledImage(self.position, sampler),
            Bind::SampledImage(self.normal, sampler),
            Bind::SampledImage(self.uv_mat, sampler),
        ]
    }
}

pub struct GBufferPass {
    pipeline: Pipeline,
    /// The material textures' sampler (normal maps).
    repeat: crate::util::Sampler,
}

impl GBufferPass {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let pipeline = raster_pipeline(
            ctx,
            shaders,
            &RasterDesc {
                name: "gbuffer",
                shaders: &["frame/gbuffer.vert", "frame/gbuffer.frag"],
                vertex_input: VertexInput::PositionNormalUv,
                colors: &[POSITION_FORMAT, NORMAL_FORMAT, UV_MAT_FORMAT, MOTION_FORMAT],
                depth: Some(DepthState { format: DEPTH_FORMAT, write: true, compare: vk::CompareOp::LESS }),
                // closed meshes' back faces culled per draw (scene_gpu::Cull)
                dynamic_cull: true,
                ..Default::default()
            },
        )?;
        Ok(GBufferPass { pipeline, repeat: crate::util::Sampler::repeat(ctx)? })
    }

    /// Declares the G-buffer images and the `gbuffer` pass that fills them.
    pub fn add(&self, graph: &mut Graph, scene: &SceneHandles, draws: DrawList, width: u32, height: u32) -> GBuffer {
        let position = graph.create_image("gb_position", ImageDesc::new_2d(POSITION_FORMAT, width, height));
        let normal = graph.create_image("gb_normal", ImageDesc::new_2d(NORMAL_FORMAT, width, height));
        let uv_mat = graph.create_image("gb_uv_mat", ImageDesc::new_2d(UV_MAT_FORMAT, width, height));
        let motion = graph.create_image("gb_motion", ImageDesc::new_2d(MOTION_FORMAT, width, height));
        let depth = graph.create_image("gb_depth", ImageDesc::new_2d(DEPTH_FORMAT, width, height));
        let mut p = graph.pass("gbuffer", PassKind::Raster);
        let [position, normal, uv_mat, motion] =
            [position, normal, uv_mat, motion].map(|h| p.write(h, Access::ColorAttachmentWrite));
        let depth = p.write(depth, Access::DepthAttachmentWrite);
        let camera = p.read(scene.camera, Access::AnyShaderReadUniform);
        let instances = p.read(scene.instances, Access::VertexShaderReadStorage);
        // the materials' normal maps bend the normals as they are written
        let materials = p.read(scene.materials, Access::FragmentShaderReadStorage);
        let textures = p.read(scene.textures, Access::FragmentShaderReadSampled);
        let repeat = self.repeat.sampler;
        let meshes = crate::raster::MeshBuffers::declare(&mut p, scene);
        let layout = self.pipeline.handle();
        p.record(move |rc| {
            let d = rc.device();
            let color = |h: ImageHandle| -> Result<vk::RenderingAttachmentInfo<'static>> {
                Ok(crate::util::color_attachment(rc.image(h)?.view, [0.0; 4]))
            };
            let colors = [color(position)?, color(normal)?, color(uv_mat)?, color(motion)?];
            let depth_att = crate::util::depth_attachment(rc.image(depth)?.view, true);
            let info = crate::raster::rendering_info(width, height, &colors, &depth_att);
            crate::raster::begin(
                rc,
                &info,
                width,
                height,
                &layout,
                &[
                    Bind::UniformBuffer(camera),
                    Bind::StorageBuffer(instances),
                    Bind::StorageBuffer(materials),
                    Bind::SampledImage(textures, repeat),
                ],
            )?;
            crate::raster::draw_instances(rc, &meshes, &draws, true)?;
            unsafe { d.cmd_end_rendering(rc.cmd) };
            Ok(())
        });
        GBuffer { position, normal, uv_mat, motion, depth, width, height }
    }
}

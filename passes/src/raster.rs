//! Graphics pipelines from one description (dynamic rendering, dynamic viewport/scissor,
//! push descriptors): the raster passes state only what differs (shaders, vertex input,
//! topology, attachments, depth, blending) instead of repeating the Vulkan create-info chain.

use crate::scene_gpu::Vertex;
use crate::util::{layouts, Pipeline};
use anyhow::{bail, Context as _, Result};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Context};
use std::sync::Arc;

/// Which attributes of the scene's vertex buffer ([`Vertex`], binding 0) the vertex shader reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VertexInput {
    /// No vertex buffer (positions from a storage buffer or generated).
    None,
    /// location 0: position.
    Position,
    /// locations 0, 1, 2: position, normal, uv.
    PositionNormalUv,
    /// location 0: an RGB32F position at offset 0 of another vertex type of this stride.
    PositionOfStride(u32),
}

/// Colour blending, the same for every attachment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Blend {
    /// Writes replace.
    Replace,
    /// RGB keeps the minimum, alpha the maximum (nearest and farthest of several surfaces).
    MinRgbMaxAlpha,
    /// RGBA sums.
    Additive,
}

/// Depth test/write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DepthState {
    pub format: vk::Format,
    pub write: bool,
    pub compare: vk::CompareOp,
}

/// What a pipeline does with a stencil attachment (a combined depth-stencil format used for its
/// stencil aspect only: no depth test).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StencilState {
    /// Every rasterized fragment sets the stencil value to 1 (compare ALWAYS, op REPLACE): a
    /// coverage mask.
    Mark { format: vk::Format },
    /// Only fragments whose stencil value is not 0 run the fragment shader (compare NOT_EQUAL
    /// 0, nothing written; the attachment is read-only).
    TestNonZero { format: vk::Format },
}

impl StencilState {
    pub fn format(self) -> vk::Format {
        match self {
            StencilState::Mark { format } | StencilState::TestNonZero { format } => format,
        }
    }
}

/// Everything a raster pass's pipeline needs.
#[derive(Clone, Debug)]
pub struct RasterDesc<'a> {
    /// Names the pipeline and its layouts (validation messages, captures).
    pub name: &'a str,
    /// Shader files under `glsl/`; the stage comes from the extension
    /// (`.vert`, `.tesc`, `.tese`, `.geom`, `.frag`).
    pub shaders: &'a [&'a str],
    pub push_constant_bytes: u32,
    pub vertex_input: VertexInput,
    pub topology: vk::PrimitiveTopology,
    /// Control points per patch (with tessellation shaders; topology `PATCH_LIST`).
    pub patch_control_points: u32,
    pub cull: vk::CullModeFlags,
    /// Cull mode and front face set per draw (`vkCmdSetCullMode`, `vkCmdSetFrontFace`, Vulkan
    /// 1.3 core) instead of `cull`: [`draw_instances`] with `cull`.
    pub dynamic_cull: bool,
    pub colors: &'a [vk::Format],
    pub blend: Blend,
    pub depth: Option<DepthState>,
    pub stencil: Option<StencilState>,
}

impl Default for RasterDesc<'_> {
    fn default() -> Self {
        RasterDesc {
            name: "raster",
            shaders: &[],
            push_constant_bytes: 0,
            vertex_input: VertexInput::None,
            topology: vk::PrimitiveTopology::TRIANGLE_LIST,
            patch_control_points: 0,
            cull: vk::CullModeFlags::NONE,
            dynamic_cull: false,
            colors: &[],
            blend: Blend::Replace,
            depth: None,
            stencil: None,
        }
    }
}

/// The shader stage of a GLSL file, from its extension (`None`: not a graphics stage).
pub fn stage_of(file: &str) -> Option<vk::ShaderStageFlags> {
    Some(match file.rsplit('.').next()? {
        "vert" => vk::ShaderStageFlags::VERTEX,
        "tesc" => vk::ShaderStageFlags::TESSELLATION_CONTROL,
        "tese" => vk::ShaderStageFlags::TESSELLATION_EVALUATION,
        "geom" => vk::ShaderStageFlags::GEOMETRY,
        "frag" => vk::ShaderStageFlags::FRAGMENT,
        _ => return None,
    })
}

/// Creates the pipeline described by `desc` (with its push-descriptor set layout and pipeline
/// layout). Errors name the pipeline: unknown shader stage, missing shader, Vulkan failures.
pub fn raster_pipeline(ctx: &Arc<Context>, shaders: &ShaderLibrary, desc: &RasterDesc) -> Result<Pipeline> {
    let mut stage_flags = vk::ShaderStageFlags::empty();
    for s in desc.shaders {
        let st = stage_of(s).with_context(|| format!("{} pipeline: '{s}' is not a raster shader stage", desc.name))?;
        if stage_flags.contains(st) {
            bail!("{} pipeline: two shaders for the stage of '{s}'", desc.name);
        }
        stage_flags |= st;
    }
    if !stage_flags.contains(vk::ShaderStageFlags::VERTEX) {
        bail!("{} pipeline: no vertex shader", desc.name);
    }
    let tess = stage_flags
        .intersects(vk::ShaderStageFlags::TESSELLATION_CONTROL | vk::ShaderStageFlags::TESSELLATION_EVALUATION);
    if tess && (desc.patch_control_points == 0 || desc.topology != vk::PrimitiveTopology::PATCH_LIST) {
        bail!("{} pipeline: tessellation needs the PATCH_LIST topology and patch_control_points", desc.name);
    }
    // The push-descriptor set from what the stages declare (visible to every stage); the push
    // range checked against their blocks.
    let code = desc.shaders.iter().map(|s| Ok((*s, shaders.get(s)?))).collect::<Result<Vec<_>>>()?;
    let set = penumbra_engine::reflect::pipeline_interface(&code, desc.push_constant_bytes)
        .with_context(|| format!("{} pipeline", desc.name))?
        .set;
    // Modules first (all destroyed below whatever happens).
    let mut modules = Vec::new();
    let mut err = None;
    for s in desc.shaders {
        match shaders.get(s).and_then(|code| ctx.create_shader_module(s, code)) {
            Ok(m) => modules.push(m),
            Err(e) => {
                err = Some(e);
                break;
            }
        }
    }
    let guards = desc
        .shaders
        .iter()
        .map(|s| penumbra_engine::shader::Specialization::for_shader(ctx, shaders, s, &[]))
        .collect::<Result<Vec<_>>>();
    let result = match (err, guards) {
        (Some(e), _) | (None, Err(e)) => Err(e),
        (None, Ok(guards)) => create(ctx, desc, &modules, &guards, stage_flags, set),
    };
    for m in modules {
        unsafe { ctx.device.destroy_shader_module(m, None) };
    }
    result
}

fn create(
    ctx: &Arc<Context>,
    desc: &RasterDesc,
    modules: &[vk::ShaderModule],
    guards: &[Option<penumbra_engine::shader::Specialization>],
    stage_flags: vk::ShaderStageFlags,
    set: penumbra_engine::reflect::SetLayout,
) -> Result<Pipeline> {
    let guard_infos: Vec<_> = guards.iter().map(|g| g.as_ref().map(|g| g.info())).collect();
    let stages: Vec<_> = desc
        .shaders
        .iter()
        .zip(modules)
        .zip(&guard_infos)
        .map(|((s, &m), guard)| {
            let st = vk::PipelineShaderStageCreateInfo::default()
                .stage(stage_of(s).expect("checked"))
                .module(m)
                .name(c"main");
            match guard {
                Some(info) => st.specialization_info(info),
                None => st,
            }
        })
        .collect();
    let stride = match desc.vertex_input {
        VertexInput::PositionOfStride(s) => s,
        _ => std::mem::size_of::<Vertex>() as u32,
    };
    let bindings = [vk::VertexInputBindingDescription { binding: 0, stride, input_rate: vk::VertexInputRate::VERTEX }];
    let attr = |location, format, offset| vk::VertexInputAttributeDescription { location, binding: 0, format, offset };
    let all_attrs = [
        attr(0, vk::Format::R32G32B32_SFLOAT, 0),
        attr(1, vk::Format::R32G32B32_SFLOAT, 12),
        attr(2, vk::Format::R32G32_SFLOAT, 24),
    ];
    let (bindings, attrs): (&[_], &[_]) = match desc.vertex_input {
        VertexInput::None => (&[], &[]),
        VertexInput::Position | VertexInput::PositionOfStride(_) => (&bindings, &all_attrs[..1]),
        VertexInput::PositionNormalUv => (&bindings, &all_attrs),
    };
    let vi = vk::PipelineVertexInputStateCreateInfo::default()
        .vertex_binding_descriptions(bindings)
        .vertex_attribute_descriptions(attrs);
    let ia = vk::PipelineInputAssemblyStateCreateInfo::default().topology(desc.topology);
    let ts = vk::PipelineTessellationStateCreateInfo::default().patch_control_points(desc.patch_control_points);
    let vp = vk::PipelineViewportStateCreateInfo::default().viewport_count(1).scissor_count(1);
    let rs = vk::PipelineRasterizationStateCreateInfo::default()
        .polygon_mode(vk::PolygonMode::FILL)
        .cull_mode(desc.cull)
        .front_face(vk::FrontFace::COUNTER_CLOCKWISE)
        .line_width(1.0);
    let ms = vk::PipelineMultisampleStateCreateInfo::default().rasterization_samples(vk::SampleCountFlags::TYPE_1);
    let mut ds = match desc.depth {
        Some(d) => vk::PipelineDepthStencilStateCreateInfo::default()
            .depth_test_enable(true)
            .depth_write_enable(d.write)
            .depth_compare_op(d.compare),
        None => vk::PipelineDepthStencilStateCreateInfo::default(),
    };
    if let Some(st) = desc.stencil {
        // (on pass, compare, write mask, reference)
        let (pass, compare, write, reference) = match st {
            StencilState::Mark { .. } => (vk::StencilOp::REPLACE, vk::CompareOp::ALWAYS, 0xff, 1),
            StencilState::TestNonZero { .. } => (vk::StencilOp::KEEP, vk::CompareOp::NOT_EQUAL, 0, 0),
        };
        let op = vk::StencilOpState::default()
            .fail_op(vk::StencilOp::KEEP)
            .pass_op(pass)
            .depth_fail_op(vk::StencilOp::KEEP)
            .compare_op(compare)
            .compare_mask(0xff)
            .write_mask(write)
            .reference(reference);
        ds = ds.stencil_test_enable(true).front(op).back(op);
    }
    let attachment = {
        let a = vk::PipelineColorBlendAttachmentState::default().color_write_mask(vk::ColorComponentFlags::RGBA);
        let ones = |a: vk::PipelineColorBlendAttachmentState| {
            a.blend_enable(true)
                .src_color_blend_factor(vk::BlendFactor::ONE)
                .dst_color_blend_factor(vk::BlendFactor::ONE)
                .src_alpha_blend_factor(vk::BlendFactor::ONE)
                .dst_alpha_blend_factor(vk::BlendFactor::ONE)
        };
        match desc.blend {
            Blend::Replace => a,
            Blend::MinRgbMaxAlpha => ones(a).color_blend_op(vk::BlendOp::MIN).alpha_blend_op(vk::BlendOp::MAX),
            Blend::Additive => ones(a).color_blend_op(vk::BlendOp::ADD).alpha_blend_op(vk::BlendOp::ADD),
        }
    };
    let blend = vec![attachment; desc.colors.len()];
    let cb = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend);
    let dyn_states = [
        vk::DynamicState::VIEWPORT,
        vk::DynamicState::SCISSOR,
        vk::DynamicState::CULL_MODE,
        vk::DynamicState::FRONT_FACE,
    ];
    let dy = vk::PipelineDynamicStateCreateInfo::default()
        .dynamic_states(&dyn_states[..if desc.dynamic_cull { 4 } else { 2 }]);
    let mut rendering = vk::PipelineRenderingCreateInfo::default()
        .color_attachment_formats(desc.colors)
        .depth_attachment_format(desc.depth.map_or(vk::Format::UNDEFINED, |d| d.format))
        .stencil_attachment_format(desc.stencil.map_or(vk::Format::UNDEFINED, |s| s.format()));
    let (set_layout, layout) = layouts(ctx, desc.name, &set, stage_flags, desc.push_constant_bytes)?;
    let mut ci = vk::GraphicsPipelineCreateInfo::default()
        .stages(&stages)
        .vertex_input_state(&vi)
        .input_assembly_state(&ia)
        .viewport_state(&vp)
        .rasterization_state(&rs)
        .multisample_state(&ms)
        .depth_stencil_state(&ds)
        .color_blend_state(&cb)
        .dynamic_state(&dy)
        .layout(layout)
        .push_next(&mut rendering);
    if desc.patch_control_points > 0 {
        ci = ci.tessellation_state(&ts);
    }
    let res = unsafe { ctx.device.create_graphics_pipelines(ctx.pipeline_cache, &[ci], None) };
    let pipeline = match res {
        Ok(p) => p[0],
        Err((_, e)) => {
            unsafe {
                ctx.device.destroy_pipeline_layout(layout, None);
                ctx.device.destroy_descriptor_set_layout(set_layout, None);
            }
            return Err(e).with_context(|| format!("{} pipeline", desc.name));
        }
    };
    ctx.set_name(pipeline, desc.name);
    Ok(Pipeline::from_raw(ctx, pipeline, layout, set_layout, set))
}

/// The scene's vertex, index and deformed-vertex buffers as a raster pass reads them.
#[derive(Clone, Copy, Debug)]
pub struct MeshBuffers {
    vertices: penumbra_engine::BufferHandle,
    indices: penumbra_engine::BufferHandle,
    deformed: Option<penumbra_engine::BufferHandle>,
}

impl MeshBuffers {
    /// Declares pass `p`'s reads of the scene's vertex and index buffers (and of the frame's
    /// deformed vertices, when it has any).
    pub fn declare(p: &mut penumbra_engine::graph::PassBuilder, scene: &crate::scene_gpu::SceneHandles) -> Self {
        use penumbra_engine::Access;
        MeshBuffers {
            vertices: p.read(scene.vertices, Access::VertexBuffer),
            indices: p.read(scene.indices, Access::IndexBuffer),
            deformed: scene.deformed_vertices.map(|h| p.read(h, Access::VertexBuffer)),
        }
    }
}

/// Binds `meshes`' index buffer and, for the static then the deformed draws, their vertex
/// buffer, calling `draw` for each of `draws` (which records the draw call itself).
pub fn draw_meshes(
    rc: &penumbra_engine::RecordContext,
    meshes: &MeshBuffers,
    draws: &[crate::scene_gpu::Draw],
    mut draw: impl FnMut(&crate::scene_gpu::Draw),
) -> Result<()> {
    if draws.is_empty() {
        return Ok(());
    }
    let (d, cmd) = (rc.device(), rc.cmd);
    let vertices = rc.buffer(meshes.vertices)?.buffer;
    let deformed = meshes.deformed.map(|h| rc.buffer(h)).transpose()?.map(|b| b.buffer);
    unsafe { d.cmd_bind_index_buffer(cmd, rc.buffer(meshes.indices)?.buffer, 0, vk::IndexType::UINT32) };
    for pass_deformed in [false, true] {
        let buffer = if pass_deformed { deformed } else { Some(vertices) };
        let Some(buffer) = buffer else { continue };
        let mut bound = false;
        for dr in draws.iter().filter(|dr| dr.deformed == pass_deformed) {
            if !bound {
                unsafe { d.cmd_bind_vertex_buffers(cmd, 0, &[buffer], &[0]) };
                bound = true;
            }
            draw(dr);
        }
    }
    Ok(())
}

/// One layer of `w` x `h` pixels rendered into `colors` and `depth`.
pub fn rendering_info<'a>(
    w: u32,
    h: u32,
    colors: &'a [vk::RenderingAttachmentInfo<'a>],
    depth: &'a vk::RenderingAttachmentInfo<'a>,
) -> vk::RenderingInfo<'a> {
    let area = vk::Rect2D { offset: vk::Offset2D::default(), extent: vk::Extent2D { width: w, height: h } };
    vk::RenderingInfo::default().render_area(area).layer_count(1).color_attachments(colors).depth_attachment(depth)
}

/// Draws one instance of each of `draws` (instance index `Draw::instance`), as
/// [`draw_meshes`] binds their buffers; with `cull`, each draw's [`crate::scene_gpu::Draw::cull`]
/// set before it (a pipeline made with [`RasterDesc::dynamic_cull`]).
pub fn draw_instances(
    rc: &penumbra_engine::RecordContext,
    meshes: &MeshBuffers,
    draws: &[crate::scene_gpu::Draw],
    cull: bool,
) -> Result<()> {
    let d = rc.device();
    draw_meshes(rc, meshes, draws, |dr| unsafe {
        if cull {
            let (mode, front) = match dr.cull {
                crate::scene_gpu::Cull::None => (vk::CullModeFlags::NONE, vk::FrontFace::COUNTER_CLOCKWISE),
                crate::scene_gpu::Cull::Back => (vk::CullModeFlags::BACK, vk::FrontFace::COUNTER_CLOCKWISE),
                crate::scene_gpu::Cull::BackMirrored => (vk::CullModeFlags::BACK, vk::FrontFace::CLOCKWISE),
            };
            d.cmd_set_cull_mode(rc.cmd, mode);
            d.cmd_set_front_face(rc.cmd, front);
        }
        let m = dr.mesh;
        d.cmd_draw_indexed(rc.cmd, m.index_count, 1, m.first_index, m.vertex_offset, dr.instance);
    })
}

/// Begins dynamic rendering with `info` over a `w` x `h` viewport and scissor (depth 0..1),
/// binds the graphics pipeline `pipe` and pushes its descriptors `binds` (checked as
/// [`crate::util::push_graphics`] checks them).
pub fn begin(
    rc: &penumbra_engine::RecordContext,
    info: &vk::RenderingInfo,
    w: u32,
    h: u32,
    pipe: &crate::util::PipelineHandle,
    binds: &[penumbra_engine::Bind],
) -> Result<()> {
    let (d, cmd) = (rc.device(), rc.cmd);
    let area = vk::Rect2D { offset: vk::Offset2D::default(), extent: vk::Extent2D { width: w, height: h } };
    unsafe {
        d.cmd_begin_rendering(cmd, info);
        d.cmd_set_viewport(
            cmd,
            0,
            &[vk::Viewport { x: 0.0, y: 0.0, width: w as f32, height: h as f32, min_depth: 0.0, max_depth: 1.0 }],
        );
        d.cmd_set_scissor(cmd, 0, &[area]);
        d.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipe.pipeline);
    }
    crate::util::push_graphics(rc, pipe, binds)
}

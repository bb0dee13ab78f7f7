//! Pipeline helpers shared by the passes: push-descriptor set layouts, compute pipelines,
//! samplers. Every object is named for validation messages.

use anyhow::{Context as _, Result};
use penumbra_engine::reflect::SetLayout;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Context};
use std::sync::Arc;

/// A pipeline with its layout and push-descriptor set layout; destroyed on drop.
pub struct Pipeline {
    ctx: Arc<Context>,
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    pub set_layout: vk::DescriptorSetLayout,
    /// The push-descriptor set's bindings, as the shaders declare them (the layout is made from
    /// them; binds are checked against them when pushed).
    pub set: SetLayout,
    /// Bytes of the shader's push-constant block (reflected; 0: unchecked), which every
    /// [`dispatch`] must push at least.
    pub push_bytes: u32,
}

impl Pipeline {
    /// The pipeline and its layout, to move into a pass's record closure (see [`dispatch`]).
    pub fn handle(&self) -> PipelineHandle {
        PipelineHandle { pipeline: self.pipeline, layout: self.layout, set: self.set, push_bytes: self.push_bytes }
    }

    /// Takes ownership of objects created elsewhere (graphics pipelines) whose set layout was
    /// made from `set`.
    pub fn from_raw(
        ctx: &Arc<Context>,
        pipeline: vk::Pipeline,
        layout: vk::PipelineLayout,
        set_layout: vk::DescriptorSetLayout,
        set: SetLayout,
    ) -> Self {
        Pipeline { ctx: ctx.clone(), pipeline, layout, set_layout, set, push_bytes: 0 }
    }
}

impl Drop for Pipeline {
    fn drop(&mut self) {
        unsafe {
            self.ctx.device.destroy_pipeline(self.pipeline, None);
            self.ctx.device.destroy_pipeline_layout(self.layout, None);
            self.ctx.device.destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

/// A push-descriptor set layout with `set`'s bindings, visible to `stages`, and a pipeline
/// layout with `push_bytes` of push constants.
pub fn layouts(
    ctx: &Context,
    name: &str,
    set: &SetLayout,
    stages: vk::ShaderStageFlags,
    push_bytes: u32,
) -> Result<(vk::DescriptorSetLayout, vk::PipelineLayout)> {
    let bindings: Vec<_> = set
        .bindings()
        .map(|(i, t)| {
            vk::DescriptorSetLayoutBinding::default()
                .binding(i)
                .descriptor_type(t)
                .descriptor_count(1)
                .stage_flags(stages)
        })
        .collect();
    let set_layout = unsafe {
        ctx.device.create_descriptor_set_layout(
            &vk::DescriptorSetLayoutCreateInfo::default()
                .flags(vk::DescriptorSetLayoutCreateFlags::PUSH_DESCRIPTOR_KHR)
                .bindings(&bindings),
            None,
        )?
    };
    ctx.set_name(set_layout, &format!("{name}.set_layout"));
    let ranges = [vk::PushConstantRange { stage_flags: stages, offset: 0, size: push_bytes }];
    let sets = [set_layout];
    let mut ci = vk::PipelineLayoutCreateInfo::default().set_layouts(&sets);
    if push_bytes > 0 {
        ci = ci.push_constant_ranges(&ranges);
    }
    let layout = unsafe { ctx.device.create_pipeline_layout(&ci, None)? };
    ctx.set_name(layout, &format!("{name}.layout"));
    Ok((set_layout, layout))
}

/// A compute pipeline from `shader` (e.g. `"frame/tonemap.comp"`) with `push_bytes` of push
/// constants; its descriptor bindings are the shader's own (binding `i` of its GLSL is
/// `binds[i]` of every [`dispatch`]).
pub fn compute_pipeline(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    shader: &str,
    push_bytes: u32,
) -> Result<Pipeline> {
    compute_pipeline_specialized(ctx, shaders, shader, push_bytes, &[])
}

/// [`compute_pipeline`] with specialization constants, `(constant_id, value)` pairs
/// (`layout(constant_id = N) const uint ...` in the shader): a mode chosen when the technique is
/// created, so that the pipeline holds that mode's code alone (lavapipe compiles all of a
/// pipeline's code at its first dispatch; avs_shade.comp's `integration` modes).
pub fn compute_pipeline_specialized(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    shader: &str,
    push_bytes: u32,
    constants: &[(u32, u32)],
) -> Result<Pipeline> {
    let spirv = shaders.get(shader)?;
    let iface = penumbra_engine::reflect::pipeline_interface(&[(shader, spirv)], push_bytes)
        .with_context(|| format!("compute pipeline '{shader}'"))?;
    let (set, block) = (iface.set, iface.push_bytes);
    let (set_layout, layout) = layouts(ctx, shader, &set, vk::ShaderStageFlags::COMPUTE, push_bytes)?;
    let spec = penumbra_engine::shader::Specialization::for_shader(ctx, shaders, shader, constants)?;
    let spec_info = spec.as_ref().map(|g| g.info());
    let module = ctx.create_shader_module(shader, spirv)?;
    let mut stage =
        vk::PipelineShaderStageCreateInfo::default().stage(vk::ShaderStageFlags::COMPUTE).module(module).name(c"main");
    if let Some(info) = spec_info.as_ref() {
        stage = stage.specialization_info(info);
    }
    let ci = [vk::ComputePipelineCreateInfo::default().stage(stage).layout(layout)];
    let res = unsafe { ctx.device.create_compute_pipelines(ctx.pipeline_cache, &ci, None) };
    unsafe { ctx.device.destroy_shader_module(module, None) };
    let pipeline = res.map_err(|(_, e)| e).with_context(|| format!("compute pipeline '{shader}'"))?[0];
    ctx.set_name(pipeline, shader);
    Ok(Pipeline { ctx: ctx.clone(), pipeline, layout, set_layout, set, push_bytes: block })
}

/// A sampler; destroyed on drop.
pub struct Sampler {
    ctx: Arc<Context>,
    pub sampler: vk::Sampler,
}

impl Sampler {
    /// Linear filtering with mips; U repeats (lat-long seam), V clamps (poles).
    pub fn latlong(ctx: &Arc<Context>) -> Result<Self> {
        let ci = vk::SamplerCreateInfo::default()
            .mag_filter(vk::Filter::LINEAR)
            .min_filter(vk::Filter::LINEAR)
            .mipmap_mode(vk::SamplerMipmapMode::LINEAR)
            .address_mode_u(vk::SamplerAddressMode::REPEAT)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .max_lod(vk::LOD_CLAMP_NONE);
        let sampler = unsafe { ctx.device.create_sampler(&ci, None)? };
        ctx.set_name(sampler, "latlong_sampler");
        Ok(Sampler { ctx: ctx.clone(), sampler })
    }

    /// Linear filtering with mips, repeating in u and v: material textures.
    pub fn repeat(ctx: &Arc<Context>) -> Result<Self> {
        let ci = vk::SamplerCreateInfo::default()
            .mag_filter(vk::Filter::LINEAR)
            .min_filter(vk::Filter::LINEAR)
            .mipmap_mode(vk::SamplerMipmapMode::LINEAR)
            .address_mode_u(vk::SamplerAddressMode::REPEAT)
            .address_mode_v(vk::SamplerAddressMode::REPEAT)
            .address_mode_w(vk::SamplerAddressMode::REPEAT)
            .max_lod(vk::LOD_CLAMP_NONE);
        let sampler = unsafe { ctx.device.create_sampler(&ci, None)? };
        ctx.set_name(sampler, "repeat_sampler");
        Ok(Sampler { ctx: ctx.clone(), sampler })
    }

    /// Nearest, clamped: for `texelFetch` of G-buffer images.
    pub fn nearest(ctx: &Arc<Context>) -> Result<Self> {
        let ci = vk::SamplerCreateInfo::default()
            .mag_filter(vk::Filter::NEAREST)
            .min_filter(vk::Filter::NEAREST)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE);
        let sampler = unsafe { ctx.device.create_sampler(&ci, None)? };
        ctx.set_name(sampler, "nearest_sampler");
        Ok(Sampler { ctx: ctx.clone(), sampler })
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        unsafe { self.ctx.device.destroy_sampler(self.sampler, None) };
    }
}

/// Workgroups of `local` covering `n`.
pub fn groups(n: u32, local: u32) -> u32 {
    n.div_ceil(local)
}

/// Raw bytes of plain-old-data values (f32/u32 arrays and #[repr(C)] structs of them).
pub fn bytes_of<T: Copy>(v: &[T]) -> Vec<u8> {
    let n = std::mem::size_of_val(v);
    let mut out = vec![0u8; n];
    // SAFETY: T is Copy plain data (only f32/u32 fields are used here); we copy its bytes.
    unsafe { std::ptr::copy_nonoverlapping(v.as_ptr() as *const u8, out.as_mut_ptr(), n) };
    out
}

/// One subresource of an image upload: mip level, array layer, extent and texel bytes.
pub struct Subresource<'a> {
    pub mip: u32,
    pub layer: u32,
    pub width: u32,
    pub height: u32,
    pub bytes: &'a [u8],
}

/// Declares a `{name}_upload` transfer pass copying `parts` (through one host-initialised
/// `{name}_staging` buffer) into their subresources of `img`. Returns the written image handle.
pub fn add_image_upload<'a>(
    graph: &mut penumbra_engine::Graph,
    name: &str,
    img: penumbra_engine::ImageHandle,
    parts: impl IntoIterator<Item = Subresource<'a>>,
) -> penumbra_engine::ImageHandle {
    use penumbra_engine::{Access, PassKind};
    let (mut data, mut regions) = (Vec::new(), Vec::new());
    for s in parts {
        regions.push(
            vk::BufferImageCopy::default()
                .buffer_offset(data.len() as u64)
                .image_subresource(vk::ImageSubresourceLayers {
                    aspect_mask: vk::ImageAspectFlags::COLOR,
                    mip_level: s.mip,
                    base_array_layer: s.layer,
                    layer_count: 1,
                })
                .image_extent(vk::Extent3D { width: s.width, height: s.height, depth: 1 }),
        );
        data.extend_from_slice(s.bytes);
    }
    let staging = graph.create_buffer_init(&format!("{name}_staging"), data);
    let mut p = graph.pass(&format!("{name}_upload"), PassKind::Transfer);
    p.read(staging, Access::TransferSrc);
    let img = p.write(img, Access::TransferDst);
    p.record(move |rc| {
        let (src, dst) = (rc.buffer(staging)?, rc.image(img)?);
        let layout = vk::ImageLayout::TRANSFER_DST_OPTIMAL;
        unsafe { rc.device().cmd_copy_buffer_to_image(rc.cmd, src.buffer, dst.image, layout, &regions) };
        Ok(())
    });
    img
}

/// A pipeline, its layout and its shaders' bindings (plain handles, `Copy`), owned by a
/// [`Pipeline`]: what a pass's record closure takes to dispatch or draw with it.
#[derive(Clone, Copy, Debug)]
pub struct PipelineHandle {
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    /// The shader's bindings.
    pub set: SetLayout,
    /// Bytes of the shader's push-constant block (0: unchecked).
    pub push_bytes: u32,
}

/// The whole recording of a compute pass's dispatch: binds the pipeline, pushes its descriptors
/// (checked against the pass's declarations), sets the push constants `push` (none when empty)
/// and dispatches `groups` workgroups. A dispatch with a zero count is skipped (Vulkan allows it,
/// but it would still bind and push for nothing).
pub fn dispatch(
    rc: &penumbra_engine::RecordContext,
    h: PipelineHandle,
    binds: &[penumbra_engine::Bind],
    push: &[u8],
    groups: [u32; 3],
) -> Result<()> {
    if groups.contains(&0) {
        return Ok(());
    }
    if (push.len() as u32) < h.push_bytes {
        anyhow::bail!(
            "pushes {} bytes of push constants; the shader's push-constant block takes {}",
            push.len(),
            h.push_bytes
        );
    }
    bind_compute(rc, &h, binds)?;
    unsafe {
        let d = rc.device();
        if !push.is_empty() {
            d.cmd_push_constants(rc.cmd, h.layout, vk::ShaderStageFlags::COMPUTE, 0, push);
        }
        d.cmd_dispatch(rc.cmd, groups[0], groups[1], groups[2]);
    }
    Ok(())
}

/// Binds a compute pipeline and pushes its descriptors (checked against the pass's declarations
/// and the shader's bindings).
pub fn bind_compute(
    rc: &penumbra_engine::RecordContext,
    h: &PipelineHandle,
    binds: &[penumbra_engine::Bind],
) -> Result<()> {
    unsafe { rc.device().cmd_bind_pipeline(rc.cmd, vk::PipelineBindPoint::COMPUTE, h.pipeline) };
    rc.push_set(vk::PipelineBindPoint::COMPUTE, h.layout, &h.set, binds)
}

/// Pushes a graphics pipeline's descriptors (checked against the pass's declarations and the
/// shaders' bindings); the pipeline is bound by [`crate::raster::begin`].
pub fn push_graphics(
    rc: &penumbra_engine::RecordContext,
    h: &PipelineHandle,
    binds: &[penumbra_engine::Bind],
) -> Result<()> {
    rc.push_set(vk::PipelineBindPoint::GRAPHICS, h.layout, &h.set, binds)
}

/// Adds transfer pass `name` copying the first `size` bytes of `src` into `dst` (`None`: as much
/// as the smaller of the two holds; a zero size copies nothing); returns the new versions
/// `(src, dst)`.
pub fn copy_buffer(
    graph: &mut penumbra_engine::Graph,
    name: &str,
    src: penumbra_engine::BufferHandle,
    dst: penumbra_engine::BufferHandle,
    size: Option<u64>,
) -> (penumbra_engine::BufferHandle, penumbra_engine::BufferHandle) {
    use penumbra_engine::{Access, PassKind};
    let mut p = graph.pass(name, PassKind::Transfer);
    let s = p.read(src, Access::TransferSrc);
    let d = p.write(dst, Access::TransferDst);
    p.record(move |rc| {
        let (sb, db) = (rc.buffer(s)?, rc.buffer(d)?);
        let size = size.unwrap_or(sb.size.min(db.size));
        if size > 0 {
            let region = vk::BufferCopy { src_offset: 0, dst_offset: 0, size };
            unsafe { rc.device().cmd_copy_buffer(rc.cmd, sb.buffer, db.buffer, &[region]) };
        }
        Ok(())
    });
    (s, d)
}

/// Fills the whole of `dst` with the 32-bit `value` in a transfer pass `name`; returns `dst`'s new
/// version.
pub fn fill_buffer(
    graph: &mut penumbra_engine::Graph,
    name: &str,
    dst: penumbra_engine::BufferHandle,
    value: u32,
) -> penumbra_engine::BufferHandle {
    use penumbra_engine::{Access, PassKind};
    let mut p = graph.pass(name, PassKind::Transfer);
    let d = p.write(dst, Access::TransferDst);
    p.record(move |rc| {
        let b = rc.buffer(d)?;
        unsafe { rc.device().cmd_fill_buffer(rc.cmd, b.buffer, 0, vk::WHOLE_SIZE, value) };
        Ok(())
    });
    d
}

/// Uploads `data` into `dst` through a new host-visible buffer `staging` and transfer pass
/// `name`; returns `dst`'s new version.
pub fn upload_into(
    graph: &mut penumbra_engine::Graph,
    name: &str,
    staging: &str,
    data: Vec<u8>,
    dst: penumbra_engine::BufferHandle,
) -> penumbra_engine::BufferHandle {
    let src = graph.create_buffer_init(staging, data);
    copy_buffer(graph, name, src, dst, None).1
}

/// A colour attachment of `view` (in `COLOR_ATTACHMENT_OPTIMAL`) cleared to `clear` and stored.
pub fn color_attachment(view: vk::ImageView, clear: [f32; 4]) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .clear_value(vk::ClearValue { color: vk::ClearColorValue { float32: clear } })
}

/// A colour attachment of `view` over its previous contents (load op load; declare
/// `Access::ColorAttachmentReadWrite`).
pub fn color_attachment_load(view: vk::ImageView) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::LOAD)
        .store_op(vk::AttachmentStoreOp::STORE)
}

/// The stencil aspect of a depth-stencil `view` as a mask being drawn (in
/// `DEPTH_STENCIL_ATTACHMENT_OPTIMAL`, `Access::DepthStencilAttachmentWrite`): cleared to 0 and
/// stored.
pub fn stencil_mark_attachment(view: vk::ImageView) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::DEPTH_STENCIL_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(vk::AttachmentStoreOp::STORE)
        .clear_value(vk::ClearValue { depth_stencil: vk::ClearDepthStencilValue { depth: 1.0, stencil: 0 } })
}

/// The stencil aspect of a depth-stencil `view` tested read-only (in
/// `DEPTH_STENCIL_READ_ONLY_OPTIMAL`, `Access::DepthStencilAttachmentRead`): loaded, and store op
/// NONE so that the pass does not write it.
pub fn stencil_test_attachment(view: vk::ImageView) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::DEPTH_STENCIL_READ_ONLY_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::LOAD)
        .store_op(vk::AttachmentStoreOp::NONE)
}

/// A depth attachment of `view` (in `DEPTH_ATTACHMENT_OPTIMAL`) cleared to 1, stored when
/// `store` (else its contents are not kept).
pub fn depth_attachment(view: vk::ImageView, store: bool) -> vk::RenderingAttachmentInfo<'static> {
    vk::RenderingAttachmentInfo::default()
        .image_view(view)
        .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
        .load_op(vk::AttachmentLoadOp::CLEAR)
        .store_op(if store { vk::AttachmentStoreOp::STORE } else { vk::AttachmentStoreOp::DONT_CARE })
        .clear_value(vk::ClearValue { depth_stencil: vk::ClearDepthStencilValue { depth: 1.0, stencil: 0 } })
}

pub fn persistent_upload(
    engine: &mut penumbra_engine::FrameStore<'_>,
    graph: &mut penumbra_engine::Graph,
    name: &str,
    data: Vec<u8>,
    force: bool,
) -> penumbra_engine::BufferHandle {
    let size = data.len().max(16) as u64;
    let h = engine.persistent_buffer(graph, name, size);
    if !(force || graph.persistent_is_new(h)) {
        return h;
    }
    crate::util::upload_into(graph, &format!("upload_{name}"), &format!("{name}.upload"), data, h)
}

/// `bytes` padded with zeros to whole 16-byte texels: the size of a buffer a shader reads as a
/// texel buffer (`Bind::TexelBuffer`, whose view covers whole texels only).
pub fn whole_texels(mut bytes: Vec<u8>) -> Vec<u8> {
    bytes.resize(texel_bytes(bytes.len() as u64) as usize, 0);
    bytes
}

/// `bytes` rounded up to whole 16-byte texels (at least one): the size of a buffer a shader
/// reads as a texel buffer.
pub fn texel_bytes(bytes: u64) -> u64 {
    bytes.next_multiple_of(16).max(16)
}

/// Storage-buffer binds of `bufs`, in binding order (most of a compute pass's bind list).
pub fn storage<const N: usize>(bufs: [penumbra_engine::BufferHandle; N]) -> [penumbra_engine::Bind; N] {
    bufs.map(penumbra_engine::Bind::StorageBuffer)
}

/// Submits `graph` (which reads buffer `from` back as `name`), waits for every frame in flight
/// and returns the read-back bytes: the end of the GPU test kernels (`crate::kernels`).
pub fn submit_and_read(
    engine: &mut penumbra_engine::Engine,
    mut graph: penumbra_engine::Graph,
    from: penumbra_engine::BufferHandle,
    name: &str,
    bytes: u64,
) -> anyhow::Result<Vec<u8>> {
    let rb = graph.create_readback(name, bytes);
    copy_buffer(&mut graph, &format!("{name}_readback"), from, rb, None);
    let (_, mut done) = engine.submit(graph)?;
    done.extend(engine.drain()?);
    done.into_iter().find_map(|o| o.readbacks.get(name).cloned()).ok_or_else(|| anyhow::anyhow!("{name}: no readback"))
}

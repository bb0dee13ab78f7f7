//! What a pass's record closure gets: the command buffer, the resources it declared (resolved
//! to Vulkan objects) and descriptor pushes checked against its declarations. Between the graph
//! (which stores record closures) and the executor (which calls them).

use crate::context::Context;
use crate::resource::{BufferHandle, GraphHandle, ImageDesc, ImageHandle};
use anyhow::{anyhow, bail, Result};
use ash::vk;

/// A resolved image for pass recording.
#[derive(Clone, Debug)]
pub struct PhysImage {
    pub image: vk::Image,
    pub view: vk::ImageView,
    pub desc: ImageDesc,
}

/// A resolved buffer for pass recording.
#[derive(Clone, Copy, Debug)]
pub struct PhysBuffer {
    pub buffer: vk::Buffer,
    pub size: u64,
    /// The buffer's `R32G32B32A32_UINT` texel view where it has one (a buffer some pass reads
    /// as a texel buffer, persistent buffers always).
    pub texel_view: Option<vk::BufferView>,
}

/// What a pass's record closure gets.
pub struct RecordContext<'a> {
    pub ctx: &'a Context,
    pub cmd: vk::CommandBuffer,
    pub pass: &'a str,
    pub(crate) declared: Vec<(u32, crate::access::Access)>,
    pub(crate) images: &'a [Option<PhysImage>],
    pub(crate) buffers: &'a [Option<PhysBuffer>],
    pub(crate) names: &'a [String],
}

impl<'a> RecordContext<'a> {
    pub fn device(&self) -> &ash::Device {
        &self.ctx.device
    }

    fn check(&self, id: u32) -> Result<()> {
        if !self.declared.iter().any(|d| d.0 == id) {
            let resource = self.names.get(id as usize).cloned().unwrap_or_else(|| format!("#{id}"));
            // the graph's `Problem::Undeclared`, caught at record time
            return Err(anyhow!("pass '{}' used '{resource}' without declaring it", self.pass));
        }
        Ok(())
    }

    /// The image behind a handle this pass declared.
    pub fn image(&self, h: ImageHandle) -> Result<&PhysImage> {
        self.check(h.raw().0)?;
        self.images
            .get(h.raw().0 as usize)
            .and_then(|i| i.as_ref())
            .ok_or_else(|| anyhow!("pass '{}': image #{} is not allocated", self.pass, h.raw().0))
    }

    fn name(&self, id: u32) -> String {
        self.names.get(id as usize).cloned().unwrap_or_default()
    }

    /// Checks that the pass declared `id` with an access satisfying `ok`, for a descriptor of `what`.
    fn check_bind(&self, id: u32, what: &str, ok: impl Fn(crate::access::Access) -> bool) -> Result<()> {
        self.check(id)?;
        let declared: Vec<_> = self.declared.iter().filter(|d| d.0 == id).map(|d| d.1).collect();
        if !declared.iter().any(|a| ok(*a)) {
            bail!("pass '{}' binds '{}' as {what}, but declared it as {:?}", self.pass, self.name(id), declared);
        }
        Ok(())
    }

    /// Pushes descriptors (VK_KHR_push_descriptor) for `set`, binding i = `binds[i]`. Every
    /// binding is checked against the pass's declarations: a storage image declared as sampled
    /// (or any other mismatch) is an error, and image layouts come from the declared access.
    pub fn push_descriptors(
        &self,
        bind_point: vk::PipelineBindPoint,
        layout: vk::PipelineLayout,
        set: u32,
        binds: &[Bind],
    ) -> Result<()> {
        self.push(bind_point, layout, set, binds, None)
    }

    /// Pushes set 0 of a pipeline whose layout is `shader_set` (its shaders' own bindings,
    /// [`crate::reflect::SetLayout`]): binding i = `binds[i]`, checked against the pass's
    /// declarations as in [`Self::push_descriptors`] and against the shaders: a bind of another
    /// type than the shader's binding is an error naming it, a binding the shaders use and
    /// `binds` does not reach is an error, and a bind no stage uses is checked but not written.
    pub fn push_set(
        &self,
        bind_point: vk::PipelineBindPoint,
        layout: vk::PipelineLayout,
        shader_set: &crate::reflect::SetLayout,
        binds: &[Bind],
    ) -> Result<()> {
        if let Some((b, t)) = shader_set.bindings().find(|&(b, _)| b as usize >= binds.len()) {
            bail!("pass '{}': its shaders use binding {b} ({t:?}) but it binds {} descriptors", self.pass, binds.len());
        }
        self.push(bind_point, layout, 0, binds, Some(shader_set))
    }

    fn push(
        &self,
        bind_point: vk::PipelineBindPoint,
        layout: vk::PipelineLayout,
        set: u32,
        binds: &[Bind],
        shader_set: Option<&crate::reflect::SetLayout>,
    ) -> Result<()> {
        use crate::access::Access as A;
        use vk::DescriptorType as T;
        enum Info {
            Image(vk::DescriptorImageInfo),
            Buffer(vk::DescriptorBufferInfo),
            Texel(vk::BufferView),
        }
        // what a sampled image and a texel buffer may be declared as
        let sampled = |a| {
            matches!(
                a,
                A::VertexShaderReadSampled
                    | A::FragmentShaderReadSampled
                    | A::ComputeShaderReadSampled
                    | A::AnyShaderReadSampled
            )
        };
        let mut infos = Vec::with_capacity(binds.len());
        for (binding, b) in binds.iter().enumerate() {
            // the descriptor's type, the bound resource (its graph id) and its info
            let (ty, id, info) = match *b {
                Bind::SampledImage(h, sampler) => {
                    self.check_bind(h.raw().0, "a sampled image", sampled)?;
                    let image_view = self.image(h)?.view;
                    let image_layout = vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL;
                    (
                        T::COMBINED_IMAGE_SAMPLER,
                        h.raw().0,
                        Info::Image(vk::DescriptorImageInfo { sampler, image_view, image_layout }),
                    )
                }
                Bind::StorageImage(h) => {
                    let ok = |a| {
                        matches!(
                            a,
                            A::FragmentShaderReadStorage
                                | A::ComputeShaderReadStorage
                                | A::ComputeShaderWriteStorage
                                | A::ComputeShaderReadWriteStorage
                        )
                    };
                    self.check_bind(h.raw().0, "a storage image", ok)?;
                    let image_view = self.image(h)?.view;
                    let info = vk::DescriptorImageInfo {
                        sampler: vk::Sampler::null(),
                        image_view,
                        image_layout: vk::ImageLayout::GENERAL,
                    };
                    (T::STORAGE_IMAGE, h.raw().0, Info::Image(info))
                }
                Bind::UniformBuffer(h) => {
                    self.check_bind(h.raw().0, "a uniform buffer", |a| a == A::AnyShaderReadUniform)?;
                    (T::UNIFORM_BUFFER, h.raw().0, Info::Buffer(self.whole(h)?))
                }
                Bind::StorageBuffer(h) => {
                    let ok = |a| {
                        matches!(
                            a,
                            A::VertexShaderReadStorage
                                | A::AnyShaderReadStorage
                                | A::FragmentShaderReadStorage
                                | A::ComputeShaderReadStorage
                                | A::ComputeShaderWriteStorage
                                | A::ComputeShaderReadWriteStorage
                        )
                    };
                    self.check_bind(h.raw().0, "a storage buffer", ok)?;
                    (T::STORAGE_BUFFER, h.raw().0, Info::Buffer(self.whole(h)?))
                }
                Bind::TexelBuffer(h) => {
                    self.check_bind(h.raw().0, "a texel buffer", sampled)?;
                    let b = self.buffer(h)?;
                    let view = b.texel_view.ok_or_else(|| {
                        anyhow!("pass '{}': buffer '{}' has no texel view (imported?)", self.pass, self.name(h.raw().0))
                    })?;
                    let limit = self.ctx.max_texel_buffer_elements as u64 * 16;
                    if b.size > limit {
                        bail!(
                            "pass '{}': buffer '{}' ({} bytes) is larger than the device's texel buffers ({} bytes)",
                            self.pass,
                            self.name(h.raw().0),
                            b.size,
                            limit
                        );
                    }
                    (T::UNIFORM_TEXEL_BUFFER, h.raw().0, Info::Texel(view))
                }
            };
            match shader_set.map(|s| s.get(binding)) {
                // no stage uses it: checked, not written
                Some(None) => continue,
                Some(Some(t)) if t != ty => bail!(
                    "pass '{}': binding {binding} is a {t:?} in its shaders but the pass binds '{}' as a {ty:?}",
                    self.pass,
                    self.name(id)
                ),
                _ => infos.push((binding as u32, ty, info)),
            }
        }
        let writes: Vec<_> = infos
            .iter()
            .map(|(binding, ty, info)| {
                let w = vk::WriteDescriptorSet::default().dst_binding(*binding).descriptor_type(*ty);
                match info {
                    Info::Image(x) => w.image_info(std::slice::from_ref(x)),
                    Info::Buffer(x) => w.buffer_info(std::slice::from_ref(x)),
                    Info::Texel(x) => w.texel_buffer_view(std::slice::from_ref(x)),
                }
            })
            .collect();
        if writes.is_empty() {
            return Ok(());
        }
        unsafe { self.ctx.push_descriptor.cmd_push_descriptor_set(self.cmd, bind_point, layout, set, &writes) };
        Ok(())
    }

    /// The whole of the buffer behind `h`, as a descriptor.
    fn whole(&self, h: BufferHandle) -> Result<vk::DescriptorBufferInfo> {
        Ok(vk::DescriptorBufferInfo { buffer: self.buffer(h)?.buffer, offset: 0, range: vk::WHOLE_SIZE })
    }

    /// The buffer behind a handle this pass declared.
    pub fn buffer(&self, h: BufferHandle) -> Result<PhysBuffer> {
        self.check(h.raw().0)?;
        self.buffers
            .get(h.raw().0 as usize)
            .and_then(|b| *b)
            .ok_or_else(|| anyhow!("pass '{}': buffer #{} is not allocated", self.pass, h.raw().0))
    }
}

/// One descriptor binding for [`RecordContext::push_descriptors`].
#[derive(Clone, Copy, Debug)]
pub enum Bind {
    SampledImage(ImageHandle, vk::Sampler),
    StorageImage(ImageHandle),
    UniformBuffer(BufferHandle),
    StorageBuffer(BufferHandle),
    /// A buffer read as a `usamplerBuffer` (`texelFetch`, 16-byte `uvec4` texels) through its
    /// `R32G32B32A32_UINT` view; declared as a sampled read (e.g.
    /// [`crate::Access::ComputeShaderReadSampled`]). On a CPU
    /// device (llvmpipe) a texel fetch at a per-invocation index is one gather of 16-byte texels,
    /// where a storage-buffer read is a bounds-checked scalar load per lane and component.
    TexelBuffer(BufferHandle),
}

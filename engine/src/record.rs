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
        use crate::access::Access as A;
        let mut image_infos: Vec<[vk::DescriptorImageInfo; 1]> = Vec::new();
        let mut buffer_infos: Vec<[vk::DescriptorBufferInfo; 1]> = Vec::new();
        let mut kinds = Vec::new();
        for b in binds {
            match *b {
                Bind::SampledImage(h, sampler) => {
                    self.check_bind(h.raw().0, "a sampled image", |a| {
                        matches!(
                            a,
                            A::VertexShaderReadSampled
                                | A::FragmentShaderReadSampled
                                | A::ComputeShaderReadSampled
                                | A::AnyShaderReadSampled
                        )
                    })?;
                    let img = self.image(h)?;
                    image_infos.push([vk::DescriptorImageInfo {
                        sampler,
                        image_view: img.view,
                        image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                    }]);
                    kinds.push((vk::DescriptorType::COMBINED_IMAGE_SAMPLER, image_infos.len() - 1));
                }
                Bind::StorageImage(h) => {
                    self.check_bind(h.raw().0, "a storage image", |a| {
                        matches!(
                            a,
                            A::FragmentShaderReadStorage
                                | A::ComputeShaderReadStorage
                                | A::ComputeShaderWriteStorage
                                | A::ComputeShaderReadWriteStorage
                        )
                    })?;
                    let img = self.image(h)?;
                    image_infos.push([vk::DescriptorImageInfo {
                        sampler: vk::Sampler::null(),
                        image_view: img.view,
                        image_layout: vk::ImageLayout::GENERAL,
                    }]);
                    kinds.push((vk::DescriptorType::STORAGE_IMAGE, image_infos.len() - 1));
                }
                Bind::UniformBuffer(h) => {
                    self.check_bind(h.raw().0, "a uniform buffer", |a| a == A::AnyShaderReadUniform)?;
                    let buf = self.buffer(h)?;
                    buffer_infos.push([vk::DescriptorBufferInfo {
                        buffer: buf.buffer,
                        offset: 0,
                        range: vk::WHOLE_SIZE,
                    }]);
                    kinds.push((vk::DescriptorType::UNIFORM_BUFFER, buffer_infos.len() - 1));
                }
                Bind::StorageBuffer(h) => {
                    self.check_bind(h.raw().0, "a storage buffer", |a| {
                        matches!(
                            a,
                            A::VertexShaderReadStorage
                                | A::AnyShaderReadStorage
                                | A::FragmentShaderReadStorage
                                | A::ComputeShaderReadStorage
                                | A::ComputeShaderWriteStorage
                                | A::ComputeShaderReadWriteStorage
                        )
                    })?;
                    let buf = self.buffer(h)?;
                    buffer_infos.push([vk::DescriptorBufferInfo {
                        buffer: buf.buffer,
                        offset: 0,
                        range: vk::WHOLE_SIZE,
                    }]);
                    kinds.push((vk::DescriptorType::STORAGE_BUFFER, buffer_infos.len() - 1));
                }
            }
        }
        let writes: Vec<vk::WriteDescriptorSet> = kinds
            .iter()
            .enumerate()
            .map(|(binding, (ty, idx))| {
                let w = vk::WriteDescriptorSet::default().dst_binding(binding as u32).descriptor_type(*ty);
                match *ty {
                    vk::DescriptorType::UNIFORM_BUFFER | vk::DescriptorType::STORAGE_BUFFER => {
                        w.buffer_info(&buffer_infos[*idx])
                    }
                    _ => w.image_info(&image_infos[*idx]),
                }
            })
            .collect();
        unsafe { self.ctx.push_descriptor.cmd_push_descriptor_set(self.cmd, bind_point, layout, set, &writes) };
        Ok(())
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
}

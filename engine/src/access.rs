//! The one table: every way a pass can touch a resource, mapped to a synchronization2 stage,
//! access mask and image layout, plus the usage flags the resource needs for it.
//!
//! Barriers are derived only from these declarations; nothing is guessed from pass code.

use ash::vk;
use serde::Serialize;

/// How a pass uses a resource. Each variant names the pipeline stage and the kind of access.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum Access {
    // ---- images
    /// Written as a colour attachment (load op clear or dont-care: the previous contents are
    /// not kept).
    ColorAttachmentWrite,
    /// Written as a colour attachment over its previous contents (load op load: pixels the
    /// pass does not cover keep their values, e.g. a history updated where a stencil test passes).
    ColorAttachmentReadWrite,
    /// Depth test and depth write.
    DepthAttachmentWrite,
    /// Depth test only, read-only depth layout.
    DepthAttachmentRead,
    /// Depth and stencil test/write on a depth-stencil format (e.g. a stencil mask).
    DepthStencilAttachmentWrite,
    /// Depth and stencil tests only (read-only depth-stencil layout).
    DepthStencilAttachmentRead,
    /// `sampler2D`/`texelFetch` in a vertex shader.
    VertexShaderReadSampled,
    /// `sampler2D`/`texelFetch` in a fragment shader.
    FragmentShaderReadSampled,
    /// `sampler2D`/`texelFetch` in a compute shader.
    ComputeShaderReadSampled,
    /// Sampled read by any shader stage (read-only data such as uploaded textures; mostly as an
    /// imported resource's final/initial access).
    AnyShaderReadSampled,
    // ---- images or buffers
    // (The four `*ReadSampled` accesses above also apply to buffers: a uniform texel buffer
    // read, `usamplerBuffer` + `texelFetch`, bound with `record::Bind::TexelBuffer`.)
    /// Storage image/buffer read in a fragment shader.
    FragmentShaderReadStorage,
    /// Storage image/buffer read in a compute shader.
    ComputeShaderReadStorage,
    /// Storage image/buffer write in a compute shader (no read of previous contents).
    ComputeShaderWriteStorage,
    /// Storage image/buffer read-modify-write in a compute shader.
    ComputeShaderReadWriteStorage,
    /// Copy/blit source.
    TransferSrc,
    /// Copy/blit/clear destination.
    TransferDst,
    // ---- buffers
    /// Storage buffer read in a vertex shader.
    VertexShaderReadStorage,
    /// Storage buffer read by any shader stage (read-only tables, e.g. the scene's materials
    /// read by a raster pass's vertex, tessellation and fragment stages).
    AnyShaderReadStorage,
    /// Uniform buffer read by any shader stage.
    AnyShaderReadUniform,
    /// Vertex buffer binding.
    VertexBuffer,
    /// Index buffer binding.
    IndexBuffer,
    /// Indirect draw/dispatch arguments.
    IndirectBuffer,
    /// Read by the host after the frame's fence (readback).
    HostRead,
    // ---- presentation
    /// Owned by the presentation engine (a swapchain image): only as an imported image's
    /// initial access (acquired; the acquire semaphore is waited at `ALL_COMMANDS`) or final
    /// access (presented; the render-finished semaphore is signalled at `ALL_COMMANDS`), never
    /// in a pass. Layout `PRESENT_SRC_KHR`, no memory access of the frame's own.
    Present,
}

/// Which resource types an access applies to.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Applies {
    Image,
    Buffer,
    Both,
}

/// What an [`Access`] means to Vulkan.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub struct AccessInfo {
    pub stage: vk::PipelineStageFlags2,
    pub access: vk::AccessFlags2,
    /// Image layout during the access (`UNDEFINED` for buffer-only accesses).
    pub layout: vk::ImageLayout,
    /// The access writes (creates a new version of the resource).
    pub write: bool,
    /// The access also reads the previous contents (read-modify-write).
    pub reads_previous: bool,
    pub applies: Applies,
    pub image_usage: vk::ImageUsageFlags,
    pub buffer_usage: vk::BufferUsageFlags,
    /// The access needs a depth/stencil format (`Some(true)`), a colour format (`Some(false)`),
    /// or does not care (`None`).
    pub depth_format: Option<bool>,
}

impl Access {
    /// Every access kind, in declaration order (for tests and documentation).
    pub const ALL: [Access; 24] = [
        Access::ColorAttachmentWrite,
        Access::ColorAttachmentReadWrite,
        Access::DepthAttachmentWrite,
        Access::DepthAttachmentRead,
        Access::DepthStencilAttachmentWrite,
        Access::DepthStencilAttachmentRead,
        Access::VertexShaderReadSampled,
        Access::FragmentShaderReadSampled,
        Access::ComputeShaderReadSampled,
        Access::AnyShaderReadSampled,
        Access::FragmentShaderReadStorage,
        Access::ComputeShaderReadStorage,
        Access::ComputeShaderWriteStorage,
        Access::ComputeShaderReadWriteStorage,
        Access::TransferSrc,
        Access::TransferDst,
        Access::VertexShaderReadStorage,
        Access::AnyShaderReadStorage,
        Access::AnyShaderReadUniform,
        Access::VertexBuffer,
        Access::IndexBuffer,
        Access::IndirectBuffer,
        Access::HostRead,
        Access::Present,
    ];

    /// The table.
    pub fn info(self) -> AccessInfo {
        use vk::AccessFlags2 as A;
        use vk::BufferUsageFlags as BU;
        use vk::ImageLayout as L;
        use vk::ImageUsageFlags as IU;
        use vk::PipelineStageFlags2 as S;
        // every shader stage (the AnyShader* accesses)
        let any_shader = S::VERTEX_SHADER
            | S::TESSELLATION_CONTROL_SHADER
            | S::TESSELLATION_EVALUATION_SHADER
            | S::GEOMETRY_SHADER
            | S::FRAGMENT_SHADER
            | S::COMPUTE_SHADER;
        let (stage, access, layout, write, reads_previous, applies, image_usage, buffer_usage, depth) = match self {
            Access::ColorAttachmentWrite => (
                S::COLOR_ATTACHMENT_OUTPUT,
                A::COLOR_ATTACHMENT_WRITE | A::COLOR_ATTACHMENT_READ,
                L::COLOR_ATTACHMENT_OPTIMAL,
                true,
                false,
                Applies::Image,
                IU::COLOR_ATTACHMENT,
                BU::empty(),
                Some(false),
            ),
            Access::ColorAttachmentReadWrite => (
                S::COLOR_ATTACHMENT_OUTPUT,
                A::COLOR_ATTACHMENT_WRITE | A::COLOR_ATTACHMENT_READ,
                L::COLOR_ATTACHMENT_OPTIMAL,
                true,
                true,
                Applies::Image,
                IU::COLOR_ATTACHMENT,
                BU::empty(),
                Some(false),
            ),
            Access::DepthAttachmentWrite => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                A::DEPTH_STENCIL_ATTACHMENT_READ | A::DEPTH_STENCIL_ATTACHMENT_WRITE,
                L::DEPTH_ATTACHMENT_OPTIMAL,
                true,
                false,
                Applies::Image,
                IU::DEPTH_STENCIL_ATTACHMENT,
                BU::empty(),
                Some(true),
            ),
            Access::DepthAttachmentRead => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                A::DEPTH_STENCIL_ATTACHMENT_READ,
                L::DEPTH_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Image,
                IU::DEPTH_STENCIL_ATTACHMENT,
                BU::empty(),
                Some(true),
            ),
            Access::DepthStencilAttachmentWrite => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                A::DEPTH_STENCIL_ATTACHMENT_READ | A::DEPTH_STENCIL_ATTACHMENT_WRITE,
                L::DEPTH_STENCIL_ATTACHMENT_OPTIMAL,
                true,
                false,
                Applies::Image,
                IU::DEPTH_STENCIL_ATTACHMENT,
                BU::empty(),
                Some(true),
            ),
            Access::DepthStencilAttachmentRead => (
                S::EARLY_FRAGMENT_TESTS | S::LATE_FRAGMENT_TESTS,
                A::DEPTH_STENCIL_ATTACHMENT_READ,
                L::DEPTH_STENCIL_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Image,
                IU::DEPTH_STENCIL_ATTACHMENT,
                BU::empty(),
                Some(true),
            ),
            Access::VertexShaderReadSampled => (
                S::VERTEX_SHADER,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Both,
                IU::SAMPLED,
                BU::UNIFORM_TEXEL_BUFFER,
                None,
            ),
            Access::FragmentShaderReadSampled => (
                S::FRAGMENT_SHADER,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Both,
                IU::SAMPLED,
                BU::UNIFORM_TEXEL_BUFFER,
                None,
            ),
            Access::ComputeShaderReadSampled => (
                S::COMPUTE_SHADER,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Both,
                IU::SAMPLED,
                BU::UNIFORM_TEXEL_BUFFER,
                None,
            ),
            Access::AnyShaderReadSampled => (
                any_shader,
                A::SHADER_SAMPLED_READ,
                L::SHADER_READ_ONLY_OPTIMAL,
                false,
                false,
                Applies::Both,
                IU::SAMPLED,
                BU::UNIFORM_TEXEL_BUFFER,
                None,
            ),
            Access::FragmentShaderReadStorage => (
                S::FRAGMENT_SHADER,
                A::SHADER_STORAGE_READ,
                L::GENERAL,
                false,
                false,
                Applies::Both,
                IU::STORAGE,
                BU::STORAGE_BUFFER,
                Some(false),
            ),
            Access::ComputeShaderReadStorage => (
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ,
                L::GENERAL,
                false,
                false,
                Applies::Both,
                IU::STORAGE,
                BU::STORAGE_BUFFER,
                Some(false),
            ),
            Access::ComputeShaderWriteStorage => (
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_WRITE,
                L::GENERAL,
                true,
                false,
                Applies::Both,
                IU::STORAGE,
                BU::STORAGE_BUFFER,
                Some(false),
            ),
            Access::ComputeShaderReadWriteStorage => (
                S::COMPUTE_SHADER,
                A::SHADER_STORAGE_READ | A::SHADER_STORAGE_WRITE,
                L::GENERAL,
                true,
                true,
                Applies::Both,
                IU::STORAGE,
                BU::STORAGE_BUFFER,
                Some(false),
            ),
            // Copies and blits (sync2 splits TRANSFER into COPY, BLIT, CLEAR, RESOLVE).
            Access::TransferSrc => (
                S::COPY | S::BLIT,
                A::TRANSFER_READ,
                L::TRANSFER_SRC_OPTIMAL,
                false,
                false,
                Applies::Both,
                IU::TRANSFER_SRC,
                BU::TRANSFER_SRC,
                None,
            ),
            Access::TransferDst => (
                S::COPY | S::BLIT | S::CLEAR,
                A::TRANSFER_WRITE,
                L::TRANSFER_DST_OPTIMAL,
                true,
                false,
                Applies::Both,
                IU::TRANSFER_DST,
                BU::TRANSFER_DST,
                None,
            ),
            Access::VertexShaderReadStorage => (
                S::VERTEX_SHADER,
                A::SHADER_STORAGE_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::STORAGE_BUFFER,
                None,
            ),
            Access::AnyShaderReadStorage => (
                any_shader,
                A::SHADER_STORAGE_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::STORAGE_BUFFER,
                None,
            ),
            Access::AnyShaderReadUniform => (
                any_shader,
                A::UNIFORM_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::UNIFORM_BUFFER,
                None,
            ),
            Access::VertexBuffer => (
                S::VERTEX_ATTRIBUTE_INPUT,
                A::VERTEX_ATTRIBUTE_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::VERTEX_BUFFER,
                None,
            ),
            Access::IndexBuffer => (
                S::INDEX_INPUT,
                A::INDEX_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::INDEX_BUFFER,
                None,
            ),
            Access::IndirectBuffer => (
                S::DRAW_INDIRECT,
                A::INDIRECT_COMMAND_READ,
                L::UNDEFINED,
                false,
                false,
                Applies::Buffer,
                IU::empty(),
                BU::INDIRECT_BUFFER,
                None,
            ),
            Access::HostRead => {
                (S::HOST, A::HOST_READ, L::UNDEFINED, false, false, Applies::Buffer, IU::empty(), BU::empty(), None)
            }
            // Execution-only dependency on the semaphore operation at ALL_COMMANDS: the layout
            // transition to/from PRESENT_SRC_KHR is ordered with the acquire/present semaphores.
            Access::Present => (
                S::ALL_COMMANDS,
                A::NONE,
                L::PRESENT_SRC_KHR,
                false,
                false,
                Applies::Image,
                IU::empty(),
                BU::empty(),
                Some(false),
            ),
        };
        AccessInfo {
            stage,
            access,
            layout,
            write,
            reads_previous,
            applies,
            image_usage,
            buffer_usage,
            depth_format: depth,
        }
    }

    pub fn is_write(self) -> bool {
        self.info().write
    }
}

pub use crate::resource::{format_texel_bytes, has_stencil, is_depth_format};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_is_consistent() {
        for a in Access::ALL {
            let i = a.info();
            assert!(!i.stage.is_empty(), "{a:?} has no stage");
            if a == Access::Present {
                // The presentation engine's accesses are made visible by the semaphores.
                assert!(i.access.is_empty() && !i.write && i.layout == vk::ImageLayout::PRESENT_SRC_KHR);
                continue;
            }
            assert!(!i.access.is_empty(), "{a:?} has no access mask");
            match i.applies {
                Applies::Image => {
                    assert_ne!(i.layout, vk::ImageLayout::UNDEFINED, "{a:?}");
                    assert!(!i.image_usage.is_empty(), "{a:?}");
                }
                Applies::Buffer => assert_eq!(i.layout, vk::ImageLayout::UNDEFINED, "{a:?}"),
                Applies::Both => {
                    assert_ne!(i.layout, vk::ImageLayout::UNDEFINED, "{a:?}");
                    assert!(!i.image_usage.is_empty() && !i.buffer_usage.is_empty(), "{a:?}");
                }
            }
            // A write access must carry a write bit in its mask; a read access none.
            let writes = vk::AccessFlags2::SHADER_STORAGE_WRITE
                | vk::AccessFlags2::COLOR_ATTACHMENT_WRITE
                | vk::AccessFlags2::DEPTH_STENCIL_ATTACHMENT_WRITE
                | vk::AccessFlags2::TRANSFER_WRITE
                | vk::AccessFlags2::HOST_WRITE;
            assert_eq!(i.write, i.access.intersects(writes), "{a:?} write flag disagrees with its mask");
            if i.reads_previous {
                assert!(i.write);
            }
        }
    }

    #[test]
    fn specific_rows() {
        let s = Access::ComputeShaderReadSampled.info();
        assert_eq!(s.stage, vk::PipelineStageFlags2::COMPUTE_SHADER);
        assert_eq!(s.access, vk::AccessFlags2::SHADER_SAMPLED_READ);
        assert_eq!(s.layout, vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL);
        let w = Access::ComputeShaderWriteStorage.info();
        assert_eq!(w.layout, vk::ImageLayout::GENERAL);
        assert_eq!(w.access, vk::AccessFlags2::SHADER_STORAGE_WRITE);
        let d = Access::DepthAttachmentWrite.info();
        assert_eq!(d.layout, vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL);
        assert_eq!(d.depth_format, Some(true));
        assert_eq!(Access::TransferDst.info().layout, vk::ImageLayout::TRANSFER_DST_OPTIMAL);
        // Blits are transfers too (a swapchain target is blitted into): found by sync
        // validation when the rows named COPY only.
        assert!(Access::TransferSrc.info().stage.contains(vk::PipelineStageFlags2::BLIT));
        assert!(Access::TransferDst.info().stage.contains(vk::PipelineStageFlags2::BLIT));
        assert_eq!(Access::HostRead.info().stage, vk::PipelineStageFlags2::HOST);
    }
}

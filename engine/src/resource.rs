//! Resources as the graph and the device layer both see them: versioned handles, image and
//! buffer descriptions, format facts. Below both: the device layer (`context`) never names the
//! graph.

use ash::vk;

/// A versioned image handle. Copy it freely; it is only meaningful in the graph that made it.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct ImageHandle {
    pub(crate) id: u32,
    pub(crate) version: u32,
}

/// A versioned buffer handle.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BufferHandle {
    pub(crate) id: u32,
    pub(crate) version: u32,
}

/// Anything a pass can declare a use of.
pub trait GraphHandle: Copy {
    fn raw(self) -> (u32, u32);
    fn with_version(self, v: u32) -> Self;
    const IS_IMAGE: bool;
}

impl GraphHandle for ImageHandle {
    fn raw(self) -> (u32, u32) {
        (self.id, self.version)
    }
    fn with_version(self, v: u32) -> Self {
        ImageHandle { id: self.id, version: v }
    }
    const IS_IMAGE: bool = true;
}

impl GraphHandle for BufferHandle {
    fn raw(self) -> (u32, u32) {
        (self.id, self.version)
    }
    fn with_version(self, v: u32) -> Self {
        BufferHandle { id: self.id, version: v }
    }
    const IS_IMAGE: bool = false;
}

impl ImageHandle {
    pub fn version(self) -> u32 {
        self.version
    }
}
impl BufferHandle {
    pub fn version(self) -> u32 {
        self.version
    }
}

/// Description of an image the graph allocates (or of an imported one).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ImageDesc {
    pub format: vk::Format,
    pub width: u32,
    pub height: u32,
    pub mip_levels: u32,
    pub array_layers: u32,
    /// View the image as a 2D array (`sampler2DArray`) even with one layer.
    pub array_view: bool,
}

impl ImageDesc {
    pub fn new_2d(format: vk::Format, width: u32, height: u32) -> Self {
        ImageDesc { format, width, height, mip_levels: 1, array_layers: 1, array_view: false }
    }
    /// A 2D array of `layers` layers, viewed as an array.
    pub fn with_layers(mut self, layers: u32) -> Self {
        self.array_layers = layers.max(1);
        self.array_view = true;
        self
    }
    pub fn with_mips(mut self, mips: u32) -> Self {
        self.mip_levels = mips;
        self
    }
    /// Bytes of all mips and layers.
    pub fn bytes(&self) -> u64 {
        let texel = format_texel_bytes(self.format);
        (0..self.mip_levels)
            .map(|m| ((self.width >> m).max(1) as u64) * ((self.height >> m).max(1) as u64) * texel)
            .sum::<u64>()
            * self.array_layers as u64
    }
    pub fn aspect(&self) -> vk::ImageAspectFlags {
        if is_depth_format(self.format) {
            let mut a = vk::ImageAspectFlags::DEPTH;
            if has_stencil(self.format) {
                a |= vk::ImageAspectFlags::STENCIL;
            }
            a
        } else {
            vk::ImageAspectFlags::COLOR
        }
    }
}

/// Description of a buffer.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct BufferDesc {
    pub size: u64,
    /// Host-visible memory (readback and host-initialised buffers).
    pub host_visible: bool,
}

/// True for depth and depth/stencil formats.
pub fn is_depth_format(f: vk::Format) -> bool {
    matches!(
        f,
        vk::Format::D16_UNORM
            | vk::Format::D32_SFLOAT
            | vk::Format::D24_UNORM_S8_UINT
            | vk::Format::D32_SFLOAT_S8_UINT
            | vk::Format::D16_UNORM_S8_UINT
            | vk::Format::X8_D24_UNORM_PACK32
    )
}

/// True for formats with a stencil aspect.
pub fn has_stencil(f: vk::Format) -> bool {
    matches!(
        f,
        vk::Format::D24_UNORM_S8_UINT
            | vk::Format::D32_SFLOAT_S8_UINT
            | vk::Format::D16_UNORM_S8_UINT
            | vk::Format::S8_UINT
    )
}

/// Bytes per texel of the formats the engine allocates (for dumps and readback).
pub fn format_texel_bytes(f: vk::Format) -> u64 {
    use vk::Format as F;
    match f {
        F::R8_UNORM | F::R8_UINT | F::S8_UINT => 1,
        F::R16_SFLOAT | F::R16_UINT | F::D16_UNORM | F::R8G8_UNORM => 2,
        F::R8G8B8A8_UNORM
        | F::R8G8B8A8_SRGB
        | F::B8G8R8A8_UNORM
        | F::B8G8R8A8_SRGB
        | F::R32_SFLOAT
        | F::R32_UINT
        | F::D32_SFLOAT
        | F::D24_UNORM_S8_UINT
        | F::R16G16_SFLOAT
        | F::A2B10G10R10_UNORM_PACK32
        | F::B10G11R11_UFLOAT_PACK32
        | F::X8_D24_UNORM_PACK32 => 4,
        F::D32_SFLOAT_S8_UINT => 5,
        F::R16G16B16A16_SFLOAT | F::R32G32_SFLOAT | F::R32G32_UINT => 8,
        F::R32G32B32_SFLOAT => 12,
        F::R32G32B32A32_SFLOAT | F::R32G32B32A32_UINT => 16,
        _ => 4,
    }
}

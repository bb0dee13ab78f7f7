//! Material texture maps on the GPU without descriptor indexing: every scene texture is
//! resampled (bilinear, repeat, as `Texture::sample`) to one `LAYER_SIZE`² layer of an RGBA32F
//! 2D array with a box-filtered mip chain. The image belongs to the scene's GPU data and is
//! imported into every frame; the first frame's `textures_upload` pass fills it and leaves it
//! readable by any shader stage (`Access::AnyShaderReadSampled`). Materials refer to layers
//! (`MaterialData.extra.y/z` in `common.glsl`).

use crate::util::bytes_of;
use anyhow::Result;
use glam::Vec2;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::{vk, Access, Context, GpuImage, Graph, ImageHandle, ImportedImage};
use penumbra_scene::Texture;
use std::cell::Cell;
use std::sync::Arc;

/// Edge of every layer (texels). Larger textures are downsampled to it.
pub const LAYER_SIZE: u32 = 256;

/// CPU texels of the array: per layer, per mip.
pub struct TextureLayers {
    layers: Vec<Vec<Vec<[f32; 4]>>>,
}

/// The GPU texture array of a scene.
pub struct MaterialTextures {
    ctx: Arc<Context>,
    image: Option<GpuImage>,
    data: TextureLayers,
    uploaded: Cell<bool>,
}

impl MaterialTextures {
    pub fn new(ctx: &Arc<Context>, textures: &[Texture]) -> Result<Self> {
        let data = TextureLayers::new(textures);
        let usage = vk::ImageUsageFlags::SAMPLED | vk::ImageUsageFlags::TRANSFER_DST;
        let image = ctx.create_image("material_textures", &data.desc(), usage)?;
        Ok(MaterialTextures { ctx: ctx.clone(), image: Some(image), data, uploaded: Cell::new(false) })
    }

    pub fn layer_count(&self) -> u32 {
        self.data.layer_count()
    }

    /// Imports the array into `graph`; the first time, also declares the `textures_upload` pass.
    pub fn add(&self, graph: &mut Graph) -> ImageHandle {
        let img = self.image.as_ref().expect("image lives until drop");
        let first = !self.uploaded.replace(true);
        let imported = ImportedImage {
            image: img.image,
            view: img.view,
            desc: img.desc.clone(),
            usage: img.usage,
            initial: None,
            initial_layout: if first { vk::ImageLayout::UNDEFINED } else { vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL },
            // After the upload, leave it visible to sampled reads in every stage of later frames.
            final_access: first.then_some(Access::AnyShaderReadSampled),
        };
        let h = graph.import_image("material_textures", imported);
        if first {
            self.data.add_upload(graph, h)
        } else {
            h
        }
    }

    /// The upload must be declared again (the frame that declared it was not submitted).
    pub fn invalidate_upload(&self) {
        self.uploaded.set(false);
    }
}

impl Drop for MaterialTextures {
    fn drop(&mut self) {
        if let Some(i) = self.image.take() {
            self.ctx.destroy_image(i);
        }
    }
}

fn mip_chain(base: Vec<[f32; 4]>, size: u32) -> Vec<Vec<[f32; 4]>> {
    let mut mips = vec![base];
    let mut s = size;
    while s > 1 {
        let prev = mips.last().unwrap();
        let n = s / 2;
        let mut next = vec![[0f32; 4]; (n * n) as usize];
        for y in 0..n {
            for x in 0..n {
                let mut acc = [0f32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let t = prev[((2 * y + dy) * s + 2 * x + dx) as usize];
                    for c in 0..4 {
                        acc[c] += 0.25 * t[c];
                    }
                }
                next[(y * n + x) as usize] = acc;
            }
        }
        mips.push(next);
        s = n;
    }
    mips
}

impl TextureLayers {
    pub fn new(textures: &[Texture]) -> Self {
        let n = LAYER_SIZE;
        let mut layers: Vec<Vec<Vec<[f32; 4]>>> = textures
            .iter()
            .map(|t| {
                let base = (0..n * n)
                    .map(|i| {
                        let uv = Vec2::new(((i % n) as f32 + 0.5) / n as f32, ((i / n) as f32 + 0.5) / n as f32);
                        let v = t.sample(uv).to_array();
                        // Texture data is validated by the scene loader; keep NaN out of the GPU anyway.
                        v.map(|c| if c.is_finite() { c } else { 0.0 })
                    })
                    .collect();
                mip_chain(base, n)
            })
            .collect();
        if layers.is_empty() {
            // No textures: one white layer so the descriptor is always valid.
            layers.push(mip_chain(vec![[1.0; 4]; (n * n) as usize], n));
        }
        TextureLayers { layers }
    }

    /// The mip chain of layer `i` (largest first, `size^2` RGBA texels each); empty outside.
    pub fn mips(&self, i: usize) -> &[Vec<[f32; 4]>] {
        self.layers.get(i).map_or(&[], |m| m.as_slice())
    }

    pub fn layer_count(&self) -> u32 {
        self.layers.len() as u32
    }

    pub fn desc(&self) -> ImageDesc {
        let mips = self.layers[0].len() as u32;
        ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, LAYER_SIZE, LAYER_SIZE)
            .with_layers(self.layer_count())
            .with_mips(mips)
    }

    /// Declares the `textures_upload` pass writing every layer and mip into `img`.
    fn add_upload(&self, graph: &mut Graph, img: ImageHandle) -> ImageHandle {
        let bytes: Vec<Vec<Vec<u8>>> =
            self.layers.iter().map(|mips| mips.iter().map(|texels| bytes_of(texels)).collect()).collect();
        let parts = bytes.iter().enumerate().flat_map(|(layer, mips)| {
            mips.iter().enumerate().map(move |(level, bytes)| {
                let s = (LAYER_SIZE >> level).max(1);
                crate::util::Subresource { mip: level as u32, layer: layer as u32, width: s, height: s, bytes }
            })
        });
        crate::util::add_image_upload(graph, "textures", img, parts)
    }
}

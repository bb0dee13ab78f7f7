//! Tone mapping (`glsl/frame/tonemap.comp`): exposure, ACES filmic fit, sRGB encoding into RGBA8.
//! NaN/Inf radiance shows as magenta instead of passing silently.

use crate::util::{compute_pipeline, groups, Pipeline, Sampler};
use anyhow::Result;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Graph, ImageHandle, PassKind};
use std::sync::Arc;

/// The output format: 8-bit UNORM holding sRGB-encoded values.
pub const LDR_FORMAT: vk::Format = vk::Format::R8G8B8A8_UNORM;

/// Tone-mapping parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TonemapParams {
    /// Linear scale applied before the curve. Default 1.
    pub exposure: f32,
}

impl Default for TonemapParams {
    fn default() -> Self {
        TonemapParams { exposure: 1.0 }
    }
}

pub struct TonemapPass {
    pipeline: Pipeline,
    nearest: Sampler,
}

impl TonemapPass {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let pipeline = compute_pipeline(ctx, shaders, "frame/tonemap.comp", 4)?;
        Ok(TonemapPass { pipeline, nearest: Sampler::nearest(ctx)? })
    }

    /// Adds the `tonemap` pass writing into `target` (an imported image with STORAGE usage) or a
    /// new transient `ldr` image. Returns the written handle.
    pub fn add(
        &self,
        graph: &mut Graph,
        hdr: ImageHandle,
        target: Option<ImageHandle>,
        params: TonemapParams,
    ) -> ImageHandle {
        let d = graph.image_desc(hdr).clone();
        let ldr = target.unwrap_or_else(|| graph.create_image("ldr", ImageDesc::new_2d(LDR_FORMAT, d.width, d.height)));
        let (w, h) = (d.width, d.height);
        let mut p = graph.pass("tonemap", PassKind::Compute);
        let hdr = p.read(hdr, Access::ComputeShaderReadSampled);
        let ldr = p.write(ldr, Access::ComputeShaderWriteStorage);
        let (pipe, nearest) = (self.pipeline.handle(), self.nearest.sampler);
        p.record(move |rc| {
            let binds = [Bind::SampledImage(hdr, nearest), Bind::StorageImage(ldr)];
            crate::util::dispatch(rc, pipe, &binds, &params.exposure.to_le_bytes(), [groups(w, 8), groups(h, 8), 1])
        });
        ldr
    }
}

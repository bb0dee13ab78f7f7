//! A heads-up overlay over the tone-mapped image (`penumbra view`'s H key): lines of text drawn
//! on the CPU with the 8x8 bitmap font of the `font8x8` crate (public-domain glyphs, MIT crate)
//! into RGBA8 texels ([`Overlay::text`]), composited by `glsl/frame/hud.comp` in a `hud` pass
//! that reads and writes the LDR image. A frame without an overlay has no such pass.

use crate::util::{compute_pipeline, groups, Pipeline};
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, Context, Graph, ImageHandle, PassKind};
use std::sync::Arc;

/// Texels to overlay, RGBA8 packed little-endian (`r | g << 8 | b << 16 | a << 24`, straight
/// alpha), row-major from the top-left, placed at `origin` in the image.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overlay {
    pub width: u32,
    pub height: u32,
    pub origin: [u32; 2],
    pub texels: Vec<u32>,
}

const INK: u32 = 0xff_ff_ff_ff;
/// The box behind the text: black at 60 % opacity.
const BOX: u32 = 0x99_00_00_00;

impl Overlay {
    /// `lines` in white on a translucent black box at the top-left corner (a margin of one
    /// glyph cell), each glyph 8x8 texels enlarged `scale` times (at least 1). Characters
    /// outside ASCII show as `?`.
    pub fn text(lines: &[String], scale: u32) -> Overlay {
        let scale = scale.max(1);
        let cell = 8 * scale;
        let pad = 2 * scale;
        let cols = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) as u32;
        let (width, height) = (cols * cell + 2 * pad, lines.len() as u32 * (cell + scale) + 2 * pad);
        let mut texels = vec![BOX; (width * height) as usize];
        for (row, line) in lines.iter().enumerate() {
            let top = pad + row as u32 * (cell + scale);
            for (col, ch) in line.chars().enumerate() {
                let code = if ch.is_ascii() && !ch.is_ascii_control() { ch as usize } else { '?' as usize };
                let glyph = font8x8::legacy::BASIC_LEGACY[code];
                let left = pad + col as u32 * cell;
                for (gy, bits) in glyph.iter().enumerate() {
                    for gx in 0..8u32 {
                        if bits >> gx & 1 == 0 {
                            continue;
                        }
                        for sy in 0..scale {
                            let y = top + gy as u32 * scale + sy;
                            let x0 = left + gx * scale;
                            let at = (y * width + x0) as usize;
                            texels[at..at + scale as usize].fill(INK);
                        }
                    }
                }
            }
        }
        Overlay { width, height, origin: [scale * 8, scale * 8], texels }
    }

    /// Whether the texel at (x, y) of the overlay is ink (tests).
    pub fn ink_at(&self, x: u32, y: u32) -> bool {
        x < self.width && y < self.height && self.texels[(y * self.width + x) as usize] == INK
    }
}

/// The `hud` pass.
pub struct HudPass {
    pipeline: Pipeline,
}

impl HudPass {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let pipeline = compute_pipeline(ctx, shaders, "frame/hud.comp", 16)?;
        Ok(HudPass { pipeline })
    }

    /// Blends `overlay` over `ldr` (an RGBA8 storage image) in place; returns the new version.
    pub fn add(&self, graph: &mut Graph, ldr: ImageHandle, overlay: &Overlay) -> ImageHandle {
        let bytes: Vec<u8> = overlay.texels.iter().flat_map(|t| t.to_le_bytes()).collect();
        let texels = graph.create_buffer_init("hud.texels", bytes);
        let mut p = graph.pass("hud", PassKind::Compute);
        let texels = p.read(texels, Access::ComputeShaderReadStorage);
        let ldr = p.write(ldr, Access::ComputeShaderReadWriteStorage);
        let pipe = self.pipeline.handle();
        let (w, h) = (overlay.width, overlay.height);
        let push: Vec<u8> = [w, h, overlay.origin[0], overlay.origin[1]].iter().flat_map(|v| v.to_le_bytes()).collect();
        p.record(move |rc| {
            let binds = [Bind::StorageImage(ldr), Bind::StorageBuffer(texels)];
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
        });
        ldr
    }
}

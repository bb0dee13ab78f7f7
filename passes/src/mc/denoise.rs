//! Technique `mc-denoised`: the baseline a user would pick today, as the vv paper compares
//! against (Monte Carlo with a denoiser, its Figures 16-18): a few samples per pixel of `mc` per
//! frame (through the pixel centres, where the G-buffer is rasterized), then spatio-temporal
//! variance-guided filtering (SVGF, Schied et al. 2017), all as passes of the frame's graph:
//!
//! 1. `mc`: [`McTechnique`] with `progressive = false` (each frame's image holds its own samples).
//! 2. `mcd_temporal` (`glsl/mc/mcd_temporal.comp`): the radiance divided by the surface's
//!    reflectance (diffuse albedo plus specular colour of the textured material, so texture detail
//!    is not blurred), blended into the history found through the G-buffer's motion vector
//!    (rejected where the previous pixel showed another instance or another distance:
//!    disocclusion), weight 1 / length with the length capped at `history`; luminance moments give
//!    each pixel's variance (spatial over 3x3 while the history is shorter than 4 frames). The
//!    history (two pairs of persistent images, ping-ponged) keeps the unfiltered accumulation.
//! 3. `mcd_atrous.<k>` (`glsl/mc/mcd_atrous.comp`), `iterations` times (fewer on small images:
//!    [`filter_iterations`]) with taps 1, 2, 4, ... pixels apart: edge-aware a-trous wavelet
//!    filtering stopped by normals, distance from the tangent plane and luminance against the
//!    filtered variance, never across faces whose geometric normals differ by more than about
//!    25 degrees (the material model's face rule makes the radiance jump there); the last
//!    multiplies the reflectance back.
//!
//! Biased by design (blur across soft shadow gradients, ghosting where history is reused under
//! changing light): the accuracy matrix measures it against the reference like every technique.

use super::McTechnique;
use crate::shade_env::HDR_FORMAT;
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::Result;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_scene::Scene;
use std::sync::Arc;

/// Parameters of `mc-denoised` (`[technique_params]` / `--param`).
#[derive(Clone, Debug, PartialEq)]
pub struct DenoiseSettings {
    /// Samples per pixel per frame (default 4).
    pub spp: u32,
    /// A-trous iterations (taps 1, 2, 4, ... pixels apart; default 4).
    pub iterations: u32,
    /// Longest history in frames (default 5: SVGF's blend weight alpha = 0.2; a longer history
    /// converges further where nothing moves but drags moving shadows: falling at 96x72, frame
    /// 30, 0.301 rmse/mean with 32 against 0.196 with 5).
    pub history: u32,
    /// Luminance edge-stopping: differences against `phi_color` standard deviations (default 4).
    pub phi_color: f32,
    /// Normal edge-stopping exponent (default 128).
    pub phi_normal: f32,
    /// Plane-distance edge-stopping, in pixel footprints per tap spacing (default 1).
    pub phi_plane: f32,
    /// Specular-lobe edge-stopping on glossy pixels: taps weighted by how far their mirror
    /// direction falls inside the pixel's specular lobe, times this (default 4: isg_bunny at
    /// 160x120 0.540 -> 0.286 rmse/mean with 1 -> 0.360, 16 -> 0.276; 0: off).
    pub phi_lobe: f32,
    /// History clipped to this frame's 3x3 neighbourhood, mean +- `clip` standard deviations
    /// per channel (Salvi 2016's variance clipping; default 1, 0: off): lighting that changes
    /// without a motion vector (a shadow moving over a still floor, a turning environment) leaves
    /// the history instead of ghosting. At 160x120 after five frames: turning_light 0.511 ->
    /// 0.244 rmse/mean, falling 0.148 -> 0.092; still views pay a little noise (chess 0.085 ->
    /// 0.092, trace_test 0.038 -> 0.044).
    pub clip: f32,
}

impl Default for DenoiseSettings {
    fn default() -> Self {
        DenoiseSettings {
            spp: 4,
            iterations: 4,
            history: 5,
            phi_color: 4.0,
            phi_normal: 128.0,
            phi_plane: 1.0,
            phi_lobe: 4.0,
            clip: 1.0,
        }
    }
}

impl DenoiseSettings {
    /// Sets one `[technique_params]` entry; any other key is an error.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("mc-denoised", key, value);
        let int = |lo: u64, hi: u64| p.int(lo, hi).map(|n| n as u32);
        let positive = || p.number(|x| x > 0.0, "a finite number > 0").map(|x| x as f32);
        match p.key() {
            "spp" => self.spp = int(1, 64)?,
            "iterations" => self.iterations = int(1, 8)?,
            "history" => self.history = int(1, 1024)?,
            "phi_color" => self.phi_color = positive()?,
            "phi_normal" => self.phi_normal = positive()?,
            "phi_plane" => self.phi_plane = positive()?,
            "phi_lobe" => self.phi_lobe = p.number(|x| x >= 0.0, "a finite number >= 0")? as f32,
            "clip" => self.clip = p.number(|x| x >= 0.0, "a finite number >= 0")? as f32,
            _ => return Err(p.unknown("spp, iterations, history, phi_color, phi_normal, phi_plane, phi_lobe, clip")),
        }
        Ok(())
    }
}

/// The a-trous iterations run at image height `height`: at most `asked`, and no more than keep
/// the filter's reach (2 (2^k - 1) pixels after k iterations of a 5x5 kernel) within an eighth
/// of the image height (at least one): SVGF's five iterations are made for 720p, and at the
/// matrix's 40x30 four of them would average over the whole image. 240 and 480 rows allow 4, 1000 rows 5.
pub fn filter_iterations(asked: u32, height: u32) -> u32 {
    let reach = |k: u32| 2 * ((1u32 << k) - 1);
    let mut n = 1;
    while n < asked.max(1) && reach(n + 1) * 8 <= height {
        n += 1;
    }
    n
}

/// Technique `mc-denoised`.
pub struct McDenoised {
    mc: McTechnique,
    temporal: Pipeline,
    atrous: Pipeline,
    nearest: Sampler,
    pub settings: DenoiseSettings,
    /// Frames declared so far: picks the history pair read (even: pair 0) and written.
    frames: u64,
}

impl McDenoised {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, settings: DenoiseSettings) -> Result<Self> {
        let temporal = compute_pipeline(ctx, shaders, "mc/mcd_temporal.comp", 32)?;
        let atrous = compute_pipeline(ctx, shaders, "mc/mcd_atrous.comp", 48)?;
        let mut mc = McTechnique::new(ctx, shaders, scene)?;
        mc.spp = settings.spp;
        mc.aa = false;
        mc.progressive = false;
        Ok(McDenoised { mc, temporal, atrous, nearest: Sampler::nearest(ctx)?, settings, frames: 0 })
    }
}

impl crate::technique::Technique for McDenoised {
    fn name(&self) -> &'static str {
        "mc-denoised"
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        let gb = inputs.gbuffer;
        let (w, h) = (gb.width, gb.height);
        let frame = inputs.frame;
        self.mc.spp = self.settings.spp;
        self.mc.scene_textures = Some(inputs.handles.textures);
        let noisy = self.mc.add_frame(engine, graph, frame, w, h);
        self.mc.scene_textures = None;
        let (noisy, materials) = noisy?;
        let textures = inputs.handles.textures;
        let desc = ImageDesc::new_2d(HDR_FORMAT, w, h);
        let read = (self.frames % 2) as usize;
        let pair = |engine: &mut FrameStore<'_>, graph: &mut Graph, k: usize| {
            (
                engine.persistent_image(graph, &format!("mcd.color.{k}"), desc.clone()),
                engine.persistent_image(graph, &format!("mcd.aux.{k}"), desc.clone()),
            )
        };
        let (prev_color, prev_aux) = pair(engine, graph, read);
        let (new_color, new_aux) = pair(engine, graph, 1 - read);
        let valid = self.frames > 0 && !graph.persistent_is_new(prev_color) && !graph.persistent_is_new(prev_aux);
        self.frames += 1;
        let eye = frame.camera.eye;
        let filter_in = graph.create_image("mcd.filter_in", desc.clone());
        let mut push = bytes_of(&[eye.x, eye.y, eye.z, if valid { 1.0 } else { 0.0 }]);
        push.extend(bytes_of(&[w, h, self.settings.history, self.settings.clip.to_bits()]));
        let nearest = self.nearest.sampler;
        let repeat = self.mc.repeat.sampler;
        let mut filter_in = {
            let mut p = graph.pass("mcd_temporal", PassKind::Compute);
            let nz = p.read(noisy, Access::ComputeShaderReadStorage);
            let [pos, uvm, mo] =
                [gb.position, gb.uv_mat, gb.motion].map(|h| p.read(h, Access::ComputeShaderReadSampled));
            let pc = p.read(prev_color, Access::ComputeShaderReadStorage);
            let pa = p.read(prev_aux, Access::ComputeShaderReadStorage);
            let [nc, na, fi] = [new_color, new_aux, filter_in].map(|h| p.write(h, Access::ComputeShaderWriteStorage));
            let mats = p.read(materials, Access::ComputeShaderReadStorage);
            let tex = p.read(textures, Access::ComputeShaderReadSampled);
            let pipe = self.temporal.handle();
            p.record(move |rc| {
                let binds = [
                    Bind::StorageImage(nz),
                    Bind::SampledImage(pos, nearest),
                    Bind::SampledImage(uvm, nearest),
                    Bind::SampledImage(mo, nearest),
                    Bind::StorageImage(pc),
                    Bind::StorageImage(pa),
                    Bind::StorageImage(nc),
                    Bind::StorageImage(na),
                    Bind::StorageImage(fi),
                    Bind::StorageBuffer(mats),
                    Bind::SampledImage(tex, repeat),
                ];
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            fi
        };
        let pixel = 2.0 * (0.5 * frame.camera.fov_y_deg.to_radians()).tan() / h.max(1) as f32;
        let n = filter_iterations(self.settings.iterations, h);
        for k in 0..n {
            let last = k + 1 == n;
            let name = if last { "mcd.hdr".to_string() } else { format!("mcd.atrous.{k}") };
            let dst = graph.create_image(&name, desc.clone());
            let mut push = bytes_of(&[eye.x, eye.y, eye.z, pixel]);
            push.extend(bytes_of(&[1u32 << k, w, h, last as u32]));
            push.extend(bytes_of(&[
                self.settings.phi_color,
                self.settings.phi_normal,
                self.settings.phi_plane,
                self.settings.phi_lobe,
            ]));
            let mut p = graph.pass(&format!("mcd_atrous.{k}"), PassKind::Compute);
            let src = p.read(filter_in, Access::ComputeShaderReadStorage);
            let out = p.write(dst, Access::ComputeShaderWriteStorage);
            let [pos, nrm, uvm] =
                [gb.position, gb.normal, gb.uv_mat].map(|h| p.read(h, Access::ComputeShaderReadSampled));
            let nz = p.read(noisy, Access::ComputeShaderReadStorage);
            let mats = p.read(materials, Access::ComputeShaderReadStorage);
            let tex = p.read(textures, Access::ComputeShaderReadSampled);
            let pipe = self.atrous.handle();
            p.record(move |rc| {
                let binds = [
                    Bind::StorageImage(src),
                    Bind::StorageImage(out),
                    Bind::SampledImage(pos, nearest),
                    Bind::SampledImage(nrm, nearest),
                    Bind::SampledImage(uvm, nearest),
                    Bind::StorageImage(nz),
                    Bind::StorageBuffer(mats),
                    Bind::SampledImage(tex, repeat),
                ];
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            filter_in = out;
        }
        Ok(filter_in)
    }
}

#[cfg(test)]
mod tests {
    use super::filter_iterations;

    #[test]
    fn the_filter_reaches_at_most_an_eighth_of_the_image() {
        assert_eq!(filter_iterations(4, 30), 1);
        assert_eq!(filter_iterations(4, 120), 3);
        assert_eq!(filter_iterations(4, 240), 4);
        assert_eq!(filter_iterations(8, 480), 4);
        assert_eq!(filter_iterations(8, 1000), 5);
        assert_eq!(filter_iterations(2, 2160), 2);
        assert_eq!(filter_iterations(0, 8), 1);
    }
}

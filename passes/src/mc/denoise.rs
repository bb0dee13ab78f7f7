//! Technique `mc-denoised`: the baseline a user would pick today, as the vv paper compares
//! against (Monte Carlo with a denoiser, its Figures 16-18): a few samples per pixel of `mc` per
//! frame (through the pixel centres, where the G-buffer is rasterized), then spatio-temporal
//! variance-guided filtering (SVGF, Schied et al. 2017) of a ratio estimator (Heitz, Hill and
//! McGuire 2018, "Combining analytic direct illumination and stochastic shadows"), all as passes
//! of the frame's graph:
//!
//! 1. `mc`: [`McTechnique`] with `progressive = false` (each frame's image holds its own
//!    samples) and `unshadowed` (beside the radiance S, the same samples' estimate U with every
//!    shadow ray taken as unoccluded, and the variance of the visible fraction S / U from the
//!    frame's own samples: zero where all of them agreed). `shade_env`: the analytic unshadowed
//!    radiance A (the `env` technique's image, noise-free).
//! 2. `mcd_temporal` (`glsl/mc/mcd_temporal.comp`): S and U divided by the surface's reflectance
//!    (diffuse albedo plus specular colour of the textured material, so texture detail is not
//!    blurred), each blended into its history found through the G-buffer's motion vector
//!    (rejected where the previous pixel showed another instance or another distance:
//!    disocclusion) and clipped to the frame's neighbourhood, weight 1 / length with the length
//!    capped at `history`; each pixel's variance is mc's own of the visible fraction, averaged
//!    over the history as the radiance is (a moving shadow is not noise, as the visible
//!    fraction's temporal moments would take it), times 4 / length while the history is
//!    shorter than 4 frames. A history whose visible fraction this frame's samples contradict
//!    (by more than half and six standard deviations, with the unshadowed estimate steady or two
//!    neighbours agreeing with the frame: a shadow that moved over a floor whose motion vector
//!    is zero, not a sample far out in U's tail) restarts: variance
//!    clipping keeps a hard edge's history, whose neighbourhood spans lit and shadowed. The
//!    history (three pairs of persistent images, ping-ponged) keeps the unfiltered
//!    accumulations.
//! 3. `mcd_atrous.<k>` (`glsl/mc/mcd_atrous.comp`), `iterations` times (fewer on small images:
//!    [`filter_iterations`]) with taps 1, 2, 4, ... pixels apart: edge-aware a-trous wavelet
//!    filtering of S and U with the same weights, stopped by normals, distance from the tangent
//!    plane and the visible fraction against its filtered variance, never across faces whose
//!    geometric normals differ by more than about 25 degrees (the material model's face rule
//!    makes the radiance jump there); the last writes A x S / U. Where no shadow ray was blocked
//!    S and U are the same sums and the output is A exactly: highlights and textures come
//!    noise-free from the analytic term, and what is filtered is only the shadows' noise.
//!
//! `ratio = false` is SVGF as published: the demodulated radiance filtered (luminance moments,
//! the 3x3 spatial variance for short histories) and the reflectance multiplied back.
//!
//! Biased by design (blur across soft shadow gradients, ghosting where history is reused under
//! changing light, A's own approximation of the unshadowed glossy term): the accuracy matrix
//! measures it against the reference like every technique.

use super::{McFrame, McTechnique};
use crate::shade_env::{ShadeEnvPass, HDR_FORMAT};
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
    /// Luminance edge-stopping: differences against `phi_color` standard deviations (default 1;
    /// with the ratio estimator the compared value is the visible fraction, and 1 against 2 and
    /// 4 keeps hard shadows' edges: god_rays at 160x120 0.057 / 0.076 / 0.091 rmse/mean, at
    /// 40x30 22 / 22 / 19 of 24 cells pass, measured before contradicted histories restarted;
    /// SVGF's demodulated radiance, `ratio = false`, was
    /// tuned at 4).
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
    /// Ratio estimator (Heitz et al. 2018, "Combining analytic direct illumination and
    /// stochastic shadows"; default true): mc writes beside its shadowed estimate the same
    /// samples' unshadowed one, both are accumulated and filtered alike, and the output is the
    /// analytic unshadowed radiance (`shade_env`, the `env` technique's) times their ratio. The
    /// shading's detail (highlights, textures) comes noise-free from the analytic term and the
    /// noise cancels where nothing is shadowed; false: SVGF's demodulated radiance, filtered.
    pub ratio: bool,
    /// With the ratio estimator: a history whose visible fraction this frame's samples
    /// contradict (by more than half and six standard deviations, the unshadowed estimate within
    /// 25 % of its history's or two neighbours agreeing with the frame) restarts (default true):
    /// a hard shadow moving over a still floor, whose history variance clipping keeps (its
    /// neighbourhood spans lit and shadowed). god_rays at 160x120: 0.053 -> 0.009 rmse/mean after
    /// two frames, 0.095 -> 0.009 after five; at 40x30 0.155 -> 0.025.
    pub restart: bool,
}

impl Default for DenoiseSettings {
    fn default() -> Self {
        DenoiseSettings {
            spp: 4,
            iterations: 4,
            history: 5,
            phi_color: 1.0,
            phi_normal: 128.0,
            phi_plane: 1.0,
            phi_lobe: 4.0,
            clip: 1.0,
            ratio: true,
            restart: true,
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
            "ratio" => self.ratio = p.flag()?,
            "restart" => self.restart = p.flag()?,
            _ => {
                return Err(p.unknown(
                    "spp, iterations, history, phi_color, phi_normal, phi_plane, phi_lobe, clip, ratio, restart",
                ))
            }
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
    /// The analytic unshadowed radiance of the ratio estimator.
    shade_env: ShadeEnvPass,
    nearest: Sampler,
    pub settings: DenoiseSettings,
    /// Frames declared so far: picks the history pair read (even: pair 0) and written.
    frames: u64,
}

impl McDenoised {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, settings: DenoiseSettings) -> Result<Self> {
        let temporal = compute_pipeline(ctx, shaders, "mc/mcd_temporal.comp", 48)?;
        let atrous = compute_pipeline(ctx, shaders, "mc/mcd_atrous.comp", 64)?;
        let mut mc = McTechnique::new(ctx, shaders, scene)?;
        mc.spp = settings.spp;
        mc.aa = false;
        mc.progressive = false;
        Ok(McDenoised {
            mc,
            temporal,
            atrous,
            shade_env: ShadeEnvPass::new(ctx, shaders)?,
            nearest: Sampler::nearest(ctx)?,
            settings,
            frames: 0,
        })
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
        let ratio = self.settings.ratio;
        self.mc.unshadowed = ratio;
        self.mc.scene_textures = Some(inputs.handles.textures);
        let noisy = self.mc.add_frame(engine, graph, frame, w, h);
        self.mc.scene_textures = None;
        let McFrame { hdr: noisy, materials, unshadowed } = noisy?;
        let textures = inputs.handles.textures;
        let desc = ImageDesc::new_2d(HDR_FORMAT, w, h);
        // the ratio estimator's images: the unshadowed estimate, its history pair and filter
        // input, the analytic unshadowed radiance; without it 1 x 1 stand-ins the shaders leave
        // alone
        let udesc = if ratio { desc.clone() } else { ImageDesc::new_2d(HDR_FORMAT, 1, 1) };
        let (noisy_u, analytic) = match unshadowed {
            Some(u) => (u, self.shade_env.add(graph, inputs.handles, gb, inputs.env)),
            None => {
                // read, never written: a persistent image (a transient one must be written first)
                let stand_in = engine.persistent_image(graph, "mcd.stand_in", udesc.clone());
                (stand_in, stand_in)
            }
        };
        let read = (self.frames % 2) as usize;
        let pair = |engine: &mut FrameStore<'_>, graph: &mut Graph, k: usize| {
            (
                engine.persistent_image(graph, &format!("mcd.color.{k}"), desc.clone()),
                engine.persistent_image(graph, &format!("mcd.aux.{k}"), desc.clone()),
            )
        };
        let (prev_color, prev_aux) = pair(engine, graph, read);
        let (new_color, new_aux) = pair(engine, graph, 1 - read);
        let prev_u = engine.persistent_image(graph, &format!("mcd.unshadowed.{read}"), udesc.clone());
        let new_u = engine.persistent_image(graph, &format!("mcd.unshadowed.{}", 1 - read), udesc.clone());
        let valid = self.frames > 0
            && !graph.persistent_is_new(prev_color)
            && !graph.persistent_is_new(prev_aux)
            && !graph.persistent_is_new(prev_u);
        self.frames += 1;
        let eye = frame.camera.eye;
        let filter_in = graph.create_image("mcd.filter_in", desc.clone());
        let filter_u = graph.create_image("mcd.filter_u", udesc.clone());
        let mut push = bytes_of(&[eye.x, eye.y, eye.z, if valid { 1.0 } else { 0.0 }]);
        push.extend(bytes_of(&[w, h, self.settings.history, self.settings.clip.to_bits()]));
        push.extend(bytes_of(&[ratio as u32, (ratio && self.settings.restart) as u32, 0, 0]));
        let nearest = self.nearest.sampler;
        let repeat = self.mc.repeat.sampler;
        let (mut filter_in, mut filter_u) = {
            let mut p = graph.pass("mcd_temporal", PassKind::Compute);
            let nz = p.read(noisy, Access::ComputeShaderReadStorage);
            let [pos, uvm, mo] =
                [gb.position, gb.uv_mat, gb.motion].map(|h| p.read(h, Access::ComputeShaderReadSampled));
            let pc = p.read(prev_color, Access::ComputeShaderReadStorage);
            let pa = p.read(prev_aux, Access::ComputeShaderReadStorage);
            let [nc, na, fi] = [new_color, new_aux, filter_in].map(|h| p.write(h, Access::ComputeShaderWriteStorage));
            let mats = p.read(materials, Access::ComputeShaderReadStorage);
            let tex = p.read(textures, Access::ComputeShaderReadSampled);
            let [nu, pu] = [noisy_u, prev_u].map(|h| p.read(h, Access::ComputeShaderReadStorage));
            let [nwu, fu] = [new_u, filter_u].map(|h| p.write(h, Access::ComputeShaderWriteStorage));
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
                    Bind::StorageImage(nu),
                    Bind::StorageImage(pu),
                    Bind::StorageImage(nwu),
                    Bind::StorageImage(fu),
                ];
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            (fi, fu)
        };
        let pixel = 2.0 * (0.5 * frame.camera.fov_y_deg.to_radians()).tan() / h.max(1) as f32;
        let n = filter_iterations(self.settings.iterations, h);
        for k in 0..n {
            let last = k + 1 == n;
            let name = if last { "mcd.hdr".to_string() } else { format!("mcd.atrous.{k}") };
            let dst = graph.create_image(&name, desc.clone());
            // the last iteration writes no unshadowed image: a stand-in
            let dst_u = graph.create_image(
                &format!("mcd.atrous_u.{k}"),
                if last { ImageDesc::new_2d(HDR_FORMAT, 1, 1) } else { udesc.clone() },
            );
            let mut push = bytes_of(&[eye.x, eye.y, eye.z, pixel]);
            push.extend(bytes_of(&[1u32 << k, w, h, last as u32]));
            push.extend(bytes_of(&[
                self.settings.phi_color,
                self.settings.phi_normal,
                self.settings.phi_plane,
                self.settings.phi_lobe,
            ]));
            push.extend(bytes_of(&[ratio as u32, 0, 0, 0]));
            let mut p = graph.pass(&format!("mcd_atrous.{k}"), PassKind::Compute);
            let src = p.read(filter_in, Access::ComputeShaderReadStorage);
            let out = p.write(dst, Access::ComputeShaderWriteStorage);
            let [pos, nrm, uvm] =
                [gb.position, gb.normal, gb.uv_mat].map(|h| p.read(h, Access::ComputeShaderReadSampled));
            let nz = p.read(noisy, Access::ComputeShaderReadStorage);
            let mats = p.read(materials, Access::ComputeShaderReadStorage);
            let tex = p.read(textures, Access::ComputeShaderReadSampled);
            let [su, an] = [filter_u, analytic].map(|h| p.read(h, Access::ComputeShaderReadStorage));
            let du = p.write(dst_u, Access::ComputeShaderWriteStorage);
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
                    Bind::StorageImage(su),
                    Bind::StorageImage(du),
                    Bind::StorageImage(an),
                ];
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            filter_in = out;
            filter_u = du;
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

//! `penumbra bench volumetric SCENE`: the temporal technique and the full baseline on the same
//! frames, each on its own engine (same device), with per-pass GPU times, the per-frame speedup
//! of the volumetric passes, the masked-pixel fraction, the difference between the two final
//! images, and missed pixels (scattering changed in the full result since the previous frame,
//! but the temporal frame reused the pixel: not marched, outside the stencil mask).

use super::{MarchMode, VolumetricEffect, VolumetricMethod, VolumetricParams};
use crate::effect::{Effect, EffectInputs};
use crate::env::EnvMapGpu;
use crate::scene_gpu::FrameConstants;
use crate::technique::Technique;
use crate::{GBufferPass, SceneGpu};
use anyhow::{bail, Result};
use glam::Mat4;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Context, Engine, FrameOutput, Graph};
use penumbra_scene::Scene;
use std::sync::Arc;

/// Options of [`bench_volumetric`].
#[derive(Clone, Debug)]
pub struct VolBenchOptions {
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub fps: f32,
    /// Time of the first frame in seconds.
    pub start_time: f32,
    /// The temporal method's refresh period: the thesis's reused frame number + 1 (default 4).
    pub reuse_frames: u32,
    /// Samples per view ray (both methods).
    pub samples: u32,
    /// Both methods use Wyman and Ramsey's hybrid (shadow-volume intervals, airlight lit segments; default true).
    pub hybrid: bool,
    /// Testing only: the temporal method skips its masked march (negative control).
    #[doc(hidden)]
    pub debug_skip_mask: bool,
}

impl Default for VolBenchOptions {
    fn default() -> Self {
        VolBenchOptions {
            width: 320,
            height: 240,
            frames: 12,
            fps: 30.0,
            start_time: 0.0,
            reuse_frames: 4,
            samples: 48,
            hybrid: true,
            debug_skip_mask: false,
        }
    }
}

/// One frame of the benchmark.
#[derive(Clone, Debug)]
pub struct VolBenchFrame {
    pub frame: u32,
    pub time: f32,
    /// What the temporal method did (`full`, `refresh`, `masked`, `skipped`).
    pub temporal_mode: String,
    /// GPU ms per `vol_*` pass.
    pub temporal_ms: Vec<(String, f64)>,
    pub full_ms: Vec<(String, f64)>,
    /// Sums over the `vol_*` passes.
    pub temporal_total_ms: f64,
    pub full_total_ms: f64,
    /// `full_total_ms / temporal_total_ms`.
    pub speedup: f64,
    /// GPU ms of the whole frame (G-buffer, surface technique and volumetric passes), as the
    /// thesis's Table 6.1 times frames.
    pub temporal_frame_ms: f64,
    pub full_frame_ms: f64,
    /// Fraction of pixels the temporal method marched this frame.
    pub marched_fraction: f64,
    /// Final HDR images, temporal vs full.
    pub mean_abs: f64,
    pub max_abs: f64,
    /// PSNR with the full image's peak; `f64::INFINITY` when identical.
    pub psnr: f64,
    pub missed_pixels: u64,
    /// Pixels whose full-method scattering changed since the previous frame.
    pub changed_pixels: u64,
}

/// The whole benchmark.
#[derive(Clone, Debug)]
pub struct VolBenchReport {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub frames: Vec<VolBenchFrame>,
    /// Sum of full ms over sum of temporal ms (all frames, `vol_*` passes).
    pub speedup: f64,
    /// The same over whole frames (surfaces included): Table 6.1's ratio.
    pub frame_speedup: f64,
    /// Mean whole-frame GPU ms per method.
    pub temporal_frame_ms: f64,
    pub full_frame_ms: f64,
    /// Mean GPU ms of the `vol_*` passes per method.
    pub temporal_vol_ms: f64,
    pub full_vol_ms: f64,
    /// Masked frames: median of (temporal `vol_march` ms / full `vol_march` ms) and the mean
    /// marched fraction of those frames (the stencil's work saving: ideally equal).
    pub masked_march_ratio: Option<f64>,
    pub masked_fraction: Option<f64>,
    /// Median GPU ms per `vol_*` pass over the frames that ran it, per method.
    pub temporal_pass_ms: Vec<(String, f64)>,
    pub full_pass_ms: Vec<(String, f64)>,
    /// Mean marched fraction over the frames.
    pub mean_marched_fraction: f64,
    pub missed_pixels: u64,
    pub notes: Vec<String>,
    /// The full method's final HDR image of the last frame (RGBA, row 0 at the top).
    pub last_full_hdr: Vec<[f32; 4]>,
}

impl VolBenchReport {
    /// A plain-text table (one line per frame, then the totals).
    pub fn table(&self) -> String {
        let mut s = format!(
            "volumetric bench '{}' {}x{} (GPU ms; vol: the vol_* passes, frame: every pass)\nframe  mode     vol_temporal  vol_full  speedup  frame_temporal  frame_full  marched  mean_abs  max_abs  psnr_dB  changed  missed\n",
            self.scene, self.width, self.height
        );
        for f in &self.frames {
            s += &format!(
                "{:5}  {:8} {:12.3} {:9.3} {:8.2} {:15.3} {:11.3} {:8.3} {:9.2e} {:8.2e} {:8.1} {:8} {:7}\n",
                f.frame,
                f.temporal_mode,
                f.temporal_total_ms,
                f.full_total_ms,
                f.speedup,
                f.temporal_frame_ms,
                f.full_frame_ms,
                f.marched_fraction,
                f.mean_abs,
                f.max_abs,
                f.psnr,
                f.changed_pixels,
                f.missed_pixels
            );
        }
        s += &format!(
            "overall speedup {:.2}x (vol_* passes), {:.2}x whole frames ({:.3} ms temporal, {:.3} ms full), mean marched fraction {:.3}, missed pixels {}\n",
            self.speedup, self.frame_speedup, self.temporal_frame_ms, self.full_frame_ms, self.mean_marched_fraction, self.missed_pixels
        );
        if let (Some(r), Some(f)) = (self.masked_march_ratio, self.masked_fraction) {
            s += &format!(
                "masked frames: vol_march costs {r:.3} of the full march for a marched fraction of {f:.3} ({:.2}x the fraction)\n",
                r / f.max(1e-9)
            );
        }
        for (label, v) in [("temporal", &self.temporal_pass_ms), ("full", &self.full_pass_ms)] {
            let parts: Vec<String> = v.iter().map(|(n, ms)| format!("{n} {ms:.3}")).collect();
            s += &format!("median ms per pass, {label}: {}\n", parts.join(", "));
        }
        for n in &self.notes {
            s += &format!("note: {n}\n");
        }
        s
    }
}

/// A minimal frame pipeline (G-buffer, technique, volumetric effect) on its own engine.
struct Runner {
    gbuffer: GBufferPass,
    technique: Box<dyn Technique>,
    effect: VolumetricEffect,
    scene_gpu: SceneGpu,
    env: EnvMapGpu,
    engine: Engine,
    prev_vp: Option<Mat4>,
}

struct RunOut {
    hdr: Vec<[f32; 4]>,
    scatter: Vec<[f32; 4]>,
    mode: MarchMode,
    frame_id: u32,
    gpu_ms: Vec<(String, f64)>,
    /// Every pass of the frame.
    frame_ms: f64,
}

fn f32s(bytes: &[u8]) -> Vec<[f32; 4]> {
    bytes
        .chunks_exact(16)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8), f(12)]
        })
        .collect()
}

impl Runner {
    fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, params: VolumetricParams) -> Result<Self> {
        let technique = crate::registry::create(&scene.technique, ctx, shaders, scene, &scene.technique_params)?;
        Ok(Runner {
            gbuffer: GBufferPass::new(ctx, shaders)?,
            technique,
            effect: VolumetricEffect::new(scene, ctx, shaders, params)?,
            scene_gpu: SceneGpu::new(ctx, scene)?,
            env: EnvMapGpu::new(scene.environment.as_ref()),
            engine: Engine::new(ctx.clone(), 1)?,
            prev_vp: None,
        })
    }

    fn frame(&mut self, scene: &Scene, frame: &penumbra_scene::Frame, w: u32, h: u32) -> Result<RunOut> {
        let mut g = Graph::new();
        let mut constants = FrameConstants::new(frame, self.prev_vp, w, h);
        constants.params[2] = self.env.mips.len() as f32;
        self.prev_vp = Some(constants.view_proj());
        self.technique.prepare(&mut self.engine, &crate::technique::PrepareInputs { frame, width: w, height: h })?;
        let mut store = penumbra_engine::FrameStore::new(&mut self.engine);
        let env = self.env.add(&mut store, &mut g);
        let (handles, draws) = self.scene_gpu.add(&mut g, frame, &constants);
        let gb = self.gbuffer.add(&mut g, &handles, draws.clone(), w, h);
        let inputs =
            EffectInputs { scene, frame, handles: &handles, draws: &draws, gbuffer: &gb, env, env_data: &self.env };
        let hdr = self.technique.add(&mut store, &mut g, &inputs)?;
        let out = self.effect.add(&mut store, &mut g, &inputs, hdr)?;
        let info = self.effect.last.expect("effect info");
        let rb = vec![(out, "vol_bench_hdr"), (info.scatter, "vol_bench_scatter")];
        crate::readback::add(&mut g, "bench_readback", &rb);
        let (_, mut done) = self.engine.submit(g)?;
        done.extend(self.engine.drain()?);
        let Some(o): Option<FrameOutput> = done.pop() else { bail!("no frame output") };
        let get = |n: &str| o.readbacks.get(n).cloned().unwrap_or_default();
        Ok(RunOut {
            hdr: f32s(&get("vol_bench_hdr")),
            scatter: f32s(&get("vol_bench_scatter")),
            mode: info.mode,
            frame_id: info.frame_id,
            frame_ms: o.gpu_ms.iter().filter(|(n, _)| n != "bench_readback").map(|x| x.1).sum(),
            gpu_ms: o.gpu_ms.into_iter().filter(|(n, _)| n.starts_with("vol_")).collect(),
        })
    }
}

/// Changed beyond float noise (the march is deterministic per pixel).
fn differs(a: [f32; 4], b: [f32; 4]) -> bool {
    (0..3).any(|c| (a[c] - b[c]).abs() > 1e-4 * a[c].abs().max(b[c].abs()) + 1e-7)
}

/// Runs the temporal method and the full baseline on the same frames of `scene`.
pub fn bench_volumetric(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    opts: &VolBenchOptions,
) -> Result<VolBenchReport> {
    if scene.medium.is_none() {
        bail!("scene '{}' has no [medium]: nothing volumetric to benchmark", scene.name);
    }
    if opts.width == 0 || opts.height == 0 || opts.width > 8192 || opts.height > 8192 || opts.frames == 0 {
        bail!("bench volumetric: bad size {}x{} or frame count {}", opts.width, opts.height, opts.frames);
    }
    if !(opts.fps.is_finite() && opts.fps > 0.0 && opts.start_time.is_finite()) {
        bail!("bench volumetric: fps must be positive and the start time finite");
    }
    let base = VolumetricParams {
        reuse_frames: opts.reuse_frames,
        samples: opts.samples,
        hybrid: opts.hybrid,
        ..Default::default()
    };
    let tp =
        VolumetricParams { method: VolumetricMethod::Temporal, debug_skip_mask: opts.debug_skip_mask, ..base.clone() };
    let mut temporal = Runner::new(ctx, shaders, scene, tp)?;
    let mut full = Runner::new(ctx, shaders, scene, VolumetricParams { method: VolumetricMethod::Full, ..base })?;
    let (w, h) = (opts.width, opts.height);
    // Warm-up (lavapipe compiles each pipeline on first use): two frames through every pass,
    // then the temporal history is forgotten so the measured run starts with a full frame.
    for k in 0..2 {
        let t = opts.start_time + k as f32 / opts.fps;
        let frame = scene.at(t, (k > 0).then_some(opts.start_time));
        temporal.frame(scene, &frame, w, h)?;
        full.frame(scene, &frame, w, h)?;
    }
    temporal.effect.reset();
    let mut frames = Vec::new();
    let mut prev_full: Option<Vec<[f32; 4]>> = None;
    let mut last_full_hdr = Vec::new();
    let mut prev_t = None;
    for k in 0..opts.frames {
        let t = opts.start_time + k as f32 / opts.fps;
        let frame = scene.at(t, prev_t);
        prev_t = Some(t);
        let a = temporal.frame(scene, &frame, w, h)?;
        let b = full.frame(scene, &frame, w, h)?;
        let n = (w * h) as usize;
        if a.hdr.len() != n || b.hdr.len() != n || a.scatter.len() != n || b.scatter.len() != n {
            bail!("bench volumetric: incomplete readbacks");
        }
        let marched = a.scatter.iter().filter(|p| p[3] == a.frame_id as f32).count();
        // Missed: the full scattering changed since the previous frame, the temporal frame kept it.
        let (mut missed, mut changed) = (0u64, 0u64);
        if let Some(pf) = &prev_full {
            for ((bs, ps), ts) in b.scatter.iter().zip(pf).zip(&a.scatter) {
                if differs(*bs, *ps) {
                    changed += 1;
                    if ts[3] != a.frame_id as f32 {
                        missed += 1;
                    }
                }
            }
        }
        let (mut sum, mut max, mut se, mut peak) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for i in 0..n {
            for c in 0..3 {
                let d = (a.hdr[i][c] as f64 - b.hdr[i][c] as f64).abs();
                sum += d;
                se += d * d;
                max = max.max(d);
                peak = peak.max(b.hdr[i][c] as f64);
            }
        }
        let mse = se / (3 * n) as f64;
        let psnr = if mse == 0.0 { f64::INFINITY } else { 10.0 * (peak.max(1e-12).powi(2) / mse).log10() };
        let tt: f64 = a.gpu_ms.iter().map(|x| x.1).sum();
        let ft: f64 = b.gpu_ms.iter().map(|x| x.1).sum();
        frames.push(VolBenchFrame {
            frame: k,
            time: t,
            temporal_mode: format!("{:?}", a.mode).to_lowercase(),
            temporal_ms: a.gpu_ms,
            full_ms: b.gpu_ms,
            temporal_total_ms: tt,
            full_total_ms: ft,
            speedup: if tt > 0.0 { ft / tt } else { f64::INFINITY },
            temporal_frame_ms: a.frame_ms,
            full_frame_ms: b.frame_ms,
            marched_fraction: marched as f64 / n as f64,
            mean_abs: sum / (3 * n) as f64,
            max_abs: max,
            psnr,
            missed_pixels: missed,
            changed_pixels: changed,
        });
        prev_full = Some(b.scatter);
        last_full_hdr = b.hdr;
    }
    let tt: f64 = frames.iter().map(|f| f.temporal_total_ms).sum();
    let ft: f64 = frames.iter().map(|f| f.full_total_ms).sum();
    let medians = |pick: &dyn Fn(&VolBenchFrame) -> &Vec<(String, f64)>| {
        let mut names: Vec<String> = Vec::new();
        for f in &frames {
            for (n, _) in pick(f) {
                if !names.contains(n) {
                    names.push(n.clone());
                }
            }
        }
        names
            .into_iter()
            .map(|n| {
                let mut v: Vec<f64> =
                    frames.iter().flat_map(|f| pick(f).iter().filter(|x| x.0 == n).map(|x| x.1)).collect();
                v.sort_by(|a, b| a.total_cmp(b));
                let m = v[v.len() / 2];
                (n, m)
            })
            .collect::<Vec<_>>()
    };
    let temporal_pass_ms = medians(&|f| &f.temporal_ms);
    let full_pass_ms = medians(&|f| &f.full_ms);
    let mean_marched_fraction = frames.iter().map(|f| f.marched_fraction).sum::<f64>() / frames.len() as f64;
    let n = frames.len() as f64;
    let temporal_frame_ms = frames.iter().map(|f| f.temporal_frame_ms).sum::<f64>() / n;
    let full_frame_ms = frames.iter().map(|f| f.full_frame_ms).sum::<f64>() / n;
    let march = |v: &Vec<(String, f64)>| v.iter().find(|x| x.0 == "vol_march").map(|x| x.1);
    let masked: Vec<&VolBenchFrame> = frames.iter().filter(|f| f.temporal_mode == "masked").collect();
    let mut ratios: Vec<f64> =
        masked.iter().filter_map(|f| Some(march(&f.temporal_ms)? / march(&f.full_ms)?.max(1e-9))).collect();
    ratios.sort_by(|a, b| a.total_cmp(b));
    let masked_march_ratio = (!ratios.is_empty()).then(|| ratios[ratios.len() / 2]);
    let masked_fraction =
        (!masked.is_empty()).then(|| masked.iter().map(|f| f.marched_fraction).sum::<f64>() / masked.len() as f64);
    Ok(VolBenchReport {
        frame_speedup: if temporal_frame_ms > 0.0 { full_frame_ms / temporal_frame_ms } else { f64::INFINITY },
        temporal_frame_ms,
        full_frame_ms,
        temporal_vol_ms: tt / n,
        full_vol_ms: ft / n,
        masked_march_ratio,
        masked_fraction,
        temporal_pass_ms,
        full_pass_ms,
        mean_marched_fraction,
        scene: scene.name.clone(),
        width: w,
        height: h,
        missed_pixels: frames.iter().map(|f| f.missed_pixels).sum(),
        frames,
        speedup: if tt > 0.0 { ft / tt } else { f64::INFINITY },
        notes: temporal.effect.notes.clone(),
        last_full_hdr,
    })
}

//! The CPU reference renderer: Monte Carlo direct lighting with exact visibility.
//!
//! For every pixel of the scene camera (Vulkan clip space, pixel (0, 0) at the top left) it
//! casts `spp` primary rays through jittered positions in the pixel and, at the first hit,
//! estimates the direct lighting integral
//! `L_o(wo) = integral f(wi, wo) L_env(wi) V(wi) cos(theta_i) dwi`
//! with one environment sample (alias table over texels, weighted by luminance x solid angle)
//! and one BRDF sample per primary ray, combined by multiple importance sampling with the power
//! heuristic (beta = 2). Visibility `V` is traced exactly against every triangle of the scene at
//! the frame's time (CWBVH from `obvhs`). Primary rays that miss see the environment.
//! Only direct lighting: no interreflections, no emission from surfaces.
//!
//! Surfaces are two-sided: the geometric normal is flipped towards the viewer. A direction
//! below the geometric surface counts as blocked by it. Shading uses the interpolated vertex
//! normal; where the viewer is below the shading hemisphere the BRDF is zero.
//!
//! Every pixel owns a PCG32 stream seeded by `(seed, pixel index)`, so the image is
//! bit-for-bit identical for a seed whatever the number of threads. The per-pixel standard
//! error of the mean is estimated from the samples' variance.

use crate::brdf::Brdf;
use crate::geometry::Geometry;
use crate::image::{Image, ImageError};
use crate::sampling::{luminance, EnvLight, Frame as ShadingFrame, Pcg32};
use glam::{Vec3, Vec4};
use penumbra_scene::Scene;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the renderer evaluates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[derive(clap::ValueEnum)]
pub enum Mode {
    /// Exact lighting and BRDFs, exact visibility.
    #[default]
    Exact,
}

/// Options of [`render`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferenceOptions {
    pub width: u32,
    pub height: u32,
    /// Samples per pixel (each: one primary ray, one light sample, one BRDF sample).
    pub spp: u32,
    /// Frame index K.
    pub frame: u32,
    /// Scene time in seconds; `None` = `frame / fps`.
    pub time: Option<f32>,
    /// Frames per second used when `time` is `None`.
    pub fps: f32,
    pub seed: u64,
    pub mode: Mode,
    /// Show a progress bar on stderr (only if stderr is a terminal).
    pub progress: bool,
}

impl Default for ReferenceOptions {
    fn default() -> Self {
        ReferenceOptions {
            width: 320,
            height: 240,
            spp: 64,
            frame: 0,
            time: None,
            fps: 30.0,
            seed: 0,
            mode: Mode::Exact,
            progress: false,
        }
    }
}

impl ReferenceOptions {
    /// The scene time of the rendered frame in seconds.
    pub fn time_s(&self) -> f32 {
        self.time.unwrap_or(self.frame as f32 / self.fps)
    }
}

/// Errors of the reference renderer.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("invalid reference options: {0}")]
    Options(String),
    #[error("scene '{scene}': {message}")]
    Scene { scene: String, message: String },
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("{path}: {message}")]
    Output { path: PathBuf, message: String },
}

/// The renderer's own estimate of its noise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseStats {
    /// Mean over pixels of (standard error of the pixel's luminance) / (pixel luminance).
    pub mean_rel_std_error: f64,
    /// Median of the same.
    pub median_rel_std_error: f64,
    /// Maximum of the same.
    pub max_rel_std_error: f64,
    /// Pixels included: luminance above `rel_threshold`.
    pub pixels_measured: u64,
    /// Pixels darker than this (1e-3 x the image's mean luminance) are left out of the relative
    /// statistics.
    pub rel_threshold: f64,
    /// Mean absolute standard error of the luminance over all pixels.
    pub mean_std_error: f64,
}

/// A rendered reference image with its noise estimate.
#[derive(Clone, Debug)]
pub struct ReferenceImage {
    /// Mean radiance per pixel (linear RGB).
    pub radiance: Image,
    /// Standard error of the mean per pixel and channel.
    pub std_error: Image,
    pub noise: NoiseStats,
    pub options: ReferenceOptions,
    pub scene: String,
    /// Scene time rendered, seconds.
    pub time_s: f32,
    pub triangles: usize,
    /// Wall-clock seconds of BVH build and rendering.
    pub render_seconds: f64,
}

/// Summary written next to the images.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReferenceSummary {
    pub scene: String,
    pub options: ReferenceOptions,
    pub time_s: f32,
    pub triangles: usize,
    pub render_seconds: f64,
    pub noise: NoiseStats,
    pub image: PathBuf,
    pub std_error_image: PathBuf,
    pub estimator: String,
}

impl ReferenceImage {
    /// Write `reference.exr`, `reference_stderr.exr` and `reference.json` into `dir` (created if
    /// needed); returns the summary.
    pub fn write(&self, dir: &Path) -> Result<ReferenceSummary, RenderError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| RenderError::Output { path: dir.into(), message: format!("cannot create directory: {e}") })?;
        let image = dir.join("reference.exr");
        let std_error_image = dir.join("reference_stderr.exr");
        self.radiance.write_exr(&image)?;
        self.std_error.write_exr(&std_error_image)?;
        let s = ReferenceSummary {
            scene: self.scene.clone(),
            options: self.options.clone(),
            time_s: self.time_s,
            triangles: self.triangles,
            render_seconds: self.render_seconds,
            noise: self.noise.clone(),
            image,
            std_error_image,
            estimator: "direct lighting, env importance sampling + BRDF sampling, power-heuristic MIS, exact BVH visibility".into(),
        };
        let json = dir.join("reference.json");
        let text = serde_json::to_string_pretty(&s).map_err(|e| RenderError::Output { path: json.clone(), message: e.to_string() })?;
        std::fs::write(&json, text).map_err(|e| RenderError::Output { path: json.clone(), message: e.to_string() })?;
        Ok(s)
    }
}

/// Everything a pixel sample needs.
pub(crate) struct Context {
    pub geo: Geometry,
    pub env: EnvLight,
    pub brdfs: Vec<Brdf>,
    pub inv_view_proj: glam::Mat4,
}

fn power_heuristic(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

impl Context {
    pub(crate) fn new(scene: &Scene, opts: &ReferenceOptions) -> Result<Self, RenderError> {
        let serr = |message: String| RenderError::Scene { scene: scene.name.clone(), message };
        let t = opts.time_s();
        let frame = scene.at(t, None);
        let geo = Geometry::new(scene, &frame).map_err(serr)?;
        let env = match &scene.environment {
            Some(e) => EnvLight::new(e).map_err(serr)?,
            None => EnvLight::black(),
        };
        let brdfs = scene.materials.iter().map(Brdf::from_material).collect();
        let aspect = opts.width as f32 / opts.height as f32;
        let vp = frame.camera.proj(aspect) * frame.camera.view();
        let inv_view_proj = vp.inverse();
        if !inv_view_proj.is_finite() {
            return Err(serr("camera has a singular view-projection matrix".into()));
        }
        Ok(Context { geo, env, brdfs, inv_view_proj })
    }

    /// Primary ray through normalized device coordinates (Vulkan: y = -1 at the top).
    fn camera_ray(&self, ndc_x: f32, ndc_y: f32) -> (Vec3, Vec3) {
        let near = self.inv_view_proj * Vec4::new(ndc_x, ndc_y, 0.0, 1.0);
        let far = self.inv_view_proj * Vec4::new(ndc_x, ndc_y, 1.0, 1.0);
        let (n, f) = (near.truncate() / near.w, far.truncate() / far.w);
        (n, (f - n).normalize())
    }

    /// One sample of the radiance arriving through the pixel: primary ray + direct lighting.
    pub(crate) fn sample(&self, ndc_x: f32, ndc_y: f32, rng: &mut Pcg32) -> Vec3 {
        let (o, d) = self.camera_ray(ndc_x, ndc_y);
        let Some(hit) = self.geo.intersect(o, d, f32::INFINITY) else {
            return self.env.radiance(d);
        };
        let wo_w = -d;
        let ng = if hit.ng.dot(wo_w) >= 0.0 { hit.ng } else { -hit.ng };
        let ns = if hit.ns.dot(ng) >= 0.0 { hit.ns } else { -hit.ns };
        let brdf = &self.brdfs[hit.material as usize];
        let frame = ShadingFrame::new(ns, hit.tangent);
        let wo = frame.to_local(wo_w);
        let origin = hit.p + ng * self.geo.epsilon();
        let mut l = Vec3::ZERO;
        // Environment sample.
        let ue = [rng.next_f32(), rng.next_f32(), rng.next_f32(), rng.next_f32()];
        if let Some((wi_w, le, pdf_l)) = self.env.sample(ue) {
            if wi_w.dot(ng) > 0.0 {
                let wi = frame.to_local(wi_w);
                let f = brdf.eval(wo, wi);
                if f != Vec3::ZERO && self.geo.unoccluded(origin, wi_w, f32::INFINITY) {
                    let w = power_heuristic(pdf_l, brdf.pdf(wo, wi));
                    l += f * le * (wi.z * w / pdf_l);
                }
            }
        }
        // BRDF sample.
        let ul = rng.next_f32();
        let ub = rng.next_vec2();
        if let Some(wi) = brdf.sample(wo, ul, ub) {
            let wi_w = frame.to_world(wi).normalize();
            let pdf_b = brdf.pdf(wo, wi);
            if pdf_b > 0.0 && wi_w.dot(ng) > 0.0 {
                let f = brdf.eval(wo, wi);
                if f != Vec3::ZERO && self.geo.unoccluded(origin, wi_w, f32::INFINITY) {
                    let le = self.env.radiance(wi_w);
                    let w = if self.env.can_sample() { power_heuristic(pdf_b, self.env.pdf(wi_w)) } else { 1.0 };
                    l += f * le * (wi.z * w / pdf_b);
                }
            }
        }
        if l.is_finite() {
            l
        } else {
            Vec3::ZERO
        }
    }
}

#[derive(Clone, Copy, Default)]
struct PixelAcc {
    sum: [f64; 3],
    sum2: [f64; 3],
    lsum: f64,
    lsum2: f64,
}

fn validate(opts: &ReferenceOptions) -> Result<(), RenderError> {
    let bad = |m: &str| Err(RenderError::Options(m.into()));
    if opts.width == 0 || opts.height == 0 {
        return bad(&format!("size {}x{} is empty", opts.width, opts.height));
    }
    if opts.width as u64 * opts.height as u64 > 1 << 28 {
        return bad(&format!("size {}x{} is too large", opts.width, opts.height));
    }
    if opts.spp < 2 {
        return bad("spp must be at least 2 (the standard error needs two samples)");
    }
    if opts.time.is_none() && !(opts.fps.is_finite() && opts.fps > 0.0) {
        return bad(&format!("fps {} must be positive", opts.fps));
    }
    if !opts.time_s().is_finite() {
        return bad("time is not finite");
    }
    Ok(())
}

/// Render the reference image of `scene` with `opts`.
pub fn render(scene: &Scene, opts: &ReferenceOptions) -> Result<ReferenceImage, RenderError> {
    validate(opts)?;
    let start = Instant::now();
    let ctx = Context::new(scene, opts)?;
    let (w, h) = (opts.width, opts.height);
    let bar = progress_bar(opts.progress, h as u64);
    let rows: Vec<Vec<PixelAcc>> = (0..h)
        .into_par_iter()
        .map(|y| {
            let row = (0..w)
                .map(|x| {
                    let idx = y as u64 * w as u64 + x as u64;
                    let mut rng = Pcg32::for_pixel(opts.seed, idx);
                    let mut acc = PixelAcc::default();
                    for _ in 0..opts.spp {
                        let j = rng.next_vec2();
                        let ndc_x = 2.0 * (x as f32 + j.x) / w as f32 - 1.0;
                        let ndc_y = 2.0 * (y as f32 + j.y) / h as f32 - 1.0;
                        let v = ctx.sample(ndc_x, ndc_y, &mut rng);
                        for c in 0..3 {
                            let x = v[c] as f64;
                            acc.sum[c] += x;
                            acc.sum2[c] += x * x;
                        }
                        let lv = luminance(v) as f64;
                        acc.lsum += lv;
                        acc.lsum2 += lv * lv;
                    }
                    acc
                })
                .collect();
            if let Some(b) = &bar {
                b.inc(1);
            }
            row
        })
        .collect();
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let n = opts.spp as f64;
    let se = |s: f64, s2: f64| ((s2 - s * s / n).max(0.0) / (n - 1.0) / n).sqrt();
    let mut radiance = Image::new(w, h);
    let mut std_error = Image::new(w, h);
    let mut lum = Vec::with_capacity((w * h) as usize);
    for (y, row) in rows.iter().enumerate() {
        for (x, a) in row.iter().enumerate() {
            let m = [0, 1, 2].map(|c| (a.sum[c] / n) as f32);
            let e = [0, 1, 2].map(|c| se(a.sum[c], a.sum2[c]) as f32);
            radiance.set(x as u32, y as u32, m);
            std_error.set(x as u32, y as u32, e);
            lum.push((a.lsum / n, se(a.lsum, a.lsum2)));
        }
    }
    let noise = noise_stats(&lum);
    Ok(ReferenceImage {
        radiance,
        std_error,
        noise,
        options: opts.clone(),
        scene: scene.name.clone(),
        time_s: opts.time_s(),
        triangles: ctx.geo.triangle_count(),
        render_seconds: start.elapsed().as_secs_f64(),
    })
}

/// Statistics of per-pixel (mean luminance, standard error of the luminance).
pub fn noise_stats(lum: &[(f64, f64)]) -> NoiseStats {
    let mean_l = lum.iter().map(|p| p.0).sum::<f64>() / lum.len().max(1) as f64;
    let thr = (1e-3 * mean_l).max(1e-12);
    let mut rel: Vec<f64> = lum.iter().filter(|p| p.0 > thr).map(|p| p.1 / p.0).collect();
    rel.sort_by(|a, b| a.total_cmp(b));
    let k = rel.len();
    NoiseStats {
        mean_rel_std_error: if k > 0 { rel.iter().sum::<f64>() / k as f64 } else { 0.0 },
        median_rel_std_error: if k > 0 { rel[k / 2] } else { 0.0 },
        max_rel_std_error: rel.last().copied().unwrap_or(0.0),
        pixels_measured: k as u64,
        rel_threshold: thr,
        mean_std_error: lum.iter().map(|p| p.1).sum::<f64>() / lum.len().max(1) as f64,
    }
}

fn progress_bar(enabled: bool, rows: u64) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    if !enabled || !std::io::stderr().is_terminal() {
        return None;
    }
    let b = indicatif::ProgressBar::new(rows);
    if let Ok(s) = indicatif::ProgressStyle::with_template(
        "reference {bar:40.cyan/blue} {pos}/{len} rows {elapsed_precise} (eta {eta})",
    ) {
        b.set_style(s);
    }
    Some(b)
}

//! A converged reference: the CPU reference rendered until its own error, estimated from the
//! samples' per-pixel variance, is below a target, and cached on disk.
//!
//! **Noise estimate.** Each batch of samples reports every pixel's standard error (the sample
//! variance over the batch's count); the final image's variance per pixel and channel is their
//! count-weighted sum, and its RMSE against the converged truth is the root of their mean.
//! Divided by the final image's mean radiance, this is the noise in the same unit as the
//! matrix's `rmse_rel_mean` metric ([`crate::metrics::Comparison::rmse_rel_mean`]): a technique
//! whose `rmse_rel_mean` is close to it is as good as the reference can tell, and `mc`'s budget
//! scales it to mc's samples per pixel.
//!
//! The samples are also split into two halves A and B rendered with disjoint seeds, and
//! `RMS(A - B) / 2` over the mean is kept beside it (`halves_noise_rmse_rel_mean`): the estimate
//! references before `noise_method = "pixel_variance"` carried. It rests on one difference per
//! pixel, so where one pixel holds most of the variance (a sharp highlight) it is a single draw of
//! a chi-square with about one degree of freedom: `isg_bunny`'s 40x30 reference said 0.0034 where
//! the per-pixel variance says 0.0091. A cached reference of that kind is re-estimated once on load
//! ([`PIXEL_NOISE_RESAMPLE_SPP`] fresh samples per pixel give the per-sample variance; the stored
//! image's is that over its count) and its sidecar rewritten.
//!
//! **Rounds.** Each round renders one batch per half (equal sample counts, fresh seeds), then
//! re-estimates the noise; since it falls as `1 / sqrt(spp)`, the next round is sized to reach
//! the target (with 15 % margin), up to `max_spp` in total.
//!
//! **Cache.** [`cache_key`] hashes (FNV-1a 64, stable across builds) the scene file's bytes, the
//! frame, fps, size, seed, target noise, mode and [`REFERENCE_VERSION`]; [`load_or_render`]
//! reads `DIR/<stem>-<w>x<h>-f<frame>-<key>.exr` and its `.json` sidecar when both exist and
//! match, else renders and writes them. Files referenced by the scene (meshes, environment
//! maps) are not part of the key: bump [`REFERENCE_VERSION`] or clear the cache after changing
//! them.

use crate::image::Image;
use crate::render::{render, Mode, ReferenceOptions, RenderError};
use penumbra_scene::Scene;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Version of the reference estimator and its conventions; part of every cache key. Bump it
/// whenever a change to `render.rs`, `brdf.rs`, `sampling.rs`, `lights.rs` or `geometry.rs`
/// changes the images.
/// - 1: converged references introduced; environment texels read as the GPU reads them.
/// - 2: equiangular distance sampling towards local lights in media (same expectation, far
///   less noise near lights inside a medium).
/// - 3: the shading normal is turned towards the viewer where it faced away
///   (`render::facing_normal`): silhouette pixels of smooth meshes are no longer black.
pub const REFERENCE_VERSION: u32 = 3;

/// Options of [`render_converged`].
#[derive(Clone, Debug)]
pub struct ConvergeOptions {
    /// Size, frame/time, seed and mode; `spp` is ignored (chosen by the rounds).
    pub base: ReferenceOptions,
    /// Target of the estimated `rmse_rel_mean` of the final image (e.g. 0.01).
    pub target_noise: f64,
    /// Samples per pixel of each half in the first round.
    pub start_spp: u32,
    /// Most samples per pixel in total (both halves); the result may then miss the target.
    pub max_spp: u32,
    /// Print a line per round and show the renderer's progress bars (on a terminal).
    pub progress: bool,
    /// Prefix of the progress lines (e.g. the scene name).
    pub label: String,
}

impl Default for ConvergeOptions {
    fn default() -> Self {
        ConvergeOptions {
            base: ReferenceOptions::default(),
            target_noise: 0.01,
            start_spp: 16,
            max_spp: 1 << 16,
            progress: false,
            label: String::new(),
        }
    }
}

/// What [`render_converged`] made; also the cache's sidecar.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ConvergedMeta {
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub frame: u32,
    pub time_s: f32,
    /// Samples per pixel in total (both halves).
    pub spp: u32,
    /// Estimated `rmse_rel_mean` of the image against the converged truth (see
    /// `noise_method`).
    pub noise_rmse_rel_mean: f64,
    /// How `noise_rmse_rel_mean` was estimated: `pixel_variance` (the samples' per-pixel variance),
    /// `pixel_variance_resampled` (the per-sample variance of fresh samples over the stored
    /// image's count: a reference cached before) or empty (the two halves' difference alone,
    /// before the per-pixel estimate; re-estimated when loaded).
    #[serde(default)]
    pub noise_method: String,
    /// The two halves' estimate `RMS(A - B) / 2` over the mean (see the module's documentation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub halves_noise_rmse_rel_mean: Option<f64>,
    pub target_noise: f64,
    /// Wall-clock seconds spent rendering (all rounds).
    pub seconds: f64,
    pub reference_version: u32,
    pub key: String,
}

/// A converged reference image.
#[derive(Clone, Debug)]
pub struct Converged {
    pub radiance: Image,
    pub meta: ConvergedMeta,
    /// Read from the cache rather than rendered.
    pub cached: bool,
}

impl Converged {
    /// Whether the estimated noise reached the target.
    pub fn converged(&self) -> bool {
        self.meta.noise_rmse_rel_mean <= self.meta.target_noise
    }
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = x;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The estimated `rmse_rel_mean` of `(a + b) / 2` from two independent halves: `RMS(a - b) / 2`
/// over pixels and channels, over the mean of `(a + b) / 2`. `None` for images of different
/// sizes; 0 for identical images; infinite when the mean is not positive but the halves differ.
pub fn halves_noise(a: &Image, b: &Image) -> Option<f64> {
    if a.width != b.width || a.height != b.height || a.pixels.len() != b.pixels.len() {
        return None;
    }
    let (mut d2, mut sum, mut n) = (0.0f64, 0.0f64, 0u64);
    for (pa, pb) in a.pixels.iter().zip(&b.pixels) {
        for c in 0..3 {
            let (x, y) = (pa[c] as f64, pb[c] as f64);
            if x.is_finite() && y.is_finite() {
                d2 += (x - y) * (x - y);
                sum += 0.5 * (x + y);
                n += 1;
            }
        }
    }
    let n = n.max(1) as f64;
    let rms = (d2 / n).sqrt() / 2.0;
    let mean = sum / n;
    Some(if rms == 0.0 {
        0.0
    } else if mean > 0.0 {
        rms / mean
    } else {
        f64::INFINITY
    })
}

/// The estimated `rmse_rel_mean` of `img` from the variance of each pixel's channels (`var`, in
/// the order of `img.pixels`): the root of their mean over the mean radiance, over the channels
/// that are finite in both. 0 when every variance is 0; infinite when the mean is not positive
/// but some variance is not 0.
pub fn pixel_noise(img: &Image, var: &[[f64; 3]]) -> f64 {
    let (mut v2, mut sum, mut n) = (0.0f64, 0.0f64, 0u64);
    for (p, v) in img.pixels.iter().zip(var) {
        for c in 0..3 {
            if p[c].is_finite() && v[c].is_finite() {
                v2 += v[c].max(0.0);
                sum += p[c] as f64;
                n += 1;
            }
        }
    }
    let n = n.max(1) as f64;
    let rms = (v2 / n).sqrt();
    let mean = sum / n;
    if rms == 0.0 {
        0.0
    } else if mean > 0.0 {
        rms / mean
    } else {
        f64::INFINITY
    }
}

/// Fresh samples per pixel that re-estimate a cached reference's noise from the per-pixel variance
/// when its sidecar has only the two halves' estimate.
pub const PIXEL_NOISE_RESAMPLE_SPP: u32 = 256;

/// The noise of `img`, a converged reference of `spp` samples per pixel rendered with `base`'s
/// options: the per-sample variance of [`PIXEL_NOISE_RESAMPLE_SPP`] fresh samples per pixel (seeds
/// disjoint from the rounds'), over `spp`, through [`pixel_noise`].
pub fn resampled_pixel_noise(
    scene: &Scene,
    base: &ReferenceOptions,
    img: &Image,
    spp: u32,
) -> Result<f64, RenderError> {
    let n = PIXEL_NOISE_RESAMPLE_SPP;
    let o =
        ReferenceOptions { spp: n, seed: splitmix(base.seed ^ 0x6e6f_6973_6520_7631), progress: false, ..base.clone() };
    let r = render(scene, &o)?;
    let scale = n as f64 / spp.max(1) as f64;
    let var: Vec<[f64; 3]> = r.std_error.pixels.iter().map(|e| e.map(|s| (s as f64) * (s as f64) * scale)).collect();
    Ok(pixel_noise(img, &var))
}

/// Accumulates batches of one half: spp-weighted sums.
struct Half {
    sum: Vec<[f64; 3]>,
    spp: u64,
}

impl Half {
    fn new(pixels: usize) -> Self {
        Half { sum: vec![[0.0; 3]; pixels], spp: 0 }
    }
    fn add(&mut self, img: &Image, spp: u32) {
        for (s, p) in self.sum.iter_mut().zip(&img.pixels) {
            for c in 0..3 {
                s[c] += p[c] as f64 * spp as f64;
            }
        }
        self.spp += spp as u64;
    }
    /// Both halves' samples together: the final image's sums.
    fn merged(&self, o: &Half) -> Half {
        let sum = self.sum.iter().zip(&o.sum).map(|(s, t)| [s[0] + t[0], s[1] + t[1], s[2] + t[2]]).collect();
        Half { sum, spp: self.spp + o.spp }
    }
    fn image(&self, w: u32, h: u32) -> Image {
        let n = self.spp.max(1) as f64;
        Image { width: w, height: h, pixels: self.sum.iter().map(|s| s.map(|v| (v / n) as f32)).collect() }
    }
}

/// Renders `scene` until the estimated noise is at most `opts.target_noise` (or `max_spp` is
/// spent).
pub fn render_converged(scene: &Scene, opts: &ConvergeOptions) -> Result<Converged, RenderError> {
    if !(opts.target_noise.is_finite() && opts.target_noise > 0.0) {
        return Err(RenderError::Options(format!("target noise {} must be positive", opts.target_noise)));
    }
    let start = Instant::now();
    let (w, h) = (opts.base.width, opts.base.height);
    let npix = w as usize * h as usize;
    let (mut a, mut b) = (Half::new(npix), Half::new(npix));
    let max_half = (opts.max_spp / 2).max(2) as u64;
    let mut batch = opts.start_spp.max(2).min(max_half as u32);
    let mut round = 0u64;
    let mut noise;
    let mut halves;
    // per pixel and channel: the sum over batches of (batch spp x standard error)^2, i.e. the
    // variance of the spp-weighted sum of the samples
    let mut var_sum = vec![[0.0f64; 3]; npix];
    loop {
        for (k, half) in [&mut a, &mut b].into_iter().enumerate() {
            let o = ReferenceOptions {
                spp: batch,
                seed: splitmix(opts.base.seed ^ splitmix(2 * round + k as u64 + 1)),
                progress: opts.progress,
                ..opts.base.clone()
            };
            let img = render(scene, &o)?;
            half.add(&img.radiance, batch);
            for (v, e) in var_sum.iter_mut().zip(&img.std_error.pixels) {
                for c in 0..3 {
                    let s = e[c] as f64 * batch as f64;
                    v[c] += s * s;
                }
            }
        }
        round += 1;
        let (ia, ib) = (a.image(w, h), b.image(w, h));
        halves = halves_noise(&ia, &ib).unwrap_or(f64::INFINITY);
        let total = (a.spp + b.spp) as f64;
        let var: Vec<[f64; 3]> = var_sum.iter().map(|v| v.map(|x| x / (total * total))).collect();
        noise = pixel_noise(&a.merged(&b).image(w, h), &var);
        let spp_half = a.spp;
        if opts.progress {
            tracing::info!(
                "reference {}: {} spp, estimated noise {:.4} (target {}; two halves' estimate {:.4}) after {:.1} s",
                opts.label,
                2 * spp_half,
                noise,
                opts.target_noise,
                halves,
                start.elapsed().as_secs_f64()
            );
        }
        if noise <= opts.target_noise || spp_half >= max_half {
            break;
        }
        // noise ~ 1/sqrt(spp): samples per half needed, with a margin; at least double.
        let need = if noise.is_finite() {
            (spp_half as f64 * (noise / opts.target_noise).powi(2) * 1.15).ceil() as u64
        } else {
            4 * spp_half
        };
        let more = need.saturating_sub(spp_half).max(spp_half).min(max_half - spp_half);
        batch = more.clamp(2, u32::MAX as u64) as u32;
    }
    let sum = a.merged(&b);
    let radiance = sum.image(w, h);
    Ok(Converged {
        radiance,
        meta: ConvergedMeta {
            scene: scene.name.clone(),
            width: w,
            height: h,
            frame: opts.base.frame,
            time_s: opts.base.time_s(),
            spp: sum.spp as u32,
            noise_rmse_rel_mean: noise,
            noise_method: "pixel_variance".into(),
            halves_noise_rmse_rel_mean: Some(halves),
            target_noise: opts.target_noise,
            seconds: start.elapsed().as_secs_f64(),
            reference_version: REFERENCE_VERSION,
            key: String::new(),
        },
        cached: false,
    })
}

/// FNV-1a 64 (stable across Rust versions and platforms, unlike `std`'s hashers).
pub fn fnv1a64(bytes: &[u8], mut h: u64) -> u64 {
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x100_0000_01b3);
    }
    h
}

/// The cache key of a converged reference of the scene whose file holds `scene_bytes`.
pub fn cache_key(scene_bytes: &[u8], opts: &ConvergeOptions) -> String {
    let mut h = fnv1a64(scene_bytes, 0xcbf2_9ce4_8422_2325);
    let o = &opts.base;
    let mode = match o.mode {
        Mode::Exact => 0u8,
        Mode::SgLighting => 1,
        Mode::Sg => 2,
    };
    let fields = format!(
        "v{REFERENCE_VERSION} {}x{} frame {} time {:?} fps {} seed {} mode {mode} lobes {} target {}{}",
        o.width,
        o.height,
        o.frame,
        o.time.map(f32::to_bits),
        o.fps.to_bits(),
        o.seed,
        o.sg_lobes,
        opts.target_noise.to_bits(),
        if o.pixel_grid > 0 { format!(" grid {}", o.pixel_grid) } else { String::new() }
    );
    h = fnv1a64(fields.as_bytes(), h);
    format!("{h:016x}")
}

/// [`cache_key`] of a loaded scene: its file's bytes, tagged with the renderer features the scene
/// uses that came after [`REFERENCE_VERSION`]'s last change (surface emission, directional
/// lights, normal maps, glTF texture transforms, a medium counted from the eye instead of the
/// near plane), so that a reference cached before the renderer drew them is not reused, while every
/// other scene keeps its key (and its checked-in reference).
pub fn scene_cache_key(scene: &Scene, scene_bytes: &[u8], opts: &ConvergeOptions) -> String {
    let mut tags = Vec::new();
    if scene.material_extras.iter().any(|x| x.emission != glam::Vec3::ZERO) {
        tags.push("emission");
    }
    if scene.lights.iter().any(|l| l.kind == penumbra_scene::LightKind::Directional) {
        tags.push("directional");
    }
    if scene.material_extras.iter().any(|x| x.normal_map.is_some()) {
        tags.push("normal_map");
    }
    if scene.material_extras.iter().any(|x| x.uv_transform.is_some()) {
        tags.push("texture_transform");
    }
    if scene.medium.is_some() {
        tags.push("medium_from_the_eye");
    }
    if tags.is_empty() {
        return cache_key(scene_bytes, opts);
    }
    let mut bytes = scene_bytes.to_vec();
    bytes.extend_from_slice(format!("\0penumbra reference features: {}", tags.join(" ")).as_bytes());
    cache_key(&bytes, opts)
}

/// A scene file's stem as a cache file name part (anything but ASCII letters, digits, `_` and
/// `-` becomes `_`).
pub fn cache_stem(stem: &str) -> String {
    stem.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' || c == '-' { c } else { '_' }).collect()
}

/// The cache file of a reference: `DIR/<stem>-<w>x<h>-f<frame>-<key>.exr` (sidecar `.json`).
pub fn cache_path(dir: &Path, stem: &str, opts: &ConvergeOptions, key: &str) -> PathBuf {
    let stem = cache_stem(stem);
    dir.join(format!("{stem}-{}x{}-f{}-{key}.exr", opts.base.width, opts.base.height, opts.base.frame))
}

/// Reads the converged reference of `scene` (loaded from a file holding `scene_bytes`, named
/// `stem` in the cache) from `cache` when it is there and matches, else renders it with
/// [`render_converged`] and writes it there (a cache that cannot be written is reported on
/// stderr, not an error).
pub fn load_or_render(
    scene: &Scene,
    scene_bytes: &[u8],
    stem: &str,
    opts: &ConvergeOptions,
    cache: Option<&Path>,
) -> Result<Converged, RenderError> {
    let key = scene_cache_key(scene, scene_bytes, opts);
    let path = cache.map(|d| cache_path(d, stem, opts, &key));
    if let Some(p) = &path {
        let meta_path = p.with_extension("json");
        if p.exists() && meta_path.exists() {
            let meta: Option<ConvergedMeta> =
                std::fs::read_to_string(&meta_path).ok().and_then(|t| serde_json::from_str(&t).ok());
            match (meta, Image::read_exr(p)) {
                (Some(meta), Ok(img))
                    if meta.key == key
                        && meta.reference_version == REFERENCE_VERSION
                        && img.width == opts.base.width
                        && img.height == opts.base.height =>
                {
                    let mut meta = meta;
                    if meta.noise_method.is_empty() {
                        // cached with the two halves' estimate only: re-estimate from the
                        // per-pixel variance of fresh samples, and keep it
                        let noise = resampled_pixel_noise(scene, &opts.base, &img, meta.spp)?;
                        tracing::info!(
                            "reference {}: noise re-estimated from the per-pixel variance: {:.4} (the two halves said {:.4})",
                            p.display(),
                            noise,
                            meta.noise_rmse_rel_mean
                        );
                        meta.halves_noise_rmse_rel_mean = Some(meta.noise_rmse_rel_mean);
                        meta.noise_rmse_rel_mean = noise;
                        meta.noise_method = "pixel_variance_resampled".into();
                        let text = serde_json::to_string_pretty(&meta).map(|t| t + "\n");
                        match text
                            .map_err(|e| e.to_string())
                            .and_then(|t| std::fs::write(&meta_path, t).map_err(|e| e.to_string()))
                        {
                            Ok(()) => {}
                            Err(e) => tracing::warn!("reference cache {}: not rewritten: {e}", meta_path.display()),
                        }
                    }
                    return Ok(Converged { radiance: img, meta, cached: true });
                }
                _ => tracing::info!("reference cache {}: stale or unreadable, rendering again", p.display()),
            }
        }
    }
    let mut c = render_converged(scene, opts)?;
    c.meta.key = key;
    if let Some(p) = &path {
        let write = || -> Result<(), String> {
            if let Some(d) = p.parent() {
                std::fs::create_dir_all(d).map_err(|e| e.to_string())?;
            }
            c.radiance.write_exr(p).map_err(|e| e.to_string())?;
            let text = serde_json::to_string_pretty(&c.meta).map_err(|e| e.to_string())? + "\n";
            std::fs::write(p.with_extension("json"), text).map_err(|e| e.to_string())
        };
        if let Err(e) = write() {
            tracing::warn!("reference cache {}: not written: {e}", p.display());
        }
    }
    Ok(c)
}

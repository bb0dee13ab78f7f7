//! The CPU reference renderer: Monte Carlo direct lighting with exact visibility.
//!
//! For every pixel of the scene camera (Vulkan clip space, pixel (0, 0) at the top left) it
//! casts `spp` primary rays through uniformly jittered positions in the pixel (starting on the
//! near plane; with [`ReferenceOptions::pixel_grid`] = n, through the centre of one of the
//! pixel's n x n sub-pixels, drawn uniformly: the sample positions of a rasterizer rendering at n
//! times the size and box-filtering down) and, at the first hit, estimates the direct lighting integral
//! `L_o(wo) = integral f(wi, wo) L_i(wi) V(wi) cos(theta_i) dwi`
//! with, per primary ray: one environment sample (alias table over texels, weighted by
//! luminance x exact texel solid angle), one sample per local light (see [`crate::lights`])
//! and one BRDF sample, combined by multiple importance sampling with the power heuristic
//! (beta = 2). Visibility `V` is traced exactly against every shadow-casting triangle of the
//! scene at the frame's time (deformed meshes included; `obvhs` CWBVH). Primary rays that miss
//! see the environment. Only direct lighting: no interreflections; a surface's emission
//! (`MaterialExtra::emission`, times its map) is added where the eye sees it and lights nothing.
//!
//! Surfaces are two-sided: the geometric normal is flipped towards the viewer, and a direction
//! below the geometric surface counts as blocked by it. Shading uses the interpolated vertex
//! normal, bent by the material's tangent-space normal map (+x along dP/du, +y along dP/dv), and
//! dP/du as tangent; where the viewer would be below the shading hemisphere the normal is
//! turned towards the viewer until n.v = 0.01 ([`facing_normal`]; the BRDF would be zero and
//! such silhouette pixels black). Materials are the frame's (animated) materials with
//! `albedo_map` (multiplies albedo) and `roughness_map` (G channel multiplies roughness; Phong
//! exponents follow `2 / r^2 - 2`) sampled bilinearly at the interpolated UV.
//!
//! **Medium** (`Scene::medium`): homogeneous, filling all space. Camera rays are attenuated by
//! `exp(-sigma_t t)`, `t` counted from the eye (the ray itself starts on the near plane) (so the environment behind an infinite medium is invisible) and gain single
//! scattering `integral T(t) sigma_s integral p(wi . d) L_i(x(t), wi) dwi dt`, estimated with one
//! distance sample per primary ray (pdf proportional to `exp(-mean(sigma_t) t)` on
//! `[0, t_hit]`) and the same light/phase-function MIS as surfaces, Henyey-Greenstein phase with
//! `cos` = dot of the propagation directions; the distance is also sampled equiangularly towards
//! each local light and the samples combined by the balance heuristic. Local lights are attenuated by `exp(-sigma_t d)`
//! on their way in; **environment light is not attenuated** on its way in (the usual fog
//! convention: an infinite medium would otherwise extinguish it completely).
//!
//! Every pixel owns a PCG32 stream seeded by `(seed, pixel index)`, so the image is
//! bit-for-bit identical for a seed whatever the number of threads. The per-pixel standard
//! error of the mean is the samples' standard deviation over sqrt(spp). Non-finite samples
//! (never expected) count as zero.

use crate::brdf::Brdf;
use crate::geometry::Geometry;
use crate::image::{Image, ImageError};
use crate::lights::LocalLight;
use crate::sampling::{luminance, EnvLight, Frame as ShadingFrame, Pcg32};
use glam::{Vec3, Vec4};
use penumbra_scene::{Environment, Scene};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What the renderer evaluates.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default, clap::ValueEnum)]
pub enum Mode {
    /// Exact lighting and BRDFs, exact visibility.
    #[default]
    Exact,
    /// The environment replaced by its K-lobe SG fit (`penumbra_math::envmap`,
    /// `ReferenceOptions::sg_lobes`), evaluated exactly per direction; exact BRDFs, local lights
    /// and visibility. Tells a technique's visibility error apart from its SG lighting error.
    SgLighting,
    /// As `SgLighting`, and the specular lobes replaced by their SG approximation from
    /// `penumbra_math::brdf` (closed-form warp of Wang et al. 2009, one lobe, per shading point):
    /// Blinn-Phong exactly the math crate's lobe, Cook-Torrance the math crate's Beckmann lobe
    /// with `m = roughness^2`. Diffuse terms, the cosine and visibility stay exact;
    /// Ashikhmin-Shirley stays exact (its 7-lobe fit is an iterative optimisation, too slow per
    /// shading point).
    Sg,
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
    /// Number of SG lobes fitted to the environment in [`Mode::SgLighting`].
    #[serde(default = "default_sg_lobes")]
    pub sg_lobes: u32,
    /// Show a progress bar on stderr (only if stderr is a terminal).
    pub progress: bool,
    /// Where primary rays cross the pixel. 0 (the default): uniformly anywhere in it (a box
    /// pixel filter, anti-aliased). n >= 1: through the centre of one of its n x n sub-pixels,
    /// drawn uniformly per sample, so the image converges to the average of those n^2 point
    /// samples: what a rasterizer sees at n x n supersampling (1: the pixel centre). The
    /// accuracy matrix compares rasterizing techniques with such a reference, so that its
    /// numbers measure shading, not the pixel filter (a thin dragon at 40x30 is mostly
    /// aliasing otherwise).
    #[serde(default)]
    pub pixel_grid: u32,
}

fn default_sg_lobes() -> u32 {
    16
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
            sg_lobes: default_sg_lobes(),
            progress: false,
            pixel_grid: 0,
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
    /// [`Mode::SgLighting`]: relative L2 error of the SG fit of the environment.
    pub sg_fit_rel_l2: Option<f64>,
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
    pub sg_fit_rel_l2: Option<f64>,
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
            sg_fit_rel_l2: self.sg_fit_rel_l2,
            image,
            std_error_image,
            estimator:
                "direct lighting, env importance sampling + BRDF sampling, power-heuristic MIS, exact BVH visibility"
                    .into(),
        };
        let json = dir.join("reference.json");
        let text = serde_json::to_string_pretty(&s)
            .map_err(|e| RenderError::Output { path: json.clone(), message: e.to_string() })?;
        std::fs::write(&json, text).map_err(|e| RenderError::Output { path: json.clone(), message: e.to_string() })?;
        Ok(s)
    }
}

/// A material at one frame: base BRDF parameters, optional texture maps.
pub(crate) struct MaterialEval {
    base: Brdf,
    material: penumbra_scene::Material,
    shininess_v: Option<f32>,
    albedo_map: Option<usize>,
    roughness_map: Option<usize>,
    emission: Vec3,
    emission_map: Option<usize>,
    normal_map: Option<usize>,
    normal_scale: f32,
}

/// A homogeneous medium.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MediumEval {
    sigma_t: Vec3,
    sigma_s: Vec3,
    g: f32,
    /// Mean extinction, used to sample distances.
    sigma_bar: f32,
}

impl MediumEval {
    fn transmittance(&self, d: f32) -> Vec3 {
        if d.is_infinite() {
            Vec3::select(self.sigma_t.cmpgt(Vec3::ZERO), Vec3::ZERO, Vec3::ONE)
        } else {
            (-self.sigma_t * d).exp()
        }
    }
    /// Henyey-Greenstein for the angle between the light's propagation direction before and
    /// after scattering.
    fn phase(&self, cos_theta: f32) -> f32 {
        let g = self.g;
        let d = (1.0 + g * g - 2.0 * g * cos_theta).max(1e-12);
        (1.0 - g * g) / (4.0 * std::f32::consts::PI * d * d.sqrt())
    }
}

/// How light scatters at a shading point: a BRDF times cosine at a surface, or the phase
/// function in the medium.
enum Scatter<'a> {
    Surface {
        brdf: Brdf,
        frame: ShadingFrame,
        wo: Vec3,
        ng: Vec3,
        /// [`Mode::Sg`]: specular lobes (local axis, sharpness, RGB amplitude) replacing the
        /// BRDF's specular term.
        spec_sg: Option<[(Vec3, f32, Vec3); 1]>,
        _p: std::marker::PhantomData<&'a ()>,
    },
    /// `d`: direction of the camera ray (light leaves towards `-d`).
    Medium { m: &'a MediumEval, d: Vec3 },
}

impl Scatter<'_> {
    /// Scattering throughput for light arriving from world direction `wi` (BRDF * cos, or phase).
    fn eval(&self, wi: Vec3) -> Vec3 {
        match self {
            Scatter::Surface { brdf, frame, wo, ng, spec_sg, .. } => {
                if wi.dot(*ng) <= 0.0 {
                    return Vec3::ZERO; // below the geometric surface: blocked by it
                }
                let l = frame.to_local(wi);
                if l.z <= 0.0 || wo.z <= 0.0 {
                    return Vec3::ZERO;
                }
                match spec_sg {
                    None => brdf.eval(*wo, l) * l.z,
                    Some(lobes) => (brdf.eval_lambert(*wo, l) + crate::sampling::eval_sg_sum(lobes, l)) * l.z,
                }
            }
            Scatter::Medium { m, d } => Vec3::splat(m.phase(wi.dot(*d))),
        }
    }
    fn pdf(&self, wi: Vec3) -> f32 {
        match self {
            Scatter::Surface { brdf, frame, wo, .. } => brdf.pdf(*wo, frame.to_local(wi)),
            Scatter::Medium { m, d } => m.phase(wi.dot(*d)),
        }
    }
    fn sample(&self, rng: &mut Pcg32) -> Option<Vec3> {
        match self {
            Scatter::Surface { brdf, frame, wo, ng, .. } => {
                let ul = rng.next_f32();
                let u = rng.next_vec2();
                let wi = frame.to_world(brdf.sample(*wo, ul, u)?).normalize();
                (wi.dot(*ng) > 0.0).then_some(wi)
            }
            Scatter::Medium { m, d } => {
                let u = rng.next_vec2();
                let g = m.g;
                // cos of the angle between the propagation directions (-wi) and (-d).
                let cos_t = if g.abs() < 1e-3 {
                    1.0 - 2.0 * u.x
                } else {
                    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x);
                    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
                };
                let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
                let phi = std::f32::consts::TAU * u.y;
                let f = ShadingFrame::new(*d, Vec3::ZERO);
                // wi makes angle theta with d (wi . d = cos(angle between -wi and -d)).
                Some(f.to_world(Vec3::new(sin_t * phi.cos(), sin_t * phi.sin(), cos_t)).normalize())
            }
        }
    }
}

/// Everything a pixel sample needs.
pub(crate) struct Context {
    pub geo: Geometry,
    pub env: EnvLight,
    pub lights: Vec<LocalLight>,
    pub medium: Option<MediumEval>,
    pub materials: Vec<MaterialEval>,
    pub textures: Vec<penumbra_scene::Texture>,
    pub inv_view_proj: glam::Mat4,
    /// The camera's eye: distances in the medium count from it.
    pub eye: Vec3,
    pub sg_fit_rel_l2: Option<f64>,
    /// [`Mode::Sg`]: SG specular lobes.
    pub sg_brdfs: bool,
}

/// The SG specular lobe of `penumbra_math::brdf` for a Blinn-Phong or Cook-Torrance BRDF at
/// local outgoing direction `wo` (RGB amplitude: specular colour for Blinn-Phong; for
/// Cook-Torrance the Schlick term is linear in F0, so lobes at F0 = 0 and 1 are combined).
pub fn sg_specular(brdf: &Brdf, wo: Vec3) -> Option<[(Vec3, f32, Vec3); 1]> {
    use penumbra_math::brdf::{BlinnPhong, CookTorrance};
    if wo.z <= 0.0 {
        return None;
    }
    let wo64 = wo.as_dvec3();
    match brdf.kind {
        penumbra_scene::BrdfKind::BlinnPhong => {
            let g = BlinnPhong { shininess: brdf.shininess as f64 }.sg_warp(wo64);
            Some([(g.axis.as_vec3(), g.lambda as f32, brdf.specular * g.mu as f32)])
        }
        penumbra_scene::BrdfKind::CookTorrance => {
            let m = brdf.alpha as f64;
            let g0 = CookTorrance { roughness: m, f0: 0.0 }.sg_warp(wo64);
            let g1 = CookTorrance { roughness: m, f0: 1.0 }.sg_warp(wo64);
            let mu = Vec3::splat(g0.mu as f32) + brdf.specular * (g1.mu - g0.mu) as f32;
            Some([(g1.axis.as_vec3(), g1.lambda as f32, mu)])
        }
        _ => None,
    }
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
        let mut sg_fit_rel_l2 = None;
        // the environment as lit at this time (its animation's rotation and intensity)
        let env_now = scene.environment.as_ref().map(|e| Environment {
            rotation: frame.environment.rotation,
            intensity: frame.environment.intensity,
            ..e.clone()
        });
        let env = match (&env_now, opts.mode) {
            (Some(e), Mode::Exact) => EnvLight::new(e).map_err(serr)?,
            (Some(e), Mode::SgLighting | Mode::Sg) => {
                let fit = penumbra_math::envmap::fit_sg_lighting(
                    e.width as usize,
                    e.height as usize,
                    &e.texels,
                    opts.sg_lobes.max(1) as usize,
                )
                .map_err(|err| serr(format!("SG fit of the environment: {err}")))?;
                sg_fit_rel_l2 = Some(fit.rel_l2_error);
                let lobes: Vec<(Vec3, f32, Vec3)> =
                    fit.lobes.iter().map(|l| (l.axis.as_vec3(), l.lambda as f32, l.mu.as_vec3())).collect();
                EnvLight::from_sg(e, &lobes).map_err(serr)?
            }
            (None, _) => EnvLight::black(),
        };
        let mut materials = Vec::with_capacity(frame.materials.len());
        for (i, m) in frame.materials.iter().enumerate() {
            let x = scene.material_extra(i);
            for (what, map) in [("albedo_map", x.albedo_map), ("roughness_map", x.roughness_map)] {
                if let Some(k) = map {
                    let ok = scene.textures.get(k).is_some_and(|t| {
                        t.width > 0 && t.height > 0 && t.texels.len() == t.width as usize * t.height as usize
                    });
                    if !ok {
                        return Err(serr(format!(
                            "material '{}': {what} refers to a missing or empty texture {k}",
                            m.name
                        )));
                    }
                }
            }
            materials.push(MaterialEval {
                base: Brdf::new(m.kind, m.albedo, m.specular, m.roughness, m.shininess, x.shininess_v),
                material: m.clone(),
                shininess_v: x.shininess_v,
                albedo_map: x.albedo_map,
                roughness_map: x.roughness_map,
                emission: if x.emission.is_finite() { x.emission.max(Vec3::ZERO) } else { Vec3::ZERO },
                emission_map: x.emission_map,
                normal_map: x.normal_map,
                normal_scale: if x.normal_scale.is_finite() && x.normal_scale != 0.0 { x.normal_scale } else { 1.0 },
            });
        }
        let lights = frame.lights.iter().filter_map(LocalLight::new).collect();
        let medium = scene.medium.as_ref().and_then(|m| {
            let st = m.sigma_a.max(Vec3::ZERO) + m.sigma_s.max(Vec3::ZERO);
            (st.is_finite() && st.max_element() > 0.0 && m.g.is_finite()).then(|| MediumEval {
                sigma_t: st,
                sigma_s: m.sigma_s.max(Vec3::ZERO),
                g: m.g.clamp(-0.999, 0.999),
                sigma_bar: (st.x + st.y + st.z) / 3.0,
            })
        });
        let aspect = opts.width as f32 / opts.height as f32;
        let vp = frame.camera.proj(aspect) * frame.camera.view();
        let inv_view_proj = vp.inverse();
        if !inv_view_proj.is_finite() {
            return Err(serr("camera has a singular view-projection matrix".into()));
        }
        Ok(Context {
            geo,
            env,
            lights,
            medium,
            materials,
            textures: scene.textures.clone(),
            inv_view_proj,
            eye: frame.camera.eye,
            sg_fit_rel_l2,
            sg_brdfs: opts.mode == Mode::Sg,
        })
    }

    /// Primary ray through normalized device coordinates (Vulkan: y = -1 at the top).
    fn camera_ray(&self, ndc_x: f32, ndc_y: f32) -> (Vec3, Vec3) {
        let near = self.inv_view_proj * Vec4::new(ndc_x, ndc_y, 0.0, 1.0);
        let far = self.inv_view_proj * Vec4::new(ndc_x, ndc_y, 1.0, 1.0);
        let (n, f) = (near.truncate() / near.w, far.truncate() / far.w);
        (n, (f - n).normalize())
    }

    fn transmittance(&self, d: f32) -> Vec3 {
        self.medium.as_ref().map_or(Vec3::ONE, |m| m.transmittance(d))
    }

    /// The BRDF at a hit, with texture maps applied.
    fn brdf_at(&self, material: u32, uv: glam::Vec2) -> Brdf {
        let me = &self.materials[material as usize];
        if me.albedo_map.is_none() && me.roughness_map.is_none() {
            return me.base;
        }
        let m = &me.material;
        let mut albedo = m.albedo;
        let (mut roughness, mut shininess, mut sv) = (m.roughness, m.shininess, me.shininess_v);
        if let Some(k) = me.albedo_map {
            albedo *= self.textures[k].sample(uv).truncate();
        }
        if let Some(k) = me.roughness_map {
            roughness = (roughness * self.textures[k].sample(uv).y).clamp(0.0, 1.0);
            // As for animated roughness: the Phong-type exponents follow 2 / r^2 - 2.
            let s = 2.0 / (roughness * roughness).max(1e-4) - 2.0;
            if let Some(v) = sv.as_mut() {
                *v *= s / shininess.max(1e-6);
            }
            shininess = s;
        }
        Brdf::new(m.kind, albedo, m.specular, roughness, shininess, sv)
    }

    /// The shading normal `ns` with the material's tangent-space normal map applied at `uv`
    /// (`material_normal` in `glsl/include/material.glsl`): +x along dP/du, +y along dP/dv.
    fn normal_at(&self, material: u32, uv: glam::Vec2, ns: Vec3, dpdu: Vec3, dpdv: Vec3) -> Vec3 {
        let me = &self.materials[material as usize];
        let Some(k) = me.normal_map else { return ns };
        let t = dpdu - ns * ns.dot(dpdu);
        if t.length_squared() < 1e-20 || !t.is_finite() {
            return ns;
        }
        let t = t.normalize();
        let mut b = ns.cross(t);
        if b.dot(dpdv) < 0.0 {
            b = -b;
        }
        let c = self.textures[k].sample(uv).truncate() * 2.0 - Vec3::ONE;
        let s = me.normal_scale;
        let n = (t * (c.x * s) + b * (c.y * s) + ns * c.z.max(1e-3)).normalize_or_zero();
        if n == Vec3::ZERO || !n.is_finite() {
            ns
        } else {
            n
        }
    }

    /// The radiance a material emits at `uv` (its emission map applied).
    fn emission_at(&self, material: u32, uv: glam::Vec2) -> Vec3 {
        let me = &self.materials[material as usize];
        match me.emission_map {
            Some(k) if me.emission != Vec3::ZERO => {
                (me.emission * self.textures[k].sample(uv).truncate()).max(Vec3::ZERO)
            }
            _ => me.emission,
        }
    }

    /// Direct lighting scattered at `p` by `sc`: environment, area and delta lights by light
    /// sampling, plus one scatter (BRDF/phase) sample, combined by the power heuristic.
    /// Lights are sampled from `p`; shadow rays start at `x` (`p` offset off the surface).
    fn direct(&self, p: Vec3, x: Vec3, sc: &Scatter, rng: &mut Pcg32) -> Vec3 {
        let mut l = Vec3::ZERO;
        // Environment sample (environment light is not attenuated by the medium).
        let ue = [rng.next_f32(), rng.next_f32(), rng.next_f32(), rng.next_f32()];
        if let Some((wi, le, pdf_l)) = self.env.sample(ue) {
            let f = sc.eval(wi);
            if f != Vec3::ZERO && self.geo.unoccluded(x, wi, f32::INFINITY) {
                let w = power_heuristic(pdf_l, sc.pdf(wi));
                l += f * le * (w / pdf_l);
            }
        }
        // Local lights, one sample each.
        for light in &self.lights {
            let u = rng.next_vec2();
            let Some(ls) = light.sample(p, u) else { continue };
            let f = sc.eval(ls.wi);
            if f == Vec3::ZERO || !self.geo.unoccluded(x, ls.wi, ls.dist * (1.0 - 1e-4)) {
                continue;
            }
            let tr = self.transmittance(ls.dist);
            match ls.pdf {
                None => l += f * ls.li * tr,
                Some(p) => {
                    let w = power_heuristic(p, sc.pdf(ls.wi));
                    l += f * ls.li * tr * (w / p);
                }
            }
        }
        // Scatter sample.
        if let Some(wi) = sc.sample(rng) {
            let pdf_s = sc.pdf(wi);
            let f = sc.eval(wi);
            if pdf_s > 0.0 && f != Vec3::ZERO {
                if self.geo.unoccluded(x, wi, f32::INFINITY) {
                    let w = if self.env.can_sample() { power_heuristic(pdf_s, self.env.pdf(wi)) } else { 1.0 };
                    l += f * self.env.radiance(wi) * (w / pdf_s);
                }
                for light in self.lights.iter().filter(|l| !l.is_delta()) {
                    if let Some((t, le, pdf_l)) = light.hit_radiance_pdf(p, wi) {
                        if self.geo.unoccluded(x, wi, t * (1.0 - 1e-4)) {
                            let w = power_heuristic(pdf_s, pdf_l);
                            l += f * le * self.transmittance(t) * (w / pdf_s);
                        }
                    }
                }
            }
        }
        l
    }

    /// One sample of the radiance arriving through the pixel: primary ray, single scattering
    /// along it in the medium (if any) and direct lighting at the first surface.
    pub(crate) fn sample(&self, ndc_x: f32, ndc_y: f32, rng: &mut Pcg32) -> Vec3 {
        let (o, d) = self.camera_ray(ndc_x, ndc_y);
        let hit = self.geo.intersect(o, d, f32::INFINITY);
        let t_hit = hit.as_ref().map_or(f32::INFINITY, |h| h.t);
        let mut l = Vec3::ZERO;
        let mut surface_tr = Vec3::ONE;
        if let Some(m) = &self.medium {
            // The medium fills the space from the eye, as every GPU technique's volumetric pass
            // measures it: the primary ray starts on the near plane (what a rasterizer sees),
            // but transmittance and in-scattering count from the eye, `t0` before it (with the
            // default near plane of 0.05 the image was about exp(sigma_t t0) too bright: 1.4%
            // on vol_donuts).
            let t0 = (o - self.eye).dot(d).max(0.0);
            let o = o - d * t0;
            let t_hit = t_hit + t0;
            surface_tr = m.transmittance(t_hit);
            // In-scattering, one distance sample per strategy combined by the balance heuristic
            // (multi-sample MIS: each sample weighs f / sum of all strategies' pdfs): the
            // transmittance (pdf ~ exp(-sigma_bar t) on [0, t_hit]) and, per local light,
            // equiangular sampling (Kulla and Fajardo 2012, pdf ~ 1 / (h^2 + (t - delta)^2)),
            // without which a light inside the medium makes the estimator's variance unbounded
            // (1 / d^2 near the light).
            let sb = m.sigma_bar;
            let mass = if t_hit.is_finite() { -(-sb * t_hit).exp_m1() } else { 1.0 };
            let pdf_exp = |t: f32| if mass > 0.0 && t >= 0.0 && t < t_hit { sb * (-sb * t).exp() / mass } else { 0.0 };
            let eq: Vec<Equiangular> =
                self.lights.iter().filter_map(|li| Equiangular::new(o, d, li.position()?, t_hit)).collect();
            let pdf_sum = |t: f32| pdf_exp(t) + eq.iter().map(|e| e.pdf(t)).sum::<f32>();
            let mut ts = Vec::with_capacity(1 + eq.len());
            let u = rng.next_f32();
            let t = -(-u * mass).ln_1p() / sb;
            if mass > 0.0 && t.is_finite() && t < t_hit {
                ts.push(t);
            }
            for e in &eq {
                let u = rng.next_f32();
                if let Some(t) = e.sample(u) {
                    ts.push(t);
                }
            }
            for t in ts {
                let p = pdf_sum(t);
                if !(p > 0.0 && p.is_finite()) {
                    continue;
                }
                let x = o + d * t;
                let sc = Scatter::Medium { m, d };
                let li = self.direct(x, x, &sc, rng);
                l += m.transmittance(t) * m.sigma_s * li / p;
            }
        }
        match hit {
            None => l += surface_tr * self.env.radiance(d),
            Some(hit) => {
                let wo_w = -d;
                let ng = if hit.ng.dot(wo_w) >= 0.0 { hit.ng } else { -hit.ng };
                let ns = if hit.ns.dot(ng) >= 0.0 { hit.ns } else { -hit.ns };
                let ns = facing_normal(self.normal_at(hit.material, hit.uv, ns, hit.tangent, hit.bitangent), wo_w);
                let brdf = self.brdf_at(hit.material, hit.uv);
                let frame = ShadingFrame::new(ns, hit.tangent);
                let wo = frame.to_local(wo_w);
                let origin = hit.p + ng * self.geo.epsilon_at(hit.p);
                let spec_sg = if self.sg_brdfs { sg_specular(&brdf, wo) } else { None };
                let sc = Scatter::Surface { brdf, frame, wo, ng, spec_sg, _p: std::marker::PhantomData };
                l += surface_tr * (self.direct(hit.p, origin, &sc, rng) + self.emission_at(hit.material, hit.uv));
            }
        }
        if l.is_finite() {
            l
        } else {
            Vec3::ZERO
        }
    }
}

/// The least the viewer's direction may rise above a shading hemisphere: [`facing_normal`].
pub const FACING_MIN_COS: f32 = 0.01;

/// The shading normal `n` (unit) turned towards the unit direction to the viewer `v` just as far
/// as needed to make `n . v` at least about [`FACING_MIN_COS`] (`n`'s component along `v` raised
/// to it, the rest kept), else `n` itself. An interpolated vertex normal at a smooth mesh's
/// silhouette, or a normal map, can turn the shading hemisphere away from the eye on a triangle
/// that faces it; the BRDF is zero for a viewer below it, and such pixels drew black (a
/// rasterizer and a ray tracer disagreeing about one pixel centre on a sliver triangle then
/// made a pixel black in one image and not in the other). Surfaces the eye sees this way are
/// shaded as if seen at a grazing angle instead (as Falcor's `adjustShadingNormal` does); the
/// GPU's `material_facing_normal` (material.glsl) is the same rule.
pub fn facing_normal(n: Vec3, v: Vec3) -> Vec3 {
    let c = n.dot(v);
    if c >= FACING_MIN_COS || !c.is_finite() {
        return n;
    }
    let b = (n + v * (FACING_MIN_COS - c)).normalize_or_zero();
    if b == Vec3::ZERO || !b.is_finite() {
        v
    } else {
        b
    }
}

/// Equiangular distance sampling towards a point `c` along the ray `o + t d`, `t` in
/// `[0, t_max]` (Kulla and Fajardo 2012).
struct Equiangular {
    delta: f32,
    h: f32,
    theta_a: f32,
    theta_b: f32,
    t_max: f32,
}

impl Equiangular {
    fn new(o: Vec3, d: Vec3, c: Vec3, t_max: f32) -> Option<Self> {
        let delta = (c - o).dot(d);
        let h = (o + d * delta - c).length().max(1e-4);
        let theta_a = (-delta / h).atan();
        let theta_b = if t_max.is_finite() { ((t_max - delta) / h).atan() } else { std::f32::consts::FRAC_PI_2 };
        (theta_b - theta_a > 1e-6 && h.is_finite() && delta.is_finite()).then_some(Equiangular {
            delta,
            h,
            theta_a,
            theta_b,
            t_max,
        })
    }
    fn sample(&self, u: f32) -> Option<f32> {
        let th = self.theta_a + u * (self.theta_b - self.theta_a);
        let t = self.delta + self.h * th.tan();
        (t.is_finite() && t >= 0.0 && t < self.t_max).then_some(t)
    }
    fn pdf(&self, t: f32) -> f32 {
        if !(t >= 0.0 && t < self.t_max) {
            return 0.0;
        }
        let x = t - self.delta;
        self.h / ((self.theta_b - self.theta_a) * (self.h * self.h + x * x))
    }
}

#[derive(Clone, Copy, Default)]
struct PixelAcc {
    sum: [f64; 3],
    sum2: [f64; 3],
    lsum: f64,
    lsum2: f64,
}

/// Checks options before rendering (sizes, samples, time): the errors are the caller's input.
pub fn validate(opts: &ReferenceOptions) -> Result<(), RenderError> {
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
    if opts.pixel_grid > 16 {
        return bad(&format!("pixel grid {} is larger than 16", opts.pixel_grid));
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
                        let j = pixel_offset(rng.next_vec2(), opts.pixel_grid);
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
        sg_fit_rel_l2: ctx.sg_fit_rel_l2,
    })
}

/// The primary ray's position in its pixel for the uniform `u` in [0, 1)^2: `u` itself, or for
/// a `grid` of n >= 1 the centre of the sub-pixel of the n x n grid that `u` falls in (each drawn
/// with probability 1 / n^2).
pub fn pixel_offset(u: glam::Vec2, grid: u32) -> glam::Vec2 {
    if grid == 0 {
        return u;
    }
    let n = grid as f32;
    ((u * n).floor().min(glam::Vec2::splat(n - 1.0)) + 0.5) / n
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

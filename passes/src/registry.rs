//! The registry: the one place that names every technique and effect, with what the engine and
//! its tools need to know of each (parameters with defaults and ranges, requirements, accuracy
//! budget, constructor). Scene files, `--technique`, `penumbra techniques`, the benches and the
//! accuracy matrix all derive from [`REGISTRY`] and [`EFFECTS`].
//!
//! Adding a technique: a module implementing [`Technique`] under
//! `passes/src/`, its shaders under `glsl/`, one [`TechniqueInfo`] here (with its parameter docs
//! and constructor), a scene, a test; then `penumbra bench matrix --techniques NAME --write-known`
//! records its accuracy cells.

use crate::technique::Technique;
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::Context;
use penumbra_scene::Scene;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Technique parameters as written (`[technique_params]` of a scene file, `--param KEY=VALUE`).
pub type Params = BTreeMap<String, String>;

/// Bad input to the registry: an unknown technique, a refused scene, an unknown parameter key or
/// a bad value. The caller's to fix, not the device's (`penumbra::Error::BadInput`).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BadInput(pub String);

fn bad(e: impl std::fmt::Display) -> anyhow::Error {
    anyhow::Error::new(BadInput(e.to_string()))
}

/// A technique's parameters parsed by its own parser; a bad one is [`BadInput`].
fn parsed<T>(r: Result<T>) -> Result<T> {
    r.map_err(|e| bad(format!("{e:#}")))
}

/// The accuracy budget of a technique, judged by the scene x technique matrix
/// (`penumbra bench matrix`, `tools/tests/matrix.rs`) against a converged CPU reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// The technique's image must have `rmse_rel_mean` (RMSE over the reference's mean
    /// radiance) at most `rmse_rel_mean`; `source` says where the figure comes from (the paper's
    /// figure where it reports one, otherwise the technique's documented approximation).
    RmseRelMean { rmse_rel_mean: f64, source: &'static str },
    /// An unbiased Monte Carlo estimator with the reference's estimator: its `rmse_rel_mean`
    /// must be at most `factor` times the noise the reference has at the technique's accumulated
    /// samples per pixel (`reference noise x sqrt(reference spp / technique spp)`), i.e. pure
    /// noise, no bias.
    Unbiased { factor: f64, source: &'static str },
    /// The unshadowed baseline (`env`): no budget; its `rel_rmse` is what `shadow_recovered`
    /// measures the shadow techniques against.
    Baseline { source: &'static str },
}

/// One documented technique parameter.
#[derive(Clone, Copy, Debug)]
pub struct ParamDoc {
    pub key: &'static str,
    /// The default, written as a scene file would write it.
    pub default: &'static str,
    /// Accepted values (a range, a list of words, `true/false`).
    pub range: &'static str,
    pub doc: &'static str,
}

/// Builds a technique for a scene with its parameters (already checked against the registry).
pub type CreateFn = fn(&Arc<Context>, &ShaderLibrary, &Scene, &Params) -> Result<Box<dyn Technique>>;

/// One registered technique: its name and what the engine and its tools need to know of it.
#[derive(Clone, Copy)]
pub struct TechniqueInfo {
    /// The name in scene files (`technique = "..."`), on the CLI and in the matrix.
    pub name: &'static str,
    /// One line for listings.
    pub summary: &'static str,
    /// The parameters it accepts (`[technique_params]`, `--param`); none: it refuses any.
    pub params: &'static [ParamDoc],
    /// Precomputes visibility for static geometry only: refuses scenes whose objects move or
    /// deform.
    pub static_only: bool,
    /// Precomputes a rigid field per shadow-casting object (moving is fine): refuses scenes
    /// whose shadow-casting objects deform, naming them, rather than shadow by their rest mesh.
    pub rigid_only: bool,
    /// Follows an animated environment (`Frame::environment`: rotation and intensity per frame);
    /// false: it bakes the lighting when created and refuses a scene whose environment is animated.
    pub animated_environment: bool,
    /// Renders shadows: the matrix requires `shadow_recovered >= 0.5` on every scene it accepts.
    pub shadows: bool,
    pub budget: Budget,
    /// Its speed/accuracy knobs: parameters and the values `bench pareto` tries, one knob at a
    /// time away from the defaults.
    pub knobs: &'static [Knob],
    pub create: CreateFn,
}

/// A speed/accuracy knob of a technique: a documented parameter and the values to try.
#[derive(Clone, Copy, Debug)]
pub struct Knob {
    pub key: &'static str,
    pub values: &'static [&'static str],
    /// Costlier values, in order, that `penumbra tune` tries only when no configuration of the
    /// sweep reaches the asked error (mc's samples per pixel: it converges to the reference).
    pub finer: &'static [&'static str],
}

const fn k(key: &'static str, values: &'static [&'static str]) -> Knob {
    Knob { key, values, finer: &[] }
}

impl std::fmt::Debug for TechniqueInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TechniqueInfo")
            .field("name", &self.name)
            .field("static_only", &self.static_only)
            .field("rigid_only", &self.rigid_only)
            .field("animated_environment", &self.animated_environment)
            .field("shadows", &self.shadows)
            .field("budget", &self.budget)
            .finish_non_exhaustive()
    }
}

impl TechniqueInfo {
    /// Accepts `[technique_params]` (the others refuse any).
    pub fn takes_params(&self) -> bool {
        !self.params.is_empty()
    }
}

/// One registered effect: pass chains a scene's requirements add after its technique.
#[derive(Clone, Copy, Debug)]
pub struct EffectInfo {
    pub name: &'static str,
    pub summary: &'static str,
    /// What in a scene adds it.
    pub when: &'static str,
    /// Its methods (the first is the default), chosen by the scene or an override.
    pub variants: &'static [&'static str],
}

/// The shadow techniques' common floor: the fraction of the unshadowed image's error
/// (`rel_rmse` of `env`) a shadow technique must remove on every scene it accepts.
pub const MIN_SHADOW_RECOVERED: f64 = 0.5;

/// Both isg modes (per pixel and per vertex) answer to the paper's figure.
const ISG_BUDGET: Budget = Budget::RmseRelMean {
    rmse_rel_mean: 0.05,
    source: "ISG paper, Fig. 12: RMS errors 3.2 % and 4.6 % against ray tracing",
};

/// Adaptive and fixed shells approximate visibility the same way.
const SHADOW_FIELDS_BUDGET: Budget = Budget::RmseRelMean {
    rmse_rel_mean: 0.15,
    source: "shadow-fields paper reports no image error; documented approximation: 4th-order SH (16 coefficients) visibility and lighting",
};

const fn p(key: &'static str, default: &'static str, range: &'static str, doc: &'static str) -> ParamDoc {
    ParamDoc { key, default, range, doc }
}

const MC_PARAMS: &[ParamDoc] = &[
    p("spp", "8", "1..=16384", "samples per pixel per frame (accumulated over frames while nothing moves; split into dispatches of 256)"),
    p("aa", "true", "true|false", "primary rays jittered over the pixel (anti-aliased); false: through the pixel centre, where rasterizing techniques sample (what `bench matrix` compares)"),
];

const MC_DENOISED_PARAMS: &[ParamDoc] = &[
    p("spp", "4", "1..=64", "samples per pixel of mc per frame (through the pixel centres)"),
    p("iterations", "4", "1..=8", "a-trous filter iterations (taps 1, 2, 4, ... pixels apart)"),
    p("history", "5", "1..=1024", "longest temporal history in frames, reprojected through the motion vectors (5: SVGF's alpha = 0.2; longer converges further on still views and drags moving shadows)"),
    p("phi_color", "1", "> 0", "luminance edge-stopping: differences against phi_color standard deviations of the pixel's noise (with the ratio estimator: of the visible fraction; 4 suits ratio = false)"),
    p("phi_normal", "128", "> 0", "normal edge-stopping exponent (pow(n . n_q, phi_normal))"),
    p("phi_plane", "1", "> 0", "depth edge-stopping: distance from the pixel's tangent plane against phi_plane pixel footprints per tap spacing"),
    p("phi_lobe", "4", ">= 0", "specular-lobe edge-stopping on glossy pixels: taps weighted by how far their mirror direction falls inside the pixel's specular lobe (0: off)"),
    p("clip", "1", ">= 0", "history clipped to the frame's 3x3 neighbourhood, mean +- clip standard deviations per channel (variance clipping: lighting that changes without a motion vector leaves the history; 0: off, SVGF's)"),
    p("ratio", "true", "true/false", "ratio estimator (Heitz et al. 2018): the analytic unshadowed radiance (the env technique's) times the filtered shadowed over the filtered unshadowed estimate of the same samples; false: SVGF's demodulated radiance filtered"),
    p("restart", "true", "true/false", "with the ratio estimator: a history whose visible fraction this frame's samples contradict (by more than half and six standard deviations, the unshadowed estimate steady or two neighbours agreeing) restarts: a hard shadow that moved over a still floor (false: it drags)"),
];

const SHADOWMAPS_PARAMS: &[ParamDoc] = &[
    p("count", "32", "1..=1024", "K directional lights (orthographic depth maps) importance-sampled from the environment (the ISG paper's Figure 11: 30 and 1024)"),
    p("size", "256", "16..=4096", "resolution of the environment directions' depth maps, texels per side (the ISG paper: 256)"),
    p("light_size", "1024", "16..=4096", "resolution of the local lights' depth maps (cube faces; a directional light's map), texels per side"),
    p("shading", "ratio", "ratio|lights", "lights: the sum over the K lights (the papers' baseline); ratio: the unshadowed environment lighting times the K lights' shadowed/unshadowed ratio"),
    p("march", "4", "0..=16", "ratio shading, glossy lobes the K directions do not cover: rays around the mirror direction marched through the visual hull of the K maps (0: off, the lit fraction under kernels around the mirror direction alone)"),
];

const ISG_PARAMS: &[ParamDoc] = &[
    p("lobes", "16", "1..=64", "K spherical Gaussians fitted to the environment"),
    p("fit_error", "0", "[0, 1)", "K chosen instead as the fewest of 4, 8, 16, 32, 64 lobes whose fit of the environment has at most this relative L2 error (0: off, `lobes` counts); the choice is noted"),
    p("spheres", "48", "0..=4096", "spheres per object of the sphere-set occluders"),
    p("side", "12", "1..=32", "patches per side of the discretized visibility region"),
    p("epsilon", "0.01", "1e-6..=0.5", "limiting-angle threshold (paper: 0.01)"),
    p("lod", "1.0", ">= 0", "BVH nodes below lod x patch size are rasterized as one sphere"),
    p("min_fraction", "0.02", "0..=1", "diffuse lobes (taken brightest first) below this fraction of the light found visible so far take the mean visibility of those traversed"),
    p("shadows", "true", "true/false", "false: visibility 1 (shading error only)"),
    p("prefiltered", "true", "true/false", "glossy = sg: specular from SG-prefiltered environment maps (eq. 10)"),
    p("diffuse", "ratio", "ratio, sg", "diffuse environment term: the map's exact irradiance times the SG lobes' visible share (ratio) or the SG lobes alone (sg, the paper's)"),
    p("glossy", "ratio", "ratio, sg", "glossy environment term: the material model's (the env technique's filtered importance sampling of the lobe) times the ISG visible fraction of the specular lobe (ratio) or eq. 9's one SG lobe of the BRDF (sg, the paper's)"),
    p("gpu_bvh", "true", "true/false", "build the sphere BVH on the GPU (up to 1024 spheres)"),
    p("thin_shells", "true", "true/false", "thin shells and open meshes cast shadows by their triangles"),
    p("light_shadows", "true", "true/false", "shadow rays toward local lights"),
    p("light_occluders", "mesh", "mesh, spheres", "what the local lights' shadow rays hit: the meshes (the frame's kd-tree) or the sphere sets and thin-shell triangles"),
    p("thin_tolerance", "0.005", ">= 0", "triangles farther than this fraction of their object's size outside its spheres cast shadows as thin-shell triangles (0: every triangle outside them)"),
    p("visibility", "isg", "isg, traced", "environment visibility: the ISG over the sphere proxies (the paper's) or 96 shadow rays per lobe through the meshes (traced: a measuring stick for the proxies' error; per-pixel mode only)"),
    p("mode", "pixel", "pixel, vertex", "visibility per pixel or per vertex"),
    p("max_edge", "0.1", ">= 0", "per-vertex mode: subdivide until edges are at most this (0: never)"),
    p("pixel_refine", "0.2", ">= 0", "per-vertex mode: triangles whose corners' visibilities differ by more than this are evaluated per pixel (1: never, the paper's pure per-vertex mode)"),
    p("isg_eval", "table", "table, sigmoid", "the patches' normalized ISG: the tabulated pre-integration or eq. 14's two sigmoids with the appendix polynomials (the paper's; poor below gamma of about 100)"),
    p("patch_rule", "centre", "centre, paper", "a sphere occludes the patches whose centre its cap covers, or every patch it overlaps (the paper's rule, conservative)"),
    p("as_lobes", "7", "7, 1", "Ashikhmin-Shirley's specular lobe as the paper's seven SGs along its anisotropy (per pixel) or one Cook-Torrance lobe of its roughness"),
];

const AVS_PARAMS: &[ParamDoc] = &[
    p("r", "32", "8..=256", "final visibility-map resolution (initial grid x a power of two; the paper's 128 measured no more accurate on any matrix scene, at 4-13x the time)"),
    p("initial_grid", "16", "16, 32", "first level's resolution"),
    p("e_max", "0.10", "0..=100", "E_v,max: insert sample points where visibility error exceeds it"),
    p("e_min", "0.05", "0..=100", "E_v,min: stop refining below it"),
    p("alpha", "0.3", "0..=100", "eq. 8 weight falloff"),
    p("interp_alpha", "0", "0..=100", "interpolation falloff (0: the paper's form)"),
    p("iterations", "2", "0..=16", "adaptation rounds per frame (with adaptation = late: any value above 0 is one step per frame; 0: none)"),
    p("adaptation", "cpu", "cpu, rounds, late", "cpu: every round on the CPU, its SH16 from cpu_grid x cpu_grid maps traced through an obvhs BVH of the frame's triangles, the final maps in the frame's graph (building the frame never waits); rounds: the paper's, each round's maps traced on the GPU and read back, a submission waited for; late: one adaptation step per frame from the newest finished frame's maps, never waiting (less accurate where things move)"),
    p("cpu_grid", "16", "8..=64, multiple of 8", "side of the CPU visibility maps whose SH16 the rounds of adaptation = cpu compare"),
    p("first_iterations", "8", "0..=64", "adaptation rounds of a frame that starts from fresh initial points (at least `iterations`; with adaptation = rounds or late each waited for before that frame)"),
    p("points", "0", "0..=65536", "initial sample points (0: automatic)"),
    p("max_points", "4096", "1..=65536", "upper bound on sample points (lowered to what one storage buffer of the device holds: 128 MiB on lavapipe, 4096 SSDFs at r = 128)"),
    p("pool_points", "4096", "0..=262144", "extra candidate points on triangles larger than the pool spacing, over the scene's area (0: mesh vertices only, the paper's pool)"),
    p("radius", "2.0", "0.01..=100", "search radius in mean nearest-neighbour distances"),
    p("neighbours", "6", "1..=8", "sample points interpolated per pixel"),
    p("ray_neighbours", "4", "0..=8", "neighbours whose maps also mark boundary rays"),
    p("integration", "axis", "axis, cells, table, adf", "how the visibility maps are integrated against lighting"),
    p("cells", "6", "1..=16", "cells per side of the lobe neighbourhood (integration = cells)"),
    p("shadows", "true", "true/false", "false: visibility 1 (shading error only)"),
    p("adaptive", "true", "true/false", "adaptive angular sampling (false: every texel traced)"),
    p("keep_hits", "true", "true/false", "keep an occluded parent's hit when its child rays miss"),
    p("prefiltered", "true", "true/false", "specular from SG-prefiltered environment maps"),
    p("diffuse", "ratio", "ratio, sg", "diffuse environment term: the map's exact irradiance times the SG lobes' visible share (ratio) or the SG lobes alone (sg, the paper's)"),
    p("glossy", "ratio", "ratio, sg", "glossy environment term: the material model's (the env technique's filtered importance sampling of the lobe) times the SSDF visibility of the specular lobe (ratio) or the one SG lobe of the BRDF (sg, the paper's)"),
    p("lobes", "16", "1..=64", "lighting spherical Gaussians"),
    p("cull", "true", "true/false", "trace only sample points the previous frame's pixels needed"),
    p("light_shadows", "traced", "traced, ssdf", "local lights' shadows: shadow rays through the frame's kd-tree (traced; the paper lights by the environment only) or the interpolated SSDF toward the light (ssdf)"),
    p("key_lights", "4", "0..=16", "with light_shadows = traced: the environment's compact bright lights split off its map as at most this many moment-matched lights whose diffuse light is shadowed by rays through the frame's kd-tree, the rest of the map through the SSDFs; 0: the whole map through the SSDFs (the paper's)"),
    p("key_rays", "predicted", "predicted, all", "rays per key light and pixel: the centre ray alone where the interpolated SSDF clears the light's disk by two texels and the ray agrees with it, the disk's rays elsewhere (predicted), or the disk's rays everywhere (all)"),
    p("key_pattern", "fixed", "fixed, stratified", "where a key light's rays point: the same disk pattern in every pixel (fixed: flat bands in a penumbra) or a point of each ray's equal-area cell of the disk drawn per pixel (stratified: grain around the disk's integral, more error against a reference)"),
    p("key_penumbra", "rays", "rays, refine", "a key light's share where its 9 rays disagree: the 9 rays' share (rays) or with 16 more rays in equal-area cells of its disk (refine: 25 finer steps instead of 9 flat bands, 16 more rays per penumbra pixel)"),
    p("key_filter", "4", "0..=8", "with light_shadows = traced: the key lights' diffuse light filtered over at most this radius in pixels (0 off): each pixel's visible share averaged with a Gaussian a sixteenth of its penumbra's width (the lights' angular radius times the distance to what their rays hit) over neighbours on its surface, nothing where the 3x3 neighbourhood's rays agree (the fixed pattern's bands in a wide penumbra, or key_pattern = stratified's grain, blur out; contact shadows keep their edge)"),
    p("capture_maps", "false", "true/false", "read the final visibility maps back into the technique's stats (tests)"),
];

const SHADOW_FIELDS_PARAMS: &[ParamDoc] = &[
    p("shells", "32", "1..=256", "C concentric shells per field (paper: 32)"),
    p("resolution", "32", "power of two 1..=256", "initial shell resolution R (paper: 64)"),
    p("map_res", "32", "2..=256", "occlusion-map rows (32 x 64 directions)"),
    p("threshold", "0.010", ">= 0", "eq. 1 adaptive subdivision threshold (paper: 0.010)"),
    p("mode", "pixel", "pixel, vertex", "diffuse shading per pixel or per vertex"),
    p("window", "none", "none, hanning, lanczos", "window of the occluders' visibility before the triple products"),
    p("srf", "true", "true/false", "local lights through source radiance fields (with light_shadows = fields)"),
    p("light_shadows", "traced", "traced, fields", "local lights' shadows by shadow rays through the frame's kd-tree (the lights then shaded pointwise) or from the fields (the paper's order-4 visibility toward the light)"),
    p("key_lights", "4", "0..=16", "with light_shadows = traced: the environment's compact bright lights split off its SH as at most this many moment-matched lights with traced shadows (and the glossy lobe's visibility traced); 0: the whole environment in the fields (the paper's)"),
    p("glossy", "reflection", "reflection, transfer", "the environment's glossy term: the material model's glossy term times the occluders' visibility along the reflection, or the paper's transfer (the specular lobe projected into the order-4 SH, multiplied by the occluders' visibilities by triple products, closed by the environment's SH: band-limited, blurs sharp reflections)"),
];

const SHADOW_FIELDS_WAVELET_PARAMS: &[ParamDoc] = &[
    p("shells", "32", "1..=64", "C concentric shells per field, radius 0.2 Vr (1 + c) (paper: 32)"),
    p("resolution", "32", "power of two 1..=64", "initial shell resolution R, sample points R x R per shell (paper: 64)"),
    p("cube", "16", "power of two 2..=64", "visibility cube maps of 6 x n x n pixels (paper: 32)"),
    p("keep", "0.05", "(0, 1]", "fraction of Haar coefficients kept per map (paper: 5 %)"),
    p("threshold", "0.010", ">= 0", "eq. 1 adaptive subdivision threshold, L1 in the pixel domain (paper: 0.010)"),
    p("adaptive", "true", "true/false", "adaptive shell resolutions (else every shell at R)"),
    p("self", "true", "true/false", "self-occlusion from per-vertex self-visibility cube maps, interpolated across the triangles (the diffuse environment term and the first 4 lights)"),
    p("lookup", "reproject", "reproject, direction", "between shell samples: each sample looks toward where the point's ray passes the occluder (reproject), or along the same direction (the paper)"),
    p("light_shadows", "traced", "traced, fields", "local lights' shadows by shadow rays through the frame's kd-tree or from the occluders' fields and the self-visibility maps (the paper's)"),
    p("key_lights", "4", "0..=16", "with light_shadows = traced: the environment's compact bright lights split off its map as at most this many moment-matched lights with traced shadows (and the glossy lobe's visibility traced); 0: the whole map in the fields (the paper's)"),
];

const VV_PARAMS: &[ParamDoc] = &[
    p("mode", "fragment1", "fragment3, fragment1, tessellation, tessellation3", "where visibility is evaluated and interpolated"),
    p("zeta", "2", "0..=16", "tessellation quality of eq. 18 (paper: 1 to 4)"),
    p("alpha", "2", "0.001..=1000", "alpha' of eq. 11 in 1/texel of the SAT map"),
    p("sat_width", "256", "even, 16..=4096", "width of the summed-area-table map"),
    p("arcs", "32", "8..=256", "arcs of the hemisphere (horizon) loop"),
    p("max_level", "64", "1..=64", "largest tessellation level"),
    p("resolution", "64", "8..=1024", "visibility-map resolution of the precompute"),
    p("specular", "on", "on/off", "specular term of glossy materials (eq. 14-16)"),
    p("refine", "1024", "0..=65536", "receiver refinement: edges longer than sqrt(scene area / refine) are split so large triangles get visibility samples (0: meshes as given)"),
    p("fallback", "0.05", "0..=10", "interpolated modes: triangles whose eq. 21 occluded solid angle disagrees with eq. 19 by more than this many sr are shaded by eq. 19 (0: eq. 21 everywhere, the paper)"),
    p("light_shadows", "traced", "traced, loops", "local lights' shadows: shadow rays through the scene's kd-tree, or from the occluder loops (no depth: an occluder behind a light still shadows it)"),
];

fn create_env(ctx: &Arc<Context>, shaders: &ShaderLibrary, _: &Scene, _: &Params) -> Result<Box<dyn Technique>> {
    Ok(Box::new(crate::shade_env::ShadeEnvPass::new(ctx, shaders)?))
}
fn create_mc(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let mut t = crate::mc::McTechnique::new(ctx, shaders, scene)?;
    parsed(crate::technique::apply_params(&mut t, params, crate::mc::McTechnique::set))?;
    Ok(Box::new(t))
}
fn create_mc_denoised(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let mut settings = crate::mc::denoise::DenoiseSettings::default();
    parsed(crate::technique::apply_params(&mut settings, params, crate::mc::denoise::DenoiseSettings::set))?;
    Ok(Box::new(crate::mc::denoise::McDenoised::new(ctx, shaders, scene, settings)?))
}
fn create_shadowmaps(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let settings = parsed(crate::shadowmaps::ShadowMapsSettings::from_params(params))?;
    Ok(Box::new(crate::shadowmaps::ShadowMapsTechnique::new(ctx, shaders, scene, settings)?))
}
fn create_isg_with(
    per_vertex: bool,
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let mut settings = crate::isg::IsgSettings { per_vertex, ..Default::default() };
    parsed(crate::technique::apply_params(&mut settings, params, crate::isg::IsgSettings::set))?;
    Ok(Box::new(crate::isg::IsgTechnique::new(ctx, shaders, scene, settings)?))
}
fn create_isg(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    create_isg_with(false, ctx, shaders, scene, params)
}
fn create_isg_vertex(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    create_isg_with(true, ctx, shaders, scene, params)
}
fn create_avs(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let settings = parsed(crate::avs::AvsSettings::from_params(params))?;
    Ok(Box::new(crate::avs::AvsTechnique::new(ctx, shaders, scene, settings)?))
}
fn create_sf_with(
    adaptive: bool,
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let options =
        crate::shadow_fields::SfOptions { adaptive, ..parsed(crate::shadow_fields::SfOptions::from_params(params))? };
    Ok(Box::new(crate::shadow_fields::ShadowFieldsTechnique::new(ctx, shaders, scene, options)?))
}
fn create_sf(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    create_sf_with(true, ctx, shaders, scene, params)
}
fn create_sf_fixed(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    create_sf_with(false, ctx, shaders, scene, params)
}
fn create_sf_wavelet(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let options = parsed(crate::shadow_fields::wavelet::SfwOptions::from_params(params))?;
    Ok(Box::new(crate::shadow_fields::wavelet::WaveletTechnique::new(ctx, shaders, scene, options)?))
}
fn create_vv(
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    let settings = parsed(crate::vv::VvSettings::from_params(params))?;
    Ok(Box::new(crate::vv::VvTechnique::new(ctx, shaders, scene, settings)?))
}

/// Every technique, in listing order: the one place that names them.
pub const REGISTRY: &[TechniqueInfo] = &[
    TechniqueInfo {
        name: "env",
        summary: "environment (exact irradiance map, importance-sampled glossy lobe) and local lights, no visibility",
        params: &[],
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: false,
        budget: Budget::Baseline { source: "unshadowed baseline: no visibility, so no accuracy budget" },
        knobs: &[],
        create: create_env,
    },
    TechniqueInfo {
        name: "mc",
        summary: "GPU Monte Carlo with the reference's estimator, progressive while nothing moves",
        params: MC_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: Budget::Unbiased {
            factor: 1.5,
            source: "the reference's estimator on the GPU: unbiased, so within 1.5x the reference estimator's noise at the same samples per pixel",
        },
        knobs: &[Knob { key: "spp", values: &["1", "16", "64"], finer: &["256", "1024", "4096"] }],
        create: create_mc,
    },
    TechniqueInfo {
        name: "mc-denoised",
        summary: "mc at a few samples per pixel per frame, denoised by spatio-temporal variance-guided filtering (SVGF): the baseline users pick today",
        params: MC_DENOISED_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "no paper reports its error (the vv paper compares against Monte Carlo with a denoiser); documented approximation: an unbiased estimate blurred by an edge-aware filter and a reprojected history, the shadow-map baseline's budget",
        },
        knobs: &[k("spp", &["1", "16"]), k("iterations", &["2", "6"])],
        create: create_mc_denoised,
    },
    TechniqueInfo {
        name: "shadowmaps",
        summary: "rasterized shadow maps: the environment as K shadowed directional lights, a cube map per local light (the papers' baseline)",
        params: SHADOWMAPS_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "no paper reports its error; documented approximation: the environment as K importance-sampled directional lights with 3x3-PCF depth maps, used as a ratio on the unshadowed environment lighting (the ISG paper compares against 30 and 1024 such maps)",
        },
        knobs: &[k("count", &["8", "128"]), k("size", &["64", "1024"])],
        create: create_shadowmaps,
    },
    TechniqueInfo {
        name: "isg",
        summary: "integral spherical Gaussians, per-pixel visibility over sphere sets (Iwasaki et al. 2012)",
        params: ISG_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: ISG_BUDGET,
        knobs: &[k("lobes", &["4", "32"]), k("side", &["4", "24"]), k("thin_tolerance", &["0.03"])],
        create: create_isg,
    },
    TechniqueInfo {
        name: "isg-vertex",
        summary: "integral spherical Gaussians with per-vertex visibility",
        params: ISG_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: ISG_BUDGET,
        knobs: &[k("lobes", &["4", "32"]), k("max_edge", &["0", "0.05"])],
        create: create_isg_vertex,
    },
    TechniqueInfo {
        name: "avs",
        summary: "adaptive visibility sampling with hemispherical distance transforms (Wang et al.)",
        params: AVS_PARAMS,
        static_only: false,
        rigid_only: false,
        animated_environment: true,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "avs paper reports no error figure; documented approximation: visibility sampled at adaptive points with E_v,max = 10 % relative visibility error",
        },
        knobs: &[k("r", &["64", "128"]), k("e_max", &["0.3"])],
        create: create_avs,
    },
    TechniqueInfo {
        name: "shadow-fields",
        summary: "adaptive shadow fields (SH occlusion and source radiance fields, adaptive shells)",
        params: SHADOW_FIELDS_PARAMS,
        static_only: false,
        rigid_only: true,
        animated_environment: true,
        shadows: true,
        budget: SHADOW_FIELDS_BUDGET,
        knobs: &[k("resolution", &["8", "16"]), k("shells", &["8", "16"])],
        create: create_sf,
    },
    TechniqueInfo {
        name: "shadow-fields-fixed",
        summary: "shadow fields at fixed (non-adaptive) shell resolution",
        params: SHADOW_FIELDS_PARAMS,
        static_only: false,
        rigid_only: true,
        animated_environment: true,
        shadows: true,
        budget: SHADOW_FIELDS_BUDGET,
        knobs: &[k("resolution", &["8", "16"]), k("shells", &["8", "16"])],
        create: create_sf_fixed,
    },
    TechniqueInfo {
        name: "shadow-fields-wavelet",
        summary: "all-frequency shadow fields (Haar-compressed visibility cube maps, pixel-domain triple product)",
        params: SHADOW_FIELDS_WAVELET_PARAMS,
        static_only: false,
        rigid_only: true,
        animated_environment: true,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.15,
            source: "shadow-fields paper reports no image error; the SH variants' budget: Haar visibility at 6 x 16 x 16 pixels, 5 % of coefficients, interpolated between shell samples",
        },
        knobs: &[k("cube", &["8", "32"]), k("resolution", &["16"])],
        create: create_sf_wavelet,
    },
    TechniqueInfo {
        name: "vv",
        summary: "vectorized visibility with spherical Voronoi interpolation (static geometry)",
        params: VV_PARAMS,
        static_only: true,
        rigid_only: false,
        animated_environment: false,
        shadows: true,
        budget: Budget::RmseRelMean {
            rmse_rel_mean: 0.10,
            source: "vv paper, Fig. 11: 29.58 dB at zeta = 4, an RMSE of 3.3 % of the peak; the paper gives no mean radiance, so 10 % of the mean assumes a peak about 3x the mean (an assumption, not a measurement)",
        },
        knobs: &[k("mode", &["fragment3", "tessellation"]), k("zeta", &["1", "4"])],
        create: create_vv,
    },
];

/// Every effect.
pub const EFFECTS: &[EffectInfo] = &[EffectInfo {
    name: "volumetric",
    summary: "single scattering in a homogeneous medium with volumetric shadows (light shafts)",
    when: "the scene has a [medium]; its `volumetric` key or --volumetric picks the method",
    variants: &["temporal", "full"],
}];

/// The registered technique `name`.
pub fn info(name: &str) -> Option<&'static TechniqueInfo> {
    REGISTRY.iter().find(|t| t.name == name)
}

/// The names of every registered technique, in [`REGISTRY`] order.
pub fn names() -> Vec<&'static str> {
    REGISTRY.iter().map(|t| t.name).collect()
}

/// `name` as a registered technique, or an error listing the registered ones.
/// The name that asks the engine to choose the technique ([`choose_auto`]); the default of
/// scene files without a `technique`, bare models and the built-in scene.
pub const AUTO: &str = "auto";

/// Checks a technique name as written in a scene file or on the command line: a registered
/// technique or [`AUTO`].
pub fn check_name(name: &str) -> Result<()> {
    if name == AUTO {
        return Ok(());
    }
    lookup(name).map(|_| ())
}

/// The technique and parameters `technique = "auto"` renders `scene` with, and why (one line);
/// `layered_rendering`: the device can run shadowmaps (`Context::shader_output_layer`).
///
/// From the measured fronts (`penumbra bench pareto`, README "The speed/accuracy trade") on
/// lavapipe at 160x120: `shadowmaps` is on the front of every surface scene measured and the only
/// shadowing technique that accepts every kind of scene (moving and deforming objects, local
/// lights, thin shells, texture maps): falling 0.13-0.15 RMSE over the mean at about 120 ms per
/// frame, where `mc` needs 64 samples per pixel and more than ten times the time for 0.12, and the
/// precomputed techniques refuse or fall behind. A scene without any light renders with `env`;
/// a device without layered rendering with `mc`.
pub fn choose_auto(scene: &Scene, layered_rendering: bool) -> (&'static str, Params, String) {
    let req = scene.requirements();
    if !req.environment_light && !req.local_lights {
        return ("env", Params::new(), "auto: env (the scene has no light to cast shadows)".into());
    }
    if !layered_rendering {
        return (
            "mc",
            Params::new(),
            "auto: mc (4 samples per pixel per frame): the device lacks shaderOutputLayer, which shadowmaps' layered pass needs (choose with --technique)".into(),
        );
    }
    let mut kinds = Vec::new();
    if req.moving_objects || req.deforming_objects {
        kinds.push("moving objects");
    }
    if req.local_lights {
        kinds.push("local lights");
    }
    if req.thin_shells {
        kinds.push("thin shells");
    }
    if req.spatially_varying_materials {
        kinds.push("texture maps");
    }
    let what = if kinds.is_empty() { String::new() } else { format!(", with {}", kinds.join(", ")) };
    (
        "shadowmaps",
        Params::new(),
        format!(
            "auto: shadowmaps (32 environment shadow maps, a cube map per local light), on the measured speed/accuracy front for scenes of this kind{what} (`penumbra bench pareto`; choose with --technique)"
        ),
    )
}

pub fn lookup(name: &str) -> Result<&'static TechniqueInfo> {
    info(name).ok_or_else(|| bad(format!("unknown technique '{name}' (registered: {})", names().join(", "))))
}

/// Why technique `name` refuses `scene` before anything is built, if it does: a static-only
/// technique on moving or deforming geometry (naming the object), a rigid-only one on deforming
/// shadow casters (naming them), a technique that bakes the lighting on an animated environment.
pub fn refusal(name: &str, scene: &Scene) -> Option<String> {
    let info = info(name)?;
    if !info.animated_environment && scene.requirements().animated_environment {
        return Some(format!(
            "'{name}' bakes the environment's lighting when it is created; this scene animates the environment's rotation or intensity ([[environment.keys]]); techniques that follow it: {}",
            REGISTRY.iter().filter(|t| t.animated_environment).map(|t| t.name).collect::<Vec<_>>().join(", ")
        ));
    }
    if info.static_only {
        for (i, o) in scene.objects.iter().enumerate() {
            let oi = scene.object_info(i);
            if oi.is_moving() || oi.is_deforming() {
                return Some(format!(
                    "'{name}' precomputes visibility for static geometry; object '{}' {}",
                    o.name,
                    if oi.is_moving() { "moves" } else { "deforms" }
                ));
            }
        }
    }
    if info.rigid_only {
        let deforming: Vec<String> = scene
            .objects
            .iter()
            .enumerate()
            .filter(|&(i, _)| scene.object_info(i).is_deforming() && scene.object_info(i).casts_shadow)
            .map(|(_, o)| format!("'{}'", o.name))
            .collect();
        if !deforming.is_empty() {
            return Some(format!(
                "'{name}' precomputes a rigid field per shadow-casting object, which a deforming object would leave as its rest mesh's shadow; object(s) {} deform (give them `casts_shadow = false`, or pick a technique that follows deforming objects: {})",
                deforming.join(", "),
                REGISTRY.iter().filter(|t| !t.static_only && !t.rigid_only && t.shadows).map(|t| t.name).collect::<Vec<_>>().join(", ")
            ));
        }
    }
    None
}

/// Checks `params` against technique `name`'s documented keys: a technique without parameters
/// refuses any; an undocumented key is an error listing the documented ones. (Values are checked
/// by the technique's own parser when it is created.)
pub fn check_params(name: &str, params: &Params) -> Result<()> {
    let info = lookup(name)?;
    if params.is_empty() {
        return Ok(());
    }
    if !info.takes_params() {
        return Err(bad(format!(
            "technique '{name}' takes no parameters (got: {})",
            params.keys().cloned().collect::<Vec<_>>().join(", ")
        )));
    }
    let unknown: Vec<&str> =
        params.keys().map(|k| k.trim()).filter(|k| !info.params.iter().any(|p| p.key == *k)).collect();
    if !unknown.is_empty() {
        return Err(bad(format!(
            "unknown {name} parameter{} '{}' (known: {})",
            if unknown.len() > 1 { "s" } else { "" },
            unknown.join("', '"),
            info.params.iter().map(|p| p.key).collect::<Vec<_>>().join(", ")
        )));
    }
    Ok(())
}

/// Creates technique `name` (or [`AUTO`]'s choice) for `scene` with `params`: an unknown name, a refused scene
/// ([`refusal`]) or a bad parameter is an error.
pub fn create(
    name: &str,
    ctx: &Arc<Context>,
    shaders: &ShaderLibrary,
    scene: &Scene,
    params: &Params,
) -> Result<Box<dyn Technique>> {
    if name == AUTO {
        // the chosen technique with the given parameters, or its own when none are given
        let (chosen, own, _) = choose_auto(scene, ctx.shader_output_layer);
        return create(chosen, ctx, shaders, scene, if params.is_empty() { &own } else { params });
    }
    let info = lookup(name)?;
    if let Some(why) = refusal(name, scene) {
        return Err(bad(why));
    }
    check_params(name, params)?;
    (info.create)(ctx, shaders, scene, params)
}

/// The registry as text (`penumbra techniques`): every technique with its summary,
/// requirements, budget and parameters, then every effect.
pub fn describe() -> String {
    let mut s =
        String::from("Techniques (scene files: technique = \"NAME\"; CLI: --technique NAME, --param KEY=VALUE):\n");
    s += "\nauto\n    the default: the engine chooses from the scene's requirements and the measured fronts (today shadowmaps for any lit scene, env without lights) and says so\n";
    for t in REGISTRY {
        s += &format!("\n{}\n    {}\n", t.name, t.summary);
        if t.static_only {
            s += "    static geometry only (refuses scenes whose objects move or deform)\n";
        }
        if t.rigid_only {
            s += "    rigid shadow casters only (refuses scenes whose shadow-casting objects deform)\n";
        }
        if !t.animated_environment {
            s += "    fixed environment lighting (refuses scenes whose [[environment.keys]] turn or dim it)\n";
        }
        match t.budget {
            Budget::RmseRelMean { rmse_rel_mean, source } => {
                s += &format!("    accuracy budget: RMSE / reference mean <= {rmse_rel_mean} ({source})\n")
            }
            Budget::Unbiased { factor, source } => {
                s += &format!("    accuracy budget: unbiased, noise <= {factor}x the reference's ({source})\n")
            }
            Budget::Baseline { source } => s += &format!("    accuracy budget: none ({source})\n"),
        }
        if t.params.is_empty() {
            s += "    parameters: none\n";
        } else {
            s += "    parameters:\n";
            for p in t.params {
                s += &format!(
                    "      {:<14} default {:<10} {:<28} {}\n",
                    p.key,
                    p.default,
                    format!("({})", p.range),
                    p.doc
                );
            }
        }
    }
    s += "\nEffects (added by what the scene contains):\n";
    for e in EFFECTS {
        s +=
            &format!("\n{}\n    {}\n    when: {}\n    methods: {}\n", e.name, e.summary, e.when, e.variants.join(", "));
    }
    s
}

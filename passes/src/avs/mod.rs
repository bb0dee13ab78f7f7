//! Adaptive visibility sampling with hemispherical distance transforms and SSDF shading (Wang,
//! Pan, Han, Chen and Bao, "Parallel and adaptive visibility sampling for rendering dynamic
//! scenes with spatially-varying reflectance"): technique `"avs"`.
//!
//! Per frame (all geometry dynamic, the kd-tree rebuilt when anything moved or deformed):
//! * **Candidate pool**: the world vertices of every instance (the paper's candidates), plus
//!   points on triangles larger than the pool spacing ([`PoolPlan`], `pool_points`): the paper's
//!   meshes have 21k-32k vertices, while a ground plane of two triangles offered no candidate
//!   where shadows fall (no shadows on `falling`, `balls_on_dish` and the medium scenes).
//! * **Initial sample points** (section 4.1), CPU: k-means over the pool with the geometric error
//!   `e_g` (eq. 6, [`penumbra_math::avs_sampling::kmeans_eg`]), the candidate nearest each
//!   centre. The set is kept across frames as pool indices, so sample points follow deforming and
//!   moving geometry; it is rebuilt only when the pool changes.
//! * **Adaptive spatial sampling** (4.3): the relative error `e_v(x_i, x_avg) / sum|c_i|` of every
//!   point against the eq. 8 interpolation of its neighbours' SH16 within the search radius,
//!   insertions above `E_v,max` (nearest vertex to the midpoint of a point and each neighbour it
//!   disagrees with) and erasures below `E_v,min` (no two neighbours in one round), on the CPU
//!   ([`penumbra_math::avs_sampling::adapt_step`]). A fresh set (first frame, changed pool) is
//!   refined by `first_iterations` rounds, every later frame by `iterations`. Where the rounds get
//!   the SH16 of the points they compare: `adaptation = cpu` (default) from 16 x 16 maps traced
//!   on the CPU through an `obvhs` BVH of the frame's triangles ([`cpu_sh16`]), so no round waits
//!   and the final set's maps are traced once, in the frame's own graph (building a frame never
//!   waits on the GPU); `adaptation = rounds`: from the GPU maps themselves (`avs_sh`), each
//!   round a small graph submitted and waited for (the paper's); `adaptation = late`: every
//!   frame traces its kept points in its own graph and copies their SH16 into a late readback
//!   (`Graph::create_late_readback`); a later frame steps once on the newest finished copy
//!   (`Engine::late_readback`, never waiting) and applies the step by pool vertex to its own set
//!   (see [`AvsSettings::late`] for what that costs). Measured at 160x120 over the 20 scenes avs
//!   accepts (session 24): `cpu` and `rounds` give the same errors within 0.003 rmse/mean
//!   (balls_on_dish 0.047 against 0.050), `cpu` in half the wall-clock on lavapipe (falling 10.0
//!   against 21.1 s per frame, hat_on_cloth 9.7 against 23.8), 10-250 ms of it on the CPU.
//! * **Adaptive angular sampling** (4.2), `avs_vis_l<L>` passes (`glsl/avs/avs_vis.comp`): one
//!   workgroup per sample point; level 0 traces the initial grid (16 x 16 or 32 x 32) with the
//!   kd-tree tracer, every further level doubles the resolution and traces only texels whose parent
//!   is a boundary texel (8-neighbourhood) in the point's own previous level or in one of its
//!   `ray_neighbours` nearest sample points' previous level at the same direction; the others copy
//!   the parent. Maps are 1 bit per texel in `penumbra_math::avs_maps`'s layout.
//! * **G-buffer culling** (section 6 "Optimization", `cull = true`): the `avs_cull` pass
//!   (`glsl/avs/avs_cull.comp`) runs the shading's neighbour search (`glsl/include/avs_gather.glsl`)
//!   per covered pixel over all kept points and sets their bits, copied into a late readback; a
//!   later frame takes the newest finished frame's bits and traces (and adapts, and transforms)
//!   only the flagged points and those inserted since, keeping the others dormant. The first frame
//!   traces the points inside the view frustum widened by the search radius. A point the
//!   adaptation erases in a culled frame goes dormant (the step saw only the traced subset), so
//!   the flags can bring it back.
//! * **HSDT** (section 5): [`crate::hsdt::Hsdt`] turns all maps into fp16 SSDFs.
//! * **Shading** (section 6), `avs_shade` (`glsl/avs/avs_shade.comp`): per pixel, the sample points
//!   within the search radius (CPU-built uniform grid) with the best eq. 8 weights, their SSDFs
//!   interpolated at any direction; environment as SG lobes, BRDFs as SG lobes from the
//!   (textured) materials; visibility of each product lobe by the SSDF at the lobe axis
//!   (`integration = "axis"`) or by integration over cells with iso-line boundaries
//!   (`integration = "cells"`); local lights shadowed by the SSDF toward them.
//!
//! Parameters (`[technique_params]` / `--param`), see [`AvsSettings::set`].

pub mod hemicube;

use crate::kdtree::{KdTreeBuilder, KdTreeHandles};
use crate::shade_env::HDR_FORMAT;
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{anyhow, bail, Result};
use glam::{Mat3, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{
    vk, Access, Bind, BufferHandle, Context, Engine, FrameStore, Graph, ImageHandle, LateReadback, PassKind,
};
use penumbra_math::avs_maps::{check_res, words_per_map};
use penumbra_math::avs_sampling::{self as samp, Grid, SurfacePoint, SH_COUNT};
use penumbra_scene::{Frame, Scene};
use std::sync::Arc;

/// `layout(constant_id = 0) AVS_MODE` of avs_shade.comp: the integration mode.
const AVS_MODE_CONSTANT_ID: u32 = 0;

/// avs_shade.comp's mode number of an integration (its `AVS_MODE`).
fn integration_mode(i: Integration) -> u32 {
    match i {
        Integration::Axis => 0,
        Integration::Cells => 1,
        Integration::Table => 2,
        Integration::Adf => 3,
    }
}

/// Visibility integration over the SSDF-bounded visible region.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Integration {
    /// SSDF at the lobe axis, straight boundary (Wang et al. 2009).
    Axis,
    /// Cells with iso-line boundaries (eq. 5, per cell).
    Cells,
    /// Part A's tabulated `T(lambda, d)` at the lobe axis (`glsl/include/ssdf_integrate.glsl`).
    Table,
    /// Part A's adaptive cells (`ssdf_visible_cells`) over a virtual map of the interpolated
    /// SSDF in the pixel's frame: slow (1.1 ms per pixel at 24x18 on lavapipe, 17 lobes), for
    /// tiny images. BROKEN ON LAVAPIPE, measured (bench avs, hat_on_cloth 24x18): 8.46 dB /
    /// relRMSE 0.791 against 17.70 dB / 0.422 for `axis`. Cause (issue 8, session 4): lavapipe
    /// ends every loop of a shader invocation once its loops have run 65535 iterations in total
    /// (see `glsl/avs/avs_vis.comp`), and one pixel's quadtree walks (with the neighbour loop of each
    /// virtual-texel fetch) need more: a loop-count probe at the end of `avs_shade` found the limit
    /// hit on all 272 shaded pixels of hat_on_cloth 24x18 (r = 64, 240 points), and on 192 of them
    /// with only the first lighting lobe integrated, so every later loop (lobes, quadtree, lights)
    /// stopped after one iteration. Fully free / occluded maps need few iterations (exact there).
    /// A fix needs the integral split over invocations (per lobe and per block of the quadtree).
    Adf,
}

/// Parameters with the paper's defaults, except where measurement chose another (`r`).
#[derive(Clone, Debug, PartialEq)]
pub struct AvsSettings {
    /// Visibility map resolution r (paper: 128; 64 and 256 evaluated). Default 32 since session
    /// 37: on all 24 scenes of the accuracy matrix at 160x120, r = 32 measured within 0.001
    /// rmse/mean of r = 128 (the sharp parts of the lighting, key lights and local lights, are
    /// shadowed by rays, and the SSDFs carry the smooth rest) at 4-13x less time per frame on
    /// lavapipe (README, `avs`); `r = 128` is the paper's.
    pub r: u32,
    /// Initial ray grid per side (paper: 16, some scenes 32).
    pub initial_grid: u32,
    /// E_v,max, relative spatial error above which points are inserted (paper: 0.10).
    pub e_max: f32,
    /// E_v,min, relative spatial error below which points may be erased (paper: 0.05).
    pub e_min: f32,
    /// alpha of e_g after normalising the scene scale (paper: 0.1 - 0.5).
    pub alpha: f32,
    /// Spatial adaptation rounds per frame (0: the initial points only, in every frame). With
    /// [`AvsSettings::late`], any value above 0 means one step per frame from the newest finished
    /// frame's maps.
    pub iterations: u32,
    /// How the spatial adaptation (4.3) gets the SH of the maps it compares (with
    /// [`AvsSettings::cpu`] false). `false` (`adaptation = "rounds"`): `iterations` rounds in
    /// every frame, each a submission waited for before the frame's graph (the CPU needs the new
    /// maps' SH): building the frame waits on the GPU. `true` (`"late"`): frames never wait. Each frame traces its kept points
    /// in its own graph and copies their SH16 into a late readback; a later frame takes the
    /// newest finished copy and runs one `adapt_step` on it (erasing and inserting by pool
    /// vertex, leaving alone what later steps changed), so the set refines one step per frame, a
    /// frame or two behind; only a fresh k-means set (the first frame, or a changed pool) is
    /// refined by `first_iterations` waited rounds before its frame, as setup. Not the default:
    /// half the steps on older maps lose accuracy where things move (160x120, seven frames:
    /// falling 0.124 against 0.078 rmse/mean, hat_on_cloth 0.093 against 0.078) for about 10%
    /// less wall-clock on lavapipe. [`AvsSettings::cpu`] (the default) never waits either,
    /// without that cost.
    pub late: bool,
    /// `adaptation = "cpu"` (default): every round of the spatial adaptation on the CPU, so that building
    /// the frame never waits on the GPU and the set refines fully every frame: the SH16 that
    /// the error metric compares come from a `cpu_grid` x `cpu_grid` visibility map per point
    /// traced through the frame's triangles in an `obvhs` BVH ([`crate::trace::CpuBvh`], all
    /// cores) instead of the GPU maps read back; the final set's maps are traced in the frame's
    /// own graph. The metric sees a coarser map than the r x r one the shading interpolates
    /// (order-4 SH are smooth; the GPU's first level is the same 16 x 16 grid).
    pub cpu: bool,
    /// Side of the CPU maps of `adaptation = "cpu"` (multiple of 8, 8..=64; default 16).
    pub cpu_grid: u32,
    /// Rounds of the frame that starts from a fresh initial set (the first frame, or a changed
    /// pool): the kept set carries every later frame's refinement on, while a fresh one starts
    /// from k-means points alone (the paper's Figure 5 shows several rounds to settle; chess at
    /// 160x120 after two frames of two rounds: black halos and missing key-light shadows).
    pub first_iterations: u32,
    /// alpha of the eq. 8 weights of the per-pixel interpolation, with positions divided by the
    /// search radius (not the scene scale): 0 uses `alpha` with the scene scale (the paper's
    /// form, default; on coarse meshes it weighs a point across a hat brim almost like the one
    /// next to the pixel).
    pub interp_alpha: f32,
    /// Initial sample points (k of k-means); 0: one per 4 vertices and one per 16 extra pool
    /// candidates ([`PoolPlan`]), between 16 and 2048 (the
    /// paper ends at 6-11% of 21k-32k vertices; the built-in scenes have 1k-3k vertices, and with
    /// one per 16 the search radius spans the hat brim).
    pub points: usize,
    /// Upper bound on sample points after insertions.
    pub max_points: usize,
    /// Extra candidate points on triangles larger than the pool spacing (see [`PoolPlan`]):
    /// about this many over the scene's surface area (0: the mesh vertices only, the paper's
    /// pool).
    pub pool_points: usize,
    /// Search radius as a multiple of the initial points' mean nearest-neighbour distance.
    pub radius: f32,
    /// Sample points interpolated per pixel (the best eq. 8 weights within the radius, <= 8).
    pub neighbours: u32,
    /// Neighbouring sample points whose previous-level maps also mark boundary rays (0: off).
    pub ray_neighbours: u32,
    /// Adaptive angular sampling (false: only the final level runs, every texel traced: r^2 rays
    /// a map, the brute-force baseline of the bench).
    pub adaptive: bool,
    /// Keep an occluded parent's hit when the refinement's four child rays all miss it (one child
    /// stays occluded when the parent's centre ray, or for an already kept parent its corner ray,
    /// confirms the occluder; not in the paper: slim occluders thinner than a child cell).
    pub keep_hits: bool,
    /// Integration mode.
    pub integration: Integration,
    /// Cells per side of the lobe neighbourhood (integration = cells).
    pub cells: u32,
    /// False: visibility 1 (separates shading from visibility error).
    pub shadows: bool,
    /// Specular Gamma_L from SG-prefiltered environment maps (true) or the lighting lobes.
    pub prefiltered: bool,
    /// Diffuse environment term: the map's exact irradiance (`lighting::irradiance_env`) times
    /// the visible share of the SG lobes' irradiance (`true`, a ratio estimator), or the SG lobes
    /// alone (`false`, the paper's: the 16-lobe fit's error, 5% too bright on the floor of
    /// `falling`, stays in every unshadowed pixel).
    pub diffuse_ratio: bool,
    /// Glossy environment term: the material model's unshadowed glossy term (the `env`
    /// technique's filtered importance sampling, `env_glossy` in `glsl/include/env_shade.glsl`)
    /// times the light-weighted SSDF visibility of the specular lobe (`true`, a ratio estimator:
    /// sum_k e_k V_k / sum_k e_k over the lighting lobes and key lights, e_k a light's share of
    /// the lobe; a lobe sharper than lambda 256 its own visible fraction), or the one SG lobe of
    /// the BRDF (`false`, the paper's: it loses the lobe's Fresnel and masking energy).
    pub glossy_ratio: bool,
    /// Lighting SG lobes.
    pub lobes: usize,
    /// G-buffer culling (section 6 "Optimization"): trace only the sample points that some
    /// covered pixel of an earlier frame needed (flags written by the `avs_cull` pass, taken from
    /// the newest finished frame, never waited for); the first frame traces the view frustum's.
    pub cull: bool,
    /// Local lights' shadows by shadow rays through the frame's kd-tree (`true`, default) or by
    /// the sign of the interpolated SSDF toward the light (`false`). The paper lights by the
    /// environment only; a point or spot light's hard shadow is finer than visibility maps
    /// interpolated between sample points (vol_rotating 160x120: the spot light's square shadow
    /// of the cube drawn as a blob).
    pub traced_lights: bool,
    /// With `traced_lights`: the environment's compact bright lights (its sun, a studio's key
    /// light: [`crate::lighting::split_key_lights`]) split off the map as at most this many
    /// moment-matched SG lights whose diffuse light is shadowed by 9 rays each through the frame's
    /// kd-tree, the rest of the map lit through the SSDFs as before (0: the whole map through the
    /// SSDFs, the paper's). A sun's shadow is as sharp as a spot light's and finer than maps
    /// interpolated between sample points a few pixels apart (chess, sf_statues at 160x120: its
    /// long shadows drawn as blotches). The glossy term stays the whole map's glossy term times
    /// the lobe's SSDF visibility, the key lights among the lights that weigh it (`glossy`).
    pub key_lights: usize,
    /// How many of a key light's rays a pixel traces (`key_rays`). `predicted` (default): where
    /// the interpolated SSDF puts the nearest visibility boundary farther from the light's axis
    /// than the light's disk plus two texels (the light wholly seen, or wholly hidden), the
    /// centre ray alone, and the whole disk only where that ray disagrees; elsewhere the disk.
    /// `all`: the disk's rays everywhere (its centre and outer ring, the inner ring in a penumbra).
    pub key_rays_predicted: bool,
    /// Where a key light's rays point (`key_pattern`): `fixed` (default), lights.glsl's disk
    /// pattern in every pixel (flat bands in a penumbra), or `stratified`, each ray at a point of
    /// its own equal-area cell of the disk drawn per pixel (grain around the disk's integral:
    /// closer to the reference's look, more error against it; see README).
    pub key_pattern_stratified: bool,
    /// A key light's share inside a penumbra (`key_penumbra`): `rays` (default), the disk's 9
    /// rays' share; `refine`, where they disagree, 16 more in equal-area cells of the disk at
    /// points drawn per shading point, the share of all 25 (9 flat steps, streaks under a wide
    /// light, become 25 finer ones with a little grain, at the cost of 16 rays per penumbra
    /// pixel: see README).
    pub key_penumbra_refine: bool,
    /// The key lights' diffuse light filtered over the screen (`key_filter`: the largest window
    /// radius in pixels, 4; 0 off): each pixel's visible share of them averaged with a Gaussian
    /// as wide as a sixteenth of its penumbra (the lights' angular radius times the distance to
    /// what their rays hit, in pixels), over neighbours on its surface
    /// (`glsl/avs/avs_key_filter.comp`); where the 3 x 3 neighbourhood's rays all agree, and at
    /// contact, nothing is filtered. The fixed pattern's bands in a wide penumbra blur out (the
    /// walking man at 640x480 0.0659 -> 0.0595 rmse/mean); with `key_pattern = stratified` the
    /// grain does (0.0591). See README.
    pub key_filter: u32,
    /// Read the final visibility maps back into [`AvsStats::maps`] (one more copy per adaptation
    /// round; for tests comparing maps texel by texel).
    pub capture_maps: bool,
}

impl Default for AvsSettings {
    fn default() -> Self {
        AvsSettings {
            r: 32,
            initial_grid: 16,
            e_max: 0.10,
            e_min: 0.05,
            alpha: 0.3,
            iterations: 2,
            late: false,
            cpu: true,
            cpu_grid: 16,
            first_iterations: 8,
            interp_alpha: 0.0,
            points: 0,
            max_points: 4096,
            pool_points: 4096,
            radius: 2.0,
            neighbours: 6,
            ray_neighbours: 4,
            adaptive: true,
            keep_hits: true,
            integration: Integration::Axis,
            cells: 6,
            shadows: true,
            prefiltered: true,
            diffuse_ratio: true,
            glossy_ratio: true,
            lobes: 16,
            cull: true,
            traced_lights: true,
            key_lights: 4,
            key_rays_predicted: true,
            key_pattern_stratified: false,
            key_penumbra_refine: false,
            key_filter: 4,
            capture_maps: false,
        }
    }
}

impl AvsSettings {
    /// Defaults with `params` applied.
    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> Result<Self> {
        let s: Self = crate::technique::settings_from_params(params, Self::set)?;
        s.validate()?;
        Ok(s)
    }

    /// Sets one parameter. Keys: `r` (32, the paper's 128; multiple of the initial grid times a power of two, at
    /// most 256), `initial_grid` (16 or 32), `e_max` (0.10), `e_min` (0.05), `alpha` (0.3), `interp_alpha` (0 = the paper's form),
    /// `iterations` (2), `adaptation` (`rounds` | `late` | `cpu`), `cpu_grid` (16), `first_iterations` (8), `points` (0 = auto), `max_points` (4096; lowered to what the device binds, see `AvsTechnique::new`), `pool_points` (4096), `radius` (2.0), `neighbours`
    /// (6, 1..8), `ray_neighbours` (4, 0..8), `integration` (`axis` | `cells` | `table` | `adf`), `cells` (6,
    /// 1..16), `shadows`, `adaptive`, `keep_hits`, `prefiltered`, `cull`, `capture_maps` (true/false), `diffuse` (`ratio` | `sg`), `glossy` (`ratio` | `sg`), `lobes` (16), `light_shadows` (`traced` | `ssdf`), `key_lights` (4, 0..16), `key_rays` (`predicted` | `all`), `key_pattern` (`fixed` | `stratified`), `key_penumbra` (`rays` | `refine`), `key_filter` (4, 0..8). Unknown keys and bad values
    /// are errors naming the key.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("avs", key, value);
        let float = |lo: f32, hi: f32| p.float(lo as f64, hi as f64).map(|x| x as f32);
        let int = |lo: u64, hi: u64| p.int(lo, hi);
        let ratio_or_sg = [("ratio", true), ("sg", false)];
        match p.key() {
            "r" => self.r = int(8, 256)? as u32,
            "initial_grid" => self.initial_grid = int(16, 32)? as u32,
            "e_max" => self.e_max = float(0.0, 100.0)?,
            "e_min" => self.e_min = float(0.0, 100.0)?,
            "alpha" => self.alpha = float(0.0, 100.0)?,
            "interp_alpha" => self.interp_alpha = float(0.0, 100.0)?,
            "iterations" => self.iterations = int(0, 16)? as u32,
            "first_iterations" => self.first_iterations = int(0, 64)? as u32,
            "adaptation" => {
                (self.late, self.cpu) =
                    p.choice(&[("rounds", (false, false)), ("late", (true, false)), ("cpu", (false, true))])?
            }
            "cpu_grid" => {
                self.cpu_grid = int(8, 64)? as u32;
                if !self.cpu_grid.is_multiple_of(8) {
                    return Err(p.bad("a multiple of 8 in 8..=64"));
                }
            }
            "points" => self.points = int(0, 1 << 16)? as usize,
            "max_points" => self.max_points = int(1, 1 << 16)? as usize,
            "pool_points" => self.pool_points = int(0, 1 << 18)? as usize,
            "radius" => self.radius = float(0.01, 100.0)?,
            "neighbours" => self.neighbours = int(1, 8)? as u32,
            "ray_neighbours" => self.ray_neighbours = int(0, 8)? as u32,
            "integration" => {
                self.integration = p.choice(&[
                    ("axis", Integration::Axis),
                    ("cells", Integration::Cells),
                    ("table", Integration::Table),
                    ("adf", Integration::Adf),
                ])?
            }
            "cells" => self.cells = int(1, 16)? as u32,
            "shadows" => self.shadows = p.flag()?,
            "adaptive" => self.adaptive = p.flag()?,
            "keep_hits" => self.keep_hits = p.flag()?,
            "prefiltered" => self.prefiltered = p.flag()?,
            "diffuse" => self.diffuse_ratio = p.choice(&ratio_or_sg)?,
            "glossy" => self.glossy_ratio = p.choice(&ratio_or_sg)?,
            "lobes" => self.lobes = int(1, 64)? as usize,
            "cull" => self.cull = p.flag()?,
            "light_shadows" => self.traced_lights = p.choice(&[("traced", true), ("ssdf", false)])?,
            "key_lights" => self.key_lights = int(0, 16)? as usize,
            "key_rays" => self.key_rays_predicted = p.choice(&[("predicted", true), ("all", false)])?,
            "key_pattern" => self.key_pattern_stratified = p.choice(&[("fixed", false), ("stratified", true)])?,
            "key_penumbra" => self.key_penumbra_refine = p.choice(&[("rays", false), ("refine", true)])?,
            "key_filter" => self.key_filter = int(0, 8)? as u32,
            "capture_maps" => self.capture_maps = p.flag()?,
            _ => return Err(p.unknown("r, initial_grid, e_max, e_min, alpha, interp_alpha, iterations, adaptation, first_iterations, points, max_points, pool_points, radius, neighbours, ray_neighbours, integration, cells, shadows, adaptive, keep_hits, prefiltered, diffuse, glossy, lobes, cull, light_shadows, key_lights, key_rays, key_pattern, key_penumbra, key_filter, capture_maps")),
        }
        Ok(())
    }

    /// Checks the combination of parameters.
    pub fn validate(&self) -> Result<()> {
        check_res(self.r).map_err(|e| anyhow!("avs parameter r: {e}"))?;
        if self.initial_grid != 16 && self.initial_grid != 32 {
            bail!("avs parameter initial_grid = {}: expected 16 or 32", self.initial_grid);
        }
        if self.r < self.initial_grid
            || !(self.r / self.initial_grid).is_power_of_two()
            || !self.r.is_multiple_of(self.initial_grid)
        {
            bail!(
                "avs parameter r = {}: must be the initial grid ({}) times a power of two",
                self.r,
                self.initial_grid
            );
        }
        if self.e_min > self.e_max {
            bail!("avs parameters e_min = {} > e_max = {}", self.e_min, self.e_max);
        }
        Ok(())
    }

    /// Levels of the angular refinement (initial grid, then doublings up to r).
    pub fn levels(&self) -> u32 {
        (self.r / self.initial_grid).trailing_zeros() + 1
    }
}

/// Statistics of the last frame (for tests and the bench).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AvsStats {
    /// Candidates of the pool (world vertices and extra points, see [`PoolPlan`]).
    pub vertices: usize,
    /// The pool's plan: `vertex_pool(scene, frame, &stats.pool_plan)` is the pool that
    /// `point_vertices` index.
    pub pool_plan: Arc<PoolPlan>,
    /// Initial sample points (k-means).
    pub initial_points: usize,
    /// Sample points after the spatial adaptation.
    pub points: usize,
    /// Points inserted / erased per adaptation round.
    pub inserted: Vec<usize>,
    pub erased: Vec<usize>,
    /// Mean relative spatial error of the last round (points with neighbours).
    pub mean_rel_error: f32,
    /// Per-pixel search radius of the last frame (world units).
    pub radius: f32,
    /// Rays traced for the final maps, summed over the points (when read back).
    pub rays: u64,
    /// Bytes of visibility maps and SSDFs.
    pub map_bytes: u64,
    pub ssdf_bytes: u64,
    /// Pool vertex of every sample point (index into the frame's vertex pool).
    pub point_vertices: Vec<usize>,
    /// Visible fraction of the hemisphere of every sample point (from the SH16 DC term).
    pub visible_fraction: Vec<f32>,
    /// Sample points buried (every direction occluded: `penumbra_math::avs_sampling::buried`):
    /// out of the adaptation, interpolated only where they are clearly a pixel's nearest. With
    /// `adaptation = cpu`, counted from the rounds' CPU maps (the shading flags them from the
    /// frame's own GPU maps).
    pub buried: usize,
    /// GPU milliseconds of the adaptation rounds' passes (name, ms), when timed.
    pub round_ms: Vec<(String, f64)>,
    /// Sample points kept but not traced this frame (G-buffer culling: no covered pixel of the
    /// previous frame needed them).
    pub dormant: usize,
    /// Pool vertices of the maps that `visible_fraction`, `buried`, `rays`, `truncated` and `maps`
    /// describe: this frame's points with `adaptation = rounds` (and on a setup frame); with the
    /// late adaptation, those of the newest frame the GPU had finished when this one was built.
    pub late_vertices: Vec<usize>,
    /// Pool vertex of every kept point at the end of the frame, traced then dormant (culling:
    /// erased points go dormant, so no vertex leaves this set while the pool stays the same).
    pub kept_vertices: Vec<usize>,
    /// Visibility maps traced this frame, summed over the adaptation rounds.
    pub traced_points: usize,
    /// Wall-clock ms of the frame's parts in `add`, in order: `pool` (the candidates at this
    /// frame's poses), `kmeans` (initial points, when the pool changed), `cull` (applying the
    /// newest finished frame's flags), then on a frame with waited rounds (setup, or `adaptation
    /// = rounds`) `rounds_wait` (the rounds' submissions waited for: tree build, tracing, SH
    /// projection), `rounds_step` (their `adapt_step`: range searches, errors, candidates),
    /// `rounds_cpu` (the rest of their CPU work: spacing checks of the insertions, erasures,
    /// slots), or on a late frame `late_step` (its one `adapt_step` and the set's update), and
    /// `shading_prep` (the frame's passes: neighbour grids and uploads).
    pub cpu_ms: Vec<(&'static str, f64)>,
    /// Wall-clock ms of the adaptation rounds' waits for their submissions (in `cpu_ms` as
    /// `rounds_wait`).
    pub(crate) rounds_wait_ms: f64,
    /// Wall-clock ms of the rounds' `adapt_step` calls (range searches and errors; in `cpu_ms`
    /// as `rounds_step`, the rest of their CPU work as `rounds_cpu`).
    pub(crate) rounds_step_ms: f64,
    /// Maps (summed over the rounds) whose visibility pass hit the driver's per-invocation loop
    /// limit (lavapipe: 65535 loop iterations, then every loop ends early; see avs_vis.comp):
    /// their untraced texels are wrong (occluded). 0 unless a chunk's rays need that many kd-tree
    /// steps.
    pub truncated: usize,
    /// The final packed visibility map of every sample point (`words_per_map(r)` words each, in
    /// the order of `point_vertices`), only with [`AvsSettings::capture_maps`] (tests).
    pub maps: Vec<Vec<u32>>,
}

impl AvsStats {
    /// Records the ms since `clock` under `name` in [`AvsStats::cpu_ms`] and restarts the clock.
    fn lap(&mut self, clock: &mut std::time::Instant, name: &'static str) {
        let now = std::time::Instant::now();
        self.cpu_ms.push((name, (now - *clock).as_secs_f64() * 1e3));
        *clock = now;
    }
}

/// Late readback (see `Graph::create_late_readback`) of the culling flags of a frame's kept points.
const LATE_USED: &str = "avs.used";
/// Late readback of a frame's SH16 per traced point, then its ray counts.
const LATE_SH: &str = "avs.sh";
/// Late readback of a frame's final maps (`capture_maps`).
const LATE_MAPS: &str = "avs.maps";
/// Frames whose point orders are kept to read their late readbacks.
const LATE_FRAMES: usize = 6;

/// Records `order` (pool vertices) as frame `frame`'s, keeping the last [`LATE_FRAMES`] frames
/// (a frame that failed to submit left its number to the next one, which replaces it).
fn push_recent(list: &mut Vec<(u64, Vec<usize>)>, frame: u64, order: Vec<usize>) {
    list.retain(|(f, _)| *f != frame);
    list.push((frame, order));
    if list.len() > LATE_FRAMES {
        list.remove(0);
    }
}

/// A readback of `n` points' SH16 followed by their ray counts (`add_sh_copy`'s layout): the
/// SH per point, the rays in all and the maps whose tracing hit the driver's loop limit (bit 31
/// of a count). `None` when it is shorter than that.
fn parse_sh_readback(bytes: &[u8], n: usize) -> Option<(Vec<[f32; SH_COUNT]>, u64, usize)> {
    if bytes.len() < n * (SH_COUNT + 1) * 4 {
        return None;
    }
    let word = |i: usize| f32::from_le_bytes([bytes[4 * i], bytes[4 * i + 1], bytes[4 * i + 2], bytes[4 * i + 3]]);
    let sh = (0..n).map(|e| std::array::from_fn(|k| word(e * SH_COUNT + k))).collect();
    let (mut rays, mut truncated) = (0u64, 0usize);
    for e in 0..n {
        let w = word(n * SH_COUNT + e).to_bits();
        rays += (w & 0x7fff_ffff) as u64;
        truncated += (w >> 31) as usize;
    }
    Some((sh, rays, truncated))
}

/// One packed visibility map read back (little-endian words).
fn map_words(bytes: &[u8]) -> Vec<u32> {
    bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
}

/// Part A's `T(lambda, d)` table as f32 bytes (generated per technique that integrates by table).
fn axis_table() -> Arc<Vec<u8>> {
    Arc::new(bytes_of(&penumbra_math::ssdf_integrate::AxisTable::generate(|_| {}).data))
}

/// Where the candidate pool places surface points besides the mesh vertices. The paper selects
/// sample points among vertices (section 4.1) of meshes with 21k-32k vertices; a coarse mesh (a
/// ground plane of two triangles) leaves the spatial sampling no candidate where its shadows are,
/// so triangles larger than the pool spacing get extra candidates, as if the mesh were refined:
/// `n - 1` points along each edge of length `L > h` (`n = ceil(L / h)`) and the interior points
/// of the triangle's barycentric grid with `n = ceil(longest edge / h)`. The plan is made once
/// (spacing and counts) and reused every frame, so the pool keeps its indices while objects move
/// or deform and its points follow them (barycentric on the frame's vertices).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoolPlan {
    /// Spacing `h` of the extra candidates (world units; 0: vertices only).
    pub spacing: f32,
    /// Per instance (in `Frame::instances` order).
    insts: Vec<InstPlan>,
    /// Candidates in all: vertices plus extra points.
    pub len: usize,
    /// Extra (non-vertex) candidates.
    pub extra: usize,
}

#[derive(Clone, Debug, Default, PartialEq)]
struct InstPlan {
    vertices: usize,
    /// (a, b, n): `n - 1` points along edge a-b.
    edges: Vec<[u32; 3]>,
    /// (i0, i1, i2, n): interior points of the triangle's n-grid.
    tris: Vec<[u32; 4]>,
}

/// The mesh of instance `inst` at this frame (deformed or rest) and its object's name.
fn instance_mesh<'a>(
    scene: &'a Scene,
    inst: &'a penumbra_scene::Instance,
) -> Result<(&'a penumbra_scene::MeshData, &'a str)> {
    let name = scene.objects.get(inst.object).map(|o| o.name.as_str()).unwrap_or("?");
    let mesh = match inst.deformed_mesh.as_deref() {
        Some(m) => m,
        None => scene.meshes.get(inst.mesh).ok_or_else(|| anyhow!("object '{name}' refers to a missing mesh"))?,
    };
    Ok((mesh, name))
}

impl PoolPlan {
    /// Vertices only.
    pub fn vertices_only(scene: &Scene, frame: &Frame) -> Result<Self> {
        Self::new(scene, frame, 0)
    }

    /// A plan adding about `extra` candidates: `h = sqrt(A / extra)` for the frame's total world
    /// triangle area `A`, so surfaces whose own vertices are denser than `h` get none.
    pub fn new(scene: &Scene, frame: &Frame, extra: usize) -> Result<Self> {
        let mut world: Vec<(Vec<Vec3>, &[u32])> = Vec::new();
        let mut area = 0.0f64;
        for inst in &frame.instances {
            let (mesh, _) = instance_mesh(scene, inst)?;
            let pos: Vec<Vec3> = mesh.positions.iter().map(|p| inst.world.transform_point3(*p)).collect();
            for t in mesh.indices.chunks_exact(3) {
                let [a, b, c] = [t[0], t[1], t[2]].map(|i| pos.get(i as usize).copied().unwrap_or(Vec3::ZERO));
                let x = 0.5 * (b - a).cross(c - a).length() as f64;
                if x.is_finite() {
                    area += x;
                }
            }
            world.push((pos, &mesh.indices));
        }
        let h = if extra > 0 && area > 0.0 { (area / extra as f64).sqrt() as f32 } else { 0.0 };
        let mut plan = PoolPlan { spacing: h, ..Default::default() };
        for (pos, indices) in &world {
            let mut ip = InstPlan { vertices: pos.len(), ..Default::default() };
            let segs = |l: f32| if h > 0.0 && l.is_finite() && l > h { (l / h).ceil().min(4096.0) as u32 } else { 1 };
            let mut seen = std::collections::HashSet::new();
            for t in indices.chunks_exact(3) {
                if t.iter().any(|&i| i as usize >= pos.len()) {
                    continue;
                }
                let mut longest = 0.0f32;
                for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                    let l = (pos[a as usize] - pos[b as usize]).length();
                    longest = longest.max(if l.is_finite() { l } else { 0.0 });
                    let key = (a.min(b), a.max(b));
                    if a != b && seen.insert(key) && segs(l) > 1 {
                        ip.edges.push([key.0, key.1, segs(l)]);
                    }
                }
                // the grid's n from the longest edge, capped by the area (an equilateral
                // triangle of side n h has area 0.43 (n h)^2): a sliver gets its edge points only
                let (a, b, c) = (pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
                let tri_area = 0.5 * (b - a).cross(c - a).length();
                let n = if tri_area > 0.0 { segs(longest).min(segs((2.5 * tri_area).sqrt())) } else { 1 };
                // interior points need n >= 3; degenerate triangles get none
                if n >= 3 {
                    ip.tris.push([t[0], t[1], t[2], n]);
                }
            }
            plan.extra += ip.edges.iter().map(|e| e[2] as usize - 1).sum::<usize>()
                + ip.tris.iter().map(|t| ((t[3] - 1) * (t[3] - 2) / 2) as usize).sum::<usize>();
            plan.len += ip.vertices;
            plan.insts.push(ip);
        }
        plan.len += plan.extra;
        Ok(plan)
    }

    /// Whether the plan was made for this frame's instances (same count, same vertex counts).
    pub fn fits(&self, scene: &Scene, frame: &Frame) -> bool {
        self.insts.len() == frame.instances.len()
            && self
                .insts
                .iter()
                .zip(&frame.instances)
                .all(|(p, i)| instance_mesh(scene, i).is_ok_and(|(m, _)| m.positions.len() == p.vertices))
    }
}

/// The frame's candidate pool: world positions and normals of every instance's vertices, then the
/// plan's extra points (see [`PoolPlan`]), in a fixed order.
pub fn vertex_pool(scene: &Scene, frame: &Frame, plan: &PoolPlan) -> Result<Vec<SurfacePoint>> {
    if !plan.insts.is_empty() && !plan.fits(scene, frame) {
        bail!("avs: the candidate plan was made for other meshes than this frame's");
    }
    let mut out = Vec::with_capacity(plan.len);
    let mut extra = Vec::with_capacity(plan.extra);
    for (k, inst) in frame.instances.iter().enumerate() {
        let (mesh, name) = instance_mesh(scene, inst)?;
        let m3 = Mat3::from_mat4(inst.world);
        let nm = if m3.determinant().abs() > 1e-20 { m3.inverse().transpose() } else { m3 };
        let has_n = mesh.normals.len() == mesh.positions.len();
        let first = out.len();
        for (i, p) in mesh.positions.iter().enumerate() {
            let pos = inst.world.transform_point3(*p);
            let n = if has_n { (nm * mesh.normals[i]).normalize_or_zero() } else { Vec3::ZERO };
            let n = if n == Vec3::ZERO || !n.is_finite() { Vec3::Y } else { n };
            if !pos.is_finite() {
                bail!("object '{name}' has non-finite vertices");
            }
            out.push(SurfacePoint { pos, normal: n });
        }
        let Some(ip) = plan.insts.get(k) else { continue };
        let v = &out[first..];
        // a point at barycentric weights w of vertices idx: position, and the weighted vertex
        // normals (the face normal where they cancel or are missing)
        let at = |idx: &[u32], w: &[f32]| {
            let pos = idx.iter().zip(w).fold(Vec3::ZERO, |s, (&i, &x)| s + v[i as usize].pos * x);
            let mut n = if has_n {
                idx.iter().zip(w).fold(Vec3::ZERO, |s, (&i, &x)| s + v[i as usize].normal * x).normalize_or_zero()
            } else {
                Vec3::ZERO
            };
            if n == Vec3::ZERO && idx.len() == 3 {
                let [a, b, c] = [0, 1, 2].map(|j| v[idx[j] as usize].pos);
                n = (b - a).cross(c - a).normalize_or_zero();
            }
            if n == Vec3::ZERO {
                n = v[idx[0] as usize].normal;
            }
            SurfacePoint { pos, normal: n }
        };
        for &[a, b, n] in &ip.edges {
            for j in 1..n {
                let x = j as f32 / n as f32;
                extra.push(at(&[a, b], &[1.0 - x, x]));
            }
        }
        for &[a, b, c, n] in &ip.tris {
            for i in 1..n {
                for j in 1..n - i {
                    let (u, w) = (i as f32 / n as f32, j as f32 / n as f32);
                    extra.push(at(&[a, b, c], &[1.0 - u - w, u, w]));
                }
            }
        }
    }
    out.extend(extra);
    Ok(out)
}

/// The six planes `(n, d)` of a view-projection matrix's frustum (Gribb-Hartmann, Vulkan depth
/// 0..1), normalised: `n.p + d >= 0` inside.
fn frustum_planes(m: glam::Mat4) -> [glam::Vec4; 6] {
    let (r0, r1, r2, r3) = (m.row(0), m.row(1), m.row(2), m.row(3));
    [r3 + r0, r3 - r0, r3 + r1, r3 - r1, r2, r3 - r2].map(|p| {
        let l = p.truncate().length();
        if l > 0.0 && l.is_finite() {
            p / l
        } else {
            glam::Vec4::new(0.0, 0.0, 0.0, 1.0)
        }
    })
}

/// Offset of the visibility rays' origins along the sample point's normal for the frame's
/// vertex pool (ten kd-tree ray epsilons of the scene extent).
pub fn ray_offset(pool: &[SurfacePoint]) -> f32 {
    let extent = pool.iter().fold(1.0f32, |m, p| m.max(p.pos.abs().max_element()));
    crate::kdtree::ray_epsilon(extent) * 10.0
}

/// Mean distance from each point to its nearest other point (a tenth of the bounding-box
/// diagonal for fewer than two points).
pub fn mean_spacing(pos: &[Vec3]) -> f32 {
    let g = Grid::new(pos, 0.0);
    let mut sum = 0.0f64;
    let mut cnt = 0usize;
    for (i, p) in pos.iter().enumerate() {
        let mut best = f32::MAX;
        for ring in 0..4 {
            g.visit_ring(*p, ring, |j, d2| {
                if j != i && d2 < best * best {
                    best = d2.sqrt();
                }
            });
        }
        if best < f32::MAX {
            sum += best as f64;
            cnt += 1;
        }
    }
    if cnt > 0 {
        (sum / cnt as f64) as f32
    } else {
        samp::scene_scale(pos) * 0.1
    }
}

/// A pixel's world size at a point, at its distance from the frame's eye (`image_height` pixels
/// over the vertical field of view): no insertion goes closer to a sample point than that.
fn pixel_spacing(frame: &Frame, image_height: u32) -> impl Fn(Vec3) -> f32 {
    let cam = &frame.camera;
    let per_distance = 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / image_height.max(1) as f32;
    let eye = cam.eye;
    move |p: Vec3| per_distance * (p - eye).length()
}

/// SH16 of the visibility of `p` from a `grid` x `grid` map in the GPU maps' layout and frame
/// (`samp::point_frame`), its rays leaving the point `offset` along the normal as
/// `avs_vis.comp` casts them, any hit through `bvh` occluding: `adaptation = cpu`'s maps.
pub fn cpu_sh16(bvh: &crate::trace::CpuBvh, p: &SurfacePoint, offset: f32, grid: u32) -> [f32; SH_COUNT] {
    let f = samp::point_frame(p.normal);
    let o = p.pos + f.n.as_vec3() * offset;
    let map = penumbra_math::avs_maps::VisMap::from_fn(grid, |i, j| {
        let d = f.to_world(penumbra_math::avs_maps::texel_dir(i, j, grid)).as_vec3();
        !bvh.occluded(&crate::trace::Ray::new(o, d, 0.0, 1e30))
    });
    samp::sh16_project(&map, &f)
}

/// GPU layout of the sample points: 3 vec4 per point (position, ray offset), (tangent, 1),
/// (normal, 0).
pub fn point_data(points: &[SurfacePoint], offset: f32) -> Vec<[f32; 4]> {
    let mut out = Vec::with_capacity(points.len() * 3);
    for p in points {
        let f = samp::point_frame(p.normal);
        let (t, n) = (f.t.as_vec3(), f.n.as_vec3());
        out.push([p.pos.x, p.pos.y, p.pos.z, offset]);
        out.push([t.x, t.y, t.z, 1.0]);
        out.push([n.x, n.y, n.z, 0.0]);
    }
    if out.is_empty() {
        out = vec![[0.0; 4]; 3];
    }
    out
}

/// The grid buffer `avs_shade.comp` and `avs_cull.comp` read (`avs_gather.glsl`): two levels
/// over the same points, each a header (dims, lower corner, cell edge, where its slots start),
/// its cell starts and its slots: `grid` (cell edge: the search radius) for the gather's passes
/// at 1 and 2.5 radii, and one of [`COARSE_CELLS`] times its cell edge (word 3 of the first
/// header: where the second starts) for the passes at 5 and 10 radii, where the points lie
/// farther apart than the radius (a big floor beside a finely meshed object), so that those scan
/// a few coarse cells instead of thousands of fine ones.
pub fn grid_words(grid: &Grid, slots: &[u32]) -> Vec<u32> {
    let mut out = grid_level_words(grid, slots, 0);
    let coarse = Grid::new(grid.points(), grid.cell * COARSE_CELLS);
    out[3] = out.len() as u32;
    let base = out.len() as u32;
    out.extend(grid_level_words(&coarse, slots, base));
    out
}

/// The coarse level's cell edge in fine cells (`avs_gather.glsl`'s passes at 5 and 10 radii scan
/// cells of 4 radii).
pub const COARSE_CELLS: f32 = 4.0;

/// One level of [`grid_words`], its word offsets counted from `base`.
fn grid_level_words(grid: &Grid, slots: &[u32], base: u32) -> Vec<u32> {
    let cells = grid.cell_start.len() - 1;
    let items = base + 16 + cells as u32 + 1;
    let mut out = vec![0u32; 16];
    out[0] = grid.dims[0];
    out[1] = grid.dims[1];
    out[2] = grid.dims[2];
    out[4] = grid.lo.x.to_bits();
    out[5] = grid.lo.y.to_bits();
    out[6] = grid.lo.z.to_bits();
    out[7] = grid.cell.to_bits();
    out[8] = items;
    out.extend_from_slice(&grid.cell_start);
    out.extend(grid.items.iter().map(|&i| slots[i as usize]));
    out.push(0);
    out
}

/// What `Technique::prepare` hands to `add`: the frame's candidate pool and, after waited
/// rounds, the points with their slots and the slot count.
struct Prepared {
    pool: Vec<SurfacePoint>,
    rounds: Option<(Vec<SurfacePoint>, Vec<u32>, u32)>,
}

/// The `"avs"` technique.
pub struct AvsTechnique {
    vis: Pipeline,
    sh: Pipeline,
    shade: Pipeline,
    hsdt: crate::hsdt::Hsdt,
    nearest: Sampler,
    linear: Sampler,
    repeat: Sampler,
    pub settings: AvsSettings,
    scene: Scene,
    pub builder: KdTreeBuilder,
    /// The lighting lobes in the map's frame at intensity 1 (`lighting::lighting_lobes_local`),
    /// turned and scaled per frame (`lighting::lobes_at`).
    lobes: Vec<[f32; 4]>,
    prefiltered: Arc<Vec<u8>>,
    /// The environment's irradiance map (`lighting::irradiance_env`), the ratio estimator's
    /// unshadowed diffuse term.
    irradiance: Arc<Vec<u8>>,
    axis_table: Arc<Vec<u8>>,
    /// The environment's key lights split off its map ([`AvsSettings::key_lights`]), 2 vec4 per
    /// light (axis + lambda, rgb amplitude; the map's frame at intensity 1, as `lobes`).
    key_lights: Vec<[f32; 4]>,
    /// Pool vertices of the current sample points (kept across frames): the traced ones.
    sample_vertices: Vec<usize>,
    /// Sample points kept but not traced (G-buffer culling).
    dormant: Vec<usize>,
    /// Candidate order of recent frames' `avs_cull` passes, by engine frame (bit i of that
    /// frame's late `avs.used` readback = vertex `order[i]`); empty: no flags asked for yet.
    cull_orders: Vec<(u64, Vec<usize>)>,
    /// The frame whose culling flags were applied last.
    applied_cull: Option<u64>,
    /// Vertices traced by recent frames of the late adaptation, by engine frame, in slot order:
    /// what their late `avs.sh` readbacks index.
    sent: Vec<(u64, Vec<usize>)>,
    /// The frame whose SH the late adaptation stepped on last.
    applied_sh: Option<u64>,
    /// The SH16 of every point after a frame's waited rounds (setup), already on the CPU: the
    /// late adaptation's first step uses them while no later frame has finished.
    setup_sh: Option<(u64, Vec<usize>, Vec<[f32; SH_COUNT]>)>,
    /// Pool vertices the late steps inserted or erased, by the frame whose set they changed
    /// first: a step on an older frame's maps leaves their neighbourhood alone.
    changes: Vec<(u64, Vec<usize>)>,
    /// What `prepare` left for this frame's `add`.
    prepared: Option<Prepared>,
    cull: Pipeline,
    key_filter: Pipeline,
    pool_len: usize,
    plan: Arc<PoolPlan>,
    radius: f32,
    /// The persistent kd-tree holds this frame's triangles (built by the first adaptation round).
    tree_current: bool,
    /// The sample points are the k-means initial set, not yet adapted (`first_iterations`).
    fresh: bool,
    /// Time the adaptation rounds with their own submissions (false: no adaptation rounds are
    /// possible inside a caller's graph without an engine, see `add`).
    pub stats: AvsStats,
    /// Settings the device lowered (see `new`), for [`crate::technique::Technique::notes`].
    notes: Vec<String>,
}

impl AvsTechnique {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, mut settings: AvsSettings) -> Result<Self> {
        settings.validate()?;
        // Every kept point's fp16 SSDF lives in one storage buffer bound whole: no more points
        // than the device's maxStorageBufferRange holds (lavapipe: 128 MiB, 4096 SSDFs at r = 128;
        // vol_big at 160x120 reached 4311 slots and a 141 MB binding).
        let ssdf_bytes = penumbra_math::avs_maps::ssdf_words_per_map(settings.r) as u64 * 4;
        let device_points = (ctx.max_storage_buffer_range as u64 / ssdf_bytes.max(1)).max(1) as usize;
        let mut notes = Vec::new();
        if settings.max_points > device_points {
            notes.push(format!(
                "avs: max_points {} lowered to {device_points}: the device binds at most {} MiB per storage buffer and one SSDF at r = {} takes {} KiB",
                settings.max_points,
                ctx.max_storage_buffer_range >> 20,
                settings.r,
                ssdf_bytes >> 10
            ));
            settings.max_points = device_points;
        }
        let vis = compute_pipeline(ctx, shaders, "avs/avs_vis.comp", 32)?;
        let sh = compute_pipeline(ctx, shaders, "avs/avs_sh.comp", 8)?;
        // the integration mode as a specialization constant: the pipeline holds one mode's code
        // (with all four, lavapipe compiled avs_shade for 18 s at the first frame; axis alone 9 s)
        let shade = crate::util::compute_pipeline_specialized(
            ctx,
            shaders,
            "avs/avs_shade.comp",
            52,
            &[(AVS_MODE_CONSTANT_ID, integration_mode(settings.integration))],
        )?;
        let cull = compute_pipeline(ctx, shaders, "avs/avs_cull.comp", 16)?;
        let key_filter = compute_pipeline(ctx, shaders, "avs/avs_key_filter.comp", 20)?;
        // the environment's key lights split off (`key_lights`): the SG lobes, the irradiance and
        // the prefiltered maps are the rest of the map's (also with `shadows = false`, where the
        // key lights are unshadowed: the same lighting with visibility 1)
        let max_key = if settings.traced_lights { settings.key_lights } else { 0 };
        let (sky, key) = crate::lighting::split_key_lights(scene.environment.as_ref(), max_key)?;
        let env = sky.as_ref().or(scene.environment.as_ref());
        let (lobes, _) = crate::lighting::lighting_lobes_local(env, settings.lobes);
        Ok(AvsTechnique {
            vis,
            sh,
            shade,
            hsdt: crate::hsdt::Hsdt::new(ctx, shaders)?,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            lobes,
            prefiltered: Arc::new(bytes_of(&crate::lighting::prefiltered_env(env))),
            irradiance: Arc::new(bytes_of(&crate::lighting::irradiance_env(env))),
            key_lights: key,
            axis_table: if settings.integration == Integration::Table { axis_table() } else { Arc::new(vec![0u8; 16]) },
            builder: KdTreeBuilder::new(ctx, shaders)?,
            scene: scene.clone(),
            settings,
            sample_vertices: Vec::new(),
            dormant: Vec::new(),
            cull_orders: Vec::new(),
            applied_cull: None,
            sent: Vec::new(),
            applied_sh: None,
            setup_sh: None,
            changes: Vec::new(),
            prepared: None,
            cull,
            key_filter,
            pool_len: usize::MAX,
            plan: Arc::new(PoolPlan::default()),
            radius: 0.0,
            tree_current: false,
            fresh: false,
            stats: AvsStats::default(),
            notes,
        })
    }

    /// Initial sample points for `pool` (k-means with e_g) and the search radius.
    fn initial_points(&mut self, pool: &[SurfacePoint]) {
        // automatic k: one per 4 mesh vertices and one per 16 extra candidates (the refined
        // coarse triangles start 4 pool spacings apart; the adaptation rounds insert the pool's
        // finer points where the visibility changes)
        let extra = self.plan.extra.min(pool.len());
        let k = if self.settings.points > 0 {
            self.settings.points
        } else {
            ((pool.len() - extra) / 4 + extra / 16).clamp(16, 2048)
        };
        let k = k.min(self.settings.max_points);
        self.sample_vertices = samp::kmeans_eg(pool, k, self.settings.alpha, 8, &mut |_, _| {});
        self.dormant.clear();
        // flags and SH of earlier frames index the old pool
        self.cull_orders.clear();
        self.sent.clear();
        self.applied_cull = None;
        self.applied_sh = None;
        self.changes.clear();
        let pos: Vec<Vec3> = self.sample_vertices.iter().map(|&v| pool[v].pos).collect();
        self.radius = (self.settings.radius * mean_spacing(&pos)).max(1e-6);
        self.stats.initial_points = self.sample_vertices.len();
        self.fresh = true;
    }

    /// Bytes of the persistent `avs.used` bit set (one bit per kept sample point).
    fn used_bytes(&self) -> u64 {
        (self.settings.max_points.max(1) as u64).div_ceil(32) * 4
    }

    /// G-buffer culling: the newest finished frame's `avs.used` bits (a late readback, never
    /// waited for) split the kept points into traced (flagged) and dormant ones. Points that frame
    /// did not know (inserted since) stay traced; without newer flags the split stays as it is.
    fn apply_cull_flags(&mut self, late: Option<&LateReadback>) {
        let Some(late) = late else { return };
        if self.applied_cull.is_some_and(|f| f >= late.frame) {
            return;
        }
        let Some((_, order)) = self.cull_orders.iter().find(|(f, _)| *f == late.frame) else { return };
        let data = &late.bytes;
        let flagged: std::collections::HashMap<usize, bool> = order
            .iter()
            .enumerate()
            .map(|(i, &v)| (v, data.get(i / 8).is_some_and(|b| (b >> (i % 8)) & 1 == 1)))
            .collect();
        let all: Vec<usize> = self.sample_vertices.iter().chain(&self.dormant).copied().collect();
        let (traced, dormant): (Vec<usize>, Vec<usize>) =
            all.into_iter().partition(|v| flagged.get(v).copied().unwrap_or(true));
        self.sample_vertices = traced;
        self.dormant = dormant;
        self.applied_cull = Some(late.frame);
    }

    /// The tree of the frame's triangles (shadow flags from the objects).
    fn tree(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, frame: &Frame) -> Result<KdTreeHandles> {
        self.builder.add_frame(engine, graph, &self.scene, frame)
    }

    /// Declares the visibility passes of `batch` (slots into the points buffer) writing each
    /// final map at its slot of `vis`; returns the new `vis` version and the stats buffer.
    fn add_visibility(
        &self,
        graph: &mut Graph,
        tree: &KdTreeHandles,
        points_buf: BufferHandle,
        points: &[SurfacePoint],
        batch: &[u32],
        mut vis: BufferHandle,
        tag: &str,
    ) -> (BufferHandle, BufferHandle) {
        let r = self.settings.r;
        let words = words_per_map(r) as u64;
        let n = batch.len() as u32;
        let k = self.settings.ray_neighbours;
        // neighbour lists among the batch (nearest first)
        let pos: Vec<Vec3> = batch.iter().map(|&s| points[s as usize].pos).collect();
        let g = Grid::new(&pos, self.radius);
        let mut data: Vec<u32> = batch.to_vec();
        for (e, p) in pos.iter().enumerate() {
            let mut nb: Vec<(f32, usize)> = g
                .range(*p, self.radius)
                .into_iter()
                .filter(|&j| {
                    j != e && samp::same_surface(&points[batch[e] as usize], &points[batch[j] as usize], self.radius)
                })
                .map(|j| ((pos[j] - *p).length_squared(), j))
                .collect();
            nb.sort_by(|a, b| a.0.total_cmp(&b.0));
            for q in 0..k as usize {
                data.push(nb.get(q).map_or(u32::MAX, |x| x.1 as u32));
            }
        }
        data.push(0);
        let batch_buf =
            graph.create_buffer_init(&format!("avs_batch{tag}"), crate::util::whole_texels(bytes_of(&data).to_vec()));
        // whole 16-byte texels: the next level reads these maps as a texel buffer
        let scratch_bytes = crate::util::texel_bytes((n.max(1) as u64) * words * 4);
        let mut scratch = [
            graph.create_buffer(&format!("avs_scratch{tag}_a"), scratch_bytes),
            graph.create_buffer(&format!("avs_scratch{tag}_b"), scratch_bytes),
        ];
        // rays per entry, accumulated by the levels' workgroups with atomics: cleared first
        let mut stats = {
            let b = graph.create_buffer(&format!("avs_rays{tag}"), (n.max(1) as u64) * 4);
            crate::util::fill_buffer(graph, &format!("avs_rays_clear{tag}"), b, 0)
        };
        let levels = self.settings.levels();
        // without adaptivity only the final level runs (every texel traced at r: r^2 rays a map)
        let first = if self.settings.adaptive { 0 } else { levels - 1 };
        for level in first..levels {
            let res = self.settings.initial_grid << level;
            let last = level + 1 == levels;
            // the shader's level: 0 traces every texel and reads no previous level
            let level = level - first;
            let mut p = graph.pass(&format!("avs_vis{tag}_l{level}"), PassKind::Compute);
            let kd = tree.read(&mut p);
            let [pb, bb] = [points_buf, batch_buf].map(|h| p.read(h, Access::ComputeShaderReadSampled));
            // level 0 reads no previous level (the points are bound in its place)
            let prev_idx = (level as usize + 1) % 2;
            let prev =
                if level == 0 { None } else { Some(p.read(scratch[prev_idx], Access::ComputeShaderReadSampled)) };
            // read-write: the map is zeroed and assembled with atomicOr in place (a write only on a
            // scratch buffer's first use, levels 0 and 1)
            let out = if last {
                p.write(vis, Access::ComputeShaderReadWriteStorage)
            } else {
                p.write(
                    scratch[level as usize % 2],
                    if level < 2 { Access::ComputeShaderWriteStorage } else { Access::ComputeShaderReadWriteStorage },
                )
            };
            let st = p.write(stats, Access::ComputeShaderReadWriteStorage);
            let flags = (k > 0) as u32 | (!self.settings.adaptive as u32) << 1 | (self.settings.keep_hits as u32) << 2;
            // the shader's probe loop runs 2 iterations unless the driver's loop limit was hit
            let push = [r, res, n, k, level, last as u32, flags, 2];
            // workgroups: batch entries x chunks of 1024 texels (AVS_VIS_CHUNK in avs_vis.comp)
            let chunks = (res * res).div_ceil(1024).max(1);
            let pipe = self.vis.handle();
            p.record(move |rc| {
                // level 0 reads no previous maps: the points stand in for them
                let texels = [pb, bb, prev.unwrap_or(pb)].map(Bind::TexelBuffer);
                let binds = [kd.binds().as_slice(), &texels, &crate::util::storage([out, st])].concat();
                crate::util::dispatch(rc, pipe, &binds, &bytes_of(&push), [n.clamp(1, 65535), chunks, 1])
            });
            stats = st;
            if last {
                vis = out;
            } else {
                scratch[level as usize % 2] = out;
            }
        }
        (vis, stats)
    }

    /// Declares the SH16 projection of the maps of `batch` (at their slots of `vis`), which also
    /// marks buried points (`samp::buried`) in `points_buf` (normal.w = 1); returns the `16 *
    /// batch` float buffer and the points buffer's new version.
    fn add_sh(
        &self,
        graph: &mut Graph,
        points_buf: BufferHandle,
        vis: BufferHandle,
        batch: &[u32],
        tag: &str,
    ) -> (BufferHandle, BufferHandle) {
        let n = batch.len() as u32;
        let mut data = batch.to_vec();
        data.push(0);
        let bb = graph.create_buffer_init(&format!("avs_sh_batch{tag}"), bytes_of(&data));
        let out = graph.create_buffer(&format!("avs_sh{tag}"), (n.max(1) as u64) * SH_COUNT as u64 * 4);
        let mut p = graph.pass(&format!("avs_sh{tag}"), PassKind::Compute);
        let pb = p.write(points_buf, Access::ComputeShaderReadWriteStorage);
        let bb = p.read(bb, Access::ComputeShaderReadStorage);
        let v = p.read(vis, Access::ComputeShaderReadStorage);
        let o = p.write(out, Access::ComputeShaderWriteStorage);
        let push = [self.settings.r, n];
        let pipe = self.sh.handle();
        p.record(move |rc| {
            let binds = crate::util::storage([pb, bb, v, o]);
            crate::util::dispatch(rc, pipe, &binds, &bytes_of(&push), [n.clamp(1, 65535), 1, 1])
        });
        (o, pb)
    }

    /// Copies `n` points' SH16 (`sh`) and then their ray counts (`rays`) into the readback `rb`.
    fn add_sh_copy(graph: &mut Graph, name: &str, sh: BufferHandle, rays: BufferHandle, rb: BufferHandle, n: u64) {
        let mut p = graph.pass(name, PassKind::Transfer);
        let s = p.read(sh, Access::TransferSrc);
        let ra = p.read(rays, Access::TransferSrc);
        let d = p.write(rb, Access::TransferDst);
        p.record(move |rc| {
            let (sb, rab, db) = (rc.buffer(s)?, rc.buffer(ra)?, rc.buffer(d)?);
            let sh_bytes = n * SH_COUNT as u64 * 4;
            unsafe {
                let dev = rc.device();
                dev.cmd_copy_buffer(
                    rc.cmd,
                    sb.buffer,
                    db.buffer,
                    &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: sh_bytes }],
                );
                dev.cmd_copy_buffer(
                    rc.cmd,
                    rab.buffer,
                    db.buffer,
                    &[vk::BufferCopy { src_offset: 0, dst_offset: sh_bytes, size: n * 4 }],
                );
            }
            Ok(())
        });
    }

    /// The spatial adaptation rounds (each its own submission, waited for) and the final
    /// visibility maps in the persistent `avs.vis` buffer. Every sample point owns a slot (its map
    /// and SSDF); erased points free their slot for later insertions. Returns the points with
    /// their slots and the slot count.
    fn adapt(
        &mut self,
        engine: &mut Engine,
        pool: &[SurfacePoint],
        frame: &Frame,
        image_height: u32,
    ) -> Result<(Vec<SurfacePoint>, Vec<u32>, u32)> {
        // a pixel's world size at p (at the point's distance from the eye): points closer together
        // than a pixel add no visible detail, so no insertion goes closer to a sample point than
        // that (balls_on_dish at 40 x 30: 1726 points and 19 s of visibility per frame without
        // it, rmse/mean 0.308 either way)
        let min_spacing = pixel_spacing(frame, image_height);
        let r = self.settings.r;
        let words = words_per_map(r) as u64;
        let cap = self.settings.max_points.max(self.sample_vertices.len()) as u64;
        let offset = ray_offset(pool);
        let pool_tree = samp::PointTree::new(&pool.iter().map(|p| p.pos).collect::<Vec<_>>());
        self.stats.inserted.clear();
        self.stats.erased.clear();
        self.stats.round_ms.clear();
        self.stats.rays = 0;
        self.stats.truncated = 0;
        self.stats.traced_points = 0;
        self.stats.rounds_wait_ms = 0.0;
        self.stats.rounds_step_ms = 0.0;
        self.tree_current = false;
        // `adaptation = cpu`: the frame's shadow-casting triangles on the CPU, for the rounds' maps
        let cpu = if self.settings.cpu {
            let (tris, _, no_shadow) = crate::kdtree::world_triangles_shading(&self.scene, frame)?;
            let casting: Vec<[Vec3; 3]> = tris.iter().zip(&no_shadow).filter(|(_, &ns)| !ns).map(|(t, _)| *t).collect();
            Some(crate::trace::CpuBvh::new(&casting))
        } else {
            None
        };
        // every point is traced again each frame (the geometry is dynamic): slots 0..n
        let mut slots: Vec<u32> = (0..self.sample_vertices.len() as u32).collect();
        let mut nslots = slots.len() as u32;
        let mut free: Vec<u32> = Vec::new();
        let mut sh: Vec<Option<[f32; SH_COUNT]>> = vec![None; slots.len()];
        let capture = self.settings.capture_maps;
        let mut maps: Vec<Vec<u32>> = vec![Vec::new(); slots.len()];
        // a fresh set of initial points (first frame, new pool) refines for `first_iterations`
        // rounds; later frames continue from the kept set; `iterations = 0`: no adaptation at all
        let rounds = if self.fresh && self.settings.iterations > 0 {
            self.settings.first_iterations.max(self.settings.iterations)
        } else {
            self.settings.iterations
        };
        self.fresh = false;
        for round in 0..=rounds {
            let points: Vec<SurfacePoint> = self.sample_vertices.iter().map(|&v| pool[v]).collect();
            let batch: Vec<u32> = (0..points.len()).filter(|&i| sh[i].is_none()).map(|i| slots[i]).collect();
            if batch.is_empty() {
                break;
            }
            let mut by_slot = vec![SurfacePoint { pos: Vec3::ZERO, normal: Vec3::Y }; nslots as usize];
            for (i, p) in points.iter().enumerate() {
                by_slot[slots[i] as usize] = *p;
            }
            let slot_point: std::collections::HashMap<u32, usize> =
                slots.iter().enumerate().map(|(i, &s)| (s, i)).collect();
            if let Some(cpu) = &cpu {
                let grid = self.settings.cpu_grid;
                let batch_sh: Vec<[f32; SH_COUNT]> = {
                    use rayon::prelude::*;
                    batch.par_iter().map(|&slot| cpu_sh16(cpu, &by_slot[slot as usize], offset, grid)).collect()
                };
                self.stats.traced_points += batch.len();
                self.stats.rays += batch.len() as u64 * (grid * grid) as u64;
                for (&slot, v) in batch.iter().zip(batch_sh) {
                    sh[slot_point[&slot]] = Some(v);
                }
            } else {
                let mut g = Graph::new();
                // the tree is (re)built in the first round only
                let kept = if round > 0 { self.builder.add_kept(&mut FrameStore::new(engine), &mut g) } else { None };
                let tree = match kept {
                    Some(t) => t,
                    None => self.tree(&mut FrameStore::new(engine), &mut g, frame)?,
                };
                self.tree_current = true;
                let points_buf = g.create_buffer_init("avs_points", bytes_of(&point_data(&by_slot, offset)));
                let vis = engine.persistent_buffer(&mut g, "avs.vis", cap * words * 4);
                let tag = format!("_i{round}");
                let (vis, rays) = self.add_visibility(&mut g, &tree, points_buf, &by_slot, &batch, vis, &tag);
                let (shb, _) = self.add_sh(&mut g, points_buf, vis, &batch, &tag);
                let n = batch.len() as u64;
                self.stats.traced_points += batch.len();
                let rb = g.create_readback("avs_sh_readback", n * (SH_COUNT as u64 + 1) * 4);
                Self::add_sh_copy(&mut g, "avs_sh_readback", shb, rays, rb, n);
                if capture {
                    let bytes = (nslots.max(1) as u64).min(cap) * words * 4;
                    let rb = g.create_readback("avs_maps_readback", bytes);
                    crate::util::copy_buffer(&mut g, "avs_maps_readback", vis, rb, Some(bytes));
                }
                let waited = std::time::Instant::now();
                let out = engine.submit_wait(g)?;
                self.stats.rounds_wait_ms += waited.elapsed().as_secs_f64() * 1e3;
                self.stats.round_ms.extend(out.gpu_ms.iter().cloned());
                let (batch_sh, rays, truncated) = out
                    .readbacks
                    .get("avs_sh_readback")
                    .and_then(|b| parse_sh_readback(b, batch.len()))
                    .ok_or_else(|| anyhow!("avs: SH readback missing"))?;
                self.stats.rays += rays;
                self.stats.truncated += truncated;
                for (&slot, v) in batch.iter().zip(batch_sh) {
                    sh[slot_point[&slot]] = Some(v);
                    let map_bytes = words as usize * 4;
                    if let Some(m) = out
                        .readbacks
                        .get("avs_maps_readback")
                        .and_then(|m| m.get(slot as usize * map_bytes..(slot as usize + 1) * map_bytes))
                    {
                        maps[slot_point[&slot]] = map_words(m);
                    }
                }
            }
            if round == rounds {
                break;
            }
            let params = samp::AdaptParams {
                alpha: self.settings.alpha,
                radius: self.radius,
                e_max: self.settings.e_max,
                e_min: self.settings.e_min,
            };
            let sh_now: Vec<[f32; SH_COUNT]> = sh.iter().map(|c| c.unwrap_or([0.0; SH_COUNT])).collect();
            let visible_now: Vec<f32> = sh_now.iter().map(samp::visible_solid_angle).collect();
            let stepped = std::time::Instant::now();
            let step =
                samp::adapt_step(&points, &self.sample_vertices, &sh_now, &visible_now, pool, &pool_tree, &params);
            self.stats.rounds_step_ms += stepped.elapsed().as_secs_f64() * 1e3;
            let errs: Vec<f32> = step.rel_error.iter().flatten().copied().collect();
            self.stats.mean_rel_error =
                if errs.is_empty() { 0.0 } else { errs.iter().sum::<f32>() / errs.len() as f32 };
            // Under G-buffer culling the step saw only the traced subset: an erased point goes
            // dormant (it stays a candidate, and the next frame's flags bring it back where a pixel
            // needs it) instead of leaving the kept set for good. Erasing for good on a subset
            // cascaded over frames: balls_on_dish 80x60, frames 26-30, rmse/mean 0.286 with black
            // trails over the dish against 0.164 without culling.
            let cull = self.settings.cull;
            let leaving = if cull { 0 } else { step.erase.len() };
            let room = self.settings.max_points.saturating_sub(points.len() - leaving + self.dormant.len());
            let grid = Grid::new(&points.iter().map(|p| p.pos).collect::<Vec<_>>(), self.radius);
            let dormant: std::collections::HashSet<usize> = self.dormant.iter().copied().collect();
            let mut insert: Vec<usize> = Vec::new();
            for &v in &step.insert {
                if insert.len() >= room {
                    break;
                }
                if dormant.contains(&v) {
                    continue;
                }
                let (p, d) = (pool[v].pos, min_spacing(pool[v].pos));
                if grid.range(p, d).is_empty() && insert.iter().all(|&u| (pool[u].pos - p).length() >= d) {
                    insert.push(v);
                }
            }
            self.stats.inserted.push(insert.len());
            self.stats.erased.push(step.erase.len());
            if insert.is_empty() && step.erase.is_empty() {
                break;
            }
            let erase: std::collections::HashSet<usize> = step.erase.iter().copied().collect();
            let mut keep_v = Vec::new();
            let mut keep_s = Vec::new();
            let mut keep_sh = Vec::new();
            let mut keep_maps = Vec::new();
            for i in 0..points.len() {
                if erase.contains(&i) {
                    free.push(slots[i]);
                    if cull {
                        self.dormant.push(self.sample_vertices[i]);
                    }
                } else {
                    keep_v.push(self.sample_vertices[i]);
                    keep_s.push(slots[i]);
                    keep_sh.push(sh[i]);
                    keep_maps.push(std::mem::take(&mut maps[i]));
                }
            }
            for v in insert {
                keep_v.push(v);
                keep_s.push(free.pop().unwrap_or_else(|| {
                    nslots += 1;
                    nslots - 1
                }));
                keep_sh.push(None);
                keep_maps.push(Vec::new());
            }
            self.sample_vertices = keep_v;
            slots = keep_s;
            sh = keep_sh;
            maps = keep_maps;
        }
        self.stats.points = self.sample_vertices.len();
        // the late adaptation's first step (the rounds' frames need none)
        let frame_no = engine.next_frame();
        self.setup_sh = self
            .settings
            .late
            .then(|| sh.iter().copied().collect::<Option<Vec<_>>>())
            .flatten()
            .map(|sh| (frame_no, self.sample_vertices.clone(), sh));
        let two_pi = 2.0 * std::f32::consts::PI;
        self.stats.visible_fraction =
            sh.iter().map(|c| c.as_ref().map_or(-1.0, |c| samp::visible_solid_angle(c) / two_pi)).collect();
        self.stats.maps = if capture { maps } else { Vec::new() };
        if self.stats.truncated > 0 {
            tracing::warn!(
                "avs: {} visibility maps hit the device's per-invocation loop limit (lavapipe: 65535 iterations); their untraced texels read as occluded",
                self.stats.truncated
            );
        }
        Ok((self.sample_vertices.iter().map(|&v| pool[v]).collect(), slots, nslots))
    }

    /// The newest finished frame's late SH readback, if it is newer than the last one used and
    /// its points are known: fills the map statistics ([`AvsStats::late_vertices`]) and returns
    /// that frame's pool vertices with their SH16. Never waits.
    fn take_late_stats(
        &mut self,
        late: Option<&LateReadback>,
        late_maps: Option<&LateReadback>,
    ) -> Option<(u64, Vec<usize>, Vec<[f32; SH_COUNT]>)> {
        let late = late?;
        if self.applied_sh.is_some_and(|f| f >= late.frame) {
            return None;
        }
        let (_, verts) = self.sent.iter().find(|(f, _)| *f == late.frame)?;
        let n = verts.len();
        let (sh, rays, truncated) = parse_sh_readback(&late.bytes, n)?;
        let two_pi = 2.0 * std::f32::consts::PI;
        self.stats.visible_fraction = sh.iter().map(|c| samp::visible_solid_angle(c) / two_pi).collect();
        self.stats.buried = self.stats.visible_fraction.iter().filter(|&&v| samp::buried(v)).count();
        self.stats.rays = rays;
        self.stats.truncated = truncated;
        self.stats.late_vertices = verts.clone();
        let words = words_per_map(self.settings.r);
        self.stats.maps = match late_maps {
            Some(m) if self.settings.capture_maps && m.frame == late.frame && m.bytes.len() >= n * words * 4 => {
                m.bytes.chunks_exact(words * 4).take(n).map(map_words).collect()
            }
            _ => Vec::new(),
        };
        if truncated > 0 {
            tracing::warn!(
                "avs: {truncated} visibility maps of frame {} hit the device's per-invocation loop limit (lavapipe: 65535 iterations); their untraced texels read as occluded",
                late.frame
            );
        }
        self.applied_sh = Some(late.frame);
        Some((late.frame, verts.clone(), sh))
    }

    /// One step of the spatial adaptation (4.3) on the newest finished frame's maps (a late
    /// readback, never waited for), applied to the current set by pool vertex: erasures leave it
    /// (under culling they go dormant, as in [`AvsTechnique::adapt`]), insertions join it when no
    /// kept point is within a pixel's width and there is room.
    fn late_step(
        &mut self,
        late_sh: Option<&LateReadback>,
        late_maps: Option<&LateReadback>,
        frame_no: u64,
        pool: &[SurfacePoint],
        frame: &Frame,
        image_height: u32,
    ) {
        self.stats.inserted.clear();
        self.stats.erased.clear();
        self.stats.round_ms.clear();
        // the newest finished frame's maps, else (right after the setup rounds, before any later
        // frame finished) the setup's last SH, once
        let late = self.take_late_stats(late_sh, late_maps);
        let Some((data_frame, verts, sh)) = late.or_else(|| self.setup_sh.take()) else { return };
        self.setup_sh = None;
        // the points this frame traces (culling may have made some of that frame's dormant since):
        // the step sees the traced subset, as a waited round does; inserting next to points no
        // pixel needs filled the set with points that went dormant at once (hat_on_cloth 64x48,
        // six frames: 782 points, 780 of them dormant, against 595 and 192 for waited rounds)
        let traced: std::collections::HashSet<usize> = self.sample_vertices.iter().copied().collect();
        let (verts, sh): (Vec<usize>, Vec<[f32; SH_COUNT]>) =
            verts.into_iter().zip(sh).filter(|(v, _)| traced.contains(v)).unzip();
        let Some(points) = verts.iter().map(|&v| pool.get(v).copied()).collect::<Option<Vec<SurfacePoint>>>() else {
            return;
        };
        let visible: Vec<f32> = sh.iter().map(samp::visible_solid_angle).collect();
        let params = samp::AdaptParams {
            alpha: self.settings.alpha,
            radius: self.radius,
            e_max: self.settings.e_max,
            e_min: self.settings.e_min,
        };
        let pool_tree = samp::PointTree::new(&pool.iter().map(|p| p.pos).collect::<Vec<_>>());
        let stepped = std::time::Instant::now();
        let step = samp::adapt_step(&points, &verts, &sh, &visible, pool, &pool_tree, &params);
        self.stats.rounds_step_ms = stepped.elapsed().as_secs_f64() * 1e3;
        let errs: Vec<f32> = step.rel_error.iter().flatten().copied().collect();
        self.stats.mean_rel_error = if errs.is_empty() { 0.0 } else { errs.iter().sum::<f32>() / errs.len() as f32 };
        // Steps applied after `data_frame` was built changed the set near their points, which
        // that frame's maps do not show: no erasure or insertion there. (Erasing a point whose
        // neighbour a later step erased left holes: two neighbours gone, one judged with the
        // other present; falling 160x120, seven frames, blotchy shadows at 0.142 against 0.078
        // for the waited rounds.)
        self.changes.retain(|(f, _)| *f > data_frame);
        let changed: Vec<Vec3> =
            self.changes.iter().flat_map(|(_, vs)| vs.iter().filter_map(|&v| pool.get(v).map(|p| p.pos))).collect();
        let changed_grid = (!changed.is_empty()).then(|| Grid::new(&changed, self.radius));
        let near_change = |p: Vec3| changed_grid.as_ref().is_some_and(|g| !g.range(p, self.radius).is_empty());
        // insertions are spaced against the current set before the erasures, as in the rounds
        let min_spacing = pixel_spacing(frame, image_height);
        let current: Vec<Vec3> = self.sample_vertices.iter().map(|&v| pool[v].pos).collect();
        let grid = Grid::new(&current, self.radius);
        let erase: std::collections::HashSet<usize> =
            step.erase.iter().map(|&i| verts[i]).filter(|&v| !near_change(pool[v].pos)).collect();
        let (gone, kept): (Vec<usize>, Vec<usize>) =
            std::mem::take(&mut self.sample_vertices).into_iter().partition(|v| erase.contains(v));
        self.sample_vertices = kept;
        if self.settings.cull {
            self.dormant.extend(gone.iter().copied());
        }
        let room = self.settings.max_points.saturating_sub(self.sample_vertices.len() + self.dormant.len());
        let taken: std::collections::HashSet<usize> =
            self.sample_vertices.iter().chain(&self.dormant).chain(&gone).copied().collect();
        let mut insert: Vec<usize> = Vec::new();
        for &v in &step.insert {
            if insert.len() >= room {
                break;
            }
            if taken.contains(&v) || near_change(pool[v].pos) {
                continue;
            }
            let (p, d) = (pool[v].pos, min_spacing(pool[v].pos));
            if grid.range(p, d).is_empty() && insert.iter().all(|&u| (pool[u].pos - p).length() >= d) {
                insert.push(v);
            }
        }
        self.stats.inserted.push(insert.len());
        self.stats.erased.push(gone.len());
        // this frame's set (built next) is the first to show the changes
        self.changes.push((frame_no, insert.iter().chain(&gone).copied().collect()));
        self.sample_vertices.extend(insert);
    }

    /// Declares this frame's visibility maps of `points` (slots 0..n of `vis`), their SH16 (which
    /// marks buried points in `points_buf`) and the late readbacks a later frame adapts from
    /// (`avs.sh`, and `avs.maps` with `capture_maps`); returns `vis` and `points_buf`.
    fn add_late_maps(
        &self,
        graph: &mut Graph,
        tree: &KdTreeHandles,
        points_buf: BufferHandle,
        points: &[SurfacePoint],
        vis: BufferHandle,
    ) -> (BufferHandle, BufferHandle) {
        let n = points.len();
        if n == 0 {
            return (vis, points_buf);
        }
        let batch: Vec<u32> = (0..n as u32).collect();
        let (vis, rays) = self.add_visibility(graph, tree, points_buf, points, &batch, vis, "");
        let (shb, points_buf) = self.add_sh(graph, points_buf, vis, &batch, "");
        if !self.settings.late {
            // `adaptation = cpu`: the SH (and the buried flags `avs_sh` sets) serve the frame only
            return (vis, points_buf);
        }
        let rb = graph.create_late_readback(LATE_SH, n as u64 * (SH_COUNT as u64 + 1) * 4);
        Self::add_sh_copy(graph, "avs_sh_copy", shb, rays, rb, n as u64);
        if self.settings.capture_maps {
            let bytes = n as u64 * words_per_map(self.settings.r) as u64 * 4;
            let rb = graph.create_late_readback(LATE_MAPS, bytes);
            crate::util::copy_buffer(graph, "avs_maps_copy", vis, rb, Some(bytes));
        }
        (vis, points_buf)
    }
}

impl crate::technique::Technique for AvsTechnique {
    fn name(&self) -> &'static str {
        "avs"
    }

    fn stats(&self) -> Option<Box<dyn std::any::Any>> {
        Some(Box::new(self.stats.clone()))
    }

    fn notes(&self, _scene: &Scene) -> Vec<String> {
        self.notes.clone()
    }

    fn prepare(&mut self, engine: &mut Engine, inputs: &crate::technique::PrepareInputs) -> Result<()> {
        let frame = inputs.frame;
        let mut clock = std::time::Instant::now();
        self.stats.cpu_ms.clear();
        if self.plan.insts.is_empty() || !self.plan.fits(&self.scene, frame) {
            self.plan = Arc::new(PoolPlan::new(&self.scene, frame, self.settings.pool_points)?);
            self.pool_len = usize::MAX;
        }
        let pool = vertex_pool(&self.scene, frame, &self.plan)?;
        self.stats.pool_plan = self.plan.clone();
        self.stats.lap(&mut clock, "pool");
        if pool.len() != self.pool_len {
            self.pool_len = pool.len();
            self.initial_points(&pool);
        }
        self.stats.lap(&mut clock, "kmeans");
        self.stats.vertices = pool.len();
        if self.settings.cull && !self.cull_orders.is_empty() {
            self.apply_cull_flags(engine.late_readback(LATE_USED));
        } else if self.settings.cull {
            // no flags yet (first frame): the view frustum, widened by the search radius, decides
            // which points are traced (the G-buffer flags take over from the next frame)
            let aspect = inputs.width as f32 / inputs.height.max(1) as f32;
            let planes = frustum_planes(frame.camera.proj(aspect) * frame.camera.view());
            let all: Vec<usize> = self.sample_vertices.iter().chain(self.dormant.iter()).copied().collect();
            let margin = self.radius * 2.5;
            let (traced, dormant): (Vec<usize>, Vec<usize>) =
                all.into_iter().partition(|&v| planes.iter().all(|p| p.truncate().dot(pool[v].pos) + p.w >= -margin));
            self.sample_vertices = traced;
            self.dormant = dormant;
        } else if !self.dormant.is_empty() {
            // culling off: every kept point is traced again
            let d = std::mem::take(&mut self.dormant);
            self.sample_vertices.extend(d);
        }
        self.stats.dormant = self.dormant.len();
        self.stats.lap(&mut clock, "cull");
        // a fresh k-means set is refined by waited rounds before its frame (setup); every later
        // frame of the late adaptation builds without waiting
        let rounds_now = !self.settings.late || (self.fresh && self.settings.iterations > 0);
        let rounds = if rounds_now {
            let done = self.adapt(engine, &pool, frame, inputs.height)?;
            // the rounds' wall-clock time, split into their waits, their adapt_step and the rest
            let rounds = clock.elapsed().as_secs_f64() * 1e3;
            let (waited, stepped) = (self.stats.rounds_wait_ms, self.stats.rounds_step_ms);
            self.stats.cpu_ms.push(("rounds_wait", waited));
            self.stats.cpu_ms.push(("rounds_step", stepped));
            self.stats.cpu_ms.push(("rounds_cpu", (rounds - waited - stepped).max(0.0)));
            self.stats.late_vertices = self.sample_vertices.clone();
            // `adaptation = cpu` traced no GPU maps: the frame's graph traces the final set's
            (!self.settings.cpu).then_some(done)
        } else {
            self.fresh = false;
            let (late_sh, late_maps) = (engine.late_readback(LATE_SH), engine.late_readback(LATE_MAPS));
            if self.settings.iterations > 0 {
                self.late_step(late_sh, late_maps, engine.next_frame(), &pool, frame, inputs.height);
            } else {
                self.take_late_stats(late_sh, late_maps);
            }
            self.stats.lap(&mut clock, "late_step");
            None
        };
        self.prepared = Some(Prepared { pool, rounds });
        Ok(())
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        let frame = inputs.frame;
        let mut clock = std::time::Instant::now();
        let Some(Prepared { pool, rounds }) = self.prepared.take() else {
            bail!("avs: a frame declared without its preparation (Technique::prepare)");
        };
        let offset = ray_offset(&pool);
        let r = self.settings.r;
        let cap = self.settings.max_points.max(self.sample_vertices.len()) as u64;
        let frame_no = engine.next_frame();
        let (points, slots, vis, points_buf, tree) = if let Some((points, slots, nslots)) = rounds {
            let vis = engine.persistent_buffer(graph, "avs.vis", cap * words_per_map(r) as u64 * 4);
            // buried points (a candidate inside a closed object, `samp::buried`: every direction
            // occluded) are interpolated only where no other point is in reach (avs_gather.glsl):
            // their maps stand for no visible surface next to the object, but a floor under an
            // endless ceiling is all buried and must stay dark (the late path's `avs_sh` pass sets
            // the same flag on the GPU)
            let buried: Vec<bool> =
                (0..points.len()).map(|i| self.stats.visible_fraction.get(i).is_some_and(|&v| v == 0.0)).collect();
            self.stats.buried = buried.iter().filter(|&&b| b).count();
            let mut by_slot = vec![SurfacePoint { pos: Vec3::ZERO, normal: Vec3::Y }; nslots as usize];
            for (i, p) in points.iter().enumerate() {
                by_slot[slots[i] as usize] = *p;
            }
            let mut point_words = point_data(&by_slot, offset);
            for (i, _) in buried.iter().enumerate().filter(|(_, &b)| b) {
                point_words[3 * slots[i] as usize + 2][3] = 1.0;
            }
            let points_buf = graph.create_buffer_init("avs_points", bytes_of(&point_words));
            // the frame's triangles for the local lights' shadow rays: the rounds' tree, or built
            // here when no round traced (no sample points)
            let tree = match self.tree_current.then(|| self.builder.add_kept(engine, graph)).flatten() {
                Some(t) => t,
                None => self.tree(engine, graph, frame)?,
            };
            (points, slots, vis, points_buf, tree)
        } else {
            let points: Vec<SurfacePoint> = self.sample_vertices.iter().map(|&v| pool[v]).collect();
            let slots: Vec<u32> = (0..points.len() as u32).collect();
            let tree = self.tree(engine, graph, frame)?;
            let points_buf = graph.create_buffer_init("avs_points", bytes_of(&point_data(&points, offset)));
            let vis = engine.persistent_buffer(graph, "avs.vis", cap * words_per_map(r) as u64 * 4);
            let (vis, points_buf) = self.add_late_maps(graph, &tree, points_buf, &points, vis);
            self.stats.traced_points = points.len();
            if self.settings.cpu {
                // the rounds' CPU maps (the shading takes the flag from the frame's own maps, `avs_sh`)
                self.stats.buried = self.stats.visible_fraction.iter().filter(|&&v| v == 0.0).count();
            }
            if self.settings.late {
                push_recent(&mut self.sent, frame_no, self.sample_vertices.clone());
            }
            (points, slots, vis, points_buf, tree)
        };
        let nslots = slots.iter().max().map_or(0, |&m| m + 1);
        self.stats.points = points.len();
        self.stats.point_vertices = self.sample_vertices.clone();
        self.stats.kept_vertices = self.sample_vertices.iter().chain(&self.dormant).copied().collect();
        let n = nslots;
        self.stats.map_bytes = points.len() as u64 * words_per_map(r) as u64 * 4;
        self.stats.ssdf_bytes = points.len() as u64 * penumbra_math::avs_maps::ssdf_words_per_map(r) as u64 * 4;

        // The frame's graph: SSDFs of the final maps, shading.
        let ssdf = self.hsdt.add(graph, "avs_hsdt", vis, n.max(1), r)?;
        let pos: Vec<Vec3> = points.iter().map(|p| p.pos).collect();
        // every kept point, traced or dormant (the candidates of the G-buffer culling)
        let all: Vec<usize> = self.sample_vertices.iter().chain(self.dormant.iter()).copied().collect();
        let all_pos: Vec<Vec3> = all.iter().map(|&v| pool[v].pos).collect();
        // the per-pixel search radius follows the final density of all kept points (the rounds
        // use the initial one)
        let shade_radius =
            if all_pos.len() >= 2 { (self.settings.radius * mean_spacing(&all_pos)).max(1e-6) } else { self.radius };
        self.stats.radius = shade_radius;
        let grid = Grid::new(&pos, shade_radius);
        let grid_buf = graph
            .create_buffer_init("avs_grid", crate::util::whole_texels(bytes_of(&grid_words(&grid, &slots)).to_vec()));
        // the lighting and key-light lobes turned and scaled to the frame's environment
        let state = inputs.frame.environment;
        let lobes = graph.create_buffer_init("avs_lobes", crate::lighting::lobes_bytes_at(&self.lobes, state));
        let prefiltered = graph.create_buffer_init("avs_prefiltered", self.prefiltered.as_ref().clone());
        let table =
            graph.create_buffer_init("avs_axis_table", crate::util::whole_texels(self.axis_table.as_ref().clone()));
        let irradiance = graph.create_buffer_init("avs_irradiance", self.irradiance.as_ref().clone());
        let key_lights =
            graph.create_buffer_init("avs_key_lights", crate::lighting::lobes_bytes_at(&self.key_lights, state));

        let (scene, gb) = (inputs.handles, inputs.gbuffer);
        let (w, h) = (gb.width, gb.height);
        // key_filter: the key lights' diffuse light apart (a 1 x 1 stand-in without), the rest in
        // `avs_base`, both added in `avs_key_filter`
        let filter = self.settings.key_filter > 0
            && self.settings.shadows
            && self.settings.traced_lights
            && !self.key_lights.is_empty();
        let hdr = graph.create_image(if filter { "avs_base" } else { "hdr" }, ImageDesc::new_2d(HDR_FORMAT, w, h));
        let key_img = if filter { (w, h) } else { (1, 1) };
        let key_out = graph.create_image("avs_key", ImageDesc::new_2d(HDR_FORMAT, key_img.0, key_img.1));
        let key_aux = graph.create_image("avs_key_aux", ImageDesc::new_2d(HDR_FORMAT, key_img.0, key_img.1));
        let mut p = graph.pass("avs_shade", PassKind::Compute);
        let kd = tree.read(&mut p);
        let io = crate::shade_env::ShadingIo::declare(&mut p, scene, gb, inputs.env, hdr);
        let hdr = io.hdr;
        let key_out = p.write(key_out, Access::ComputeShaderWriteStorage);
        let key_aux = p.write(key_aux, Access::ComputeShaderWriteStorage);
        let lights = p.read(scene.lights, Access::ComputeShaderReadStorage);
        let textures = p.read(scene.textures, Access::ComputeShaderReadSampled);
        let [lobes, prefiltered, ir, kl] =
            [lobes, prefiltered, irradiance, key_lights].map(|h| p.read(h, Access::ComputeShaderReadStorage));
        // the points, grid, SSDFs and axis table are texel buffers (avs_shade.comp)
        let [pts, gr, sd, tb] =
            [points_buf, grid_buf, ssdf, table].map(|h| p.read(h, Access::ComputeShaderReadSampled));
        let pos_scale = samp::scene_scale(&pool.iter().map(|p| p.pos).collect::<Vec<_>>());
        let s = &self.settings;
        let mut push: Vec<u8> = Vec::with_capacity(52);
        push.extend(bytes_of(&[scene.light_count, (self.lobes.len() / 2) as u32, r, s.neighbours.clamp(1, 8)]));
        let (wa, wscale) =
            if s.interp_alpha > 0.0 { (s.interp_alpha, 1.0 / shade_radius) } else { (s.alpha, 1.0 / pos_scale) };
        push.extend(bytes_of(&[wa, wscale, shade_radius]));
        push.extend(bytes_of(&[
            (!s.shadows || points.is_empty()) as u32
                | ((s.shadows && s.traced_lights) as u32) << 1
                | (s.key_rays_predicted as u32) << 2
                | (s.key_pattern_stratified as u32) << 3
                | (s.key_penumbra_refine as u32) << 4
                | (filter as u32) << 5,
            s.cells.clamp(1, 16),
            if s.glossy_ratio { 2 } else { (!s.prefiltered) as u32 },
            s.diffuse_ratio as u32,
        ]));
        // shadow rays leave the pixel's surface as the sample points' rays do
        push.extend(bytes_of(&[offset]));
        push.extend(bytes_of(&[(self.key_lights.len() / 2) as u32]));
        let pipe = self.shade.handle();
        let (nearest, linear, repeat) = (self.nearest.sampler, self.linear.sampler, self.repeat.sampler);
        p.record(move |rc| {
            let rest = [Bind::StorageBuffer(lights), Bind::SampledImage(textures, repeat)];
            let storage = [
                Bind::StorageBuffer(lobes),
                Bind::StorageBuffer(prefiltered),
                Bind::TexelBuffer(pts),
                Bind::TexelBuffer(gr),
                Bind::TexelBuffer(sd),
                Bind::TexelBuffer(tb),
                Bind::StorageBuffer(ir),
            ];
            let binds = [
                &io.binds(nearest, linear)[..],
                &rest,
                &storage,
                &kd.binds(),
                &[Bind::StorageBuffer(kl), Bind::StorageImage(key_out), Bind::StorageImage(key_aux)],
            ]
            .concat();
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
        });
        let hdr = if filter {
            let out = graph.create_image("hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
            let mut p = graph.pass("avs_key_filter", PassKind::Compute);
            let g = gb.read_sampled(&mut p);
            let b = p.read(hdr, Access::ComputeShaderReadStorage);
            let k = p.read(key_out, Access::ComputeShaderReadStorage);
            let ka = p.read(key_aux, Access::ComputeShaderReadStorage);
            let o = p.write(out, Access::ComputeShaderWriteStorage);
            let cam = &inputs.frame.camera;
            let per_distance = 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / h.max(1) as f32;
            let mut push = bytes_of(&cam.eye.to_array()).to_vec();
            push.extend(bytes_of(&[per_distance]));
            push.extend(bytes_of(&[self.settings.key_filter as i32]));
            let pipe = self.key_filter.handle();
            p.record(move |rc| {
                let binds = [
                    &g.binds(nearest)[..],
                    &[Bind::StorageImage(b), Bind::StorageImage(k), Bind::StorageImage(ka), Bind::StorageImage(o)],
                ]
                .concat();
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            o
        } else {
            hdr
        };
        // G-buffer culling: flag the kept points this frame's covered pixels need (read next frame)
        if self.settings.cull && !all.is_empty() && all.len() <= self.settings.max_points {
            let all_pts: Vec<SurfacePoint> = all.iter().map(|&v| pool[v]).collect();
            let ids: Vec<u32> = (0..all.len() as u32).collect();
            let grid_all = Grid::new(&all_pos, shade_radius);
            let pbuf = graph.create_buffer_init("avs_cull_points", bytes_of(&point_data(&all_pts, offset)));
            let gbuf = graph.create_buffer_init("avs_cull_grid", bytes_of(&grid_words(&grid_all, &ids)));
            let used = graph.create_buffer("avs_used", self.used_bytes());
            let used = crate::util::fill_buffer(graph, "avs_cull_clear", used, 0);
            let mut p = graph.pass("avs_cull", PassKind::Compute);
            let g = gb.read_sampled(&mut p);
            let pb = p.read(pbuf, Access::ComputeShaderReadStorage);
            let gr = p.read(gbuf, Access::ComputeShaderReadStorage);
            let u = p.write(used, Access::ComputeShaderReadWriteStorage);
            // the shader's push block: radius, alpha, inv_scale, max_neighbours (as avs_shade)
            let mut push: Vec<u8> = Vec::with_capacity(16);
            push.extend(bytes_of(&[shade_radius, wa, wscale]));
            push.extend(bytes_of(&[s.neighbours.clamp(1, 8)]));
            let pipe = self.cull.handle();
            p.record(move |rc| {
                let binds = [
                    &g.binds(nearest)[..],
                    &[Bind::StorageBuffer(pb), Bind::StorageBuffer(gr), Bind::StorageBuffer(u)],
                ]
                .concat();
                crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
            });
            // read by a later frame, never waited for (`apply_cull_flags`)
            let bytes = self.used_bytes();
            let rb = graph.create_late_readback(LATE_USED, bytes);
            crate::util::copy_buffer(graph, "avs_used_copy", u, rb, Some(bytes));
            push_recent(&mut self.cull_orders, frame_no, all);
        }
        self.stats.lap(&mut clock, "shading_prep");
        Ok(hdr)
    }
}

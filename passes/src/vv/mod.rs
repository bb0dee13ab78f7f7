//! Vectorized visibility with spherical-Voronoi correspondence (Leung et al. 2021, building on
//! Ho et al. 2015): technique `"vv"` (issue 9, part B: integration, shading modes, bench).
//!
//! Offline (part A, `penumbra_math::vv`): per-vertex vectorized visibility of the scene's static
//! objects (world space, object order) and per-triangle triple lists. Per frame:
//! * `vv_sat_rows` + `vv_sat_cols` (compute): the summed-area tables of `l L_e(l)` and `L_e(l)`
//!   (x, y, z and 1 channels, RGB) of the lat-long lighting, fp32 with Kahan-compensated prefix sums (rows,
//!   then columns), rebuilt every frame so the lighting may change; in `tessellation` modes a
//!   second table of the Phong-blurred (alpha 256) lighting (eq. 17). Environment rotation and
//!   intensity are applied at lookup (directions are rotated into map space).
//! * `shade_env`: the background and the unshadowed local lights of the `env` technique (the
//!   objects' pixels are then overdrawn).
//! * `vv_shade` (raster, own depth): one non-indexed draw of the model's triangles. Modes
//!   ([`VvMode`]): `fragment3` (eq. 19: three syntheses and three SAT evaluations per fragment
//!   blended barycentrically, the previous method), `fragment1` (eq. 21: the interpolated
//!   vectorized visibility evaluated once per fragment), `tessellation` (vertex shader: each
//!   vertex's radiance under the original and the blurred lighting; tessellation control shader:
//!   `n = 2^round(zeta Delta)` per edge/inside, eq. 17-18; evaluation shader: eq. 21 at every
//!   tessellated vertex; fragments interpolate) and `tessellation3` (the same with eq. 19 at the
//!   tessellated vertices: the previous method under dynamic tessellation). Triangles after
//!   tessellation are counted with a pipeline-statistics query (clipping invocations).
//!
//! Eq. 17's Delta is measured in display units, as the paper's (its radiance values are the
//! displayed pixel values in [0, 1]): each radiance goes through this renderer's display mapping
//! (exposure, ACES fit, sRGB transfer) before the difference (`glsl/vv/vv_tess.vert`).
//!
//! Shading (`glsl/include/vv_data.glsl`): the diffuse integral over the visible directions from
//! the loops (eq. 9/12); the glossy term as eq. 14, `L_s = k_s U * gamma`, with `k_s U` the
//! scene material's unshadowed glossy reflection exactly as the `env` technique draws it
//! (`env_glossy` in `env_shade.glsl`: the BRDF lobe importance-sampled over the mip-filtered environment) and gamma the
//! Cap-weighted visible share of the cap W around the reflected view direction (eq. 15-16): the
//! occluder loops clipped to W (`vv_clip_*` of `glsl/include/vv_sat.glsl`, the port of
//! `penumbra_math::vv_sat::clip_to_cap`) against W clipped to the normal's hemisphere; exactly 1
//! when no occluder reaches W. W's Phong exponent follows the material's GGX alpha `a` (Blinn-Phong
//! `s = 2 / a^2 - 2`, Phong `s / 4`, within [1, 4096]); its radius holds 95 % of the lobe's energy.
//! Materials come from the frame's material table through `material.glsl` (albedo and roughness
//! maps, animated roughness); per vertex only its material index is stored. Local lights
//! (`lights.glsl`, up to [`MAX_LIGHTS`]) are shadowed by rays through the scene's kd-tree
//! (`light_shadows = traced`, default; a sphere light by rays to its disk), or with point
//! visibility from the same loops (`loops`: occluded when the loops wind around the light's
//! direction; hard shadows, a sphere light as its centre; the loops carry no depth, so an
//! occluder behind a light still shadows it). The paper lights by the environment only. The
//! interpolated modes shade triangles whose correspondence is unsound by eq. 19
//! ([`VvSettings::fallback`]). Receivers made of large triangles are refined ([`scene_model`]).
//! Objects that move or deform are not supported (their visibility is precomputed at rest, t = 0).

use crate::shade_env::{ShadeEnvPass, HDR_FORMAT};
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{bail, Context as _, Result};
use glam::DVec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_math::vv::{Correspondence, VectorizedVisibility, VvModel, VvParams};
use penumbra_scene::Scene;
use std::sync::Arc;

/// Local lights shaded with visibility (`VV_MAX_LIGHTS` of `glsl/include/vv_data.glsl`).
pub const MAX_LIGHTS: u32 = 8;

/// Width of the 2D images holding flat arrays (`vv_tc` in `glsl/include/vv_data.glsl`).
pub const TEX_W: usize = 4096;

/// Statistics of a `vv` technique (`Renderer::technique_stats::<VvStats>()`).
#[derive(Clone, Debug, Default)]
pub struct VvStats {
    /// Triangles after tessellation in the last finished frame (tessellated modes, once a
    /// frame's pipeline statistics are available).
    pub tessellated_triangles: Option<u64>,
    /// Triangles shaded by eq. 19 in an interpolated mode, their correspondence being unsound
    /// ([`VvSettings::fallback`]), and all triangles.
    pub fallback_triangles: usize,
    pub triangles: usize,
}

/// Shading modes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VvMode {
    Fragment3,
    Fragment1,
    Tessellation,
    Tessellation3,
}

impl VvMode {
    pub fn name(self) -> &'static str {
        match self {
            VvMode::Fragment3 => "fragment3",
            VvMode::Fragment1 => "fragment1",
            VvMode::Tessellation => "tessellation",
            VvMode::Tessellation3 => "tessellation3",
        }
    }
    fn code(self) -> i32 {
        match self {
            VvMode::Fragment3 => 0,
            VvMode::Fragment1 => 1,
            VvMode::Tessellation => 2,
            VvMode::Tessellation3 => 3,
        }
    }
    pub fn tessellated(self) -> bool {
        matches!(self, VvMode::Tessellation | VvMode::Tessellation3)
    }
    /// Uses the correspondence (eq. 21).
    pub fn interpolated(self) -> bool {
        matches!(self, VvMode::Fragment1 | VvMode::Tessellation)
    }
}

/// Parameters (`[technique_params]` / `--param`).
#[derive(Clone, Debug, PartialEq)]
pub struct VvSettings {
    pub mode: VvMode,
    /// Tessellation quality zeta of eq. 18 (paper: 1 to 4).
    pub zeta: f32,
    /// `alpha'` of eq. 11 in 1/texel of the SAT map.
    pub alpha: f32,
    /// Width of the SAT map (the environment is box-downsampled to it; height = width / 2).
    pub sat_width: u32,
    /// Arcs of the hemisphere (horizon) loop.
    pub hemisphere_arcs: u32,
    /// Largest tessellation level.
    pub max_level: u32,
    /// Visibility-map resolution of the precompute (part A's `VvParams::resolution`).
    pub resolution: u32,
    /// Specular term of glossy materials (eq. 14-16); off: their diffuse part only.
    pub specular: bool,
    /// Receiver refinement: about this many vertices spread over the scene's area (edges longer
    /// than `sqrt(area / refine)` are split, [`scene_model`]); 0 keeps the meshes as given.
    pub refine: u32,
    /// Interpolated modes: triangles whose eq. 21 occluded solid angle disagrees with eq. 19's by
    /// more than this (sr, `penumbra_math::vv::interpolation_disagreement`) are shaded by eq. 19;
    /// 0 = eq. 21 everywhere (the paper).
    pub fallback: f32,
    /// Local lights' shadows by shadow rays through the scene's kd-tree (`true`, default;
    /// `light_shadows = traced`) or from the occluder loops (`false`, `loops`: no depth, so an
    /// occluder behind a light still shadows it; the paper lights by the environment only).
    pub traced_lights: bool,
}

impl Default for VvSettings {
    fn default() -> Self {
        VvSettings {
            mode: VvMode::Fragment1,
            zeta: 2.0,
            alpha: penumbra_math::vv_sat::DEFAULT_ALPHA as f32,
            sat_width: 256,
            hemisphere_arcs: 32,
            max_level: 64,
            resolution: VvParams::default().resolution,
            specular: true,
            refine: 1024,
            fallback: 0.05,
            traced_lights: true,
        }
    }
}

impl VvSettings {
    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> Result<Self> {
        crate::technique::settings_from_params(params, Self::set)
    }

    /// Keys: `mode` (fragment3, fragment1, tessellation, tessellation3; default fragment1),
    /// `zeta` (0..=16, default 2), `alpha` (> 0, default 2), `sat_width` (16..=4096, even,
    /// default 256), `arcs` (8..=256, default 32), `max_level` (1..=64), `resolution` (8..=1024),
    /// `specular` (on / off, default on), `refine` (0..=65536, default 1024), `fallback` (0..=10
    /// sr, default 0.05; 0 = off), `light_shadows` (traced / loops, default traced).
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("vv", key, value);
        let num = |lo: f64, hi: f64| p.float(lo, hi);
        let int = |lo: u64, hi: u64| p.int(lo, hi).map(|x| x as u32);
        match p.key() {
            "mode" => {
                self.mode = p.choice(&[
                    ("fragment3", VvMode::Fragment3),
                    ("fragment1", VvMode::Fragment1),
                    ("tessellation", VvMode::Tessellation),
                    ("tessellation3", VvMode::Tessellation3),
                ])?
            }
            "zeta" => self.zeta = num(0.0, 16.0)? as f32,
            "alpha" => self.alpha = num(1e-3, 1e3)? as f32,
            "sat_width" => {
                self.sat_width = int(16, 4096)?;
                if !self.sat_width.is_multiple_of(2) {
                    return Err(p.bad("an even integer in 16..=4096"));
                }
            }
            "arcs" => self.hemisphere_arcs = int(8, 256)?,
            "max_level" => self.max_level = int(1, 64)?,
            "resolution" => self.resolution = int(8, 1024)?,
            "refine" => self.refine = int(0, 65536)?,
            "fallback" => self.fallback = num(0.0, 10.0)? as f32,
            "specular" => {
                self.specular = p.choice(&[
                    ("on", true),
                    ("true", true),
                    ("1", true),
                    ("off", false),
                    ("false", false),
                    ("0", false),
                ])?
            }
            "light_shadows" => self.traced_lights = p.choice(&[("traced", true), ("loops", false)])?,
            _ => return Err(p.unknown(
                "mode, zeta, alpha, sat_width, arcs, max_level, resolution, specular, refine, fallback, light_shadows",
            )),
        }
        Ok(())
    }
}

/// The geometry vv shades: the scene's objects in world space (object order), their long
/// triangles refined ([`VvSettings::refine`]), with each vertex's texture coordinate and object.
pub struct VvGeometry {
    pub model: VvModel,
    /// Per model vertex: texture coordinate.
    pub uvs: Vec<glam::Vec2>,
    /// Per model vertex: index of its object in `scene.objects`.
    pub object: Vec<u32>,
}

/// The edge length limit for a refinement target of `refine` vertices over `area` (world
/// units): `sqrt(area / refine)`, 0 for `refine = 0` (no refinement).
pub fn refine_edge(area: f64, refine: u32) -> f32 {
    if refine == 0 || !(area > 0.0) {
        0.0
    } else {
        (area / refine as f64).sqrt() as f32
    }
}

/// The model of a scene's shadow-casting and receiving objects in world space (object order).
/// Vectorized visibility is sampled at vertices (section II-B): a receiver made of a few large
/// triangles (a two-triangle floor) has its visibility known at its corners only, far from the
/// shadows falling on it, and renders unshadowed. With `refine > 0` every edge longer than
/// [`refine_edge`]`(scene area, refine)`, and than twice the scene's median edge, is split
/// ([`penumbra_scene::MeshData::refine_long_edges`], conforming, on the same flat triangles),
/// so such receivers get vertices at the scale of
/// their shadows; finely tessellated meshes are left as they are. `refine = 0` keeps the
/// scene's meshes (the paper's coarse models as given).
pub fn scene_model(scene: &Scene, refine: u32) -> Result<VvGeometry> {
    let mut world = Vec::new();
    for (i, o) in scene.objects.iter().enumerate() {
        let info = scene.object_info(i);
        if info.is_moving() || info.is_deforming() {
            bail!("vv: object '{}' moves or deforms; vectorized visibility is precomputed for static geometry", o.name);
        }
        let m = scene.meshes.get(o.mesh).with_context(|| format!("vv: object '{}' has no mesh", o.name))?;
        world.push((m.transformed(o.transform), info.casts_shadow));
    }
    let area: f64 = world
        .iter()
        .map(|(m, _)| {
            m.indices
                .chunks_exact(3)
                .map(|t| {
                    let p = |k: usize| m.positions[t[k] as usize].as_dvec3();
                    0.5 * (p(1) - p(0)).cross(p(2) - p(0)).length()
                })
                .sum::<f64>()
        })
        .sum();
    // never below twice the scene's median edge: only triangles far larger than the scene's
    // typical one (floors, walls) are split, a uniformly tessellated model stays as given
    let mut edges: Vec<f32> = world
        .iter()
        .flat_map(|(m, _)| {
            m.indices.chunks_exact(3).flat_map(move |t| {
                (0..3).map(move |k| (m.positions[t[k] as usize] - m.positions[t[(k + 1) % 3] as usize]).length())
            })
        })
        .collect();
    let median = if edges.is_empty() {
        0.0
    } else {
        let mid = edges.len() / 2;
        *edges.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    let max_edge = match refine_edge(area, refine) {
        h if h > 0.0 => h.max(2.0 * median),
        h => h,
    };
    let (mut objs, mut uvs, mut object) = (Vec::new(), Vec::new(), Vec::new());
    let cap = 8 * refine as usize + world.iter().map(|(m, _)| m.triangle_count()).sum::<usize>();
    let refined: Vec<(penumbra_scene::MeshData, bool)> =
        world.into_iter().map(|(m, c)| (m.refine_long_edges(max_edge, cap), c)).collect();
    for (i, (m, casts_shadow)) in refined.iter().enumerate() {
        uvs.extend((0..m.positions.len()).map(|v| m.uvs.get(v).copied().unwrap_or_default()));
        object.extend(std::iter::repeat_n(i as u32, m.positions.len()));
        objs.push(penumbra_math::vv::ObjectMesh {
            positions: &m.positions,
            normals: &m.normals,
            indices: &m.indices,
            world: glam::Mat4::IDENTITY,
            casts_shadow: *casts_shadow,
        });
    }
    let model = VvModel::from_objects(objs);
    model.validate().map_err(anyhow::Error::msg)?;
    Ok(VvGeometry { model, uvs, object })
}

/// Offline data of a scene and its cost.
pub struct VvSceneData {
    pub geometry: VvGeometry,
    pub vis: VectorizedVisibility,
    pub corr: Option<Correspondence>,
    pub visibility_seconds: f64,
    pub correspondence_seconds: f64,
    pub visibility_bytes: usize,
    pub triple_bytes: usize,
}

impl VvSceneData {
    /// The scene's data through the on-disk cache (`<temp>/penumbra-vv/<scene>-<model hash>-
    /// <parameters hash>.pvv`, `penumbra_math::vv::load_or_compute`): computed once per model
    /// (after refinement) and resolution, then read back by every technique, test and bench
    /// process that needs it (a stale or corrupt file is recomputed). No state is kept in the
    /// process.
    pub fn cached(scene: &Scene, resolution: u32, refine: u32) -> Result<Arc<Self>> {
        let geometry = scene_model(scene, refine)?;
        let params = VvParams { resolution, ..Default::default() };
        params.validate().map_err(anyhow::Error::msg)?;
        let dir = std::env::temp_dir().join("penumbra-vv");
        let model = &geometry.model;
        let bar = progress_bar(model.positions.len() as u64 + 2 * model.triangle_count() as u64, "vv precompute");
        let (d, _) = penumbra_math::vv::load_or_compute(model, &params, &dir, &scene.name, &|_, k| bar.inc(k))
            .map_err(anyhow::Error::msg)?;
        bar.finish_and_clear();
        let vis = d.vis;
        let corr = d.corr;
        let visibility_bytes = vis.points.len() * 16 + (vis.seq_offsets.len() + 2 * vis.vertex_seqs.len()) * 4;
        let triple_bytes = corr.triple_bytes();
        Ok(Arc::new(VvSceneData {
            geometry,
            vis,
            corr: Some(corr),
            visibility_seconds: d.stats.visibility_seconds,
            correspondence_seconds: d.stats.correspondence_seconds,
            visibility_bytes,
            triple_bytes,
        }))
    }

    pub fn model(&self) -> &VvModel {
        &self.geometry.model
    }
}

/// A progress bar on stderr (hidden with `PENUMBRA_NO_PROGRESS`).
fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!("{what} {{bar:40}} {{pos}}/{{len}} {{elapsed}}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    if std::env::var_os("PENUMBRA_NO_PROGRESS").is_some() {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar
}

/// Per model vertex of `geo`: the index of its object's material in the scene's material table
/// (the shaders read the frame's `MaterialData` through material.glsl).
pub fn vertex_materials(scene: &Scene, geo: &VvGeometry) -> Vec<u32> {
    geo.object.iter().map(|&o| scene.objects.get(o as usize).map_or(0, |o| o.material as u32)).collect()
}

/// GPU images' contents (built once).
struct Uploads {
    points: (Vec<u8>, u32),
    ints: (Vec<u8>, u32),
    verts: (Vec<u8>, u32),
    off0: [i32; 4],
    off1: [i32; 4],
    triangles: u32,
    sat_w: u32,
    sat_h: u32,
    env: Arc<Vec<u8>>,
    blurred: Arc<Vec<u8>>,
    /// Triangles shaded by eq. 19 in the interpolated modes (`VvSettings::fallback`).
    fallback_triangles: usize,
    /// Hash of the three arrays (the persistent images' names).
    key: u64,
}

fn pad_rows<T: Copy + Default>(mut v: Vec<T>, per_texel: usize) -> (Vec<T>, u32) {
    let texels = (v.len() / per_texel).max(1);
    let rows = texels.div_ceil(TEX_W);
    v.resize(rows * TEX_W * per_texel, T::default());
    (v, rows as u32)
}

/// Box-downsamples a lat-long map to `w x w/2` (or keeps it when smaller), times `intensity` 1.
pub fn downsample(width: usize, height: usize, texels: &[[f32; 3]], w: usize) -> (usize, usize, Vec<[f32; 3]>) {
    let w = w.min(width).max(2);
    let h = (w / 2).max(1);
    let mut out = vec![[0.0f32; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            let (x0, x1) = (x * width / w, ((x + 1) * width / w).max(x * width / w + 1));
            let (y0, y1) = (y * height / h, ((y + 1) * height / h).max(y * height / h + 1));
            let mut s = [0.0f64; 3];
            let mut wsum = 0.0;
            for yy in y0..y1.min(height) {
                // texel solid angle weight within the box
                let th = std::f64::consts::PI * (yy as f64 + 0.5) / height as f64;
                let wt = th.sin();
                for xx in x0..x1.min(width) {
                    let t = texels[yy * width + xx];
                    for c in 0..3 {
                        let v = t[c] as f64;
                        s[c] += if v.is_finite() && v > 0.0 { v * wt } else { 0.0 };
                    }
                    wsum += wt;
                }
            }
            out[y * w + x] = [(s[0] / wsum) as f32, (s[1] / wsum) as f32, (s[2] / wsum) as f32];
        }
    }
    (w, h, out)
}

/// The lighting blurred with a normalised Phong lobe `cos^alpha` (eq. 17's `L'`), brute force.
pub fn phong_blur(width: usize, height: usize, texels: &[[f32; 3]], alpha: f64) -> Vec<[f32; 3]> {
    use rayon::prelude::*;
    let dirs: Vec<DVec3> = (0..width * height)
        .map(|i| {
            penumbra_math::envmap::latlong_direction(
                ((i % width) as f64 + 0.5) / width as f64,
                ((i / width) as f64 + 0.5) / height as f64,
            )
        })
        .collect();
    let sa: Vec<f64> = (0..height)
        .map(|y| {
            let t0 = std::f64::consts::PI * y as f64 / height as f64;
            let t1 = std::f64::consts::PI * (y + 1) as f64 / height as f64;
            (t0.cos() - t1.cos()) * 2.0 * std::f64::consts::PI / width as f64
        })
        .collect();
    let cut = 1e-4f64.powf(1.0 / alpha);
    (0..width * height)
        .into_par_iter()
        .map(|i| {
            let d = dirs[i];
            let (mut s, mut w) = (DVec3::ZERO, 0.0);
            for (j, e) in dirs.iter().enumerate() {
                let c = d.dot(*e);
                if c > cut {
                    let k = c.powf(alpha) * sa[j / width];
                    let t = texels[j];
                    s += DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64).max(DVec3::ZERO) * k;
                    w += k;
                }
            }
            let r = if w > 0.0 { s / w } else { DVec3::ZERO };
            [r.x as f32, r.y as f32, r.z as f32]
        })
        .collect()
}

impl Uploads {
    fn new(scene: &Scene, data: &VvSceneData, settings: &VvSettings) -> Result<Self> {
        let vis = &data.vis;
        let model = data.model();
        let mut ints: Vec<u32> = Vec::new();
        let off_seq = ints.len();
        ints.extend(&vis.seq_offsets);
        let off_vseq = ints.len();
        for s in &vis.vertex_seqs {
            ints.extend(s);
        }
        let (off_tri, off_loop, off_triples);
        let empty = Correspondence {
            tri_offsets: vec![0; model.triangle_count() + 1],
            loop_offsets: vec![0],
            triples: Vec::new(),
        };
        let corr = data.corr.as_ref().unwrap_or(&empty);
        off_tri = ints.len();
        // bit 31 of a triangle's first loop offset: its eq. 21 interpolation disagrees with eq. 19
        // (penumbra_math::vv::interpolation_disagreement) by more than `fallback`: shaded by eq. 19
        let fallback = if settings.fallback > 0.0 && settings.mode.interpolated() && data.corr.is_some() {
            penumbra_math::vv::interpolation_disagreement(model, vis, corr)
                .iter()
                .map(|&d| d > settings.fallback)
                .collect()
        } else {
            vec![false; model.triangle_count()]
        };
        let fallback_triangles = fallback.iter().filter(|f| **f).count();
        ints.extend(corr.tri_offsets.iter().enumerate().map(|(t, &o)| {
            if fallback.get(t) == Some(&true) {
                o | 1 << 31
            } else {
                o
            }
        }));
        if corr.tri_offsets.last().is_some_and(|&o| o >= 1 << 31) {
            bail!("vv: too many triple loops for the GPU layout");
        }
        off_loop = ints.len();
        ints.extend(&corr.loop_offsets);
        off_triples = ints.len();
        for t in &corr.triples {
            ints.extend(t);
        }
        let off_tv = ints.len();
        ints.extend(&model.indices);
        if ints.len() >= (1 << 31) || vis.points.len() >= (1 << 31) {
            bail!("vv: data too large for the GPU layout");
        }
        let (ints, ints_rows) = pad_rows(ints, 1);
        let mut points: Vec<f32> = vis.points.iter().flatten().copied().collect();
        if points.is_empty() {
            points.extend([0.0; 4]);
        }
        let (points, points_rows) = pad_rows(points, 4);
        // materials from the scene itself (the cached data may come from a scene with the same
        // geometry and other materials)
        let material = vertex_materials(scene, &data.geometry);
        let mut verts = Vec::with_capacity(model.positions.len() * 12);
        for (i, p) in model.positions.iter().enumerate() {
            let n = model.normals[i];
            let uv = data.geometry.uvs.get(i).copied().unwrap_or_default();
            let mat = material.get(i).copied().unwrap_or(0) as f32;
            // (position, u), (normal, v), (material index, 0, 0, 0): vv_data.glsl
            verts.extend([p.x, p.y, p.z, uv.x, n.x, n.y, n.z, uv.y, mat, 0.0, 0.0, 0.0]);
        }
        let (verts, verts_rows) = pad_rows(verts, 4);
        let env = scene
            .environment
            .as_ref()
            .context("vv: the scene has no environment map (the technique integrates environment lighting)")?;
        let (w, h, small) =
            downsample(env.width as usize, env.height as usize, &env.texels, settings.sat_width as usize);
        let blurred = if settings.mode.tessellated() { phong_blur(w, h, &small, 256.0) } else { small.clone() };
        let rgba = |t: &[[f32; 3]]| -> Vec<u8> {
            bytes_of(&t.iter().map(|c| [c[0], c[1], c[2], 0.0]).collect::<Vec<[f32; 4]>>())
        };
        let (points, ints, verts) = (bytes_of(&points), bytes_of(&ints), bytes_of(&verts));
        let key = {
            use std::hash::{Hash, Hasher};
            let mut h = std::collections::hash_map::DefaultHasher::new();
            (&points, &ints, &verts).hash(&mut h);
            h.finish()
        };
        Ok(Uploads {
            points: (points, points_rows),
            ints: (ints, ints_rows),
            verts: (verts, verts_rows),
            key,
            off0: [off_seq as i32, off_vseq as i32, off_tri as i32, off_loop as i32],
            off1: [off_triples as i32, off_tv as i32, settings.max_level as i32, 0],
            triangles: model.triangle_count() as u32,
            sat_w: w as u32,
            sat_h: h as u32,
            env: Arc::new(rgba(&small)),
            blurred: Arc::new(rgba(&blurred)),
            fallback_triangles,
        })
    }
}

/// The `"vv"` technique.
pub struct VvTechnique {
    ctx: Arc<Context>,
    rows: Pipeline,
    cols: Pipeline,
    /// `None` for [`VvTechnique::sat_only`].
    raster: Option<Pipeline>,
    composite: Pipeline,
    env: ShadeEnvPass,
    nearest: Sampler,
    /// Material texture maps (repeat).
    repeat: Sampler,
    latlong: Sampler,
    settings: VvSettings,
    up: Uploads,
    /// The pipeline-statistics query (null without `pipelineStatisticsQuery`).
    query: vk::QueryPool,
    pub data: Arc<VvSceneData>,
    /// The scene's kd-tree for the local lights' shadow rays (`light_shadows = traced`).
    kd: Option<crate::kdtree::KdTreeBuilder>,
}

impl Drop for VvTechnique {
    fn drop(&mut self) {
        if self.query != vk::QueryPool::null() {
            unsafe { self.ctx.device.destroy_query_pool(self.query, None) };
        }
    }
}

/// The stages of vv's raster pipeline (`tess`: the tessellated mode's), which its push
/// constants are visible to.
fn raster_stages(tess: bool) -> vk::ShaderStageFlags {
    let tess_stages = vk::ShaderStageFlags::TESSELLATION_CONTROL | vk::ShaderStageFlags::TESSELLATION_EVALUATION;
    vk::ShaderStageFlags::VERTEX | vk::ShaderStageFlags::FRAGMENT | if tess { tess_stages } else { Default::default() }
}

fn raster_pipeline(ctx: &Arc<Context>, shaders: &ShaderLibrary, tess: bool) -> Result<Pipeline> {
    let (name, files): (&str, &[&str]) = if tess {
        ("vv_tess", &["vv/vv_tess.vert", "vv/vv_tess.tesc", "vv/vv_tess.tese", "vv/vv_tess.frag"])
    } else {
        ("vv_shade", &["vv/vv_shade.vert", "vv/vv_shade.frag"])
    };
    let desc = crate::raster::RasterDesc {
        name,
        shaders: files,
        push_constant_bytes: 64,
        topology: if tess { vk::PrimitiveTopology::PATCH_LIST } else { vk::PrimitiveTopology::TRIANGLE_LIST },
        patch_control_points: if tess { 3 } else { 0 },
        colors: &[HDR_FORMAT],
        depth: Some(crate::raster::DepthState {
            format: crate::gbuffer::DEPTH_FORMAT,
            write: true,
            compare: vk::CompareOp::LESS,
        }),
        ..Default::default()
    };
    crate::raster::raster_pipeline(ctx, shaders, &desc)
}

impl VvTechnique {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, settings: VvSettings) -> Result<Self> {
        let data = VvSceneData::cached(scene, settings.resolution, settings.refine)?;
        Self::with_data(ctx, shaders, scene, settings, data)
    }

    /// Without the raster pipeline (the large shading shaders, the slowest part of creation on
    /// lavapipe): for [`VvTechnique::add_sat`] and [`crate::kernels::vv::VvParity`] in tests; [`Technique::add`]
    /// then fails.
    ///
    /// [`Technique::add`]: crate::technique::Technique::add
    pub fn sat_only(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, settings: VvSettings) -> Result<Self> {
        let data = VvSceneData::cached(scene, settings.resolution, settings.refine)?;
        Self::build(ctx, shaders, scene, settings, data, false)
    }

    /// With precomputed data (shared between techniques of a bench).
    pub fn with_data(
        ctx: &Arc<Context>,
        shaders: &ShaderLibrary,
        scene: &Scene,
        settings: VvSettings,
        data: Arc<VvSceneData>,
    ) -> Result<Self> {
        Self::build(ctx, shaders, scene, settings, data, true)
    }

    fn build(
        ctx: &Arc<Context>,
        shaders: &ShaderLibrary,
        scene: &Scene,
        settings: VvSettings,
        data: Arc<VvSceneData>,
        raster: bool,
    ) -> Result<Self> {
        if settings.mode.interpolated() && data.corr.is_none() {
            bail!(
                "vv: mode {} needs the per-triangle correspondence (triple lists), which is not available yet",
                settings.mode.name()
            );
        }
        let rows = compute_pipeline(ctx, shaders, "vv/vv_sat_rows.comp", 8)?;
        let cols = compute_pipeline(ctx, shaders, "vv/vv_sat_cols.comp", 8)?;
        if raster && settings.mode.tessellated() && !ctx.tessellation_shader {
            return Err(crate::registry::BadInput(format!(
                "vv: mode {} needs tessellation shaders, which this device (or the application that created it) has not enabled; use mode = fragment1 or fragment3",
                settings.mode.name()
            ))
            .into());
        }
        let raster = if raster { Some(raster_pipeline(ctx, shaders, settings.mode.tessellated())?) } else { None };
        // the kd-tree of the local lights' shadow rays (traced, with local lights to shade)
        let kd = if raster.is_some() && settings.traced_lights && !scene.lights.is_empty() {
            Some(crate::kdtree::KdTreeBuilder::new(ctx, shaders)?)
        } else {
            None
        };
        let composite = compute_pipeline(ctx, shaders, "vv/vv_composite.comp", 0)?;
        let up = Uploads::new(scene, &data, &settings)?;
        let qci = vk::QueryPoolCreateInfo::default()
            .query_type(vk::QueryType::PIPELINE_STATISTICS)
            .query_count(1)
            .pipeline_statistics(vk::QueryPipelineStatisticFlags::CLIPPING_INVOCATIONS);
        let query = if ctx.pipeline_statistics_query {
            let q = unsafe { ctx.device.create_query_pool(&qci, None)? };
            ctx.set_name(q, "vv_statistics");
            q
        } else {
            vk::QueryPool::null()
        };
        Ok(VvTechnique {
            ctx: ctx.clone(),
            rows,
            cols,
            raster,
            composite,
            env: ShadeEnvPass::new(ctx, shaders)?,
            nearest: Sampler::nearest(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            latlong: Sampler::latlong(ctx)?,
            kd,
            settings,
            up,
            query,
            data,
        })
    }

    pub fn settings(&self) -> &VvSettings {
        &self.settings
    }

    /// Triangles rasterized by the last finished frame (pipeline statistics), if available.
    pub fn read_triangle_count(&self) -> Option<u64> {
        if self.query == vk::QueryPool::null() {
            return None;
        }
        let mut r = [0u64; 1];
        let ok =
            unsafe { self.ctx.device.get_query_pool_results(self.query, 0, &mut r, vk::QueryResultFlags::TYPE_64) };
        ok.ok().map(|_| r[0])
    }

    /// What the parity kernels (`crate::kernels::vv`) need of the technique: SAT map width and
    /// height, hemisphere arcs, alpha' and the nearest sampler.
    pub(crate) fn sat_params(&self) -> (u32, u32, u32, f32, vk::Sampler) {
        (self.up.sat_w, self.up.sat_h, self.settings.hemisphere_arcs, self.settings.alpha, self.nearest.sampler)
    }

    /// The SAT map (width, height, RGBA32F texels of the downsampled environment).
    pub fn sat_input(&self) -> (u32, u32, Arc<Vec<u8>>) {
        (self.up.sat_w, self.up.sat_h, self.up.env.clone())
    }

    /// `vv_sat_rows` + `vv_sat_cols`: the SAT of `texels` (RGBA32F bytes of a
    /// [`VvTechnique::sat_input`]-sized map) as an image of `(W + 1) x 4 (H + 1)` corners
    /// (channels x, y, z of `l L_e` and `L_e`).
    pub fn add_sat(&self, graph: &mut Graph, name: &str, texels: &Arc<Vec<u8>>) -> ImageHandle {
        let (w, h) = (self.up.sat_w, self.up.sat_h);
        let input = graph.create_buffer_init(&format!("{name}_texels"), texels.as_ref().clone());
        let sat = graph.create_image(name, ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, w + 1, 4 * (h + 1)));
        let mut push = Vec::new();
        push.extend_from_slice(&(w as i32).to_le_bytes());
        push.extend_from_slice(&(h as i32).to_le_bytes());
        let mut p = graph.pass(&format!("{name}_rows"), PassKind::Compute);
        let input = p.read(input, Access::ComputeShaderReadStorage);
        let sat = p.write(sat, Access::ComputeShaderWriteStorage);
        let pipe = self.rows.handle();
        let push1 = push.clone();
        p.record(move |rc| {
            let binds = [Bind::StorageBuffer(input), Bind::StorageImage(sat)];
            crate::util::dispatch(rc, pipe, &binds, &push1, [groups(h + 1, 64), 1, 1])
        });
        let mut p = graph.pass(&format!("{name}_cols"), PassKind::Compute);
        let sat = p.write(sat, Access::ComputeShaderReadWriteStorage);
        let pipe = self.cols.handle();
        p.record(move |rc| {
            crate::util::dispatch(rc, pipe, &[Bind::StorageImage(sat)], &push, [groups(w + 1, 64), 1, 1])
        });
        sat
    }

    /// A flat-array image (`R32G32B32A32_SFLOAT` or `R32_UINT`, width [`TEX_W`]) kept by the
    /// engine across frames, uploaded on the first frame only (static data: no per-frame
    /// re-upload). Its name carries the hash of the technique's data (`Uploads::key`), so two vv
    /// techniques on one engine never read each other's arrays.
    fn add_array(
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        name: &str,
        key: u64,
        format: vk::Format,
        bytes: &[u8],
        rows: u32,
    ) -> ImageHandle {
        let img = engine.persistent_image(
            graph,
            &format!("{name}.{key:016x}"),
            ImageDesc::new_2d(format, TEX_W as u32, rows),
        );
        if !graph.persistent_is_new(img) {
            return img;
        }
        let part = crate::util::Subresource { mip: 0, layer: 0, width: TEX_W as u32, height: rows, bytes };
        crate::util::add_image_upload(graph, name, img, [part])
    }
}

impl crate::technique::Technique for VvTechnique {
    fn name(&self) -> &'static str {
        "vv"
    }

    fn stats(&self) -> Option<Box<dyn std::any::Any>> {
        // non-blocking: the query holds the last finished frame's count
        let tessellated_triangles = if self.settings.mode.tessellated() { self.read_triangle_count() } else { None };
        Some(Box::new(VvStats {
            tessellated_triangles,
            fallback_triangles: self.up.fallback_triangles,
            triangles: self.up.triangles as usize,
        }))
    }

    fn limitations(&self, scene: &penumbra_scene::Scene) -> Vec<String> {
        // texture maps, animated roughness: the scene's materials through material.glsl
        let mut v = Vec::new();
        if scene.lights.len() > MAX_LIGHTS as usize {
            v.push(format!(
                "vv: only the first {MAX_LIGHTS} of the scene's {} local lights are rendered on vv-shaded objects",
                scene.lights.len()
            ));
        }
        v
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        let base = self.env.add(graph, inputs.handles, inputs.gbuffer, inputs.env);
        let sat = self.add_sat(graph, "vv_sat", &self.up.env);
        let blur = if self.settings.mode.tessellated() {
            Some(self.add_sat(graph, "vv_sat_blur", &self.up.blurred))
        } else {
            None
        };
        let key = self.up.key;
        let (vec4, uint) = (vk::Format::R32G32B32A32_SFLOAT, vk::Format::R32_UINT);
        let mut array = |name: &str, format, (bytes, rows): &(Vec<u8>, u32)| {
            Self::add_array(engine, graph, name, key, format, bytes, *rows)
        };
        let points = array("vv_points", vec4, &self.up.points);
        let ints = array("vv_ints", uint, &self.up.ints);
        let verts = array("vv_verts", vec4, &self.up.verts);
        // the scene's triangles for the local lights' shadow rays (built once: vv's scenes are
        // static), or placeholders without local lights
        let (kd_bufs, kd_tree) = crate::kdtree::KdTreeBuilder::add_frame_or_stand_ins(
            self.kd.as_mut().filter(|_| inputs.handles.light_count > 0),
            engine,
            graph,
            inputs.scene,
            inputs.frame,
            "vv",
        )?;
        let (w, h) = (inputs.gbuffer.width, inputs.gbuffer.height);
        let depth = graph.create_image("vv_depth", ImageDesc::new_2d(crate::gbuffer::DEPTH_FORMAT, w, h));
        let objects = graph.create_image("vv_objects", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let tess = self.settings.mode.tessellated();
        let mut p = graph.pass(if tess { "vv_tess" } else { "vv_shade" }, PassKind::Raster);
        let objects = p.write(objects, Access::ColorAttachmentWrite);
        let depth = p.write(depth, Access::DepthAttachmentWrite);
        let camera = p.read(inputs.handles.camera, Access::AnyShaderReadUniform);
        let [points, ints, verts, sat] = [points, ints, verts, sat].map(|h| p.read(h, Access::AnyShaderReadSampled));
        let blur = blur.map(|b| p.read(b, Access::AnyShaderReadSampled)).unwrap_or(sat);
        let textures = p.read(inputs.handles.textures, Access::AnyShaderReadSampled);
        let materials = p.read(inputs.handles.materials, Access::AnyShaderReadStorage);
        let env_map = p.read(inputs.env, Access::AnyShaderReadSampled);
        let lights = p.read(inputs.handles.lights, Access::AnyShaderReadStorage);
        let kd = crate::kdtree::KdTreeReads::declare(&mut p, kd_bufs, true);
        let mut off1 = self.up.off1;
        off1[3] = inputs.handles.light_count.min(MAX_LIGHTS) as i32;
        let mut push = Vec::with_capacity(64);
        for v in [
            self.up.sat_w as i32,
            self.up.sat_h as i32,
            self.settings.hemisphere_arcs as i32,
            self.settings.mode.code(),
        ] {
            push.extend_from_slice(&v.to_le_bytes());
        }
        for v in self.up.off0.iter().chain(&off1) {
            push.extend_from_slice(&v.to_le_bytes());
        }
        let traced = if kd_tree { 1.0 } else { 0.0 };
        for v in [self.settings.alpha, self.settings.zeta, if self.settings.specular { 1.0 } else { 0.0 }, traced] {
            push.extend_from_slice(&v.to_le_bytes());
        }
        let raster =
            self.raster.as_ref().context("vv: technique built without its raster pipeline (VvTechnique::sat_only)")?;
        let layout = raster.handle();
        let (nearest, repeat, latlong) = (self.nearest.sampler, self.repeat.sampler, self.latlong.sampler);
        let vertex_count = 3 * self.up.triangles;
        let query = self.query;
        p.record(move |rc| {
            let d = rc.device();
            let color = [crate::util::color_attachment(rc.image(objects)?.view, [0.0; 4])];
            let depth_att = crate::util::depth_attachment(rc.image(depth)?.view, true);
            let info = crate::raster::rendering_info(w, h, &color, &depth_att);
            unsafe {
                if query != vk::QueryPool::null() {
                    d.cmd_reset_query_pool(rc.cmd, query, 0, 1);
                    d.cmd_begin_query(rc.cmd, query, 0, vk::QueryControlFlags::empty());
                }
            }
            crate::raster::begin(
                rc,
                &info,
                w,
                h,
                &layout,
                &[
                    Bind::UniformBuffer(camera),
                    Bind::SampledImage(points, nearest),
                    Bind::SampledImage(ints, nearest),
                    Bind::SampledImage(verts, nearest),
                    Bind::SampledImage(sat, nearest),
                    Bind::SampledImage(blur, nearest),
                    Bind::SampledImage(textures, repeat),
                    Bind::StorageBuffer(materials),
                    Bind::SampledImage(env_map, latlong),
                    Bind::StorageBuffer(lights),
                    Bind::TexelBuffer(kd.tris),
                    Bind::TexelBuffer(kd.nodes),
                    Bind::TexelBuffer(kd.refs),
                    Bind::StorageBuffer(kd.header),
                ],
            )?;
            unsafe {
                d.cmd_push_constants(rc.cmd, layout.layout, raster_stages(tess), 0, &push);
                d.cmd_draw(rc.cmd, vertex_count, 1, 0, 0);
                d.cmd_end_rendering(rc.cmd);
                if query != vk::QueryPool::null() {
                    d.cmd_end_query(rc.cmd, query, 0);
                }
            }
            Ok(())
        });
        let hdr = graph.create_image("vv_hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let mut p = graph.pass("vv_composite", PassKind::Compute);
        let base = p.read(base, Access::ComputeShaderReadSampled);
        let objects = p.read(objects, Access::ComputeShaderReadSampled);
        let hdr = p.write(hdr, Access::ComputeShaderWriteStorage);
        let pipe = self.composite.handle();
        p.record(move |rc| {
            let binds =
                [Bind::SampledImage(base, nearest), Bind::SampledImage(objects, nearest), Bind::StorageImage(hdr)];
            crate::util::dispatch(rc, pipe, &binds, &[], [groups(w, 8), groups(h, 8), 1])
        });
        Ok(hdr)
    }
}

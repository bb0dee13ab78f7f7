//! Technique `shadow-fields-wavelet`: all-frequency shadow fields (Zhou et al. 2005, section 6;
//! Ng et al. 2004's Haar triple product), per pixel on the GPU.
//!
//! * Precompute ([`WaveletFields::build`]): per mesh that casts shadows, a binary visibility cube
//!   map (`6 x n x n`, object frame) at every sample point of every shell (the same shells and
//!   polar sample grid as the SH fields), each face Haar-transformed and cut to the largest
//!   `keep` fraction of coefficients (the paper: 5 %), 8-bit per shell
//!   ([`penumbra_math::shadow_field::haar::HaarField`]), fixed or adaptive (R halved while eq. 1,
//!   L1 in the pixel domain, stays under the threshold).
//! * The GPU holds each sample's truncated map decoded and thresholded back to binary
//!   visibility (`6 n^2` bits per sample, about the compressed size; [`HaarField::shell_bits`])
//!   and `sfw_shade.comp` evaluates, per pixel,
//!   the product of the occluders' maps (bilinear between the sample points of a shell, linear
//!   between shells, each occluder's rotation applied to the lookup direction instead of to its
//!   coefficients) in the pixel domain, which at the map resolution is the Haar triple product
//!   exactly (the product of piecewise-constant maps is piecewise constant on the same pixels).
//!   Diffuse: the environment's exact irradiance at the normal times the visible share of
//!   `L cos` over the cube's pixels (a ratio estimator, so the cube's discretization of the
//!   cosine leaves the unshadowed term alone); glossy: the prefiltered environment along the
//!   reflection times the visible share of the environment's light within the lobe; local
//!   lights analytically (no source radiance fields: a delta light's field is one pixel), times
//!   the occluders' visibility toward them, bilinear in the cube face.
//! * Between a shell's samples each sample looks toward where the point's ray passes nearest
//!   the occluder's centre (`lookup = reproject`, from outside the occluder's bounding sphere),
//!   so the interpolated maps agree on where the occluder is; `direction` is the paper's
//!   lookup (the same direction from every sample: shifted shadows blended). Each occluder's
//!   bounding cone culls its lookups.
//! * Self-occlusion (`self`, the paper's per-vertex self-visibility): a binary cube map per
//!   vertex ([`penumbra_math::shadow_field::haar::self_maps`]); per frame `sfw_self.comp` turns
//!   it into the visible share of the environment's `L cos` and the visibility toward the first
//!   4 lights, and a raster pass interpolates them across the triangles (coarse meshes suffer:
//!   a vertex in a concave crease darkens whole triangles; chess's 400-triangle pieces).
//!
//! * With `light_shadows = traced` (default) the local lights' shadows are rays through the
//!   frame's kd-tree instead, and the environment's key lights (`key_lights`) are split off the
//!   map as moment-matched lights with traced shadows, the cube and the irradiance map holding
//!   the rest (a departure from the paper, which `light_shadows = fields` undoes).
//!
//! What it does not do: deforming shadow casters (refused by the registry, naming them, as the
//! SH fields are: a rigid field cannot follow them), caching of the fields on disk, keeping the
//! maps on the GPU between frames (uploaded every frame), sphere lights' extent (shadowed as
//! points).

use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, Pipeline, Sampler};
use anyhow::{anyhow, Result};
use glam::Vec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, BufferHandle, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_math::shadow_field::haar::{raw_maps, CubeTable, HaarField};
use penumbra_scene::{Environment, EnvironmentState, Scene};
use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::sync::Arc;

/// Options of the all-frequency variant.
#[derive(Clone, Debug)]
pub struct SfwOptions {
    /// Concentric shells per field (paper: 32), radius 0.2 Vr (1 + c): outside the outermost
    /// (6.4 Vr at 32) an object casts nothing, so fewer shells cut long shadows short (16:
    /// sf_spheres' 40x30 error 0.177 of the mean where 32 gives 0.140).
    pub shells: usize,
    /// Initial polar resolution R of every shell (power of two; paper: 64). 32 by default: at 16
    /// sf_spheres' 40x30 error is 0.177 of the mean, at 32 0.140 (32 shells, 16 pixel faces).
    pub resolution: usize,
    /// Cube face resolution n of the visibility maps (power of two; paper: 32).
    pub cube: usize,
    /// Fraction of Haar coefficients kept per map (paper: 0.05).
    pub keep: f64,
    /// Eq. 1 threshold (L1 in the pixel domain) of the adaptive shells (paper: 0.010).
    pub threshold: f64,
    /// Adaptive shells (else every shell at R).
    pub adaptive: bool,
    /// Interpolate between shell samples with each sample looking at where the point's ray
    /// passes the occluder (else along the same direction, the paper's lookup).
    pub reproject: bool,
    /// Per-vertex self-visibility maps, interpolated across the triangles (the paper's
    /// self-occlusion; else a surface sees only the other objects).
    pub self_occlusion: bool,
    /// Local lights' shadows by shadow rays through the frame's kd-tree (`light_shadows =
    /// traced`, default), or from the occluders' fields and the self-visibility maps (`fields`:
    /// the nearest shell samples' cube maps, which shift and double a spot light's hard shadow:
    /// vol_rotating's cube).
    pub light_traced: bool,
    /// With `light_shadows = traced`: the environment's compact bright lights split off its
    /// map as at most this many moment-matched lights with traced shadows (and the glossy
    /// lobe's visibility traced), the rest of the map through the fields (as
    /// `SfOptions::key_lights`; 0: the whole map in the fields, the paper's).
    pub key_lights: usize,
    /// Directory of the precomputed fields and self-visibility maps, one file per mesh and
    /// parameter set (`<hash>.psw`, `<hash>.pss`; `None`: no caching). Default: the shadow
    /// fields' cache directory under the system's temporary directory.
    pub cache_dir: Option<std::path::PathBuf>,
}

impl Default for SfwOptions {
    fn default() -> Self {
        SfwOptions {
            shells: 32,
            resolution: 32,
            cube: 16,
            keep: 0.05,
            threshold: 0.010,
            adaptive: true,
            reproject: true,
            self_occlusion: true,
            light_traced: true,
            key_lights: 4,
            cache_dir: Some(std::env::temp_dir().join("penumbra-shadow-fields")),
        }
    }
}

impl SfwOptions {
    /// Options from `[technique_params]` / `--param` (see [`SfwOptions::set`]).
    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> Result<Self> {
        crate::technique::settings_from_params(params, Self::set)
    }

    /// Sets one parameter: `shells` (1..=64), `resolution` (power of two 1..=64), `cube` (power
    /// of two 2..=64), `keep` (0 < keep <= 1), `threshold` (>= 0), `adaptive` (true/false),
    /// `lookup` (`reproject` | `direction`), `self` (true/false), `light_shadows` (`traced` |
    /// `fields`), `key_lights` (0..=16).
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("shadow-fields-wavelet", key, value);
        if crate::shadow_fields::set_light_option(&mut self.light_traced, &mut self.key_lights, &p)? {
            return Ok(());
        }
        match p.key() {
            "shells" => self.shells = p.int(1, 64)? as usize,
            "resolution" => self.resolution = p.pow2(1, 64)? as usize,
            "cube" => self.cube = p.pow2(2, 64)? as usize,
            "keep" => self.keep = p.number(|x| x > 0.0 && x <= 1.0, "a number in (0, 1]")?,
            "threshold" => self.threshold = p.number(|x| x >= 0.0, "a finite number >= 0")?,
            "adaptive" => self.adaptive = p.flag()?,
            "lookup" => self.reproject = p.choice(&[("reproject", true), ("direction", false)])?,
            "self" => self.self_occlusion = p.flag()?,
            _ => {
                return Err(p.unknown(
                    "shells, resolution, cube, keep, threshold, adaptive, lookup, self, light_shadows, key_lights",
                ))
            }
        }
        Ok(())
    }
}

/// What the precompute built for one mesh.
#[derive(Clone, Debug)]
pub struct WaveletReport {
    pub mesh: String,
    /// Compressed bytes (per kept coefficient a u16 index and a u8 value), fixed / the field
    /// used (adaptive unless `adaptive = false`).
    pub fixed_bytes: usize,
    pub adaptive_bytes: usize,
    /// Per-shell resolution of the field used.
    pub resolutions: Vec<usize>,
    pub seconds: f64,
    /// Loaded from the cache directory (no ray casting).
    pub cached: bool,
}

impl WaveletReport {
    /// A mesh without a field (casts nothing).
    fn empty(mesh: &str) -> Self {
        WaveletReport {
            mesh: mesh.to_string(),
            fixed_bytes: 0,
            adaptive_bytes: 0,
            resolutions: Vec::new(),
            seconds: 0.0,
            cached: false,
        }
    }
}

/// The all-frequency fields of every mesh of a scene (`None`: no triangles, or no object that
/// uses it casts shadows).
pub struct WaveletFields {
    pub fields: Vec<Option<Arc<HaarField>>>,
    /// Per mesh: its vertices' self-visibility maps
    /// ([`penumbra_math::shadow_field::haar::self_maps`]; `None`: no triangles, or
    /// self-occlusion off).
    pub self_maps: Vec<Option<Arc<Vec<u32>>>>,
    /// Seconds spent on the self-visibility maps.
    pub self_seconds: f64,
    pub reports: Vec<WaveletReport>,
    pub options: SfwOptions,
}

impl WaveletFields {
    /// Ray-casts and compresses the field of every mesh (identical meshes share one).
    pub fn build(scene: &Scene, options: &SfwOptions) -> Result<Self> {
        let table = CubeTable::new(options.cube);
        let mut fields: Vec<Option<Arc<HaarField>>> = Vec::new();
        let mut reports = Vec::new();
        let t_self = std::time::Instant::now();
        let mut self_maps: Vec<Option<Arc<Vec<u32>>>> = Vec::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            let ok = options.self_occlusion
                && m.indices.len() >= 3
                && m.normals.len() == m.positions.len()
                && m.positions.iter().all(|p| p.is_finite());
            let same = |k: usize| {
                self_maps[k].is_some() && scene.meshes[k].same_shape(m) && scene.meshes[k].normals == m.normals
            };
            let maps = if !ok {
                None
            } else if let Some(first) = (0..mi).find(|&k| same(k)) {
                self_maps[first].clone()
            } else {
                let path = cache_path(options, "pss", |h| {
                    hash_mesh(m, true, h);
                    table.n.hash(h);
                });
                let per = table.dirs.len().div_ceil(32);
                let loaded =
                    path.as_ref().and_then(|p| self_maps_from_bytes(&std::fs::read(p).ok()?, m.positions.len(), per));
                Some(Arc::new(match loaded {
                    Some(maps) => maps,
                    None => {
                        let maps =
                            penumbra_math::shadow_field::haar::self_maps(&m.positions, &m.normals, &m.indices, &table);
                        if let Some(p) = &path {
                            super::write_cache_file(p, &self_maps_to_bytes(&maps, m.positions.len(), per));
                        }
                        maps
                    }
                }))
            };
            self_maps.push(maps);
        }
        let self_seconds = t_self.elapsed().as_secs_f64();
        for (mi, m) in scene.meshes.iter().enumerate() {
            // a mesh no shadow-casting object uses needs no field (a floor)
            let casts = scene
                .objects
                .iter()
                .enumerate()
                .any(|(oi, o)| o.mesh == mi && scene.object_info.get(oi).is_none_or(|i| i.casts_shadow));
            if !casts || m.indices.len() < 3 || m.positions.is_empty() {
                fields.push(None);
                reports.push(WaveletReport::empty(&m.name));
                continue;
            }
            let same = |k: usize| fields[k].is_some() && scene.meshes[k].same_shape(m);
            if let Some(first) = (0..mi).find(|&k| same(k)) {
                fields.push(fields[first].clone());
                reports.push(WaveletReport { mesh: m.name.clone(), seconds: 0.0, ..reports[first].clone() });
                continue;
            }
            let t0 = std::time::Instant::now();
            // a mesh collapsed to a point (or with non-finite positions) casts nothing
            let (_, vr) = penumbra_math::shadow_field::bounds(&m.positions);
            if !(vr.is_finite() && vr > 0.0) {
                fields.push(None);
                reports.push(WaveletReport::empty(&m.name));
                continue;
            }
            let path = cache_path(options, "psw", |h| {
                hash_mesh(m, false, h);
                (options.shells, options.resolution, table.n, options.keep.to_bits()).hash(h);
                (options.adaptive, options.threshold.to_bits()).hash(h);
            });
            // a cached file holds the field used and the fixed field's size
            let loaded = path.as_ref().and_then(|p| {
                let b = std::fs::read(p).ok()?;
                let (size, field) = b.split_at_checked(8)?;
                // (the hash names the parameters; a file that disagrees with them is not used)
                let field = HaarField::from_bytes(field).ok().filter(|f| {
                    f.n == table.n
                        && f.shells.len() == options.shells
                        && f.shells.iter().all(|s| s.resolution <= options.resolution)
                })?;
                Some((field, u64::from_le_bytes(size.try_into().ok()?) as usize))
            });
            let cached = loaded.is_some();
            let (field, fixed_bytes) = match loaded {
                Some(x) => x,
                None => {
                    let (c, vr, maps) = raw_maps(&m.positions, &m.indices, options.shells, options.resolution, &table);
                    let (field, fixed_bytes) = HaarField::build_sized(
                        c,
                        vr,
                        &maps,
                        options.resolution,
                        &table,
                        options.keep,
                        options.adaptive,
                        options.threshold,
                    );
                    if let Some(p) = &path {
                        let mut b = (fixed_bytes as u64).to_le_bytes().to_vec();
                        b.extend(field.to_bytes());
                        super::write_cache_file(p, &b);
                    }
                    (field, fixed_bytes)
                }
            };
            reports.push(WaveletReport {
                mesh: m.name.clone(),
                fixed_bytes,
                adaptive_bytes: field.bytes(),
                resolutions: field.resolutions(),
                seconds: t0.elapsed().as_secs_f64(),
                cached,
            });
            fields.push(Some(Arc::new(field)));
        }
        Ok(WaveletFields { fields, self_maps, self_seconds, reports, options: options.clone() })
    }
}

/// The cache file (extension `ext`) of the inputs `hash` feeds, when `options` cache.
fn cache_path(options: &SfwOptions, ext: &str, hash: impl FnOnce(&mut DefaultHasher)) -> Option<std::path::PathBuf> {
    let dir = options.cache_dir.as_ref()?;
    let mut h = DefaultHasher::new();
    // the file format's version: a change of the precompute changes it
    (ext, 1u32).hash(&mut h);
    hash(&mut h);
    Some(dir.join(format!("{:016x}.{ext}", h.finish())))
}

/// Hashes a mesh's positions and indices (and normals).
fn hash_mesh(m: &penumbra_scene::MeshData, normals: bool, h: &mut DefaultHasher) {
    for v in &m.positions {
        v.to_array().map(f32::to_bits).hash(h);
    }
    if normals {
        for v in &m.normals {
            v.to_array().map(f32::to_bits).hash(h);
        }
    }
    m.indices.hash(h);
}

/// Self-visibility maps as a cache file: `"PSS1"`, vertex count, words per vertex, the words
/// (little endian).
fn self_maps_to_bytes(maps: &[u32], vertices: usize, per: usize) -> Vec<u8> {
    let mut b = b"PSS1".to_vec();
    b.extend_from_slice(&(vertices as u32).to_le_bytes());
    b.extend_from_slice(&(per as u32).to_le_bytes());
    b.extend(maps.iter().flat_map(|w| w.to_le_bytes()));
    b
}

/// Parses [`self_maps_to_bytes`]; `None` unless it holds exactly `vertices` x `per` words.
fn self_maps_from_bytes(b: &[u8], vertices: usize, per: usize) -> Option<Vec<u32>> {
    let words = b.strip_prefix(b"PSS1")?;
    let (head, words) = words.split_at_checked(8)?;
    let v = u32::from_le_bytes(head[..4].try_into().ok()?) as usize;
    let p = u32::from_le_bytes(head[4..].try_into().ok()?) as usize;
    if v != vertices || p != per || words.len() != 4 * vertices * per {
        return None;
    }
    Some(words.chunks_exact(4).map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]])).collect())
}

/// std430 `SfwInst` of `sfw_shade.comp` and `sfw_self.comp` (176 bytes).
#[repr(C)]
#[derive(Clone, Copy)]
struct GpuInst {
    world_to_local: [[f32; 4]; 4],
    /// xyz shell centre (object space), w shell step 0.2 Vr.
    center_step: [f32; 4],
    /// x first shell, y shell count (0: none), z casts shadow.
    info: [u32; 4],
    /// xyz world position of the shell centre, w the world bounding radius (Vr times the
    /// instance's largest axis scale).
    center_world: [f32; 4],
    local_to_world: [[f32; 4]; 4],
}

/// The technique.
pub struct WaveletTechnique {
    shade: Pipeline,
    nearest: Sampler,
    linear: Sampler,
    repeat: Sampler,
    pub fields: Arc<WaveletFields>,
    /// Binary maps of every shell of every distinct mesh (`6 n^2` bits per sample).
    maps: Arc<Vec<u32>>,
    /// Per shell: (first word of its maps, R).
    shells: Vec<[u32; 4]>,
    /// Per mesh: (first shell, shell count, centre, step).
    mesh_shells: Vec<(u32, u32, Vec3, f32)>,
    /// Per cube pixel (world frame): direction, then the environment's radiance times the
    /// pixel's solid angle, at the environment state it was made for.
    dirs: (EnvironmentState, Arc<Vec<u8>>),
    /// The map the cube's radiance comes from (the rest of it with key lights split off), kept
    /// when the scene animates its environment: a frame at another state makes its own cube.
    cube_env: Option<Environment>,
    table: CubeTable,
    irradiance: Arc<Vec<u8>>,
    casts: Vec<bool>,
    /// Self-occlusion: the per-vertex pass, the raster pass, every mesh's maps and each
    /// mesh's first word in them, each mesh's vertices (object position, normal), and each
    /// mesh's (first index, index count, vertex offset) in the scene's buffers.
    self_pass: Pipeline,
    self_raster: Pipeline,
    self_data: Arc<Vec<u32>>,
    mesh_self: Vec<Option<u32>>,
    mesh_verts: Vec<Vec<[f32; 4]>>,
    mesh_ranges: Vec<(u32, u32, i32)>,
    /// The frame's kd-tree for the local and key lights' shadow rays (`light_shadows = traced`,
    /// with local or key lights to shade).
    kd: Option<crate::kdtree::KdTreeBuilder>,
    /// The key lights split off the environment, 2 per light (axis + lambda, RGB amplitude, in
    /// the map's frame at intensity 1: `lighting::lobes_at` the frame's state), shaded with the
    /// kd-tree's rays ([`SfwOptions::key_lights`]).
    key: Vec<[f32; 4]>,
}

/// Format of the interpolated self-occlusion images.
const SELF_FORMAT: vk::Format = vk::Format::R16G16B16A16_SFLOAT;

/// The environment on the cube of face resolution `table.n`, world frame: per pixel the mean
/// radiance over the pixel (8 x 8 sub-directions, `state`'s intensity and rotation applied)
/// times its solid angle; zero without an environment.
pub fn env_cube(env: Option<&Environment>, state: EnvironmentState, table: &CubeTable) -> Vec<[f32; 4]> {
    let n = table.n;
    let mut out = Vec::with_capacity(table.dirs.len());
    const SUB: usize = 8;
    for f in 0..6 {
        for i in 0..n {
            for j in 0..n {
                let k = (f * n + i) * n + j;
                let Some(env) = env else {
                    out.push([0.0; 4]);
                    continue;
                };
                let mut acc = Vec3::ZERO;
                let mut wsum = 0.0f32;
                for a in 0..SUB {
                    for b in 0..SUB {
                        let u = 2.0 * (j as f32 + (b as f32 + 0.5) / SUB as f32) / n as f32 - 1.0;
                        let v = 2.0 * (i as f32 + (a as f32 + 0.5) / SUB as f32) / n as f32 - 1.0;
                        let d = CubeTable::face_point(f, u as f64, v as f64).as_vec3();
                        let l = d.length();
                        let w = 1.0 / (l * l * l);
                        let r = env.radiance_at(d / l, state);
                        if r.is_finite() {
                            acc += w * r.max(Vec3::ZERO);
                        }
                        wsum += w;
                    }
                }
                let mean = acc / wsum.max(1e-30);
                let sa = table.w[k] as f32;
                out.push([mean.x * sa, mean.y * sa, mean.z * sa, 0.0]);
            }
        }
    }
    out
}

/// The shader's `dirs` buffer: the cube's directions, then [`env_cube`] at `state`.
fn cube_dirs(env: Option<&Environment>, state: EnvironmentState, table: &CubeTable) -> Vec<u8> {
    let mut dirs: Vec<[f32; 4]> = table.dirs.iter().map(|d| [d.x as f32, d.y as f32, d.z as f32, 0.0]).collect();
    dirs.extend(env_cube(env, state, table));
    bytes_of(&dirs)
}

impl WaveletTechnique {
    /// Precomputes the fields of `scene` and builds the pipeline.
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, options: SfwOptions) -> Result<Self> {
        let fields = Arc::new(WaveletFields::build(scene, &options)?);
        let shade = compute_pipeline(ctx, shaders, "shadow_fields/sfw_shade.comp", 24)?;
        let self_pass = compute_pipeline(ctx, shaders, "shadow_fields/sfw_self.comp", 16)?;
        let self_raster = {
            use crate::raster::{raster_pipeline, DepthState, RasterDesc, VertexInput};
            raster_pipeline(
                ctx,
                shaders,
                &RasterDesc {
                    name: "sfw_self",
                    shaders: &["shadow_fields/sfw_self.vert", "shadow_fields/sfw_self.frag"],
                    vertex_input: VertexInput::Position,
                    colors: &[SELF_FORMAT, SELF_FORMAT],
                    depth: Some(DepthState {
                        format: crate::gbuffer::DEPTH_FORMAT,
                        write: true,
                        compare: vk::CompareOp::LESS,
                    }),
                    ..Default::default()
                },
            )?
        };
        let mut self_data: Vec<u32> = Vec::new();
        let mut mesh_self = Vec::new();
        let mut mesh_verts = Vec::new();
        let mut mesh_ranges = Vec::new();
        let (mut first_index, mut vertex_offset) = (0u32, 0i32);
        let mut seen_self: Vec<(*const Vec<u32>, u32)> = Vec::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            mesh_ranges.push((first_index, m.indices.len() as u32, vertex_offset));
            first_index += m.indices.len() as u32;
            vertex_offset += m.positions.len() as i32;
            match fields.self_maps.get(mi).and_then(|x| x.as_ref()) {
                Some(maps) => {
                    let off = match seen_self.iter().find(|(p, _)| std::ptr::eq(*p, Arc::as_ptr(maps))) {
                        Some(&(_, o)) => o,
                        None => {
                            let o = self_data.len() as u32;
                            self_data.extend_from_slice(maps);
                            seen_self.push((Arc::as_ptr(maps), o));
                            o
                        }
                    };
                    mesh_self.push(Some(off));
                    mesh_verts.push(
                        m.positions
                            .iter()
                            .zip(&m.normals)
                            .flat_map(|(p, n)| [[p.x, p.y, p.z, 1.0], [n.x, n.y, n.z, 0.0]])
                            .collect(),
                    );
                }
                None => {
                    mesh_self.push(None);
                    mesh_verts.push(Vec::new());
                }
            }
        }
        if 4 * self_data.len() as u64 > ctx.max_storage_buffer_range as u64 {
            return Err(anyhow!("shadow-fields-wavelet: the self-visibility maps take {} MiB, more than this device binds in one buffer: lower cube", (4 * self_data.len()) >> 20));
        }
        self_data.resize(self_data.len().max(4), 0);
        let table = CubeTable::new(options.cube);
        let n = table.n;
        let mut maps: Vec<u32> = Vec::new();
        let mut shells = Vec::new();
        let mut mesh_shells = Vec::new();
        let mut uploaded: Vec<(*const HaarField, (u32, u32, Vec3, f32))> = Vec::new();
        for f in &fields.fields {
            let Some(f) = f else {
                mesh_shells.push((0, 0, Vec3::ZERO, 1.0));
                continue;
            };
            if f.n != n {
                return Err(anyhow!("shadow-fields-wavelet: a field of cube resolution {} (expected {n})", f.n));
            }
            if let Some((_, e)) = uploaded.iter().find(|(p, _)| std::ptr::eq(*p, Arc::as_ptr(f))) {
                mesh_shells.push(*e);
                continue;
            }
            let e = (shells.len() as u32, f.shells.len() as u32, f.center, 0.2 * f.bound_radius);
            for (c, s) in f.shells.iter().enumerate() {
                shells.push([maps.len() as u32, s.resolution as u32, 0, 0]);
                maps.extend(f.shell_bits(c));
            }
            uploaded.push((Arc::as_ptr(f), e));
            mesh_shells.push(e);
        }
        let bytes = 4 * maps.len() as u64;
        if bytes > ctx.max_storage_buffer_range as u64 {
            return Err(anyhow!(
                "shadow-fields-wavelet: the visibility maps take {:.1} MiB, more than this device binds in one buffer ({:.1} MiB): lower shells, resolution or cube",
                bytes as f64 / 1048576.0,
                ctx.max_storage_buffer_range as f64 / 1048576.0
            ));
        }
        maps.resize(maps.len().max(4), 0);
        if shells.is_empty() {
            shells.push([0; 4]);
        }
        // the key lights split off the environment: the cube's radiance and the irradiance map
        // are then the rest of the map's
        let max_key = if options.light_traced { options.key_lights } else { 0 };
        let (sky, key) = crate::lighting::split_key_lights(scene.environment.as_ref(), max_key)?;
        let env = sky.as_ref().or(scene.environment.as_ref());
        let state = scene.environment.as_ref().map_or(EnvironmentState::NONE, Environment::state);
        let cube_env = if scene.requirements().animated_environment { env.cloned() } else { None };
        let dirs = cube_dirs(env, state, &table);
        let casts = crate::shadow_fields::casts_flags(scene);
        Ok(WaveletTechnique {
            shade,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            fields,
            maps: Arc::new(maps),
            shells,
            mesh_shells,
            dirs: (state, Arc::new(dirs)),
            cube_env,
            table,
            irradiance: Arc::new(bytes_of(&crate::lighting::irradiance_env(env))),
            casts,
            self_pass,
            self_raster,
            self_data: Arc::new(self_data),
            mesh_self,
            mesh_verts,
            mesh_ranges,
            kd: if options.light_traced && (!scene.lights.is_empty() || !key.is_empty()) {
                Some(crate::kdtree::KdTreeBuilder::new(ctx, shaders)?)
            } else {
                None
            },
            key,
        })
    }

    /// Bytes the GPU holds for the maps.
    pub fn gpu_bytes(&self) -> usize {
        4 * self.maps.len()
    }
}

impl WaveletTechnique {
    /// The self-occlusion images of a frame: per visible instance with maps, every vertex's
    /// values (sfw_self.comp) interpolated across its triangles by a raster pass into two
    /// `w x h` images (cleared to 1: no self-occlusion where nothing is drawn).
    fn add_self(
        &self,
        graph: &mut Graph,
        inputs: &TechniqueInputs,
        insts: BufferHandle,
        dirs: BufferHandle,
        w: u32,
        hh: u32,
    ) -> (ImageHandle, ImageHandle) {
        let frame = inputs.frame;
        let n = self.fields.options.cube.max(2).next_power_of_two() as u32;
        let per = (6 * n * n).div_ceil(32);
        let mut slots: Vec<[u32; 4]> = Vec::new();
        let mut verts: Vec<[f32; 4]> = Vec::new();
        let mut base_of = vec![0i32; frame.instances.len().max(1)];
        let mut draws = Vec::new();
        if self.fields.options.self_occlusion {
            for (ii, inst) in frame.instances.iter().enumerate() {
                let (Some(Some(off)), Some(&(first, count, offset))) =
                    (self.mesh_self.get(inst.mesh), self.mesh_ranges.get(inst.mesh))
                else {
                    continue;
                };
                let mv = &self.mesh_verts[inst.mesh];
                let nv = (mv.len() / 2) as u32;
                if nv == 0 || count == 0 {
                    continue;
                }
                // base[instance] + gl_VertexIndex (which includes the mesh's vertex offset) = slot
                base_of[ii] = slots.len() as i32 - offset;
                for v in 0..nv {
                    slots.push([off + v * per, ii as u32, 0, 0]);
                }
                verts.extend_from_slice(mv);
                draws.push((first, count, offset, ii as u32));
            }
        }
        let total = slots.len() as u32;
        let img_share = graph.create_image("sfw_self_share", ImageDesc::new_2d(SELF_FORMAT, w, hh));
        let img_lights = graph.create_image("sfw_self_lights", ImageDesc::new_2d(SELF_FORMAT, w, hh));
        let values = if total > 0 {
            let slot_buf = graph.create_buffer_init("sfw_self_slots", bytes_of(&slots));
            let vert_buf = graph.create_buffer_init("sfw_self_verts", bytes_of(&verts));
            let maps = graph.create_buffer_init("sfw_self_maps", bytes_of(self.self_data.as_ref()));
            let out = graph.create_buffer_init("sfw_self_values", vec![0u8; total as usize * 32]);
            let mut p = graph.pass("sfw_self", PassKind::Compute);
            let r = [slot_buf, vert_buf, maps, insts, dirs, inputs.handles.lights]
                .map(|b| p.read(b, Access::ComputeShaderReadStorage));
            let out = p.write(out, Access::ComputeShaderWriteStorage);
            let pipe = self.self_pass.handle();
            let push = crate::util::bytes_of(&[total, n, inputs.handles.light_count, 0u32]);
            let gx = total.min(32768);
            let gy = total.div_ceil(gx);
            p.record(move |rc| {
                let mut binds: Vec<Bind> = r.iter().map(|&b| Bind::StorageBuffer(b)).collect();
                binds.push(Bind::StorageBuffer(out));
                crate::util::dispatch(rc, pipe, &binds, &push, [gx, gy, 1])
            });
            out
        } else {
            graph.create_buffer_init("sfw_self_values", vec![0u8; 32])
        };
        let out = super::add_vertex_raster(
            graph,
            "sfw_self_display",
            &self.self_raster,
            inputs,
            values,
            &base_of,
            draws,
            &[(img_share, [1.0; 4]), (img_lights, [1.0; 4])],
            w,
            hh,
        );
        (out[0], out[1])
    }
}

impl crate::technique::Technique for WaveletTechnique {
    fn name(&self) -> &'static str {
        "shadow-fields-wavelet"
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        let frame = inputs.frame;
        // the local lights' occluders: the frame's triangles (rebuilt when anything moved), or
        // four empty stand-ins the shader never reads (traced = 0)
        let (kd_bufs, traced) = crate::kdtree::KdTreeBuilder::add_frame_or_stand_ins(
            self.kd.as_mut(),
            engine,
            graph,
            inputs.scene,
            frame,
            "sfw",
        )?;
        let traced = traced as u32;
        let key_count = (self.key.len() / 2) as u32 * traced;
        let key =
            graph.create_buffer_init("sfw_key_lights", crate::lighting::lobes_bytes_at(&self.key, frame.environment));
        let insts: Vec<GpuInst> = frame
            .instances
            .iter()
            .map(|inst| {
                let (first, count, c, step) =
                    self.mesh_shells.get(inst.mesh).copied().unwrap_or((0, 0, Vec3::ZERO, 1.0));
                let casts = self.casts.get(inst.object).copied().unwrap_or(true);
                let cw = inst.world.transform_point3(c);
                let scale = inst
                    .world
                    .x_axis
                    .truncate()
                    .length()
                    .max(inst.world.y_axis.truncate().length())
                    .max(inst.world.z_axis.truncate().length());
                // 1e-4 of slack: a silhouette pixel's centre exactly on the cone stays inside
                let radius = 5.0 * step * scale * (1.0 + 1e-4);
                GpuInst {
                    world_to_local: inst.world.inverse().to_cols_array_2d(),
                    center_step: [c.x, c.y, c.z, step],
                    info: [first, count, casts as u32, 0],
                    center_world: [cw.x, cw.y, cw.z, radius],
                    local_to_world: inst.world.to_cols_array_2d(),
                }
            })
            .collect();
        let inst_bytes = if insts.is_empty() { vec![0u8; std::mem::size_of::<GpuInst>()] } else { bytes_of(&insts) };
        let maps = graph.create_buffer_init("sfw_maps", bytes_of(self.maps.as_ref()));
        let shells = graph.create_buffer_init("sfw_shells", bytes_of(&self.shells));
        let inst_buf = graph.create_buffer_init("sfw_insts", inst_bytes);
        if self.dirs.0 != frame.environment {
            if let Some(env) = &self.cube_env {
                self.dirs = (frame.environment, Arc::new(cube_dirs(Some(env), frame.environment, &self.table)));
            }
        }
        let dirs = graph.create_buffer_init("sfw_dirs", self.dirs.1.as_ref().clone());
        let irr = graph.create_buffer_init("sfw_irradiance", self.irradiance.as_ref().clone());
        let gb = inputs.gbuffer;
        let (w, hh) = (gb.width, gb.height);
        let (self_share, self_lights) = self.add_self(graph, inputs, inst_buf, dirs, w, hh);
        let hdr = graph.create_image("hdr", ImageDesc::new_2d(crate::shade_env::HDR_FORMAT, w, hh));
        let mut p = graph.pass("sfw_shade", PassKind::Compute);
        let io = crate::shade_env::ShadingIo::declare(&mut p, inputs.handles, gb, inputs.env, hdr);
        let hdr = io.hdr;
        let r = [maps, shells, inst_buf, dirs, irr, inputs.handles.lights]
            .map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let [tex, self_share, self_lights] =
            [inputs.handles.textures, self_share, self_lights].map(|h| p.read(h, Access::ComputeShaderReadSampled));
        let kd = crate::kdtree::KdTreeReads::declare(&mut p, kd_bufs, false);
        let key = p.read(key, Access::ComputeShaderReadStorage);
        let pipe = self.shade.handle();
        let (nearest, linear, repeat) = (self.nearest.sampler, self.linear.sampler, self.repeat.sampler);
        let n = self.fields.options.cube.max(2).next_power_of_two() as u32;
        let push = crate::util::bytes_of(&[
            frame.instances.len() as u32,
            inputs.handles.light_count,
            n,
            self.fields.options.reproject as u32,
            traced,
            key_count,
        ]);
        p.record(move |rc| {
            let mut binds = io.binds(nearest, linear);
            binds.extend(r.iter().map(|&b| Bind::StorageBuffer(b)));
            binds.push(Bind::SampledImage(tex, repeat));
            binds.push(Bind::SampledImage(self_share, nearest));
            binds.push(Bind::SampledImage(self_lights, nearest));
            binds.extend(kd.binds());
            binds.push(Bind::StorageBuffer(key));
            // one workgroup of 64 per pixel: the cube's directions split over its invocations
            crate::util::dispatch(rc, pipe, &binds, &push, [w, hh, 1])
        });
        Ok(hdr)
    }
}

//! Technique `shadow-fields`: adaptive precomputed shadow fields (Tamura et al., after Zhou et
//! al. 2005) for rigid objects under environment lighting.
//!
//! * Precompute ([`SceneFields::build`]): one object occlusion field per mesh
//!   (`penumbra_math::shadow_field`), fixed and adaptive, cached as one file per object and
//!   variant (`<cache>/<hash>-{fixed,adaptive}.psf`).
//! * CPU path ([`cpu_shade_points`]): per vertex, the self-occlusion transfer rotated to world,
//!   triple products with every other object's interpolated, dequantized, rotated visibility,
//!   double product with the environment's order-4 SH.
//! * GPU: the same per point in `glsl/sf_points.comp` ([`ShadowFieldsTechnique::add_points`]),
//!   and per G-buffer pixel in `glsl/sf_shade.comp` (the technique's image; pixels use the
//!   clamped-cosine transfer of their normal, without self-occlusion, which the per-vertex
//!   transfer carries only at vertices; glossy materials add the prefiltered environment along
//!   the reflection and local lights are evaluated with the material BRDF, both shadowed by the
//!   product of the other objects' visibilities in that direction).
//!
//! Registered as `shadow-fields` (adaptive) and `shadow-fields-fixed` (every shell at the
//! initial resolution) so `penumbra bench --techniques shadow-fields,shadow-fields-fixed`
//! measures both against the reference in one run.

pub mod bench;

use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{anyhow, Result};
use glam::{DVec3, Mat3, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, BufferHandle, Context, Engine, Graph, ImageHandle, PassKind};
use penumbra_math::sh::TripleProductTensor;
use penumbra_math::shadow_field::{
    self as sf, InstanceFrame, ObjectField, Params, ShadePoint, NCOEF, ROT_FLOATS,
};
use penumbra_scene::{Environment, Frame, Scene};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::sync::Arc;

/// Options of the technique and of the precompute.
#[derive(Clone, Debug)]
pub struct SfOptions {
    /// Precompute parameters. Default: 32 shells (paper), initial R = 32 (paper: 64), 32 x 64
    /// directions per occlusion map (paper: 64 x 64), threshold 0.010 (paper).
    pub params: Params,
    /// Use the adaptive shells (else every shell at the initial resolution).
    pub adaptive: bool,
    /// Directory of the per-object field files (`None`: no caching).
    pub cache_dir: Option<PathBuf>,
    /// Print precompute progress to stderr.
    pub progress: bool,
}

impl Default for SfOptions {
    fn default() -> Self {
        SfOptions {
            params: Params { shells: 32, resolution: 32, map_res: 32, threshold: 0.010, min_resolution: 1 },
            adaptive: true,
            cache_dir: Some(std::env::temp_dir().join("penumbra-shadow-fields")),
            progress: false,
        }
    }
}

/// What the precompute did for one mesh.
#[derive(Clone, Debug)]
pub struct FieldReport {
    pub mesh: String,
    pub vertices: usize,
    pub triangles: usize,
    /// Coefficient bytes (`sum R_c^2 * 16`) fixed / adaptive.
    pub fixed_bytes: usize,
    pub adaptive_bytes: usize,
    /// File bytes (with quantization tables and self-transfer) fixed / adaptive.
    pub fixed_file_bytes: usize,
    pub adaptive_file_bytes: usize,
    /// Per-shell resolution after adaptation.
    pub resolutions: Vec<u32>,
    /// Ray-casting seconds (0 when loaded from the cache).
    pub seconds: f64,
    pub rays: u64,
    pub cached: bool,
}

/// Fixed and adaptive fields of every mesh of a scene.
pub struct SceneFields {
    /// Per mesh: (fixed, adaptive).
    pub fields: Vec<(Arc<ObjectField>, Arc<ObjectField>)>,
    pub reports: Vec<FieldReport>,
    pub options: SfOptions,
}

fn cache_key(m: &penumbra_scene::MeshData, p: &Params) -> String {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for v in m.positions.iter().chain(m.normals.iter()) {
        v.to_array().map(f32::to_bits).hash(&mut h);
    }
    m.indices.hash(&mut h);
    (p.shells, p.resolution, p.map_res, p.threshold.to_bits(), p.min_resolution, 1u32).hash(&mut h);
    format!("{:016x}", h.finish())
}

impl SceneFields {
    /// Precomputes (or loads from the cache) the fields of every mesh of `scene`.
    pub fn build(scene: &Scene, options: &SfOptions) -> Result<Self> {
        let mut fields = Vec::new();
        let mut reports = Vec::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            let key = cache_key(m, &options.params);
            let paths = options.cache_dir.as_ref().map(|d| (d.join(format!("{key}-fixed.psf")), d.join(format!("{key}-adaptive.psf"))));
            let loaded = paths.as_ref().and_then(|(f, a)| {
                let f = ObjectField::from_bytes(&std::fs::read(f).ok()?).ok()?;
                let a = ObjectField::from_bytes(&std::fs::read(a).ok()?).ok()?;
                (f.self_transfer.len() == m.positions.len() && a.self_transfer.len() == m.positions.len()).then_some((f, a))
            });
            let (fixed, adaptive, seconds, rays, cached) = match loaded {
                Some((f, a)) => (f, a, 0.0, 0, true),
                None => {
                    let total = (options.params.shells * options.params.resolution.next_power_of_two().pow(2) + m.positions.len()) as u64;
                    let done = std::sync::atomic::AtomicU64::new(0);
                    let name = m.name.clone();
                    let show = options.progress;
                    let progress = move |n: u64| {
                        let d = done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n;
                        if show && (d % (total / 20).max(1) == 0 || d == total) {
                            eprintln!("shadow field '{name}': {:.0}%", 100.0 * d as f64 / total as f64);
                        }
                    };
                    let raw = sf::precompute(&m.positions, &m.normals, &m.indices, &options.params, &progress)
                        .map_err(|e| anyhow!("mesh {mi} '{}': {e}", m.name))?;
                    let f = raw.to_fixed();
                    let a = raw.to_adaptive(options.params.threshold, options.params.min_resolution);
                    if let Some((pf, pa)) = &paths {
                        // The cache is an optimisation: failures to write it are not errors.
                        if let Some(dir) = pf.parent() {
                            let _ = std::fs::create_dir_all(dir);
                        }
                        let _ = std::fs::write(pf, f.to_bytes());
                        let _ = std::fs::write(pa, a.to_bytes());
                    }
                    (f, a, raw.seconds, raw.rays, false)
                }
            };
            reports.push(FieldReport {
                mesh: m.name.clone(),
                vertices: m.positions.len(),
                triangles: m.indices.len() / 3,
                fixed_bytes: fixed.data_bytes(),
                adaptive_bytes: adaptive.data_bytes(),
                fixed_file_bytes: fixed.file_bytes(),
                adaptive_file_bytes: adaptive.file_bytes(),
                resolutions: adaptive.resolutions(),
                seconds,
                rays,
                cached,
            });
            fields.push((Arc::new(fixed), Arc::new(adaptive)));
        }
        Ok(SceneFields { fields, reports, options: options.clone() })
    }

    /// The field used for mesh `mesh` (adaptive or fixed).
    pub fn field(&self, mesh: usize, adaptive: bool) -> Option<&ObjectField> {
        self.fields.get(mesh).map(|(f, a)| if adaptive { a.as_ref() } else { f.as_ref() })
    }
}

/// `penumbra precompute shadow-field` for the CLI: precomputes the fields of every mesh of
/// `scene` and writes one file per object and variant, `<out>/<mesh>.fixed.psf` and
/// `<out>/<mesh>.adaptive.psf` (mesh names sanitized, index-suffixed when repeated), read back
/// with [`ObjectField::from_bytes`]. Returns the per-mesh reports and the paths written.
pub fn precompute_files(scene: &Scene, options: &SfOptions, out: &std::path::Path) -> Result<(Vec<FieldReport>, Vec<PathBuf>)> {
    let fields = SceneFields::build(scene, options)?;
    std::fs::create_dir_all(out).map_err(|e| anyhow!("{}: {e}", out.display()))?;
    let mut paths = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (mi, ((f, a), m)) in fields.fields.iter().zip(&scene.meshes).enumerate() {
        let mut name: String = m.name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
        if name.is_empty() || !seen.insert(name.clone()) {
            name = format!("{name}_{mi}");
            seen.insert(name.clone());
        }
        for (kind, field) in [("fixed", f), ("adaptive", a)] {
            let p = out.join(format!("{name}.{kind}.psf"));
            std::fs::write(&p, field.to_bytes()).map_err(|e| anyhow!("{}: {e}", p.display()))?;
            paths.push(p);
        }
    }
    Ok((fields.reports, paths))
}

/// Order-4 SH (rgb) of the environment radiance in world space (intensity and rotation
/// applied); zero without an environment.
pub fn env_light_sh(env: Option<&Environment>) -> [[f64; 3]; NCOEF] {
    let mut out = [[0.0; 3]; NCOEF];
    let Some(env) = env else { return out };
    let (w, h) = (env.width as usize, env.height as usize);
    if w == 0 || h == 0 || env.texels.len() < w * h {
        return out;
    }
    let stride = (w / 256).max(1);
    let rot = Mat3::from_rotation_y(env.rotation);
    let mut y = [0.0; NCOEF];
    let dphi = std::f64::consts::TAU / w as f64;
    let dth = std::f64::consts::PI / h as f64;
    for j in (0..h).step_by(stride) {
        let v = (j as f64 + 0.5) / h as f64;
        let th = v * std::f64::consts::PI;
        let rows = stride.min(h - j);
        let wgt_row = ((th - 0.5 * dth).cos() - (th - 0.5 * dth + rows as f64 * dth).cos()).abs();
        for i in (0..w).step_by(stride) {
            let cols = stride.min(w - i);
            let u = (i as f32 + 0.5) / w as f32;
            let d = (rot * Environment::direction(u, v as f32)).as_dvec3();
            sf_basis(d, &mut y);
            let t = env.texels[j * w + i];
            let wgt = wgt_row * cols as f64 * dphi * env.intensity as f64;
            for e in 0..NCOEF {
                for c in 0..3 {
                    out[e][c] += wgt * t[c] as f64 * y[e];
                }
            }
        }
    }
    out
}

fn sf_basis(d: DVec3, y: &mut [f64; NCOEF]) {
    penumbra_math::sh::eval_basis_into(sf::ORDER, d, y);
}

/// Per object: whether it casts shadows.
pub fn casts_flags(scene: &Scene) -> Vec<bool> {
    (0..scene.objects.len()).map(|i| scene.object_info.get(i).map_or(true, |o| o.casts_shadow)).collect()
}

/// Per-frame instance setup for the CPU path.
pub fn instance_frames<'a>(scene: &Scene, frame: &Frame, fields: &'a SceneFields, adaptive: bool) -> Vec<InstanceFrame<'a>> {
    frame
        .instances
        .iter()
        .map(|inst| {
            let casts = scene.object_info.get(inst.object).map_or(true, |i| i.casts_shadow);
            let field = if casts { fields.field(inst.mesh, adaptive) } else { None };
            InstanceFrame::new(field, inst.world.as_dmat4())
        })
        .collect()
}

/// A point for the GPU (std430 `SfPoint` of `glsl/sf_points.comp`, 96 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GpuPoint {
    pub pos_inst: [f32; 4],
    pub albedo: [f32; 4],
    pub t: [f32; NCOEF],
}

/// The points of a frame: every vertex of every instance (world position, self-transfer),
/// optionally culled (`cull = Some(aspect)`) to the camera's view: vertices outside the
/// frustum (5% margin) or whose normal faces away from the eye are dropped (paper 5.3).
pub fn vertex_points(scene: &Scene, frame: &Frame, fields: &SceneFields, cull: Option<f32>) -> Vec<ShadePoint> {
    let aspect = cull.filter(|a| a.is_finite() && *a > 0.0).unwrap_or(1.0);
    let cull = cull.is_some();
    let vp = frame.camera.proj(aspect) * frame.camera.view();
    let eye = frame.camera.eye;
    let mut out = Vec::new();
    for (ii, inst) in frame.instances.iter().enumerate() {
        let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
        let Some((_, field)) = fields.fields.get(inst.mesh) else { continue };
        let albedo = frame.materials.get(inst.material).or(scene.materials.get(inst.material)).map_or(Vec3::splat(0.5), |m| m.albedo);
        let nm = Mat3::from_mat4(inst.world).inverse().transpose();
        for (vi, p) in mesh.positions.iter().enumerate() {
            let wp = inst.world.transform_point3(*p);
            if cull {
                let n = (nm * mesh.normals.get(vi).copied().unwrap_or(Vec3::Y)).normalize_or_zero();
                let c = vp * wp.extend(1.0);
                let inside = c.w > 0.0 && c.x.abs() <= c.w * 1.05 && c.y.abs() <= c.w * 1.05;
                if !inside || n.dot(eye - wp) < 0.0 {
                    continue;
                }
            }
            let t = field.self_transfer.get(vi).copied().unwrap_or([0.0; NCOEF]);
            out.push(ShadePoint {
                pos: wp.as_dvec3(),
                inst: ii,
                albedo: albedo.as_dvec3(),
                transfer: t.map(|x| x as f64),
            });
        }
    }
    out
}

/// The CPU rendering path: radiance per point and its unclamped minimum channel.
pub fn cpu_shade_points(
    points: &[ShadePoint],
    insts: &[InstanceFrame],
    light: &[[f64; 3]; NCOEF],
    tensor: &TripleProductTensor,
) -> Vec<(DVec3, f64)> {
    sf::shade_points(points, insts, light, tensor)
}

/// std430 `SfShell`.
#[repr(C)]
#[derive(Clone, Copy)]
struct GpuShell {
    info: [u32; 4],
    min: [f32; NCOEF],
    step: [f32; NCOEF],
}

/// std430 `SfInst` (432 bytes).
#[repr(C)]
#[derive(Clone, Copy)]
struct GpuInst {
    world_to_local: [[f32; 4]; 4],
    center_step: [f32; 4],
    info: [u32; 4],
    rot: [f32; ROT_FLOATS],
}

/// The field tables as the shaders read them.
pub struct GpuTables {
    /// Quantized coefficients of every mesh, packed (4 per word).
    pub data: Vec<u8>,
    shells: Vec<GpuShell>,
    /// First shell index and shell count per mesh.
    mesh_shells: Vec<(u32, u32)>,
    mesh_geom: Vec<(Vec3, f32)>,
    pub tensor: Vec<u8>,
    pub tensor_count: u32,
}

impl GpuTables {
    /// Packs the (adaptive or fixed) fields of every mesh: the data buffer and the address
    /// table (offset, R, min, step per shell).
    pub fn new(fields: &SceneFields, adaptive: bool, tensor: &TripleProductTensor) -> Self {
        let mut data = Vec::new();
        let mut shells = Vec::new();
        let mut mesh_shells = Vec::new();
        let mut mesh_geom = Vec::new();
        for mi in 0..fields.fields.len() {
            let f = fields.field(mi, adaptive).expect("mesh index in range");
            mesh_shells.push((shells.len() as u32, f.shells.len() as u32));
            mesh_geom.push((f.center, f.shell_step() as f32));
            for s in &f.shells {
                shells.push(GpuShell { info: [(data.len() / 4) as u32, s.resolution, 0, 0], min: s.min, step: s.step });
                data.extend_from_slice(&s.data);
            }
        }
        let entries: Vec<[u32; 2]> = tensor
            .entries
            .iter()
            .map(|&(i, j, k, c)| [i as u32 | (j as u32) << 8 | (k as u32) << 16, (c as f32).to_bits()])
            .collect();
        GpuTables { data, shells, mesh_shells, mesh_geom, tensor: bytes_of(&entries), tensor_count: entries.len() as u32 }
    }

    /// Per-instance records of a frame (rotation matrices computed once per instance).
    fn instances(&self, casts: &[bool], frame: &Frame) -> Vec<GpuInst> {
        frame
            .instances
            .iter()
            .map(|inst| {
                let f = InstanceFrame::new(None, inst.world.as_dmat4());
                let casts = casts.get(inst.object).copied().unwrap_or(true);
                let (first, count) = self.mesh_shells.get(inst.mesh).copied().unwrap_or((0, 0));
                let (c, step) = self.mesh_geom.get(inst.mesh).copied().unwrap_or((Vec3::ZERO, 1.0));
                GpuInst {
                    world_to_local: f.world_to_local.as_mat4().to_cols_array_2d(),
                    center_step: [c.x, c.y, c.z, step],
                    info: [first, count, casts as u32, 0],
                    rot: f.rot.map(|x| x as f32),
                }
            })
            .collect()
    }
}

/// Buffers of one frame's field tables in a graph.
#[derive(Clone, Copy, Debug)]
pub struct SfHandles {
    pub data: BufferHandle,
    pub shells: BufferHandle,
    pub insts: BufferHandle,
    pub tensor: BufferHandle,
    pub light: BufferHandle,
    pub inst_count: u32,
    pub tensor_count: u32,
}

/// Uploads the tables, this frame's instances and the lighting (host-initialised buffers).
pub fn upload(graph: &mut Graph, tables: &GpuTables, casts: &[bool], frame: &Frame, light: &[[f64; 3]; NCOEF]) -> SfHandles {
    let insts = tables.instances(casts, frame);
    let light4: Vec<[f32; 4]> = light.iter().map(|c| [c[0] as f32, c[1] as f32, c[2] as f32, 0.0]).collect();
    let mut data = tables.data.clone();
    data.resize(data.len().max(16), 0);
    let shells = if tables.shells.is_empty() { vec![GpuShell { info: [0; 4], min: [0.0; 16], step: [0.0; 16] }] } else { tables.shells.clone() };
    let inst_bytes = if insts.is_empty() { vec![0u8; std::mem::size_of::<GpuInst>()] } else { bytes_of(&insts) };
    SfHandles {
        data: graph.create_buffer_init("sf_data", data),
        shells: graph.create_buffer_init("sf_shells", bytes_of(&shells)),
        insts: graph.create_buffer_init("sf_insts", inst_bytes),
        tensor: graph.create_buffer_init("sf_tensor", tables.tensor.clone()),
        light: graph.create_buffer_init("sf_light", bytes_of(&light4)),
        inst_count: insts.len() as u32,
        tensor_count: tables.tensor_count,
    }
}

/// The technique: per-pixel shading pass, and the per-point pass of the GPU rendering path.
pub struct ShadowFieldsTechnique {
    shade: Pipeline,
    points: Pipeline,
    nearest: Sampler,
    linear: Sampler,
    pub fields: Arc<SceneFields>,
    pub tables: GpuTables,
    pub light: [[f64; 3]; NCOEF],
    pub tensor: TripleProductTensor,
    pub adaptive: bool,
    /// Per object: casts shadows (`ObjectInfo::casts_shadow`).
    pub casts: Vec<bool>,
}

impl ShadowFieldsTechnique {
    /// Precomputes (or loads) the fields of `scene` and builds the pipelines.
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, options: SfOptions) -> Result<Self> {
        let fields = Arc::new(SceneFields::build(scene, &options)?);
        Self::with_fields(ctx, shaders, scene, fields, options.adaptive)
    }

    /// With fields built elsewhere (e.g. shared between the fixed and adaptive variants).
    pub fn with_fields(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, fields: Arc<SceneFields>, adaptive: bool) -> Result<Self> {
        use vk::DescriptorType as T;
        let sb = T::STORAGE_BUFFER;
        let shade = compute_pipeline(
            ctx,
            shaders,
            "sf_shade.comp",
            &[
                T::UNIFORM_BUFFER,
                sb,
                T::COMBINED_IMAGE_SAMPLER,
                T::COMBINED_IMAGE_SAMPLER,
                T::COMBINED_IMAGE_SAMPLER,
                T::COMBINED_IMAGE_SAMPLER,
                T::STORAGE_IMAGE,
                sb,
                sb,
                sb,
                sb,
                sb,
                sb,
            ],
            12,
        )?;
        let points = compute_pipeline(ctx, shaders, "sf_points.comp", &[sb; 7], 12)?;
        let tensor = TripleProductTensor::new(sf::ORDER);
        let tables = GpuTables::new(&fields, adaptive, &tensor);
        Ok(ShadowFieldsTechnique {
            shade,
            points,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            fields,
            tables,
            light: env_light_sh(scene.environment.as_ref()),
            tensor,
            adaptive,
            casts: casts_flags(scene),
        })
    }

    /// Adds the per-point pass (GPU rendering path): returns the output buffer (`vec4` per
    /// point: rgb radiance clamped at 0, w the unclamped minimum channel).
    pub fn add_points(&self, graph: &mut Graph, h: &SfHandles, points: &[ShadePoint]) -> BufferHandle {
        let gp: Vec<GpuPoint> = points
            .iter()
            .map(|p| GpuPoint {
                pos_inst: [p.pos.x as f32, p.pos.y as f32, p.pos.z as f32, p.inst as f32],
                albedo: [p.albedo.x as f32, p.albedo.y as f32, p.albedo.z as f32, 1.0],
                t: p.transfer.map(|x| x as f32),
            })
            .collect();
        let n = gp.len() as u32;
        let pts = graph.create_buffer_init("sf_points", if gp.is_empty() { vec![0u8; 96] } else { bytes_of(&gp) });
        let out = graph.create_buffer("sf_point_radiance", (n.max(1) as u64) * 16);
        let mut p = graph.pass("sf_points", PassKind::Compute);
        let r = [h.data, h.shells, h.insts, h.tensor, h.light, pts].map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let out = p.write(out, Access::ComputeShaderWriteStorage);
        let (pipeline, layout) = (self.points.pipeline, self.points.layout);
        let push: Vec<u8> = [n, h.inst_count, h.tensor_count].iter().flat_map(|x| x.to_le_bytes()).collect();
        p.record(move |rc| {
            let mut binds: Vec<Bind> = r.iter().map(|&b| Bind::StorageBuffer(b)).collect();
            binds.push(Bind::StorageBuffer(out));
            crate::util::bind_compute(rc, pipeline, layout, &binds)?;
            unsafe {
                let d = rc.device();
                d.cmd_push_constants(rc.cmd, layout, vk::ShaderStageFlags::COMPUTE, 0, &push);
                if n > 0 {
                    d.cmd_dispatch(rc.cmd, groups(n, 64), 1, 1);
                }
            }
            Ok(())
        });
        out
    }
}

impl crate::technique::Technique for ShadowFieldsTechnique {
    fn name(&self) -> &'static str {
        if self.adaptive {
            "shadow-fields"
        } else {
            "shadow-fields-fixed"
        }
    }

    fn add(&mut self, _engine: &mut Engine, graph: &mut Graph, inputs: &crate::technique::TechniqueInputs) -> Result<ImageHandle> {
        let h = upload(graph, &self.tables, &self.casts, inputs.frame, &self.light);
        let gb = inputs.gbuffer;
        let (w, hh) = (gb.width, gb.height);
        let hdr = graph.create_image("hdr", ImageDesc::new_2d(crate::shade_env::HDR_FORMAT, w, hh));
        let mut p = graph.pass("sf_shade", PassKind::Compute);
        let camera = p.read(inputs.scene.camera, Access::AnyShaderReadUniform);
        let materials = p.read(inputs.scene.materials, Access::ComputeShaderReadStorage);
        let pos = p.read(gb.position, Access::ComputeShaderReadSampled);
        let nrm = p.read(gb.normal, Access::ComputeShaderReadSampled);
        let uvm = p.read(gb.uv_mat, Access::ComputeShaderReadSampled);
        let env = p.read(inputs.env, Access::ComputeShaderReadSampled);
        let hdr = p.write(hdr, Access::ComputeShaderWriteStorage);
        let r = [h.data, h.shells, h.insts, h.tensor, h.light, inputs.scene.lights].map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let (pipeline, layout) = (self.shade.pipeline, self.shade.layout);
        let (nearest, linear) = (self.nearest.sampler, self.linear.sampler);
        let push: Vec<u8> = [h.inst_count, h.tensor_count, inputs.scene.light_count].iter().flat_map(|x| x.to_le_bytes()).collect();
        p.record(move |rc| {
            let mut binds = vec![
                Bind::UniformBuffer(camera),
                Bind::StorageBuffer(materials),
                Bind::SampledImage(pos, nearest),
                Bind::SampledImage(nrm, nearest),
                Bind::SampledImage(uvm, nearest),
                Bind::SampledImage(env, linear),
                Bind::StorageImage(hdr),
            ];
            binds.extend(r.iter().map(|&b| Bind::StorageBuffer(b)));
            crate::util::bind_compute(rc, pipeline, layout, &binds)?;
            unsafe {
                let d = rc.device();
                d.cmd_push_constants(rc.cmd, layout, vk::ShaderStageFlags::COMPUTE, 0, &push);
                d.cmd_dispatch(rc.cmd, groups(w, 8), groups(hh, 8), 1);
            }
            Ok(())
        });
        Ok(hdr)
    }
}

/// Copies `size` bytes of `src` into a new readback buffer `name`.
pub fn add_readback(graph: &mut Graph, src: BufferHandle, name: &str, size: u64) -> BufferHandle {
    let rb = graph.create_readback(name, size.max(4));
    let mut p = graph.pass(&format!("readback_{name}"), PassKind::Transfer);
    let s = p.read(src, Access::TransferSrc);
    let d = p.write(rb, Access::TransferDst);
    p.record(move |rc| {
        let (sb, db) = (rc.buffer(s)?, rc.buffer(d)?);
        if size > 0 {
            unsafe { rc.device().cmd_copy_buffer(rc.cmd, sb.buffer, db.buffer, &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size }]) };
        }
        Ok(())
    });
    d
}

/// Runs the GPU rendering path on `points` for `frame`: per point `[r, g, b, unclamped min]`
/// and the GPU milliseconds of the `sf_points` pass.
pub fn gpu_shade_points(
    engine: &mut Engine,
    tech: &ShadowFieldsTechnique,
    frame: &Frame,
    points: &[ShadePoint],
) -> Result<(Vec<[f32; 4]>, f64)> {
    let mut g = Graph::new();
    let h = upload(&mut g, &tech.tables, &tech.casts, frame, &tech.light);
    let out = tech.add_points(&mut g, &h, points);
    add_readback(&mut g, out, "sf_points_out", points.len().max(1) as u64 * 16);
    engine.submit(g)?;
    let mut outs = engine.drain()?;
    let o = outs.pop().ok_or_else(|| anyhow!("no frame output"))?;
    let bytes = o.readbacks.get("sf_points_out").ok_or_else(|| anyhow!("no readback"))?;
    let vals: Vec<[f32; 4]> = bytes
        .chunks_exact(16)
        .take(points.len())
        .map(|c| [0, 1, 2, 3].map(|k| f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])))
        .collect();
    let ms = o.gpu_ms.iter().filter(|(n, _)| n == "sf_points").map(|(_, m)| m).sum();
    Ok((vals, ms))
}

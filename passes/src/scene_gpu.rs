//! The scene's GPU data: one vertex and one index buffer for all meshes, the material table
//! (uploaded once), and per-frame camera constants and instance transforms (host-initialised
//! graph buffers).

use crate::textures::MaterialTextures;
use crate::util::bytes_of;
use anyhow::{bail, Result};
use glam::{Mat4, Vec3};
use penumbra_engine::{vk, BufferHandle, Context, GpuBuffer, Graph, ImageHandle};
use penumbra_scene::{BrdfKind, Frame, LightInstance, LightKind, Material, MaterialExtra, Scene};
use std::sync::Arc;

/// Interleaved vertex: position, normal, uv (32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct Vertex {
    pub pos: [f32; 3],
    pub normal: [f32; 3],
    pub uv: [f32; 2],
}

/// std140 layout of `CameraData` in `glsl/include/common.glsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct FrameConstants {
    pub view_proj: [[f32; 4]; 4],
    pub prev_view_proj: [[f32; 4]; 4],
    pub inv_view_proj: [[f32; 4]; 4],
    pub eye: [f32; 4],
    /// width, height, env mip count, env intensity (the frame's)
    pub params: [f32; 4],
    /// cos(rotation), sin(rotation) (the frame's environment rotation), exposure, unused
    pub env_rot: [f32; 4],
}

/// std430 layout of `InstanceData`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
struct InstanceData {
    model: [[f32; 4]; 4],
    prev_model: [[f32; 4]; 4],
    normal_matrix: [[f32; 4]; 4],
    ids: [u32; 4],
}

/// std430 layout of `MaterialData`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
struct MaterialData {
    albedo_kind: [f32; 4],
    spec_rough: [f32; 4],
    extra: [f32; 4],
    /// rgb emitted radiance, w emission map layer (-1 none)
    emission: [f32; 4],
    /// x normal map layer (-1 none), y its scale
    normal: [f32; 4],
}

#[derive(Clone, Copy, Debug)]
pub struct MeshRange {
    pub first_index: u32,
    pub index_count: u32,
    pub vertex_offset: i32,
}

pub struct SceneGpu {
    ctx: Arc<Context>,
    vertices: Option<GpuBuffer>,
    indices: Option<GpuBuffer>,
    pub meshes: Vec<MeshRange>,
    pub vertex_count: usize,
    pub triangle_count: usize,
    /// Texture maps of each material (layers of `textures`).
    extras: Vec<MaterialExtra>,
    /// The scene's texture maps as one 2D array.
    pub textures: MaterialTextures,
    /// The medium's extinction coefficient (zero without a medium): `LightData.extra.yzw`, so
    /// every technique attenuates local light on its way in by `exp(-sigma_t d)`
    /// (`light_transmittance` of `glsl/include/common.glsl`), as the reference does.
    sigma_t: Vec3,
    /// Per object: the G-buffer culls its back faces ([`Cull`]: `MeshData::is_closed_outward`,
    /// neither a thin shell nor a two-sided material).
    cull_back: Vec<bool>,
    /// The specular albedo table (`penumbra_math::dfg::packed`) that follows the frame
    /// constants in the camera buffer (`cam_dfg` of `glsl/include/env_dfg.glsl`).
    dfg: Vec<[f32; 4]>,
    /// The environment's irradiance map (`lighting::camera_irradiance`) that follows the table
    /// (`cam_irr` of `glsl/include/env_shade.glsl`).
    irradiance: Vec<[f32; 4]>,
}

/// Handles of the scene's buffers in one frame's graph.
#[derive(Clone, Copy, Debug)]
pub struct SceneHandles {
    pub vertices: BufferHandle,
    pub indices: BufferHandle,
    pub materials: BufferHandle,
    pub camera: BufferHandle,
    pub instances: BufferHandle,
    /// Vertices of this frame's deformed meshes (host-initialised).
    pub deformed_vertices: Option<BufferHandle>,
    /// Local lights of this frame (`LightData`), and their count.
    pub lights: BufferHandle,
    pub light_count: u32,
    /// Material texture maps: RGBA32F 2D array (`sampler2DArray`), one layer per scene texture,
    /// indexed by `MaterialData.extra.y` (albedo) / `.z` (roughness, G channel).
    pub textures: ImageHandle,
}

/// One draw: a mesh range, the instance index, and whether its vertices come from the frame's
/// deformed-vertex buffer (`vertex_offset` then indexes that buffer).
#[derive(Clone, Copy, Debug)]
pub struct Draw {
    pub mesh: MeshRange,
    pub instance: u32,
    pub deformed: bool,
    /// Back-face culling of the G-buffer's draw (`raster::draw_instances` with `cull`).
    pub cull: Cull,
}

/// A draw's back-face culling in the G-buffer: for closed, outward-wound meshes at rest
/// (`MeshData::is_closed_outward`; not thin shells, two-sided materials or deforming instances)
/// a back face shows only where the rasterizer rounds a silhouette pixel onto it (a ray through
/// the pixel centre goes past), shaded from inside the object: culled.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Cull {
    #[default]
    None,
    /// Counter-clockwise triangles face the viewer.
    Back,
    /// A mirroring transform: clockwise ones do.
    BackMirrored,
}

/// Per-frame draw list.
pub type DrawList = Vec<Draw>;

impl SceneGpu {
    pub fn new(ctx: &Arc<Context>, scene: &Scene) -> Result<Self> {
        let mut verts = Vec::new();
        let mut idx = Vec::new();
        let mut meshes = Vec::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            if m.positions.len() != m.normals.len() || m.positions.len() != m.uvs.len() {
                bail!("mesh {mi} '{}': positions, normals and uvs differ in count", m.name);
            }
            if let Some(bad) = m.indices.iter().find(|&&i| i as usize >= m.positions.len()) {
                bail!("mesh {mi} '{}': index {bad} out of range ({} vertices)", m.name, m.positions.len());
            }
            meshes.push(MeshRange {
                first_index: idx.len() as u32,
                index_count: m.indices.len() as u32,
                vertex_offset: verts.len() as i32,
            });
            for i in 0..m.positions.len() {
                verts.push(Vertex {
                    pos: m.positions[i].to_array(),
                    normal: m.normals[i].to_array(),
                    uv: m.uvs[i].to_array(),
                });
            }
            idx.extend_from_slice(&m.indices);
        }
        let vertex_count = verts.len();
        let triangle_count = idx.len() / 3;
        let (vertices, indices) = if verts.is_empty() || idx.is_empty() {
            (None, None)
        } else {
            (
                Some(ctx.create_buffer_with_data(
                    "scene.vertices",
                    &bytes_of(&verts),
                    vk::BufferUsageFlags::VERTEX_BUFFER,
                )?),
                Some(ctx.create_buffer_with_data(
                    "scene.indices",
                    &bytes_of(&idx),
                    vk::BufferUsageFlags::INDEX_BUFFER,
                )?),
            )
        };
        let extras = (0..scene.materials.len()).map(|i| scene.material_extra(i)).collect();
        let textures = MaterialTextures::new(ctx, &scene.textures)?;
        let sigma_t = scene.medium.map_or(Vec3::ZERO, |m| m.sigma_t().max(Vec3::ZERO));
        // once per mesh (objects share meshes; welding hashes every vertex)
        let closed: Vec<bool> = scene.meshes.iter().map(|m| m.is_closed_outward()).collect();
        let cull_back = scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                !scene.object_info(i).thin_shell
                    && !scene.material_extras.get(o.material).is_some_and(|e| e.two_sided)
                    && closed.get(o.mesh).copied().unwrap_or(false)
            })
            .collect();
        Ok(SceneGpu {
            ctx: ctx.clone(),
            cull_back,
            vertices,
            indices,
            meshes,
            vertex_count,
            triangle_count,
            extras,
            textures,
            sigma_t,
            dfg: penumbra_math::dfg::packed(),
            irradiance: crate::lighting::camera_irradiance(scene.environment.as_ref()),
        })
    }
}

/// The material table in the layout of `MaterialData` (std430): the one packing of the scene's
/// materials that every technique reads (`glsl/include/material.glsl`). `extras` gives texture
/// layers (albedo map, roughness map, emission map), the emission and the second Ashikhmin-Shirley exponent per material
/// index (may be shorter). Values are sanitised as the reference's `Brdf::new` does: albedo
/// finite and >= 0, specular in [0, 1], roughness in [0, 1], exponents in [0, 1e6].
pub fn material_table(materials: &[Material], extras: &[MaterialExtra]) -> Vec<u8> {
    let san = |v: glam::Vec3| if v.is_finite() { v.max(glam::Vec3::ZERO) } else { glam::Vec3::ZERO };
    let num = |x: f32, default: f32, hi: f32| if x.is_finite() { x } else { default }.clamp(0.0, hi);
    let materials: Vec<MaterialData> = materials
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let albedo = san(m.albedo);
            let spec = san(m.specular).min(glam::Vec3::ONE);
            let shininess = num(m.shininess, 1.0, 1e6);
            let x = extras.get(i);
            // nv: Ashikhmin-Shirley's exponent along the bitangent (isotropic: the shininess)
            let shininess_v = x.and_then(|x| x.shininess_v).map_or(shininess, |v| num(v, shininess, 1e6));
            MaterialData {
                albedo_kind: [
                    albedo.x,
                    albedo.y,
                    albedo.z,
                    match m.kind {
                        BrdfKind::Diffuse => 0.0,
                        BrdfKind::BlinnPhong => 1.0,
                        BrdfKind::CookTorrance => 2.0,
                        BrdfKind::AshikhminShirley => 3.0,
                    },
                ],
                spec_rough: [spec.x, spec.y, spec.z, num(m.roughness, 1.0, 1.0)],
                extra: [
                    shininess,
                    x.and_then(|x| x.albedo_map).map_or(-1.0, |l| l as f32),
                    x.and_then(|x| x.roughness_map).map_or(-1.0, |l| l as f32),
                    shininess_v,
                ],
                emission: {
                    let e = x.map_or(glam::Vec3::ZERO, |x| san(x.emission));
                    [e.x, e.y, e.z, x.and_then(|x| x.emission_map).map_or(-1.0, |l| l as f32)]
                },
                normal: {
                    let s = x.map_or(1.0, |x| x.normal_scale);
                    let s = if s.is_finite() && s != 0.0 { s } else { 1.0 };
                    [x.and_then(|x| x.normal_map).map_or(-1.0, |l| l as f32), s, 0.0, 0.0]
                },
            }
        })
        .collect();
    if materials.is_empty() {
        vec![0u8; std::mem::size_of::<MaterialData>()]
    } else {
        bytes_of(&materials)
    }
}

/// std430 layout of `LightData` in `common.glsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
struct LightData {
    /// xyz position, w kind (0 point, 1 spot, 2 sphere, 3 directional)
    pos_kind: [f32; 4],
    /// xyz direction, w cos(outer cone)
    dir_cos_outer: [f32; 4],
    /// rgb power (colour * intensity), w cos(inner cone)
    power_cos_inner: [f32; 4],
    /// x sphere radius
    extra: [f32; 4],
}

/// `sigma_t`: the medium's extinction, zero without one (see [`SceneGpu`]).
fn light_table(lights: &[LightInstance], sigma_t: Vec3) -> (Vec<u8>, u32) {
    let data: Vec<LightData> = lights
        .iter()
        .map(|l| {
            let (kind, cos_outer, cos_inner, radius) = match l.kind {
                LightKind::Point => (0.0, -1.0, -1.0, 0.0),
                LightKind::Spot { inner_deg, outer_deg } => {
                    (1.0, outer_deg.to_radians().cos(), inner_deg.to_radians().cos(), 0.0)
                }
                LightKind::Sphere { radius } => (2.0, -1.0, -1.0, radius),
                LightKind::Directional => (3.0, -1.0, -1.0, 0.0),
            };
            LightData {
                pos_kind: [l.position.x, l.position.y, l.position.z, kind],
                dir_cos_outer: {
                    let d = l.direction.normalize_or(Vec3::NEG_Y);
                    [d.x, d.y, d.z, cos_outer]
                },
                power_cos_inner: [l.power.x, l.power.y, l.power.z, cos_inner],
                extra: [radius, sigma_t.x, sigma_t.y, sigma_t.z],
            }
        })
        .collect();
    let n = data.len() as u32;
    (if data.is_empty() { vec![0u8; 64] } else { bytes_of(&data) }, n)
}

impl SceneGpu {
    /// Imports the static buffers and creates this frame's constants; returns the handles and
    /// the draw list (empty meshes skipped).
    pub fn add(&self, graph: &mut Graph, frame: &Frame, constants: &FrameConstants) -> (SceneHandles, DrawList) {
        let import = |g: &mut Graph, name: &str, b: &Option<GpuBuffer>| match b {
            Some(b) => g.import_buffer(name, b.buffer, b.size, b.usage),
            // An empty scene still declares the buffers; they are never bound.
            None => g.create_buffer_init(name, vec![0u8; 4]),
        };
        let vertices = import(graph, "scene.vertices", &self.vertices);
        let indices = import(graph, "scene.indices", &self.indices);
        let materials = graph.create_buffer_init("frame.materials", material_table(&frame.materials, &self.extras));
        let (light_bytes, light_count) = light_table(&frame.lights, self.sigma_t);
        let lights = graph.create_buffer_init("frame.lights", light_bytes);
        let mut inst = Vec::new();
        let mut draws = Vec::new();
        let mut deformed_verts: Vec<Vertex> = Vec::new();
        for (i, it) in frame.instances.iter().enumerate() {
            let normal = it.world.inverse().transpose();
            // back faces culled for closed, outward-wound meshes at rest (a deformation could
            // turn them inside out); a mirroring transform turns the winding
            let cull = if self.cull_back.get(it.object).copied().unwrap_or(false) && it.deformed_mesh.is_none() {
                if glam::Mat3::from_mat4(it.world).determinant() < 0.0 {
                    Cull::BackMirrored
                } else {
                    Cull::Back
                }
            } else {
                Cull::None
            };
            inst.push(InstanceData {
                model: it.world.to_cols_array_2d(),
                prev_model: it.prev_world.to_cols_array_2d(),
                normal_matrix: normal.to_cols_array_2d(),
                ids: [it.material as u32, i as u32, 0, 0],
            });
            let Some(r) = self.meshes.get(it.mesh) else { continue };
            if r.index_count == 0 {
                continue;
            }
            match &it.deformed_mesh {
                // Same topology as the rest mesh: reuse its indices, offset into the new vertices.
                Some(m) if m.positions.len() == m.normals.len() && m.positions.len() == m.uvs.len() => {
                    let mesh = MeshRange { vertex_offset: deformed_verts.len() as i32, ..*r };
                    for k in 0..m.positions.len() {
                        deformed_verts.push(Vertex {
                            pos: m.positions[k].to_array(),
                            normal: m.normals[k].to_array(),
                            uv: m.uvs[k].to_array(),
                        });
                    }
                    draws.push(Draw { mesh, instance: i as u32, deformed: true, cull });
                }
                _ => draws.push(Draw { mesh: *r, instance: i as u32, deformed: false, cull }),
            }
        }
        if inst.is_empty() {
            inst.push(InstanceData {
                model: Mat4::IDENTITY.to_cols_array_2d(),
                prev_model: Mat4::IDENTITY.to_cols_array_2d(),
                normal_matrix: Mat4::IDENTITY.to_cols_array_2d(),
                ids: [0; 4],
            });
        }
        // the frame constants (`CameraData`), the specular albedo table (`cam_dfg`), the
        // environment's irradiance map (`cam_irr`)
        let mut camera_bytes = bytes_of(std::slice::from_ref(constants));
        camera_bytes.extend(bytes_of(&self.dfg));
        camera_bytes.extend(bytes_of(&self.irradiance));
        let camera = graph.create_buffer_init("frame.camera", camera_bytes);
        let instances = graph.create_buffer_init("frame.instances", bytes_of(&inst));
        let deformed_vertices = (!deformed_verts.is_empty())
            .then(|| graph.create_buffer_init("frame.deformed_vertices", bytes_of(&deformed_verts)));
        let textures = self.textures.add(graph);
        let handles = SceneHandles {
            vertices,
            indices,
            materials,
            camera,
            instances,
            deformed_vertices,
            lights,
            light_count,
            textures,
        };
        (handles, draws)
    }

    /// One-time uploads must be declared again (the frame that declared them failed).
    pub fn invalidate_uploads(&self) {
        self.textures.invalidate_upload();
    }

    pub fn vertex_buffer(&self) -> Option<vk::Buffer> {
        self.vertices.as_ref().map(|b| b.buffer)
    }
}

impl FrameConstants {
    /// Camera matrices for `frame` at `width` x `height`, and its environment's rotation and
    /// intensity (`Frame::environment`); `prev` is the previous frame's camera (the same camera
    /// on the first frame). The environment's mip count and the exposure are the caller's (1).
    pub fn new(frame: &Frame, prev_view_proj: Option<Mat4>, width: u32, height: u32) -> Self {
        let aspect = width as f32 / height.max(1) as f32;
        let vp = frame.camera.proj(aspect) * frame.camera.view();
        let eye: Vec3 = frame.camera.eye;
        FrameConstants {
            view_proj: vp.to_cols_array_2d(),
            prev_view_proj: prev_view_proj.unwrap_or(vp).to_cols_array_2d(),
            inv_view_proj: vp.inverse().to_cols_array_2d(),
            eye: [eye.x, eye.y, eye.z, 1.0],
            params: [width as f32, height as f32, 1.0, frame.environment.intensity],
            env_rot: [frame.environment.rotation.cos(), frame.environment.rotation.sin(), 1.0, 0.0],
        }
    }

    pub fn view_proj(&self) -> Mat4 {
        Mat4::from_cols_array_2d(&self.view_proj)
    }
}

impl Drop for SceneGpu {
    fn drop(&mut self) {
        for b in [self.vertices.take(), self.indices.take()].into_iter().flatten() {
            self.ctx.destroy_buffer(b);
        }
    }
}

//! Scene description for penumbra: meshes, materials, camera, lighting, media and motion,
//! evaluated at a time `t` into a [`Frame`] the renderer consumes.
//!
//! This crate has no GPU code. The engine and the passes read [`Scene`] and [`Frame`].
//!
//! Interface contract used by the renderer (keep these names; add freely):
//! - [`Scene::default_scene`] the built-in default scene of `penumbra render`.
//! - [`Scene::at`] evaluates every transform at time `t`.
//! - [`MeshData`] positions/normals/uvs/indices, world transforms in [`Instance`].
//! - [`Environment`] a lat-long RGB float map (see its docs for orientation).
//!
//! Additions (see the README-style docs on each item):
//! - [`Scene::load`] reads a `.toml` scene file ([`format`](mod@format)) or a bare `.glb`/`.gltf` model
//!   ([`Scene::from_model`]); errors are one [`SceneError`] naming the file and the problem;
//!   repairs of degenerate input are reported in [`Scene::warnings`].
//! - Lights ([`Light`]), a participating [`Medium`], per-object motion and deformation
//!   ([`ObjectInfo`], [`motion`]), textures and per-material extras ([`MaterialExtra`]),
//!   animated materials and camera, and the visibility `technique`.
//! - [`Scene::requirements`] tells the render graph what the scene needs.

pub mod error;
pub mod format;
pub mod gltf_load;
pub mod limits;
pub mod mesh;
pub mod motion;
pub mod texture;
pub mod walker;

pub use error::SceneError;
pub use limits::{Budget, Limits};
pub use mesh::{EdgeStats, MeshData};
pub use motion::{Deformation, Interp, Rig, RigidMotion, Track};
pub use texture::{Pattern, Texture};

use glam::{Mat4, Vec3};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Pinhole camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    pub near: f32,
    pub far: f32,
}

impl Camera {
    pub fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, self.up)
    }
    /// Vulkan clip space (y down, depth 0..1).
    pub fn proj(&self, aspect: f32) -> Mat4 {
        let mut p = Mat4::perspective_rh(self.fov_y_deg.to_radians(), aspect, self.near, self.far);
        p.y_axis.y = -p.y_axis.y;
        p
    }
}

impl Camera {
    /// A camera looking at the box `lo..hi` from the front (+Z) and slightly above, far enough
    /// that the bounding sphere fits the vertical field of view `fov_y_deg`.
    pub fn framing(lo: Vec3, hi: Vec3, fov_y_deg: f32) -> Camera {
        let center = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-4);
        let dist = radius / (fov_y_deg.to_radians() * 0.5).sin() * 1.1;
        let dir = Vec3::new(0.0, 0.35, 1.0).normalize();
        Camera {
            eye: center + dir * dist,
            target: center,
            up: Vec3::Y,
            fov_y_deg,
            near: (dist - radius).max(dist * 1e-3) * 0.5,
            far: (dist + radius) * 10.0,
        }
    }
}

fn light_at(l: &Light, t: f32) -> (Vec3, Vec3) {
    let m = l.motion.eval(t);
    (m.transform_point3(l.position), m.transform_vector3(l.direction).normalize_or_zero())
}

/// BRDF model of a material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BrdfKind {
    Diffuse,
    BlinnPhong,
    CookTorrance,
    AshikhminShirley,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub kind: BrdfKind,
    /// Diffuse albedo (linear RGB).
    pub albedo: Vec3,
    /// Specular reflectance at normal incidence (linear RGB).
    pub specular: Vec3,
    /// Perceptual roughness in [0, 1] (Cook-Torrance) ; Blinn-Phong uses `shininess`.
    pub roughness: f32,
    pub shininess: f32,
}

impl Material {
    pub fn blinn_phong(name: &str, albedo: Vec3, specular: Vec3, shininess: f32) -> Self {
        let roughness = (2.0 / (shininess + 2.0)).sqrt();
        Material { name: name.into(), kind: BrdfKind::BlinnPhong, albedo, specular, roughness, shininess }
    }

    pub fn diffuse(name: &str, albedo: Vec3) -> Self {
        Material {
            name: name.into(),
            kind: BrdfKind::Diffuse,
            albedo,
            specular: Vec3::ZERO,
            roughness: 1.0,
            shininess: 1.0,
        }
    }
    pub fn glossy(name: &str, albedo: Vec3, specular: Vec3, roughness: f32) -> Self {
        Material {
            name: name.into(),
            kind: BrdfKind::CookTorrance,
            albedo,
            specular,
            roughness,
            shininess: 2.0 / (roughness * roughness).max(1e-4) - 2.0,
        }
    }
}

/// A lat-long environment map, rows from the +Y pole (top, v = 0) to -Y (bottom).
///
/// Convention (also for loaded EXR/HDR files, whose first row is the top): u = 0.5 (image
/// centre column) looks towards +Z, u = 0.25 towards +X, u = 0 and 1 towards -Z; i.e.
/// `phi = 2 pi u` grows from -Z towards +X. `rotation` turns the map about +Y
/// (counter-clockwise seen from above): a world direction `d` looks up
/// `uv(Ry(-rotation) d)`, see [`Environment::radiance`]. `intensity` scales every texel.
/// Direction for pixel centre (u, v) in `[0,1]^2`: phi = 2*pi*u, theta = pi*v,
/// d = (sin(theta) * sin(phi), cos(theta), -sin(theta) * cos(phi))... see [`Environment::direction`].
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    pub width: u32,
    pub height: u32,
    /// Linear RGB radiance, row-major, `width * height` texels.
    pub texels: Vec<[f32; 3]>,
    /// Scale applied to every texel.
    pub intensity: f32,
    /// Rotation about +Y in radians.
    pub rotation: f32,
}

impl Environment {
    /// Its rotation and intensity as loaded (a frame's own: `Frame::environment`).
    pub fn state(&self) -> EnvironmentState {
        EnvironmentState { rotation: self.rotation, intensity: self.intensity }
    }

    /// Unit direction for lat-long coordinates (u, v) in `[0,1]^2` (before `rotation`).
    /// u = 0 and u = 1 is the -Z direction... phi grows towards +X; v = 0 is +Y (up).
    pub fn direction(u: f32, v: f32) -> Vec3 {
        let phi = u * std::f32::consts::TAU;
        let theta = v * std::f32::consts::PI;
        Vec3::new(theta.sin() * phi.sin(), theta.cos(), -theta.sin() * phi.cos())
    }

    /// Inverse of [`Environment::direction`].
    pub fn uv(d: Vec3) -> (f32, f32) {
        let theta = d.y.clamp(-1.0, 1.0).acos();
        let mut phi = d.x.atan2(-d.z);
        if phi < 0.0 {
            phi += std::f32::consts::TAU;
        }
        (phi / std::f32::consts::TAU, theta / std::f32::consts::PI)
    }

    /// A procedural sky: blue gradient above the horizon, a warm sun, dark ground.
    pub fn procedural_sky(width: u32, height: u32) -> Self {
        let sun = Vec3::new(0.4, 0.75, 0.5).normalize();
        let mut texels = Vec::with_capacity((width * height) as usize);
        for j in 0..height {
            for i in 0..width {
                let u = (i as f32 + 0.5) / width as f32;
                let v = (j as f32 + 0.5) / height as f32;
                let d = Self::direction(u, v);
                let c = if d.y >= 0.0 {
                    let t = d.y.powf(0.5);
                    Vec3::new(0.9, 0.95, 1.0).lerp(Vec3::new(0.25, 0.45, 0.9), t) * 1.2
                } else {
                    Vec3::new(0.25, 0.22, 0.2) * (1.0 + d.y * 0.5)
                };
                let s = d.dot(sun).max(0.0);
                let c = c + Vec3::new(40.0, 36.0, 30.0) * s.powf(2000.0) + Vec3::new(0.6, 0.5, 0.3) * s.powf(16.0);
                texels.push(c.to_array());
            }
        }
        Environment { width, height, texels, intensity: 1.0, rotation: 0.0 }
    }

    /// Whether a texel is read as it is: every channel finite and not negative. Any other texel
    /// is read as black, the whole texel, by every technique and by the reference.
    pub fn texel_ok(t: &[f32; 3]) -> bool {
        t.iter().all(|c| c.is_finite() && *c >= 0.0)
    }

    /// Texels that are not [`Environment::texel_ok`].
    pub fn bad_texels(&self) -> usize {
        self.texels.iter().filter(|t| !Self::texel_ok(t)).count()
    }

    /// Sets every texel that is not [`Environment::texel_ok`] to black and returns how many it
    /// changed, so that every consumer (SG fits, wavelet cubes, SATs, SH projections, importance
    /// tables, the GPU map and the reference) reads the same radiance.
    pub fn repair_texels(&mut self) -> usize {
        let mut n = 0;
        for t in self.texels.iter_mut() {
            if !Self::texel_ok(t) {
                *t = [0.0; 3];
                n += 1;
            }
        }
        n
    }
}

/// One object of the scene.
#[derive(Clone, Debug, PartialEq)]
pub struct Object {
    pub name: String,
    /// Index into [`Scene::meshes`].
    pub mesh: usize,
    /// Index into [`Scene::materials`].
    pub material: usize,
    /// Object-to-world transform at rest (t = 0 unless animated).
    pub transform: Mat4,
}

/// Kinds of local light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightKind {
    /// Point light; `intensity` is radiant intensity (W/sr) scaled by `color`.
    Point,
    /// Spot light along `direction` with a smooth falloff between the inner and outer cone
    /// half-angles (degrees).
    Spot { inner_deg: f32, outer_deg: f32 },
    /// Spherical area light of `radius`; `intensity` is the emitted radiance scale.
    Sphere { radius: f32 },
    /// Directional (sun) light shining along `direction` from infinitely far; `intensity` is the
    /// irradiance (W/m^2) it gives a surface facing it, scaled by `color`; `position` is unused.
    /// Not allowed in a scene with a participating medium (the medium fills all space, so no light
    /// from infinity reaches it).
    Directional,
}

/// A local light. Its world position and direction at time t are `motion.eval(t)` applied to
/// `position` (as a point) and `direction` (as a vector).
#[derive(Clone, Debug, PartialEq)]
pub struct Light {
    pub name: String,
    pub kind: LightKind,
    pub position: Vec3,
    /// Unit direction the light points to (spot and directional lights; ignored otherwise).
    pub direction: Vec3,
    /// Linear RGB colour.
    pub color: Vec3,
    pub intensity: f32,
    pub motion: RigidMotion,
    /// The light's fixture (a lamp shade, a housing): an index into [`Scene::objects`] of a
    /// rigid object that moves with the light (same [`RigidMotion`]). The reference and every
    /// technique see it as an ordinary object; `shadow-fields` precomputes it into the light's
    /// source radiance field (the paper's SRF of a real emitter) instead of applying its
    /// occlusion to its own light again.
    pub fixture: Option<usize>,
}

/// A light evaluated at one time.
#[derive(Clone, Debug, PartialEq)]
pub struct LightInstance {
    /// Index into [`Scene::lights`].
    pub light: usize,
    pub kind: LightKind,
    pub position: Vec3,
    pub direction: Vec3,
    /// `color * intensity`.
    pub power: Vec3,
    /// Position or direction changed since the previous frame.
    pub moved: bool,
}

/// A homogeneous participating medium filling the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Medium {
    /// Absorption coefficient per unit length (RGB).
    pub sigma_a: Vec3,
    /// Scattering coefficient per unit length (RGB).
    pub sigma_s: Vec3,
    /// Henyey-Greenstein asymmetry g in (-1, 1); 0 is isotropic.
    pub g: f32,
}

impl Medium {
    pub fn sigma_t(&self) -> Vec3 {
        self.sigma_a + self.sigma_s
    }
    /// Henyey-Greenstein phase function for the cosine between incoming and outgoing directions.
    pub fn phase(&self, cos_theta: f32) -> f32 {
        let g = self.g;
        let d = 1.0 + g * g - 2.0 * g * cos_theta;
        (1.0 - g * g) / (4.0 * std::f32::consts::PI * d * d.sqrt())
    }
}

/// Per-material data beyond [`Material`] (kept separate so `Material` struct literals in other
/// crates keep compiling). Indexed like [`Scene::materials`]; see [`Scene::material_extra`].
#[derive(Clone, Debug, PartialEq, Default)]
pub struct MaterialExtra {
    /// Albedo texture (index into [`Scene::textures`]), multiplies `albedo`, linear RGB.
    pub albedo_map: Option<usize>,
    /// Roughness texture (G channel), multiplies `roughness`.
    pub roughness_map: Option<usize>,
    /// Ashikhmin-Shirley exponent along the bitangent (`nv`); `None` = isotropic
    /// (`nv = shininess`, `nu = shininess`).
    pub shininess_v: Option<f32>,
    /// Shade both sides (thin shells such as cloth).
    pub two_sided: bool,
    /// Emitted radiance (linear RGB, W/(sr m^2)) that the surface shows to the eye; it lights
    /// nothing else (the reference is direct lighting only, and so are the techniques).
    pub emission: Vec3,
    /// Emission texture (index into [`Scene::textures`]), multiplies `emission`, linear RGB.
    pub emission_map: Option<usize>,
    /// Tangent-space normal map (index into [`Scene::textures`], linear: rgb = n * 0.5 + 0.5,
    /// +x along increasing u, +y along increasing v, as glTF's `normalTexture`).
    pub normal_map: Option<usize>,
    /// The normal map's x and y scale (glTF's `normalTexture.scale`; 0 is read as 1).
    pub normal_scale: f32,
    /// A glTF material's `KHR_texture_transform`, already baked into the texture coordinates of
    /// the primitives that use it (kept to say so, e.g. in the reference cache key; nothing
    /// applies it again).
    pub uv_transform: Option<gltf_load::UvTransform>,
}

impl MaterialExtra {
    pub fn is_spatially_varying(&self) -> bool {
        self.albedo_map.is_some()
            || self.roughness_map.is_some()
            || self.emission_map.is_some()
            || self.normal_map.is_some()
    }
}

/// Animated material parameters (keyframed, applied by [`Scene::at`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialAnimation {
    /// Index into [`Scene::materials`].
    pub material: usize,
    /// Roughness over time; the Blinn-Phong / Ashikhmin-Shirley `shininess` follows as
    /// `2 / roughness^2 - 2`.
    pub roughness: Option<Track<f32>>,
    pub albedo: Option<Track<Vec3>>,
    pub specular: Option<Track<Vec3>>,
}

/// Animated environment lighting (`[[environment.keys]]`, applied by [`Scene::at`]): each track,
/// when present, overrides the environment's rotation (radians about +Y) or intensity.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct EnvironmentAnimation {
    pub rotation: Option<Track<f32>>,
    pub intensity: Option<Track<f32>>,
}

/// The environment's lighting state at one time: its rotation about +Y (radians) and its
/// intensity (the scale of every texel). The texels never change over time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EnvironmentState {
    pub rotation: f32,
    pub intensity: f32,
}

impl EnvironmentState {
    /// No environment: nothing turned, nothing lit.
    pub const NONE: EnvironmentState = EnvironmentState { rotation: 0.0, intensity: 0.0 };
}

/// An animated camera: each track, when present, overrides the camera field.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct CameraPath {
    pub eye: Option<Track<Vec3>>,
    pub target: Option<Track<Vec3>>,
    pub fov_y_deg: Option<Track<f32>>,
}

/// A glTF node driving an object: world base transform = `placement * rig.global(node, t)`.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeMotion {
    pub rig: Arc<Rig>,
    pub node: usize,
    pub placement: Mat4,
}

/// Motion, deformation and flags of one object (indexed like [`Scene::objects`]; see
/// [`Scene::object_info`]). The world transform at time t is
/// `motion.eval(t) * base(t)` where `base` is `node.placement * rig.global(node, t)` for glTF
/// nodes and `Object::transform` otherwise. Deformations are applied in order in object
/// space to the rest mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectInfo {
    pub motion: RigidMotion,
    pub node: Option<NodeMotion>,
    pub deformations: Vec<Deformation>,
    /// An intentionally open, two-sided surface (cloth, leaves).
    pub thin_shell: bool,
    /// Whether the object occludes light (ground planes usually only receive).
    pub casts_shadow: bool,
    /// File the mesh came from (for messages), if any.
    pub source: Option<PathBuf>,
}

impl Default for ObjectInfo {
    fn default() -> Self {
        ObjectInfo {
            motion: RigidMotion::Static,
            node: None,
            deformations: Vec::new(),
            thin_shell: false,
            casts_shadow: true,
            source: None,
        }
    }
}

impl ObjectInfo {
    pub fn is_moving(&self) -> bool {
        !self.motion.is_static() || self.node.as_ref().is_some_and(|n| n.rig.node_animated(n.node))
    }
    pub fn is_deforming(&self) -> bool {
        self.deformations.iter().any(|d| d.is_animated())
    }
}

/// What a scene needs from the render graph.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Requirements {
    /// An environment map lights the scene.
    pub environment_light: bool,
    /// At least one point/spot/sphere light.
    pub local_lights: bool,
    /// A participating medium (volumetric passes).
    pub medium: bool,
    /// Some object's rigid transform changes over time (acceleration-structure refits).
    pub moving_objects: bool,
    /// Some object's vertices change over time (BLAS rebuilds / per-vertex updates).
    pub deforming_objects: bool,
    /// Some object is an open two-sided surface.
    pub thin_shells: bool,
    /// Some material uses a texture map.
    pub spatially_varying_materials: bool,
    /// The camera is animated.
    pub animated_camera: bool,
    /// Some light moves.
    pub animated_lights: bool,
    /// Some material parameter is animated.
    pub animated_materials: bool,
    /// The environment's rotation or intensity is animated (`[[environment.keys]]`).
    pub animated_environment: bool,
}

impl Requirements {
    /// Nothing in the scene changes over time except possibly the camera.
    pub fn is_static_geometry(&self) -> bool {
        !self.moving_objects && !self.deforming_objects
    }
}

/// The default visibility technique of a scene that names none.
pub const DEFAULT_TECHNIQUE: &str = "auto";

/// Options of [`Scene::load_with`].
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Accepted technique names; `None` accepts any name as written (the renderer checks it
    /// against its registry, `penumbra_passes::registry`).
    pub techniques: Option<Vec<String>>,
    /// Fail with [`SceneError::NotClosed`] unless every shadow-casting object that is not a
    /// thin shell has a closed mesh (for techniques that need closed occluders).
    pub require_closed_meshes: bool,
    /// What loading may allocate (checked before allocating).
    pub limits: Limits,
}

/// A complete scene at rest.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub camera: Camera,
    pub environment: Option<Environment>,
    pub meshes: Vec<MeshData>,
    pub materials: Vec<Material>,
    pub objects: Vec<Object>,
    /// Visibility technique (default [`DEFAULT_TECHNIQUE`]).
    pub technique: String,
    /// Technique parameters (`[technique_params]` in a scene file, `--param key=value` on the
    /// command line), as text; the technique validates them (unknown keys are errors).
    pub technique_params: std::collections::BTreeMap<String, String>,
    pub lights: Vec<Light>,
    pub medium: Option<Medium>,
    /// Volumetric method of the medium's passes: `"temporal"` or `"full"`; `None` = temporal
    /// (the `[medium]` table's `volumetric` key).
    pub volumetric: Option<String>,
    /// Textures referenced by [`MaterialExtra`].
    pub textures: Vec<Texture>,
    /// Per-material extras, indexed like `materials` (may be shorter: missing = default).
    pub material_extras: Vec<MaterialExtra>,
    /// Per-object motion and flags, indexed like `objects` (may be shorter: missing = static).
    pub object_info: Vec<ObjectInfo>,
    pub material_animations: Vec<MaterialAnimation>,
    pub camera_path: Option<CameraPath>,
    /// The environment's rotation and intensity over time (`None`: as loaded, constant).
    pub environment_animation: Option<EnvironmentAnimation>,
    /// Repairs made while loading (zero-area triangles removed, normals normalized, ...).
    pub warnings: Vec<String>,
    /// The file the scene was loaded from.
    pub source: Option<PathBuf>,
}

/// One object instance evaluated at a time.
#[derive(Clone, Debug, PartialEq)]
pub struct Instance {
    pub object: usize,
    pub mesh: usize,
    pub material: usize,
    pub world: Mat4,
    /// World transform at the previous frame (equals `world` for static objects / first frame).
    pub prev_world: Mat4,
    pub moved: bool,
    /// The vertices changed since the previous frame (always false on the first frame).
    pub deformed: bool,
    /// The deformed mesh at this time (object space, same topology as `meshes[mesh]`), for
    /// objects with deformations; `None` means the rest mesh applies.
    pub deformed_mesh: Option<Arc<MeshData>>,
    /// The deformed mesh at the previous frame's time (for motion vectors), if deforming and
    /// a previous time was given.
    pub prev_deformed_mesh: Option<Arc<MeshData>>,
}

/// The scene evaluated at one time.
#[derive(Clone, Debug)]
pub struct Frame {
    pub time: f32,
    pub camera: Camera,
    pub instances: Vec<Instance>,
    /// Camera at the previous frame (equals `camera` on the first frame).
    pub prev_camera: Camera,
    pub camera_moved: bool,
    pub lights: Vec<LightInstance>,
    /// Materials evaluated at this time (animated parameters applied), like `Scene::materials`.
    pub materials: Vec<Material>,
    /// Indices of materials whose parameters changed since the previous frame.
    pub materials_changed: Vec<usize>,
    /// The environment's rotation and intensity at this time ([`EnvironmentState::NONE`]
    /// without an environment); the texels are `Scene::environment`'s.
    pub environment: EnvironmentState,
    /// The environment's rotation or intensity changed since the previous frame.
    pub environment_changed: bool,
}

impl Frame {
    pub fn any_moved(&self) -> bool {
        self.instances.iter().any(|i| i.moved)
    }
    pub fn any_deformed(&self) -> bool {
        self.instances.iter().any(|i| i.deformed)
    }
}

impl Scene {
    /// Evaluate the scene at time `t` (seconds); `prev_t` gives the previous frame's time for
    /// motion vectors (None on the first frame). Deterministic: a pure function of `t` and
    /// `prev_t`.
    pub fn at(&self, t: f32, prev_t: Option<f32>) -> Frame {
        let default_info = ObjectInfo::default();
        let instances = self
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| {
                let info = self.object_info.get(i).unwrap_or(&default_info);
                let world = self.world_at(i, t);
                let prev_world = prev_t.map_or(world, |p| self.world_at(i, p));
                let moved = !world.abs_diff_eq(prev_world, 1e-6);
                let (deformed_mesh, prev_deformed_mesh, deformed) = if info.deformations.is_empty() {
                    (None, None, false)
                } else {
                    let cur = Arc::new(self.deformed_mesh(i, t));
                    let prev = prev_t.map(|p| Arc::new(self.deformed_mesh(i, p)));
                    let changed = prev
                        .as_ref()
                        .is_some_and(|p| p.positions.iter().zip(&cur.positions).any(|(a, b)| !a.abs_diff_eq(*b, 1e-7)));
                    (Some(cur), prev, changed)
                };
                Instance {
                    object: i,
                    mesh: o.mesh,
                    material: o.material,
                    world,
                    prev_world,
                    moved,
                    deformed,
                    deformed_mesh,
                    prev_deformed_mesh,
                }
            })
            .collect();
        let camera = self.camera_at(t);
        let prev_camera = prev_t.map_or_else(|| camera.clone(), |p| self.camera_at(p));
        let camera_moved = camera != prev_camera;
        let lights = self
            .lights
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let (p, d) = light_at(l, t);
                let moved = prev_t.is_some_and(|pt| {
                    let (pp, pd) = light_at(l, pt);
                    !pp.abs_diff_eq(p, 1e-6) || !pd.abs_diff_eq(d, 1e-6)
                });
                LightInstance { light: i, kind: l.kind, position: p, direction: d, power: l.color * l.intensity, moved }
            })
            .collect();
        let materials = self.materials_at(t);
        let materials_changed = match prev_t {
            Some(p) => {
                let prev = self.materials_at(p);
                (0..materials.len()).filter(|&k| materials[k] != prev[k]).collect()
            }
            None => Vec::new(),
        };
        let environment = self.environment_at(t);
        let environment_changed = prev_t.is_some_and(|p| self.environment_at(p) != environment);
        Frame {
            time: t,
            camera,
            instances,
            prev_camera,
            camera_moved,
            lights,
            materials,
            materials_changed,
            environment,
            environment_changed,
        }
    }

    /// The environment's rotation and intensity at time `t` (its animation's tracks override the
    /// loaded values); [`EnvironmentState::NONE`] without an environment.
    pub fn environment_at(&self, t: f32) -> EnvironmentState {
        let Some(e) = &self.environment else { return EnvironmentState::NONE };
        let mut s = EnvironmentState { rotation: e.rotation, intensity: e.intensity };
        if let Some(a) = &self.environment_animation {
            if let Some(k) = &a.rotation {
                s.rotation = k.sample(t);
            }
            if let Some(k) = &a.intensity {
                s.intensity = k.sample(t).max(0.0);
            }
        }
        s
    }

    /// World transform of object `i` at time `t`.
    pub fn world_at(&self, i: usize, t: f32) -> Mat4 {
        let o = &self.objects[i];
        match self.object_info.get(i) {
            None => o.transform,
            Some(info) => {
                let base = match &info.node {
                    Some(n) => n.placement * n.rig.global(n.node, t),
                    None => o.transform,
                };
                info.motion.eval(t) * base
            }
        }
    }

    /// The object-space mesh of object `i` at time `t` (the rest mesh when not deforming).
    pub fn deformed_mesh(&self, i: usize, t: f32) -> MeshData {
        let rest = &self.meshes[self.objects[i].mesh];
        let mut m = rest.clone();
        if let Some(info) = self.object_info.get(i) {
            for d in &info.deformations {
                d.apply(&mut m, rest, t);
            }
        }
        m
    }

    /// Camera at time `t` (the `camera_path` tracks override `camera`).
    pub fn camera_at(&self, t: f32) -> Camera {
        let mut c = self.camera.clone();
        if let Some(p) = &self.camera_path {
            if let Some(k) = &p.eye {
                c.eye = k.sample(t);
            }
            if let Some(k) = &p.target {
                c.target = k.sample(t);
            }
            if let Some(k) = &p.fov_y_deg {
                c.fov_y_deg = k.sample(t);
            }
        }
        c
    }

    /// Materials with their animations applied at time `t`.
    pub fn materials_at(&self, t: f32) -> Vec<Material> {
        let mut mats = self.materials.clone();
        for a in &self.material_animations {
            let Some(m) = mats.get_mut(a.material) else { continue };
            if let Some(k) = &a.roughness {
                m.roughness = k.sample(t).clamp(0.0, 1.0);
                m.shininess = 2.0 / (m.roughness * m.roughness).max(1e-4) - 2.0;
            }
            if let Some(k) = &a.albedo {
                m.albedo = k.sample(t);
            }
            if let Some(k) = &a.specular {
                m.specular = k.sample(t);
            }
        }
        mats
    }

    /// Extras of material `i` (default when not set).
    pub fn material_extra(&self, i: usize) -> MaterialExtra {
        self.material_extras.get(i).cloned().unwrap_or_default()
    }

    /// Motion and flags of object `i` (static default when not set).
    pub fn object_info(&self, i: usize) -> ObjectInfo {
        self.object_info.get(i).cloned().unwrap_or_default()
    }

    /// What the scene needs from the render graph.
    pub fn requirements(&self) -> Requirements {
        let info = |i: usize| self.object_info.get(i);
        let n = self.objects.len();
        Requirements {
            environment_light: self.environment.is_some(),
            local_lights: !self.lights.is_empty(),
            medium: self.medium.is_some(),
            moving_objects: (0..n).any(|i| info(i).is_some_and(|x| x.is_moving())),
            deforming_objects: (0..n).any(|i| info(i).is_some_and(|x| x.is_deforming())),
            thin_shells: (0..n).any(|i| info(i).is_some_and(|x| x.thin_shell)),
            spatially_varying_materials: self
                .objects
                .iter()
                .any(|o| self.material_extras.get(o.material).is_some_and(|e| e.is_spatially_varying())),
            animated_camera: self.camera_path.as_ref().is_some_and(|p| {
                p.eye.as_ref().is_some_and(|k| !k.is_constant())
                    || p.target.as_ref().is_some_and(|k| !k.is_constant())
                    || p.fov_y_deg.as_ref().is_some_and(|k| !k.is_constant())
            }),
            animated_lights: self.lights.iter().any(|l| !l.motion.is_static()),
            animated_materials: self.material_animations.iter().any(|a| {
                a.roughness.as_ref().is_some_and(|k| !k.is_constant())
                    || a.albedo.as_ref().is_some_and(|k| !k.is_constant())
                    || a.specular.as_ref().is_some_and(|k| !k.is_constant())
            }),
            animated_environment: self.environment.is_some()
                && self.environment_animation.as_ref().is_some_and(|a| {
                    a.rotation.as_ref().is_some_and(|k| !k.is_constant())
                        || a.intensity.as_ref().is_some_and(|k| !k.is_constant())
                }),
        }
    }

    /// Checks that every transform, light, camera and deformation stays finite at a set of
    /// sample times (0 to 60 s); loaders call it so huge-but-finite parameters that overflow
    /// during playback are reported at load time instead of producing NaN frames.
    pub fn check_finite_motion(&self) -> Result<(), String> {
        const TIMES: [f32; 10] = [0.0, 0.1, 0.5, 1.0, 1.7, 2.0, 3.3, 5.0, 10.0, 60.0];
        for t in TIMES {
            for i in 0..self.objects.len() {
                if !self.world_at(i, t).is_finite() {
                    return Err(format!(
                        "object '{}': its motion gives a non-finite transform at t = {t}",
                        self.objects[i].name
                    ));
                }
                if self.object_info.get(i).is_some_and(|x| x.is_deforming())
                    && self.deformed_mesh(i, t).positions.iter().any(|p| !p.is_finite())
                {
                    return Err(format!(
                        "object '{}': its deformation gives non-finite vertices at t = {t}",
                        self.objects[i].name
                    ));
                }
            }
            for l in &self.lights {
                let (p, d) = light_at(l, t);
                if !p.is_finite() || !d.is_finite() {
                    return Err(format!("light '{}': its motion gives a non-finite position at t = {t}", l.name));
                }
            }
            let c = self.camera_at(t);
            if !c.view().is_finite() {
                return Err(format!("camera: non-finite view at t = {t}"));
            }
            if self
                .materials_at(t)
                .iter()
                .any(|m| !m.albedo.is_finite() || !m.specular.is_finite() || !m.shininess.is_finite())
            {
                return Err(format!("a material animation gives non-finite values at t = {t}"));
            }
        }
        Ok(())
    }

    /// Total vertex count of the meshes used by the objects (each object counts its mesh).
    pub fn vertex_count(&self) -> usize {
        self.objects.iter().map(|o| self.meshes[o.mesh].positions.len()).sum()
    }

    /// Fails with [`SceneError::NotClosed`] naming the first shadow-casting, non-thin-shell
    /// object whose mesh is open or non-manifold; `why` says who needs it (e.g. the technique).
    pub fn check_closed_meshes(&self, why: &str) -> Result<(), SceneError> {
        let mut checked = vec![None; self.meshes.len()];
        for (i, o) in self.objects.iter().enumerate() {
            let info = self.object_info(i);
            if info.thin_shell || !info.casts_shadow {
                continue;
            }
            let stats = *checked[o.mesh].get_or_insert_with(|| self.meshes[o.mesh].edge_stats());
            if stats != EdgeStats::default() {
                let path = self.source.clone().unwrap_or_else(|| PathBuf::from(&self.name));
                return Err(SceneError::NotClosed {
                    mesh_file: info.source.unwrap_or_else(|| path.clone()),
                    path,
                    object: o.name.clone(),
                    boundary: stats.boundary,
                    non_manifold: stats.non_manifold,
                    why: why.to_string(),
                });
            }
        }
        Ok(())
    }

    /// Load a scene: `.toml` scene files ([`format`](mod@format)) or bare `.glb` / `.gltf` models
    /// ([`Scene::from_model`]). The technique name is kept as written (the renderer checks it).
    pub fn load(path: impl AsRef<Path>) -> Result<Scene, SceneError> {
        Self::load_with(path, &LoadOptions::default())
    }

    /// [`Scene::load`] with options.
    pub fn load_with(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Scene, SceneError> {
        let path = path.as_ref();
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let budget = Budget::new(options.limits);
        let scene = match ext.as_str() {
            "toml" => format::load_toml_with(path, options, &budget)?,
            "glb" | "gltf" => Self::from_model_with(path, &budget)?,
            _ => return Err(SceneError::UnknownFormat { path: path.to_path_buf() }),
        };
        if scene.medium.is_some() {
            if let Some(l) = scene.lights.iter().find(|l| matches!(l.kind, LightKind::Directional)) {
                return Err(SceneError::Unsupported {
                    path: path.to_path_buf(),
                    feature: format!(
                        "directional light '{}' in a scene with a participating medium (the medium fills all space: no light from infinity reaches it; use a spot or point light)",
                        l.name
                    ),
                });
            }
        }
        if options.require_closed_meshes {
            scene.check_closed_meshes(&format!("technique '{}' needs closed meshes", scene.technique))?;
        }
        Ok(scene)
    }

    /// A bare glTF model as a scene: its meshes, materials and (first) animation, standing on
    /// a ground plane, under the default procedural sky, with a camera framing its bounds.
    pub fn from_model(path: &Path) -> Result<Scene, SceneError> {
        Self::from_model_with(path, &Budget::new(Limits::default()))
    }

    /// [`Scene::from_model`] taking what the model needs from `budget`.
    pub fn from_model_with(path: &Path, budget: &Budget) -> Result<Scene, SceneError> {
        let asset = gltf_load::load_with(path, budget)?;
        let mut scene = Scene::empty(path.file_stem().and_then(|s| s.to_str()).unwrap_or("model"));
        scene.source = Some(path.to_path_buf());
        scene.environment = Some(Environment::procedural_sky(256, 128));
        let placement = Mat4::IDENTITY;
        let first = scene.objects.len();
        gltf_load::instantiate(&mut scene, &asset, placement, Some(0), None, path)?;
        let (lo, hi) = scene
            .bounds_at(0.0, first..scene.objects.len())
            .ok_or_else(|| SceneError::invalid(path, "the model has no geometry"))?;
        let center = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-4);
        // Ground plane under the model.
        let gm = scene.meshes.len();
        scene.meshes.push(MeshData::plane(radius * 10.0, 1));
        let mat = scene.materials.len();
        scene.materials.push(Material::diffuse("ground", Vec3::splat(0.5)));
        scene.objects.push(Object {
            name: "ground".into(),
            mesh: gm,
            material: mat,
            transform: Mat4::from_translation(Vec3::new(center.x, lo.y, center.z)),
        });
        scene.object_info.resize(scene.objects.len(), ObjectInfo::default());
        scene.object_info.last_mut().unwrap().casts_shadow = false;
        scene.camera = Camera::framing(lo, hi, 40.0);
        if let Some(c) = &asset.camera {
            // the file's camera: at its node's origin looking down the node's -Z, +Y up
            let world = placement * asset.rig.global(c.node, 0.0);
            let eye = world.transform_point3(Vec3::ZERO);
            let forward = world.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
            let up = world.transform_vector3(Vec3::Y).normalize_or(Vec3::Y);
            if !eye.is_finite() || forward == Vec3::ZERO || forward.cross(up).length() < 1e-4 {
                return Err(SceneError::invalid(
                    path,
                    format!("camera '{}': its node's transform is degenerate", c.name),
                ));
            }
            // an infinite projection gets the framing's far plane (or one past the model)
            let far = c.zfar.unwrap_or_else(|| scene.camera.far.max((eye - center).length() + 4.0 * radius));
            scene.camera = Camera { eye, target: eye + forward, up, fov_y_deg: c.yfov_deg, near: c.znear, far };
            if asset.rig.node_animated(c.node) {
                scene.warnings.push(format!(
                    "{}: camera '{}': its node is animated; the camera stays where it is at t = 0",
                    path.display(),
                    c.name
                ));
            }
        }
        scene.check_finite_motion().map_err(|m| SceneError::invalid(path, m))?;
        if !scene.camera.view().is_finite() || !scene.camera.far.is_finite() {
            return Err(SceneError::invalid(path, "the model's bounds are too large to frame"));
        }
        Ok(scene)
    }

    /// An empty scene (no objects) with a default camera and no lighting.
    pub fn empty(name: &str) -> Scene {
        Scene {
            name: name.into(),
            camera: Camera {
                eye: Vec3::new(0.0, 1.0, 4.0),
                target: Vec3::ZERO,
                up: Vec3::Y,
                fov_y_deg: 45.0,
                near: 0.05,
                far: 100.0,
            },
            environment: None,
            meshes: Vec::new(),
            materials: Vec::new(),
            objects: Vec::new(),
            technique: DEFAULT_TECHNIQUE.into(),
            technique_params: Default::default(),
            lights: Vec::new(),
            medium: None,
            volumetric: None,
            textures: Vec::new(),
            material_extras: Vec::new(),
            object_info: Vec::new(),
            material_animations: Vec::new(),
            camera_path: None,
            environment_animation: None,
            warnings: Vec::new(),
            source: None,
        }
    }

    /// World-space bounds of the given objects at time `t` (deformations included).
    pub fn bounds_at(&self, t: f32, objects: std::ops::Range<usize>) -> Option<(Vec3, Vec3)> {
        let mut b: Option<(Vec3, Vec3)> = None;
        for i in objects {
            let w = self.world_at(i, t);
            let m = self.deformed_mesh(i, t);
            for p in &m.positions {
                let q = w.transform_point3(*p);
                b = Some(match b {
                    None => (q, q),
                    Some((lo, hi)) => (lo.min(q), hi.max(q)),
                });
            }
        }
        b
    }

    /// The built-in default scene of `penumbra render`: a few primitives on a plane under a
    /// procedural sky.
    pub fn default_scene() -> Scene {
        let meshes = vec![
            MeshData::plane(8.0, 1),
            MeshData::uv_sphere(0.7, 48, 24),
            MeshData::cube(0.6),
            MeshData::torus(0.55, 0.2, 48, 16),
        ];
        let materials = vec![
            Material::diffuse("ground", Vec3::new(0.6, 0.6, 0.58)),
            Material::glossy("red_plastic", Vec3::new(0.7, 0.12, 0.1), Vec3::splat(0.04), 0.3),
            Material::diffuse("blue_matte", Vec3::new(0.15, 0.3, 0.75)),
            Material::glossy("gold", Vec3::new(0.05, 0.04, 0.02), Vec3::new(1.0, 0.78, 0.34), 0.25),
        ];
        let objects = vec![
            Object { name: "ground".into(), mesh: 0, material: 0, transform: Mat4::IDENTITY },
            Object {
                name: "sphere".into(),
                mesh: 1,
                material: 1,
                transform: Mat4::from_translation(Vec3::new(-1.1, 0.7, 0.0)),
            },
            Object {
                name: "cube".into(),
                mesh: 2,
                material: 2,
                transform: Mat4::from_translation(Vec3::new(0.9, 0.6, -0.6)) * Mat4::from_rotation_y(0.6),
            },
            Object {
                name: "torus".into(),
                mesh: 3,
                material: 3,
                transform: Mat4::from_translation(Vec3::new(0.6, 0.2, 1.1)),
            },
        ];
        let mut s = Scene::empty("default");
        s.camera = Camera {
            eye: Vec3::new(0.0, 2.2, 5.0),
            target: Vec3::new(0.0, 0.5, 0.0),
            up: Vec3::Y,
            fov_y_deg: 45.0,
            near: 0.05,
            far: 100.0,
        };
        s.environment = Some(Environment::procedural_sky(256, 128));
        s.meshes = meshes;
        s.materials = materials;
        s.objects = objects;
        s.object_info = vec![ObjectInfo::default(); s.objects.len()];
        s.object_info[0].casts_shadow = false;
        s
    }
}

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

pub mod mesh;
pub use mesh::MeshData;

use glam::{Mat4, Vec3};

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
/// Direction for pixel centre (u, v) in [0,1]^2: phi = 2*pi*u, theta = pi*v,
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
    /// Unit direction for lat-long coordinates (u, v) in [0,1]^2 (before `rotation`).
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

/// A complete scene at rest.
#[derive(Clone, Debug)]
pub struct Scene {
    pub name: String,
    pub camera: Camera,
    pub environment: Option<Environment>,
    pub meshes: Vec<MeshData>,
    pub materials: Vec<Material>,
    pub objects: Vec<Object>,
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
}

/// The scene evaluated at one time.
#[derive(Clone, Debug)]
pub struct Frame {
    pub time: f32,
    pub camera: Camera,
    pub instances: Vec<Instance>,
}

impl Scene {
    /// Evaluate the scene at time `t` (seconds); `prev_t` gives the previous frame's time for
    /// motion vectors (None on the first frame).
    pub fn at(&self, t: f32, _prev_t: Option<f32>) -> Frame {
        let instances = self
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| Instance {
                object: i,
                mesh: o.mesh,
                material: o.material,
                world: o.transform,
                prev_world: o.transform,
                moved: false,
            })
            .collect();
        Frame { time: t, camera: self.camera.clone(), instances }
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
                transform: Mat4::from_translation(Vec3::new(0.9, 0.6, -0.6))
                    * Mat4::from_rotation_y(0.6),
            },
            Object {
                name: "torus".into(),
                mesh: 3,
                material: 3,
                transform: Mat4::from_translation(Vec3::new(0.6, 0.2, 1.1)),
            },
        ];
        Scene {
            name: "default".into(),
            camera: Camera {
                eye: Vec3::new(0.0, 2.2, 5.0),
                target: Vec3::new(0.0, 0.5, 0.0),
                up: Vec3::Y,
                fov_y_deg: 45.0,
                near: 0.05,
                far: 100.0,
            },
            environment: Some(Environment::procedural_sky(256, 128)),
            meshes,
            materials,
            objects,
        }
    }
}

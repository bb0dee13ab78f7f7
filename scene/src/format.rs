//! The TOML scene file format. `scenes/example.toml` documents every key with comments.
//!
//! Summary (all lengths in scene units, angles in degrees, times in seconds, colours linear
//! RGB; a colour or vector given as one number means that number in every component):
//!
//! ```toml
//! name = "my_scene"          # default: the file name
//! technique = "auto"         # visibility technique, default "auto" (the engine chooses)
//! [technique_params]         # key = value parameters of the technique (e.g. isg: lobes = 16)
//! [camera]                   # eye, target, up, fov_deg, near, far; [[camera.keys]] t, eye, target, fov_deg
//! [environment]              # file = "x.exr" | "x.hdr", or procedural = "sky"; intensity; rotation_deg;
//!                            # loop, [[environment.keys]] t, rotation_deg, intensity
//! [[light]]                  # type = "point" | "spot" | "sphere" | "directional", position (not for
//!                            # "directional"), direction, color, intensity (W/sr; directional: the
//!                            # irradiance it gives a surface facing it), inner_deg, outer_deg,
//!                            # radius, motion = {...}, fixture = "object name" (moves with it)
//! [medium]                   # sigma_a, sigma_s, g (Henyey-Greenstein), volumetric = "temporal" | "full"
//! [materials.NAME]           # type = "diffuse" | "blinn_phong" | "cook_torrance" | "ashikhmin_shirley",
//!                            # albedo, specular, roughness, shininess, shininess_v, two_sided, emission (rgb radiance the eye sees),
//!                            # albedo_map / roughness_map / normal_map (tangent space, linear) =
//!                            # { file = "x.png" } | { pattern = "checker", ... },
//!                            # loop, [[materials.NAME.keys]] t, roughness, albedo, specular
//! [[object]]                 # name, mesh = { type = "sphere", ... } | file = "x.glb", material,
//!                            # position, rotation_deg, scale, fit_height, animation, thin_shell,
//!                            # casts_shadow, motion = { type = ... }, deform = [{ type = ... }]
//! ```
//!
//! Unknown keys and wrong types are errors that quote line and column. File paths are
//! relative to the scene file.

use crate::error::SceneError;
use crate::gltf_load::{self, GltfAsset};
use crate::motion::{Deformation, Interp, RigidMotion, Track};
use crate::texture::{Pattern, Texture};
use crate::{
    BrdfKind, CameraPath, Environment, Light, LightKind, LoadOptions, Material, MaterialAnimation, MaterialExtra,
    Medium, MeshData, Object, ObjectInfo, Scene,
};
use glam::{Mat4, Quat, Vec3, Vec4};
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::Deserialize;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use toml::Spanned;

/// A 3-vector written as `[x, y, z]` or as one number (all components).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct V3(pub Vec3);

impl<'de> Deserialize<'de> for V3 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Vis;
        impl<'de> Visitor<'de> for Vis {
            type Value = V3;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or an array of 3 numbers")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> Result<V3, E> {
                Ok(V3(Vec3::splat(v as f32)))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<V3, E> {
                Ok(V3(Vec3::splat(v as f32)))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<V3, A::Error> {
                let mut v = [0.0f32; 3];
                for (k, c) in v.iter_mut().enumerate() {
                    *c = seq.next_element::<f32>()?.ok_or_else(|| de::Error::invalid_length(k, &self))?;
                }
                if seq.next_element::<f32>()?.is_some() {
                    return Err(de::Error::invalid_length(4, &self));
                }
                Ok(V3(Vec3::from_array(v)))
            }
        }
        d.deserialize_any(Vis)
    }
}

fn one() -> f32 {
    1.0
}
fn yes() -> bool {
    true
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: Option<String>,
    technique: Option<String>,
    #[serde(default)]
    technique_params: BTreeMap<String, toml::Value>,
    camera: CameraSpec,
    environment: Option<Spanned<EnvSpec>>,
    #[serde(default)]
    light: Vec<Spanned<LightSpec>>,
    medium: Option<MediumSpec>,
    #[serde(default)]
    materials: BTreeMap<String, Spanned<MaterialSpec>>,
    #[serde(default)]
    object: Vec<Spanned<ObjectSpec>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSpec {
    eye: V3,
    target: V3,
    up: Option<V3>,
    fov_deg: Option<f32>,
    near: Option<f32>,
    far: Option<f32>,
    #[serde(default)]
    keys: Vec<CameraKey>,
    #[serde(default, rename = "loop")]
    looping: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraKey {
    t: f32,
    eye: V3,
    target: V3,
    fov_deg: Option<f32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvSpec {
    file: Option<String>,
    procedural: Option<String>,
    #[serde(default = "one")]
    intensity: f32,
    #[serde(default)]
    rotation_deg: f32,
    /// Keyframes of rotation_deg and intensity over time (each in every key or in none).
    #[serde(default)]
    keys: Vec<EnvKey>,
    #[serde(default, rename = "loop")]
    looping: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EnvKey {
    t: f32,
    rotation_deg: Option<f32>,
    intensity: Option<f32>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
enum LightType {
    Point,
    Spot,
    Sphere,
    Directional,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LightSpec {
    name: Option<String>,
    #[serde(rename = "type")]
    kind: LightType,
    position: Option<V3>,
    direction: Option<V3>,
    color: Option<V3>,
    intensity: f32,
    inner_deg: Option<f32>,
    outer_deg: Option<f32>,
    radius: Option<f32>,
    motion: Option<MotionSpec>,
    /// Name of the object that is the light's fixture (moves with it).
    fixture: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MediumSpec {
    sigma_a: V3,
    sigma_s: V3,
    #[serde(default)]
    g: f32,
    /// "temporal" (default) or "full".
    volumetric: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, rename_all = "snake_case")]
enum MaterialType {
    Diffuse,
    BlinnPhong,
    CookTorrance,
    AshikhminShirley,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialSpec {
    #[serde(rename = "type")]
    kind: MaterialType,
    albedo: V3,
    specular: Option<V3>,
    roughness: Option<f32>,
    shininess: Option<f32>,
    shininess_v: Option<f32>,
    #[serde(default)]
    two_sided: bool,
    emission: Option<V3>,
    albedo_map: Option<TextureSpec>,
    roughness_map: Option<TextureSpec>,
    normal_map: Option<TextureSpec>,
    #[serde(default)]
    keys: Vec<MaterialKey>,
    #[serde(default, rename = "loop")]
    looping: bool,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MaterialKey {
    t: f32,
    roughness: Option<f32>,
    albedo: Option<V3>,
    specular: Option<V3>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TextureSpec {
    file: Option<String>,
    pattern: Option<String>,
    #[serde(default = "eight")]
    scale: f32,
    a: Option<V3>,
    b: Option<V3>,
    #[serde(default = "tex_size")]
    size: u32,
}
fn eight() -> f32 {
    8.0
}
fn tex_size() -> u32 {
    256
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, tag = "type", rename_all = "snake_case")]
enum MeshSpec {
    Plane {
        size: f32,
        #[serde(default)]
        divisions: Option<u32>,
    },
    Sphere {
        radius: f32,
        slices: Option<u32>,
        stacks: Option<u32>,
    },
    Icosphere {
        radius: f32,
        subdivisions: Option<u32>,
    },
    Cube {
        size: f32,
    },
    Torus {
        major_radius: f32,
        minor_radius: f32,
        major_segments: Option<u32>,
        minor_segments: Option<u32>,
    },
    Cloth {
        size_x: f32,
        size_z: f32,
        nx: Option<u32>,
        nz: Option<u32>,
        folds: Option<f32>,
        fold_height: Option<f32>,
    },
    Hat {
        radius: f32,
        height: f32,
        segments: Option<u32>,
        rings: Option<u32>,
    },
    Dish {
        radius: f32,
        depth: f32,
        segments: Option<u32>,
        rings: Option<u32>,
    },
    Chess {
        piece: String,
        #[serde(default = "one")]
        scale: f32,
        segments: Option<u32>,
    },
}

#[derive(Deserialize)]
#[serde(untagged)]
enum AnimSel {
    On(bool),
    Index(usize),
    Name(String),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectSpec {
    name: Option<String>,
    mesh: Option<MeshSpec>,
    file: Option<String>,
    material: Option<String>,
    position: Option<V3>,
    rotation_deg: Option<V3>,
    scale: Option<V3>,
    fit_height: Option<f32>,
    animation: Option<AnimSel>,
    #[serde(default)]
    thin_shell: bool,
    #[serde(default = "yes")]
    casts_shadow: bool,
    motion: Option<MotionSpec>,
    #[serde(default)]
    deform: Vec<DeformSpec>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, tag = "type", rename_all = "snake_case")]
enum MotionSpec {
    Static,
    Keyframes {
        keys: Vec<RigidKey>,
        #[serde(default, rename = "loop")]
        looping: bool,
        #[serde(default)]
        step: bool,
    },
    Spin {
        axis: V3,
        speed_deg: f32,
        center: Option<V3>,
    },
    Roll {
        center: V3,
        radius: f32,
        ball_radius: f32,
        period: f32,
        #[serde(default)]
        phase_deg: f32,
    },
    Fall {
        height: f32,
        #[serde(default = "gravity")]
        gravity: f32,
        #[serde(default)]
        restitution: f32,
        #[serde(default)]
        delay: f32,
        axis: Option<V3>,
        #[serde(default)]
        spin_deg: f32,
    },
    Oscillate {
        amplitude: V3,
        period: f32,
        #[serde(default)]
        phase_deg: f32,
    },
}
fn gravity() -> f32 {
    9.81
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RigidKey {
    t: f32,
    position: Option<V3>,
    rotation_deg: Option<V3>,
    scale: Option<V3>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, tag = "type", rename_all = "snake_case")]
enum DeformSpec {
    Wave {
        amplitude: f32,
        wavelength: f32,
        period: f32,
        direction: Option<V3>,
        #[serde(default)]
        pinned: bool,
    },
    Squash {
        amount: f32,
        period: f32,
    },
}

/// Line and column (1-based) of byte offset `at` in `text`.
fn line_col(text: &str, at: usize) -> (usize, usize) {
    let at = at.min(text.len());
    let before = &text[..at];
    let line = before.matches('\n').count() + 1;
    let col = before.rfind('\n').map_or(at, |n| at - n - 1) + 1;
    (line, col)
}

/// Euler angles in degrees, applied X first, then Y, then Z (R = Rz * Ry * Rx).
pub fn euler_deg(v: Vec3) -> Quat {
    let r = v * (std::f32::consts::PI / 180.0);
    Quat::from_rotation_z(r.z) * Quat::from_rotation_y(r.y) * Quat::from_rotation_x(r.x)
}

struct Ctx<'a> {
    path: &'a Path,
    text: &'a str,
    dir: PathBuf,
    budget: &'a crate::Budget,
}

impl Ctx<'_> {
    fn err_at(&self, span: std::ops::Range<usize>, msg: impl std::fmt::Display) -> SceneError {
        let (l, c) = line_col(self.text, span.start);
        SceneError::invalid(self.path, format!("line {l}, column {c}: {msg}"))
    }
    /// Wrap an error from a referenced file with the scene file and line.
    fn referenced(&self, span: std::ops::Range<usize>) -> impl Fn(SceneError) -> SceneError + '_ {
        move |e| SceneError::Referenced {
            path: self.path.to_path_buf(),
            line: line_col(self.text, span.start).0,
            source: Box::new(e),
        }
    }
    fn resolve(&self, file: &str) -> PathBuf {
        self.dir.join(file)
    }
}

/// Load a TOML scene file.
pub fn load_toml(path: &Path, options: &LoadOptions) -> Result<Scene, SceneError> {
    load_toml_with(path, options, &crate::Budget::new(options.limits))
}

/// [`load_toml`] taking what it loads from `budget`.
pub fn load_toml_with(path: &Path, options: &LoadOptions, budget: &crate::Budget) -> Result<Scene, SceneError> {
    let bytes = budget.read_file(path, "scene file", options.limits.max_scene_file_bytes)?;
    let text = String::from_utf8(bytes).map_err(|e| SceneError::Syntax {
        path: path.to_path_buf(),
        message: format!("not UTF-8 text (byte {})", e.utf8_error().valid_up_to()),
    })?;
    parse_toml_with(path, &text, options, budget)
}

/// Parse scene-file text; `path` names the file in messages and anchors relative paths.
pub fn parse_toml(path: &Path, text: &str, options: &LoadOptions) -> Result<Scene, SceneError> {
    parse_toml_with(path, text, options, &crate::Budget::new(options.limits))
}

/// [`parse_toml`] taking what the referenced files need from `budget`.
pub fn parse_toml_with(
    path: &Path,
    text: &str,
    options: &LoadOptions,
    budget: &crate::Budget,
) -> Result<Scene, SceneError> {
    let file: SceneFile = toml::from_str(text)
        .map_err(|e| SceneError::Syntax { path: path.to_path_buf(), message: e.to_string().trim_end().to_string() })?;
    let ctx = Ctx { path, text, dir: path.parent().map(Path::to_path_buf).unwrap_or_default(), budget };
    let mut scene = Scene::empty(
        &file.name.clone().unwrap_or_else(|| path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene").to_string()),
    );
    scene.source = Some(path.to_path_buf());

    // Technique.
    if let Some(t) = &file.technique {
        if let Some(known) = &options.techniques {
            if !known.iter().any(|k| k == t) {
                return Err(SceneError::invalid(
                    path,
                    format!("unknown technique '{t}' (known: {})", known.join(", ")),
                ));
            }
        }
        scene.technique = t.clone();
    }
    for (k, v) in &file.technique_params {
        let text = match v {
            toml::Value::String(s) => s.clone(),
            toml::Value::Integer(i) => i.to_string(),
            toml::Value::Float(f) => f.to_string(),
            toml::Value::Boolean(b) => b.to_string(),
            other => {
                return Err(SceneError::invalid(
                    path,
                    format!("technique_params.{k}: expected a number, boolean or string, got {}", other.type_str()),
                ))
            }
        };
        scene.technique_params.insert(k.clone(), text);
    }

    // Camera.
    let c = &file.camera;
    scene.camera.eye = finite3(&ctx, "camera.eye", c.eye.0)?;
    scene.camera.target = finite3(&ctx, "camera.target", c.target.0)?;
    scene.camera.up = finite3(&ctx, "camera.up", c.up.map_or(Vec3::Y, |v| v.0))?;
    scene.camera.fov_y_deg = c.fov_deg.unwrap_or(45.0);
    scene.camera.near = c.near.unwrap_or(0.05);
    scene.camera.far = c.far.unwrap_or(100.0);
    let cam = &scene.camera;
    if !(cam.fov_y_deg > 0.0 && cam.fov_y_deg < 180.0) {
        return Err(SceneError::invalid(path, format!("camera.fov_deg must be in (0, 180), got {}", cam.fov_y_deg)));
    }
    if !(cam.near > 0.0 && cam.far > cam.near && cam.far.is_finite()) {
        return Err(SceneError::invalid(
            path,
            format!("camera needs 0 < near < far, got near {} far {}", cam.near, cam.far),
        ));
    }
    if (cam.eye - cam.target).length() < 1e-6 || (cam.eye - cam.target).cross(cam.up).length() < 1e-9 {
        return Err(SceneError::invalid(path, "camera eye equals target or up is parallel to the view direction"));
    }
    if !c.keys.is_empty() {
        let times: Vec<f32> = c.keys.iter().map(|k| k.t).collect();
        let interp = Interp::Linear;
        let mk = |v: Vec<Vec3>, what: &str| -> Result<Track<Vec3>, SceneError> {
            if v.iter().any(|x| !x.is_finite()) {
                return Err(SceneError::invalid(path, format!("camera.keys: {what} has a NaN/Inf component")));
            }
            Track::new(times.clone(), v, interp, c.looping)
                .map_err(|m| SceneError::invalid(path, format!("camera.keys: {m}")))
        };
        let eye = mk(c.keys.iter().map(|k| k.eye.0).collect(), "eye")?;
        let target = mk(c.keys.iter().map(|k| k.target.0).collect(), "target")?;
        let fovs: Vec<Option<f32>> = c.keys.iter().map(|k| k.fov_deg).collect();
        let fov = if fovs.iter().all(|f| f.is_some()) {
            let v: Vec<f32> = fovs.into_iter().flatten().collect();
            if v.iter().any(|f| !(*f > 0.0 && *f < 180.0)) {
                return Err(SceneError::invalid(path, "camera.keys: fov_deg must be in (0, 180)"));
            }
            Some(Track::new(times.clone(), v, interp, c.looping).map_err(|m| SceneError::invalid(path, m))?)
        } else if fovs.iter().any(|f| f.is_some()) {
            return Err(SceneError::invalid(path, "camera.keys: give fov_deg in every key or in none"));
        } else {
            None
        };
        scene.camera_path = Some(CameraPath { eye: Some(eye), target: Some(target), fov_y_deg: fov });
    }

    // Environment.
    if let Some(e) = &file.environment {
        let span = e.span();
        let e = e.get_ref();
        let mut env = match (&e.file, &e.procedural) {
            (Some(f), None) => {
                Environment::load_with(&ctx.resolve(f), ctx.budget).map_err(ctx.referenced(span.clone()))?
            }
            (None, Some(p)) if p == "sky" => Environment::procedural_sky(256, 128),
            (None, Some(p)) => {
                return Err(SceneError::invalid(path, format!("environment.procedural: unknown '{p}' (known: sky)")))
            }
            _ => return Err(SceneError::invalid(path, "environment: give exactly one of `file` or `procedural`")),
        };
        if !(e.intensity.is_finite() && e.intensity >= 0.0 && e.rotation_deg.is_finite()) {
            return Err(SceneError::invalid(
                path,
                "environment: intensity must be finite and >= 0, rotation_deg finite",
            ));
        }
        env.intensity = e.intensity;
        env.rotation = e.rotation_deg.to_radians();
        if !e.keys.is_empty() {
            let bad = |m: String| ctx.err_at(span.clone(), format!("environment.keys: {m}"));
            let times: Vec<f32> = e.keys.iter().map(|k| k.t).collect();
            let rot: Vec<Option<f32>> = e.keys.iter().map(|k| k.rotation_deg.map(f32::to_radians)).collect();
            let int: Vec<Option<f32>> = e.keys.iter().map(|k| k.intensity).collect();
            if rot.iter().flatten().any(|r| !r.is_finite()) {
                return Err(bad("rotation_deg must be finite".into()));
            }
            if int.iter().flatten().any(|i| !(i.is_finite() && *i >= 0.0)) {
                return Err(bad("intensity must be finite and >= 0".into()));
            }
            let anim = crate::EnvironmentAnimation {
                rotation: keyed_track(rot, &times, e.looping, "rotation_deg").map_err(bad)?,
                intensity: keyed_track(int, &times, e.looping, "intensity").map_err(bad)?,
            };
            if anim.rotation.is_none() && anim.intensity.is_none() {
                return Err(bad("give rotation_deg or intensity in the keys".into()));
            }
            scene.environment_animation = Some(anim);
        }
        let repaired = env.repair_texels();
        if repaired > 0 {
            let what = e.file.as_deref().unwrap_or("the environment map");
            scene.warnings.push(format!(
                "{what}: {repaired} texels with a negative channel read as black (by every technique and the reference)"
            ));
        }
        scene.environment = Some(env);
    }

    // Lights (fixtures are resolved after the objects).
    let mut fixtures: Vec<(usize, String, std::ops::Range<usize>, bool)> = Vec::new();
    for (i, l) in file.light.iter().enumerate() {
        let span = l.span();
        let l = l.get_ref();
        let name = l.name.clone().unwrap_or_else(|| format!("light{i}"));
        let what = format!("light '{name}'");
        let position = match (&l.kind, l.position) {
            (LightType::Directional, None) => Vec3::ZERO,
            (LightType::Directional, Some(_)) => {
                return Err(ctx.err_at(span, format!("{what}: a directional light has no position (give `direction`)")))
            }
            (_, Some(p)) => p.0,
            (_, None) => return Err(ctx.err_at(span, format!("{what}: missing `position`"))),
        };
        let direction = l.direction.map_or(Vec3::NEG_Y, |d| d.0);
        let color = l.color.map_or(Vec3::ONE, |c| c.0);
        if !position.is_finite() || !direction.is_finite() || !color.is_finite() || !l.intensity.is_finite() {
            return Err(ctx.err_at(span, format!("{what}: a value is NaN or infinite")));
        }
        if l.intensity < 0.0 || color.min_element() < 0.0 {
            return Err(ctx.err_at(span, format!("{what}: intensity and color must be >= 0")));
        }
        let kind = match l.kind {
            LightType::Point => LightKind::Point,
            LightType::Spot => {
                let outer = l.outer_deg.unwrap_or(30.0);
                let inner = l.inner_deg.unwrap_or(outer * 0.8);
                if !(inner >= 0.0 && inner <= outer && outer > 0.0 && outer < 90.0) {
                    return Err(ctx.err_at(span, format!("{what}: need 0 <= inner_deg <= outer_deg < 90")));
                }
                if direction.length() < 1e-6 {
                    return Err(ctx.err_at(span, format!("{what}: direction is zero")));
                }
                LightKind::Spot { inner_deg: inner, outer_deg: outer }
            }
            LightType::Sphere => {
                let r = l.radius.unwrap_or(0.1);
                if !(r > 0.0 && r.is_finite()) {
                    return Err(ctx.err_at(span, format!("{what}: radius must be > 0")));
                }
                LightKind::Sphere { radius: r }
            }
            LightType::Directional => {
                if l.direction.is_none() || direction.length() < 1e-6 {
                    return Err(ctx.err_at(span, format!("{what}: a directional light needs a non-zero `direction`")));
                }
                LightKind::Directional
            }
        };
        let motion = match &l.motion {
            Some(m) => motion(&ctx, span.clone(), &what, m)?,
            None => RigidMotion::Static,
        };
        if let Some(f) = &l.fixture {
            if matches!(l.kind, LightType::Directional) {
                return Err(ctx.err_at(span, format!("{what}: a directional light has no fixture")));
            }
            fixtures.push((scene.lights.len(), f.clone(), span.clone(), l.motion.is_some()));
        }
        scene.lights.push(Light {
            name,
            kind,
            position,
            direction: direction.normalize_or(Vec3::NEG_Y),
            color,
            intensity: l.intensity,
            motion,
            fixture: None,
        });
    }

    // Medium.
    if let Some(m) = &file.medium {
        let (a, s) = (m.sigma_a.0, m.sigma_s.0);
        if !a.is_finite() || !s.is_finite() || a.min_element() < 0.0 || s.min_element() < 0.0 {
            return Err(SceneError::invalid(path, "medium: sigma_a and sigma_s must be finite and >= 0"));
        }
        if !(m.g > -1.0 && m.g < 1.0) {
            return Err(SceneError::invalid(path, format!("medium: g must be in (-1, 1), got {}", m.g)));
        }
        scene.medium = Some(Medium { sigma_a: a, sigma_s: s, g: m.g });
        if let Some(v) = &m.volumetric {
            if v != "temporal" && v != "full" {
                return Err(SceneError::invalid(
                    path,
                    format!("medium: volumetric must be \"temporal\" or \"full\", got \"{v}\""),
                ));
            }
            scene.volumetric = Some(v.clone());
        }
    }

    // Materials.
    let mut mat_index: HashMap<String, usize> = HashMap::new();
    for (name, spec) in &file.materials {
        let span = spec.span();
        let m = spec.get_ref();
        let what = format!("material '{name}'");
        let (mat, extra, anim) = material(&ctx, span, &what, name, m, &mut scene.textures, scene.materials.len())?;
        mat_index.insert(name.clone(), scene.materials.len());
        scene.materials.push(mat);
        scene.material_extras.push(extra);
        if let Some(a) = anim {
            scene.material_animations.push(a);
        }
    }

    // Objects.
    if file.object.is_empty() {
        return Err(SceneError::invalid(path, "empty scene: no [[object]] entries"));
    }
    let mut assets: HashMap<PathBuf, GltfAsset> = HashMap::new();
    let mut default_material = None;
    for (i, o) in file.object.iter().enumerate() {
        let span = o.span();
        let o = o.get_ref();
        let name = o.name.clone().unwrap_or_else(|| format!("object{i}"));
        let what = format!("object '{name}'");
        let position = o.position.map_or(Vec3::ZERO, |v| v.0);
        let rotation = o.rotation_deg.map_or(Vec3::ZERO, |v| v.0);
        let scale = o.scale.map_or(Vec3::ONE, |v| v.0);
        if !position.is_finite() || !rotation.is_finite() || !scale.is_finite() {
            return Err(ctx.err_at(span, format!("{what}: transform has a NaN or infinite value")));
        }
        if scale.abs().min_element() < 1e-8 {
            return Err(ctx.err_at(span, format!("{what}: scale has a zero component")));
        }
        let transform = Mat4::from_scale_rotation_translation(scale, euler_deg(rotation), position);
        let material = match &o.material {
            Some(m) => Some(*mat_index.get(m).ok_or_else(|| {
                let mut known: Vec<&String> = mat_index.keys().collect();
                known.sort();
                ctx.err_at(span.clone(), format!("{what}: unknown material '{m}' (defined: {known:?})"))
            })?),
            None => None,
        };
        let rigid = match &o.motion {
            Some(m) => motion(&ctx, span.clone(), &what, m)?,
            None => RigidMotion::Static,
        };
        let mut deformations = Vec::new();
        for d in &o.deform {
            deformations.push(deform(&ctx, span.clone(), &what, d)?);
        }
        let range = match (&o.mesh, &o.file) {
            (Some(spec), None) => {
                if o.fit_height.is_some() || o.animation.is_some() {
                    return Err(ctx.err_at(span, format!("{what}: fit_height and animation apply to glTF files only")));
                }
                let mut mesh = primitive(&ctx, span.clone(), &what, spec)?;
                mesh.validate_and_repair(&path.display().to_string(), &mut scene.warnings)
                    .map_err(|m| ctx.err_at(span.clone(), format!("{what}: {m}")))?;
                let mat = match material {
                    Some(m) => m,
                    None => *default_material.get_or_insert_with(|| {
                        scene.materials.push(Material::diffuse("default", Vec3::splat(0.7)));
                        scene.material_extras.push(MaterialExtra::default());
                        scene.materials.len() - 1
                    }),
                };
                scene.meshes.push(mesh);
                scene.objects.push(Object {
                    name: name.clone(),
                    mesh: scene.meshes.len() - 1,
                    material: mat,
                    transform,
                });
                scene.object_info.push(ObjectInfo::default());
                scene.objects.len() - 1..scene.objects.len()
            }
            (None, Some(f)) => {
                let fp = ctx.resolve(f);
                if !assets.contains_key(&fp) {
                    let a = gltf_load::load_with(&fp, ctx.budget).map_err(ctx.referenced(span.clone()))?;
                    assets.insert(fp.clone(), a);
                }
                let asset = &assets[&fp];
                let animation = match &o.animation {
                    None | Some(AnimSel::On(true)) => Some(0),
                    Some(AnimSel::On(false)) => None,
                    Some(AnimSel::Index(k)) => {
                        if *k >= asset.animation_names.len() {
                            return Err(ctx.err_at(
                                span,
                                format!(
                                    "{what}: animation {k} does not exist ({} has {})",
                                    f,
                                    asset.animation_names.len()
                                ),
                            ));
                        }
                        Some(*k)
                    }
                    Some(AnimSel::Name(n)) => {
                        Some(asset.animation_names.iter().position(|x| x == n).ok_or_else(|| {
                            ctx.err_at(
                                span.clone(),
                                format!("{what}: no animation named '{n}' in {f} (has {:?})", asset.animation_names),
                            )
                        })?)
                    }
                };
                let fit = match o.fit_height {
                    None => Mat4::IDENTITY,
                    Some(h) if h > 0.0 && h.is_finite() => {
                        let mut tmp = Scene::empty("fit");
                        let r = gltf_load::instantiate(&mut tmp, asset, Mat4::IDENTITY, animation, None, &fp)?;
                        let (lo, hi) =
                            tmp.bounds_at(0.0, r).ok_or_else(|| SceneError::invalid(&fp, "model has no geometry"))?;
                        let s = h / (hi.y - lo.y).max(1e-9);
                        let c = (lo + hi) * 0.5;
                        Mat4::from_scale(Vec3::splat(s)) * Mat4::from_translation(Vec3::new(-c.x, -lo.y, -c.z))
                    }
                    Some(h) => return Err(ctx.err_at(span, format!("{what}: fit_height must be > 0, got {h}"))),
                };
                let r = gltf_load::instantiate(&mut scene, asset, transform * fit, animation, material, &fp)?;
                for k in r.clone() {
                    if r.len() > 1 {
                        scene.objects[k].name = format!("{name}/{}", scene.objects[k].name);
                    } else {
                        scene.objects[k].name = name.clone();
                    }
                }
                r
            }
            _ => return Err(ctx.err_at(span, format!("{what}: give exactly one of `mesh` or `file`"))),
        };
        for k in range {
            let info = &mut scene.object_info[k];
            info.motion = rigid.clone();
            info.deformations.extend(deformations.iter().cloned());
            info.thin_shell |= o.thin_shell;
            info.casts_shadow = o.casts_shadow;
            if info.source.is_none() {
                info.source = Some(path.to_path_buf());
            }
        }
    }
    for (li, name, span, own_motion) in fixtures {
        let what = format!("light '{}'", scene.lights[li].name);
        let found: Vec<usize> = (0..scene.objects.len()).filter(|&k| scene.objects[k].name == name).collect();
        let k = match found[..] {
            [k] => k,
            [] => {
                let known: Vec<&str> = scene.objects.iter().map(|o| o.name.as_str()).collect();
                return Err(ctx.err_at(span, format!("{what}: fixture '{name}' is no object (objects: {known:?})")));
            }
            _ => return Err(ctx.err_at(span, format!("{what}: fixture '{name}' names {} objects", found.len()))),
        };
        let info = &scene.object_info[k];
        if !info.deformations.is_empty() || info.node.as_ref().is_some_and(|n| n.rig.node_animated(n.node)) {
            return Err(ctx.err_at(
                span,
                format!("{what}: fixture '{name}' deforms or is animated by its file; a fixture must be rigid"),
            ));
        }
        if own_motion && scene.lights[li].motion != info.motion {
            return Err(ctx.err_at(
                span,
                format!(
                    "{what}: its motion differs from its fixture '{name}''s (leave the light's `motion` out: it \
                     moves with its fixture)"
                ),
            ));
        }
        scene.lights[li].motion = info.motion.clone();
        scene.lights[li].fixture = Some(k);
    }
    scene.check_finite_motion().map_err(|m| SceneError::invalid(path, m))?;
    if scene.environment.is_none() && scene.lights.is_empty() {
        scene.warnings.push(format!("{}: no environment and no lights: the scene is unlit", path.display()));
    }
    Ok(scene)
}

fn finite3(ctx: &Ctx, what: &str, v: Vec3) -> Result<Vec3, SceneError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(SceneError::invalid(ctx.path, format!("{what} has a NaN or infinite component")))
    }
}

fn positive(ctx: &Ctx, span: &std::ops::Range<usize>, what: &str, key: &str, v: f32) -> Result<f32, SceneError> {
    if v > 0.0 && v.is_finite() {
        Ok(v)
    } else {
        Err(ctx.err_at(span.clone(), format!("{what}: {key} must be a positive finite number, got {v}")))
    }
}

fn primitive(ctx: &Ctx, span: std::ops::Range<usize>, what: &str, spec: &MeshSpec) -> Result<MeshData, SceneError> {
    let p = |key: &str, v: f32| positive(ctx, &span, what, key, v);
    let seg = |v: Option<u32>, d: u32| v.unwrap_or(d).clamp(3, 1024);
    Ok(match spec {
        MeshSpec::Plane { size, divisions } => {
            MeshData::plane(p("size", *size)?, divisions.unwrap_or(1).clamp(1, 1024))
        }
        MeshSpec::Sphere { radius, slices, stacks } => {
            MeshData::uv_sphere(p("radius", *radius)?, seg(*slices, 32), stacks.unwrap_or(16).clamp(2, 1024))
        }
        MeshSpec::Icosphere { radius, subdivisions } => {
            MeshData::icosphere(p("radius", *radius)?, subdivisions.unwrap_or(2).min(5))
        }
        MeshSpec::Cube { size } => MeshData::cube(p("size", *size)? * 0.5),
        MeshSpec::Torus { major_radius, minor_radius, major_segments, minor_segments } => MeshData::torus(
            p("major_radius", *major_radius)?,
            p("minor_radius", *minor_radius)?,
            seg(*major_segments, 48),
            seg(*minor_segments, 16),
        ),
        MeshSpec::Cloth { size_x, size_z, nx, nz, folds, fold_height } => {
            let fh = fold_height.unwrap_or(0.0);
            let fo = folds.unwrap_or(0.0);
            if !fh.is_finite() || !fo.is_finite() {
                return Err(ctx.err_at(span, format!("{what}: folds and fold_height must be finite")));
            }
            MeshData::cloth(
                p("size_x", *size_x)?,
                p("size_z", *size_z)?,
                nx.unwrap_or(32).clamp(1, 1024),
                nz.unwrap_or(32).clamp(1, 1024),
                fo,
                fh,
            )
        }
        MeshSpec::Hat { radius, height, segments, rings } => MeshData::hat_refined(
            p("radius", *radius)?,
            p("height", *height)?,
            seg(*segments, 32),
            rings.unwrap_or(1).clamp(1, 128),
        ),
        MeshSpec::Dish { radius, depth, segments, rings } => MeshData::dish(
            p("radius", *radius)?,
            p("depth", *depth)?,
            seg(*segments, 48),
            rings.unwrap_or(6).clamp(2, 256),
        ),
        MeshSpec::Chess { piece, scale, segments } => {
            let s = p("scale", *scale)?;
            let m = MeshData::chess_piece(piece, seg(*segments, 24)).ok_or_else(|| {
                ctx.err_at(
                    span.clone(),
                    format!("{what}: unknown chess piece '{piece}' (pawn, rook, bishop, queen, king)"),
                )
            })?;
            if s == 1.0 {
                m
            } else {
                m.transformed(Mat4::from_scale(Vec3::splat(s)))
            }
        }
    })
}

fn motion(ctx: &Ctx, span: std::ops::Range<usize>, what: &str, m: &MotionSpec) -> Result<RigidMotion, SceneError> {
    let bad = |msg: String| ctx.err_at(span.clone(), format!("{what}: motion: {msg}"));
    let fin = |v: Vec3, k: &str| if v.is_finite() { Ok(v) } else { Err(bad(format!("{k} is NaN or infinite"))) };
    let finf = |v: f32, k: &str| if v.is_finite() { Ok(v) } else { Err(bad(format!("{k} is NaN or infinite"))) };
    Ok(match m {
        MotionSpec::Static => RigidMotion::Static,
        MotionSpec::Keyframes { keys, looping, step } => {
            if keys.is_empty() {
                return Err(bad("keyframes need at least one key".into()));
            }
            let times: Vec<f32> = keys.iter().map(|k| k.t).collect();
            let interp = if *step { Interp::Step } else { Interp::Linear };
            fn all_or_none<T>(v: Vec<Option<T>>) -> Result<Option<Vec<T>>, ()> {
                if v.iter().all(|x| x.is_some()) {
                    Ok(Some(v.into_iter().flatten().collect()))
                } else if v.iter().all(|x| x.is_none()) {
                    Ok(None)
                } else {
                    Err(())
                }
            }
            let need = |k: &str| bad(format!("give `{k}` in every key or in none"));
            let pos =
                all_or_none(keys.iter().map(|k| k.position.map(|v| v.0)).collect()).map_err(|_| need("position"))?;
            let rot = all_or_none(keys.iter().map(|k| k.rotation_deg.map(|v| v.0)).collect())
                .map_err(|_| need("rotation_deg"))?;
            let sc = all_or_none(keys.iter().map(|k| k.scale.map(|v| v.0)).collect()).map_err(|_| need("scale"))?;
            for v in pos.iter().chain(rot.iter()).chain(sc.iter()).flatten() {
                fin(*v, "a key value")?;
            }
            let tr = pos.map(|v| Track::new(times.clone(), v, interp, *looping)).transpose().map_err(bad)?;
            let ro = rot
                .map(|v| Track::new(times.clone(), v.into_iter().map(euler_deg).collect(), interp, *looping))
                .transpose()
                .map_err(bad)?;
            let sc = sc.map(|v| Track::new(times.clone(), v, interp, *looping)).transpose().map_err(bad)?;
            RigidMotion::Keyframes { translation: tr, rotation: ro, scale: sc }
        }
        MotionSpec::Spin { axis, speed_deg, center } => {
            let axis = fin(axis.0, "axis")?;
            if axis.length() < 1e-6 {
                return Err(bad("axis is zero".into()));
            }
            RigidMotion::Spin {
                axis: axis.normalize(),
                center: fin(center.map_or(Vec3::ZERO, |c| c.0), "center")?,
                speed: finf(*speed_deg, "speed_deg")?.to_radians(),
            }
        }
        MotionSpec::Roll { center, radius, ball_radius, period, phase_deg } => RigidMotion::Roll {
            center: fin(center.0, "center")?,
            radius: positive(ctx, &span, what, "radius", *radius)?,
            ball_radius: positive(ctx, &span, what, "ball_radius", *ball_radius)?,
            period: if period.is_finite() && *period != 0.0 {
                *period
            } else {
                return Err(bad("period must be finite and non-zero".into()));
            },
            phase: finf(*phase_deg, "phase_deg")?.to_radians(),
        },
        MotionSpec::Fall { height, gravity, restitution, delay, axis, spin_deg } => {
            if !(*height >= 0.0 && height.is_finite()) {
                return Err(bad(format!("height must be >= 0, got {height}")));
            }
            if !(*restitution >= 0.0 && *restitution < 1.0) {
                return Err(bad(format!("restitution must be in [0, 1), got {restitution}")));
            }
            RigidMotion::Fall {
                height: *height,
                gravity: positive(ctx, &span, what, "gravity", *gravity)?,
                restitution: *restitution,
                delay: finf(*delay, "delay")?,
                axis: fin(axis.map_or(Vec3::X, |a| a.0), "axis")?.normalize_or(Vec3::X),
                spin: finf(*spin_deg, "spin_deg")?.to_radians(),
            }
        }
        MotionSpec::Oscillate { amplitude, period, phase_deg } => RigidMotion::Oscillate {
            amplitude: fin(amplitude.0, "amplitude")?,
            period: positive(ctx, &span, what, "period", *period)?,
            phase: finf(*phase_deg, "phase_deg")?.to_radians(),
        },
    })
}

fn deform(ctx: &Ctx, span: std::ops::Range<usize>, what: &str, d: &DeformSpec) -> Result<Deformation, SceneError> {
    Ok(match d {
        DeformSpec::Wave { amplitude, wavelength, period, direction, pinned } => {
            let dir = direction.map_or(Vec3::X, |v| v.0);
            if !amplitude.is_finite() || !dir.is_finite() || Vec3::new(dir.x, 0.0, dir.z).length() < 1e-6 {
                return Err(ctx.err_at(
                    span,
                    format!("{what}: wave: amplitude must be finite and direction a non-zero XZ vector"),
                ));
            }
            Deformation::Wave {
                amplitude: *amplitude,
                wavelength: positive(ctx, &span, what, "wavelength", *wavelength)?,
                period: positive(ctx, &span, what, "period", *period)?,
                direction: dir,
                pinned: *pinned,
            }
        }
        DeformSpec::Squash { amount, period } => {
            if !(*amount >= 0.0 && *amount < 0.9) {
                return Err(ctx.err_at(span, format!("{what}: squash: amount must be in [0, 0.9), got {amount}")));
            }
            Deformation::Squash { amount: *amount, period: positive(ctx, &span, what, "period", *period)? }
        }
    })
}

fn material(
    ctx: &Ctx,
    span: std::ops::Range<usize>,
    what: &str,
    name: &str,
    m: &MaterialSpec,
    textures: &mut Vec<Texture>,
    index: usize,
) -> Result<(Material, MaterialExtra, Option<MaterialAnimation>), SceneError> {
    let albedo = m.albedo.0;
    let specular = m.specular.map_or(Vec3::splat(0.04), |v| v.0);
    if !albedo.is_finite() || !specular.is_finite() || albedo.min_element() < 0.0 || specular.min_element() < 0.0 {
        return Err(ctx.err_at(span, format!("{what}: albedo and specular must be finite and >= 0")));
    }
    let check01 = |v: f32, k: &str| {
        if (0.0..=1.0).contains(&v) {
            Ok(v)
        } else {
            Err(ctx.err_at(span.clone(), format!("{what}: {k} must be in [0, 1], got {v}")))
        }
    };
    let mut mat = match m.kind {
        MaterialType::Diffuse => Material::diffuse(name, albedo),
        MaterialType::CookTorrance => {
            Material::glossy(name, albedo, specular, check01(m.roughness.unwrap_or(0.5), "roughness")?)
        }
        MaterialType::BlinnPhong | MaterialType::AshikhminShirley => {
            let s = match (m.shininess, m.roughness) {
                (Some(s), _) => s,
                (None, Some(r)) => 2.0 / (check01(r, "roughness")? * r).max(1e-4) - 2.0,
                (None, None) => 32.0,
            };
            if !(s >= 0.0 && s.is_finite()) {
                return Err(ctx.err_at(span, format!("{what}: shininess must be finite and >= 0, got {s}")));
            }
            let mut mm = Material::blinn_phong(name, albedo, specular, s);
            if matches!(m.kind, MaterialType::AshikhminShirley) {
                mm.kind = BrdfKind::AshikhminShirley;
            }
            mm
        }
    };
    if let Some(r) = m.roughness {
        mat.roughness = check01(r, "roughness")?;
    }
    let mut extra = MaterialExtra { two_sided: m.two_sided, ..Default::default() };
    if let Some(e) = m.emission {
        if !e.0.is_finite() || e.0.min_element() < 0.0 {
            return Err(ctx.err_at(span, format!("{what}: emission must be finite and >= 0")));
        }
        extra.emission = e.0;
    }
    if let Some(v) = m.shininess_v {
        if !matches!(m.kind, MaterialType::AshikhminShirley) {
            return Err(ctx.err_at(span, format!("{what}: shininess_v applies to ashikhmin_shirley only")));
        }
        if !(v >= 0.0 && v.is_finite()) {
            return Err(ctx.err_at(span, format!("{what}: shininess_v must be finite and >= 0")));
        }
        extra.shininess_v = Some(v);
    }
    for (spec, srgb, slot) in [(&m.albedo_map, true, 0), (&m.roughness_map, false, 1), (&m.normal_map, false, 2)] {
        let Some(t) = spec else { continue };
        let tex = match (&t.file, &t.pattern) {
            (Some(f), None) => {
                Texture::load_with(&ctx.resolve(f), srgb, ctx.budget).map_err(ctx.referenced(span.clone()))?
            }
            (None, Some(p)) => {
                let pat = match p.as_str() {
                    "checker" => Pattern::Checker,
                    "stripes" => Pattern::Stripes,
                    "noise" => Pattern::Noise,
                    _ => {
                        return Err(ctx.err_at(span, format!("{what}: unknown pattern '{p}' (checker, stripes, noise)")))
                    }
                };
                let a = t.a.map_or(Vec3::ONE, |v| v.0);
                let b = t.b.map_or(Vec3::splat(0.5), |v| v.0);
                if !a.is_finite() || !b.is_finite() || !t.scale.is_finite() || t.scale <= 0.0 {
                    return Err(
                        ctx.err_at(span, format!("{what}: pattern colours and scale must be finite (scale > 0)"))
                    );
                }
                Texture::pattern(
                    &format!("{name}.{}", ["albedo", "roughness", "normal"][slot]),
                    pat,
                    t.size,
                    t.scale,
                    a.extend(1.0),
                    b.extend(1.0),
                )
            }
            _ => {
                return Err(ctx.err_at(span, format!("{what}: a texture map needs exactly one of `file` or `pattern`")))
            }
        };
        textures.push(tex);
        match slot {
            0 => extra.albedo_map = Some(textures.len() - 1),
            1 => extra.roughness_map = Some(textures.len() - 1),
            _ => extra.normal_map = Some(textures.len() - 1),
        }
    }
    let _ = Vec4::ZERO;
    let anim = if m.keys.is_empty() {
        None
    } else {
        let times: Vec<f32> = m.keys.iter().map(|k| k.t).collect();
        let bad = |msg: String| ctx.err_at(span.clone(), format!("{what}: keys: {msg}"));
        let rough: Vec<Option<f32>> = m.keys.iter().map(|k| k.roughness).collect();
        let alb: Vec<Option<Vec3>> = m.keys.iter().map(|k| k.albedo.map(|v| v.0)).collect();
        let spec: Vec<Option<Vec3>> = m.keys.iter().map(|k| k.specular.map(|v| v.0)).collect();
        if rough.iter().flatten().any(|r| !(0.0..=1.0).contains(r)) {
            return Err(bad("roughness must be in [0, 1]".into()));
        }
        if alb.iter().chain(spec.iter()).flatten().any(|v| !v.is_finite() || v.min_element() < 0.0) {
            return Err(bad("colours must be finite and >= 0".into()));
        }
        Some(MaterialAnimation {
            material: index,
            roughness: keyed_track(rough, &times, m.looping, "roughness").map_err(bad)?,
            albedo: keyed_track(alb, &times, m.looping, "albedo").map_err(bad)?,
            specular: keyed_track(spec, &times, m.looping, "specular").map_err(bad)?,
        })
    };
    Ok((mat, extra, anim))
}

/// A linear track of one keyed value (`k`) of `[[...keys]]`: `None` when no key gives it, an error
/// when only some do.
fn keyed_track<T: crate::motion::Lerp>(
    v: Vec<Option<T>>,
    times: &[f32],
    looping: bool,
    k: &str,
) -> Result<Option<Track<T>>, String> {
    if v.iter().all(|x| x.is_none()) {
        return Ok(None);
    }
    if v.iter().any(|x| x.is_none()) {
        return Err(format!("give `{k}` in every key or in none"));
    }
    Track::new(times.to_vec(), v.into_iter().flatten().collect(), Interp::Linear, looping).map(Some)
}

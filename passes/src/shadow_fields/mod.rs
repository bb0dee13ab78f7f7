//! Technique `shadow-fields`: adaptive precomputed shadow fields (Tamura et al., after Zhou et
//! al. 2005) for rigid objects under environment lighting and local lights.
//!
//! * Precompute ([`SceneFields::build`]): one object occlusion field (OOF) per mesh
//!   (`penumbra_math::shadow_field`), fixed and adaptive, cached as one file per object and
//!   variant (`<cache>/<hash>-{fixed,adaptive}.psf`), and one source radiance field (SRF) per
//!   local light (same shells, adaptivity with a threshold relative to each shell's radiance,
//!   and 8-bit quantization; analytic, so not cached).
//! * CPU path ([`cpu_shade_points`]): per vertex, Fig. 3 of the paper: the self-occlusion
//!   transfer rotated to world, the other objects and the lights sorted by distance, triple
//!   products with each occluder's interpolated, dequantized, rotated visibility, double
//!   products with each light's radiance field and finally with the environment's order-4 SH.
//! * GPU: the same per point in `glsl/shadow_fields/sf_points.comp` ([`ShadowFieldsTechnique::add_points`]).
//!   The technique's image ([`SfMode`]): `vertex` computes the visible vertices (culled on the
//!   CPU: front-facing triangles inside the view, paper 5.3) in `sf_points.comp`, interpolates
//!   them across the triangles in a raster pass (`sf_vertex.vert/.frag`), and `sf_shade.comp`
//!   multiplies the albedo; `pixel` evaluates the same per G-buffer pixel with the clamped-cosine
//!   transfer of its normal (no self-occlusion). Glossy materials add the prefiltered
//!   environment along the reflection and the local lights' specular lobe, each shadowed by the
//!   occluders' visibility in that direction.
//! * `light_shadows = traced` (default; a departure from the paper, stated): the local lights
//!   are shaded pointwise with their shadows traced through the frame's kd-tree, and the
//!   environment's key lights ([`SfOptions::key_lights`]) are split off its SH and shaded the
//!   same way, the glossy lobe's visibility then traced too; the fields carry the rest of the
//!   environment (`light_shadows = fields`, `key_lights = 0`: the paper's path).
//!
//! Registered as `shadow-fields` (adaptive) and `shadow-fields-fixed` (every shell at the
//! initial resolution) so `penumbra bench --techniques shadow-fields,shadow-fields-fixed`
//! measures both against the reference in one run. Parameters (`[technique_params]`,
//! `--param`): see [`SfOptions::set`].

pub mod bench;
pub mod wavelet;

use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{anyhow, Result};
use glam::{DMat4, DVec3, Mat3, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, BufferHandle, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_math::sh::TripleProductTensor;
use penumbra_math::shadow_field::{
    self as sf, InstanceFrame, LightFrame, LightSource, ObjectField, Params, ShadeOptions, ShadePoint, Window, NCOEF,
    ROT_FLOATS,
};
use penumbra_scene::{Environment, EnvironmentState, Frame, LightKind, Scene};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::sync::Arc;

/// How the technique's image gets its diffuse radiance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SfMode {
    /// Per visible vertex (the paper), interpolated across triangles; self-occlusion included.
    Vertex,
    /// Per G-buffer pixel with the clamped-cosine transfer of the pixel's normal.
    Pixel,
}

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
    /// Diffuse shading per vertex or per pixel.
    pub mode: SfMode,
    /// Window of the occluders' visibility before the triple products.
    pub window: Window,
    /// Local lights through their source radiance fields (else pointwise, shadowed by the
    /// occluders' visibility toward the light).
    pub srf: bool,
    /// Local lights' shadows by shadow rays through the frame's kd-tree (`light_shadows =
    /// traced`, default; the lights are then shaded pointwise, `srf` aside), or from the
    /// fields (`fields`: the paper's, order-4 visibility toward the light, which blurs a spot
    /// light's hard shadow into a smudge: vol_rotating's cube).
    pub light_traced: bool,
    /// With `light_shadows = traced`: the environment's compact bright lights (a studio's key
    /// and fill lights, a sun: texels over 100 x the median, whole) split off as at most this
    /// many moment-matched lobes (`penumbra_math::envmap::split_lights`), each shaded as a light
    /// of that extent whose shadow is traced (9 rays through the kd-tree across the lobe), the
    /// rest of the environment through the fields as before. Order-4 SH cannot hold the shadow
    /// of a light of a few degrees carrying 95 % of a floor's light (studio.exr); 0 keeps the
    /// whole environment in the fields (the paper's).
    pub key_lights: usize,
    /// The environment's glossy term (`glossy`): `reflection` (default) the material model's
    /// glossy environment term times the occluders' visibility along the reflection (traced
    /// across the key lights' lobes); `transfer` the paper's: the specular lobe (times the
    /// cosine) projected into the order-4 SH basis as a transfer vector that the occluders'
    /// visibilities multiply by triple products and the environment's SH closes by a double
    /// product, times the lobe's directional albedo; the key lights' share through their own
    /// rays as before. Band-limited to l <= 3: a sharp lobe reflects a blurred environment.
    pub glossy_transfer: bool,
}

impl Default for SfOptions {
    fn default() -> Self {
        SfOptions {
            params: Params { shells: 32, resolution: 32, map_res: 32, threshold: 0.010, min_resolution: 1 },
            adaptive: true,
            cache_dir: Some(std::env::temp_dir().join("penumbra-shadow-fields")),
            progress: false,
            mode: SfMode::Pixel,
            window: Window::None,
            srf: true,
            light_traced: true,
            key_lights: 4,
            glossy_transfer: false,
        }
    }
}

impl SfOptions {
    /// Options from `[technique_params]` / `--param` (see [`SfOptions::set`]).
    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> Result<Self> {
        crate::technique::settings_from_params(params, Self::set)
    }

    /// Sets one parameter. Keys: `shells` (C, default 32, 1..=256), `resolution` (initial R,
    /// 32, power of two 1..=256), `map_res` (occlusion map rows, 32, 2..=256), `threshold`
    /// (eq. 1, 0.010, >= 0), `mode` (`pixel` | `vertex`), `window` (`none` | `hanning` |
    /// `lanczos`), `srf` (local lights through source radiance fields: true/false or 1/0),
    /// `light_shadows` (`traced` | `fields`), `key_lights` (0..=16), `glossy` (`reflection` |
    /// `transfer`, [`SfOptions::glossy_transfer`]). Unknown keys and bad values are errors.
    pub fn set(&mut self, key: &str, value: &str) -> Result<()> {
        let p = crate::technique::Param::new("shadow-fields", key, value);
        if set_light_option(&mut self.light_traced, &mut self.key_lights, &p)? {
            return Ok(());
        }
        match p.key() {
            "shells" => self.params.shells = p.int(1, 256)? as usize,
            "resolution" => self.params.resolution = p.pow2(1, 256)? as usize,
            "map_res" => self.params.map_res = p.int(2, 256)? as usize,
            "threshold" => self.params.threshold = p.number(|x| x >= 0.0, "a finite number >= 0")?,
            "mode" => self.mode = p.choice(&[("pixel", SfMode::Pixel), ("vertex", SfMode::Vertex)])?,
            "window" => self.window = Window::parse(p.text()).ok_or_else(|| p.bad("none, hanning or lanczos"))?,
            "srf" => self.srf = p.flag()?,
            "glossy" => self.glossy_transfer = p.choice(&[("reflection", false), ("transfer", true)])?,
            _ => {
                return Err(p.unknown(
                    "shells, resolution, map_res, threshold, mode, window, srf, light_shadows, key_lights, glossy",
                ))
            }
        }
        Ok(())
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
    /// An identical earlier mesh whose field this one shares (stored and uploaded once; not
    /// counted again in the totals).
    pub shared_with: Option<usize>,
}

/// Fixed and adaptive fields of every mesh and every local light of a scene.
pub struct SceneFields {
    /// Per mesh: (fixed, adaptive) occlusion fields.
    pub fields: Vec<(Arc<ObjectField>, Arc<ObjectField>)>,
    pub reports: Vec<FieldReport>,
    /// Per scene light: (fixed, adaptive) source radiance fields (unit power, light frame).
    pub lights: Vec<(Arc<ObjectField>, Arc<ObjectField>)>,
    /// Per scene light: what it is.
    pub light_sources: Vec<LightSource>,
    /// Per scene light: sizes and per-shell resolutions (`mesh` is the light's name).
    pub light_reports: Vec<FieldReport>,
    /// Per scene light with a fixture (`Light::fixture`): the fixture's object index and the
    /// light's frame in the fixture's frame (the light frame at time t is the fixture
    /// instance's world matrix times it). Its source radiance field holds the fixture's
    /// occlusion.
    pub light_fixtures: Vec<Option<(usize, DMat4)>>,
    pub options: SfOptions,
}

/// The frame of light `l` at rest (its declared position, `+z` along its declared direction)
/// in the frame of its fixture, object `f` (`None` if `f` is out of range or the result is
/// not finite): with it the fixture is sampled in the light's frame at precomputation and the
/// light's frame follows the fixture's motion when rendering.
pub fn fixture_light_frame(scene: &Scene, l: &penumbra_scene::Light, f: usize) -> Option<DMat4> {
    if f >= scene.objects.len() {
        return None;
    }
    let light_rest =
        DMat4::from_rotation_translation(sf::light_rotation(l.direction.as_dvec3()), l.position.as_dvec3());
    // the object's base transform: its world at t = 0 without its motion at t = 0
    let m0 = l.motion.eval(0.0).as_dmat4();
    let base = m0.inverse() * scene.world_at(f, 0.0).as_dmat4();
    let light_in_fixture = base.inverse() * light_rest;
    light_in_fixture.is_finite().then_some(light_in_fixture)
}

/// The [`LightSource`] of a scene light kind (cone angles as the reference renderer).
pub fn light_source(kind: &LightKind) -> LightSource {
    match *kind {
        LightKind::Point => LightSource::Point,
        LightKind::Spot { inner_deg, outer_deg } => LightSource::Spot {
            cos_inner: (inner_deg.clamp(0.0, 180.0) as f64).to_radians().cos(),
            cos_outer: (outer_deg.clamp(0.0, 180.0) as f64).to_radians().cos(),
        },
        LightKind::Sphere { radius } => LightSource::Sphere { radius: radius.max(0.0) as f64 },
        // no source radiance field: its field instances emit nothing (`instances`,
        // `light_frames`) and the shaders shade it pointwise
        LightKind::Directional => LightSource::Point,
    }
}

/// Outermost shell radius of light `li`'s source radiance field: twice the largest distance
/// from the light (at t = 0) to a corner of the world bounds of the objects at t = 0 (at
/// least 1). Beyond it the light is evaluated analytically (exact for point and spot lights).
pub fn srf_reach(scene: &Scene, li: usize) -> f64 {
    let frame = scene.at(0.0, None);
    let Some(l) = frame.lights.get(li) else { return 1.0 };
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for inst in &frame.instances {
        if let Some((a, b)) = scene.meshes.get(inst.mesh).and_then(|m| m.bounds()) {
            for k in 0..8 {
                let c = Vec3::new(
                    if k & 1 == 0 { a.x } else { b.x },
                    if k & 2 == 0 { a.y } else { b.y },
                    if k & 4 == 0 { a.z } else { b.z },
                );
                let w = inst.world.transform_point3(c);
                lo = lo.min(w);
                hi = hi.max(w);
            }
        }
    }
    let mut d = 0.0f64;
    if lo.is_finite() && hi.is_finite() {
        for k in 0..8 {
            let c = Vec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            d = d.max((c - l.position).length() as f64);
        }
    }
    if d.is_finite() {
        (2.0 * d).max(1.0)
    } else {
        1.0
    }
}

/// Writes one precomputed file of a cache directory (created if missing): beside, then renamed,
/// so that a reader (another process sharing the cache) never sees half a file. The cache is an
/// optimisation: failing to write it is not an error.
pub(crate) fn write_cache_file(path: &std::path::Path, bytes: &[u8]) {
    if let Some(dir) = path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    if std::fs::write(&tmp, bytes).is_ok() && std::fs::rename(&tmp, path).is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
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
        let mut fields: Vec<(Arc<ObjectField>, Arc<ObjectField>)> = Vec::new();
        let mut reports: Vec<FieldReport> = Vec::new();
        let mut by_key: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            let key = cache_key(m, &options.params);
            if let Some(&first) = by_key.get(&key) {
                // identical geometry (e.g. the ten pins of a bowling scene): one field
                let f: (Arc<ObjectField>, Arc<ObjectField>) = fields[first].clone();
                reports.push(FieldReport {
                    mesh: m.name.clone(),
                    shared_with: Some(first),
                    cached: true,
                    seconds: 0.0,
                    rays: 0,
                    ..reports[first].clone()
                });
                fields.push(f);
                continue;
            }
            by_key.insert(key.clone(), mi);
            let paths = options
                .cache_dir
                .as_ref()
                .map(|d| (d.join(format!("{key}-fixed.psf")), d.join(format!("{key}-adaptive.psf"))));
            let loaded = paths.as_ref().and_then(|(f, a)| {
                let f = ObjectField::from_bytes(&std::fs::read(f).ok()?).ok()?;
                let a = ObjectField::from_bytes(&std::fs::read(a).ok()?).ok()?;
                (f.self_transfer.len() == m.positions.len() && a.self_transfer.len() == m.positions.len())
                    .then_some((f, a))
            });
            let (fixed, adaptive, seconds, rays, cached) = match loaded {
                Some((f, a)) => (f, a, 0.0, 0, true),
                None => {
                    let total = (options.params.shells * options.params.resolution.next_power_of_two().pow(2)
                        + m.positions.len()) as u64;
                    let done = std::sync::atomic::AtomicU64::new(0);
                    let name = m.name.clone();
                    let show = options.progress;
                    let progress = move |n: u64| {
                        let d = done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n;
                        if show && (d.is_multiple_of((total / 20).max(1)) || d == total) {
                            tracing::info!("shadow field '{name}': {:.0}%", 100.0 * d as f64 / total as f64);
                        }
                    };
                    let raw = sf::precompute(&m.positions, &m.normals, &m.indices, &options.params, &progress)
                        .map_err(|e| anyhow!("mesh {mi} '{}': {e}", m.name))?;
                    let f = raw.to_fixed();
                    let a = raw.to_adaptive(options.params.threshold, options.params.min_resolution);
                    if let Some((pf, pa)) = &paths {
                        write_cache_file(pf, &f.to_bytes());
                        write_cache_file(pa, &a.to_bytes());
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
                shared_with: None,
            });
            fields.push((Arc::new(fixed), Arc::new(adaptive)));
        }
        let mut lights = Vec::new();
        let mut light_sources = Vec::new();
        let mut light_reports = Vec::new();
        let mut light_fixtures = Vec::new();
        for (li, l) in scene.lights.iter().enumerate() {
            let src = light_source(&l.kind);
            let reach = srf_reach(scene, li);
            let fixture = l.fixture.and_then(|f| Some((f, fixture_light_frame(scene, l, f)?)));
            let caster = fixture.map(|(f, light_in_fixture)| {
                let mesh = &scene.meshes[scene.objects[f].mesh];
                let to_light = light_in_fixture.inverse();
                let pos: Vec<Vec3> =
                    mesh.positions.iter().map(|p| to_light.transform_point3(p.as_dvec3()).as_vec3()).collect();
                (sf::RayCaster::new(&pos, &mesh.indices), mesh.indices.len() / 3, f)
            });
            let raw = sf::precompute_srf_through(src, caster.as_ref().map(|c| &c.0), reach, &options.params, &|_| {})
                .map_err(|e| anyhow!("light {li} '{}': {e}", l.name))?;
            let f = raw.to_fixed();
            let a = raw.to_adaptive_relative(options.params.threshold, options.params.min_resolution);
            light_reports.push(FieldReport {
                mesh: match &caster {
                    Some((_, _, f)) => format!("light '{}' in '{}'", l.name, scene.objects[*f].name),
                    None => format!("light '{}'", l.name),
                },
                vertices: 0,
                triangles: caster.as_ref().map_or(0, |c| c.1),
                fixed_bytes: f.data_bytes(),
                adaptive_bytes: a.data_bytes(),
                fixed_file_bytes: f.file_bytes(),
                adaptive_file_bytes: a.file_bytes(),
                resolutions: a.resolutions(),
                seconds: raw.seconds,
                rays: raw.rays,
                cached: false,
                shared_with: None,
            });
            lights.push((Arc::new(f), Arc::new(a)));
            light_sources.push(src);
            light_fixtures.push(fixture);
        }
        Ok(SceneFields {
            fields,
            reports,
            lights,
            light_sources,
            light_reports,
            light_fixtures,
            options: options.clone(),
        })
    }

    /// The source radiance field of light `li` (adaptive or fixed).
    pub fn light_field(&self, li: usize, adaptive: bool) -> Option<&ObjectField> {
        self.lights.get(li).map(|(f, a)| if adaptive { a.as_ref() } else { f.as_ref() })
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
pub fn precompute_files(
    scene: &Scene,
    options: &SfOptions,
    out: &std::path::Path,
) -> Result<(Vec<FieldReport>, Vec<PathBuf>)> {
    let fields = SceneFields::build(scene, options)?;
    std::fs::create_dir_all(out).map_err(|e| anyhow!("{}: {e}", out.display()))?;
    let mut paths = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for (mi, ((f, a), m)) in fields.fields.iter().zip(&scene.meshes).enumerate() {
        let mut name: String =
            m.name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
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

/// The light options both shadow-field variants take, `light_shadows` (`traced` | `fields`)
/// into `light_traced` and `key_lights` (0..=16): whether `key` was one of them (a bad value is
/// `bad`'s error).
pub(crate) fn set_light_option(
    light_traced: &mut bool,
    key_lights: &mut usize,
    p: &crate::technique::Param,
) -> Result<bool> {
    match p.key() {
        "light_shadows" => *light_traced = p.choice(&[("traced", true), ("fields", false)])?,
        "key_lights" => *key_lights = p.int(0, 16)? as usize,
        _ => return Ok(false),
    }
    Ok(true)
}

/// Order-4 SH (rgb) of the environment radiance in world space (its loaded intensity and
/// rotation applied); zero without an environment.
pub fn env_light_sh(env: Option<&Environment>) -> [[f64; 3]; NCOEF] {
    env_light_sh_at(env, env.map_or(EnvironmentState::NONE, Environment::state))
}

/// [`env_light_sh`] at `state` (the map turned by its rotation about +Y, scaled by its
/// intensity).
pub fn env_light_sh_at(env: Option<&Environment>, state: EnvironmentState) -> [[f64; 3]; NCOEF] {
    let mut out = [[0.0; 3]; NCOEF];
    let Some(env) = env else { return out };
    let (w, h) = (env.width as usize, env.height as usize);
    if w == 0 || h == 0 || env.texels.len() < w * h {
        return out;
    }
    let stride = (w / 256).max(1);
    let rot = Mat3::from_rotation_y(state.rotation);
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
            let wgt = wgt_row * cols as f64 * dphi * state.intensity as f64;
            for e in 0..NCOEF {
                for c in 0..3 {
                    out[e][c] += wgt * t[c] as f64 * y[e];
                }
            }
        }
    }
    out
}

/// `sh` (rgb, the map's frame at intensity 1: [`env_light_sh_at`] at rotation 0, intensity 1)
/// turned by `state`'s rotation about +Y (an exact SH rotation) and scaled by its intensity.
pub fn sh_at(sh: &[[f64; 3]; NCOEF], state: EnvironmentState) -> [[f64; 3]; NCOEF] {
    let r = penumbra_math::sh::ShRotation::new(sf::ORDER, glam::DMat3::from_rotation_y(state.rotation as f64));
    let mut out = [[0.0; 3]; NCOEF];
    for c in 0..3 {
        let turned = r.apply(&sh.iter().map(|v| v[c]).collect::<Vec<f64>>());
        for (o, t) in out.iter_mut().zip(turned) {
            o[c] = t * state.intensity as f64;
        }
    }
    out
}

fn sf_basis(d: DVec3, y: &mut [f64; NCOEF]) {
    penumbra_math::sh::eval_basis_into(sf::ORDER, d, y);
}

/// Per object: whether it casts shadows.
pub fn casts_flags(scene: &Scene) -> Vec<bool> {
    (0..scene.objects.len()).map(|i| scene.object_info.get(i).is_none_or(|o| o.casts_shadow)).collect()
}

/// Per-frame instance setup for the CPU path. With `srf` a light's fixture sorts just after
/// its light ([`fixture_sort_keys`]).
pub fn instance_frames<'a>(
    scene: &Scene,
    frame: &Frame,
    fields: &'a SceneFields,
    adaptive: bool,
    srf: bool,
) -> Vec<InstanceFrame<'a>> {
    let mut out: Vec<InstanceFrame<'a>> = frame
        .instances
        .iter()
        .map(|inst| {
            let casts = scene.object_info.get(inst.object).is_none_or(|i| i.casts_shadow);
            let field = if casts { fields.field(inst.mesh, adaptive) } else { None };
            InstanceFrame::new(field, inst.world.as_dmat4())
        })
        .collect();
    if srf {
        for (k, pos) in fixture_sort_keys(frame, fields) {
            if let Some(f) = out.get_mut(k) {
                f.center_world = pos;
                f.sort_bias = sf::FIXTURE_SORT_BIAS;
            }
        }
    }
    out
}

/// Instance index and sort position of every light fixture of the frame: its light's world
/// position, so that with [`sf::FIXTURE_SORT_BIAS`] it comes just after its light among a
/// point's entities (the light's source radiance field holds the fixture's occlusion already;
/// lights further away are shadowed by it).
pub fn fixture_sort_keys(frame: &Frame, fields: &SceneFields) -> Vec<(usize, DVec3)> {
    frame
        .lights
        .iter()
        .filter_map(|l| {
            let (k, _) = fixture_world(frame, &fields.light_fixtures, l)?;
            l.position.is_finite().then(|| (k, l.position.as_dvec3()))
        })
        .collect()
}

/// Frame light `l` as the CPU and GPU paths shade it, with `field` (or none: analytic): zero
/// power where the reference cannot emit from it ([`field_emits`]), its frame following its
/// fixture if it has one ([`fixture_world`]); and that fixture's instance index.
fn light_frame<'a>(
    frame: &Frame,
    fixtures: &[Option<(usize, DMat4)>],
    l: &penumbra_scene::LightInstance,
    src: LightSource,
    field: Option<&'a ObjectField>,
) -> (LightFrame<'a>, Option<usize>) {
    let power = if field_emits(l) { l.power.max(Vec3::ZERO).as_dvec3() } else { DVec3::ZERO };
    let pos = if l.position.is_finite() { l.position.as_dvec3() } else { DVec3::ZERO };
    match fixture_world(frame, fixtures, l) {
        Some((k, w)) => (LightFrame::with_world(field, src, w, power), Some(k)),
        None => (LightFrame::new(field, src, pos, l.direction.as_dvec3(), power), None),
    }
}

/// For frame light `l` with a fixture ([`SceneFields::light_fixtures`]): the fixture's
/// instance index and the light's frame (light to world): the fixture instance's world matrix
/// times the light's frame in the fixture's frame.
fn fixture_world(
    frame: &Frame,
    fixtures: &[Option<(usize, DMat4)>],
    l: &penumbra_scene::LightInstance,
) -> Option<(usize, DMat4)> {
    let (f, light_in_fixture) = fixtures.get(l.light).copied().flatten()?;
    let k = frame.instances.iter().position(|i| i.object == f)?;
    let w = frame.instances[k].world.as_dmat4() * light_in_fixture;
    w.is_finite().then_some((k, w))
}

/// Whether light `l` emits through its source-radiance-field instance: the reference can emit
/// from it (finite power and position, a spot's direction non-zero), and it is not directional
/// (no source radiance field: the shaders shade it pointwise, its instance emits nothing).
fn field_emits(l: &penumbra_scene::LightInstance) -> bool {
    l.power.is_finite()
        && l.position.is_finite()
        && l.kind != LightKind::Directional
        && (!matches!(l.kind, LightKind::Spot { .. }) || l.direction.is_finite() && l.direction.length_squared() > 0.0)
}

/// Per-frame light setup for the CPU path: every light of the frame with its source radiance
/// field (`srf`) or analytic everywhere (`!srf`). Lights the reference cannot emit from (zero or
/// non-finite power or position, zero spot direction) get zero power.
pub fn light_frames<'a>(frame: &Frame, fields: &'a SceneFields, adaptive: bool, srf: bool) -> Vec<LightFrame<'a>> {
    frame
        .lights
        .iter()
        .map(|l| {
            let src = fields.light_sources.get(l.light).copied().unwrap_or_else(|| light_source(&l.kind));
            let field = if srf { fields.light_field(l.light, adaptive) } else { None };
            light_frame(frame, &fields.light_fixtures, l, src, field).0
        })
        .collect()
}

/// A point for the GPU (std430 `SfPoint` of `glsl/shadow_fields/sf_points.comp`, 112 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct GpuPoint {
    pub pos: [f32; 4],
    pub albedo: [f32; 4],
    /// x receiver instance, y output slot.
    pub ids: [u32; 4],
    pub t: [f32; NCOEF],
}

/// The points of a frame: every vertex of every instance (world position, self-transfer),
/// optionally culled (`cull = Some(aspect)`) as the paper does on the CPU (5.3): only the
/// vertices of triangles facing the eye (oriented by their vertex normals) and not entirely
/// outside one plane of the view frustum (5% margin) are kept.
pub fn vertex_points(scene: &Scene, frame: &Frame, fields: &SceneFields, cull: Option<f32>) -> Vec<ShadePoint> {
    visible_vertices(scene, frame, fields, cull).0
}

/// [`vertex_points`] and each point's slot in the frame's per-vertex array (instances in
/// order, each with its mesh's vertex count), the first slot of each instance, and the slot
/// count.
pub fn visible_vertices(
    scene: &Scene,
    frame: &Frame,
    fields: &SceneFields,
    cull: Option<f32>,
) -> (Vec<ShadePoint>, Vec<u32>, Vec<u32>, u32) {
    let aspect = cull.filter(|a| a.is_finite() && *a > 0.0).unwrap_or(1.0);
    let cull = cull.is_some();
    let vp = frame.camera.proj(aspect) * frame.camera.view();
    let eye = frame.camera.eye;
    let mut out = Vec::new();
    let mut slots = Vec::new();
    let mut bases = Vec::with_capacity(frame.instances.len());
    let mut base = 0u32;
    for (ii, inst) in frame.instances.iter().enumerate() {
        bases.push(base);
        let Some(mesh) = scene.meshes.get(inst.mesh) else { continue };
        let nv = mesh.positions.len();
        let this_base = base;
        base += nv as u32;
        let Some((_, field)) = fields.fields.get(inst.mesh) else { continue };
        let albedo = frame
            .materials
            .get(inst.material)
            .or(scene.materials.get(inst.material))
            .map_or(Vec3::splat(0.5), |m| m.albedo);
        let world: Vec<Vec3> = mesh.positions.iter().map(|p| inst.world.transform_point3(*p)).collect();
        let keep = if cull {
            let nm = Mat3::from_mat4(inst.world).inverse().transpose();
            let clip: Vec<glam::Vec4> = world.iter().map(|w| vp * w.extend(1.0)).collect();
            // outside codes: bit k set when beyond plane k (x-, x+, y-, y+, near)
            let code = |c: &glam::Vec4| -> u32 {
                let m = 1.05 * c.w;
                ((c.x < -m) as u32)
                    | ((c.x > m) as u32) << 1
                    | ((c.y < -m) as u32) << 2
                    | ((c.y > m) as u32) << 3
                    | ((c.w <= 0.0) as u32) << 4
            };
            let codes: Vec<u32> = clip.iter().map(code).collect();
            let mut keep = vec![false; nv];
            for t in mesh.indices.chunks_exact(3) {
                let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
                if a >= nv || b >= nv || c >= nv || codes[a] & codes[b] & codes[c] != 0 {
                    continue;
                }
                let mut fnrm = (world[b] - world[a]).cross(world[c] - world[a]);
                let vn: Vec3 = [a, b, c].iter().map(|&k| nm * mesh.normals.get(k).copied().unwrap_or(Vec3::ZERO)).sum();
                if fnrm.dot(vn) < 0.0 {
                    fnrm = -fnrm;
                }
                let centroid = (world[a] + world[b] + world[c]) / 3.0;
                let to_eye = eye - centroid;
                // front facing, with a tolerance for edge-on triangles
                if fnrm.dot(to_eye) >= -1e-4 * fnrm.length() * to_eye.length() {
                    keep[a] = true;
                    keep[b] = true;
                    keep[c] = true;
                }
            }
            keep
        } else {
            vec![true; nv]
        };
        for (vi, wp) in world.iter().enumerate() {
            if !keep[vi] {
                continue;
            }
            let t = field.self_transfer.get(vi).copied().unwrap_or([0.0; NCOEF]);
            out.push(ShadePoint {
                pos: wp.as_dvec3(),
                inst: ii,
                albedo: albedo.as_dvec3(),
                transfer: t.map(|x| x as f64),
            });
            slots.push(this_base + vi as u32);
        }
    }
    (out, slots, bases, base)
}

/// The CPU rendering path: radiance per point and its unclamped minimum channel (occluders,
/// local lights and the environment `light`, Fig. 3).
pub fn cpu_shade_points(
    points: &[ShadePoint],
    insts: &[InstanceFrame],
    lights: &[LightFrame],
    light: &[[f64; 3]; NCOEF],
    tensor: &TripleProductTensor,
    window: Window,
) -> Vec<(DVec3, f64)> {
    sf::shade_points_with(points, insts, lights, light, tensor, &ShadeOptions { window })
}

/// std430 `SfShell`.
#[repr(C)]
#[derive(Clone, Copy)]
struct GpuShell {
    info: [u32; 4],
    min: [f32; NCOEF],
    step: [f32; NCOEF],
}

/// std430 `SfInst` (480 bytes).
#[repr(C)]
#[derive(Clone, Copy)]
struct GpuInst {
    world_to_local: [[f32; 4]; 4],
    center_step: [f32; 4],
    info: [u32; 4],
    center_world: [f32; 4],
    light_a: [f32; 4],
    light_b: [f32; 4],
    /// Lights: the medium's extinction sigma_t in xyz (zero without a medium).
    medium: [f32; 4],
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
    /// First shell index and shell count of each scene light's source radiance field.
    light_shells: Vec<(u32, u32)>,
    light_geom: Vec<(Vec3, f32)>,
    light_sources: Vec<LightSource>,
    /// [`SceneFields::light_fixtures`].
    light_fixtures: Vec<Option<(usize, DMat4)>>,
    /// The scene medium's extinction (zero without one): local light is attenuated by
    /// `exp(-sigma_t d)` on its way in, as the reference does.
    pub sigma_t: Vec3,
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
            if let Some(first) = fields.reports.get(mi).and_then(|r| r.shared_with) {
                // shared field: same shells, uploaded once
                mesh_shells.push(mesh_shells[first]);
                mesh_geom.push(mesh_geom[first]);
                continue;
            }
            mesh_shells.push((shells.len() as u32, f.shells.len() as u32));
            mesh_geom.push((f.center, f.shell_step() as f32));
            for s in &f.shells {
                shells.push(GpuShell { info: [(data.len() / 4) as u32, s.resolution, 0, 0], min: s.min, step: s.step });
                data.extend_from_slice(&s.data);
            }
        }
        let mut light_shells = Vec::new();
        let mut light_geom = Vec::new();
        for li in 0..fields.lights.len() {
            let f = fields.light_field(li, adaptive).expect("light index in range");
            light_shells.push((shells.len() as u32, f.shells.len() as u32));
            light_geom.push((f.center, f.shell_step() as f32));
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
        GpuTables {
            data,
            shells,
            mesh_shells,
            mesh_geom,
            light_shells,
            light_geom,
            light_sources: fields.light_sources.clone(),
            light_fixtures: fields.light_fixtures.clone(),
            sigma_t: Vec3::ZERO,
            tensor: bytes_of(&entries),
            tensor_count: entries.len() as u32,
        }
    }

    /// Per-instance records of a frame (rotation matrices computed once per instance), then
    /// one per light (its source radiance field when `srf`, else none: analytic radiance).
    fn instances(&self, casts: &[bool], frame: &Frame, srf: bool) -> Vec<GpuInst> {
        let mut out: Vec<GpuInst> = frame
            .instances
            .iter()
            .map(|inst| {
                let (first, count) = self.mesh_shells.get(inst.mesh).copied().unwrap_or((0, 0));
                let (c, step) = self.mesh_geom.get(inst.mesh).copied().unwrap_or((Vec3::ZERO, 1.0));
                let f = InstanceFrame::new(None, inst.world.as_dmat4());
                let casts = casts.get(inst.object).copied().unwrap_or(true);
                let cw = inst.world.transform_point3(c);
                GpuInst {
                    world_to_local: f.world_to_local.as_mat4().to_cols_array_2d(),
                    center_step: [c.x, c.y, c.z, step],
                    info: [first, count, casts as u32, 0],
                    center_world: [cw.x, cw.y, cw.z, 0.0],
                    light_a: [0.0; 4],
                    light_b: [0.0; 4],
                    medium: [0.0; 4],
                    rot: f.rot.map(|x| x as f32),
                }
            })
            .collect();
        for l in &frame.lights {
            let src = self.light_sources.get(l.light).copied().unwrap_or_else(|| light_source(&l.kind));
            let (lf, fixture) = light_frame(frame, &self.light_fixtures, l, src, None);
            let power = lf.power.as_vec3();
            let pos = if l.position.is_finite() { l.position } else { Vec3::ZERO };
            if let (Some(k), true) = (fixture, srf) {
                // the fixture sorts just after its light (shade_point's rule)
                out[k].center_world = [pos.x, pos.y, pos.z, sf::FIXTURE_SORT_BIAS as f32];
            }
            let (first, count) = if srf { self.light_shells.get(l.light).copied().unwrap_or((0, 0)) } else { (0, 0) };
            let (c, step) = self.light_geom.get(l.light).copied().unwrap_or((Vec3::ZERO, 1.0));
            let (kind, ci, co, rad) = match src {
                LightSource::Point => (0.0, 1.0, 1.0, 0.0),
                LightSource::Spot { cos_inner, cos_outer } => (1.0, cos_inner as f32, cos_outer as f32, 0.0),
                LightSource::Sphere { radius } => (2.0, 1.0, 1.0, radius as f32),
            };
            out.push(GpuInst {
                world_to_local: lf.world_to_local.as_mat4().to_cols_array_2d(),
                center_step: [c.x, c.y, c.z, step],
                info: [first, count, 1, if fixture.is_some() { 2 } else { 1 }],
                center_world: [pos.x, pos.y, pos.z, 0.0],
                light_a: [power.x, power.y, power.z, kind],
                light_b: [ci, co, rad, 0.0],
                medium: [self.sigma_t.x, self.sigma_t.y, self.sigma_t.z, 0.0],
                rot: lf.rot.map(|x| x as f32),
            });
        }
        out
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
    /// Object instances (the first records of `insts`), then `light_count` lights.
    pub inst_count: u32,
    pub light_count: u32,
    pub tensor_count: u32,
}

/// Uploads the tables, this frame's instances and lights, and the environment lighting
/// (host-initialised buffers).
pub fn upload(
    graph: &mut Graph,
    tables: &GpuTables,
    casts: &[bool],
    frame: &Frame,
    light: &[[f64; 3]; NCOEF],
    srf: bool,
) -> SfHandles {
    let insts = tables.instances(casts, frame, srf);
    let light4: Vec<[f32; 4]> = light.iter().map(|c| [c[0] as f32, c[1] as f32, c[2] as f32, 0.0]).collect();
    let mut data = tables.data.clone();
    data.resize(data.len().max(16), 0);
    let shells = if tables.shells.is_empty() {
        vec![GpuShell { info: [0; 4], min: [0.0; 16], step: [0.0; 16] }]
    } else {
        tables.shells.clone()
    };
    let inst_bytes = if insts.is_empty() { vec![0u8; std::mem::size_of::<GpuInst>()] } else { bytes_of(&insts) };
    SfHandles {
        data: graph.create_buffer_init("sf_data", data),
        shells: graph.create_buffer_init("sf_shells", bytes_of(&shells)),
        insts: graph.create_buffer_init("sf_insts", inst_bytes),
        tensor: graph.create_buffer_init("sf_tensor", tables.tensor.clone()),
        light: graph.create_buffer_init("sf_light", bytes_of(&light4)),
        inst_count: frame.instances.len() as u32,
        light_count: frame.lights.len() as u32,
        tensor_count: tables.tensor_count,
    }
}

/// The technique: the per-point pass (GPU rendering path), the per-vertex display raster pass
/// and the per-pixel shading pass.
pub struct ShadowFieldsTechnique {
    shade: Pipeline,
    points: Pipeline,
    vertex: Pipeline,
    nearest: Sampler,
    linear: Sampler,
    /// Material texture maps (repeat).
    repeat: Sampler,
    pub fields: Arc<SceneFields>,
    pub tables: GpuTables,
    pub light: [[f64; 3]; NCOEF],
    /// The environment's SH that the frames shade with: [`Self::light`] less the key lights
    /// when they are split off ([`SfOptions::key_lights`]), in the map's frame at intensity 1.
    shade_light_local: [[f64; 3]; NCOEF],
    /// The key lights, 2 per light: axis + lambda, RGB amplitude, in the map's frame at intensity
    /// 1 (`lighting::lobes_at` the frame's state).
    key: Vec<[f32; 4]>,
    pub tensor: TripleProductTensor,
    pub adaptive: bool,
    pub mode: SfMode,
    pub window: Window,
    pub srf: bool,
    /// The environment's glossy term through the SH transfer ([`SfOptions::glossy_transfer`]).
    pub glossy_transfer: bool,
    /// The frame's kd-tree for the local lights' shadow rays (`light_shadows = traced`, with
    /// local lights to shade): the lights are then shaded pointwise, not through their fields.
    kd: Option<crate::kdtree::KdTreeBuilder>,
    /// Per object: casts shadows (`ObjectInfo::casts_shadow`).
    pub casts: Vec<bool>,
    /// Per mesh: (first index, index count, vertex offset) in the scene's index/vertex buffers.
    mesh_ranges: Vec<(u32, u32, i32)>,
    scene: Arc<Scene>,
}

/// Format of the interpolated per-vertex radiance image.
pub const VERTEX_RADIANCE_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;

fn vertex_pipeline(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Pipeline> {
    use crate::raster::{raster_pipeline, DepthState, RasterDesc, VertexInput};
    raster_pipeline(
        ctx,
        shaders,
        &RasterDesc {
            name: "sf_vertex",
            shaders: &["shadow_fields/sf_vertex.vert", "shadow_fields/sf_vertex.frag"],
            vertex_input: VertexInput::Position,
            colors: &[VERTEX_RADIANCE_FORMAT],
            depth: Some(DepthState { format: crate::gbuffer::DEPTH_FORMAT, write: true, compare: vk::CompareOp::LESS }),
            ..Default::default()
        },
    )
}

impl ShadowFieldsTechnique {
    /// Precomputes (or loads) the fields of `scene` and builds the pipelines.
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, options: SfOptions) -> Result<Self> {
        let fields = Arc::new(SceneFields::build(scene, &options)?);
        let mut t = Self::with_fields(ctx, shaders, scene, fields, options.adaptive)?;
        t.mode = options.mode;
        t.window = options.window;
        t.srf = options.srf;
        t.glossy_transfer = options.glossy_transfer;
        Ok(t)
    }

    /// With fields built elsewhere (e.g. shared between the fixed and adaptive variants); mode,
    /// window, srf and glossy from the fields' options.
    pub fn with_fields(
        ctx: &Arc<Context>,
        shaders: &ShaderLibrary,
        scene: &Scene,
        fields: Arc<SceneFields>,
        adaptive: bool,
    ) -> Result<Self> {
        let shade = compute_pipeline(ctx, shaders, "shadow_fields/sf_shade.comp", 36)?;
        let points = compute_pipeline(ctx, shaders, "shadow_fields/sf_points.comp", 20)?;
        let vertex = vertex_pipeline(ctx, shaders)?;
        let tensor = TripleProductTensor::new(sf::ORDER);
        let mut tables = GpuTables::new(&fields, adaptive, &tensor);
        tables.sigma_t = scene.medium.map_or(Vec3::ZERO, |m| m.sigma_t().max(Vec3::ZERO));
        let mut mesh_ranges = Vec::new();
        let (mut first, mut offset) = (0u32, 0i32);
        for m in &scene.meshes {
            mesh_ranges.push((first, m.indices.len() as u32, offset));
            first += m.indices.len() as u32;
            offset += m.positions.len() as i32;
        }
        let o = fields.options.clone();
        let light = env_light_sh(scene.environment.as_ref());
        let traced = o.light_traced && (!scene.lights.is_empty() || o.key_lights > 0);
        let (sky, key) =
            crate::lighting::split_key_lights(scene.environment.as_ref(), if traced { o.key_lights } else { 0 })?;
        // the SH the frames shade with, in the map's frame at intensity 1 (each frame's is turned
        // and scaled to its environment's state)
        let unit = EnvironmentState { rotation: 0.0, intensity: 1.0 };
        let shade_light_local = env_light_sh_at(sky.as_ref().or(scene.environment.as_ref()), unit);
        Ok(ShadowFieldsTechnique {
            shade,
            points,
            vertex,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            tables,
            light,
            shade_light_local,
            tensor,
            adaptive,
            mode: o.mode,
            window: o.window,
            srf: o.srf,
            glossy_transfer: o.glossy_transfer,
            kd: if o.light_traced && (!scene.lights.is_empty() || !key.is_empty()) {
                Some(crate::kdtree::KdTreeBuilder::new(ctx, shaders)?)
            } else {
                None
            },
            key,
            casts: casts_flags(scene),
            mesh_ranges,
            scene: Arc::new(scene.clone()),
            fields,
        })
    }

    /// Whether the local lights go through their source radiance fields (`srf`, unless their
    /// shadows are traced).
    pub fn lights_through_fields(&self) -> bool {
        self.srf && self.kd.is_none()
    }

    fn window_code(&self) -> u32 {
        match self.window {
            Window::None => 0,
            Window::Hanning => 1,
            Window::Lanczos => 2,
        }
    }

    /// Adds the per-point pass (GPU rendering path): point `i` writes `vec4` (rgb radiance
    /// times its albedo clamped at 0, w the unclamped minimum channel) at `slots[i]` (`None`:
    /// at `i`) of the returned buffer of `out_len` entries, zero elsewhere; the local lights
    /// through their source radiance fields when `srf` (else none: shaded pointwise).
    pub fn add_points(
        &self,
        graph: &mut Graph,
        h: &SfHandles,
        points: &[ShadePoint],
        slots: Option<&[u32]>,
        out_len: u32,
        srf: bool,
    ) -> BufferHandle {
        let gp: Vec<GpuPoint> = points
            .iter()
            .enumerate()
            .map(|(i, p)| GpuPoint {
                pos: [p.pos.x as f32, p.pos.y as f32, p.pos.z as f32, 1.0],
                albedo: [p.albedo.x as f32, p.albedo.y as f32, p.albedo.z as f32, 1.0],
                ids: [
                    p.inst as u32,
                    slots.and_then(|s| s.get(i).copied()).unwrap_or(i as u32).min(out_len.saturating_sub(1)),
                    0,
                    0,
                ],
                t: p.transfer.map(|x| x as f32),
            })
            .collect();
        let n = gp.len() as u32;
        let pts = graph.create_buffer_init(
            "sf_points",
            if gp.is_empty() { vec![0u8; std::mem::size_of::<GpuPoint>()] } else { bytes_of(&gp) },
        );
        let out = graph.create_buffer_init("sf_point_radiance", vec![0u8; out_len.max(1) as usize * 16]);
        let mut p = graph.pass("sf_points", PassKind::Compute);
        let r =
            [h.data, h.shells, h.insts, h.tensor, h.light, pts].map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let out = p.write(out, Access::ComputeShaderWriteStorage);
        let pipe = self.points.handle();
        let n_light = if srf { h.light_count } else { 0 };
        let push = crate::util::bytes_of(&[n, h.inst_count, h.tensor_count, n_light, self.window_code()]);
        p.record(move |rc| {
            let mut binds: Vec<Bind> = r.iter().map(|&b| Bind::StorageBuffer(b)).collect();
            binds.push(Bind::StorageBuffer(out));
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(n, 64), 1, 1])
        });
        out
    }

    /// The per-vertex display (paper 5): the visible vertices' radiance (albedo 1) on the GPU,
    /// interpolated across the triangles by a raster pass into a `w x h` image.
    fn add_vertex_display(
        &self,
        graph: &mut Graph,
        h: &SfHandles,
        inputs: &TechniqueInputs,
        w: u32,
        hh: u32,
    ) -> ImageHandle {
        let frame = inputs.frame;
        let aspect = w as f32 / hh.max(1) as f32;
        let (mut points, slots, bases, total) = visible_vertices(&self.scene, frame, &self.fields, Some(aspect));
        for p in &mut points {
            p.albedo = DVec3::ONE;
        }
        let rad = self.add_points(graph, h, &points, Some(&slots), total.max(1), self.lights_through_fields());
        // base[instance] + gl_VertexIndex (which includes the mesh's vertex offset) = slot
        let mut draws = Vec::new();
        let mut base_of = vec![0i32; frame.instances.len().max(1)];
        for (ii, inst) in frame.instances.iter().enumerate() {
            let Some(&(first, count, offset)) = self.mesh_ranges.get(inst.mesh) else { continue };
            base_of[ii] = bases[ii] as i32 - offset;
            if count > 0 && self.fields.fields.get(inst.mesh).is_some() {
                draws.push((first, count, offset, ii as u32));
            }
        }
        let img = graph.create_image("sf_vertex_radiance", ImageDesc::new_2d(VERTEX_RADIANCE_FORMAT, w, hh));
        add_vertex_raster(graph, "sf_vertex", &self.vertex, inputs, rad, &base_of, draws, &[(img, [0.0; 4])], w, hh)[0]
    }
}

/// The per-vertex displays' raster pass (`name`): draws each `(first index, index count, vertex
/// offset, instance)` of `draws` with `pipe`, whose bindings are the camera, the instances,
/// `values` (per-vertex data) and `base_of` (each instance's first slot minus its mesh's vertex
/// offset), into `colors` (cleared to their values) over a depth buffer of its own; returns the
/// written images in order.
pub(crate) fn add_vertex_raster(
    graph: &mut Graph,
    name: &str,
    pipe: &Pipeline,
    inputs: &TechniqueInputs,
    values: BufferHandle,
    base_of: &[i32],
    draws: Vec<(u32, u32, i32, u32)>,
    colors: &[(ImageHandle, [f32; 4])],
    w: u32,
    hh: u32,
) -> Vec<ImageHandle> {
    let bases_buf = graph.create_buffer_init(&format!("{name}_bases"), bytes_of(base_of));
    let depth = graph.create_image(&format!("{name}_depth"), ImageDesc::new_2d(crate::gbuffer::DEPTH_FORMAT, w, hh));
    let mut p = graph.pass(name, PassKind::Raster);
    let colors: Vec<(ImageHandle, [f32; 4])> =
        colors.iter().map(|&(img, clear)| (p.write(img, Access::ColorAttachmentWrite), clear)).collect();
    let depth = p.write(depth, Access::DepthAttachmentWrite);
    let camera = p.read(inputs.handles.camera, Access::AnyShaderReadUniform);
    let [instances, values, bases_buf] =
        [inputs.handles.instances, values, bases_buf].map(|h| p.read(h, Access::VertexShaderReadStorage));
    let vertices = p.read(inputs.handles.vertices, Access::VertexBuffer);
    let indices = p.read(inputs.handles.indices, Access::IndexBuffer);
    let (pipeline, layout) = (pipe.pipeline, pipe.handle());
    let written: Vec<ImageHandle> = colors.iter().map(|c| c.0).collect();
    p.record(move |rc| {
        let d = rc.device();
        let mut color = Vec::with_capacity(colors.len());
        for &(img, clear) in &colors {
            color.push(crate::util::color_attachment(rc.image(img)?.view, clear));
        }
        let depth_att = crate::util::depth_attachment(rc.image(depth)?.view, true);
        let area = vk::Rect2D { offset: vk::Offset2D::default(), extent: vk::Extent2D { width: w, height: hh } };
        let info = vk::RenderingInfo::default()
            .render_area(area)
            .layer_count(1)
            .color_attachments(&color)
            .depth_attachment(&depth_att);
        let (vb, ib) = (rc.buffer(vertices)?, rc.buffer(indices)?);
        unsafe {
            d.cmd_begin_rendering(rc.cmd, &info);
            d.cmd_set_viewport(
                rc.cmd,
                0,
                &[vk::Viewport { x: 0.0, y: 0.0, width: w as f32, height: hh as f32, min_depth: 0.0, max_depth: 1.0 }],
            );
            d.cmd_set_scissor(rc.cmd, 0, &[area]);
            d.cmd_bind_pipeline(rc.cmd, vk::PipelineBindPoint::GRAPHICS, pipeline);
        }
        crate::util::push_graphics(
            rc,
            &layout,
            &[
                Bind::UniformBuffer(camera),
                Bind::StorageBuffer(instances),
                Bind::StorageBuffer(values),
                Bind::StorageBuffer(bases_buf),
            ],
        )?;
        unsafe {
            if !draws.is_empty() {
                d.cmd_bind_index_buffer(rc.cmd, ib.buffer, 0, vk::IndexType::UINT32);
                d.cmd_bind_vertex_buffers(rc.cmd, 0, &[vb.buffer], &[0]);
            }
            for &(first, count, offset, inst) in &draws {
                d.cmd_draw_indexed(rc.cmd, count, 1, first, offset, inst);
            }
            d.cmd_end_rendering(rc.cmd);
        }
        Ok(())
    });
    written
}

impl crate::technique::Technique for ShadowFieldsTechnique {
    fn name(&self) -> &'static str {
        if self.adaptive {
            "shadow-fields"
        } else {
            "shadow-fields-fixed"
        }
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        let srf = self.lights_through_fields();
        // the environment's SH and key lights turned and scaled to the frame's state
        let state = inputs.frame.environment;
        let light = sh_at(&self.shade_light_local, state);
        let h = upload(graph, &self.tables, &self.casts, inputs.frame, &light, srf);
        let key_count = (self.key.len() / 2) as u32;
        let key = graph.create_buffer_init("sf_key_lights", crate::lighting::lobes_bytes_at(&self.key, state));
        // the local lights' occluders: the frame's triangles (rebuilt when anything moved), or
        // four empty stand-ins the shader never reads (traced = 0)
        let (kd_bufs, traced) = crate::kdtree::KdTreeBuilder::add_frame_or_stand_ins(
            self.kd.as_mut(),
            engine,
            graph,
            &self.scene,
            inputs.frame,
            "sf",
        )?;
        let traced = traced as u32;
        let gb = inputs.gbuffer;
        let (w, hh) = (gb.width, gb.height);
        let vtx = (self.mode == SfMode::Vertex).then(|| self.add_vertex_display(graph, &h, inputs, w, hh));
        let hdr = graph.create_image("hdr", ImageDesc::new_2d(crate::shade_env::HDR_FORMAT, w, hh));
        let mut p = graph.pass("sf_shade", PassKind::Compute);
        let io = crate::shade_env::ShadingIo::declare(&mut p, inputs.handles, gb, inputs.env, hdr);
        // pixel mode binds the environment in the (unused) vertex-radiance slot
        let vtx = vtx.map(|v| p.read(v, Access::ComputeShaderReadSampled)).unwrap_or(io.env);
        let hdr = io.hdr;
        let r = [h.data, h.shells, h.insts, h.tensor, h.light, inputs.handles.lights]
            .map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let tex = p.read(inputs.handles.textures, Access::ComputeShaderReadSampled);
        let kd = crate::kdtree::KdTreeReads::declare(&mut p, kd_bufs, false);
        let key = p.read(key, Access::ComputeShaderReadStorage);
        let pipe = self.shade.handle();
        let (nearest, linear, repeat) = (self.nearest.sampler, self.linear.sampler, self.repeat.sampler);
        let mode = (self.mode == SfMode::Vertex) as u32;
        let push = crate::util::bytes_of(&[
            h.inst_count,
            h.tensor_count,
            inputs.handles.light_count,
            srf as u32,
            self.window_code(),
            mode,
            traced,
            key_count * traced,
            self.glossy_transfer as u32,
        ]);
        p.record(move |rc| {
            let mut binds = io.binds(nearest, linear);
            binds.extend(r.iter().map(|&b| Bind::StorageBuffer(b)));
            binds.push(Bind::SampledImage(vtx, nearest));
            binds.push(Bind::SampledImage(tex, repeat));
            binds.extend(kd.binds());
            binds.push(Bind::StorageBuffer(key));
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(hh, 8), 1])
        });
        Ok(hdr)
    }
}

/// Runs the GPU rendering path on `points` for `frame`: per point `[r, g, b, unclamped min]`
/// and the GPU milliseconds of the `sf_points` pass.
pub fn gpu_shade_points(
    engine: &mut penumbra_engine::Engine,
    tech: &ShadowFieldsTechnique,
    frame: &Frame,
    points: &[ShadePoint],
) -> Result<(Vec<[f32; 4]>, f64)> {
    let mut g = Graph::new();
    let h = upload(&mut g, &tech.tables, &tech.casts, frame, &tech.light, tech.srf);
    let out = tech.add_points(&mut g, &h, points, None, points.len().max(1) as u32, tech.srf);
    crate::trace::add_copy_to_readback(&mut g, out, "sf_points_out", points.len().max(1) as u64 * 16);
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

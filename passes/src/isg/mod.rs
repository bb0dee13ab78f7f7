//! Integral spherical Gaussian shadows (Iwasaki et al. 2012) with sphere-set occluders and
//! thin-shell triangles: technique `"isg"` (per-pixel visibility) and `"isg-vertex"` (per-vertex
//! visibility interpolated by the raster, [`vertex`]); `mode = "pixel" | "vertex"` in
//! `[technique_params]` / `--param mode=...` selects the same.
//!
//! Per frame:
//! * CPU: every shadow-casting closed object's sphere set (built once at creation by
//!   [`penumbra_math::sphereset::approximate_spheres`], or loaded from
//!   `<scene dir>/<scene name>.<object name>.spheres` when that file exists) is moved to world
//!   space: deforming objects through the spheres' vertex anchors on the deformed mesh (radii
//!   following the mesh's clearance, [`penumbra_math::sphereset::SphereSet::deformed`]), then the
//!   instance transform (radius times the largest axis scale). A CPU binary BVH over the spheres is
//!   built top-down by median splits on the longest axis of the centres (O(N log N); a few
//!   hundred spheres take microseconds), inner nodes bound both children's spheres exactly. This
//!   is the CPU fallback; by default the BVH is built on the GPU (`isg_bvh`,
//!   `glsl/isg/isg_bvh.comp`): Morton codes, bitonic sort and Karras 2012 LBVH in one workgroup,
//!   bounding spheres bottom-up (up to 1024 spheres).
//! * GPU (`isg_shade`, `glsl/isg/isg_shade.comp` + `glsl/include/isg.glsl`): per pixel, K lighting
//!   SGs (fitted once to the environment, `penumbra_math::envmap::fit_sg_lighting`); the BVH is
//!   traversed per lobe with cone-vs-sphere culling, leaf (or small inner) spheres mark the
//!   patches within the limiting angle they cover, and the occluded patches' ISGs (tabulated,
//!   [`penumbra_math::isg::IsgTable`]) are subtracted. Diffuse: per lobe, unshadowed
//!   SG-cosine integral times the visible fraction of the lobe times the cosine SG. Specular:
//!   eq. 9 with `Gamma_L` from the SG-prefiltered environment maps (eq. 10), or optionally from
//!   the lighting SGs (`prefiltered=0`, exact for SG lighting).
//! * Thin shells (objects marked `thin_shell`, open meshes that cast shadows, and thin walls
//!   whose fitted spheres cover less than [`MIN_SPHERE_COVERAGE`] of their volume, which the
//!   technique's notes name) are not sphere-approximated: their world-space triangles (deformed per frame) go to
//!   the GPU with a CPU BVH of their bounding spheres; the traversal culls nodes against the
//!   lobe's cone and the tangent plane, and every leaf triangle marks the patches whose centre
//!   direction passes through it (its projection on the hemisphere; the paper rasterizes the
//!   projected triangles, as Kautz et al. 2004).
//! * Per-vertex mode ([`vertex`]): the same visibilities at the mesh vertices, interpolated.
//! * Local lights (`light_shadows`, default on): per pixel, shadow rays from the shading point
//!   through the meshes (`light_occluders = mesh`, default: the frame's kd-tree, built only for
//!   scenes with local lights) or through the sphere BVH (analytic ray-sphere) and the thin-shell
//!   triangles (`spheres`): one ray to a point or spot light, 9 over a sphere light's disk (soft
//!   shadows). The paper lights by the environment; a local light's hard shadow shows every
//!   sphere-set gap (god_rays 40x30: two floor pixels beside the bunny lit, 0.208). The ISG of an
//!   SG with the light's solid angle would be the paper's alternative; it is not implemented.
//!
//! Not done: Ashikhmin-Shirley uses one Cook-Torrance lobe.

use crate::shade_env::HDR_FORMAT;
use crate::technique::TechniqueInputs;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::Result;
use glam::{Mat4, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, FrameStore, Graph, ImageHandle, PassKind};
use penumbra_math::isg::IsgTable;
use penumbra_math::sphereset::{approximate_spheres, measure_coverage, SphereSet};
use penumbra_scene::{Frame, Scene};
use std::sync::Arc;

pub mod vertex;

/// Parameters (paper defaults where the paper has one).
#[derive(Clone, Debug, PartialEq)]
pub struct IsgSettings {
    /// Lighting SG lobes K (the reference's SG mode uses 16).
    pub lobes: usize,
    /// With `Some(e)`: K is instead the fewest of `lighting::LOBE_COUNTS` (4 to 64) whose fit of
    /// the environment has a relative L2 error of at most e (`fit_error`; the choice and the
    /// error are in the technique's notes).
    pub fit_error: Option<f64>,
    /// Spheres per object when the set is built at start-up.
    pub spheres_per_object: usize,
    /// Patches per side of the discretized region (paper: 100 to 400 patches -> 10 to 20).
    pub patch_side: u32,
    /// Limiting-angle threshold (paper: 0.01).
    pub epsilon: f64,
    /// BVH descent threshold: an inner node whose projected half-angle is below `lod` times the
    /// patch size is rasterized as one sphere.
    pub lod: f32,
    /// Diffuse lighting lobes, taken brightest first, below this fraction of the light found
    /// visible so far at a pixel take the energy-weighted mean visibility of those traversed
    /// (0 evaluates every lobe; `glsl/include/isg_lobes.glsl`). Against the visible light, not
    /// the unshadowed total: in an umbra of the dominant lobe the sky's lobes are traversed.
    pub min_lobe_fraction: f32,
    /// False: visibility 1 everywhere (separates the shading error from the visibility error).
    pub shadows: bool,
    /// Specular `Gamma_L` from the SG-prefiltered environment maps (the paper, eq. 10); false:
    /// from the K lighting SGs (matches the SG-lighting reference).
    pub prefiltered_specular: bool,
    /// Diffuse environment term: the map's exact irradiance (`lighting::irradiance_env`) times
    /// the visible share of the SG lobes' irradiance (`true`, a ratio estimator), or the SG lobes
    /// alone (`false`, the paper's: the 16-lobe fit's error stays in every unshadowed pixel).
    pub diffuse_ratio: bool,
    /// Glossy environment term: the material model's unshadowed glossy term (the `env`
    /// technique's filtered importance sampling, `env_glossy` in `glsl/include/env_shade.glsl`) times the ISG visible fraction of
    /// the specular lobe (`true`, a ratio estimator), or eq. 9's one SG lobe of the BRDF
    /// (`false`, the paper's: it loses the lobe's Fresnel and masking energy).
    pub glossy_ratio: bool,
    /// Build the BVH on the GPU (`isg_bvh` pass, LBVH over Morton codes, up to
    /// [`GPU_BVH_MAX`] spheres); false or more spheres: the CPU median-split BVH.
    pub gpu_bvh: bool,
    /// Per-vertex visibility (the paper's per-vertex shadowing) instead of per pixel.
    pub per_vertex: bool,
    /// Per-vertex mode: meshes are subdivided until their longest edge is at most this (world
    /// units; 0: never).
    pub max_edge: f32,
    /// Per-vertex mode: a triangle whose vertices' visibilities (diffuse per channel, or glossy)
    /// differ by more than this is evaluated per pixel (shadow boundaries, glossy visibility that
    /// changes across a coarse triangle); 1 or more: never, the paper's pure per-vertex mode.
    pub pixel_refine: f32,
    /// The corners' normalized ISG: the table (default) or eq. 14's sigmoids (`isg_eval`).
    pub model: penumbra_math::isg::IsgModel,
    /// Which patches a sphere occludes: centre (default) or the paper's overlap rule
    /// (`patch_rule`).
    pub rule: penumbra_math::isg::PatchRule,
    /// Thin shells (and open meshes) cast shadows by their projected triangles.
    pub thin_shells: bool,
    /// Local lights are shadowed by shadow rays through the same occluders (sphere BVH and
    /// thin-shell triangles): one ray for point and spot lights (hard shadows), 9 rays over the
    /// disk of a sphere light (soft). Evaluated per pixel in both modes.
    pub light_shadows: bool,
    /// Local lights' shadow rays through the meshes (`true`, `light_occluders = mesh`: the
    /// frame's kd-tree) or through the spheres and thin-shell triangles (`false`, `spheres`).
    pub light_mesh: bool,
    /// Environment visibility traced through the frame's kd-tree (`visibility = traced`: 96
    /// shadow rays per lobe drawn from it) instead of the ISG over the sphere proxies (`isg`,
    /// default): not the paper's method but its measuring stick, the error left when the
    /// proxies and the ISG are exact, so the visibility's share of a cell's error shows apart
    /// from the SG lighting's.
    pub traced_visibility: bool,
    /// Triangles farther than this fraction of their object's size outside its spheres cast
    /// shadows as thin shells ([`thin_parts_with`]; default [`THIN_PART_TOLERANCE`]).
    pub thin_tolerance: f32,
    /// Ashikhmin-Shirley's specular lobe as the paper's seven SGs (`as_lobes = 7`: `sg_as_lobes`
    /// in `glsl/include/sg.glsl`, the closed-form Gauss-Hermite split of the anisotropic lobe,
    /// per pixel in the G-buffer's tangent frame and per vertex in the mesh's uv tangent frame,
    /// [`vertex::vertex_tangents`]) or as one Cook-Torrance lobe of the material's roughness (`1`).
    pub as_seven_lobes: bool,
}

/// Most spheres the one-workgroup GPU LBVH takes.
pub const GPU_BVH_MAX: usize = 1024;

impl Default for IsgSettings {
    fn default() -> Self {
        IsgSettings {
            lobes: 16,
            fit_error: None,
            spheres_per_object: 48,
            patch_side: 12,
            epsilon: 0.01,
            lod: 1.0,
            min_lobe_fraction: 0.02,
            shadows: true,
            prefiltered_specular: true,
            diffuse_ratio: true,
            glossy_ratio: true,
            gpu_bvh: true,
            per_vertex: false,
            max_edge: 0.1,
            pixel_refine: 0.2,
            model: penumbra_math::isg::IsgModel::Table,
            rule: penumbra_math::isg::PatchRule::Centre,
            thin_shells: true,
            light_shadows: true,
            light_mesh: true,
            traced_visibility: false,
            thin_tolerance: THIN_PART_TOLERANCE,
            as_seven_lobes: true,
        }
    }
}

impl IsgSettings {
    /// Bits 4 and 5 of the shaders' flags ([`model_flags`]).
    pub fn model_flags(&self) -> u32 {
        model_flags(self.model, self.rule)
    }

    /// Defaults with the scene's `technique_params` applied (see [`IsgSettings::set`]).
    pub fn from_params(params: &std::collections::BTreeMap<String, String>) -> anyhow::Result<Self> {
        crate::technique::settings_from_params(params, Self::set)
    }

    /// Sets one parameter. Keys: `lobes` (K, default 16), `spheres` (per object, 48), `side`
    /// (patches per side, 12), `epsilon` (0.01), `lod` (1.0), `min_fraction` (0.02), `shadows`,
    /// `prefiltered`, `gpu_bvh`, `thin_shells`, `light_shadows` (true/false or 1/0), `mode` (`pixel` or
    /// `vertex`), `max_edge` (per-vertex subdivision, world units, 0.1; 0: none), `pixel_refine`
    /// (per-vertex mode: the corner visibility spread above which a triangle is evaluated per
    /// pixel, 0.2; 1: never), `isg_eval` (`table` or the paper's `sigmoid`), `patch_rule`
    /// (`centre` or the paper's `paper`), `as_lobes` (Ashikhmin-Shirley's SG lobes, 7 or 1). Unknown keys
    /// and bad values are errors.
    pub fn set(&mut self, key: &str, value: &str) -> anyhow::Result<()> {
        use penumbra_math::isg::{IsgModel, PatchRule};
        let p = crate::technique::Param::new("isg", key, value);
        // counts and sizes are clamped into their ranges, as the scene files have them
        let count = || p.int(0, u64::MAX).map_err(|_| p.bad("a whole number"));
        let num = |lo: f64, hi: f64| p.number(|_| true, "a finite number").map(|x| x.clamp(lo, hi));
        let at_least_0 = || p.number(|x| x >= 0.0, "a finite number >= 0").map(|x| x as f32);
        let ratio_or_sg = [("ratio", true), ("sg", false)];
        match p.key() {
            "lobes" => self.lobes = count()?.clamp(1, 64) as usize,
            "fit_error" => {
                let e = p.number(|x| (0.0..1.0).contains(&x), "a number in [0, 1) (0: off)")?;
                self.fit_error = (e > 0.0).then_some(e);
            }
            "spheres" => self.spheres_per_object = count()?.min(4096) as usize,
            "side" => self.patch_side = count()?.clamp(1, 32) as u32,
            "epsilon" => self.epsilon = num(1e-6, 0.5)?,
            "lod" => self.lod = num(0.0, f64::INFINITY)? as f32,
            "min_fraction" => self.min_lobe_fraction = num(0.0, 1.0)? as f32,
            "shadows" => self.shadows = p.flag()?,
            "prefiltered" => self.prefiltered_specular = p.flag()?,
            "diffuse" => self.diffuse_ratio = p.choice(&ratio_or_sg)?,
            "glossy" => self.glossy_ratio = p.choice(&ratio_or_sg)?,
            "gpu_bvh" => self.gpu_bvh = p.flag()?,
            "thin_shells" => self.thin_shells = p.flag()?,
            "light_shadows" => self.light_shadows = p.flag()?,
            "light_occluders" => self.light_mesh = p.choice(&[("mesh", true), ("spheres", false)])?,
            "thin_tolerance" => self.thin_tolerance = at_least_0()?,
            "visibility" => self.traced_visibility = p.choice(&[("isg", false), ("traced", true)])?,
            "mode" => self.per_vertex = p.choice(&[("pixel", false), ("vertex", true)])?,
            "max_edge" => self.max_edge = at_least_0()?,
            "isg_eval" => self.model = p.choice(&[("table", IsgModel::Table), ("sigmoid", IsgModel::PaperFit)])?,
            "patch_rule" => {
                self.rule = p.choice(&[("centre", PatchRule::Centre), ("center", PatchRule::Centre), ("paper", PatchRule::Paper)])?
            }
            "pixel_refine" => self.pixel_refine = at_least_0()?,
            "as_lobes" => self.as_seven_lobes = p.choice(&[("7", true), ("1", false)])?,
            _ => return Err(p.unknown("lobes, fit_error, spheres, side, epsilon, lod, min_fraction, shadows, prefiltered, diffuse, glossy, gpu_bvh, thin_shells, light_shadows, light_occluders, thin_tolerance, visibility, mode, max_edge, pixel_refine, isg_eval, patch_rule, as_lobes")),
        }
        Ok(())
    }
}

/// Bits 4 and 5 of the ISG shaders' flags: `isg_paper_fit` and `isg_paper_rule` in
/// `glsl/include/isg.glsl` (every shader that includes it reads them from its push constants).
pub fn model_flags(model: penumbra_math::isg::IsgModel, rule: penumbra_math::isg::PatchRule) -> u32 {
    use penumbra_math::isg::{IsgModel, PatchRule};
    ((model == IsgModel::PaperFit) as u32) << 4 | ((rule == PatchRule::Paper) as u32) << 5
}

/// A world-space sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldSphere {
    pub center: Vec3,
    pub radius: f32,
}

/// A BVH node as the shader reads it (`IsgNode` in `glsl/include/isg.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuNode {
    /// Centre, radius.
    pub sphere: [f32; 4],
    /// Left child (-1 for a leaf), right child, sphere index, unused.
    pub info: [i32; 4],
}

/// Smallest sphere bounding two spheres.
pub fn merge_spheres(a: WorldSphere, b: WorldSphere) -> WorldSphere {
    let d = b.center - a.center;
    let dist = d.length();
    if dist + b.radius <= a.radius {
        return a;
    }
    if dist + a.radius <= b.radius {
        return b;
    }
    let r = 0.5 * (dist + a.radius + b.radius);
    let center = if dist > 0.0 { a.center + d * ((r - a.radius) / dist) } else { a.center };
    // Round up slightly so f32 error never leaves a child outside.
    WorldSphere { center, radius: r * (1.0 + 1e-6) + 1e-7 }
}

/// Binary BVH over `spheres` (root at 0, `2N - 1` nodes, empty for no spheres): top-down median
/// split on the longest axis of the centres; every parent bounds its children.
pub fn build_bvh(spheres: &[WorldSphere]) -> Vec<GpuNode> {
    let mut nodes = Vec::with_capacity(spheres.len() * 2);
    let mut idx: Vec<usize> =
        (0..spheres.len()).filter(|&i| spheres[i].radius > 0.0 && spheres[i].center.is_finite()).collect();
    if idx.is_empty() {
        return nodes;
    }
    fn rec(spheres: &[WorldSphere], idx: &mut [usize], nodes: &mut Vec<GpuNode>) -> (usize, WorldSphere) {
        let me = nodes.len();
        nodes.push(GpuNode { sphere: [0.0; 4], info: [-1, -1, -1, 0] });
        if idx.len() == 1 {
            let s = spheres[idx[0]];
            nodes[me] =
                GpuNode { sphere: [s.center.x, s.center.y, s.center.z, s.radius], info: [-1, -1, idx[0] as i32, 0] };
            return (me, s);
        }
        let (lo, hi) = idx.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), &i| {
            (lo.min(spheres[i].center), hi.max(spheres[i].center))
        });
        let ext = hi - lo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        idx.sort_by(|&a, &b| spheres[a].center[axis].total_cmp(&spheres[b].center[axis]));
        let mid = idx.len() / 2;
        let (l, r) = idx.split_at_mut(mid);
        let (li, ls) = rec(spheres, l, nodes);
        let (ri, rs) = rec(spheres, r, nodes);
        let s = merge_spheres(ls, rs);
        nodes[me] =
            GpuNode { sphere: [s.center.x, s.center.y, s.center.z, s.radius], info: [li as i32, ri as i32, -1, 0] };
        (me, s)
    }
    rec(spheres, &mut idx, &mut nodes);
    nodes
}

/// The axis scales of object `i`'s transform at t = 0 when they differ (by more than 1 %), else
/// one: its sphere set is fitted to the mesh scaled by them ([`scene_sphere_sets`]) and placed
/// by the transform without them ([`frame_spheres`]), since a sphere scaled non-uniformly is no
/// sphere (a box scaled by (0.25, 1, 0.25) holding spheres of its unit-cube radius times 1 cast a
/// blob four times too wide).
pub fn baked_scale(scene: &Scene, i: usize) -> Vec3 {
    if i >= scene.objects.len() {
        return Vec3::ONE;
    }
    let w = scene.world_at(i, 0.0);
    let s = Vec3::new(w.x_axis.truncate().length(), w.y_axis.truncate().length(), w.z_axis.truncate().length());
    if !s.is_finite() || s.min_element() <= 0.0 || s.max_element() <= 1.01 * s.min_element() {
        Vec3::ONE
    } else {
        s
    }
}

/// Sphere sets of a scene's objects (index = object), `None` for objects without one (thin
/// shells, non-casters, open meshes, thin walls: see [`is_thin_caster`]). An object scaled
/// non-uniformly gets its set in the scaled mesh's frame ([`baked_scale`]).
pub fn scene_sphere_sets(scene: &Scene, per_object: usize) -> Vec<Option<SphereSet>> {
    scene_sphere_sets_noting(scene, per_object).0
}

/// [`scene_sphere_sets`] and what went wrong with the `.spheres` files it found (unreadable,
/// malformed, or anchored to vertices the mesh does not have): those objects get fitted
/// spheres instead, and the user is told.
pub fn scene_sphere_sets_noting(scene: &Scene, per_object: usize) -> (Vec<Option<SphereSet>>, Vec<String>) {
    let mut notes = Vec::new();
    // Objects sharing a mesh (at the same baked scale) share its set (built once).
    let mut built: std::collections::HashMap<(usize, [u32; 3]), Option<SphereSet>> = std::collections::HashMap::new();
    let sets = scene
        .objects
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let info = scene.object_info(i);
            let mesh = scene.meshes.get(o.mesh)?;
            if !info.casts_shadow || info.thin_shell || !mesh.is_closed() {
                return None;
            }
            let baked = baked_scale(scene, i);
            let key = (o.mesh, baked.to_array().map(f32::to_bits));
            if let Some(dir) = scene.source.as_ref().and_then(|s| s.parent()) {
                let path = dir.join(format!("{}.{}.spheres", scene.name, o.name));
                if path.exists() && baked != Vec3::ONE {
                    notes.push(format!(
                        "{}: '{}' is scaled non-uniformly ({:.3}, {:.3}, {:.3}), which spheres in its mesh's frame cannot follow; isg fits {per_object} spheres to the scaled mesh instead",
                        path.display(),
                        o.name,
                        baked.x,
                        baked.y,
                        baked.z
                    ));
                } else if path.exists() {
                    let problem = match std::fs::read_to_string(&path) {
                        Err(e) => format!("cannot be read ({e})"),
                        Ok(text) => match SphereSet::parse(&text) {
                            Err(e) => format!("is not a sphere file ({e})"),
                            Ok(set) => {
                                let n = mesh.positions.len() as u32;
                                if set.spheres.iter().all(|s| s.anchors.iter().all(|&a| a < n)) {
                                    return Some(set);
                                }
                                format!("anchors its spheres to vertices the mesh does not have ({n} vertices)")
                            }
                        },
                    };
                    notes.push(format!(
                        "{}: {problem}; isg fits {per_object} spheres to '{}' instead",
                        path.display(),
                        o.name
                    ));
                }
            }
            if let Some(set) = built.get(&key) {
                return set.clone();
            }
            // a mesh with the same vertices and triangles as one already fitted (the same
            // procedural ball on several objects) shares its set
            let same = built
                .iter()
                .find(|(k, _)| k.1 == key.1 && scene.meshes.get(k.0).is_some_and(|m| m.same_shape(mesh)));
            let set = match same {
                Some((_, set)) => set.clone(),
                None => {
                    let scaled: Vec<Vec3> = mesh.positions.iter().map(|&p| p * baked).collect();
                    let set = approximate_spheres(&scaled, &mesh.indices, per_object).ok();
                    // A thin wall (balls_on_dish's dish: 48 spheres cover 19 % of it) cannot be
                    // held by spheres: they cast almost no shadow and, touching the surface, cover
                    // grazing lobes of the points beside them (black speckles). Such an object
                    // casts its shadows as a thin shell instead.
                    let coverage = set.as_ref().and_then(|set| {
                        measure_coverage(&scaled, &mesh.indices, &set.spheres, COVERAGE_RESOLUTION).ok()
                    });
                    match coverage {
                        Some(c) if c.covered < MIN_SPHERE_COVERAGE => {
                            notes.push(format!(
                                "'{}': {} spheres cover {:.0} % of its volume (a thin wall, under {:.0} %): isg casts its shadows as thin-shell triangles (exact, slower)",
                                o.name,
                                set.as_ref().map_or(0, |s| s.spheres.len()),
                                100.0 * c.covered,
                                100.0 * MIN_SPHERE_COVERAGE
                            ));
                            None
                        }
                        _ => set,
                    }
                }
            };
            built.insert(key, set.clone());
            set
        })
        .collect::<Vec<_>>();
    // deforming objects' sets keep their rest clearances (each frame's `deformed` then searches
    // only the deformed mesh)
    let sets = sets
        .into_iter()
        .enumerate()
        .map(|(i, set)| {
            let set = set?;
            let mesh = scene.meshes.get(scene.objects[i].mesh)?;
            if !scene.object_info(i).is_deforming() {
                return Some(set);
            }
            let baked = baked_scale(scene, i);
            let scaled: Vec<Vec3> = mesh.positions.iter().map(|&p| p * baked).collect();
            Some(set.with_rest_clearances(&scaled, &mesh.indices))
        })
        .collect();
    (sets, notes)
}

/// World-space spheres of a frame.
pub fn frame_spheres(scene: &Scene, sets: &[Option<SphereSet>], frame: &Frame) -> Vec<WorldSphere> {
    let mut out = Vec::new();
    for inst in &frame.instances {
        let Some(Some(set)) = sets.get(inst.object) else { continue };
        let Some(rest) = scene.meshes.get(inst.mesh) else { continue };
        let baked = baked_scale(scene, inst.object);
        let local = match &inst.deformed_mesh {
            Some(d) if d.positions.len() == rest.positions.len() => {
                if baked == Vec3::ONE {
                    set.deformed(&rest.positions, &d.positions, &rest.indices)
                } else {
                    let scaled = |v: &[Vec3]| v.iter().map(|&p| p * baked).collect::<Vec<_>>();
                    set.deformed(&scaled(&rest.positions), &scaled(&d.positions), &rest.indices)
                }
            }
            _ => set.spheres.clone(),
        };
        // the set is in the frame of the mesh scaled by `baked`
        let w: Mat4 = inst.world * Mat4::from_scale(baked.recip());
        let scale = w.x_axis.truncate().length().max(w.y_axis.truncate().length()).max(w.z_axis.truncate().length());
        for s in local {
            let c = w.transform_point3(s.center);
            let r = s.radius * scale;
            if c.is_finite() && r.is_finite() && r > 0.0 {
                out.push(WorldSphere { center: c, radius: r });
            }
        }
    }
    out
}

/// Whether object `i` casts shadows as a thin shell (projected triangles): a shadow caster
/// without a sphere set in `sets` ([`scene_sphere_sets`]): marked `thin_shell`, an open mesh (no
/// inside for spheres), or a thin wall its spheres cover less than [`MIN_SPHERE_COVERAGE`] of.
pub fn is_thin_caster(scene: &Scene, sets: &[Option<SphereSet>], i: usize) -> bool {
    let info = scene.object_info(i);
    scene.objects.get(i).is_some_and(|o| scene.meshes.get(o.mesh).is_some())
        && info.casts_shadow
        && sets.get(i).is_none_or(|s| s.is_none())
}

/// Objects whose fitted sphere set covers less of their volume than this cast their shadows as
/// thin shells (see [`scene_sphere_sets_noting`]). The paper's closed objects are covered 85-96 %
/// by 48 spheres (bunny 89 %, king 86 %, hat 85 %, balls 96 %); balls_on_dish's 3.75 cm thick dish
/// 19 %.
pub const MIN_SPHERE_COVERAGE: f64 = 0.5;

/// Voxels along the longest axis of the coverage measurement.
const COVERAGE_RESOLUTION: usize = 64;

/// A mesh point farther than this fraction of its object's bounding-box diagonal outside every
/// sphere of the object's set is not held by the spheres, and its triangles cast shadows as thin
/// shells (the default of the `thin_tolerance` parameter). The spheres are inscribed, so a
/// piece's flat base or a bunny's ears lie outside them: at 160x120 on the matrix scenes, 0.03
/// (hat_on_cloth's 2 cm brim only) left chess 0.064, vv_bunny 0.056, sf_statues 0.055 and
/// hat_on_cloth 0.056 rmse/mean against the 0.05 budget; 0.01 gives 0.045, 0.031, 0.040 and 0.048
/// at 1.1-2.4x the time per frame (lavapipe). Session 34, at 40x30: 0.01 left hat_on_cloth at
/// 0.058 (the brim's crevice at the crown's foot, which the inset spheres leave open) and
/// isg_bunny at 0.056 (an ear's shadow); 0.005 gives 0.048 and 0.048 (0.0075: 0.053, 0.054) at
/// 1.2-1.7x the time per frame (hat_on_cloth 65 -> 75 ms, isg_bunny 34 -> 54, falling 35 -> 52,
/// bunny 237 -> 406).
pub const THIN_PART_TOLERANCE: f32 = 0.005;

/// Per object, the triangles (indices into its mesh's triangle list) that cast shadows as thin
/// shells: every triangle of a thin caster ([`is_thin_caster`]); of an object with spheres, the
/// triangles with a vertex or centroid more than [`THIN_PART_TOLERANCE`] of the object's size
/// outside all of them (rest pose), the thin parts its spheres do not hold (a hat's brim), so
/// that they still cast their shadows.
pub fn thin_parts(scene: &Scene, sets: &[Option<SphereSet>]) -> Vec<Vec<u32>> {
    thin_parts_with(scene, sets, THIN_PART_TOLERANCE)
}

/// [`thin_parts`] with `tolerance` (a fraction of each object's bounding-box diagonal) in place
/// of [`THIN_PART_TOLERANCE`]: 0 makes every triangle not inside a sphere a thin shell.
pub fn thin_parts_with(scene: &Scene, sets: &[Option<SphereSet>], tolerance: f32) -> Vec<Vec<u32>> {
    (0..scene.objects.len())
        .map(|i| {
            let Some(mesh) = scene.objects.get(i).and_then(|o| scene.meshes.get(o.mesh)) else { return Vec::new() };
            let tris = (mesh.indices.len() / 3) as u32;
            if is_thin_caster(scene, sets, i) {
                return (0..tris).collect();
            }
            let Some(Some(set)) = sets.get(i) else { return Vec::new() };
            if !scene.object_info(i).casts_shadow || set.spheres.is_empty() {
                return Vec::new();
            }
            // in the frame the set was fitted in (the mesh scaled by `baked_scale`)
            let baked = baked_scale(scene, i);
            let (lo, hi) = mesh
                .positions
                .iter()
                .map(|&p| p * baked)
                .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(a, b), p| (a.min(p), b.max(p)));
            let tol = tolerance * (hi - lo).length();
            let outside = |p: Vec3| set.spheres.iter().all(|s| (p * baked - s.center).length() - s.radius > tol);
            let vertex_out: Vec<bool> = mesh.positions.iter().map(|&p| outside(p)).collect();
            (0..tris)
                .filter(|&t| {
                    let idx = &mesh.indices[3 * t as usize..3 * t as usize + 3];
                    let Some(v) =
                        idx.iter().map(|&k| mesh.positions.get(k as usize).copied()).collect::<Option<Vec<_>>>()
                    else {
                        return false;
                    };
                    idx.iter().any(|&k| vertex_out[k as usize]) || outside((v[0] + v[1] + v[2]) / 3.0)
                })
                .collect()
        })
        .collect()
}

/// World-space triangles of the frame's thin-shell parts ([`thin_parts`]; deformed meshes when
/// deforming).
pub fn frame_thin_triangles(scene: &Scene, parts: &[Vec<u32>], frame: &Frame) -> Vec<[Vec3; 3]> {
    let mut out = Vec::new();
    for inst in &frame.instances {
        let Some(part) = parts.get(inst.object).filter(|p| !p.is_empty()) else { continue };
        let Some(rest) = scene.meshes.get(inst.mesh) else { continue };
        let pos = match &inst.deformed_mesh {
            Some(d) if d.positions.len() == rest.positions.len() => &d.positions,
            _ => &rest.positions,
        };
        for &t in part {
            let Some(t) = rest.indices.get(3 * t as usize..3 * t as usize + 3) else { continue };
            let Some(v) = t
                .iter()
                .map(|&i| pos.get(i as usize).map(|p| inst.world.transform_point3(*p)))
                .collect::<Option<Vec<_>>>()
            else {
                continue;
            };
            if v.iter().all(|p| p.is_finite()) {
                out.push([v[0], v[1], v[2]]);
            }
        }
    }
    out
}

/// BVH over triangles' bounding spheres (centroid, farthest vertex); leaves index the triangles.
pub fn build_triangle_bvh(tris: &[[Vec3; 3]]) -> Vec<GpuNode> {
    let spheres: Vec<WorldSphere> = tris
        .iter()
        .map(|t| {
            let c = (t[0] + t[1] + t[2]) / 3.0;
            let r = t.iter().map(|p| (*p - c).length()).fold(0.0f32, f32::max);
            // Degenerate (zero-size) triangles still get a leaf; the shader skips them.
            WorldSphere { center: c, radius: r * (1.0 + 1e-5) + 1e-6 }
        })
        .collect();
    build_bvh(&spheres)
}

/// The `"isg"` / `"isg-vertex"` technique.
pub struct IsgTechnique {
    /// Problems with the scene's `.spheres` files and the thin walls and parts cast as triangles (notes).
    sphere_notes: Vec<String>,
    pipeline: Pipeline,
    bvh_pipeline: Pipeline,
    /// Per-vertex mode: the vertex compute and raster pipelines.
    vertex_pipelines: Option<(Pipeline, Pipeline)>,
    nearest: Sampler,
    linear: Sampler,
    repeat: Sampler,
    settings: IsgSettings,
    scene: Scene,
    sets: Vec<Option<SphereSet>>,
    /// Per object, its triangles that cast shadows as thin shells ([`thin_parts`]).
    thin: Vec<Vec<u32>>,
    refined: std::collections::HashMap<usize, vertex::Refined>,
    table: Arc<Vec<u8>>,
    /// The lighting lobes in the map's frame at intensity 1 (`lighting::lighting_lobes_local`):
    /// each frame turns and scales them to its environment's state (`lighting::lobes_at`).
    lobes: Vec<[f32; 4]>,
    prefiltered: Arc<Vec<u8>>,
    /// The environment's irradiance map (the ratio estimator's unshadowed diffuse term).
    irradiance: Arc<Vec<u8>>,
    /// Spheres, BVH nodes, thin-shell triangles and evaluated receiver vertices (per-vertex
    /// mode) of the last frame (for tests and reports).
    pub last_sphere_count: usize,
    pub last_node_count: usize,
    pub last_triangle_count: usize,
    pub last_vertex_count: usize,
    /// The kd-tree of the frame's triangles: local lights' shadow rays (`light_occluders =
    /// mesh`), for scenes with local lights.
    kd: Option<crate::kdtree::KdTreeBuilder>,
}

impl IsgTechnique {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene, settings: IsgSettings) -> Result<Self> {
        let shade = if settings.per_vertex { "isg/isg_shade_vertex.comp" } else { "isg/isg_shade.comp" };
        let pipeline = compute_pipeline(ctx, shaders, shade, 40)?;
        let bvh_pipeline = compute_pipeline(ctx, shaders, "isg/isg_bvh.comp", 36)?;
        let vertex_pipelines = if settings.per_vertex {
            Some((compute_pipeline(ctx, shaders, "isg/isg_vertex.comp", 32)?, vertex::raster_pipeline(ctx, shaders)?))
        } else {
            None
        };
        let table = IsgTable::default_table().to_gpu(settings.epsilon);
        let env = scene.environment.as_ref();
        let (lobes, fit) = match settings.fit_error {
            Some(target) => {
                let (k, lobes, err) = crate::lighting::lobes_for_error(env, target);
                let say = err.map(|e| {
                    let met = if e <= target { "within" } else { "the most lobes tried: over" };
                    format!("isg: {k} lighting lobes fit the environment to a relative L2 error of {e:.3} ({met} fit_error = {target})")
                });
                (lobes, say)
            }
            None => (crate::lighting::lighting_lobes_local(env, settings.lobes).0, None),
        };
        let prefiltered = crate::lighting::prefiltered_env(scene.environment.as_ref());
        let (sets, mut sphere_notes) = scene_sphere_sets_noting(scene, settings.spheres_per_object);
        sphere_notes.extend(fit);
        let thin = thin_parts_with(scene, &sets, settings.thin_tolerance);
        for (i, part) in thin.iter().enumerate() {
            let (Some(Some(set)), Some(o)) = (sets.get(i), scene.objects.get(i)) else { continue };
            if !part.is_empty() {
                let tris = scene.meshes.get(o.mesh).map_or(0, |m| m.indices.len() / 3);
                sphere_notes.push(format!(
                    "'{}': {} of its {tris} triangles lie outside its {} spheres (thin parts): they cast their shadows as thin-shell triangles",
                    o.name,
                    part.len(),
                    set.spheres.len()
                ));
            }
        }
        if settings.per_vertex {
            // what max_edge asks beyond the triangle budget is said, not silently dropped
            for (i, o) in scene.objects.iter().enumerate() {
                let Some(mesh) = scene.meshes.get(o.mesh) else { continue };
                let longest = vertex::longest_edge(&mesh.positions, &mesh.indices)
                    * vertex::largest_scale(&scene.world_at(i, 0.0));
                let (asked, applied) = vertex::subdivision_levels(mesh.indices.len() / 3, longest, settings.max_edge);
                if asked > applied {
                    sphere_notes.push(format!(
                        "'{}': subdivided {applied} times, not the {asked} times max_edge = {:e} asks (at most {} triangles per object): its longest edge stays {:.3e}",
                        o.name,
                        settings.max_edge,
                        vertex::MAX_REFINED_TRIANGLES,
                        longest / (1u64 << applied) as f32
                    ));
                }
            }
        }
        // Mesa 22.3's lavapipe ends an invocation's loops after 65535 iterations, silently; the
        // loop guard (`penumbra bench loop-guard`) measured isg's visibility loops past that on
        // most scenes with occluders: where the driver has the limit, say so
        let mut probe = penumbra_engine::Engine::new(ctx.clone(), 1)?;
        if let Some(n) = crate::kernels::loop_probe::loop_limit(&mut probe, shaders, 100_000)? {
            sphere_notes.push(format!(
                "this driver ({}) ends a shader invocation's loops after {n} iterations: isg's visibility loops (every lighting lobe's BVH walks and patch rasterization in one invocation) pass that where many occluders overlap (balls_on_dish, falling, hat_on_cloth, chess, sf_bowling, sf_statues, the bunnies), and those pixels come out wrong; lavapipe in Mesa 25 has no such limit",
                ctx.driver_info()
            ));
        }
        drop(probe);
        let settings_traces_lights =
            (settings.light_shadows && settings.light_mesh && !scene.lights.is_empty()) || settings.traced_visibility;
        Ok(IsgTechnique {
            pipeline,
            bvh_pipeline,
            vertex_pipelines,
            nearest: Sampler::nearest(ctx)?,
            linear: Sampler::latlong(ctx)?,
            repeat: Sampler::repeat(ctx)?,
            sets,
            thin,
            sphere_notes,
            refined: Default::default(),
            scene: scene.clone(),
            settings,
            table: Arc::new(bytes_of(&table)),
            lobes,
            prefiltered: Arc::new(bytes_of(&prefiltered)),
            irradiance: Arc::new(bytes_of(&crate::lighting::irradiance_env(scene.environment.as_ref()))),
            last_sphere_count: 0,
            last_node_count: 0,
            last_triangle_count: 0,
            last_vertex_count: 0,
            kd: if settings_traces_lights { Some(crate::kdtree::KdTreeBuilder::new(ctx, shaders)?) } else { None },
        })
    }

    /// The lighting lobes the shaders evaluate.
    fn lobe_count(&self) -> u32 {
        (self.lobes.len() / 2) as u32
    }

    /// The sphere sets (index = object).
    pub fn sphere_sets(&self) -> &[Option<SphereSet>] {
        &self.sets
    }
}

impl IsgTechnique {
    /// The `isg_bvh` pass: LBVH of `spheres` (2..=GPU_BVH_MAX) on the GPU; returns the node
    /// buffer and its node count.
    fn add_gpu_bvh(&self, graph: &mut Graph, spheres: &[WorldSphere]) -> (penumbra_engine::BufferHandle, i32) {
        let n = spheres.len();
        let data: Vec<[f32; 4]> = spheres.iter().map(|s| [s.center.x, s.center.y, s.center.z, s.radius]).collect();
        let (lo, hi) =
            spheres.iter().fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), s| {
                (lo.min(s.center), hi.max(s.center))
            });
        let inv = (hi - lo).max(Vec3::splat(1e-6)).recip();
        let input = graph.create_buffer_init("isg_spheres", bytes_of(&data));
        let nodes = graph.create_buffer("isg_bvh", ((2 * n - 1) * std::mem::size_of::<GpuNode>()) as u64);
        let mut p = graph.pass("isg_bvh", PassKind::Compute);
        let input = p.read(input, Access::ComputeShaderReadStorage);
        let nodes = p.write(nodes, Access::ComputeShaderWriteStorage); // reads only its own writes
        let mut push = Vec::with_capacity(36);
        for v in [lo.x, lo.y, lo.z, 0.0, inv.x, inv.y, inv.z, 0.0] {
            push.extend_from_slice(&f32::to_le_bytes(v));
        }
        push.extend_from_slice(&(n as i32).to_le_bytes());
        let pipe = self.bvh_pipeline.handle();
        p.record(move |rc| {
            crate::util::dispatch(rc, pipe, &[Bind::StorageBuffer(input), Bind::StorageBuffer(nodes)], &push, [1, 1, 1])
        });
        (nodes, (2 * n - 1) as i32)
    }

    /// Per-vertex mode: the `isg_vertex` compute pass over the frame's receiver vertices and
    /// the `isg_vertex_raster` pass interpolating its output; returns the interpolated image.
    fn add_vertex_passes(
        &mut self,
        graph: &mut Graph,
        inputs: &TechniqueInputs,
        table: penumbra_engine::BufferHandle,
        lobes: penumbra_engine::BufferHandle,
        bvh: penumbra_engine::BufferHandle,
        node_count: i32,
        tris: penumbra_engine::BufferHandle,
        tri_nodes: penumbra_engine::BufferHandle,
        tri_node_count: i32,
    ) -> Result<ImageHandle> {
        let (w, h) = (inputs.gbuffer.width, inputs.gbuffer.height);
        let view_proj = crate::scene_gpu::FrameConstants::new(inputs.frame, None, w, h).view_proj();
        let view = Some((view_proj, inputs.frame.camera.eye));
        let recv = vertex::frame_receivers(&self.scene, inputs.frame, self.settings.max_edge, &mut self.refined, view);
        self.last_vertex_count = recv.evaluated;
        let count = recv.vertices.len() as u32;
        let index_count = recv.indices.len() as u32;
        let verts = if recv.vertices.is_empty() { vec![vertex::IsgVertex::default()] } else { recv.vertices };
        let indices = if recv.indices.is_empty() { vec![0u32; 3] } else { recv.indices };
        let verts = graph.create_buffer_init("isg_vertices", bytes_of(&verts));
        let index_buf = graph.create_buffer_init("isg_vertex_indices", bytes_of(&indices));
        let vis = graph.create_buffer("isg_vertex_vis", (count.max(1) as u64) * 16);
        let Some((compute, raster)) = &self.vertex_pipelines else {
            anyhow::bail!("isg: per-vertex pipelines missing")
        };
        let vertex_pipe = compute.handle();
        let rl = raster.handle();
        let scene = inputs.handles;
        let mut p = graph.pass("isg_vertex", PassKind::Compute);
        let camera = p.read(scene.camera, Access::AnyShaderReadUniform);
        let materials = p.read(scene.materials, Access::ComputeShaderReadStorage);
        let verts_c = p.read(verts, Access::ComputeShaderReadStorage);
        let vis = p.write(vis, Access::ComputeShaderWriteStorage);
        let lobes = p.read(lobes, Access::ComputeShaderReadStorage);
        let [table, bvh, tris, tri_nodes] =
            [table, bvh, tris, tri_nodes].map(|h| p.read(h, Access::ComputeShaderReadSampled));
        let mut push = Vec::with_capacity(32);
        push.extend_from_slice(&count.to_le_bytes());
        push.extend_from_slice(&self.lobe_count().to_le_bytes());
        push.extend_from_slice(&(if self.settings.shadows { node_count } else { 0 }).to_le_bytes());
        push.extend_from_slice(&(if self.settings.shadows { tri_node_count } else { 0 }).to_le_bytes());
        push.extend_from_slice(&(self.settings.patch_side.clamp(1, 32) as i32).to_le_bytes());
        push.extend_from_slice(&self.settings.lod.to_le_bytes());
        push.extend_from_slice(&self.settings.min_lobe_fraction.max(0.0).to_le_bytes());
        push.extend_from_slice(
            &(self.settings.model_flags() | (self.settings.as_seven_lobes as u32) << 6).to_le_bytes(),
        );
        p.record(move |rc| {
            let storage = crate::util::storage([materials, verts_c, vis, lobes]);
            let texels = [table, bvh, tris, tri_nodes].map(Bind::TexelBuffer);
            let binds = [&[Bind::UniformBuffer(camera)][..], &storage, &texels].concat();
            crate::util::dispatch(rc, vertex_pipe, &binds, &push, [groups(count, 64), 1, 1])
        });
        let image = graph.create_image("isg_vis", ImageDesc::new_2d(vertex::VIS_FORMAT, w, h));
        let depth = graph.create_image("isg_vis_depth", ImageDesc::new_2d(vertex::VIS_DEPTH_FORMAT, w, h));
        let mut p = graph.pass("isg_vertex_raster", PassKind::Raster);
        let image = p.write(image, Access::ColorAttachmentWrite);
        let depth = p.write(depth, Access::DepthAttachmentWrite);
        let camera = p.read(scene.camera, Access::AnyShaderReadUniform);
        let [vis, verts_v, index_buf] = [vis, verts, index_buf].map(|h| p.read(h, Access::VertexShaderReadStorage));
        let refine = self.settings.pixel_refine;
        p.record(move |rc| {
            let d = rc.device();
            // cleared to r < 0: no receiver triangle here (per-pixel fallback)
            let colors = [crate::util::color_attachment(rc.image(image)?.view, [-1.0; 4])];
            let depth_att = crate::util::depth_attachment(rc.image(depth)?.view, false);
            let info = crate::raster::rendering_info(w, h, &colors, &depth_att);
            crate::raster::begin(
                rc,
                &info,
                w,
                h,
                &rl,
                &[
                    Bind::UniformBuffer(camera),
                    Bind::StorageBuffer(vis),
                    Bind::StorageBuffer(verts_v),
                    Bind::StorageBuffer(index_buf),
                ],
            )?;
            unsafe {
                if count > 0 && index_count > 0 {
                    let stages = vk::ShaderStageFlags::VERTEX | vk::ShaderStageFlags::FRAGMENT;
                    d.cmd_push_constants(rc.cmd, rl.layout, stages, 0, &refine.to_le_bytes());
                    d.cmd_draw(rc.cmd, index_count, 1, 0, 0);
                }
                d.cmd_end_rendering(rc.cmd);
            }
            Ok(())
        });
        Ok(image)
    }
}

impl crate::technique::Technique for IsgTechnique {
    fn name(&self) -> &'static str {
        if self.settings.per_vertex {
            "isg-vertex"
        } else {
            "isg"
        }
    }

    fn notes(&self, _scene: &Scene) -> Vec<String> {
        self.sphere_notes.clone()
    }

    fn add(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph, inputs: &TechniqueInputs) -> Result<ImageHandle> {
        // local lights' occluders (and traced visibility's): the frame's triangles (rebuilt when
        // anything moved), or four empty stand-ins the shader never reads (flags bits 2, 3 off)
        let (kd_bufs, kd_tree) = crate::kdtree::KdTreeBuilder::add_frame_or_stand_ins(
            self.kd.as_mut(),
            engine,
            graph,
            &self.scene,
            inputs.frame,
            "isg",
        )?;
        let spheres = frame_spheres(&self.scene, &self.sets, inputs.frame);
        self.last_sphere_count = spheres.len();
        let (scene, gb) = (inputs.handles, inputs.gbuffer);
        let (w, h) = (gb.width, gb.height);
        let table = graph.create_buffer_init("isg_table", crate::util::whole_texels(self.table.as_ref().clone()));
        let lobes = crate::lighting::lobes_bytes_at(&self.lobes, inputs.frame.environment);
        let lobes = graph.create_buffer_init("isg_lobes", lobes);
        let prefiltered = graph.create_buffer_init("isg_prefiltered", self.prefiltered.as_ref().clone());
        let irradiance = graph.create_buffer_init("isg_irradiance", self.irradiance.as_ref().clone());
        let (bvh, node_count) = if self.settings.gpu_bvh && spheres.len() >= 2 && spheres.len() <= GPU_BVH_MAX {
            self.add_gpu_bvh(graph, &spheres)
        } else {
            let nodes = build_bvh(&spheres);
            let count = nodes.len() as i32;
            let nodes = if nodes.is_empty() { vec![GpuNode { sphere: [0.0; 4], info: [-1; 4] }] } else { nodes };
            (graph.create_buffer_init("isg_bvh", bytes_of(&nodes)), count)
        };
        self.last_node_count = node_count as usize;
        // Thin shells: world-space triangles and their BVH (CPU, median splits).
        let tris = if self.settings.thin_shells {
            frame_thin_triangles(&self.scene, &self.thin, inputs.frame)
        } else {
            Vec::new()
        };
        self.last_triangle_count = tris.len();
        let tri_nodes = build_triangle_bvh(&tris);
        let tri_node_count = tri_nodes.len() as i32;
        let tri_data: Vec<[f32; 4]> = tris.iter().flat_map(|t| t.map(|p| [p.x, p.y, p.z, 0.0])).collect();
        let tri_data = if tri_data.is_empty() { vec![[0.0f32; 4]; 3] } else { tri_data };
        let tri_nodes =
            if tri_nodes.is_empty() { vec![GpuNode { sphere: [0.0; 4], info: [-1; 4] }] } else { tri_nodes };
        let tris_buf = graph.create_buffer_init("isg_thin_triangles", bytes_of(&tri_data));
        let tri_bvh = graph.create_buffer_init("isg_thin_bvh", bytes_of(&tri_nodes));
        let vertex_vis = if self.settings.per_vertex {
            Some(self.add_vertex_passes(
                graph,
                inputs,
                table,
                lobes,
                bvh,
                node_count,
                tris_buf,
                tri_bvh,
                tri_node_count,
            )?)
        } else {
            None
        };
        let hdr = graph.create_image("hdr", ImageDesc::new_2d(HDR_FORMAT, w, h));
        let mut p = graph.pass("isg_shade", PassKind::Compute);
        let io = crate::shade_env::ShadingIo::declare(&mut p, scene, gb, inputs.env, hdr);
        let hdr = io.hdr;
        let lights = p.read(scene.lights, Access::ComputeShaderReadStorage);
        let textures = p.read(scene.textures, Access::ComputeShaderReadSampled);
        // the ISG's table, sphere BVH and thin shells are texel buffers (glsl/include/isg.glsl)
        let [table, bvh, tris_buf, tri_bvh] =
            [table, bvh, tris_buf, tri_bvh].map(|h| p.read(h, Access::ComputeShaderReadSampled));
        let [lobes, prefiltered, irradiance] =
            [lobes, prefiltered, irradiance].map(|h| p.read(h, Access::ComputeShaderReadStorage));
        let vertex_vis = vertex_vis.map(|v| p.read(v, Access::ComputeShaderReadSampled));
        let kd = crate::kdtree::KdTreeReads::declare(&mut p, kd_bufs, false);
        let mut push = Vec::with_capacity(40);
        push.extend_from_slice(&scene.light_count.to_le_bytes());
        push.extend_from_slice(&self.lobe_count().to_le_bytes());
        push.extend_from_slice(&node_count.to_le_bytes());
        push.extend_from_slice(&(self.settings.patch_side.clamp(1, 32) as i32).to_le_bytes());
        push.extend_from_slice(&self.settings.lod.to_le_bytes());
        let flags = !self.settings.shadows as u32
            | (!self.settings.light_shadows as u32) << 1
            | ((kd_tree && self.settings.light_mesh) as u32) << 2
            | ((kd_tree && self.settings.traced_visibility) as u32) << 3
            | self.settings.model_flags()
            | (self.settings.as_seven_lobes as u32) << 6;
        push.extend_from_slice(&flags.to_le_bytes());
        push.extend_from_slice(&self.settings.min_lobe_fraction.max(0.0).to_le_bytes());
        let specular_mode = if self.settings.glossy_ratio { 2u32 } else { !self.settings.prefiltered_specular as u32 };
        push.extend_from_slice(&specular_mode.to_le_bytes());
        push.extend_from_slice(&tri_node_count.to_le_bytes());
        push.extend_from_slice(&(self.settings.diffuse_ratio as u32).to_le_bytes());
        let pipe = self.pipeline.handle();
        let (nearest, linear, repeat) = (self.nearest.sampler, self.linear.sampler, self.repeat.sampler);
        p.record(move |rc| {
            let mut binds = io.binds(nearest, linear);
            binds.extend([Bind::StorageBuffer(lights), Bind::SampledImage(textures, repeat)]);
            binds.extend([
                Bind::TexelBuffer(table),
                Bind::StorageBuffer(lobes),
                Bind::TexelBuffer(bvh),
                Bind::StorageBuffer(prefiltered),
                Bind::TexelBuffer(tris_buf),
                Bind::TexelBuffer(tri_bvh),
                Bind::StorageBuffer(irradiance),
            ]);
            if let Some(v) = vertex_vis {
                binds.push(Bind::SampledImage(v, nearest));
            }
            binds.extend(kd.binds());
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(w, 8), groups(h, 8), 1])
        });
        Ok(hdr)
    }
}

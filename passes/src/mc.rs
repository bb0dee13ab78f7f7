//! The GPU Monte Carlo baseline, technique `mc` (`glsl/mc.comp`): the "GPU-based Monte Carlo ray
//! tracing" the papers compare against, on the compute tracer of [`crate::trace`].
//!
//! Per pixel and frame, [`McTechnique::spp`] samples of the CPU reference's estimator
//! (`penumbra_reference::render`): a primary ray through a uniformly jittered position in the
//! pixel (from the near plane, closest hit through the kd-tree), and at the hit one environment
//! sample (texel chosen with probability proportional to luminance x texel solid angle, as the
//! reference's alias table, here by marginal/conditional CDFs), one sample per local light
//! (point, spot, sphere: `penumbra_reference::lights`) and one BRDF sample (the reference's
//! diffuse/specular mixture), combined by the power heuristic (sphere lights and the environment;
//! delta lights unweighted), each with an any-hit shadow ray through the tree. Same BRDFs (`penumbra_reference::brdf`), two-sided surfaces
//! (geometric normal towards the viewer, directions below it blocked), shading normals and
//! tangent frames, shadow-ray offset `3e-5 (1 + max |p|)` along the geometric normal, and
//! `casts_shadow = false` objects ignored by shadow rays. Primary rays that miss see the
//! environment.
//!
//! Progressive: a persistent RGBA32F image sums the samples (alpha counts them) and the output is
//! the mean; it restarts when the camera, an object, a deformation, a light or a material changed, when
//! the tree was rebuilt, or when the image is new (first frame, resize).
//!
//! Texture maps (albedo multiplies, roughness G channel multiplies roughness and sets Phong-type
//! exponents to `2 / r^2 - 2`) are sampled bilinearly from the scene's texture array
//! ([`crate::textures`], layers resampled to 256^2, so slightly smoother than the reference's
//! texels). Not yet (the reference has them): the participating medium, anisotropic
//! Ashikhmin-Shirley exponents (`shininess_v`).

use crate::kdtree::{KdTreeBuilder, KdTreeHandles};
use crate::scene_gpu::FrameConstants;
use crate::shade_env::HDR_FORMAT;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline};
use anyhow::{bail, Result};
use glam::{Mat3, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, BufferHandle, Context, Engine, Graph, ImageHandle, PassKind};
use penumbra_scene::{BrdfKind, Environment, Frame, Material, Scene};
use std::sync::Arc;

/// Environment sampling tables (CPU side).
pub struct EnvTables {
    pub width: u32,
    pub height: u32,
    /// rgb radiance (intensity applied), w = probability of the texel.
    pub texels: Vec<[f32; 4]>,
    /// Marginal CDF over rows (height + 1), then each row's conditional CDF (width + 1).
    pub cdf: Vec<f32>,
    pub can_sample: bool,
    pub cos_rot: f32,
    pub sin_rot: f32,
}

fn luminance(c: Vec3) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

impl EnvTables {
    pub fn new(env: Option<&Environment>) -> Self {
        let black = Environment { width: 1, height: 1, texels: vec![[0.0; 3]], intensity: 0.0, rotation: 0.0 };
        let env = match env {
            Some(e) if e.width > 0 && e.height > 0 && e.texels.len() == (e.width * e.height) as usize => e,
            _ => &black,
        };
        let (w, h) = (env.width as usize, env.height as usize);
        let intensity = if env.intensity.is_finite() { env.intensity } else { 0.0 };
        let rot = if env.rotation.is_finite() { env.rotation } else { 0.0 };
        let rad: Vec<Vec3> = env
            .texels
            .iter()
            .map(|t| {
                let v = Vec3::from_array(*t) * intensity;
                if v.is_finite() {
                    v
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let pi = std::f64::consts::PI;
        let row_sa: Vec<f64> = (0..h)
            .map(|j| ((j as f64 * pi / h as f64).cos() - ((j + 1) as f64 * pi / h as f64).cos()) * 2.0 * pi / w as f64)
            .collect();
        let weights: Vec<f64> =
            rad.iter().enumerate().map(|(i, t)| luminance(t.max(Vec3::ZERO)) * row_sa[i / w]).collect();
        let total: f64 = weights.iter().sum();
        let can_sample = total.is_finite() && total > 0.0;
        let mut cdf = Vec::with_capacity(h + 1 + h * (w + 1));
        let row_tot: Vec<f64> = (0..h).map(|j| weights[j * w..(j + 1) * w].iter().sum()).collect();
        let mut acc = 0.0;
        cdf.push(0.0);
        for (j, rt) in row_tot.iter().enumerate() {
            acc += rt;
            cdf.push(if j + 1 == h { 1.0 } else { (acc / total.max(1e-300)) as f32 });
        }
        for j in 0..h {
            let mut a = 0.0;
            cdf.push(0.0);
            for i in 0..w {
                a += weights[j * w + i];
                cdf.push(if i + 1 == w {
                    1.0
                } else if row_tot[j] > 0.0 {
                    (a / row_tot[j]) as f32
                } else {
                    (i + 1) as f32 / w as f32
                });
            }
        }
        let texels = rad
            .iter()
            .zip(&weights)
            .map(|(r, wt)| [r.x, r.y, r.z, if can_sample { (wt / total) as f32 } else { 0.0 }])
            .collect();
        EnvTables { width: w as u32, height: h as u32, texels, cdf, can_sample, cos_rot: rot.cos(), sin_rot: rot.sin() }
    }
}

/// Per-material parameters as the reference's `Brdf::new` sanitises them, 4 vec4 each: (albedo,
/// kind), (specular, GGX alpha), (shininess nu, nv, p_spec, 0), (albedo map layer, roughness map
/// layer (-1: none), roughness, shininess). `extras` gives the maps (may be shorter).
pub fn material_table(materials: &[Material], extras: &[penumbra_scene::MaterialExtra]) -> Vec<[f32; 4]> {
    let mut out = Vec::new();
    for (i, m) in materials.iter().enumerate() {
        let san = |v: Vec3| if v.is_finite() { v.max(Vec3::ZERO) } else { Vec3::ZERO };
        let albedo = san(m.albedo);
        let spec = san(m.specular).min(Vec3::ONE);
        let rough = if m.roughness.is_finite() { m.roughness } else { 1.0 }.clamp(0.0, 1.0);
        let shin = if m.shininess.is_finite() { m.shininess } else { 1.0 }.clamp(0.0, 1e6);
        let alpha = (rough * rough).max(1e-3);
        let (ld, ls) = (luminance(albedo) as f32, luminance(spec) as f32);
        let p_spec = match m.kind {
            BrdfKind::Diffuse => 0.0,
            _ if ls <= 0.0 => 0.0,
            _ if ld <= 0.0 => 1.0,
            _ => (ls / (ld + ls)).clamp(0.05, 0.95),
        };
        let kind = match m.kind {
            BrdfKind::Diffuse => 0.0,
            BrdfKind::BlinnPhong => 1.0,
            BrdfKind::CookTorrance => 2.0,
            BrdfKind::AshikhminShirley => 3.0,
        };
        out.push([albedo.x, albedo.y, albedo.z, kind]);
        out.push([spec.x, spec.y, spec.z, alpha]);
        out.push([shin, shin, p_spec, 0.0]);
        let layer = |l: Option<usize>| l.map_or(-1.0, |l| l as f32);
        let x = extras.get(i);
        out.push([layer(x.and_then(|x| x.albedo_map)), layer(x.and_then(|x| x.roughness_map)), rough, shin]);
    }
    if out.is_empty() {
        out = vec![[0.0; 4]; 4];
    }
    out
}

/// Local lights as `penumbra_reference::lights::LocalLight::new` keeps them (lights that cannot
/// emit are dropped): 4 vec4 each, the layout of `lights` in `glsl/mc.comp`.
pub fn light_table(lights: &[penumbra_scene::LightInstance]) -> Vec<[f32; 4]> {
    use penumbra_scene::LightKind;
    let mut out = Vec::new();
    for l in lights {
        let p = l.power;
        if !p.is_finite() || p.max_element() <= 0.0 || !l.position.is_finite() {
            continue;
        }
        let power = p.max(Vec3::ZERO);
        let pos = l.position;
        match l.kind {
            LightKind::Point => {
                out.extend([[pos.x, pos.y, pos.z, 0.0], [0.0; 4], [power.x, power.y, power.z, 0.0], [0.0; 4]]);
            }
            LightKind::Spot { inner_deg, outer_deg } => {
                let axis = l.direction.normalize_or_zero();
                if axis == Vec3::ZERO || !axis.is_finite() {
                    continue;
                }
                let ci = inner_deg.clamp(0.0, 180.0).to_radians().cos();
                let co = outer_deg.clamp(0.0, 180.0).to_radians().cos();
                out.extend([
                    [pos.x, pos.y, pos.z, 1.0],
                    [axis.x, axis.y, axis.z, co],
                    [power.x, power.y, power.z, ci],
                    [0.0; 4],
                ]);
            }
            LightKind::Sphere { radius } => {
                if !(radius.is_finite() && radius > 0.0) {
                    continue;
                }
                out.extend([
                    [pos.x, pos.y, pos.z, 2.0],
                    [0.0; 4],
                    [power.x, power.y, power.z, 0.0],
                    [radius, 0.0, 0.0, 0.0],
                ]);
            }
        }
    }
    out
}

/// Triangles, their shading data and their "casts no shadow" flags.
pub type ShadingTriangles = (Vec<[Vec3; 3]>, Vec<[f32; 4]>, Vec<bool>);

/// World triangles with shading data (6 vec4 each: n0 + material bits, n1, n2, tangent,
/// (uv0, uv1), (uv2, 0, 0)) and
/// shadow flags, in the order of [`crate::kdtree::world_triangles`] (degenerate ones dropped).
pub fn world_triangles_shading(scene: &Scene, frame: &Frame) -> Result<ShadingTriangles> {
    let mut tris = Vec::new();
    let mut data = Vec::new();
    let mut no_shadow = Vec::new();
    for wm in crate::kdtree::world_meshes(scene, frame)? {
        let (name, inst, mesh) = (wm.name, wm.inst, wm.mesh);
        if inst.material >= frame.materials.len() {
            bail!("object '{name}' refers to material {} of {}", inst.material, frame.materials.len());
        }
        let casts = scene.object_info(inst.object).casts_shadow;
        let m3 = Mat3::from_mat4(inst.world);
        let normal_m = if m3.determinant().abs() > 1e-20 { m3.inverse().transpose() } else { m3 };
        let np = mesh.positions.len();
        let has_n = mesh.normals.len() == np;
        let has_uv = mesh.uvs.len() == np;
        for t in wm.triangles() {
            let ([i0, i1, i2], [p0, p1, p2]) = t?;
            let (e1, e2) = (p1 - p0, p2 - p0);
            let ng = e1.cross(e2).normalize();
            let n = [i0, i1, i2].map(|i| {
                if !has_n {
                    return ng;
                }
                let n = (normal_m * mesh.normals[i]).normalize_or_zero();
                if n == Vec3::ZERO || !n.is_finite() {
                    ng
                } else {
                    n
                }
            });
            let mut tangent = Vec3::ZERO;
            if has_uv {
                let (d1, d2) = (mesh.uvs[i1] - mesh.uvs[i0], mesh.uvs[i2] - mesh.uvs[i0]);
                let det = d1.x * d2.y - d1.y * d2.x;
                if det.abs() > 1e-12 {
                    let tt = (e1 * d2.y - e2 * d1.y) / det;
                    if tt.is_finite() {
                        tangent = tt;
                    }
                }
            }
            tris.push([p0, p1, p2]);
            data.push([n[0].x, n[0].y, n[0].z, f32::from_bits(inst.material as u32)]);
            data.push([n[1].x, n[1].y, n[1].z, 0.0]);
            data.push([n[2].x, n[2].y, n[2].z, 0.0]);
            data.push([tangent.x, tangent.y, tangent.z, 0.0]);
            let uv = |i: usize| if has_uv { mesh.uvs[i] } else { glam::Vec2::ZERO };
            let (u0, u1, u2) = (uv(i0), uv(i1), uv(i2));
            data.push([u0.x, u0.y, u1.x, u1.y]);
            data.push([u2.x, u2.y, 0.0, 0.0]);
            no_shadow.push(!casts);
        }
    }
    Ok((tris, data, no_shadow))
}

/// Technique `mc`.
pub struct McTechnique {
    pipeline: Pipeline,
    textures: crate::textures::MaterialTextures,
    /// The renderer's texture array for the frame being declared (see `Technique::add`).
    scene_textures: Option<ImageHandle>,
    repeat: crate::util::Sampler,
    extras: Vec<penumbra_scene::MaterialExtra>,
    pub builder: KdTreeBuilder,
    scene: Scene,
    env: EnvTables,
    /// Samples per pixel per frame (default 4).
    pub spp: u32,
    frame_index: u32,
    /// Samples per pixel accumulated in the image after the last frame.
    pub accumulated: u32,
    tri_count: Option<usize>,
}

impl McTechnique {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary, scene: &Scene) -> Result<Self> {
        use vk::DescriptorType as T;
        let pipeline = compute_pipeline(
            ctx,
            shaders,
            "mc.comp",
            &[
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_BUFFER,
                T::STORAGE_IMAGE,
                T::STORAGE_IMAGE,
                T::STORAGE_BUFFER,
                T::COMBINED_IMAGE_SAMPLER,
            ],
            112,
        )?;
        Ok(McTechnique {
            pipeline,
            textures: crate::textures::MaterialTextures::new(ctx, &scene.textures)?,
            scene_textures: None,
            repeat: crate::util::Sampler::repeat(ctx)?,
            extras: (0..scene.materials.len()).map(|i| scene.material_extra(i)).collect(),
            builder: KdTreeBuilder::new(ctx, shaders)?,
            scene: scene.clone(),
            env: EnvTables::new(scene.environment.as_ref()),
            spp: 4,
            frame_index: 0,
            accumulated: 0,
            tri_count: None,
        })
    }

    /// Copies host data into a persistent buffer when it is new; returns its latest handle.
    pub(crate) fn persistent_upload(
        engine: &mut Engine,
        graph: &mut Graph,
        name: &str,
        data: Vec<u8>,
        force: bool,
    ) -> BufferHandle {
        let size = data.len().max(16) as u64;
        let h = engine.persistent_buffer(graph, name, size);
        if !(force || graph.persistent_is_new(h)) {
            return h;
        }
        crate::util::upload_into(graph, &format!("upload_{name}"), &format!("{name}.upload"), data, h)
    }

    /// Declares the tree (rebuilt when geometry changed) and the `mc` pass; returns the HDR image.
    pub fn add_frame(
        &mut self,
        engine: &mut Engine,
        graph: &mut Graph,
        frame: &Frame,
        width: u32,
        height: u32,
    ) -> Result<ImageHandle> {
        let geometry_changed = frame.any_moved() || frame.any_deformed();
        let kept =
            if geometry_changed || self.tri_count.is_none() { None } else { self.builder.add_kept(engine, graph) };
        // Triangle shading data lives beside the tree (same triangle order).
        let (tree, tridata, rebuilt): (KdTreeHandles, BufferHandle, bool) = match kept {
            Some(t) => {
                let n = self.tri_count.unwrap_or(0);
                let td = engine.persistent_buffer(graph, "mc.tridata", (n as u64 * 96).max(16));
                if graph.persistent_is_new(td) {
                    let (_, data, _) = world_triangles_shading(&self.scene, frame)?;
                    let td = Self::persistent_upload_into(graph, td, bytes_of(&data));
                    (t, td, true)
                } else {
                    (t, td, false)
                }
            }
            None => {
                let (tris, data, no_shadow) = world_triangles_shading(&self.scene, frame)?;
                let t = self.builder.add_triangles_flagged(engine, graph, &tris, Some(&no_shadow), true)?;
                let td = Self::persistent_upload(engine, graph, "mc.tridata", bytes_of(&data), true);
                self.tri_count = Some(tris.len());
                (t, td, true)
            }
        };
        let env_texels = Self::persistent_upload(engine, graph, "mc.env_texels", bytes_of(&self.env.texels), false);
        let env_cdf = Self::persistent_upload(engine, graph, "mc.env_cdf", bytes_of(&self.env.cdf), false);
        let materials =
            graph.create_buffer_init("mc.materials", bytes_of(&material_table(&frame.materials, &self.extras)));
        // Inside the renderer the scene's texture array is already in the graph; standalone
        // (tests, benches) the technique imports its own copy.
        let textures = match self.scene_textures.take() {
            Some(t) => t,
            None => self.textures.add(graph),
        };
        let light_data = light_table(&frame.lights);
        let light_count = (light_data.len() / 4) as u32;
        let lights = graph
            .create_buffer_init("mc.lights", if light_data.is_empty() { vec![0u8; 64] } else { bytes_of(&light_data) });
        let accum = engine.persistent_image(graph, "mc.accum", ImageDesc::new_2d(HDR_FORMAT, width, height));
        let reset = graph.persistent_is_new(accum)
            || rebuilt
            || geometry_changed
            || frame.camera_moved
            || !frame.materials_changed.is_empty()
            || frame.lights.iter().any(|l| l.moved)
            || self.accumulated == 0;
        if reset {
            self.accumulated = 0;
        }
        let hdr = graph.create_image("mc.hdr", ImageDesc::new_2d(HDR_FORMAT, width, height));
        let inv_vp = FrameConstants::new(frame, None, width, height).inv_view_proj;
        let mut push: Vec<u8> = Vec::with_capacity(112);
        for c in inv_vp {
            push.extend(bytes_of(&c));
        }
        push.extend(bytes_of(&[width, height, self.spp, self.frame_index]));
        push.extend(bytes_of(&[
            self.env.width,
            self.env.height,
            reset as u32 | (self.env.can_sample as u32) << 1,
            light_count,
        ]));
        push.extend(bytes_of(&[self.env.cos_rot, self.env.sin_rot, 0.0, 0.0]));
        self.frame_index = self.frame_index.wrapping_add(1);
        self.accumulated += self.spp;

        let mut p = graph.pass("mc", PassKind::Compute);
        let kd = tree.read(&mut p);
        let td = p.read(tridata, Access::ComputeShaderReadStorage);
        let mats = p.read(materials, Access::ComputeShaderReadStorage);
        let et = p.read(env_texels, Access::ComputeShaderReadStorage);
        let ec = p.read(env_cdf, Access::ComputeShaderReadStorage);
        let accum = p.write(accum, Access::ComputeShaderReadWriteStorage);
        let hdr = p.write(hdr, Access::ComputeShaderWriteStorage);
        let lt = p.read(lights, Access::ComputeShaderReadStorage);
        let tex = p.read(textures, Access::ComputeShaderReadSampled);
        let repeat = self.repeat.sampler;
        let pipe = self.pipeline.handle();
        p.record(move |rc| {
            let rest = [
                Bind::StorageBuffer(td),
                Bind::StorageBuffer(mats),
                Bind::StorageBuffer(et),
                Bind::StorageBuffer(ec),
                Bind::StorageImage(accum),
                Bind::StorageImage(hdr),
                Bind::StorageBuffer(lt),
                Bind::SampledImage(tex, repeat),
            ];
            let binds = [kd.binds().as_slice(), &rest].concat();
            crate::util::dispatch(rc, pipe, &binds, &push, [groups(width, 8), groups(height, 8), 1])
        });
        Ok(hdr)
    }

    fn persistent_upload_into(graph: &mut Graph, h: BufferHandle, data: Vec<u8>) -> BufferHandle {
        crate::util::upload_into(graph, "upload_mc.tridata", "mc.tridata.upload", data, h)
    }
}

impl crate::technique::Technique for McTechnique {
    fn samples_per_pixel(&self) -> Option<u32> {
        Some(self.accumulated)
    }

    fn limitations(&self, scene: &Scene) -> Vec<String> {
        let mut anisotropic: Vec<&str> = scene
            .objects
            .iter()
            .filter_map(|o| {
                let m = scene.materials.get(o.material)?;
                let v = scene.material_extra(o.material).shininess_v?;
                (m.kind == BrdfKind::AshikhminShirley && v != m.shininess).then_some(m.name.as_str())
            })
            .collect();
        anisotropic.sort();
        anisotropic.dedup();
        if anisotropic.is_empty() {
            Vec::new()
        } else {
            vec![format!(
                "mc: anisotropic Ashikhmin-Shirley exponents (shininess_v) are rendered isotropic (material {})",
                anisotropic.join(", ")
            )]
        }
    }
    fn name(&self) -> &'static str {
        "mc"
    }
    fn add(
        &mut self,
        engine: &mut Engine,
        graph: &mut Graph,
        inputs: &crate::technique::TechniqueInputs,
    ) -> Result<ImageHandle> {
        self.scene_textures = Some(inputs.scene.textures);
        let r = self.add_frame(engine, graph, inputs.frame, inputs.gbuffer.width, inputs.gbuffer.height);
        self.scene_textures = None;
        r
    }
}

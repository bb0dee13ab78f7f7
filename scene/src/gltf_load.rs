//! glTF 2.0 loading (`.gltf` with embedded or external buffers, `.glb`) through the `gltf`
//! crate: meshes (triangles), node hierarchy, metallic-roughness materials (mapped to
//! [`BrdfKind::CookTorrance`](crate::BrdfKind::CookTorrance)), base-colour and metallic-roughness textures, animations
//! (translation / rotation / scale / morph weights; step and linear, cubic-spline keys use
//! their values linearly), skins and morph targets.
//!
//! Every accessor is checked (type, component type, bounds, finite values) before use, so a
//! malformed file gives a [`SceneError`] naming the file and the problem instead of a panic.
//! Draco-compressed primitives (`KHR_draco_mesh_compression`) are decoded with the pure-Rust
//! `draco-core` decoder (`read_draco_primitive`); any other required extension is refused by
//! name.

use crate::error::SceneError;
use crate::limits::{Budget, Limits};
use crate::motion::{AnimChannel, Animation, Channel, Deformation, Interp, MorphTarget, Rig, Skin, Track};
use crate::texture::{srgb_to_linear, Texture};
use crate::{Light, LightKind, Material, MaterialExtra, MeshData, NodeMotion, Object, ObjectInfo, Scene};
use glam::{Mat4, Quat, Vec2, Vec3};
use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One triangle primitive of the file.
#[derive(Clone, Debug)]
pub struct Primitive {
    pub mesh: MeshData,
    /// Index into [`GltfAsset::materials`].
    pub material: Option<usize>,
    pub joints: Option<Vec<[u16; 4]>>,
    pub weights: Option<Vec<[f32; 4]>>,
    pub targets: Vec<MorphTarget>,
    /// Default morph weights of the glTF mesh.
    pub default_weights: Vec<f32>,
}

/// A primitive placed by a node of the default scene.
#[derive(Clone, Debug)]
pub struct Part {
    pub name: String,
    pub node: usize,
    /// Index into [`GltfAsset::primitives`].
    pub primitive: usize,
    pub skin: Option<usize>,
}

/// A `KHR_lights_punctual` light placed by a node of the default scene.
#[derive(Clone, Debug)]
pub struct AssetLight {
    pub name: String,
    pub node: usize,
    /// Point, spot or directional (cone half-angles in degrees).
    pub kind: LightKind,
    pub color: Vec3,
    /// The file's intensity (candela for point and spot lights, lux for directional ones)
    /// divided by 683 lm/W: W/sr, or W/m^2 for a directional light (see [`LUMENS_PER_WATT`]).
    pub intensity: f32,
}

/// The glTF extensions penumbra reads.
pub const SUPPORTED_EXTENSIONS: &[&str] =
    &["KHR_lights_punctual", "KHR_materials_emissive_strength", "KHR_texture_transform", "KHR_draco_mesh_compression"];

/// A `KHR_texture_transform` of one texture reference: `uv' = T(offset) R(rotation) S(scale) uv`
/// with the extension's matrices (`R = [cos sin; -sin cos]`, counter-clockwise in the image).
/// penumbra bakes a material's transform into the texture coordinates of the primitives that
/// use it, so every technique and the reference see the transformed coordinates alike.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UvTransform {
    pub offset: [f32; 2],
    pub rotation: f32,
    pub scale: [f32; 2],
}

impl UvTransform {
    pub const IDENTITY: UvTransform = UvTransform { offset: [0.0, 0.0], rotation: 0.0, scale: [1.0, 1.0] };

    pub fn apply(&self, uv: Vec2) -> Vec2 {
        let (s, c) = self.rotation.sin_cos();
        let (x, y) = (uv.x * self.scale[0], uv.y * self.scale[1]);
        Vec2::new(c * x + s * y + self.offset[0], -s * x + c * y + self.offset[1])
    }

    /// Reads the extension object of a texture reference (`None`: the reference has none):
    /// the transform and its `texCoord` override, if any. Errors name what is malformed.
    pub fn parse(v: Option<&gltf::json::Value>) -> Result<Option<(UvTransform, Option<u64>)>, String> {
        let Some(v) = v else { return Ok(None) };
        let obj = v.as_object().ok_or("KHR_texture_transform is not an object")?;
        let pair = |key: &str, default: [f32; 2]| -> Result<[f32; 2], String> {
            match obj.get(key) {
                None => Ok(default),
                Some(a) => {
                    let a = a
                        .as_array()
                        .filter(|a| a.len() == 2)
                        .ok_or(format!("KHR_texture_transform {key} is not two numbers"))?;
                    let x: Vec<f32> = a.iter().filter_map(|x| x.as_f64()).map(|x| x as f32).collect();
                    if x.len() != 2 || !x.iter().all(|x| x.is_finite()) {
                        return Err(format!("KHR_texture_transform {key} is not two finite numbers"));
                    }
                    Ok([x[0], x[1]])
                }
            }
        };
        let rotation = match obj.get("rotation") {
            None => 0.0,
            Some(r) => r
                .as_f64()
                .map(|r| r as f32)
                .filter(|r| r.is_finite())
                .ok_or("KHR_texture_transform rotation is not a finite number")?,
        };
        let t = UvTransform { offset: pair("offset", [0.0, 0.0])?, rotation, scale: pair("scale", [1.0, 1.0])? };
        Ok(Some((t, obj.get("texCoord").and_then(|t| t.as_u64()))))
    }
}

/// Photometric glTF light intensities (candela, lux) become the scene's radiometric units
/// (W/sr, W/m^2) divided by this luminous efficacy (the 555 nm maximum, as Blender's exporter
/// converts watts to them).
pub const LUMENS_PER_WATT: f32 = 683.0;

/// A perspective camera placed by a node of the default scene (the first one met).
#[derive(Clone, Debug)]
pub struct AssetCamera {
    pub name: String,
    pub node: usize,
    pub yfov_deg: f32,
    pub znear: f32,
    /// `None`: an infinite projection.
    pub zfar: Option<f32>,
}

/// Everything read from a glTF file.
#[derive(Clone, Debug)]
pub struct GltfAsset {
    pub path: PathBuf,
    pub primitives: Vec<Primitive>,
    pub parts: Vec<Part>,
    pub materials: Vec<Material>,
    pub extras: Vec<MaterialExtra>,
    pub textures: Vec<Texture>,
    /// Node hierarchy, animations and skins (no animation selected).
    pub rig: Rig,
    pub animation_names: Vec<String>,
    /// `KHR_lights_punctual` lights of the default scene.
    pub lights: Vec<AssetLight>,
    /// The default scene's first perspective camera.
    pub camera: Option<AssetCamera>,
    pub warnings: Vec<String>,
}

/// A binary glTF container (`.glb`) of a JSON document's bytes and a binary buffer: the
/// 12-byte header, the JSON chunk padded with spaces and the BIN chunk padded with zeros to 4
/// bytes.
pub fn glb_bytes(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| n.next_multiple_of(4);
    let (jl, bl) = (pad(json.len()), pad(bin.len()));
    let total = 12 + 8 + jl + 8 + bl;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(jl as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(20 + jl, b' ');
    out.extend_from_slice(&(bl as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    out.resize(total, 0);
    out
}

fn gerr(path: &Path, m: impl Into<String>) -> SceneError {
    SceneError::Gltf { path: path.to_path_buf(), message: m.into() }
}

/// Load a `.glb` or `.gltf` file.
pub fn load(path: &Path) -> Result<GltfAsset, SceneError> {
    load_with(path, &Budget::new(Limits::default()))
}

/// [`load`] taking the file, its buffers, images and accessors from `budget` before allocating
/// them.
pub fn load_with(path: &Path, budget: &Budget) -> Result<GltfAsset, SceneError> {
    let bytes = budget.read_data_file(path, "glTF file")?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    // The gltf crate has debug assertions on accessor layouts; everything is checked first,
    // but a panic inside it must still never escape as a crash.
    let p = path.to_path_buf();
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || load_bytes_with(&p, &bytes, &base, budget))) {
        Ok(r) => r,
        Err(_) => Err(gerr(path, "malformed file (the glTF reader failed on inconsistent data)")),
    }
}

/// Load from memory; `base` resolves external URIs, `path` is used in messages.
pub fn load_bytes(path: &Path, bytes: &[u8], base: &Path) -> Result<GltfAsset, SceneError> {
    load_bytes_with(path, bytes, base, &Budget::new(Limits::default()))
}

/// [`load_bytes`] within `budget`.
pub fn load_bytes_with(path: &Path, bytes: &[u8], base: &Path, budget: &Budget) -> Result<GltfAsset, SceneError> {
    if bytes.is_empty() {
        return Err(gerr(path, "file is empty"));
    }
    // Required extensions first, by name (validation would only say "unsupported").
    let raw = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| gerr(path, describe(&e)))?;
    if let Some(ext) = raw.document.extensions_required().find(|e| !SUPPORTED_EXTENSIONS.contains(e)) {
        return Err(SceneError::Unsupported {
            path: path.to_path_buf(),
            feature: format!("glTF extension {ext} (listed in extensionsRequired)"),
        });
    }
    // gltf-json's validation indexes the POSITION accessor without a bounds check.
    {
        use gltf::json::validation::Checked;
        let root = raw.document.as_json();
        for (mi, m) in root.meshes.iter().enumerate() {
            for (pi, p) in m.primitives.iter().enumerate() {
                for (sem, idx) in &p.attributes {
                    if idx.value() >= root.accessors.len() {
                        let name = match sem {
                            Checked::Valid(s) => s.to_string(),
                            Checked::Invalid => "an invalid attribute".into(),
                        };
                        return Err(gerr(
                            path,
                            format!("mesh {mi} primitive {pi}: {name} refers to accessor {} which does not exist ({} accessors)", idx.value(), root.accessors.len()),
                        ));
                    }
                }
            }
        }
        // Images: the gltf crate unwraps a source that is neither a URI nor a buffer view with
        // a MIME type (found by fuzzing).
        for (ii, img) in root.images.iter().enumerate() {
            match (&img.uri, &img.buffer_view) {
                (Some(_), None) => {}
                (None, Some(v)) => {
                    if v.value() >= root.buffer_views.len() {
                        return Err(gerr(
                            path,
                            format!("image {ii} refers to buffer view {} which does not exist", v.value()),
                        ));
                    }
                    if img.mime_type.is_none() {
                        return Err(gerr(path, format!("image {ii} is stored in a buffer view but has no mimeType")));
                    }
                }
                (None, None) => return Err(gerr(path, format!("image {ii} has neither a uri nor a bufferView"))),
                (Some(_), Some(_)) => return Err(gerr(path, format!("image {ii} has both a uri and a bufferView"))),
            }
        }
        // Animation channels index nodes and samplers without checks in the gltf crate.
        for (ai, a) in root.animations.iter().enumerate() {
            for (ci, c) in a.channels.iter().enumerate() {
                if c.target.node.value() >= root.nodes.len() {
                    return Err(gerr(
                        path,
                        format!(
                            "animation {ai} channel {ci} targets node {} which does not exist",
                            c.target.node.value()
                        ),
                    ));
                }
                if matches!(c.target.path, Checked::Invalid) {
                    return Err(gerr(path, format!("animation {ai} channel {ci} has an invalid target path")));
                }
                if c.sampler.value() >= a.samplers.len() {
                    return Err(gerr(
                        path,
                        format!("animation {ai} channel {ci} uses sampler {} which does not exist", c.sampler.value()),
                    ));
                }
            }
            for (si, smp) in a.samplers.iter().enumerate() {
                if matches!(smp.interpolation, Checked::Invalid) {
                    return Err(gerr(path, format!("animation {ai} sampler {si} has an invalid interpolation")));
                }
                for acc in [smp.input.value(), smp.output.value()] {
                    if acc >= root.accessors.len() {
                        return Err(gerr(
                            path,
                            format!("animation {ai} sampler {si} refers to accessor {acc} which does not exist"),
                        ));
                    }
                }
            }
        }
    }
    // The gltf crate's validation, less what it says of Draco primitives (their accessors have
    // no buffer view: the data is in the extension's) and of required extensions penumbra reads
    // itself (the crate knows neither Draco nor, without its feature, texture transforms).
    {
        use gltf::json::validation::{Error as V, Validate};
        let root = raw.document.as_json();
        let mut draco_accessors = std::collections::HashSet::new();
        for p in root.meshes.iter().flat_map(|m| &m.primitives) {
            if p.extensions.as_ref().is_some_and(|e| e.others.contains_key(DRACO)) {
                draco_accessors.extend(p.attributes.values().map(|a| a.value()));
                draco_accessors.extend(p.indices.map(|i| i.value()));
            }
        }
        let mut errors = Vec::new();
        root.validate(root, gltf::json::Path::new, &mut |p, e| errors.push((p(), e)));
        errors.retain(|(p, e)| {
            let p = p.as_str();
            let viewless = matches!(e, V::Missing)
                && p.strip_prefix("accessors[")
                    .and_then(|r| r.strip_suffix("].bufferView"))
                    .and_then(|i| i.parse::<usize>().ok())
                    .is_some_and(|i| draco_accessors.contains(&i));
            let read_by_penumbra = matches!(e, V::Unsupported)
                && p.starts_with("extensionsRequired")
                && SUPPORTED_EXTENSIONS.iter().any(|x| p.contains(&format!("\"{x}\"")));
            !(viewless || read_by_penumbra)
        });
        if !errors.is_empty() {
            return Err(gerr(path, describe(&gltf::Error::Validation(errors))));
        }
    }
    let doc = raw.document;
    let blob = raw.blob;
    // Buffers: check external files exist so the message names them.
    for b in doc.buffers() {
        if let gltf::buffer::Source::Uri(uri) = b.source() {
            check_uri(path, base, uri, &format!("buffer {}", b.index()))?;
        } else if blob.is_none() {
            return Err(gerr(path, format!("buffer {} refers to the GLB binary chunk, which is missing", b.index())));
        }
    }
    // Every declared buffer and every accessor's data against the budget and its buffer view,
    // before any of it is read.
    for b in doc.buffers() {
        budget.take(path, &format!("buffer {}", b.index()), b.length() as u64)?;
    }
    check_accessor_bounds(path, &doc, budget)?;
    let buffers = gltf::import_buffers(&doc, Some(base), blob).map_err(|e| match e {
        gltf::Error::BufferLength { buffer, expected, actual } => {
            gerr(path, format!("buffer {buffer} is truncated: expected {expected} bytes but the data has {actual}"))
        }
        other => gerr(path, format!("cannot load buffers: {}", describe(&other))),
    })?;
    let bufs: Vec<&[u8]> = buffers.iter().map(|d| d.0.as_slice()).collect();
    let get = |b: gltf::Buffer| bufs.get(b.index()).copied();
    let mut warnings = Vec::new();
    let label = path.display().to_string();
    // Extensions the file uses that penumbra reads nothing of (required ones were refused above).
    let ignored: Vec<&str> = doc.extensions_used().filter(|e| !SUPPORTED_EXTENSIONS.contains(e)).collect();
    if !ignored.is_empty() {
        warnings.push(format!(
            "{label}: uses glTF extension{} penumbra ignores: {} (it reads {})",
            if ignored.len() > 1 { "s" } else { "" },
            ignored.join(", "),
            SUPPORTED_EXTENSIONS.join(", ")
        ));
    }

    // Textures and materials.
    let mut textures = Vec::new();
    let mut image_map: HashMap<(usize, bool), usize> = HashMap::new();
    let mut load_image = |img: gltf::Image, srgb: bool, textures: &mut Vec<Texture>| -> Result<usize, SceneError> {
        if let Some(&t) = image_map.get(&(img.index(), srgb)) {
            return Ok(t);
        }
        if let gltf::image::Source::Uri { uri, .. } = img.source() {
            check_uri(path, base, uri, &format!("image {}", img.index()))?;
        }
        let encoded = image_bytes(path, base, &img, &buffers, budget)?;
        let decoded =
            crate::texture::decode_checked(path, &format!("image {}", img.index()), &encoded, None, budget, 20)
                .map_err(|e| match e {
                    SceneError::Image { message, .. } => {
                        gerr(path, format!("image {} cannot be decoded: {message}", img.index()))
                    }
                    e => e,
                })?;
        let data = gltf_data(decoded);
        let name = img.name().map(str::to_string).unwrap_or_else(|| format!("image{}", img.index()));
        let tex = convert_image(&name, &data, srgb).ok_or_else(|| SceneError::Unsupported {
            path: path.to_path_buf(),
            feature: format!("image pixel format {:?} (image {})", data.format, img.index()),
        })?;
        textures.push(tex);
        image_map.insert((img.index(), srgb), textures.len() - 1);
        Ok(textures.len() - 1)
    };
    let mut materials = Vec::new();
    let mut extras = Vec::new();
    for m in doc.materials() {
        let pbr = m.pbr_metallic_roughness();
        let c = pbr.base_color_factor();
        let base_rgb = Vec3::new(c[0], c[1], c[2]);
        let metallic = pbr.metallic_factor().clamp(0.0, 1.0);
        let roughness = pbr.roughness_factor().clamp(0.0, 1.0);
        let name = m.name().map(str::to_string).unwrap_or_else(|| format!("material{}", m.index().unwrap_or(0)));
        if !base_rgb.is_finite() || !metallic.is_finite() || !roughness.is_finite() {
            return Err(gerr(path, format!("material '{name}' has non-finite factors")));
        }
        let mut mat =
            Material::glossy(&name, base_rgb * (1.0 - metallic), Vec3::splat(0.04).lerp(base_rgb, metallic), roughness);
        mat.name = name.clone();
        let mut ex = MaterialExtra { two_sided: m.double_sided(), ..Default::default() };
        // KHR_texture_transform of each texture reference the material model reads
        const TT: &str = "KHR_texture_transform";
        let mut uv_refs: Vec<(&str, Option<(UvTransform, Option<u64>)>)> = Vec::new();
        let parse_tt = |what: &'static str, v: Option<&gltf::json::Value>| {
            UvTransform::parse(v)
                .map(|t| (what, t))
                .map_err(|e| gerr(path, format!("material '{name}': {what} texture: {e}")))
        };
        if let Some(info) = pbr.base_color_texture() {
            uv_refs.push(parse_tt("base colour", info.extension_value(TT))?);
            if info.tex_coord() != 0 {
                warnings.push(format!(
                    "{label}: material '{name}': base colour uses TEXCOORD_{}, reading TEXCOORD_0",
                    info.tex_coord()
                ));
            }
            ex.albedo_map = Some(load_image(info.texture().source(), true, &mut textures)?);
            // The texture carries the colour: the factor multiplies it.
            mat.albedo = base_rgb * (1.0 - metallic);
        }
        if let Some(info) = pbr.metallic_roughness_texture() {
            uv_refs.push(parse_tt("metallic-roughness", info.extension_value(TT))?);
            ex.roughness_map = Some(load_image(info.texture().source(), false, &mut textures)?);
        }
        // Emission: the factor times KHR_materials_emissive_strength, times the texture (sRGB).
        let strength = m.emissive_strength().unwrap_or(1.0);
        let emission = Vec3::from_array(m.emissive_factor()) * strength;
        if !emission.is_finite() || emission.min_element() < 0.0 {
            return Err(gerr(path, format!("material '{name}' has a non-finite or negative emission")));
        }
        ex.emission = emission;
        if let Some(info) = m.emissive_texture() {
            if emission != Vec3::ZERO {
                uv_refs.push(parse_tt("emissive", info.extension_value(TT))?);
                ex.emission_map = Some(load_image(info.texture().source(), true, &mut textures)?);
            }
        }
        if let Some(nt) = m.normal_texture() {
            if nt.tex_coord() != 0 {
                warnings.push(format!(
                    "{label}: material '{name}': normal map uses TEXCOORD_{}, reading TEXCOORD_0",
                    nt.tex_coord()
                ));
            }
            let scale = nt.scale();
            if !scale.is_finite() {
                return Err(gerr(path, format!("material '{name}': normal map scale is not finite")));
            }
            uv_refs.push(parse_tt("normal", nt.extension_value(TT))?);
            ex.normal_map = Some(load_image(nt.texture().source(), false, &mut textures)?);
            ex.normal_scale = scale;
        }
        // One transform per material, baked into the texture coordinates of its primitives below:
        // the first texture's, said when another texture of the material differs.
        let first = uv_refs.first().map(|(what, t)| (*what, t.map_or(UvTransform::IDENTITY, |t| t.0)));
        if let Some((what, t0)) = first {
            if let Some((other, _)) = uv_refs.iter().find(|(_, t)| t.map_or(UvTransform::IDENTITY, |t| t.0) != t0) {
                warnings.push(format!(
                    "{label}: material '{name}': its {other} texture has another {TT} than its {what} texture; penumbra applies the {what} texture's to all of them"
                ));
            }
            for (w, t) in &uv_refs {
                if let Some((_, Some(k))) = t {
                    if *k != 0 {
                        warnings.push(format!(
                            "{label}: material '{name}': {w} texture's {TT} selects TEXCOORD_{k}, reading TEXCOORD_0"
                        ));
                    }
                }
            }
        }
        ex.uv_transform = first.map(|f| f.1).filter(|t| *t != UvTransform::IDENTITY);
        // What the material model has no place for yet, said once per material.
        let mut ignored: Vec<String> = Vec::new();
        if m.occlusion_texture().is_some() {
            ignored.push("its occlusion map (the techniques compute visibility themselves)".into());
        }
        if m.alpha_mode() != gltf::material::AlphaMode::Opaque {
            ignored.push(format!("alpha mode {:?} (rendered opaque)", m.alpha_mode()));
        }
        if !ignored.is_empty() {
            warnings.push(format!("{label}: material '{name}': penumbra ignores {}", ignored.join(", ")));
        }
        materials.push(mat);
        extras.push(ex);
    }

    // Primitives.
    let mut primitives = Vec::new();
    let mut prim_index: HashMap<(usize, usize), usize> = HashMap::new();
    for mesh in doc.meshes() {
        let mesh_name = mesh.name().map(str::to_string).unwrap_or_else(|| format!("mesh{}", mesh.index()));
        let default_weights = mesh.weights().map(|w| w.to_vec()).unwrap_or_default();
        if default_weights.iter().any(|w| !w.is_finite()) {
            return Err(gerr(path, format!("mesh '{mesh_name}' has non-finite (NaN/Inf) morph weights")));
        }
        for prim in mesh.primitives() {
            let pname =
                if mesh.primitives().len() > 1 { format!("{mesh_name}.{}", prim.index()) } else { mesh_name.clone() };
            if prim.mode() != Mode::Triangles {
                warnings.push(format!(
                    "{label}: mesh '{pname}': primitive mode {:?} is not triangles, skipped",
                    prim.mode()
                ));
                continue;
            }
            let p = match prim.extension_value(DRACO) {
                Some(ext) => read_draco_primitive(
                    path,
                    &label,
                    &pname,
                    &doc,
                    &prim,
                    ext,
                    &get,
                    default_weights.clone(),
                    &mut warnings,
                )?,
                None => read_primitive(path, &label, &pname, &prim, &get, default_weights.clone(), &mut warnings)?,
            };
            prim_index.insert((mesh.index(), prim.index()), primitives.len());
            primitives.push(p);
        }
    }

    // KHR_texture_transform: each primitive's texture coordinates through its material's transform.
    for p in &mut primitives {
        if let Some(t) = p.material.and_then(|m| extras.get(m).and_then(|x: &MaterialExtra| x.uv_transform)) {
            for uv in &mut p.mesh.uvs {
                *uv = t.apply(*uv);
            }
        }
    }

    // Nodes.
    let n_nodes = doc.nodes().len();
    let mut parent = vec![None; n_nodes];
    let mut rest = Vec::with_capacity(n_nodes);
    for node in doc.nodes() {
        for ch in node.children() {
            if parent[ch.index()].is_some() || ch.index() == node.index() {
                return Err(gerr(path, format!("node {} has more than one parent (not a tree)", ch.index())));
            }
            parent[ch.index()] = Some(node.index());
        }
        let (t, r, s) = node.transform().decomposed();
        let (t, r, s) = (Vec3::from_array(t), Quat::from_array(r), Vec3::from_array(s));
        if !t.is_finite() || !r.is_finite() || !s.is_finite() {
            return Err(gerr(path, format!("node {} has a non-finite (NaN/Inf) transform", node.index())));
        }
        rest.push((t, norm_quat(r), s));
    }
    // Cycles: walk up from each node.
    for n in 0..n_nodes {
        let (mut k, mut steps) = (n, 0);
        while let Some(p) = parent[k] {
            k = p;
            steps += 1;
            if steps > n_nodes {
                return Err(gerr(path, format!("node {n} is part of a cycle in the node hierarchy")));
            }
        }
    }

    // Skins.
    let mut skins = Vec::new();
    for skin in doc.skins() {
        let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
        let ibm = match skin.inverse_bind_matrices() {
            Some(acc) => {
                check_accessor(path, &acc, &[Dimensions::Mat4], &[DataType::F32], "inverse bind matrices")?;
                let r = skin.reader(get);
                let v: Vec<Mat4> = r
                    .read_inverse_bind_matrices()
                    .ok_or_else(|| out_of_bounds(path, &acc, "inverse bind matrices"))?
                    .map(|m| Mat4::from_cols_array_2d(&m))
                    .collect();
                if v.len() < joints.len() {
                    return Err(gerr(
                        path,
                        format!(
                            "skin {} has {} joints but {} inverse bind matrices",
                            skin.index(),
                            joints.len(),
                            v.len()
                        ),
                    ));
                }
                if v.iter().any(|m| !m.is_finite()) {
                    return Err(gerr(path, format!("skin {} has a non-finite inverse bind matrix", skin.index())));
                }
                v
            }
            None => vec![Mat4::IDENTITY; joints.len()],
        };
        skins.push(Skin { joints, inverse_bind: ibm });
    }

    // Animations.
    let mut animations = Vec::new();
    let mut animation_names = Vec::new();
    for anim in doc.animations() {
        let name = anim.name().map(str::to_string).unwrap_or_else(|| format!("animation{}", anim.index()));
        let mut channels = Vec::new();
        let mut duration: f32 = 0.0;
        for ch in anim.channels() {
            let what = format!("animation '{name}' channel {}", ch.index());
            let sampler = ch.sampler();
            check_accessor(path, &sampler.input(), &[Dimensions::Scalar], &[DataType::F32], &format!("{what} times"))?;
            let out = sampler.output();
            let reader = ch.reader(get);
            let times: Vec<f32> =
                reader.read_inputs().ok_or_else(|| out_of_bounds(path, &sampler.input(), &what))?.collect();
            let cubic = sampler.interpolation() == gltf::animation::Interpolation::CubicSpline;
            if cubic {
                warnings.push(format!("{label}: {what}: cubic-spline keys are interpolated linearly"));
            }
            let interp = if sampler.interpolation() == gltf::animation::Interpolation::Step {
                Interp::Step
            } else {
                Interp::Linear
            };
            let node = ch.target().node().index();
            use gltf::animation::util::ReadOutputs;
            let norm = [DataType::F32, DataType::I8, DataType::U8, DataType::I16, DataType::U16];
            match ch.target().property() {
                gltf::animation::Property::Translation | gltf::animation::Property::Scale => {
                    check_accessor(path, &out, &[Dimensions::Vec3], &[DataType::F32], &what)?
                }
                gltf::animation::Property::Rotation => check_accessor(path, &out, &[Dimensions::Vec4], &norm, &what)?,
                gltf::animation::Property::MorphTargetWeights => {
                    check_accessor(path, &out, &[Dimensions::Scalar], &norm, &what)?
                }
            }
            let outs = reader.read_outputs().ok_or_else(|| out_of_bounds(path, &out, &what))?;
            let bad = |m: String| gerr(path, format!("{what}: {m}"));
            let target = match outs {
                ReadOutputs::Translations(it) => {
                    let v: Vec<Vec3> = pick_values(it.map(Vec3::from_array).collect(), cubic);
                    if v.iter().any(|x| !x.is_finite()) {
                        return Err(bad("non-finite (NaN/Inf) translation".into()));
                    }
                    Channel::Translation(Track::new(times.clone(), v, interp, false).map_err(bad)?)
                }
                ReadOutputs::Scales(it) => {
                    let v: Vec<Vec3> = pick_values(it.map(Vec3::from_array).collect(), cubic);
                    if v.iter().any(|x| !x.is_finite()) {
                        return Err(bad("non-finite (NaN/Inf) scale".into()));
                    }
                    Channel::Scale(Track::new(times.clone(), v, interp, false).map_err(bad)?)
                }
                ReadOutputs::Rotations(it) => {
                    let v: Vec<Quat> = pick_values(it.into_f32().map(Quat::from_array).collect(), cubic);
                    if v.iter().any(|x| !x.is_finite()) {
                        return Err(bad("non-finite (NaN/Inf) rotation".into()));
                    }
                    let v = v.into_iter().map(norm_quat).collect();
                    Channel::Rotation(Track::new(times.clone(), v, interp, false).map_err(bad)?)
                }
                ReadOutputs::MorphTargetWeights(it) => {
                    let flat: Vec<f32> = it.into_f32().collect();
                    if flat.iter().any(|x| !x.is_finite()) {
                        return Err(bad("non-finite (NaN/Inf) morph weight".into()));
                    }
                    let per = if times.is_empty() { 0 } else { flat.len() / times.len() };
                    let per = if cubic { per / 3 } else { per };
                    if per == 0 {
                        return Err(bad("no morph weights".into()));
                    }
                    let chunks: Vec<Vec<f32>> = flat.chunks(per).map(|c| c.to_vec()).collect();
                    let chunks = pick_values(chunks, cubic);
                    Channel::Weights(Track::new(times.clone(), chunks, interp, false).map_err(bad)?)
                }
            };
            duration = duration.max(times.last().copied().unwrap_or(0.0));
            channels.push(AnimChannel { node, target });
        }
        animations.push(Animation { name: name.clone(), channels, duration });
        animation_names.push(name);
    }

    // Parts: primitives placed by the nodes of the default (or first) scene.
    let roots: Vec<usize> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().map(|n| n.index()).collect(),
        None => (0..n_nodes).filter(|&n| parent[n].is_none()).collect(),
    };
    let mut parts = Vec::new();
    let mut stack: Vec<usize> = roots.into_iter().rev().collect();
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    let mut visited = vec![false; n_nodes];
    let json = doc.as_json();
    let light_defs: &[gltf::json::extensions::scene::khr_lights_punctual::Light] =
        json.extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref()).map_or(&[], |k| k.lights.as_slice());
    let mut lights = Vec::new();
    let mut camera = None;
    while let Some(n) = stack.pop() {
        if std::mem::replace(&mut visited[n], true) {
            continue;
        }
        let node = &nodes[n];
        if let Some(li) =
            json.nodes[n].extensions.as_ref().and_then(|e| e.khr_lights_punctual.as_ref()).map(|k| k.light.value())
        {
            let def = light_defs.get(li).ok_or_else(|| {
                gerr(
                    path,
                    format!(
                        "node {n} uses KHR_lights_punctual light {li} which does not exist ({} lights)",
                        light_defs.len()
                    ),
                )
            })?;
            lights.push(asset_light(path, &label, n, li, def, &mut warnings)?);
        }
        if let Some(cam) = node.camera() {
            let cname = cam.name().map(str::to_string).unwrap_or_else(|| format!("camera{}", cam.index()));
            match cam.projection() {
                gltf::camera::Projection::Perspective(p) if camera.is_none() => {
                    let (yfov, znear, zfar) = (p.yfov(), p.znear(), p.zfar());
                    let fov = yfov.to_degrees();
                    if !(fov > 0.0 && fov < 180.0 && znear > 0.0 && znear.is_finite()) {
                        return Err(gerr(path, format!("camera '{cname}': yfov must be in (0, pi) and znear > 0")));
                    }
                    if let Some(f) = zfar.filter(|&f| !(f > znear && f.is_finite())) {
                        return Err(gerr(
                            path,
                            format!("camera '{cname}': zfar {f} must be finite and > znear {znear}"),
                        ));
                    }
                    camera = Some(AssetCamera { name: cname, node: n, yfov_deg: fov, znear, zfar });
                }
                gltf::camera::Projection::Perspective(_) => warnings.push(format!(
                    "{label}: camera '{cname}' ignored (the first perspective camera of the scene is used)"
                )),
                gltf::camera::Projection::Orthographic(_) => warnings.push(format!(
                    "{label}: camera '{cname}' is orthographic, which penumbra does not render: ignored"
                )),
            }
        }
        if let Some(mesh) = node.mesh() {
            for prim in mesh.primitives() {
                if let Some(&pi) = prim_index.get(&(mesh.index(), prim.index())) {
                    let skin = node.skin().map(|s| s.index());
                    if let (Some(s), Some(j)) = (skin, &primitives[pi].joints) {
                        let nj = skins[s].joints.len();
                        if let Some(bad) = j.iter().flatten().find(|&&x| x as usize >= nj) {
                            return Err(gerr(
                                path,
                                format!(
                                    "mesh '{}': joint index {bad} is out of range (skin {s} has {nj} joints)",
                                    primitives[pi].mesh.name
                                ),
                            ));
                        }
                    }
                    let name = node.name().map(str::to_string).unwrap_or_else(|| primitives[pi].mesh.name.clone());
                    parts.push(Part { name, node: n, primitive: pi, skin });
                }
            }
        }
        for ch in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push(ch.index());
        }
    }
    if parts.is_empty() {
        return Err(SceneError::invalid(path, "empty scene: the glTF file has no triangle meshes in its scene"));
    }
    let rig = Rig { parent, rest, animations, skins, animation: None };
    rig.check_finite().map_err(|m| gerr(path, m))?;
    Ok(GltfAsset {
        path: path.to_path_buf(),
        primitives,
        parts,
        materials,
        extras,
        textures,
        rig,
        animation_names,
        lights,
        camera,
        warnings,
    })
}

/// A `KHR_lights_punctual` light definition `li`, placed by node `n`.
fn asset_light(
    path: &Path,
    label: &str,
    n: usize,
    li: usize,
    def: &gltf::json::extensions::scene::khr_lights_punctual::Light,
    warnings: &mut Vec<String>,
) -> Result<AssetLight, SceneError> {
    use gltf::json::extensions::scene::khr_lights_punctual::Type;
    use gltf::json::validation::Checked;
    let name = def.name.clone().unwrap_or_else(|| format!("light{li}"));
    let color = Vec3::from_array(def.color);
    if !color.is_finite() || color.min_element() < 0.0 || !def.intensity.is_finite() || def.intensity < 0.0 {
        return Err(gerr(path, format!("light '{name}': color and intensity must be finite and >= 0")));
    }
    let kind = match &def.type_ {
        Checked::Valid(Type::Point) => LightKind::Point,
        Checked::Valid(Type::Directional) => LightKind::Directional,
        Checked::Valid(Type::Spot) => {
            let (inner, outer) = def
                .spot
                .as_ref()
                .map_or((0.0, std::f32::consts::FRAC_PI_4), |s| (s.inner_cone_angle, s.outer_cone_angle));
            let (inner, outer) = (inner.to_degrees(), outer.to_degrees());
            if !(inner >= 0.0 && inner < outer && outer <= 90.0) {
                return Err(gerr(
                    path,
                    format!("light '{name}': spot cone angles need 0 <= inner < outer <= pi/2, got {inner} and {outer} degrees"),
                ));
            }
            // the scene's spot lights need outer < 90 degrees
            LightKind::Spot { inner_deg: inner.min(89.0), outer_deg: outer.min(89.5) }
        }
        Checked::Invalid => {
            return Err(gerr(path, format!("light '{name}': invalid type (expected point, spot or directional)")))
        }
    };
    if def.range.is_some() {
        warnings.push(format!(
            "{label}: light '{name}': `range` ignored (penumbra's lights fall off with the inverse square everywhere)"
        ));
    }
    Ok(AssetLight { name, node: n, kind, color, intensity: def.intensity / LUMENS_PER_WATT })
}

fn norm_quat(q: Quat) -> Quat {
    let l = q.length();
    if l.is_finite() && l > 1e-8 {
        q / l
    } else {
        Quat::IDENTITY
    }
}

/// Cubic-spline outputs are (in-tangent, value, out-tangent) triples: keep the values.
fn pick_values<T: Clone>(v: Vec<T>, cubic: bool) -> Vec<T> {
    if cubic {
        v.chunks(3).filter_map(|c| c.get(1).cloned()).collect()
    } else {
        v
    }
}

/// A readable message for a gltf crate error.
fn describe(e: &gltf::Error) -> String {
    match e {
        gltf::Error::Binary(b) => format!("malformed or truncated GLB container: {b:?}"),
        gltf::Error::Deserialize(d) => format!("malformed JSON: {d}"),
        gltf::Error::Io(io) => format!("I/O error: {io}"),
        other => other.to_string(),
    }
}

fn check_uri(path: &Path, base: &Path, uri: &str, what: &str) -> Result<(), SceneError> {
    if uri.starts_with("data:") {
        return Ok(());
    }
    if uri.contains("://") {
        return Err(SceneError::Unsupported {
            path: path.to_path_buf(),
            feature: format!("URI scheme in {what}: {uri}"),
        });
    }
    let decoded = percent_decode(uri);
    let file = base.join(&decoded);
    if !file.is_file() {
        return Err(gerr(path, format!("{what} references missing file '{decoded}' ({})", file.display())));
    }
    Ok(())
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let Some(v) = std::str::from_utf8(&b[i + 1..i + 3]).ok().and_then(|h| u8::from_str_radix(h, 16).ok()) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Every accessor's elements fit its buffer view (and the view its buffer), a sparse accessor's
/// entries fit theirs, and what reading them allocates fits the budget: counts are checked
/// before the gltf crate allocates by them.
fn check_accessor_bounds(path: &Path, doc: &gltf::Document, budget: &Budget) -> Result<(), SceneError> {
    let fits =
        |what: &str, view: &gltf::buffer::View, offset: usize, count: usize, size: usize| -> Result<(), SceneError> {
            let stride = view.stride().unwrap_or(size).max(size) as u128;
            let need = if count == 0 { 0 } else { offset as u128 + stride * (count as u128 - 1) + size as u128 };
            if need > view.length() as u128 {
                return Err(gerr(
                    path,
                    format!(
                        "{what}: {count} elements of {size} bytes need {need} bytes of buffer view {}, which holds {}",
                        view.index(),
                        view.length()
                    ),
                ));
            }
            if view.offset() as u128 + view.length() as u128 > view.buffer().length() as u128 {
                return Err(gerr(
                    path,
                    format!(
                        "buffer view {} ends at byte {} of buffer {}, which holds {}",
                        view.index(),
                        view.offset() + view.length(),
                        view.buffer().index(),
                        view.buffer().length()
                    ),
                ));
            }
            Ok(())
        };
    for acc in doc.accessors() {
        let what = format!("accessor {}", acc.index());
        if let Some(view) = acc.view() {
            fits(&what, &view, acc.offset(), acc.count(), acc.size())?;
        }
        if let Some(sp) = acc.sparse() {
            if sp.count() > acc.count() {
                return Err(gerr(path, format!("{what}: {} sparse entries for {} elements", sp.count(), acc.count())));
            }
            let isize = match sp.indices().index_type() {
                gltf::accessor::sparse::IndexType::U8 => 1,
                gltf::accessor::sparse::IndexType::U16 => 2,
                gltf::accessor::sparse::IndexType::U32 => 4,
            };
            fits(&format!("{what} sparse indices"), &sp.indices().view(), sp.indices().offset(), sp.count(), isize)?;
            fits(&format!("{what} sparse values"), &sp.values().view(), sp.values().offset(), sp.count(), acc.size())?;
        }
        // Read as f32 (or u32) elements, then converted once: twice the f32 size.
        let dims = acc.dimensions().multiplicity() as u64;
        budget.take(
            path,
            &format!("{what} ({} elements)", acc.count()),
            (acc.count() as u64).saturating_mul(dims * 4 * 2),
        )?;
    }
    Ok(())
}

/// The encoded bytes of an image: its buffer view, its data URI or its file.
fn image_bytes(
    path: &Path,
    base: &Path,
    img: &gltf::Image,
    buffers: &[gltf::buffer::Data],
    budget: &Budget,
) -> Result<Vec<u8>, SceneError> {
    let what = format!("image {}", img.index());
    match img.source() {
        gltf::image::Source::View { view, .. } => {
            let buf = buffers
                .get(view.buffer().index())
                .ok_or_else(|| gerr(path, format!("{what}: buffer {} is missing", view.buffer().index())))?;
            buf.0
                .get(view.offset()..view.offset().saturating_add(view.length()))
                .map(<[u8]>::to_vec)
                .ok_or_else(|| gerr(path, format!("{what}: buffer view {} lies outside its buffer", view.index())))
        }
        gltf::image::Source::Uri { uri, .. } => {
            if let Some(rest) = uri.strip_prefix("data:") {
                let (_, payload) =
                    rest.split_once(";base64,").ok_or_else(|| gerr(path, format!("{what}: data URI is not base64")))?;
                budget.take(path, &format!("{what} (data URI)"), payload.len() as u64)?;
                use base64::Engine as _;
                base64::engine::general_purpose::STANDARD
                    .decode(payload)
                    .map_err(|e| gerr(path, format!("{what}: data URI is not valid base64: {e}")))
            } else {
                budget.read_data_file(&base.join(percent_decode(uri)), &format!("{what} file"))
            }
        }
    }
}

/// A decoded image in the gltf crate's layout (what [`convert_image`] reads).
fn gltf_data(img: image::DynamicImage) -> gltf::image::Data {
    use gltf::image::Format as F;
    use image::DynamicImage as D;
    let (width, height) = (img.width(), img.height());
    let le16 = |v: Vec<u16>| v.into_iter().flat_map(u16::to_le_bytes).collect::<Vec<u8>>();
    let le32 = |v: Vec<f32>| v.into_iter().flat_map(f32::to_le_bytes).collect::<Vec<u8>>();
    let (format, pixels) = match img {
        D::ImageLuma8(i) => (F::R8, i.into_raw()),
        D::ImageLumaA8(i) => (F::R8G8, i.into_raw()),
        D::ImageRgb8(i) => (F::R8G8B8, i.into_raw()),
        D::ImageRgba8(i) => (F::R8G8B8A8, i.into_raw()),
        D::ImageLuma16(i) => (F::R16, le16(i.into_raw())),
        D::ImageLumaA16(i) => (F::R16G16, le16(i.into_raw())),
        D::ImageRgb16(i) => (F::R16G16B16, le16(i.into_raw())),
        D::ImageRgba16(i) => (F::R16G16B16A16, le16(i.into_raw())),
        D::ImageRgb32F(i) => (F::R32G32B32FLOAT, le32(i.into_raw())),
        D::ImageRgba32F(i) => (F::R32G32B32A32FLOAT, le32(i.into_raw())),
        other => (F::R8G8B8A8, other.to_rgba8().into_raw()),
    };
    gltf::image::Data { pixels, format, width, height }
}

fn out_of_bounds(path: &Path, acc: &gltf::Accessor, what: &str) -> SceneError {
    gerr(path, format!("{what}: accessor {} lies outside its buffer (truncated data?)", acc.index()))
}

/// Check an accessor's element type and count (a Draco primitive's accessors have no data of
/// their own: [`check_accessor`] adds the layout checks for those that do).
fn check_accessor_type(
    path: &Path,
    acc: &gltf::Accessor,
    dims: &[Dimensions],
    types: &[DataType],
    what: &str,
) -> Result<(), SceneError> {
    if !dims.contains(&acc.dimensions()) || !types.contains(&acc.data_type()) {
        return Err(gerr(
            path,
            format!(
                "{what}: accessor {} has type {:?} {:?}, expected one of {:?} {:?}",
                acc.index(),
                acc.dimensions(),
                acc.data_type(),
                dims,
                types
            ),
        ));
    }
    if acc.count() == 0 {
        return Err(gerr(path, format!("{what}: accessor {} is empty", acc.index())));
    }
    Ok(())
}

/// Check an accessor's element type and layout so reading it cannot hit the gltf crate's
/// assertions.
fn check_accessor(
    path: &Path,
    acc: &gltf::Accessor,
    dims: &[Dimensions],
    types: &[DataType],
    what: &str,
) -> Result<(), SceneError> {
    check_accessor_type(path, acc, dims, types, what)?;
    if let Some(view) = acc.view() {
        if let Some(stride) = view.stride() {
            if stride < acc.size() {
                return Err(gerr(
                    path,
                    format!(
                        "{what}: buffer view {} stride {stride} is smaller than an element ({} bytes)",
                        view.index(),
                        acc.size()
                    ),
                ));
            }
        }
    } else if acc.sparse().is_none() {
        return Err(gerr(path, format!("{what}: accessor {} has no buffer view", acc.index())));
    }
    if let Some(sp) = acc.sparse() {
        if sp.count() == 0 {
            return Err(gerr(path, format!("{what}: sparse accessor {} has no entries", acc.index())));
        }
    }
    Ok(())
}

/// Component types a normalized float attribute may be stored as.
const NORMALIZED_TYPES: &[DataType] = &[DataType::F32, DataType::U8, DataType::U16];
/// Component types of triangle indices.
const INDEX_TYPES: &[DataType] = &[DataType::U8, DataType::U16, DataType::U32];

/// The per-vertex attributes penumbra reads besides POSITION (F32 VEC3): semantic, name in the
/// file, element type and the component types accepted (uncompressed and Draco primitives alike).
fn vertex_attributes() -> [(gltf::Semantic, &'static str, Dimensions, &'static [DataType]); 4] {
    use gltf::Semantic;
    [
        (Semantic::Normals, "NORMAL", Dimensions::Vec3, &[DataType::F32]),
        (Semantic::TexCoords(0), "TEXCOORD_0", Dimensions::Vec2, NORMALIZED_TYPES),
        (Semantic::Joints(0), "JOINTS_0", Dimensions::Vec4, &[DataType::U8, DataType::U16]),
        (Semantic::Weights(0), "WEIGHTS_0", Dimensions::Vec4, NORMALIZED_TYPES),
    ]
}

fn read_primitive<'a, 's, F>(
    path: &Path,
    label: &str,
    name: &str,
    prim: &'a gltf::Primitive<'a>,
    get: &F,
    default_weights: Vec<f32>,
    warnings: &mut Vec<String>,
) -> Result<Primitive, SceneError>
where
    F: Clone + Fn(gltf::Buffer<'a>) -> Option<&'s [u8]>,
{
    use gltf::Semantic;
    let what = |s: &str| format!("mesh '{name}' {s}");
    let pos_acc = prim.get(&Semantic::Positions).ok_or_else(|| gerr(path, what("has no POSITION attribute")))?;
    check_accessor(path, &pos_acc, &[Dimensions::Vec3], &[DataType::F32], &what("POSITION"))?;
    let n = pos_acc.count();
    for (sem, _, dims, types) in vertex_attributes() {
        if let Some(acc) = prim.get(&sem) {
            check_accessor(path, &acc, &[dims], types, &what(&format!("{sem:?}")))?;
            if acc.count() != n {
                return Err(gerr(path, what(&format!("{sem:?} has {} elements for {n} vertices", acc.count()))));
            }
        }
    }
    if let Some(acc) = prim.indices() {
        check_accessor(path, &acc, &[Dimensions::Scalar], INDEX_TYPES, &what("indices"))?;
    }
    for (k, t) in prim.morph_targets().enumerate() {
        for (acc, s) in [(t.positions(), "POSITION"), (t.normals(), "NORMAL"), (t.tangents(), "TANGENT")] {
            if let Some(acc) = acc {
                check_accessor(
                    path,
                    &acc,
                    &[Dimensions::Vec3],
                    &[DataType::F32],
                    &what(&format!("morph target {k} {s}")),
                )?;
                if acc.count() != n {
                    return Err(gerr(
                        path,
                        what(&format!("morph target {k} {s} has {} elements for {n} vertices", acc.count())),
                    ));
                }
            }
        }
    }
    let r = prim.reader(get.clone());
    let positions: Vec<Vec3> = r
        .read_positions()
        .ok_or_else(|| out_of_bounds(path, &pos_acc, &what("POSITION")))?
        .map(Vec3::from_array)
        .collect();
    let normals: Vec<Vec3> = match r.read_normals() {
        Some(it) => it.map(Vec3::from_array).collect(),
        None if prim.get(&Semantic::Normals).is_some() => {
            return Err(out_of_bounds(path, &prim.get(&Semantic::Normals).unwrap(), &what("NORMAL")))
        }
        None => Vec::new(),
    };
    let uvs: Vec<Vec2> = match r.read_tex_coords(0) {
        Some(it) => it.into_f32().map(Vec2::from_array).collect(),
        None if prim.get(&Semantic::TexCoords(0)).is_some() => {
            return Err(gerr(path, what("TEXCOORD_0 lies outside its buffer")))
        }
        None => Vec::new(),
    };
    let indices: Vec<u32> = match r.read_indices() {
        Some(it) => it.into_u32().collect(),
        None if prim.indices().is_some() => {
            return Err(out_of_bounds(path, &prim.indices().unwrap(), &what("indices")))
        }
        None => (0..n as u32).collect(),
    };
    let joints = match r.read_joints(0) {
        Some(it) => Some(it.into_u16().collect::<Vec<_>>()),
        None if prim.get(&Semantic::Joints(0)).is_some() => {
            return Err(gerr(path, what("JOINTS_0 lies outside its buffer")))
        }
        None => None,
    };
    let weights = match r.read_weights(0) {
        Some(it) => Some(it.into_f32().collect::<Vec<_>>()),
        None if prim.get(&Semantic::Weights(0)).is_some() => {
            return Err(gerr(path, what("WEIGHTS_0 lies outside its buffer")))
        }
        None => None,
    };
    if joints.is_some() != weights.is_some() {
        return Err(gerr(path, what("has JOINTS_0 without WEIGHTS_0 or the reverse")));
    }
    if let Some(w) = &weights {
        if w.iter().flatten().any(|x| !x.is_finite()) {
            return Err(gerr(path, what("has non-finite (NaN/Inf) skin weights")));
        }
    }
    let mut targets = Vec::new();
    for (k, (p, nrm, _)) in r.read_morph_targets().enumerate() {
        let positions: Vec<Vec3> =
            p.map(|it| it.map(Vec3::from_array).collect()).unwrap_or_else(|| vec![Vec3::ZERO; n]);
        let normals: Option<Vec<Vec3>> = nrm.map(|it| it.map(Vec3::from_array).collect());
        if positions.len() != n || normals.as_ref().is_some_and(|v| v.len() != n) {
            return Err(gerr(path, what(&format!("morph target {k} lies outside its buffer"))));
        }
        if positions.iter().chain(normals.iter().flatten()).any(|v| !v.is_finite()) {
            return Err(gerr(path, what(&format!("morph target {k} has non-finite (NaN/Inf) values"))));
        }
        targets.push(MorphTarget { positions, normals });
    }
    let mut mesh = MeshData { name: name.to_string(), positions, normals, uvs, indices };
    // The repair may drop triangles but never vertices, so per-vertex data stays aligned.
    mesh.validate_and_repair(label, warnings).map_err(|m| SceneError::invalid(path, m))?;
    Ok(Primitive { mesh, material: prim.material().index(), joints, weights, targets, default_weights })
}

/// The extension of Draco-compressed primitives.
const DRACO: &str = "KHR_draco_mesh_compression";

/// A primitive stored as `KHR_draco_mesh_compression` data: its buffer view decoded by the
/// pure-Rust `draco-core` decoder, the glTF attributes read from the Draco attributes the
/// extension maps them to (POSITION, NORMAL, TEXCOORD_0, JOINTS_0, WEIGHTS_0; others ignored as
/// in uncompressed primitives), the Draco faces as the indices. The decode is bounded by the
/// counts the primitive's accessors declare (taken from the scene's memory budget with every
/// accessor): at most twice the declared vertices and triangles. Morph targets on a Draco
/// primitive are refused by name.
#[allow(clippy::too_many_arguments)]
fn read_draco_primitive<'a, 's, F>(
    path: &Path,
    label: &str,
    name: &str,
    doc: &'a gltf::Document,
    prim: &gltf::Primitive<'a>,
    ext: &gltf::json::Value,
    get: &F,
    default_weights: Vec<f32>,
    warnings: &mut Vec<String>,
) -> Result<Primitive, SceneError>
where
    F: Fn(gltf::Buffer<'a>) -> Option<&'s [u8]>,
{
    use draco_core::DataType as D;
    use gltf::Semantic;
    let what = |s: &str| format!("mesh '{name}' {s}");
    let view_index = ext
        .get("bufferView")
        .and_then(|v| v.as_u64())
        .ok_or_else(|| gerr(path, what(&format!("{DRACO} has no bufferView"))))? as usize;
    let view = doc.views().nth(view_index).ok_or_else(|| {
        gerr(path, what(&format!("{DRACO} refers to buffer view {view_index}, which does not exist")))
    })?;
    let ids = ext
        .get("attributes")
        .and_then(|v| v.as_object())
        .ok_or_else(|| gerr(path, what(&format!("{DRACO} has no attributes"))))?;
    let pos_acc = prim.get(&Semantic::Positions).ok_or_else(|| gerr(path, what("has no POSITION attribute")))?;
    check_accessor_type(path, &pos_acc, &[Dimensions::Vec3], &[DataType::F32], &what("POSITION"))?;
    let n = pos_acc.count();
    for (sem, label, dims, types) in vertex_attributes() {
        if let Some(acc) = prim.get(&sem) {
            check_accessor_type(path, &acc, &[dims], types, &what(label))?;
        }
    }
    let tris = match prim.indices() {
        Some(acc) => {
            check_accessor_type(path, &acc, &[Dimensions::Scalar], INDEX_TYPES, &what("indices"))?;
            acc.count() / 3
        }
        None => n / 3,
    };
    if prim.morph_targets().next().is_some() {
        return Err(SceneError::Unsupported {
            path: path.to_path_buf(),
            feature: format!("morph targets on the Draco-compressed mesh '{name}'"),
        });
    }
    let bytes = get(view.buffer())
        .and_then(|b| b.get(view.offset()..view.offset().saturating_add(view.length())))
        .ok_or_else(|| gerr(path, what(&format!("{DRACO}: buffer view {view_index} lies outside its buffer"))))?;
    let max_points = 2 * n as u64 + 64;
    let limits = draco_core::DecodeLimits::default()
        .with_max_points(max_points)
        .with_max_faces(2 * tris as u64 + 64)
        .with_max_decoded_bytes(max_points * 4 * 16);
    let mut buffer = draco_core::DecoderBuffer::new(bytes).with_limits(limits);
    let mut mesh = draco_core::Mesh::new();
    draco_core::MeshDecoder::new()
        .decode(&mut buffer, &mut mesh)
        .map_err(|e| gerr(path, what(&format!("{DRACO} data in buffer view {view_index} cannot be decoded: {e}"))))?;
    let points = mesh.num_points();
    if points == 0 || mesh.num_faces() == 0 {
        return Err(gerr(path, what(&format!("{DRACO} data in buffer view {view_index} holds no triangles"))));
    }
    // One attribute as `comps` floats per point; integers the accessor declares normalized are
    // scaled to [0, 1] as glTF reads them.
    let read = |sem: &Semantic, label: &str, comps: usize| -> Result<Option<Vec<f32>>, SceneError> {
        let Some(id) = ids.get(label) else { return Ok(None) };
        let id = id
            .as_u64()
            .and_then(|v| u32::try_from(v).ok())
            .ok_or_else(|| gerr(path, what(&format!("{DRACO}: {label}'s attribute id is not an integer"))))?;
        let a = mesh.attribute_by_unique_id(id).ok_or_else(|| {
            gerr(path, what(&format!("{DRACO}: {label} is Draco attribute {id}, which the data does not have")))
        })?;
        let mut v = a.read_f32s(points, comps);
        if prim.get(sem).is_some_and(|acc| acc.normalized()) {
            let scale = match a.data_type() {
                D::Uint8 => 1.0 / 255.0,
                D::Uint16 => 1.0 / 65535.0,
                _ => 1.0,
            };
            v.iter_mut().for_each(|x| *x *= scale);
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(gerr(path, what(&format!("{label} has non-finite (NaN/Inf) values"))));
        }
        Ok(Some(v))
    };
    let positions: Vec<Vec3> = read(&Semantic::Positions, "POSITION", 3)?
        .ok_or_else(|| gerr(path, what(&format!("{DRACO} does not map POSITION to a Draco attribute"))))?
        .chunks_exact(3)
        .map(Vec3::from_slice)
        .collect();
    let normals: Vec<Vec3> = read(&Semantic::Normals, "NORMAL", 3)?
        .map(|v| v.chunks_exact(3).map(Vec3::from_slice).collect())
        .unwrap_or_default();
    let uvs: Vec<Vec2> = read(&Semantic::TexCoords(0), "TEXCOORD_0", 2)?
        .map(|v| v.chunks_exact(2).map(Vec2::from_slice).collect())
        .unwrap_or_default();
    let joints = match read(&Semantic::Joints(0), "JOINTS_0", 4)? {
        Some(v) => {
            if v.iter().any(|&j| j < 0.0 || j > u16::MAX as f32 || j.fract() != 0.0) {
                return Err(gerr(path, what("JOINTS_0 holds values that are not joint indices")));
            }
            Some(v.chunks_exact(4).map(|c| [c[0] as u16, c[1] as u16, c[2] as u16, c[3] as u16]).collect::<Vec<_>>())
        }
        None => None,
    };
    let weights = read(&Semantic::Weights(0), "WEIGHTS_0", 4)?
        .map(|v| v.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect::<Vec<_>>());
    if joints.is_some() != weights.is_some() {
        return Err(gerr(path, what("has JOINTS_0 without WEIGHTS_0 or the reverse")));
    }
    if points != n {
        warnings.push(format!(
            "{label}: mesh '{name}': its Draco data decodes {points} vertices where the POSITION accessor declares {n}"
        ));
    }
    let indices: Vec<u32> = mesh.faces().iter().flat_map(|f| f.map(|p| p.0)).collect();
    let mut mesh = MeshData { name: name.to_string(), positions, normals, uvs, indices };
    mesh.validate_and_repair(label, warnings).map_err(|m| SceneError::invalid(path, m))?;
    Ok(Primitive { mesh, material: prim.material().index(), joints, weights, targets: Vec::new(), default_weights })
}

fn convert_image(name: &str, d: &gltf::image::Data, srgb: bool) -> Option<Texture> {
    use gltf::image::Format as F;
    let n = (d.width * d.height) as usize;
    let (ch, bytes) = match d.format {
        F::R8 => (1, 1),
        F::R8G8 => (2, 1),
        F::R8G8B8 => (3, 1),
        F::R8G8B8A8 => (4, 1),
        F::R16 => (1, 2),
        F::R16G16 => (2, 2),
        F::R16G16B16 => (3, 2),
        F::R16G16B16A16 => (4, 2),
        F::R32G32B32FLOAT => (3, 4),
        F::R32G32B32A32FLOAT => (4, 4),
    };
    if d.pixels.len() < n * ch * bytes {
        return None;
    }
    let comp = |i: usize| -> f32 {
        match bytes {
            1 => d.pixels[i] as f32 / 255.0,
            2 => u16::from_le_bytes([d.pixels[2 * i], d.pixels[2 * i + 1]]) as f32 / 65535.0,
            _ => f32::from_le_bytes([d.pixels[4 * i], d.pixels[4 * i + 1], d.pixels[4 * i + 2], d.pixels[4 * i + 3]]),
        }
    };
    let texels = (0..n)
        .map(|p| {
            let c: Vec<f32> = (0..ch).map(|k| comp(p * ch + k)).collect();
            let mut t = match ch {
                1 => [c[0], c[0], c[0], 1.0],
                2 => [c[0], c[1], 0.0, 1.0],
                3 => [c[0], c[1], c[2], 1.0],
                _ => [c[0], c[1], c[2], c[3]],
            };
            if srgb && bytes != 4 {
                for v in &mut t[..3] {
                    *v = srgb_to_linear(*v);
                }
            }
            t
        })
        .collect();
    Some(Texture { name: name.into(), width: d.width, height: d.height, texels })
}

/// Add the asset's parts to `scene` as objects placed by `placement`, playing `animation`
/// (index; ignored when the file has none). `material` overrides every part's material.
/// Returns the range of the new objects.
pub fn instantiate(
    scene: &mut Scene,
    asset: &GltfAsset,
    placement: Mat4,
    animation: Option<usize>,
    material: Option<usize>,
    path: &Path,
) -> Result<std::ops::Range<usize>, SceneError> {
    let rig = Arc::new(Rig { animation: animation.filter(|&a| a < asset.rig.animations.len()), ..asset.rig.clone() });
    let tex0 = scene.textures.len();
    scene.textures.extend(asset.textures.iter().cloned());
    let mat0 = scene.materials.len();
    scene.material_extras.resize(mat0, MaterialExtra::default());
    for (m, e) in asset.materials.iter().zip(&asset.extras) {
        scene.materials.push(m.clone());
        scene.material_extras.push(MaterialExtra {
            albedo_map: e.albedo_map.map(|t| t + tex0),
            roughness_map: e.roughness_map.map(|t| t + tex0),
            emission_map: e.emission_map.map(|t| t + tex0),
            normal_map: e.normal_map.map(|t| t + tex0),
            ..e.clone()
        });
    }
    let mut default_mat = None;
    let mesh0 = scene.meshes.len();
    scene.meshes.extend(asset.primitives.iter().map(|p| p.mesh.clone()));
    scene.object_info.resize(scene.objects.len(), ObjectInfo::default());
    let first = scene.objects.len();
    scene.warnings.extend(asset.warnings.iter().cloned());
    if let Some(c) = &asset.camera {
        // a model placed by a scene file: the scene's [camera] is the one used
        if scene.source.as_deref() != Some(path) {
            scene.warnings.push(format!(
                "{}: camera '{}' ignored (the scene file's [camera] is used)",
                path.display(),
                c.name
            ));
        }
    }
    for part in &asset.parts {
        let prim = &asset.primitives[part.primitive];
        let mat = match (material, prim.material) {
            (Some(m), _) => m,
            (None, Some(m)) => mat0 + m,
            (None, None) => *default_mat.get_or_insert_with(|| {
                scene.materials.push(Material::glossy("gltf_default", Vec3::splat(0.8), Vec3::splat(0.04), 0.5));
                scene.material_extras.push(MaterialExtra::default());
                scene.materials.len() - 1
            }),
        };
        let mut info = ObjectInfo { source: Some(path.to_path_buf()), ..Default::default() };
        info.thin_shell = prim.material.is_some_and(|m| asset.extras[m].two_sided);
        let transform;
        if !prim.targets.is_empty() {
            info.deformations.push(Deformation::Morph {
                rig: rig.clone(),
                node: part.node,
                targets: prim.targets.clone(),
                default_weights: prim.default_weights.clone(),
            });
        }
        match (part.skin, &prim.joints, &prim.weights) {
            (Some(s), Some(j), Some(w)) => {
                // Skinned vertices are placed by the joints (the node transform is ignored).
                info.deformations.push(Deformation::Skin {
                    rig: rig.clone(),
                    skin: s,
                    joints: j.clone(),
                    weights: w.clone(),
                });
                transform = placement;
            }
            _ => {
                transform = placement * rig.global(part.node, 0.0);
                if rig.node_animated(part.node) {
                    info.node = Some(NodeMotion { rig: rig.clone(), node: part.node, placement });
                }
            }
        }
        scene.objects.push(Object { name: part.name.clone(), mesh: mesh0 + part.primitive, material: mat, transform });
        scene.object_info.push(info);
    }
    for l in &asset.lights {
        let world = placement * rig.global(l.node, 0.0);
        if rig.node_animated(l.node) {
            scene.warnings.push(format!(
                "{}: light '{}': its node is animated; the light stays where it is at t = 0",
                path.display(),
                l.name
            ));
        }
        scene.lights.push(Light {
            name: l.name.clone(),
            kind: l.kind,
            position: world.transform_point3(Vec3::ZERO),
            // glTF lights shine along their node's -Z
            direction: world.transform_vector3(Vec3::NEG_Z).normalize_or(Vec3::NEG_Y),
            color: l.color,
            intensity: l.intensity,
            motion: crate::RigidMotion::Static,
            fixture: None,
        });
    }
    Ok(first..scene.objects.len())
}

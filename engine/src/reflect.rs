//! What a SPIR-V module expects of its pipeline layout: its descriptor bindings (set, binding,
//! descriptor type, count) and the bytes of its push-constant block, read from the module's own
//! declarations; and [`pipeline_interface`], a pipeline's push-descriptor set ([`SetLayout`])
//! made from them (the binding contract stated once, in the GLSL): a binding of two types in two
//! stages, or a push range shorter than a shader's block, is an error naming the shader and the
//! binding when the pipeline is created, instead of a validation message at draw time (or
//! silently wrong data on a driver without validation).
//!
//! Only what the project's shaders use is understood (no external crate: the registry offers
//! none offline): storage and uniform buffers, combined image samplers, sampled and storage
//! images, samplers, texel buffers, input attachments, arrays of them, and push-constant blocks
//! of scalars, vectors, matrices, arrays and structs.

use anyhow::{bail, Result};
use ash::vk;
use std::collections::{BTreeMap, HashMap};

/// One descriptor binding a shader declares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ShaderBinding {
    pub ty: vk::DescriptorType,
    /// Array elements (1 for a single descriptor, 0 for a runtime-sized array).
    pub count: u32,
}

/// The layout a shader module expects.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ShaderInterface {
    /// By (set, binding).
    pub bindings: BTreeMap<(u32, u32), ShaderBinding>,
    /// Bytes of the push-constant block up to the end of its last member (0: none).
    pub push_bytes: u32,
}

// opcodes
const OP_DECORATE: u32 = 71;
const OP_MEMBER_DECORATE: u32 = 72;
const OP_TYPE_INT: u32 = 21;
const OP_TYPE_FLOAT: u32 = 22;
const OP_TYPE_VECTOR: u32 = 23;
const OP_TYPE_MATRIX: u32 = 24;
const OP_TYPE_IMAGE: u32 = 25;
const OP_TYPE_SAMPLER: u32 = 26;
const OP_TYPE_SAMPLED_IMAGE: u32 = 27;
const OP_TYPE_ARRAY: u32 = 28;
const OP_TYPE_RUNTIME_ARRAY: u32 = 29;
const OP_TYPE_STRUCT: u32 = 30;
const OP_TYPE_POINTER: u32 = 32;
const OP_CONSTANT: u32 = 43;
const OP_VARIABLE: u32 = 59;
// decorations
const DEC_BLOCK: u32 = 2;
const DEC_BUFFER_BLOCK: u32 = 3;
const DEC_ARRAY_STRIDE: u32 = 6;
const DEC_MATRIX_STRIDE: u32 = 7;
const DEC_BINDING: u32 = 33;
const DEC_DESCRIPTOR_SET: u32 = 34;
const DEC_OFFSET: u32 = 35;
// storage classes
const SC_UNIFORM_CONSTANT: u32 = 0;
const SC_UNIFORM: u32 = 2;
const SC_PUSH_CONSTANT: u32 = 9;
const SC_STORAGE_BUFFER: u32 = 12;

#[derive(Clone, Debug)]
enum Type {
    Scalar(u32),
    Vector(u32, u32),
    Matrix(u32, u32),
    Image {
        dim: u32,
        sampled: u32,
    },
    Sampler,
    SampledImage,
    Array(u32, u32),
    RuntimeArray(u32),
    Struct(Vec<u32>),
    /// The pointee.
    Pointer(u32),
}

/// Reads the bindings and push-constant size of a SPIR-V module (bytes, little-endian words).
pub fn reflect(spirv: &[u8]) -> Result<ShaderInterface> {
    if spirv.len() < 20 || !spirv.len().is_multiple_of(4) {
        bail!("not a SPIR-V module ({} bytes)", spirv.len());
    }
    let words: Vec<u32> = spirv.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if words[0] != 0x0723_0203 {
        bail!("not a SPIR-V module (magic {:#010x})", words[0]);
    }
    let mut types: HashMap<u32, Type> = HashMap::new();
    let mut constants: HashMap<u32, u32> = HashMap::new();
    let mut decorations: HashMap<(u32, u32), u32> = HashMap::new();
    let mut flags: HashMap<u32, Vec<u32>> = HashMap::new();
    let mut member_offsets: HashMap<(u32, u32), u32> = HashMap::new();
    let mut member_matrix_stride: HashMap<(u32, u32), u32> = HashMap::new();
    let mut variables: Vec<(u32, u32, u32)> = Vec::new();
    let mut i = 5;
    while i < words.len() {
        let (count, op) = ((words[i] >> 16) as usize, words[i] & 0xffff);
        if count == 0 || i + count > words.len() {
            bail!("malformed SPIR-V: instruction at word {i} runs past the end");
        }
        let w = &words[i + 1..i + count];
        let at = |k: usize| w.get(k).copied().unwrap_or(0);
        match op {
            OP_DECORATE => match at(1) {
                DEC_BINDING | DEC_DESCRIPTOR_SET | DEC_ARRAY_STRIDE => {
                    decorations.insert((at(0), at(1)), at(2));
                }
                d => flags.entry(at(0)).or_default().push(d),
            },
            OP_MEMBER_DECORATE => match at(2) {
                DEC_OFFSET => {
                    member_offsets.insert((at(0), at(1)), at(3));
                }
                DEC_MATRIX_STRIDE => {
                    member_matrix_stride.insert((at(0), at(1)), at(3));
                }
                _ => {}
            },
            OP_TYPE_INT | OP_TYPE_FLOAT => {
                types.insert(at(0), Type::Scalar(at(1) / 8));
            }
            OP_TYPE_VECTOR => {
                types.insert(at(0), Type::Vector(at(1), at(2)));
            }
            OP_TYPE_MATRIX => {
                types.insert(at(0), Type::Matrix(at(1), at(2)));
            }
            OP_TYPE_IMAGE => {
                types.insert(at(0), Type::Image { dim: at(2), sampled: at(6) });
            }
            OP_TYPE_SAMPLER => {
                types.insert(at(0), Type::Sampler);
            }
            OP_TYPE_SAMPLED_IMAGE => {
                types.insert(at(0), Type::SampledImage);
            }
            OP_TYPE_ARRAY => {
                types.insert(at(0), Type::Array(at(1), at(2)));
            }
            OP_TYPE_RUNTIME_ARRAY => {
                types.insert(at(0), Type::RuntimeArray(at(1)));
            }
            OP_TYPE_STRUCT => {
                types.insert(at(0), Type::Struct(w[1..].to_vec()));
            }
            OP_TYPE_POINTER => {
                types.insert(at(0), Type::Pointer(at(2)));
            }
            OP_CONSTANT => {
                constants.insert(at(1), at(2));
            }
            OP_VARIABLE => variables.push((at(0), at(1), at(2))),
            _ => {}
        }
        i += count;
    }
    let has = |id: u32, d: u32| flags.get(&id).is_some_and(|f| f.contains(&d));
    let mut out = ShaderInterface::default();
    for (ptr, id, class) in variables {
        let Some(Type::Pointer(mut ty)) = types.get(&ptr).cloned() else { continue };
        if class == SC_PUSH_CONSTANT {
            let size = size_of(ty, None, &types, &constants, &decorations, &member_offsets, &member_matrix_stride)?;
            out.push_bytes = out.push_bytes.max(size);
            continue;
        }
        if ![SC_UNIFORM_CONSTANT, SC_UNIFORM, SC_STORAGE_BUFFER].contains(&class) {
            continue;
        }
        let mut count = 1u32;
        loop {
            match types.get(&ty) {
                Some(Type::Array(elem, len)) => {
                    count = count.saturating_mul(constants.get(len).copied().unwrap_or(1));
                    ty = *elem;
                }
                Some(Type::RuntimeArray(elem)) => {
                    count = 0;
                    ty = *elem;
                }
                _ => break,
            }
        }
        let dt = match (class, types.get(&ty)) {
            (SC_STORAGE_BUFFER, _) => vk::DescriptorType::STORAGE_BUFFER,
            (SC_UNIFORM, _) if has(ty, DEC_BUFFER_BLOCK) => vk::DescriptorType::STORAGE_BUFFER,
            (SC_UNIFORM, _) if has(ty, DEC_BLOCK) => vk::DescriptorType::UNIFORM_BUFFER,
            (_, Some(Type::SampledImage)) => vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            (_, Some(Type::Sampler)) => vk::DescriptorType::SAMPLER,
            (_, Some(Type::Image { dim: 5, sampled: 2 })) => vk::DescriptorType::STORAGE_TEXEL_BUFFER,
            (_, Some(Type::Image { dim: 5, .. })) => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
            (_, Some(Type::Image { dim: 6, .. })) => vk::DescriptorType::INPUT_ATTACHMENT,
            (_, Some(Type::Image { sampled: 2, .. })) => vk::DescriptorType::STORAGE_IMAGE,
            (_, Some(Type::Image { .. })) => vk::DescriptorType::SAMPLED_IMAGE,
            (_, other) => bail!("variable %{id}: a descriptor of a type not understood ({other:?})"),
        };
        let set = decorations.get(&(id, DEC_DESCRIPTOR_SET)).copied().unwrap_or(0);
        let Some(&binding) = decorations.get(&(id, DEC_BINDING)) else {
            bail!("variable %{id}: a descriptor without a binding decoration")
        };
        out.bindings.insert((set, binding), ShaderBinding { ty: dt, count });
    }
    Ok(out)
}

/// Bytes a value of type `ty` occupies (a struct: to the end of its last member; `matrix_stride`
/// of a matrix member, else its columns tightly packed).
fn size_of(
    ty: u32,
    matrix_stride: Option<u32>,
    types: &HashMap<u32, Type>,
    constants: &HashMap<u32, u32>,
    decorations: &HashMap<(u32, u32), u32>,
    offsets: &HashMap<(u32, u32), u32>,
    strides: &HashMap<(u32, u32), u32>,
) -> Result<u32> {
    let size = |t: u32, ms: Option<u32>| size_of(t, ms, types, constants, decorations, offsets, strides);
    Ok(match types.get(&ty) {
        Some(Type::Scalar(b)) => *b,
        Some(Type::Vector(c, n)) => size(*c, None)? * n,
        Some(Type::Matrix(col, n)) => match matrix_stride {
            Some(s) => s * n,
            None => size(*col, None)? * n,
        },
        Some(Type::Array(elem, len)) => {
            let n = constants.get(len).copied().unwrap_or(1);
            let stride = match decorations.get(&(ty, DEC_ARRAY_STRIDE)) {
                Some(&s) => s,
                None => size(*elem, None)?,
            };
            stride * n
        }
        Some(Type::Struct(members)) => {
            let mut end = 0;
            for (k, &m) in members.iter().enumerate() {
                let off = offsets.get(&(ty, k as u32)).copied().unwrap_or(0);
                end = end.max(off + size(m, strides.get(&(ty, k as u32)).copied())?);
            }
            end
        }
        other => bail!("a push-constant member of a type not understood ({other:?})"),
    })
}

/// The most bindings a push-descriptor set of the project's pipelines holds.
pub const MAX_SET_BINDINGS: usize = 32;

/// The descriptor type of each binding of a pipeline's push-descriptor set (set 0), as its
/// shaders declare them: binding `i` is `get(i)`, `None` where no stage uses it (the optimiser
/// drops unused bindings). A pipeline's layout is made from this, and a pass's binds are checked
/// against it when pushed ([`crate::RecordContext::push_set`]), so the binding contract is stated
/// once, in the GLSL, instead of again in a hand-written type list.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SetLayout {
    types: [Option<vk::DescriptorType>; MAX_SET_BINDINGS],
}

impl SetLayout {
    /// The type of binding `i` (`None`: not used by any stage).
    pub fn get(&self, i: usize) -> Option<vk::DescriptorType> {
        self.types.get(i).copied().flatten()
    }

    /// The used bindings and their types, in binding order.
    pub fn bindings(&self) -> impl Iterator<Item = (u32, vk::DescriptorType)> + '_ {
        self.types.iter().enumerate().filter_map(|(i, t)| t.map(|t| (i as u32, t)))
    }
}

/// What a pipeline's layout is made from: its push-descriptor set and the largest push-constant
/// block of its stages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineInterface {
    pub set: SetLayout,
    /// Bytes of the largest push-constant block (0: none).
    pub push_bytes: u32,
}

/// Reads the modules (`(name, SPIR-V)`, one per stage) of a pipeline whose push range is
/// `push_range` bytes: the union of their bindings as its [`SetLayout`] and their largest
/// push-constant block. Every binding must be in set 0, a single descriptor, of one type in
/// every stage that uses it and below [`MAX_SET_BINDINGS`], and the push range must cover every
/// stage's block; every violation is reported at once, naming the shader.
pub fn pipeline_interface(modules: &[(&str, &[u8])], push_range: u32) -> Result<PipelineInterface> {
    let mut set = SetLayout::default();
    let mut push_bytes = 0;
    let mut errors = Vec::new();
    for (name, spirv) in modules {
        let iface = match reflect(spirv) {
            Ok(i) => i,
            Err(e) => {
                errors.push(format!("{name}: {e:#}"));
                continue;
            }
        };
        for (&(s, binding), b) in &iface.bindings {
            match set.types.get_mut(binding as usize) {
                _ if s != 0 => {
                    errors.push(format!("{name}: binding {binding} is in set {s}; push descriptors use set 0"))
                }
                _ if b.count != 1 => {
                    errors.push(format!("{name}: binding {binding} is an array of {} descriptors", b.count))
                }
                None => errors.push(format!("{name}: binding {binding} is past the {MAX_SET_BINDINGS} a set holds")),
                Some(Some(t)) if *t != b.ty => {
                    errors.push(format!("{name}: binding {binding} is a {:?}, another stage declares a {t:?}", b.ty))
                }
                Some(t) => *t = Some(b.ty),
            }
        }
        if iface.push_bytes > push_range {
            errors.push(format!(
                "{name}: its push-constant block takes {} bytes but the layout's range is {push_range}",
                iface.push_bytes
            ));
        }
        push_bytes = push_bytes.max(iface.push_bytes);
    }
    if !errors.is_empty() {
        bail!("pipeline layout does not match its shaders:\n  - {}", errors.join("\n  - "));
    }
    Ok(PipelineInterface { set, push_bytes })
}

#[cfg(test)]
mod tests {
    use super::*;
    use penumbra_shaderc::shaderc::ShaderKind;
    use std::path::Path;

    fn spirv(src: &str, kind: ShaderKind) -> Vec<u8> {
        let words = crate::glsl_compile::compile_glsl_source(src, kind, Path::new("test.glsl"), Path::new("."))
            .unwrap_or_else(|e| panic!("{e}"));
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }

    const COMPUTE: &str = r#"#version 460
        layout(local_size_x = 8) in;
        layout(std430, binding = 0) readonly buffer A { float a[]; };
        layout(std430, binding = 1) buffer B { vec4 b[]; };
        layout(binding = 2) uniform U { mat4 m; vec4 v; } u;
        layout(binding = 3) uniform sampler2D tex;
        layout(binding = 4, rgba32f) uniform writeonly image2D img;
        layout(binding = 5) uniform sampler2DArray layers;
        layout(push_constant) uniform P { uint n; float x; vec3 dir; } pc;
        void main() {
            uint i = gl_GlobalInvocationID.x;
            vec4 t = texture(tex, vec2(a[i])) + texture(layers, vec3(pc.x));
            b[i] = u.m * u.v + t + vec4(pc.dir, float(pc.n));
            imageStore(img, ivec2(i), t);
        }"#;

    #[test]
    fn bindings_and_push_block_are_read_from_the_module() {
        use vk::DescriptorType as T;
        let iface = reflect(&spirv(COMPUTE, ShaderKind::Compute)).unwrap();
        let got: Vec<(u32, T, u32)> = iface.bindings.iter().map(|(&(s, b), x)| (s * 100 + b, x.ty, x.count)).collect();
        assert_eq!(
            got,
            vec![
                (0, T::STORAGE_BUFFER, 1),
                (1, T::STORAGE_BUFFER, 1),
                (2, T::UNIFORM_BUFFER, 1),
                (3, T::COMBINED_IMAGE_SAMPLER, 1),
                (4, T::STORAGE_IMAGE, 1),
                (5, T::COMBINED_IMAGE_SAMPLER, 1),
            ]
        );
        // uint at 0, float at 4, vec3 at 16 (std430: 16-byte aligned): 28 bytes
        assert_eq!(iface.push_bytes, 28);
    }

    #[test]
    fn the_set_is_the_shaders_own_and_disagreements_are_errors_naming_them() {
        use vk::DescriptorType as T;
        let m = spirv(COMPUTE, ShaderKind::Compute);
        let good = [
            T::STORAGE_BUFFER,
            T::STORAGE_BUFFER,
            T::UNIFORM_BUFFER,
            T::COMBINED_IMAGE_SAMPLER,
            T::STORAGE_IMAGE,
            T::COMBINED_IMAGE_SAMPLER,
        ];
        let one = |push_range| pipeline_interface(&[("c.comp", &m)], push_range);
        let iface = one(28).unwrap();
        let want: Vec<(u32, T)> = good.iter().enumerate().map(|(i, t)| (i as u32, *t)).collect();
        assert_eq!(iface.set.bindings().collect::<Vec<_>>(), want);
        assert_eq!(iface.push_bytes, 28);
        assert_eq!(one(64).unwrap(), iface, "a larger push range: fine");
        let e = one(16).unwrap_err().to_string();
        assert!(e.contains("c.comp: its push-constant block takes 28 bytes but the layout's range is 16"), "{e}");
        // two stages: the union of their bindings; one binding of two types is an error
        let vert = r#"#version 460
            layout(std430, binding = 1) readonly buffer B { vec4 b[]; };
            layout(std430, binding = 3) readonly buffer C { vec4 c[]; };
            void main() { gl_Position = b[gl_VertexIndex] + c[0]; }"#;
        let frag = r#"#version 460
            layout(binding = 0) uniform U { vec4 v; } u;
            layout(location = 0) out vec4 o;
            void main() { o = u.v; }"#;
        let (v, f) = (spirv(vert, ShaderKind::Vertex), spirv(frag, ShaderKind::Fragment));
        let set = pipeline_interface(&[("v.vert", &v), ("f.frag", &f)], 0).unwrap().set;
        let got: Vec<_> = set.bindings().collect();
        assert_eq!(got, vec![(0, T::UNIFORM_BUFFER), (1, T::STORAGE_BUFFER), (3, T::STORAGE_BUFFER)]);
        assert_eq!(set.get(2), None, "a binding no stage uses is left out");
        let e = pipeline_interface(&[("v.vert", &v), ("c.comp", &m)], 28).unwrap_err().to_string();
        assert!(
            e.contains("c.comp: binding 3 is a COMBINED_IMAGE_SAMPLER, another stage declares a STORAGE_BUFFER"),
            "{e}"
        );
        assert!(reflect(&[0u8; 24]).is_err());
    }

    #[test]
    fn arrays_sets_and_matrices_in_push_blocks() {
        let frag = r#"#version 460
            layout(set = 1, binding = 2) uniform sampler2D texs[4];
            layout(push_constant) uniform P { mat4 m; vec2 uv[3]; } pc;
            layout(location = 0) out vec4 o;
            void main() { o = pc.m * texture(texs[1], pc.uv[2]); }"#;
        let iface = reflect(&spirv(frag, ShaderKind::Fragment)).unwrap();
        assert_eq!(
            iface.bindings.get(&(1, 2)),
            Some(&ShaderBinding { ty: vk::DescriptorType::COMBINED_IMAGE_SAMPLER, count: 4 })
        );
        // mat4 (64) then vec2[3] with an 8-byte stride (std430)
        assert_eq!(iface.push_bytes, 64 + 24);
        let e = pipeline_interface(&[("f.frag", &spirv(frag, ShaderKind::Fragment))], 88).unwrap_err().to_string();
        assert!(e.contains("f.frag: binding 2 is in set 1"), "{e}");
    }
}

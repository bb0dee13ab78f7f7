//! Buffers read as uniform texel buffers (`Bind::TexelBuffer`, a `usamplerBuffer` over the
//! buffer's `R32G32B32A32_UINT` view; the tracer's tree, the ISG's and avs's tables): every word
//! reads back as written, under validation, and a binding that does not match the pass's
//! declarations is refused naming the pass and the buffer.

use penumbra::engine::shader::ShaderLibrary;
use penumbra::engine::{Access, Bind, Context, ContextDesc, Engine, Graph, PassKind};
use penumbra_passes::util::{compute_pipeline, submit_and_read, whole_texels};
use std::path::Path;

// out[i] = texel i of src, with its four words reversed (a component select the compiler must
// keep), for i < n
const COPY_COMP: &str = r#"#version 450
layout(local_size_x = 64) in;
layout(set = 0, binding = 0) uniform usamplerBuffer src;
layout(std430, set = 0, binding = 1) writeonly buffer Out { uvec4 dst[]; };
layout(push_constant) uniform Push { uint n; } pc;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) return;
    uvec4 t = texelFetch(src, int(i));
    dst[i] = t.wzyx;
}
"#;

fn library() -> ShaderLibrary {
    let words = ShaderLibrary::compile_source("copy.comp", COPY_COMP, Path::new("glsl/include")).unwrap();
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    ShaderLibrary::from_embedded(&[("copy.comp", bytes.as_slice())], None)
}

/// One frame: `words` uploaded, read as a texel buffer declared `read_as`, written out; the
/// read-back words or the frame's error.
fn round_trip(e: &mut Engine, words: &[u32], read_as: Access) -> anyhow::Result<Vec<u32>> {
    let p = compute_pipeline(&e.ctx, &library(), "copy.comp", 4)?;
    let pipe = p.handle();
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let texels = (bytes.len() as u64).div_ceil(16) as u32;
    let mut g = Graph::new();
    let src = g.create_buffer_init("texel_src", whole_texels(bytes));
    let dst = g.create_buffer("texel_dst", texels.max(1) as u64 * 16);
    let mut pass = g.pass("texel_copy", PassKind::Compute);
    let src = pass.read(src, read_as);
    let dst = pass.write(dst, Access::ComputeShaderWriteStorage);
    pass.record(move |rc| {
        let binds = [Bind::TexelBuffer(src), Bind::StorageBuffer(dst)];
        penumbra_passes::util::dispatch(rc, pipe, &binds, &texels.to_le_bytes(), [texels.div_ceil(64).max(1), 1, 1])
    });
    let out = submit_and_read(e, g, dst, "texel_rb", texels.max(1) as u64 * 16);
    drop(p);
    let out = out?;
    Ok(out.chunks_exact(4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
}

#[test]
fn texel_buffers_read_every_word_as_written() {
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).unwrap();
    let mut e = Engine::new(ctx.clone(), 1).unwrap();
    // 1001 words: a partial last texel (padded with zeros by whole_texels), float bits among them
    let words: Vec<u32> = (0..1001u32)
        .map(|i| if i % 3 == 0 { (i as f32 * -0.37).to_bits() } else { i.wrapping_mul(2654435761) })
        .collect();
    let out = round_trip(&mut e, &words, Access::ComputeShaderReadSampled).unwrap();
    assert_eq!(out.len(), 1004);
    for (t, chunk) in out.chunks_exact(4).enumerate() {
        for (c, got) in chunk.iter().enumerate() {
            let i = 4 * t + (3 - c);
            let want = words.get(i).copied().unwrap_or(0);
            assert_eq!(*got, want, "word {i}");
        }
    }
    drop(e);
    assert_eq!(ctx.validation.error_count(), 0, "validation errors: {:?}", ctx.validation.errors());
}

#[test]
fn a_texel_binding_of_a_storage_read_is_refused() {
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let mut e = Engine::new(ctx, 1).unwrap();
    let err = round_trip(&mut e, &[1, 2, 3, 4], Access::ComputeShaderReadStorage).unwrap_err().to_string();
    assert!(
        err.contains(
            "pass 'texel_copy' binds 'texel_src' as a texel buffer, but declared it as [ComputeShaderReadStorage]"
        ),
        "{err}"
    );
}

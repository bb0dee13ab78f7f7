//! Wrong resource declarations are caught: by the graph's own checks where it can see them,
//! otherwise by synchronization validation on the device.

use penumbra::engine::graph::ImageDesc;
use penumbra::engine::shader::ShaderLibrary;
use penumbra::engine::{vk, Access, Bind, Context, ContextDesc, Engine, Graph, PassKind};
use penumbra_passes::util::compute_pipeline;
use std::path::Path;
use std::sync::Arc;

const WRITE_COMP: &str = r#"#version 450
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0, rgba32f) uniform image2D img;
void main() { imageStore(img, ivec2(gl_GlobalInvocationID.xy), vec4(1.0)); }
"#;

fn library() -> ShaderLibrary {
    let words = ShaderLibrary::compile_source("t.comp", WRITE_COMP, Path::new("glsl/include")).unwrap();
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    ShaderLibrary::from_embedded(&[("t.comp", bytes.as_slice())], None)
}

fn engine(validation: bool) -> Engine {
    let ctx = Context::new(&ContextDesc { validation, ..Default::default() }).unwrap();
    Engine::new(ctx, 1).unwrap()
}

#[test]
fn storage_image_declared_as_sampled_is_caught_by_the_graph() {
    let mut e = engine(false);
    let p = compute_pipeline(&e.ctx, &library(), "t.comp", 0).unwrap();
    let (pipeline, layout) = (p.pipeline, p.layout);
    let mut g = Graph::new();
    let img = g.create_image("img", ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, 8, 8));
    let mut pass = g.pass("write", PassKind::Compute);
    let img = pass.write(img, Access::ComputeShaderWriteStorage);
    pass.record(move |rc| {
        unsafe { rc.device().cmd_bind_pipeline(rc.cmd, vk::PipelineBindPoint::COMPUTE, pipeline) };
        rc.push_descriptors(vk::PipelineBindPoint::COMPUTE, layout, 0, &[Bind::StorageImage(img)])?;
        unsafe { rc.device().cmd_dispatch(rc.cmd, 1, 1, 1) };
        Ok(())
    });
    let mut pass = g.pass("wrong", PassKind::Compute);
    // Declared as a sampled read, bound (and written) as a storage image.
    let img2 = pass.read(img, Access::ComputeShaderReadSampled);
    pass.side_effect();
    pass.record(move |rc| {
        unsafe { rc.device().cmd_bind_pipeline(rc.cmd, vk::PipelineBindPoint::COMPUTE, pipeline) };
        rc.push_descriptors(vk::PipelineBindPoint::COMPUTE, layout, 0, &[Bind::StorageImage(img2)])?;
        unsafe { rc.device().cmd_dispatch(rc.cmd, 1, 1, 1) };
        Ok(())
    });
    let err = e.submit(g).expect_err("a wrong binding must fail the frame").to_string();
    assert!(
        err.contains("pass 'wrong' binds 'img' as a storage image, but declared it as [ComputeShaderReadSampled]"),
        "{err}"
    );
    assert!(err.contains("not submitted"), "{err}");
    drop(p);
}

#[test]
fn undeclared_resource_use_is_caught() {
    let mut e = engine(false);
    let mut g = Graph::new();
    let a = g.create_buffer_init("a", vec![0u8; 64]);
    let rb = g.create_readback("rb", 64);
    let mut pass = g.pass("copy", PassKind::Transfer);
    let rb = pass.write(rb, Access::TransferDst);
    pass.record(move |rc| {
        let _ = rc.buffer(a)?; // never declared by this pass
        let _ = rc.buffer(rb)?;
        Ok(())
    });
    let err = e.submit(g).unwrap_err().to_string();
    assert!(err.contains("pass 'copy' used 'a' without declaring it"), "{err}");
    // The engine recovers: the next (valid) frame runs.
    let mut g = Graph::new();
    let rb = g.create_readback("rb", 64);
    let mut pass = g.pass("clear", PassKind::Transfer);
    let rb = pass.write(rb, Access::TransferDst);
    pass.record(move |rc| {
        let b = rc.buffer(rb)?;
        unsafe { rc.device().cmd_fill_buffer(rc.cmd, b.buffer, 0, 64, 7) };
        Ok(())
    });
    e.submit(g).unwrap();
    let out = e.drain().unwrap();
    assert_eq!(out.len(), 1);
    assert!(out[0].readbacks["rb"].chunks(4).all(|c| c == [7, 0, 0, 0]));
}

/// Pass `fill` writes a buffer with vkCmdFillBuffer; `copy` copies it to a readback buffer.
fn fill_then_copy(e: &mut Engine, declare_fill_as_write: bool) -> Vec<u8> {
    let mut g = Graph::new();
    let data = g.create_buffer_init("data", vec![0u8; 256]);
    let rb = g.create_readback("rb", 256);
    let mut pass = g.pass("fill", PassKind::Transfer);
    let data = if declare_fill_as_write {
        pass.write(data, Access::TransferDst)
    } else {
        // Wrong: the pass writes the buffer but declares a read. The graph cannot see the
        // command, so it derives no barrier before `copy`.
        pass.read(data, Access::TransferSrc)
    };
    pass.side_effect();
    pass.record(move |rc| {
        let b = rc.buffer(data)?;
        unsafe { rc.device().cmd_fill_buffer(rc.cmd, b.buffer, 0, 256, 0x2a2a2a2a) };
        Ok(())
    });
    penumbra_passes::util::copy_buffer(&mut g, "copy", data, rb, Some(256));
    let (compiled, _) = e.submit(g).unwrap();
    let copy = compiled.pass("copy").unwrap();
    assert_eq!(copy.barriers.len(), if declare_fill_as_write { 1 } else { 0 });
    e.drain().unwrap().remove(0).readbacks.remove("rb").unwrap()
}

#[test]
fn missing_write_declaration_is_caught_by_sync_validation() {
    let mut e = engine(true);
    let log: Arc<_> = e.ctx.validation.clone();
    let ok = fill_then_copy(&mut e, true);
    assert!(ok.iter().all(|&b| b == 0x2a));
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
    fill_then_copy(&mut e, false);
    drop(e);
    assert!(log.error_count() > 0, "synchronization validation missed the hazard");
    assert!(log.errors().iter().any(|m| m.contains("SYNC-HAZARD-READ-AFTER-WRITE")), "{:#?}", log.errors());
}

#[test]
fn shader_errors_name_file_and_line() {
    let bad = "#version 450\nlayout(local_size_x = 1) in;\nvoid main() {\n  undefined_call();\n}\n";
    let err = ShaderLibrary::compile_source("broken.comp", bad, Path::new("glsl/include")).unwrap_err().to_string();
    assert!(err.contains("broken.comp:4"), "{err}");
    // Hot reload from the sources recompiles a real shader.
    let mut lib = penumbra::shader_library();
    let before = lib.get("frame/tonemap.comp").unwrap().len();
    lib.reload("frame/tonemap.comp").unwrap();
    assert_eq!(lib.get("frame/tonemap.comp").unwrap().len(), before);
    assert!(lib.reload("missing.comp").is_err());
}

/// A pipeline's descriptor set is its shader's own bindings: a pass that binds fewer
/// descriptors than the shader uses, or a descriptor of another type than the shader declares,
/// fails the frame naming the pass and the binding; a binding the shader does not use (binding 1
/// here, left out of the SPIR-V) is checked against the declarations but not written, so the
/// right binds run validation-clean.
#[test]
fn binds_are_checked_against_the_shaders_own_bindings() {
    const TWO: &str = r#"#version 450
layout(local_size_x = 8, local_size_y = 8) in;
layout(set = 0, binding = 0, rgba32f) uniform image2D img;
layout(std430, set = 0, binding = 1) readonly buffer Unused { float unused[]; };
layout(std430, set = 0, binding = 2) readonly buffer Scale { float scale[]; };
void main() { imageStore(img, ivec2(gl_GlobalInvocationID.xy), vec4(scale[0])); }
"#;
    let words = ShaderLibrary::compile_source("two.comp", TWO, Path::new("glsl/include")).unwrap();
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    let lib = ShaderLibrary::from_embedded(&[("two.comp", bytes.as_slice())], None);
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).unwrap();
    let log = ctx.validation.clone();
    let mut e = Engine::new(ctx, 1).unwrap();
    let p = compute_pipeline(&e.ctx, &lib, "two.comp", 0).unwrap();
    let set: Vec<_> = p.set.bindings().collect();
    assert_eq!(set, vec![(0, vk::DescriptorType::STORAGE_IMAGE), (2, vk::DescriptorType::STORAGE_BUFFER)]);
    // how many binds the pass gives (0: image, 1: unused buffer, 2: scale), and binding 2 as an image
    let frame = |e: &mut Engine, n: usize, wrong_type: bool| {
        let h = p.handle();
        let mut g = Graph::new();
        let img = g.create_image("img", ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, 8, 8));
        let buf = g.create_buffer_init("scale", 1.0f32.to_le_bytes().to_vec());
        let mut pass = g.pass("two", PassKind::Compute);
        let img = pass.write(img, Access::ComputeShaderWriteStorage);
        let buf = pass.read(buf, Access::ComputeShaderReadStorage);
        pass.side_effect();
        pass.record(move |rc| {
            let third = if wrong_type { Bind::StorageImage(img) } else { Bind::StorageBuffer(buf) };
            let binds = [Bind::StorageImage(img), Bind::StorageBuffer(buf), third];
            penumbra_passes::util::dispatch(rc, h, &binds[..n], &[], [1, 1, 1])
        });
        e.submit(g).map(|_| ()).map_err(|err| err.to_string())
    };
    let err = frame(&mut e, 2, false).expect_err("binding 2 left out");
    assert!(err.contains("pass 'two': its shaders use binding 2 (STORAGE_BUFFER) but it binds 2 descriptors"), "{err}");
    let err = frame(&mut e, 3, true).expect_err("binding 2 of the wrong type");
    assert!(
        err.contains(
            "pass 'two': binding 2 is a STORAGE_BUFFER in its shaders but the pass binds 'img' as a STORAGE_IMAGE"
        ),
        "{err}"
    );
    frame(&mut e, 3, false).expect("the shader's bindings, binding 1 unused");
    e.drain().unwrap();
    drop(p);
    drop(e);
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
}

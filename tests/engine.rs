//! Engine behaviour on the device: persistent resources across frames in flight, pool reuse,
//! timestamps per pass.

use penumbra::engine::{vk, Access, BufferHandle, Context, ContextDesc, Engine, Graph, PassKind};
use penumbra::passes::util::copy_buffer;

/// Transfer pass `name` filling the first `size` bytes of `buf` with the word `value`; returns
/// the written version.
fn fill(g: &mut Graph, name: &str, buf: BufferHandle, size: u64, value: u32) -> BufferHandle {
    let mut p = g.pass(name, PassKind::Transfer);
    let buf = p.write(buf, Access::TransferDst);
    p.record(move |rc| {
        let b = rc.buffer(buf)?;
        unsafe { rc.device().cmd_fill_buffer(rc.cmd, b.buffer, 0, size, value) };
        Ok(())
    });
    buf
}

/// Each frame shifts a persistent buffer of 16 words up by one word through a transient copy and
/// writes 1 into word 0, then reads it back: after frame k the first k+1 words are 1. Any lost
/// or reordered frame, or a missing dependency between frames in flight, changes the result.
fn accumulate_frame(e: &mut Engine) -> Graph {
    let mut g = Graph::new();
    let acc = e.persistent_buffer(&mut g, "acc", 64);
    let fresh = g.persistent_is_new(acc);
    let ones = g.create_buffer("ones", 64);
    let sum = g.create_buffer("sum", 64);
    let rb = g.create_readback("acc_rb", 64);
    // Frame 0 starts the accumulator at zero.
    let acc = if fresh { fill(&mut g, "zero", acc, 64, 0) } else { acc };
    // sum = acc (last frame's contents).
    let (_, sum) = copy_buffer(&mut g, "copy_in", acc, sum, Some(64));
    let ones = fill(&mut g, "ones", ones, 64, 1);
    // acc[i+1] = sum[i] shifted by one word, acc[0] = 1: after k frames acc holds a ramp of 1s.
    let mut p = g.pass("shift", PassKind::Transfer);
    let s2 = p.read(sum, Access::TransferSrc);
    let o2 = p.read(ones, Access::TransferSrc);
    let acc2 = p.write(acc, Access::TransferDst);
    p.record(move |rc| {
        let (s, o, d) = (rc.buffer(s2)?, rc.buffer(o2)?, rc.buffer(acc2)?);
        unsafe {
            rc.device().cmd_copy_buffer(
                rc.cmd,
                s.buffer,
                d.buffer,
                &[vk::BufferCopy { src_offset: 0, dst_offset: 4, size: 60 }],
            );
            rc.device().cmd_copy_buffer(
                rc.cmd,
                o.buffer,
                d.buffer,
                &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size: 4 }],
            );
        }
        Ok(())
    });
    copy_buffer(&mut g, "read", acc2, rb, Some(64));
    g
}

#[test]
fn persistent_buffer_carries_state_across_frames_in_flight() {
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).unwrap();
    let log = ctx.validation.clone();
    let mut e = Engine::new(ctx, 2).unwrap();
    let mut outs = Vec::new();
    for _ in 0..6 {
        let g = accumulate_frame(&mut e);
        let (_, done) = e.submit(g).unwrap();
        outs.extend(done);
    }
    outs.extend(e.drain().unwrap());
    assert_eq!(outs.len(), 6);
    for (k, o) in outs.iter().enumerate() {
        assert_eq!(o.frame, k as u64);
        let words: Vec<u32> =
            o.readbacks["acc_rb"].chunks(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        // After frame k, the first k+1 words are 1 and the rest 0.
        let want: Vec<u32> = (0..16).map(|i| u32::from(i <= k)).collect();
        assert_eq!(words, want, "frame {k}");
        // Every live pass was timed.
        assert!(o.gpu_ms.iter().any(|(n, _)| n == "shift"));
    }
    // Transients were reused from the pool rather than created per frame (2 slots in flight).
    assert!(e.pool_stats.reused >= 6, "{:?}", e.pool_stats);
    assert!(e.pool_stats.created <= 2 * 4, "{:?}", e.pool_stats);
    drop(e);
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
}

/// Transients whose size changes every frame (as avs's follow its sample points) do not pile up
/// in the pool: entries unused for `POOL_KEEP_FRAMES` frames are freed, so device memory stays
/// flat; and every allocation is returned when the engine is dropped (no leak).
#[test]
fn the_pool_evicts_unused_transients_and_nothing_leaks() {
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let (_, before, _) = ctx.memory_report();
    let mut e = Engine::new(ctx.clone(), 2).unwrap();
    let mut peak = 0;
    for k in 0..40u64 {
        let mut g = Graph::new();
        let size = 4096 * (k + 1);
        let grow = g.create_buffer("grow", size);
        let rb = g.create_readback("grow_rb", 4);
        let grow = fill(&mut g, "fill", grow, size, k as u32);
        copy_buffer(&mut g, "read", grow, rb, Some(4));
        e.submit(g).unwrap();
        peak = peak.max(e.pooled());
    }
    e.drain().unwrap();
    // 40 sizes were asked for; the pool holds a few frames' worth at most
    assert!(peak <= 2 * (penumbra::engine::POOL_KEEP_FRAMES as usize + 3), "peak pooled {peak}");
    assert!(e.pool_stats.evicted >= 30, "{:?}", e.pool_stats);
    drop(e);
    let (_, after, _) = ctx.memory_report();
    assert_eq!(after, before, "allocations leaked by the engine");
}

#[test]
fn pipeline_cache_is_saved_read_back_and_foreign_files_are_ignored() {
    // The context's VkPipelineCache is seeded from this driver's file and written back
    // (atomically) when the context is dropped; a file with another header is not handed to
    // the driver. (lavapipe keeps only the 32-byte header in it: Mesa's own shader cache does
    // its caching; other drivers put their pipelines there.)
    let dir =
        std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("penumbra_pcache_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let desc = ContextDesc { pipeline_cache_dir: Some(dir.clone()), ..Default::default() };
    {
        let ctx = Context::new(&desc).unwrap();
        assert_eq!(ctx.pipeline_cache_loaded, 0, "nothing on disk yet");
        let shaders = penumbra::shader_library();
        let _pass = penumbra::passes::tonemap::TonemapPass::new(&ctx, &shaders).unwrap();
    }
    let files: Vec<std::path::PathBuf> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(files.len(), 1, "one file per driver, no temporary left: {files:?}");
    let name = files[0].file_name().unwrap().to_string_lossy().to_string();
    assert!(name.starts_with("pipelines-") && name.ends_with(".bin"), "{name}");
    let bytes = std::fs::read(&files[0]).unwrap();
    assert!(bytes.len() >= 32 && u32::from_le_bytes(bytes[4..8].try_into().unwrap()) == 1, "a VkPipelineCache header");
    {
        let ctx = Context::new(&desc).unwrap();
        assert_eq!(ctx.pipeline_cache_loaded, bytes.len(), "read back");
    }
    // Another driver's (or a corrupt) file: ignored, the context still starts.
    let mut foreign = bytes.clone();
    foreign[16] ^= 0xff;
    std::fs::write(&files[0], &foreign).unwrap();
    {
        let ctx = Context::new(&desc).unwrap();
        assert_eq!(ctx.pipeline_cache_loaded, 0, "a foreign UUID is not handed to the driver");
    }
    std::fs::write(&files[0], b"garbage").unwrap();
    assert_eq!(Context::new(&desc).unwrap().pipeline_cache_loaded, 0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn frames_with_more_passes_than_the_timestamp_pool_are_still_timed() {
    // 200 passes (400 timestamps, more than a slot's initial 256): the slot's pool grows and
    // every pass gets its GPU time (before, timestamps were silently off for such frames).
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let mut e = Engine::new(ctx, 2).unwrap();
    let mut outs = Vec::new();
    for _ in 0..3 {
        let mut g = Graph::new();
        // A chain: each pass copies the previous buffer into the next and adds nothing, so none
        // is culled.
        let chain0 = g.create_buffer("chain0", 256);
        let mut buf = fill(&mut g, "fill", chain0, 256, 199);
        for k in 1..200u32 {
            let next = g.create_buffer(&format!("chain{k}"), 256);
            buf = copy_buffer(&mut g, &format!("copy{k}"), buf, next, Some(256)).1;
        }
        let rb = g.create_readback("chain_rb", 4);
        copy_buffer(&mut g, "read", buf, rb, Some(4));
        let (_, done) = e.submit(g).unwrap();
        outs.extend(done);
    }
    outs.extend(e.drain().unwrap());
    assert_eq!(outs.len(), 3);
    for o in &outs {
        assert_eq!(o.gpu_ms.len(), 201, "every live pass timed");
        assert_eq!(o.readbacks["chain_rb"], 199u32.to_le_bytes().to_vec(), "the last fill wins");
    }
}

/// Readback buffers take host-cached memory where the device has a host-visible, coherent and
/// cached type (reading write-combined `CpuToGpu` memory cost about 200 ms per 640x480 RGBA32F
/// frame on an NVIDIA H200); upload buffers stay host-visible.
#[test]
fn readback_buffers_are_host_cached() {
    use vk::MemoryPropertyFlags as M;
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let props = unsafe { ctx.instance.get_physical_device_memory_properties(ctx.physical) };
    let want = M::HOST_VISIBLE | M::HOST_COHERENT | M::HOST_CACHED;
    let has_cached = props.memory_types_as_slice().iter().any(|t| t.property_flags.contains(want));
    let rb = ctx.create_readback_buffer("rb", 1024, vk::BufferUsageFlags::TRANSFER_DST).unwrap();
    let up = ctx.create_buffer("up", 1024, vk::BufferUsageFlags::TRANSFER_SRC, true).unwrap();
    let (fr, fu) = (rb.memory_flags(), up.memory_flags());
    ctx.destroy_buffer(rb);
    ctx.destroy_buffer(up);
    assert!(fr.contains(M::HOST_VISIBLE | M::HOST_COHERENT), "readback memory {fr:?}");
    assert!(!has_cached || fr.contains(M::HOST_CACHED), "readback memory {fr:?}, a cached type exists");
    assert!(fu.contains(M::HOST_VISIBLE), "upload memory {fu:?}");
}

/// A late readback is not returned with its frame: the engine keeps the newest finished copy,
/// which frames built later read without waiting (`poll` collects finished frames, never blocks).
#[test]
fn late_readbacks_reach_later_frames_without_waiting() {
    let ctx = Context::new(&ContextDesc { validation: true, ..Default::default() }).unwrap();
    let log = ctx.validation.clone();
    let mut e = Engine::new(ctx.clone(), 2).unwrap();
    let frame = |e: &mut Engine, value: u32| {
        let mut g = Graph::new();
        let b = g.create_buffer("value", 4);
        let w = fill(&mut g, "fill", b, 4, value);
        let rb = g.create_late_readback("value", 4);
        penumbra::passes::util::copy_buffer(&mut g, "value_copy", w, rb, Some(4));
        e.submit(g).unwrap().1
    };
    assert!(e.late_readback("value").is_none());
    let mut outs = Vec::new();
    for k in 0..5u32 {
        // what frame k may see: only frames already collected, each newer than the last seen
        e.poll().unwrap();
        if let Some(l) = e.late_readback("value") {
            assert!(l.frame < k as u64);
            assert_eq!(l.bytes, (100 + l.frame as u32).to_le_bytes());
        }
        outs.extend(frame(&mut e, 100 + k));
    }
    outs.extend(e.drain().unwrap());
    assert_eq!(outs.iter().map(|o| o.frame).collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
    // the frames' own outputs do not carry it
    assert!(outs.iter().all(|o| o.readbacks.is_empty()), "{:?}", outs[0].readbacks.keys());
    let l = e.late_readback("value").expect("the last frame's copy");
    assert_eq!((l.frame, l.bytes.clone()), (4, 104u32.to_le_bytes().to_vec()));
    // poll with nothing in flight, and after a wait: nothing left to collect, nothing returned twice
    e.poll().unwrap();
    assert!(e.drain().unwrap().is_empty());
    drop(e);
    assert_eq!(log.error_count(), 0, "{:#?}", log.errors());
}

/// Every shader the build compiled can be reflected (`engine::reflect`): the check of each
/// pipeline's hand-written layout against its shaders understands all of them, and finds the
/// bindings they declare (every compute shader binds something).
#[test]
fn every_shader_of_the_build_reflects() {
    let lib = penumbra::shader_library();
    let mut n = 0;
    for name in lib.names() {
        let iface =
            penumbra::engine::reflect::reflect(lib.get(name).unwrap()).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        if name.ends_with(".comp") {
            assert!(!iface.bindings.is_empty(), "{name}: no bindings found");
        }
        assert!(iface.bindings.keys().all(|&(set, _)| set == 0), "{name}: a set other than 0: {:?}", iface.bindings);
        n += 1;
    }
    assert!(n > 50, "{n} shaders");
}

/// Specialization constants of a compute pipeline (`passes::util::compute_pipeline_specialized`):
/// none on an ordinary library gives no specialization info, the loop guard's ids and an id given
/// twice are refused by name, and a specialized pipeline is created and runs (avs_shade.comp's
/// `AVS_MODE`; tests/avs.rs checks that each mode draws its own image).
#[test]
fn specialization_constants_are_checked() {
    use penumbra::engine::shader::Specialization;
    let ctx = Context::new(&ContextDesc::default()).unwrap();
    let lib = penumbra::shader_library();
    let shader = "avs/avs_shade.comp";
    assert!(Specialization::for_shader(&ctx, &lib, shader, &[]).unwrap().is_none());
    let s = Specialization::for_shader(&ctx, &lib, shader, &[(0, 3)]).unwrap().expect("one constant");
    let info = s.info();
    assert_eq!((info.map_entry_count, info.data_size), (1, 4));
    let reserved = penumbra::engine::glsl_compile::LOOP_GUARD_CONSTANT_IDS[0];
    let e = Specialization::for_shader(&ctx, &lib, shader, &[(reserved, 1)]).err().expect("reserved id");
    assert!(e.to_string().contains("loop guard") && e.to_string().contains(shader), "{e}");
    let e = Specialization::for_shader(&ctx, &lib, shader, &[(0, 1), (0, 2)]).err().expect("twice");
    assert!(e.to_string().contains("twice"), "{e}");
    for mode in 0..4 {
        penumbra::passes::util::compute_pipeline_specialized(&ctx, &lib, shader, 52, &[(0, mode)]).unwrap();
    }
}

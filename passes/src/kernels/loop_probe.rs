//! `loop_probe`: measures the device's per-invocation loop limit (`glsl/tests/loop_probe.comp`).
//!
//! llvmpipe/lavapipe in Mesa 22.3 ends every loop of a shader invocation, silently, once the
//! invocation's loops have run 65535 iterations in total (one counter shared by all loops). Shaders
//! whose work can approach such a limit split it over invocations or carry a probe of their own;
//! this kernel says whether the device has the limit at all.

use crate::util::{compute_pipeline, storage};
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Engine, Graph, PassKind};

/// What one invocation ran of two loops of `first` and `second` iterations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopCounts {
    pub first: u32,
    pub second: u32,
}

/// Runs one invocation of two loops of `first` then `second` iterations and reads back how many
/// iterations each really ran.
pub fn run_loops(engine: &mut Engine, shaders: &ShaderLibrary, first: u32, second: u32) -> Result<LoopCounts> {
    let ctx = engine.ctx.clone();
    let pipeline = compute_pipeline(&ctx, shaders, "tests/loop_probe.comp", 8)?;
    let mut graph = Graph::new();
    let out = graph.create_buffer("loop_probe_out", 8);
    let mut p = graph.pass("loop_probe", PassKind::Compute);
    let out_w = p.write(out, Access::ComputeShaderWriteStorage);
    let mut push = Vec::with_capacity(8);
    push.extend_from_slice(&first.to_le_bytes());
    push.extend_from_slice(&second.to_le_bytes());
    let pipe = pipeline.handle();
    p.record(move |rc| crate::util::dispatch(rc, pipe, &storage([out_w]), &push, [1, 1, 1]));
    let bytes = crate::util::submit_and_read(engine, graph, out_w, "loop_probe", 8);
    drop(pipeline);
    let bytes = bytes?;
    let word = |i: usize| u32::from_le_bytes([bytes[4 * i], bytes[4 * i + 1], bytes[4 * i + 2], bytes[4 * i + 3]]);
    Ok(LoopCounts { first: word(0), second: word(1) })
}

/// The device's per-invocation loop limit: `None` when one invocation runs `probe` iterations of
/// one loop and then a second loop in full, else the number of iterations the first loop ran.
pub fn loop_limit(engine: &mut Engine, shaders: &ShaderLibrary, probe: u32) -> Result<Option<u32>> {
    let c = run_loops(engine, shaders, probe, 16)?;
    Ok(if c.first == probe && c.second == 16 { None } else { Some(c.first) })
}

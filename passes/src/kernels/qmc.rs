//! `qmc_points`: the randomized quasi-Monte Carlo points `mc` samples with (`qmc_2d` of
//! `glsl/include/qmc.glsl`, through `glsl/tests/qmc_points.comp`), read back for tests of their
//! stratification.

use crate::util::{bytes_of, compute_pipeline, groups, storage};
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Engine, Graph, PassKind};

/// Points `first .. first + count` of each sequence `seeds` names: `result[s][k]` is point
/// `first + k` of sequence `seeds[s]`, in [0, 1)^2.
pub fn qmc_points(
    engine: &mut Engine,
    shaders: &ShaderLibrary,
    seeds: &[u32],
    first: u32,
    count: u32,
) -> Result<Vec<Vec<[f32; 2]>>> {
    let ctx = engine.ctx.clone();
    let pipeline = compute_pipeline(&ctx, shaders, "tests/qmc_points.comp", 12)?;
    let n = count as u64 * seeds.len() as u64;
    let out_bytes = n.max(1) * 8;
    let seed_data: Vec<u32> = if seeds.is_empty() { vec![0] } else { seeds.to_vec() };
    let mut graph = Graph::new();
    let sb = graph.create_buffer_init("qmc_seeds", bytes_of(&seed_data));
    let out = graph.create_buffer("qmc_points_out", out_bytes);
    let mut p = graph.pass("qmc_points", PassKind::Compute);
    let sb = p.read(sb, Access::ComputeShaderReadStorage);
    let out_w = p.write(out, Access::ComputeShaderWriteStorage);
    let push = bytes_of(&[first, count, seeds.len() as u32]).to_vec();
    let pipe = pipeline.handle();
    p.record(move |rc| crate::util::dispatch(rc, pipe, &storage([sb, out_w]), &push, [groups(n as u32, 64), 1, 1]));
    let bytes = crate::util::submit_and_read(engine, graph, out_w, "qmc_points", out_bytes);
    drop(pipeline);
    let bytes = bytes?;
    let f: Vec<f32> = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok((0..seeds.len())
        .map(|s| {
            (0..count as usize)
                .map(|k| [f[2 * (s * count as usize + k)], f[2 * (s * count as usize + k) + 1]])
                .collect()
        })
        .collect())
}

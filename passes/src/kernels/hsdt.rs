//! `hsdt_integrate_test`: the SSDF lighting integrals of `glsl/include/ssdf_integrate.glsl` on
//! the GPU.

use crate::util::{bytes_of, compute_pipeline, dispatch, groups, Pipeline};
use anyhow::Result;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, Graph, PassKind};
use std::sync::Arc;

/// Evaluator of the SSDF integrals of `glsl/include/ssdf_integrate.glsl` for (map, lobe) pairs
/// (`glsl/tests/hsdt_integrate_test.comp`; tests and `penumbra bench hsdt`).
pub struct IntegrateEval {
    pipe: Pipeline,
}

impl IntegrateEval {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        Ok(IntegrateEval { pipe: compute_pipeline(ctx, shaders, "tests/hsdt_integrate_test.comp", 8)? })
    }

    /// Adds a pass `name` evaluating `n` (map, lobe) pairs: `lobes` = `n` x (axis.xyz, lambda) f32,
    /// `params` = `n` x (mu, cosine 0/1, map index, methods 1 = (a) / 2 = (b) / 3 = both) f32,
    /// `ssdf` the fp16 maps, `table` the `AxisTable` f32 data. Returns `n` x (a, b) f32.
    pub fn add(
        &self,
        graph: &mut Graph,
        name: &str,
        ssdf: BufferHandle,
        table: BufferHandle,
        lobes: BufferHandle,
        params: BufferHandle,
        n: u32,
        r: u32,
    ) -> BufferHandle {
        let out = graph.create_buffer(&format!("{name}_out"), (n as u64 * 8).max(8));
        let mut p = graph.pass(name, PassKind::Compute);
        let ins = [ssdf, table, lobes, params].map(|b| p.read(b, Access::ComputeShaderReadStorage));
        let o = p.write(out, Access::ComputeShaderWriteStorage);
        let pipe = self.pipe.handle();
        p.record(move |rc| {
            let mut binds: Vec<Bind> = ins.iter().map(|b| Bind::StorageBuffer(*b)).collect();
            binds.push(Bind::StorageBuffer(o));
            dispatch(rc, pipe, &binds, &bytes_of(&[r, n]), [groups(n, 16).max(1), 1, 1])
        });
        o
    }
}

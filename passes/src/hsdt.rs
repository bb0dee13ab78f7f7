//! GPU hemispherical signed distance transform (paper section 5, Algorithm 1): packed visibility
//! maps in, fp16 SSDFs out, in two compute passes per batch of maps, declared through the graph:
//!
//! * `{name}_rows_b{k}` (`glsl/hsdt/hsdt_rows.comp`): latitude scans, one invocation per (map, row);
//!   writes the nearest occluded / visible column of every texel in its row into a transient
//!   `{name}_g` buffer (4 bytes per texel of a batch, reused by the batches).
//! * `{name}_cols_b{k}` (`glsl/hsdt/hsdt_cols.comp`): longitude scans, one invocation per (map, pair
//!   of columns) (so each invocation owns whole fp16x2 words); Meijster lower envelope with
//!   spherical distances, writes the signed distances (radians, fp16).
//!
//! Layouts (visibility bits, SSDF words, sign, units) are those of `penumbra_math::avs_maps`; the
//! result equals `penumbra_math::hsdt::hsdt` up to f32 evaluation and fp16 rounding (both are
//! exact transforms over texel centres). Maps are processed in batches so the intermediate buffer
//! stays under [`G_BUDGET_BYTES`] (e.g. 512 maps at r = 128).

use crate::util::{bytes_of, compute_pipeline, dispatch, groups, Pipeline};
use anyhow::{anyhow, Result};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, Graph, PassKind};
use penumbra_math::avs_maps::{check_res, ssdf_words_per_map, words_per_map};
use std::sync::Arc;

/// Upper bound on the bytes of one batch's intermediate (phase 1) buffer.
pub const G_BUDGET_BYTES: u64 = 32 << 20;
/// Shaders this module needs.
pub const SHADERS: [&str; 2] = ["hsdt/hsdt_rows.comp", "hsdt/hsdt_cols.comp"];

/// The two HSDT pipelines.
pub struct Hsdt {
    rows: Pipeline,
    cols: Pipeline,
    /// Maps per batch; `None`: [`batch_maps`].
    pub batch: Option<u32>,
}

/// Maps per batch at resolution `r` (bounded by [`G_BUDGET_BYTES`] and the dispatch limit).
pub fn batch_maps(r: u32) -> u32 {
    ((G_BUDGET_BYTES / (r as u64 * r as u64 * 4)) as u32).clamp(1, 65535)
}

impl Hsdt {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        Ok(Hsdt {
            rows: compute_pipeline(ctx, shaders, "hsdt/hsdt_rows.comp", 16)?,
            cols: compute_pipeline(ctx, shaders, "hsdt/hsdt_cols.comp", 16)?,
            batch: None,
        })
    }

    /// Adds the HSDT of the first `n` maps of `vis` (packed bits, `words_per_map(r)` u32 each)
    /// into a new transient buffer `{name}_ssdf` (`ssdf_words_per_map(r)` u32 per map); returns it.
    pub fn add(&self, graph: &mut Graph, name: &str, vis: BufferHandle, n: u32, r: u32) -> Result<BufferHandle> {
        let bytes = (n as u64 * ssdf_words_per_map(r) as u64 * 4).max(4);
        let out = graph.create_buffer(&format!("{name}_ssdf"), bytes);
        self.add_into(graph, name, vis, n, r, out)
    }

    /// As [`Hsdt::add`] but writing into `out` (e.g. a persistent buffer); returns its new
    /// version. Errors on an unsupported `r` or buffers too small for `n` maps.
    pub fn add_into(
        &self,
        graph: &mut Graph,
        name: &str,
        vis: BufferHandle,
        n: u32,
        r: u32,
        out: BufferHandle,
    ) -> Result<BufferHandle> {
        check_res(r).map_err(|e| anyhow!("hsdt '{name}': {e}"))?;
        let need_vis = n as u64 * words_per_map(r) as u64 * 4;
        let need_out = n as u64 * ssdf_words_per_map(r) as u64 * 4;
        let (have_vis, have_out) = (graph.resource(vis).desc.bytes(), graph.resource(out).desc.bytes());
        if have_vis < need_vis || have_out < need_out {
            return Err(anyhow!(
                "hsdt '{name}': {n} maps at r = {r} need {need_vis} bytes of visibility bits and {need_out} bytes of SSDF, buffers have {have_vis} and {have_out}"
            ));
        }
        let mut vis = vis;
        let mut out = out;
        let batch = self.batch.unwrap_or_else(|| batch_maps(r)).clamp(1, 65535);
        // one intermediate buffer, reused by every batch (the graph orders the batches)
        let mut g = graph.create_buffer(&format!("{name}_g"), (batch.min(n).max(1) as u64) * r as u64 * r as u64 * 4);
        let mut first = 0u32;
        let mut b = 0;
        while first < n {
            let count = batch.min(n - first);
            let push = [r, count, first, 0];
            {
                let mut p = graph.pass(&format!("{name}_rows_b{b}"), PassKind::Compute);
                let v = p.read(vis, Access::ComputeShaderReadStorage);
                // each invocation re-reads only its own writes: a plain write for the graph
                let gw = p.write(g, Access::ComputeShaderWriteStorage);
                let pipe = self.rows.handle();
                p.record(move |rc| {
                    let binds = [Bind::StorageBuffer(v), Bind::StorageBuffer(gw)];
                    dispatch(rc, pipe, &binds, &bytes_of(&push), [groups(r, 64), count, 1])
                });
                vis = v;
                // `g` for the next pass
                let mut p = graph.pass(&format!("{name}_cols_b{b}"), PassKind::Compute);
                let v = p.read(vis, Access::ComputeShaderReadStorage);
                let gr = p.read(gw, Access::ComputeShaderReadStorage);
                // later batches keep the earlier batches' maps: a read-write for the graph (a plain
                // write would let it cull the earlier batches' passes)
                let o = if b == 0 {
                    p.write(out, Access::ComputeShaderWriteStorage)
                } else {
                    p.write(out, Access::ComputeShaderReadWriteStorage)
                };
                let pipe = self.cols.handle();
                p.record(move |rc| {
                    let binds = [Bind::StorageBuffer(v), Bind::StorageBuffer(gr), Bind::StorageBuffer(o)];
                    dispatch(rc, pipe, &binds, &bytes_of(&push), [groups(r / 2, 64), count, 1])
                });
                vis = v;
                out = o;
                g = gr;
            }
            first += count;
            b += 1;
        }
        Ok(out)
    }
}

/// Decodes `n` fp16 SSDFs of resolution `r` from buffer bytes (`r * r` f32 per map).
pub fn decode_ssdf(bytes: &[u8], n: usize, r: u32) -> Vec<Vec<f32>> {
    let words: Vec<u32> = bytes.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect();
    let wpm = ssdf_words_per_map(r);
    (0..n).map(|p| penumbra_math::avs_maps::unpack_ssdf_f16(&words[p * wpm..(p + 1) * wpm])).collect()
}

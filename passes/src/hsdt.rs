//! GPU hemispherical signed distance transform (paper section 5, Algorithm 1): packed visibility
//! maps in, fp16 SSDFs out, in one compute pass per batch of maps, declared through the graph:
//! `{name}_b{k}` (`glsl/hsdt/hsdt.comp`), one invocation per (map, pair of columns) (so each
//! invocation owns whole fp16x2 words). The latitude scans' answer (the nearest occluded and
//! visible column in a row) is read off the row's bits where the longitude scans need it, so no
//! intermediate buffer is written or read: the pass reads `r * r / 8` bytes of bits and writes
//! `2 r * r` bytes of SSDF per map. The longitude scans build Meijster's lower envelopes with
//! spherical distances, each separator in closed form
//! (`penumbra_math::hsdt::closed_form_separator`).
//!
//! Layouts (visibility bits, SSDF words, sign, units) are those of `penumbra_math::avs_maps`; the
//! result equals `penumbra_math::hsdt::hsdt` up to f32 evaluation and fp16 rounding (both are
//! exact transforms over texel centres). Batches only bound one dispatch's size (65535 maps).

use crate::util::{bytes_of, compute_pipeline, dispatch, groups, Pipeline};
use anyhow::{anyhow, Result};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, Graph, PassKind};
use penumbra_math::avs_maps::{check_res, ssdf_words_per_map, words_per_map};
use std::sync::Arc;

/// Shaders this module needs.
pub const SHADERS: [&str; 1] = ["hsdt/hsdt.comp"];

/// The HSDT pipeline.
pub struct Hsdt {
    pipe: Pipeline,
    /// Maps per dispatch (at most 65535, the default).
    pub batch: Option<u32>,
}

/// Bytes the pass reads and writes per map at resolution `r`: the map's bits and its fp16 SSDF.
pub fn bytes_per_map(r: u32) -> u64 {
    (words_per_map(r) + ssdf_words_per_map(r)) as u64 * 4
}

impl Hsdt {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        Ok(Hsdt { pipe: compute_pipeline(ctx, shaders, "hsdt/hsdt.comp", 16)?, batch: None })
    }

    /// Adds the HSDT of the first `n` maps of `vis` (packed bits, `words_per_map(r)` u32 each)
    /// into a new transient buffer `{name}_ssdf` (`ssdf_words_per_map(r)` u32 per map); returns it.
    pub fn add(&self, graph: &mut Graph, name: &str, vis: BufferHandle, n: u32, r: u32) -> Result<BufferHandle> {
        // whole 16-byte texels: avs_shade reads the SSDFs as a texel buffer
        let bytes = crate::util::texel_bytes(n as u64 * ssdf_words_per_map(r) as u64 * 4);
        let out = graph.create_buffer(&format!("{name}_ssdf"), bytes);
        self.add_into(graph, name, vis, n, r, out)
    }

    /// Transforms `n` maps (`words`: packed bits, `words_per_map(r)` u32 each) in a submission of
    /// their own, passes `hsdt_b{k}`, and waits for it: the output's readback `ssdf` holds the
    /// SSDFs ([`decode_ssdf`]), its `gpu_ms` the passes' times when `engine` keeps timestamps.
    pub fn transform_alone(
        &self,
        engine: &mut penumbra_engine::Engine,
        words: &[u32],
        n: u32,
        r: u32,
    ) -> Result<penumbra_engine::FrameOutput> {
        let mut g = Graph::new();
        let vis = g.create_buffer_init("vis", bytes_of(words));
        let out = self.add(&mut g, "hsdt", vis, n, r)?;
        let bytes = g.resource(out).desc.bytes();
        crate::trace::add_copy_to_readback(&mut g, out, "ssdf", bytes);
        engine.submit(g)?;
        engine.drain()?.pop().ok_or_else(|| anyhow!("hsdt: no frame output"))
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
        let batch = self.batch.unwrap_or(65535).clamp(1, 65535);
        let mut first = 0u32;
        let mut b = 0;
        while first < n {
            let count = batch.min(n - first);
            let push = [r, count, first, 0];
            let mut p = graph.pass(&format!("{name}_b{b}"), PassKind::Compute);
            let v = p.read(vis, Access::ComputeShaderReadStorage);
            // later batches keep the earlier batches' maps: a read-write for the graph (a plain
            // write would let it cull the earlier batches' passes)
            let o = if b == 0 {
                p.write(out, Access::ComputeShaderWriteStorage)
            } else {
                p.write(out, Access::ComputeShaderReadWriteStorage)
            };
            let pipe = self.pipe.handle();
            p.record(move |rc| {
                let binds = [Bind::StorageBuffer(v), Bind::StorageBuffer(o)];
                dispatch(rc, pipe, &binds, &bytes_of(&push), [groups(r / 2, 32), count, 1])
            });
            vis = v;
            out = o;
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

//! The compute ray tracer (`glsl/trace/trace.comp`, traversal in `glsl/include/kdtree.glsl`): a pass
//! hands a ray buffer and gets a hit buffer, through the kd-tree of [`crate::kdtree`].
//!
//! Rays: 32 bytes each, `(origin.xyz, tmin), (direction.xyz, tmax)` as f32 (see [`Ray`]).
//! Hits: 16 bytes each, `(t, b1, b2, triangle index as u32 bits)`; `t < 0` is a miss. Any-hit
//! mode stops at the first hit found (its `t` only says "occluded").
//!
//! Traversal: front-to-back kd-tree walk with a short stack of 6 entries held in registers (Horn et al. 2007):
//! entries pushed beyond it drop the farthest one, and when the stack runs dry after a drop the
//! ray restarts from the root with `tmin` moved past the finished cells (kd-restart). No per-ray
//! stack lives in memory. Triangles are tested with the watertight test of Woop, Benthin and
//! Wald (2013) (without its double-precision fallback). Self-intersection policy: the tracer
//! honours `[tmin, tmax]` exactly; callers leaving a surface offset the origin along the
//! geometric normal by [`crate::kdtree::ray_epsilon`] (as the CPU reference does).

use crate::kdtree::KdTreeHandles;
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline};
use anyhow::Result;
use glam::Vec3;
use obvhs::{
    cwbvh::{builder::build_cwbvh_from_tris, CwBvh},
    ray::{Ray as ORay, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};
use obvhs_glam::Vec3A;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, Graph, PassKind};
use std::sync::Arc;

pub const RAY_BYTES: u64 = 32;
pub const HIT_BYTES: u64 = 16;
/// Rays each invocation traces in turn (amortises the per-invocation cost of software drivers).
pub const RAYS_PER_INVOCATION: u32 = 8;

/// Query kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TraceMode {
    /// Visibility: any hit in `[tmin, tmax]`.
    AnyHit,
    /// The closest hit in `[tmin, tmax]`, with barycentrics and triangle index.
    ClosestHit,
}

/// One ray as laid out in the ray buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ray {
    pub origin: [f32; 3],
    pub tmin: f32,
    pub dir: [f32; 3],
    pub tmax: f32,
}

impl Ray {
    pub fn new(o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Self {
        Ray { origin: o.to_array(), tmin, dir: d.to_array(), tmax }
    }
}

/// One decoded hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub b1: f32,
    pub b2: f32,
    pub triangle: u32,
}

/// Decodes a hit buffer; `None` for misses.
pub fn decode_hits(bytes: &[u8]) -> Vec<Option<Hit>> {
    bytes
        .chunks_exact(16)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes(c[4 * i..4 * i + 4].try_into().unwrap());
            let t = f(0);
            (t >= 0.0).then(|| Hit { t, b1: f(1), b2: f(2), triangle: f(3).to_bits() })
        })
        .collect()
}

/// The tracer's pipeline.
pub struct Tracer {
    pipeline: Pipeline,
}

impl Tracer {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let pipeline = compute_pipeline(ctx, shaders, "trace/trace.comp", 8)?;
        Ok(Tracer { pipeline })
    }

    /// Adds a `trace` pass: every ray of `rays` (its size / 32 rays) through `tree`; returns the
    /// hit buffer (transient, 16 bytes per ray).
    pub fn add_trace(
        &self,
        graph: &mut Graph,
        tree: &KdTreeHandles,
        rays: BufferHandle,
        mode: TraceMode,
    ) -> BufferHandle {
        let count = (graph.resource(rays).desc.bytes() / RAY_BYTES) as u32;
        // Names follow the ray buffer's (unique per graph): `trace_any:<rays>`, `<rays>.hits`.
        let rays_name = graph.resource(rays).name.clone();
        let hits = graph.create_buffer(&format!("{rays_name}.hits"), (count as u64 * HIT_BYTES).max(HIT_BYTES));
        let kind = if mode == TraceMode::AnyHit { "trace_any" } else { "trace_closest" };
        let mut p = graph.pass(&format!("{kind}:{rays_name}"), PassKind::Compute);
        let kd = tree.read(&mut p);
        let rays = p.read(rays, Access::ComputeShaderReadSampled);
        let hits = p.write(hits, Access::ComputeShaderWriteStorage);
        let push = [count, (mode == TraceMode::AnyHit) as u32];
        let pipe = self.pipeline.handle();
        p.record(move |rc| {
            let binds = [kd.binds().as_slice(), &[Bind::TexelBuffer(rays), Bind::StorageBuffer(hits)]].concat();
            crate::util::dispatch(rc, pipe, &binds, &bytes_of(&push), [groups(count, 64 * RAYS_PER_INVOCATION), 1, 1])
        });
        hits
    }
}

/// `tracer.add_trace(...)` as a free function: rays in, hits out.
pub fn add_trace(
    graph: &mut Graph,
    tracer: &Tracer,
    tree: &KdTreeHandles,
    rays: BufferHandle,
    mode: TraceMode,
) -> BufferHandle {
    tracer.add_trace(graph, tree, rays, mode)
}

/// A host-initialised ray buffer.
pub fn upload_rays(graph: &mut Graph, name: &str, rays: &[Ray]) -> BufferHandle {
    graph.create_buffer_init(name, bytes_of(rays))
}

/// Copies `size` bytes of `src` into a new readback buffer `name`; returns (readback, src).
pub fn add_copy_to_readback(
    graph: &mut Graph,
    src: BufferHandle,
    name: &str,
    size: u64,
) -> (BufferHandle, BufferHandle) {
    let rb = graph.create_readback(name, size.max(4));
    let (s, d) = crate::util::copy_buffer(graph, &format!("readback_{name}"), src, rb, Some(size));
    (d, s)
}

fn a(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

/// The CPU twin of the tracer: an `obvhs` CWBVH over triangles (Möller-Trumbore test), for CPU
/// work that must not wait on the GPU (avs's `adaptation = cpu`) and for the tracer's tests and
/// benchmark.
pub struct CpuBvh {
    tris: Vec<Triangle>,
    bvh: Option<CwBvh>,
}

impl CpuBvh {
    pub fn new(tris: &[[Vec3; 3]]) -> Self {
        let tris: Vec<Triangle> = tris.iter().map(|t| Triangle { v0: a(t[0]), v1: a(t[1]), v2: a(t[2]) }).collect();
        let bvh = (!tris.is_empty())
            .then(|| build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Default::default()));
        CpuBvh { tris, bvh }
    }

    fn oray(r: &Ray) -> ORay {
        ORay::new(a(Vec3::from(r.origin)), a(Vec3::from(r.dir)), r.tmin, r.tmax)
    }

    /// Closest hit: (t, triangle).
    pub fn closest(&self, r: &Ray) -> Option<(f32, u32)> {
        let bvh = self.bvh.as_ref()?;
        let mut hit = RayHit::none();
        let tris = &self.tris;
        let found = bvh
            .ray_traverse(Self::oray(r), &mut hit, |ray, id| tris[bvh.primitive_indices[id] as usize].intersect(ray));
        (found && hit.t.is_finite()).then(|| (hit.t, bvh.primitive_indices[hit.primitive_id as usize]))
    }

    /// Any hit in [tmin, tmax].
    pub fn occluded(&self, r: &Ray) -> bool {
        let Some(bvh) = self.bvh.as_ref() else { return false };
        let tris = &self.tris;
        !bvh.ray_traverse_miss(Self::oray(r), |ray, id| tris[bvh.primitive_indices[id] as usize].intersect(ray))
    }
}

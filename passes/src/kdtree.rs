//! kd-tree over the frame's world-space triangles, built on the GPU in compute passes
//! (`glsl/trace/kdtree_init.comp`, `glsl/trace/kdtree_build.comp`), kept in persistent buffers and rebuilt only
//! when geometry moved or deformed (static scenes build once). The same buffers can hold a
//! threaded BVH built on the host instead ([`Structure::Bvh`], session 39: `obvhs`'s BVH2 laid
//! out depth first with miss links, the default on a CPU device such as lavapipe, where its
//! stackless walk runs 2-3x faster than the kd-tree's and its host build is faster than the
//! device build); `kd_trace` in `glsl/include/kdtree.glsl` walks whichever the header names, so
//! every technique traces either without a change.
//!
//! # Build (after Zhou, Hou, Wang and Guo 2008, with the differences listed)
//! Breadth first, two compute dispatches per tree level, with no host read-back (every dispatch
//! reads the level's node range from counters the previous one wrote):
//! - `kdtree_level<L>` (`glsl/trace/kdtree_build.comp`), nodes with more than
//!   [`KdTreeParams::small_max`] references, one workgroup (64 invocations) per node, visiting only
//!   the nodes their parents listed as large:
//!   - *large-node stage* (more than [`KdTreeParams::large_threshold`] references): the
//!     references' tight bounds (clipped to the cell) are reduced in shared memory; if one side of
//!     the cell is more than 25% empty the empty space is cut off, else the node is split at the
//!     spatial median of the tight bounds' longest axis (Zhou et al.: same rules);
//!   - medium nodes: the SAH below, binned cooperatively;
//! - `kdtree_level<L>_small` (`glsl/trace/kdtree_small.comp`), *small-node stage*: one invocation per
//!   node (as Zhou et al.), SAH (traversal cost 1, intersection cost 1.5) on 16 bins per axis over
//!   the cell; a leaf when no split beats the leaf cost, at most [`KdTreeParams::leaf_size`]
//!   references, or at [`KdTreeParams::max_depth`].
//!
//! Differences from Zhou et al.: in the large-node stage one workgroup per node instead of
//! triangle-chunk parallelism with segmented scans; binned SAH (16 bins) instead of the exact SAH
//! over all triangle-bound candidates with bit-mask triangle sets; triangle bounds are clipped to
//! the cell as boxes (the triangle's box intersected with the cell), not by clipping the
//! triangle; children's references are appended to one growing reference buffer (interior
//! nodes' lists are not compacted away), so the reference buffer holds every level's lists;
//! storage is bounded by [`KdTreeParams`] and an overflow turns the node into a leaf (still
//! correct, slower) and sets a flag in [`KdStats`].
//!
//! References are assigned conservatively: a triangle goes to every child whose cell, grown by
//! `eps` = 1e-5 x the scene extent, its clipped bounds touch and the triangle itself overlaps
//! (the separating-axis test of Akenine-Moller 2001, `kd_tri_box_overlap` in
//! `glsl/include/kdtree_build.glsl`), so rounding in the traversal cannot skip it, while a slanted
//! triangle whose box reaches a cell it passes beside is not referenced there (session 32: 1.4-2.6x
//! fewer leaf references, hat_on_cloth 37 866 -> 16 662, chess_set 3.7 M -> 1.4 M, which no
//! longer overflows its storage).
//!
//! # Buffers (layout shared with `glsl/include/kdtree.glsl`)
//! - `kdtree.tris`: 3 vec4 per triangle (world-space vertices; `w` of the first = 1: the
//!   triangle casts no shadow and any-hit queries skip it);
//! - `kdtree.nodes`: uvec4 per node (see the include);
//! - `kdtree.refs`: u32 triangle indices;
//! - `kdtree.header`: 128 u32 counters, then the large-node lists: 0 references allocated, 1 leaves, 2 references in leaves,
//!   3 deepest leaf level, 4 overflow flags (1 references, 2 nodes), 5 empty leaves, 6 triangles,
//!   8..14 scene box (f32 bits), 16+L nodes allocated on level L, 64+L first node of level L,
//!   112/113 large-node list lengths (level parity), 114/115 list overflow flags; 128.. lists;
//!   word 7 = 1: the buffers hold a threaded BVH instead: `nodes` has 2 uvec4 per node, then
//!   the leaves' triangles copied in leaf order, 3 uvec4 each (from word 65's index on), `refs`
//!   is unused, the header holds 1 leaves, 2 triangles in leaves, 3 depth, 6 triangles, the box
//!   and 64 the node count.

use crate::util::{bytes_of, compute_pipeline, groups, Pipeline};
use anyhow::{anyhow, bail, Result};
use glam::{Mat3, Vec3};
use penumbra_engine::graph::PassBuilder;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{Access, Bind, BufferHandle, Context, FrameStore, Graph, PassKind};
use penumbra_scene::{Frame, Instance, MeshData, Scene};
use std::sync::Arc;

/// Header words: 128 counters, then two large-node lists of 4096 entries
/// (`glsl/include/kdtree_build.glsl`).
pub const HEADER_WORDS: u64 = 128 + 2 * 4096;
/// Words of the header holding the counters and statistics.
pub const STATS_WORDS: u64 = 128;
/// Header word saying which structure the buffers hold (0 kd-tree, 1 threaded BVH).
const HDR_STRUCTURE: usize = 7;
const MAX_LEVELS: u32 = 40;

/// Build parameters.
#[derive(Clone, Copy, Debug)]
pub struct KdTreeParams {
    /// Deepest level (root = level 0); `None`: 8 + 1.3 log2(triangles) (Havran), at most 40.
    pub max_depth: Option<u32>,
    /// Nodes with at most this many references become leaves.
    pub leaf_size: u32,
    /// Nodes with more references are split by the large-node rules.
    pub large_threshold: u32,
    /// Nodes with at most this many references are processed one per invocation
    /// (`glsl/trace/kdtree_small.comp`), larger ones one per workgroup.
    pub small_max: u32,
    /// Node capacity per triangle (plus 8192).
    pub nodes_per_triangle: u32,
    /// Reference capacity per triangle (plus 32768); all levels' lists live in it.
    pub refs_per_triangle: u32,
    /// The structure the tracer walks ([`KdTreeBuilder::new`] takes the context's
    /// `ContextDesc::tracer`; `auto` picks [`Structure::Bvh`] on a CPU device).
    pub structure: Structure,
}

/// The acceleration structure behind the tracer; both live in the same four buffers and
/// `kd_trace` (`glsl/include/kdtree.glsl`) walks either, told by the header's word 7.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Structure {
    /// The kd-tree built on the device (module docs), the default on a GPU.
    #[default]
    KdTree,
    /// A threaded BVH built on the host by `obvhs` (binned PLOC, leaves of up to 8 triangles)
    /// and uploaded (session 39): on lavapipe its walk is 2-3x faster than the kd-tree's (no
    /// stack: each node holds its box and a miss link, the next node in depth-first order when
    /// the ray misses it or after its leaf), and the host build is faster than the device build
    /// there; the default on a CPU device. Any-hit queries end at the first hit; closest-hit
    /// ones walk the whole tree in a fixed order, shrinking `tmax`.
    Bvh,
}

impl Default for KdTreeParams {
    fn default() -> Self {
        KdTreeParams {
            max_depth: None,
            leaf_size: 2,
            large_threshold: 256,
            small_max: 64,
            nodes_per_triangle: 12,
            refs_per_triangle: 96,
            structure: Structure::KdTree,
        }
    }
}

/// Build statistics (read back from `kdtree.header`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KdStats {
    pub triangles: u32,
    pub nodes: u32,
    pub leaves: u32,
    pub empty_leaves: u32,
    /// Triangle references in leaves.
    pub leaf_refs: u32,
    /// Deepest leaf level (root = 0).
    pub depth: u32,
    /// References allocated during the build (all levels).
    pub refs_allocated: u32,
    /// 1: reference storage overflowed, 2: node storage overflowed (nodes became leaves).
    pub overflow: u32,
    /// Bytes of the tree buffers (triangles, nodes, references, header) as allocated.
    pub bytes_allocated: u64,
    /// Bytes in use: triangles + nodes x 16 + references allocated x 4 + header (a BVH: nodes
    /// x 32, its leaves' triangle copies x 48, its counters).
    pub bytes_used: u64,
    /// Which structure the header describes.
    pub structure: Structure,
    /// A threaded BVH's depth-first orders in the buffers (7, or 1 when the node buffer cannot
    /// hold seven); 0 for a kd-tree.
    pub bvh_orders: u32,
}

/// Handles of the tree in one frame's graph (latest versions).
#[derive(Clone, Copy, Debug)]
pub struct KdTreeHandles {
    pub tris: BufferHandle,
    pub nodes: BufferHandle,
    pub refs: BufferHandle,
    pub header: BufferHandle,
    pub triangles: u32,
    /// Largest absolute coordinate (at least 1): scales ray offsets, see [`ray_epsilon`].
    pub extent: f32,
    /// The tree is (re)built in this frame's graph.
    pub built_this_frame: bool,
}

impl KdTreeHandles {
    /// The four buffers in binding order: triangles, nodes, references, header.
    pub fn buffers(&self) -> [BufferHandle; 4] {
        [self.tris, self.nodes, self.refs, self.header]
    }
}

/// The tree's four buffers as read by one tracing pass (bindings `tris, nodes, refs, header`
/// in that order, as the users of `glsl/include/kdtree.glsl` declare them).
#[derive(Clone, Copy, Debug)]
pub struct KdTreeReads {
    pub tris: BufferHandle,
    pub nodes: BufferHandle,
    pub refs: BufferHandle,
    pub header: BufferHandle,
}

impl KdTreeHandles {
    /// Declares the pass's reads of the tree by compute shaders (texel reads of the triangles,
    /// nodes and refs, a storage read of the header).
    pub fn read(&self, p: &mut PassBuilder<'_>) -> KdTreeReads {
        KdTreeReads::declare(p, self.buffers(), false)
    }
}

impl KdTreeReads {
    /// Declares a pass's reads of a tree's four buffers (triangles, nodes, refs, header: as
    /// [`KdTreeHandles::buffers`] or stand-ins): texel reads of the first three and a storage
    /// read of the header, by compute shaders, or by any stage (`any_stage`: a raster pass).
    pub fn declare(p: &mut PassBuilder<'_>, b: [BufferHandle; 4], any_stage: bool) -> Self {
        let (texel, storage) = if any_stage {
            (Access::AnyShaderReadSampled, Access::AnyShaderReadStorage)
        } else {
            (Access::ComputeShaderReadSampled, Access::ComputeShaderReadStorage)
        };
        KdTreeReads {
            tris: p.read(b[0], texel),
            nodes: p.read(b[1], texel),
            refs: p.read(b[2], texel),
            header: p.read(b[3], storage),
        }
    }

    /// The four bindings, in declaration order: the triangles, nodes and refs as texel buffers
    /// (`usamplerBuffer`, `glsl/include/kdtree.glsl`), the header as a storage buffer.
    pub fn binds(&self) -> [Bind; 4] {
        [
            Bind::TexelBuffer(self.tris),
            Bind::TexelBuffer(self.nodes),
            Bind::TexelBuffer(self.refs),
            Bind::StorageBuffer(self.header),
        ]
    }
}

/// Self-intersection offset policy of the tracer's users: a ray leaving a surface starts at
/// `p + ng * ray_epsilon(extent)` with `ng` the geometric normal turned towards the ray (the same
/// offset as the CPU reference, `1e-4 x` the largest absolute scene coordinate), and `tmin = 0`.
/// The traversal itself honours `[tmin, tmax]` exactly.
pub fn ray_epsilon(extent: f32) -> f32 {
    1e-4 * extent.max(1.0)
}

/// One frame instance's mesh (the deformed mesh where the frame has one) with its vertices in
/// world space.
pub struct WorldMesh<'a> {
    /// The object's name (for errors).
    pub name: &'a str,
    pub inst: &'a Instance,
    pub mesh: &'a MeshData,
    pub positions: Vec<Vec3>,
}

impl WorldMesh<'_> {
    /// The non-degenerate triangles as (vertex indices, world corners), in index order; an
    /// index out of range or a non-finite vertex is an error naming the mesh and the object.
    pub fn triangles(&self) -> impl Iterator<Item = Result<([usize; 3], [Vec3; 3])>> + '_ {
        self.mesh.indices.chunks_exact(3).filter_map(move |t| {
            let i = [t[0] as usize, t[1] as usize, t[2] as usize];
            let np = self.positions.len();
            if i.iter().any(|&k| k >= np) {
                return Some(Err(anyhow!(
                    "mesh '{}' of object '{}' has an index out of range ({np} vertices)",
                    self.mesh.name,
                    self.name
                )));
            }
            let p = i.map(|k| self.positions[k]);
            if !p.iter().all(|v| v.is_finite()) {
                return Some(Err(anyhow!(
                    "mesh '{}' of object '{}' has non-finite vertices",
                    self.mesh.name,
                    self.name
                )));
            }
            ((p[1] - p[0]).cross(p[2] - p[0]).length_squared() > 0.0).then_some(Ok((i, p)))
        })
    }
}

/// The frame's instances in world space, in instance order. A missing mesh or a non-finite
/// transform is an error naming the object.
pub fn world_meshes<'a>(scene: &'a Scene, frame: &'a Frame) -> Result<Vec<WorldMesh<'a>>> {
    frame
        .instances
        .iter()
        .map(|inst| {
            let name = scene.objects.get(inst.object).map(|o| o.name.as_str()).unwrap_or("?");
            let mesh = match inst.deformed_mesh.as_deref() {
                Some(m) => m,
                None => match scene.meshes.get(inst.mesh) {
                    Some(m) => m,
                    None => bail!("object '{name}' refers to mesh {} of {}", inst.mesh, scene.meshes.len()),
                },
            };
            if !inst.world.is_finite() {
                bail!("object '{name}' has a non-finite world transform");
            }
            let positions = mesh.positions.iter().map(|p| inst.world.transform_point3(*p)).collect();
            Ok(WorldMesh { name, inst, mesh, positions })
        })
        .collect()
}

/// The frame's world-space triangles (deformed meshes where the frame has them), degenerate
/// triangles dropped, in instance order. Errors name the object at fault.
pub fn world_triangles(scene: &Scene, frame: &Frame) -> Result<Vec<[Vec3; 3]>> {
    let mut out = Vec::new();
    for wm in world_meshes(scene, frame)? {
        for t in wm.triangles() {
            out.push(t?.1);
        }
    }
    Ok(out)
}

/// Parses the header read back after a build (see [`KdTreeBuilder::add_stats_readback`]).
pub fn parse_stats(header: &[u8], allocated: u64) -> Option<KdStats> {
    if header.len() < STATS_WORDS as usize * 4 {
        return None;
    }
    let w = |i: usize| u32::from_le_bytes(header[4 * i..4 * i + 4].try_into().unwrap());
    let triangles = w(6);
    if w(HDR_STRUCTURE) == 1 {
        // threaded BVH: 32 bytes per node, a 48-byte copy per leaf triangle
        let (nodes, refs) = (w(64), w(2));
        return Some(KdStats {
            triangles,
            nodes,
            leaves: w(1),
            empty_leaves: 0,
            leaf_refs: refs,
            depth: w(3),
            refs_allocated: refs,
            overflow: 0,
            bytes_allocated: allocated,
            bytes_used: triangles as u64 * 48
                + nodes as u64 * 32 * w(66).max(1) as u64
                + refs as u64 * 48
                + STATS_WORDS * 4,
            structure: Structure::Bvh,
            bvh_orders: w(66),
        });
    }
    // Dispatch L writes the first node of level L + 1: the largest such entry is the total.
    let nodes = (0..=MAX_LEVELS as usize).map(|l| w(64 + l)).max().unwrap_or(0);
    let refs_allocated = w(0);
    Some(KdStats {
        structure: Structure::KdTree,
        bvh_orders: 0,
        triangles,
        nodes,
        leaves: w(1),
        empty_leaves: w(5),
        leaf_refs: w(2),
        depth: w(3),
        refs_allocated,
        overflow: w(4),
        bytes_allocated: allocated,
        // (after an overflow the allocation counter overshoots the capacity)
        bytes_used: (triangles as u64 * 48 + nodes as u64 * 16 + refs_allocated as u64 * 4 + HEADER_WORDS * 4)
            .min(allocated.max(1)),
    })
}

/// Builds the tree (pipelines and the rebuild decision).
pub struct KdTreeBuilder {
    init: Pipeline,
    build: Pipeline,
    small: Pipeline,
    pub params: KdTreeParams,
    /// Triangle count of the tree in the persistent buffers, if one was built.
    built: Option<u32>,
    /// Levels dispatched by the last build.
    pub last_levels: u32,
    /// Bytes allocated by the last build.
    pub last_bytes: u64,
    extent: f32,
}

impl KdTreeBuilder {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let init = compute_pipeline(ctx, shaders, "trace/kdtree_init.comp", 32)?;
        let build = compute_pipeline(ctx, shaders, "trace/kdtree_build.comp", 32)?;
        let small = compute_pipeline(ctx, shaders, "trace/kdtree_small.comp", 32)?;
        let structure = match ctx.tracer {
            penumbra_engine::TracerStructure::KdTree => Structure::KdTree,
            penumbra_engine::TracerStructure::Bvh => Structure::Bvh,
            penumbra_engine::TracerStructure::Auto => {
                // SAFETY: the context's instance and physical device are alive.
                let props = unsafe { ctx.instance.get_physical_device_properties(ctx.physical) };
                if props.device_type == penumbra_engine::vk::PhysicalDeviceType::CPU {
                    Structure::Bvh
                } else {
                    Structure::KdTree
                }
            }
        };
        Ok(KdTreeBuilder {
            init,
            build,
            small,
            params: KdTreeParams { structure, ..KdTreeParams::default() },
            built: None,
            last_levels: 0,
            last_bytes: 0,
            extent: 1.0,
        })
    }

    fn sizes(&self, n: u32) -> (u64, u64, u64, u32) {
        let n64 = n as u64;
        let tris = (n64 * 48).max(48);
        let max_nodes = (n64 * self.params.nodes_per_triangle as u64 + 8192).min(u32::MAX as u64 / 2) & !1;
        let refs = (n64 * self.params.refs_per_triangle as u64 + 32768).min(u32::MAX as u64 / 8);
        (tris, max_nodes, refs, max_nodes as u32)
    }

    /// The tree's persistent buffers for `n` triangles: (name, bytes) in binding order.
    fn persistent_buffers(&self, n: u32) -> [(&'static str, u64); 4] {
        let (tri_bytes, max_nodes, refs, _) = self.sizes(n);
        [
            ("kdtree.tris", tri_bytes),
            ("kdtree.nodes", max_nodes * 16),
            // whole 16-byte texels: the shaders read the refs four to a texel
            ("kdtree.refs", crate::util::texel_bytes(refs * 4)),
            ("kdtree.header", HEADER_WORDS * 4),
        ]
    }

    fn persistent(&self, engine: &mut FrameStore<'_>, graph: &mut Graph, n: u32) -> (KdTreeHandles, u64) {
        let b = self.persistent_buffers(n);
        let [tris, nodes, refs, header] = b.map(|(name, size)| engine.persistent_buffer(graph, name, size));
        let h = KdTreeHandles { tris, nodes, refs, header, triangles: n, extent: 1.0, built_this_frame: false };
        (h, b.iter().map(|(_, size)| size).sum())
    }

    /// The tree of `tris`; built in this graph when `rebuild` or when the persistent buffers are
    /// new (first use, size change).
    pub fn add_triangles(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        tris: &[[Vec3; 3]],
        rebuild: bool,
    ) -> Result<KdTreeHandles> {
        self.add_triangles_flagged(engine, graph, tris, None, rebuild)
    }

    /// As [`KdTreeBuilder::add_triangles`]; triangles with `no_shadow[i]` are skipped by any-hit
    /// (visibility) queries (`ObjectInfo::casts_shadow == false`), closest-hit still finds them.
    pub fn add_triangles_flagged(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        tris: &[[Vec3; 3]],
        no_shadow: Option<&[bool]>,
        rebuild: bool,
    ) -> Result<KdTreeHandles> {
        if no_shadow.is_some_and(|f| f.len() != tris.len()) {
            bail!("kd-tree: {} shadow flags for {} triangles", no_shadow.map_or(0, |f| f.len()), tris.len());
        }
        if tris.len() > (u32::MAX / 64) as usize {
            bail!("kd-tree: {} triangles is more than supported", tris.len());
        }
        let n = tris.len() as u32;
        let (h, bytes) = self.persistent(engine, graph, n);
        let fresh = [h.tris, h.nodes, h.refs, h.header].iter().any(|b| graph.persistent_is_new(*b));
        if !(rebuild || fresh || self.built != Some(n)) {
            return Ok(KdTreeHandles { extent: self.extent, ..h });
        }
        self.build_into(graph, h, bytes, tris, no_shadow)
    }

    /// The tree of `frame`'s triangles ([`world_triangles_shading`], shadow flags from the
    /// objects): the kept one when nothing moved or deformed and its buffers survived (the
    /// triangles are then not even gathered), else built in this graph.
    pub fn add_frame(
        &mut self,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        scene: &Scene,
        frame: &Frame,
    ) -> Result<KdTreeHandles> {
        let moved = frame.any_moved() || frame.any_deformed();
        if !moved {
            if let Some(t) = self.add_kept(engine, graph) {
                return Ok(t);
            }
        }
        let (tris, _, no_shadow) = world_triangles_shading(scene, frame)?;
        self.add_triangles_flagged(engine, graph, &tris, Some(&no_shadow), moved)
    }

    /// For a technique whose shader binds the tree only sometimes: with a `builder`, its tree of
    /// `frame` ([`KdTreeBuilder::add_frame`]) and true; without, four empty stand-in buffers
    /// (`<prefix>_kd_none<i>`, for a shader told not to read them) and false. The buffers in
    /// binding order (triangles, nodes, references, header).
    pub fn add_frame_or_stand_ins(
        builder: Option<&mut Self>,
        engine: &mut FrameStore<'_>,
        graph: &mut Graph,
        scene: &Scene,
        frame: &Frame,
        prefix: &str,
    ) -> Result<([BufferHandle; 4], bool)> {
        Ok(match builder {
            Some(b) => (b.add_frame(engine, graph, scene, frame)?.buffers(), true),
            None => (
                std::array::from_fn(|i| graph.create_buffer_init(&format!("{prefix}_kd_none{i}"), vec![0u8; 16])),
                false,
            ),
        })
    }

    /// The kept tree's handles when one was built and its buffers survived (no rebuild). When
    /// they did not (first use, or a frame that built the tree was never submitted), nothing is
    /// declared in `graph`: the caller builds the tree there.
    pub fn add_kept(&mut self, engine: &mut FrameStore<'_>, graph: &mut Graph) -> Option<KdTreeHandles> {
        let n = self.built?;
        if !self.persistent_buffers(n).iter().all(|(name, size)| engine.has_persistent_buffer(name, *size)) {
            return None;
        }
        let (probe, _) = self.persistent(engine, graph, n);
        Some(KdTreeHandles { extent: self.extent, ..probe })
    }

    fn build_into(
        &mut self,
        graph: &mut Graph,
        mut h: KdTreeHandles,
        bytes: u64,
        tris: &[[Vec3; 3]],
        no_shadow: Option<&[bool]>,
    ) -> Result<KdTreeHandles> {
        let n = tris.len() as u32;
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(-f32::MAX));
        let mut extent = 1.0f32;
        for t in tris {
            for v in t {
                if !v.is_finite() {
                    bail!("kd-tree: non-finite vertex {v}");
                }
                lo = lo.min(*v);
                hi = hi.max(*v);
                extent = extent.max(v.abs().max_element());
            }
        }
        h.extent = extent;
        let eps = 1e-5 * extent;
        if n > 0 {
            lo -= Vec3::splat(4.0 * eps);
            hi += Vec3::splat(4.0 * eps);
        }
        let max_depth = self
            .params
            .max_depth
            .unwrap_or_else(|| (8.0 + 1.3 * (n.max(1) as f32).log2()).round() as u32)
            .clamp(1, MAX_LEVELS);
        let (_, max_nodes, ref_cap, _) = self.sizes(n);

        // ---- upload the triangles into the persistent buffer
        let mut data = Vec::with_capacity(tris.len() * 12);
        for (i, t) in tris.iter().enumerate() {
            let skip = no_shadow.is_some_and(|f| f[i]);
            for (k, v) in t.iter().enumerate() {
                data.extend_from_slice(&[v.x, v.y, v.z, if k == 0 && skip { 1.0 } else { 0.0 }]);
            }
        }
        if data.is_empty() {
            data = vec![0.0; 12];
        }
        let upload = graph.create_buffer_init("kdtree.upload", bytes_of(&data));
        let size = data.len() as u64 * 4;
        h.tris = crate::util::copy_buffer(graph, "kdtree_upload", upload, h.tris, Some(size)).1;
        if self.params.structure == Structure::Bvh {
            if n >= 1 << 24 {
                bail!("threaded BVH: {n} triangles is more than its 24-bit leaf references hold");
            }
            let bvh = ThreadedBvh::build(tris, eps);
            let mut header = vec![0u32; STATS_WORDS as usize];
            header[1] = bvh.leaves;
            header[2] = bvh.refs.len() as u32;
            header[3] = bvh.depth;
            header[6] = n;
            header[HDR_STRUCTURE] = 1;
            for a in 0..3 {
                header[8 + a] = lo[a].to_bits();
                header[11 + a] = hi[a].to_bits();
            }
            let per_layout = bvh.nodes.len() / BVH_LAYOUTS;
            header[64] = per_layout as u32;
            // the orders fit the node buffer (leaves of ~2-8 triangles), else the first alone
            let layouts = if (2 * bvh.nodes.len() + 3 * bvh.refs.len()) as u64 <= max_nodes { BVH_LAYOUTS } else { 1 };
            header[66] = layouts as u32;
            let bvh = ThreadedBvh { nodes: bvh.nodes[..per_layout * layouts].to_vec(), ..bvh };
            // the leaves' triangles copied in leaf order after the nodes, 3 uvec4 each (v0, v1, v2;
            // v0.w the input index, bit 31 set when the triangle casts no shadow): no indirection
            let base = 2 * bvh.nodes.len() as u32;
            header[65] = base;
            let mut nodes: Vec<[u32; 4]> =
                bvh.nodes.iter().flat_map(|n| [[n[0], n[1], n[2], n[3]], [n[4], n[5], n[6], n[7]]]).collect();
            for &k in &bvh.refs {
                let t = &tris[k as usize];
                let flag = if no_shadow.is_some_and(|f| f[k as usize]) { 1 << 31 } else { 0 };
                nodes.push([t[0].x.to_bits(), t[0].y.to_bits(), t[0].z.to_bits(), k | flag]);
                nodes.push([t[1].x.to_bits(), t[1].y.to_bits(), t[1].z.to_bits(), 0]);
                nodes.push([t[2].x.to_bits(), t[2].y.to_bits(), t[2].z.to_bits(), 0]);
            }
            if nodes.is_empty() {
                nodes.push([0; 4]);
            }
            if nodes.len() as u64 > max_nodes {
                bail!("threaded BVH: {} node words exceed the node buffer's {max_nodes}", nodes.len());
            }
            for (name, data, dst) in [
                ("kdtree_bvh_nodes", bytes_of(&nodes), &mut h.nodes),
                ("kdtree_bvh_header", bytes_of(&header), &mut h.header),
            ] {
                let size = data.len() as u64;
                let src = graph.create_buffer_init(&format!("{name}.upload"), data);
                *dst = crate::util::copy_buffer(graph, name, src, *dst, Some(size)).1;
            }
            h.built_this_frame = true;
            self.built = Some(n);
            self.extent = extent;
            self.last_levels = 0;
            self.last_bytes = bytes;
            return Ok(h);
        }

        // ---- init: root, counters
        let boxes = graph.create_buffer("kdtree.boxes", max_nodes * 32);
        let mut push = [0u32; 8];
        for a in 0..3 {
            push[a] = lo[a].to_bits();
            push[4 + a] = hi[a].to_bits();
        }
        push[3] = n;
        let mut p = graph.pass("kdtree_init", PassKind::Compute);
        let [nodes, bx, refs, header] =
            [h.nodes, boxes, h.refs, h.header].map(|h| p.write(h, Access::ComputeShaderWriteStorage));
        let pipe = self.init.handle();
        p.record(move |rc| {
            let binds = crate::util::storage([nodes, bx, refs, header]);
            crate::util::dispatch(rc, pipe, &binds, &bytes_of(&push), [groups(n.max(STATS_WORDS as u32), 64), 1, 1])
        });
        let (mut nodes, mut bx, mut refs, mut header) = (nodes, bx, refs, header);

        // ---- one pass per level
        for level in 0..max_depth {
            let mut push: [u32; 8] = [
                level,
                max_nodes as u32,
                ref_cap.min(u32::MAX as u64) as u32,
                max_depth,
                eps.to_bits(),
                self.params.leaf_size,
                self.params.large_threshold,
                0,
            ];
            push[7] = self.params.small_max;
            // Large nodes (one workgroup each), then small nodes (one invocation each).
            for (stage, pipeline, wgs) in [
                ("", &self.build, 1u32 << level.min(6)),
                ("_small", &self.small, (1u32 << level.min(12)).div_ceil(64).min(64)),
            ] {
                let mut p = graph.pass(&format!("kdtree_level{level}{stage}"), PassKind::Compute);
                let tr = p.read(h.tris, Access::ComputeShaderReadStorage);
                nodes = p.write(nodes, Access::ComputeShaderReadWriteStorage);
                bx = p.write(bx, Access::ComputeShaderReadWriteStorage);
                refs = p.write(refs, Access::ComputeShaderReadWriteStorage);
                header = p.write(header, Access::ComputeShaderReadWriteStorage);
                let pipe = pipeline.handle();
                let binds = crate::util::storage([tr, nodes, bx, refs, header]);
                p.record(move |rc| crate::util::dispatch(rc, pipe, &binds, &bytes_of(&push), [wgs, 1, 1]));
            }
        }
        h.nodes = nodes;
        h.refs = refs;
        h.header = header;
        h.built_this_frame = true;
        self.built = Some(n);
        self.extent = extent;
        self.last_levels = max_depth;
        self.last_bytes = bytes;
        Ok(h)
    }

    /// Copies the header into a readback buffer named `name` (parse with [`parse_stats`]).
    pub fn add_stats_readback(graph: &mut Graph, tree: &mut KdTreeHandles, name: &str) -> BufferHandle {
        let (rb, hd) = crate::trace::add_copy_to_readback(graph, tree.header, name, STATS_WORDS * 4);
        tree.header = hd;
        rb
    }
}

/// Triangles, their shading data and their "casts no shadow" flags.
pub type ShadingTriangles = (Vec<[Vec3; 3]>, Vec<[f32; 4]>, Vec<bool>);

/// World triangles with shading data (6 vec4 each: n0 + material bits, n1, n2, tangent,
/// (uv0, uv1), (uv2, 0, 0)) and
/// shadow flags, in the order of [`crate::kdtree::world_triangles`] (degenerate ones dropped).
pub fn world_triangles_shading(scene: &Scene, frame: &Frame) -> Result<ShadingTriangles> {
    let mut tris = Vec::new();
    let mut data = Vec::new();
    let mut no_shadow = Vec::new();
    for wm in crate::kdtree::world_meshes(scene, frame)? {
        let (name, inst, mesh) = (wm.name, wm.inst, wm.mesh);
        if inst.material >= frame.materials.len() {
            bail!("object '{name}' refers to material {} of {}", inst.material, frame.materials.len());
        }
        let casts = scene.object_info(inst.object).casts_shadow;
        let m3 = Mat3::from_mat4(inst.world);
        let normal_m = if m3.determinant().abs() > 1e-20 { m3.inverse().transpose() } else { m3 };
        let np = mesh.positions.len();
        let has_n = mesh.normals.len() == np;
        let has_uv = mesh.uvs.len() == np;
        for t in wm.triangles() {
            let ([i0, i1, i2], [p0, p1, p2]) = t?;
            let (e1, e2) = (p1 - p0, p2 - p0);
            let ng = e1.cross(e2).normalize();
            let n = [i0, i1, i2].map(|i| {
                if !has_n {
                    return ng;
                }
                let n = (normal_m * mesh.normals[i]).normalize_or_zero();
                if n == Vec3::ZERO || !n.is_finite() {
                    ng
                } else {
                    n
                }
            });
            let mut tangent = Vec3::ZERO;
            if has_uv {
                let (d1, d2) = (mesh.uvs[i1] - mesh.uvs[i0], mesh.uvs[i2] - mesh.uvs[i0]);
                let det = d1.x * d2.y - d1.y * d2.x;
                if det.abs() > 1e-12 {
                    let tt = (e1 * d2.y - e2 * d1.y) / det;
                    if tt.is_finite() {
                        tangent = tt;
                    }
                }
            }
            tris.push([p0, p1, p2]);
            data.push([n[0].x, n[0].y, n[0].z, f32::from_bits(inst.material as u32)]);
            data.push([n[1].x, n[1].y, n[1].z, 0.0]);
            data.push([n[2].x, n[2].y, n[2].z, 0.0]);
            data.push([tangent.x, tangent.y, tangent.z, 0.0]);
            let uv = |i: usize| if has_uv { mesh.uvs[i] } else { glam::Vec2::ZERO };
            let (u0, u1, u2) = (uv(i0), uv(i1), uv(i2));
            data.push([u0.x, u0.y, u1.x, u1.y]);
            data.push([u2.x, u2.y, 0.0, 0.0]);
            no_shadow.push(!casts);
        }
    }
    Ok((tris, data, no_shadow))
}

/// Bounds of the triangles.
pub fn bounds(tris: &[[Vec3; 3]]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(-f32::MAX);
    for t in tris {
        for v in t {
            lo = lo.min(*v);
            hi = hi.max(*v);
        }
    }
    if lo.x > hi.x {
        (Vec3::ZERO, Vec3::ZERO)
    } else {
        (lo, hi)
    }
}

/// Depth-first orders of the threaded BVH: six per axis (x, y, z) and direction sign, the child
/// whose box centre lies nearer along it first, a ray walking the order of its direction's
/// largest component (a closest hit is found, and `tmax` shrinks, sooner); and a seventh for
/// any-hit rays (session 48), which need any occluder, not the nearest: of two children the ray
/// enters, the one with the lower subtree nodes / occlusion probability first (the ordering of
/// Ize and Hansen's RTSAH, "RTSAH Traversal Order for Occlusion Rays", 2011, with the probability
/// that a ray through a box meets its triangles estimated by their area over half the box's
/// surface, at most 1). The board under chess_set's pieces, a few large triangles filling a flat
/// box, comes before the pieces' many small ones: its coherent any-hit rays 2.2x faster (the
/// host build 118 -> 131 ms there).
const BVH_LAYOUTS: usize = 7;

/// A threaded BVH in the tracer's buffers ([`Structure::Bvh`]).
struct ThreadedBvh {
    /// 8 words per node (`glsl/include/kdtree.glsl`): lo.xyz (f32 bits), miss link (the next
    /// node in depth-first order after this one's subtree; `u32::MAX` ends the walk), hi.xyz,
    /// leaf info (0: interior, its first child follows it; else count << 24 | first reference);
    /// [`BVH_LAYOUTS`] copies of the tree, one per depth-first order.
    nodes: Vec<[u32; 8]>,
    /// Triangle indices of the leaves, in leaf order (their triangles are copied in this order
    /// after the nodes).
    refs: Vec<u32>,
    leaves: u32,
    depth: u32,
}

impl ThreadedBvh {
    /// `obvhs`'s BVH2 of `tris` (medium build: binned PLOC with reinsertion, leaves of up to 8),
    /// laid out depth first in [`BVH_LAYOUTS`] orders, each node's first child next to it;
    /// boxes grown by `pad` against rounding in the slab test (a triangle on a box's face must
    /// not be missed).
    fn build(tris: &[[Vec3; 3]], pad: f32) -> Self {
        use obvhs::{bvh2::builder::build_bvh2_from_tris, triangle::Triangle, BvhBuildParams};
        let a = |v: Vec3| obvhs_glam::Vec3A::new(v.x, v.y, v.z);
        let otris: Vec<Triangle> = tris.iter().map(|t| Triangle { v0: a(t[0]), v1: a(t[1]), v2: a(t[2]) }).collect();
        if otris.is_empty() {
            return ThreadedBvh { nodes: Vec::new(), refs: Vec::new(), leaves: 0, depth: 0 };
        }
        let bvh = build_bvh2_from_tris(&otris, BvhBuildParams::medium_build(), &mut Default::default());
        let centre = |n: usize, axis: usize| {
            let b = &bvh.nodes[n].aabb;
            b.min[axis] + b.max[axis]
        };
        // per node: its subtree's node count and triangle area (children after parents in
        // obvhs's array is not guaranteed: a post-order from the root)
        let mut post = Vec::with_capacity(bvh.nodes.len());
        let mut st = vec![0usize];
        while let Some(n) = st.pop() {
            post.push(n);
            let nd = &bvh.nodes[n];
            if nd.prim_count == 0 {
                st.push(nd.first_index as usize);
                st.push(nd.first_index as usize + 1);
            }
        }
        let mut sub_nodes = vec![1f32; bvh.nodes.len()];
        let mut sub_area = vec![0f32; bvh.nodes.len()];
        for &n in post.iter().rev() {
            let nd = &bvh.nodes[n];
            if nd.prim_count == 0 {
                let (l, r) = (nd.first_index as usize, nd.first_index as usize + 1);
                sub_nodes[n] = 1.0 + sub_nodes[l] + sub_nodes[r];
                sub_area[n] = sub_area[l] + sub_area[r];
            } else {
                sub_area[n] = (nd.first_index..nd.first_index + nd.prim_count)
                    .map(|i| {
                        let t = &tris[bvh.primitive_indices[i as usize] as usize];
                        0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
                    })
                    .sum();
            }
        }
        // any-hit order: a ray entering both children should try first the one likelier to stop
        // it per node it costs (RTSAH's ordering, Ize and Hansen 2011, with the occlusion
        // probability estimated by the triangles' area over half the box's surface)
        let any_hit_key = |n: usize| {
            let b = &bvh.nodes[n].aabb;
            let e = b.max - b.min;
            let half_box = (e.x * e.y + e.y * e.z + e.z * e.x).max(1e-30);
            sub_nodes[n] / (sub_area[n] / half_box).clamp(1e-6, 1.0)
        };
        // BVH_LAYOUTS depth-first orders (in parallel): per axis and direction sign, the nearer
        // child first; the last for any-hit rays
        use rayon::prelude::*;
        let layouts: Vec<(Vec<[u32; 8]>, u32, u32)> = (0..BVH_LAYOUTS)
            .into_par_iter()
            .map(|k| {
                let (axis, back) = (k / 2, k % 2 == 1);
                let (mut leaves, mut depth) = (0u32, 0u32);
                let mut order = Vec::with_capacity(bvh.nodes.len());
                let mut stack = vec![(0usize, 0u32)];
                while let Some((n, d)) = stack.pop() {
                    order.push(n);
                    depth = depth.max(d);
                    let nd = &bvh.nodes[n];
                    if nd.prim_count == 0 {
                        let (l, r) = (nd.first_index as usize, nd.first_index as usize + 1);
                        let (near, far) = if k == 6 {
                            if any_hit_key(l) <= any_hit_key(r) {
                                (l, r)
                            } else {
                                (r, l)
                            }
                        } else if (centre(l, axis) <= centre(r, axis)) != back {
                            (l, r)
                        } else {
                            (r, l)
                        };
                        stack.push((far, d + 1));
                        stack.push((near, d + 1));
                    }
                }
                let mut size = vec![1usize; bvh.nodes.len()];
                for &n in order.iter().rev() {
                    let nd = &bvh.nodes[n];
                    if nd.prim_count == 0 {
                        size[n] = 1 + size[nd.first_index as usize] + size[nd.first_index as usize + 1];
                    }
                }
                let mut pos = vec![0usize; bvh.nodes.len()];
                for (i, &n) in order.iter().enumerate() {
                    pos[n] = i;
                }
                let nodes = order
                    .iter()
                    .map(|&n| {
                        let nd = &bvh.nodes[n];
                        let miss = pos[n] + size[n];
                        let miss = if miss >= order.len() { u32::MAX } else { miss as u32 };
                        let info = if nd.prim_count == 0 {
                            0
                        } else {
                            leaves += 1;
                            (nd.prim_count.min(255) << 24) | nd.first_index
                        };
                        let lo = Vec3::new(nd.aabb.min.x, nd.aabb.min.y, nd.aabb.min.z) - Vec3::splat(pad);
                        let hi = Vec3::new(nd.aabb.max.x, nd.aabb.max.y, nd.aabb.max.z) + Vec3::splat(pad);
                        [
                            lo.x.to_bits(),
                            lo.y.to_bits(),
                            lo.z.to_bits(),
                            miss,
                            hi.x.to_bits(),
                            hi.y.to_bits(),
                            hi.z.to_bits(),
                            info,
                        ]
                    })
                    .collect();
                (nodes, leaves, depth)
            })
            .collect();
        let (leaves, depth) = (layouts[0].1, layouts[0].2);
        let nodes = layouts.into_iter().flat_map(|l| l.0).collect();
        ThreadedBvh { nodes, refs: bvh.primitive_indices.clone(), leaves, depth }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The any-hit order (the seventh) walks first into the subtree likelier to stop a ray per
    /// node: a floor of two large triangles before a dense cluster of small ones above it, which
    /// the downward direction's near-first order reaches first.
    #[test]
    fn the_any_hit_order_tries_the_large_occluder_first() {
        let mut tris = vec![
            [Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, 5.0)],
            [Vec3::new(-5.0, 0.0, -5.0), Vec3::new(5.0, 0.0, 5.0), Vec3::new(-5.0, 0.0, 5.0)],
        ];
        // 2048 small triangles scattered in a unit box above the floor
        let mut rng = 12345u32;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 17;
            rng ^= rng << 5;
            rng as f32 / u32::MAX as f32
        };
        for _ in 0..2048 {
            let c = Vec3::new(next() - 0.5, 2.0 + next(), next() - 0.5);
            let e = 0.02;
            tris.push([c, c + Vec3::new(e, 0.0, 0.0), c + Vec3::new(0.0, e, e)]);
        }
        let bvh = ThreadedBvh::build(&tris, 1e-5);
        let per = bvh.nodes.len() / BVH_LAYOUTS;
        let first_leaf = |k: usize| {
            let nodes = &bvh.nodes[k * per..(k + 1) * per];
            let mut i = 0;
            while nodes[i][7] == 0 {
                i += 1; // an interior node's first child follows it
            }
            let (first, count) = ((nodes[i][7] & 0xff_ffff) as usize, (nodes[i][7] >> 24) as usize);
            bvh.refs[first..first + count].to_vec()
        };
        let any = first_leaf(6);
        assert!(!any.is_empty() && any.iter().all(|&t| t < 2), "any-hit order's first leaf: {any:?}");
        // a ray going down (-y: order 3) walks the nearer child first: the cluster above
        let down = first_leaf(3);
        assert!(down.iter().all(|&t| t >= 2), "downward order's first leaf: {down:?}");
    }
}

//! Per-vertex ISG shadowing (the paper's per-vertex mode, section 5): the visibility integrals
//! are evaluated at the mesh vertices in compute (`isg_vertex`, `glsl/isg/isg_vertex.comp`), the
//! raster interpolates them over the triangles (`isg_vertex_raster`, `glsl/isg/isg_vertex.vert/.frag`,
//! an RGBA32F image with its own depth buffer) and `isg_shade_vertex.comp` shades every pixel
//! with them (pixels no receiver triangle covers fall back to the per-pixel evaluation, and so do
//! the pixels of a triangle whose corners' visibilities differ by more than `pixel_refine`: the
//! vertex shader, drawing unindexed, reads its triangle's three corners and writes -1 over its pixels).
//!
//! The receivers are every instance's mesh (deformed when the object deforms) in world space,
//! built on the CPU per frame. A per-vertex method needs vertices where the shadows are: meshes
//! whose longest edge exceeds `max_edge` (world units at the object's scale when first seen,
//! e.g. a two-triangle floor) are split uniformly (every triangle into four, new vertices at the
//! edge midpoints, shared edges split once, so no cracks) until it does; a split vertex is the
//! midpoint of its two parents, so the subdivided surface is the original one and it follows the
//! deformation.
//!
//! Only vertices of triangles that can show are evaluated: triangles entirely outside the view
//! frustum and back faces of closed, one-sided meshes (hidden behind their front faces) are left
//! out of the raster, and vertices no remaining triangle uses are skipped by the compute pass.

use crate::util::Pipeline;
use anyhow::Result;
use glam::{Mat3, Mat4, Vec3};
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Context};
use penumbra_scene::{Frame, MeshData, Scene};
use std::collections::HashMap;
use std::sync::Arc;

/// Vertex as `isg_vertex.comp` reads it and `isg_vertex.vert` rasterizes it (48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IsgVertex {
    /// World position, material index.
    pub pos_mat: [f32; 4],
    /// World normal, flags (bit 0: two-sided, the normal is turned toward the eye; bit 1: no
    /// visible triangle uses the vertex, not evaluated).
    pub normal_flags: [f32; 4],
    /// World tangent (unit, perpendicular to the normal: the direction of increasing u, as the
    /// G-buffer's per pixel; zero where the mesh has no usable uv: the shader's frame then takes
    /// Duff et al.'s basis vector, as the G-buffer does), 0. Ashikhmin-Shirley's anisotropy runs
    /// along it (`as_lobes = 7` per vertex).
    pub tangent: [f32; 4],
}

/// Per-vertex tangents of a triangle mesh: at each vertex the sum of its triangles' unit dP/du
/// (the direction of increasing u, from positions and uvs as the G-buffer computes it per pixel),
/// not normalized (zero where no adjacent triangle has a usable uv mapping, and for every vertex
/// when `uvs` does not match `positions`).
pub fn vertex_tangents(positions: &[Vec3], uvs: &[glam::Vec2], indices: &[u32]) -> Vec<Vec3> {
    let mut t = vec![Vec3::ZERO; positions.len()];
    if uvs.len() != positions.len() {
        return t;
    }
    for tri in indices.chunks_exact(3) {
        let [a, b, c] = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
        if a >= positions.len() || b >= positions.len() || c >= positions.len() {
            continue;
        }
        let (e1, e2) = (positions[b] - positions[a], positions[c] - positions[a]);
        let (d1, d2) = (uvs[b] - uvs[a], uvs[c] - uvs[a]);
        let det = d1.x * d2.y - d1.y * d2.x;
        if !(det.abs() > 1e-12) {
            continue;
        }
        // dP/du (its length and sign from the uv mapping, normalized: each triangle counts alike)
        let Some(dpdu) = ((e1 * d2.y - e2 * d1.y) / det).try_normalize() else { continue };
        for v in [a, b, c] {
            t[v] += dpdu;
        }
    }
    t
}

/// Subdivided topology of one mesh: vertices beyond the mesh's own are midpoints of two earlier
/// ones (`splits`, in order), `indices` the subdivided triangles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Refined {
    pub base_vertices: usize,
    pub splits: Vec<(u32, u32)>,
    pub indices: Vec<u32>,
    /// Subdivision levels applied (each splits every triangle into four).
    pub levels: u32,
}

/// Most triangles a subdivided mesh may reach (levels stop before exceeding it).
pub const MAX_REFINED_TRIANGLES: usize = 1 << 18;

/// Uniform midpoint subdivision of `positions`/`indices` until the longest edge (after `scale`)
/// is at most `max_edge` (no subdivision for `max_edge <= 0`, non-finite values or degenerate
/// input), within [`MAX_REFINED_TRIANGLES`].
pub fn refine(positions: &[Vec3], indices: &[u32], scale: f32, max_edge: f32) -> Refined {
    let n = positions.len();
    let valid: Vec<u32> =
        indices.chunks_exact(3).filter(|t| t.iter().all(|&i| (i as usize) < n)).flatten().copied().collect();
    let mut out = Refined { base_vertices: n, splits: Vec::new(), indices: valid, levels: 0 };
    if !(max_edge > 0.0 && max_edge.is_finite() && scale > 0.0 && scale.is_finite()) {
        return out;
    }
    let (_, levels) =
        subdivision_levels(out.indices.len() / 3, longest_edge(positions, &out.indices) * scale, max_edge);
    let mut count = n as u32;
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(out.indices.len() * 4);
        for t in out.indices.chunks_exact(3) {
            let mut m = |a: u32, b: u32| {
                let key = (a.min(b), a.max(b));
                *mid.entry(key).or_insert_with(|| {
                    out.splits.push(key);
                    count += 1;
                    count - 1
                })
            };
            let (ab, bc, ca) = (m(t[0], t[1]), m(t[1], t[2]), m(t[2], t[0]));
            next.extend_from_slice(&[t[0], ab, ca, ab, t[1], bc, ca, bc, t[2], ab, bc, ca]);
        }
        out.indices = next;
        out.levels += 1;
    }
    out
}

/// The largest scale factor of `w`'s axes (what subdivision measures edges with).
pub fn largest_scale(w: &Mat4) -> f32 {
    w.x_axis.truncate().length().max(w.y_axis.truncate().length()).max(w.z_axis.truncate().length())
}

/// The longest finite edge of the triangles `indices` (triangles with an index outside
/// `positions` are skipped).
pub fn longest_edge(positions: &[Vec3], indices: &[u32]) -> f32 {
    indices
        .chunks_exact(3)
        .filter_map(|t| {
            Some([*positions.get(t[0] as usize)?, *positions.get(t[1] as usize)?, *positions.get(t[2] as usize)?])
        })
        .flat_map(|[a, b, c]| [(a - b).length(), (b - c).length(), (c - a).length()])
        .filter(|l| l.is_finite())
        .fold(0.0f32, f32::max)
}

/// Midpoint-subdivision levels that bring a longest edge of `longest` (world units) to at most
/// `max_edge`: `(asked, applied)`, where `applied` is what [`refine`] does for `triangles`
/// triangles within [`MAX_REFINED_TRIANGLES`] (asked > applied: the budget stopped it short).
pub fn subdivision_levels(triangles: usize, longest: f32, max_edge: f32) -> (u32, u32) {
    if !(max_edge > 0.0 && max_edge.is_finite() && longest > max_edge && longest.is_finite()) {
        return (0, 0);
    }
    // saturating float-to-int cast: 1e-10 asks for 34 levels, f32::MIN_POSITIVE for 127
    let asked = (longest / max_edge).log2().ceil().max(0.0) as u32;
    // at most 15 levels (4^15 triangles per triangle) before the budget: no shift overflows
    let mut levels = asked.min(15);
    while levels > 0 && triangles << (2 * levels) > MAX_REFINED_TRIANGLES {
        levels -= 1;
    }
    (asked, levels)
}

impl Refined {
    /// Per-vertex values of the subdivided mesh (summed at the midpoints, not normalized) from
    /// the base mesh's, as tangents of [`vertex_tangents`].
    pub fn apply_sum(&self, values: &[Vec3]) -> Vec<Vec3> {
        let mut v: Vec<Vec3> = (0..self.base_vertices).map(|i| values.get(i).copied().unwrap_or(Vec3::ZERO)).collect();
        for &(a, b) in &self.splits {
            v.push(v[a as usize] + v[b as usize]);
        }
        v
    }

    /// Positions and normals of the subdivided mesh from the base mesh's.
    pub fn apply(&self, positions: &[Vec3], normals: &[Vec3]) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut p: Vec<Vec3> = positions.to_vec();
        let mut n: Vec<Vec3> = (0..positions.len()).map(|i| normals.get(i).copied().unwrap_or(Vec3::Y)).collect();
        for &(a, b) in &self.splits {
            p.push(0.5 * (p[a as usize] + p[b as usize]));
            n.push((n[a as usize] + n[b as usize]).try_normalize().unwrap_or(n[a as usize]));
        }
        (p, n)
    }
}

/// The receivers of one frame: world-space vertices and triangles (indices into `vertices`).
#[derive(Clone, Debug, Default)]
pub struct Receivers {
    pub vertices: Vec<IsgVertex>,
    pub indices: Vec<u32>,
    /// Vertices evaluated (used by a kept triangle).
    pub evaluated: usize,
    /// Triangles before culling.
    pub triangles_total: usize,
}

/// Whether a world-space triangle is entirely outside the frustum of `view_proj`.
fn outside_frustum(view_proj: &Mat4, t: [Vec3; 3]) -> bool {
    let c = t.map(|p| *view_proj * p.extend(1.0));
    let all = |f: &dyn Fn(glam::Vec4) -> bool| c.iter().all(|v| f(*v));
    all(&|v| v.x < -v.w)
        || all(&|v| v.x > v.w)
        || all(&|v| v.y < -v.w)
        || all(&|v| v.y > v.w)
        || all(&|v| v.z > v.w)
        || all(&|v| v.w <= 0.0)
}

/// Builds the frame's receivers; `cache` keeps each object's subdivision (computed when the
/// object is first seen, at its scale then).
///
/// With `view` (view-projection, eye), triangles that cannot show are culled (module docs).
pub fn frame_receivers(
    scene: &Scene,
    frame: &Frame,
    max_edge: f32,
    cache: &mut HashMap<usize, Refined>,
    view: Option<(Mat4, Vec3)>,
) -> Receivers {
    let mut out = Receivers::default();
    for inst in &frame.instances {
        let Some(rest) = scene.meshes.get(inst.mesh) else { continue };
        let mesh: &MeshData = match &inst.deformed_mesh {
            Some(d) if d.positions.len() == rest.positions.len() => d,
            _ => rest,
        };
        if mesh.indices.is_empty() || mesh.positions.is_empty() {
            continue;
        }
        let w: Mat4 = inst.world;
        let scale = largest_scale(&w);
        let refined =
            cache.entry(inst.object).or_insert_with(|| refine(&rest.positions, &rest.indices, scale, max_edge));
        if refined.base_vertices != mesh.positions.len() {
            *refined = refine(&rest.positions, &rest.indices, scale, max_edge);
        }
        let (p, n) = refined.apply(&mesh.positions, &mesh.normals);
        let uvs = if mesh.uvs.len() == mesh.positions.len() { &mesh.uvs } else { &rest.uvs };
        let tangents = refined.apply_sum(&vertex_tangents(&mesh.positions, uvs, &rest.indices));
        let tm = Mat3::from_mat4(w);
        let nm = Mat3::from_mat4(w.inverse().transpose());
        let info = scene.object_info(inst.object);
        let two_sided = info.thin_shell
            || scene.material_extras.get(inst.material).is_some_and(|e| e.two_sided)
            || !rest.is_closed();
        let base = out.vertices.len() as u32;
        let wps: Vec<Vec3> = p.iter().map(|pi| w.transform_point3(*pi)).collect();
        let wns: Vec<Vec3> = n.iter().map(|ni| (nm * *ni).try_normalize().unwrap_or(Vec3::Y)).collect();
        let mut used = vec![view.is_none(); wps.len()];
        out.triangles_total += refined.indices.len() / 3;
        for t in refined.indices.chunks_exact(3) {
            let [a, b, c] = [t[0] as usize, t[1] as usize, t[2] as usize];
            if let Some((vp, eye)) = &view {
                let tri = [wps[a], wps[b], wps[c]];
                if outside_frustum(vp, tri) {
                    continue;
                }
                if !two_sided {
                    // Geometric normal oriented like the vertex normals: a back face of a closed
                    // mesh is hidden by its front faces.
                    let g = (tri[1] - tri[0]).cross(tri[2] - tri[0]);
                    let g = if g.dot(wns[a] + wns[b] + wns[c]) < 0.0 { -g } else { g };
                    if g.dot(*eye - tri[0]) < 0.0 {
                        continue;
                    }
                }
                used[a] = true;
                used[b] = true;
                used[c] = true;
            }
            out.indices.extend_from_slice(&[base + t[0], base + t[1], base + t[2]]);
        }
        for (((wp, wn), u), t) in wps.iter().zip(&wns).zip(&used).zip(&tangents) {
            out.evaluated += *u as usize;
            let flags = if two_sided { 1.0 } else { 0.0 } + if *u { 0.0 } else { 2.0 };
            let wt = tm * *t;
            let wt = (wt - *wn * wn.dot(wt)).try_normalize().unwrap_or(Vec3::ZERO);
            out.vertices.push(IsgVertex {
                pos_mat: [wp.x, wp.y, wp.z, inst.material as f32],
                normal_flags: [wn.x, wn.y, wn.z, flags],
                tangent: [wt.x, wt.y, wt.z, 0.0],
            });
        }
    }
    out
}

/// Format of the interpolated visibility image.
pub const VIS_FORMAT: vk::Format = vk::Format::R32G32B32A32_SFLOAT;
/// Its depth buffer.
pub const VIS_DEPTH_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

/// The raster pipeline of `isg_vertex_raster`: camera uniform, per-vertex visibilities, the
/// vertices and the triangles' indices (storage buffers read by the vertex shader, which draws
/// unindexed, three invocations per triangle), and `pixel_refine` as a 4-byte push constant.
pub fn raster_pipeline(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Pipeline> {
    use crate::raster::{DepthState, RasterDesc, VertexInput};
    crate::raster::raster_pipeline(
        ctx,
        shaders,
        &RasterDesc {
            name: "isg_vertex_raster",
            shaders: &["isg/isg_vertex.vert", "isg/isg_vertex.frag"],
            push_constant_bytes: 4,
            vertex_input: VertexInput::None,
            colors: &[VIS_FORMAT],
            depth: Some(DepthState { format: VIS_DEPTH_FORMAT, write: true, compare: vk::CompareOp::LESS }),
            ..Default::default()
        },
    )
}

//! `isg_parity`: the ISG visibility of `glsl/include/isg.glsl` on the GPU.

use crate::isg::{build_bvh, build_triangle_bvh, GpuNode, WorldSphere};
use crate::util::{bytes_of, compute_pipeline, groups};
use anyhow::Result;
use glam::Vec3;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::Bind;
use penumbra_engine::{Access, Engine, Graph, PassKind};
use penumbra_math::isg::IsgTable;

/// One visibility query of [`gpu_visibility`]: shading point, normal, SG lobe axis and
/// sharpness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VisibilityQuery {
    pub p: Vec3,
    pub n: Vec3,
    pub axis: Vec3,
    pub gamma: f32,
}

/// Evaluates `isg_visible` (`glsl/include/isg.glsl`) on the GPU for `queries` against
/// `spheres` (CPU BVH) and thin-shell `triangles` (one compute dispatch of
/// `glsl/tests/isg_parity.comp` in a graph of its own): the shader side of the shader-vs-CPU parity
/// test against [`penumbra_math::isg::visible_fraction_with_triangles`] with the same `params`
/// (patches per side up to 32, epsilon, the ISG model and the patch rule).
pub fn gpu_visibility(
    engine: &mut Engine,
    shaders: &ShaderLibrary,
    queries: &[VisibilityQuery],
    spheres: &[WorldSphere],
    triangles: &[[Vec3; 3]],
    params: &penumbra_math::isg::IsgParams,
    lod: f32,
) -> Result<Vec<f32>> {
    let ctx = engine.ctx.clone();
    let pipeline = compute_pipeline(&ctx, shaders, "tests/isg_parity.comp", 24)?;
    let table = IsgTable::default_table().to_gpu(params.epsilon);
    let nodes = build_bvh(spheres);
    let node_count = nodes.len() as i32;
    let nodes = if nodes.is_empty() { vec![GpuNode { sphere: [0.0; 4], info: [-1; 4] }] } else { nodes };
    let tri_nodes = build_triangle_bvh(triangles);
    let tri_node_count = tri_nodes.len() as i32;
    let tri_nodes = if tri_nodes.is_empty() { vec![GpuNode { sphere: [0.0; 4], info: [-1; 4] }] } else { tri_nodes };
    let tri_data: Vec<[f32; 4]> = triangles.iter().flat_map(|t| t.map(|p| [p.x, p.y, p.z, 0.0])).collect();
    let tri_data = if tri_data.is_empty() { vec![[0.0f32; 4]; 3] } else { tri_data };
    let q: Vec<[f32; 4]> = queries
        .iter()
        .flat_map(|q| [[q.p.x, q.p.y, q.p.z, 0.0], [q.n.x, q.n.y, q.n.z, 0.0], [q.axis.x, q.axis.y, q.axis.z, q.gamma]])
        .collect();
    let q = if q.is_empty() { vec![[0.0f32; 4]; 3] } else { q };
    let count = queries.len() as u32;
    let mut graph = Graph::new();
    let qb = graph.create_buffer_init("isg_queries", bytes_of(&q));
    let out = graph.create_buffer("isg_parity_out", count.max(1) as u64 * 4);
    let tb = graph.create_buffer_init("isg_table", crate::util::whole_texels(bytes_of(&table).to_vec()));
    let nb = graph.create_buffer_init("isg_bvh", bytes_of(&nodes));
    let trb = graph.create_buffer_init("isg_thin_triangles", bytes_of(&tri_data));
    let tnb = graph.create_buffer_init("isg_thin_bvh", bytes_of(&tri_nodes));
    let mut p = graph.pass("isg_parity", PassKind::Compute);
    let qb = p.read(qb, Access::ComputeShaderReadStorage);
    let out_w = p.write(out, Access::ComputeShaderWriteStorage);
    let [tb, nb, trb, tnb] = [tb, nb, trb, tnb].map(|h| p.read(h, Access::ComputeShaderReadSampled));
    let mut push = Vec::with_capacity(24);
    push.extend_from_slice(&count.to_le_bytes());
    push.extend_from_slice(&node_count.to_le_bytes());
    push.extend_from_slice(&tri_node_count.to_le_bytes());
    push.extend_from_slice(&(params.patch_side.clamp(1, 32) as i32).to_le_bytes());
    push.extend_from_slice(&lod.to_le_bytes());
    push.extend_from_slice(&crate::isg::model_flags(params.model, params.rule).to_le_bytes());
    let pipe = pipeline.handle();
    p.record(move |rc| {
        let binds = [&crate::util::storage([qb, out_w])[..], &[tb, nb, trb, tnb].map(Bind::TexelBuffer)].concat();
        crate::util::dispatch(rc, pipe, &binds, &push, [groups(count, 64), 1, 1])
    });
    let bytes = crate::util::submit_and_read(engine, graph, out_w, "isg_parity", count.max(1) as u64 * 4);
    drop(pipeline);
    let bytes = bytes?;
    Ok(bytes.chunks_exact(4).take(queries.len()).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect())
}

/// One query of [`gpu_as_lobes`]: shading normal, tangent, unit direction to the eye, and the
/// Ashikhmin-Shirley exponents and Fresnel F0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AsLobesQuery {
    pub n: Vec3,
    pub t: Vec3,
    pub v: Vec3,
    pub nu: f32,
    pub nv: f32,
    pub f0: f32,
}

/// One lobe of [`gpu_as_lobes`]: world axis, sharpness and (grey) weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AsLobe {
    pub axis: Vec3,
    pub lambda: f32,
    pub weight: f32,
}

/// Evaluates `sg_as_lobes` (`glsl/include/sg.glsl`: Ashikhmin-Shirley's seven SG lobes, in the
/// frame `brdf_frame` of `glsl/include/brdf_ref.glsl`) on the GPU for `queries` (one dispatch of
/// `glsl/tests/sg_as_parity.comp`): the shader side of the parity test against
/// [`penumbra_math::brdf::AshikhminShirley::sg7_hermite`].
pub fn gpu_as_lobes(
    engine: &mut Engine,
    shaders: &ShaderLibrary,
    queries: &[AsLobesQuery],
) -> Result<Vec<[AsLobe; 7]>> {
    let ctx = engine.ctx.clone();
    let pipeline = compute_pipeline(&ctx, shaders, "tests/sg_as_parity.comp", 4)?;
    let q: Vec<[f32; 4]> = queries
        .iter()
        .flat_map(|q| {
            [
                [q.n.x, q.n.y, q.n.z, 0.0],
                [q.t.x, q.t.y, q.t.z, 0.0],
                [q.v.x, q.v.y, q.v.z, 0.0],
                [q.nu, q.nv, q.f0, 0.0],
            ]
        })
        .collect();
    let q = if q.is_empty() { vec![[0.0f32; 4]; 4] } else { q };
    let count = queries.len() as u32;
    let out_bytes = count.max(1) as u64 * 14 * 16;
    let mut graph = Graph::new();
    let qb = graph.create_buffer_init("as_lobes_queries", bytes_of(&q));
    let out = graph.create_buffer("as_lobes_out", out_bytes);
    let mut p = graph.pass("sg_as_parity", PassKind::Compute);
    let qb = p.read(qb, Access::ComputeShaderReadStorage);
    let out_w = p.write(out, Access::ComputeShaderWriteStorage);
    let push = count.to_le_bytes().to_vec();
    let pipe = pipeline.handle();
    p.record(move |rc| {
        let binds = crate::util::storage([qb, out_w]);
        crate::util::dispatch(rc, pipe, &binds, &push, [groups(count, 64), 1, 1])
    });
    let bytes = crate::util::submit_and_read(engine, graph, out_w, "sg_as_parity", out_bytes);
    drop(pipeline);
    let bytes = bytes?;
    let f: Vec<f32> = bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok((0..queries.len())
        .map(|i| {
            std::array::from_fn(|k| {
                let o = (14 * i + 2 * k) * 4;
                AsLobe { axis: Vec3::new(f[o], f[o + 1], f[o + 2]), lambda: f[o + 3], weight: f[o + 4] }
            })
        })
        .collect())
}

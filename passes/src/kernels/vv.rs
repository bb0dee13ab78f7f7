//! `vv_parity` and `vv_cap_parity`: the vv technique's GLSL integration on the GPU.

use crate::util::{bytes_of, compute_pipeline, Pipeline};
use crate::vv::VvTechnique;
use anyhow::Result;
use glam::Vec3;
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Graph, ImageHandle, PassKind};
use std::sync::Arc;

/// `vv_parity` (tests): per case, `n . ∫ l L_e` over the hemisphere of `n` minus occluder loops,
/// with the technique's GLSL integration (`glsl/tests/vv_parity.comp`), to compare with
/// `penumbra_math::vv_sat`. Keep it alive until the frames using it have finished.
pub struct VvParity {
    pipe: Pipeline,
}

impl VvParity {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        Ok(VvParity { pipe: compute_pipeline(ctx, shaders, "tests/vv_parity.comp", 32)? })
    }

    /// The cases on `sat` (an image of [`crate::vv::VvTechnique::add_sat`] of `tech`'s map size, with its
    /// alpha' and hemisphere arcs). `cases`: `(n, loops)` with loops of map-space unit
    /// directions in part A's orientation (counter-clockwise from outside around the occluded
    /// region). Returns an RGBA32F image of `cases.len() x 1` texels (rgb).
    pub fn add(
        &self,
        tech: &VvTechnique,
        graph: &mut Graph,
        sat: ImageHandle,
        cases: &[(Vec3, Vec<Vec<Vec3>>)],
    ) -> ImageHandle {
        let mut data: Vec<[f32; 4]> = vec![[0.0; 4]; cases.len()];
        for (c, (n, loops)) in cases.iter().enumerate() {
            data[c][0] = data.len() as f32;
            data.push([n.x, n.y, n.z, loops.len() as f32]);
            for l in loops {
                data.push([l.len() as f32, 0.0, 0.0, 0.0]);
                data.extend(l.iter().map(|d| [d.x, d.y, d.z, 0.0]));
            }
        }
        parity_pass(&self.pipe, tech, graph, "vv_parity", sat, data, cases.len() as u32, 1)
    }
}

/// The pass of [`VvParity`] and [`VvCapParity`]: `count` cases (`data`: case offsets, then the
/// cases) on `sat`, written to an RGBA32F image `name` of `count x rows` texels.
fn parity_pass(
    pipe: &Pipeline,
    tech: &VvTechnique,
    graph: &mut Graph,
    name: &str,
    sat: ImageHandle,
    data: Vec<[f32; 4]>,
    count: u32,
    rows: u32,
) -> ImageHandle {
    let input = graph.create_buffer_init(&format!("{name}_cases"), bytes_of(&data));
    let out = graph.create_image(name, ImageDesc::new_2d(vk::Format::R32G32B32A32_SFLOAT, count.max(1), rows));
    let (sat_w, sat_h, arcs, alpha, nearest) = tech.sat_params();
    let mut push = Vec::new();
    for v in [sat_w as i32, sat_h as i32, arcs as i32, count as i32] {
        push.extend_from_slice(&v.to_le_bytes());
    }
    for v in [alpha, 0.0, 0.0, 0.0] {
        push.extend_from_slice(&v.to_le_bytes());
    }
    let mut p = graph.pass(name, PassKind::Compute);
    let sat = p.read(sat, Access::ComputeShaderReadSampled);
    let input = p.read(input, Access::ComputeShaderReadStorage);
    let out = p.write(out, Access::ComputeShaderWriteStorage);
    let pipe = pipe.handle();
    p.record(move |rc| {
        let binds = [Bind::SampledImage(sat, nearest), Bind::StorageBuffer(input), Bind::StorageImage(out)];
        crate::util::dispatch(rc, pipe, &binds, &push, [count, 1, 1])
    });
    out
}

/// One case of [`VvCapParity`]: normal, reflection direction, cap cosine `cos xi` and occluder
/// loops (map-space unit directions in the closed hemisphere of the normal, clockwise seen from
/// the centre around the occluded region, as the shading shaders' synthesized loops).
pub type CapCase = (Vec3, Vec3, f32, Vec<Vec<Vec3>>);

/// `vv_cap_parity` (tests): per case, the specular visibility ratio gamma of eq. 15 with the
/// technique's GLSL (`glsl/tests/vv_cap_parity.comp`: loops clipped to the cap, cap clipped to the
/// hemisphere, Cap weighting of eq. 16), to compare with `penumbra_math::vv_sat::cap_ratio`.
/// Keep it alive until the frames using it have finished.
pub struct VvCapParity {
    pipe: Pipeline,
}

impl VvCapParity {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        Ok(VvCapParity { pipe: compute_pipeline(ctx, shaders, "tests/vv_cap_parity.comp", 32)? })
    }

    /// The cases on `sat` (an image of [`crate::vv::VvTechnique::add_sat`] of `tech`'s map size, with its
    /// alpha' and arcs per circle). Returns an RGBA32F image of `cases.len() x 3` texels: row 0
    /// gamma, row 1 the numerator, row 2 the denominator of eq. 15 (rgb).
    pub fn add(&self, tech: &VvTechnique, graph: &mut Graph, sat: ImageHandle, cases: &[CapCase]) -> ImageHandle {
        let mut data: Vec<[f32; 4]> = vec![[0.0; 4]; cases.len()];
        for (c, (n, r, cos_xi, loops)) in cases.iter().enumerate() {
            data[c][0] = data.len() as f32;
            data.push([n.x, n.y, n.z, loops.len() as f32]);
            data.push([r.x, r.y, r.z, *cos_xi]);
            for l in loops {
                data.push([l.len() as f32, 0.0, 0.0, 0.0]);
                data.extend(l.iter().map(|d| [d.x, d.y, d.z, 0.0]));
            }
        }
        parity_pass(&self.pipe, tech, graph, "vv_cap_parity", sat, data, cases.len() as u32, 3)
    }
}

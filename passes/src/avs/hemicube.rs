//! The paper's Fig. 7 baseline: visibility maps by rasterized hemicubes ("the shadow map-based
//! approach that replaces our adaptive visibility sampling by rendering shadow maps").
//!
//! Per sample point, 5 depth-only views of all shadow-casting world triangles (`avs_hemicube.vert`,
//! 90-degree frusta from the point offset along its normal: +n, +t, -t, +b, -b; the side faces
//! rasterize only their upper half) at face resolution F = r / 2 (the same angular texel size as
//! the r x r map at its centre), then `avs_hemicube.comp` converts them into the technique's
//! 1-bit r x r maps (`penumbra_math::avs_maps` layout). Points are batched into one depth atlas
//! of at most 4096 rows (5F x F per point); the batches reuse it.

use crate::raster::{DepthState, RasterDesc, VertexInput};
use crate::util::{bytes_of, compute_pipeline, groups, Pipeline, Sampler};
use anyhow::{bail, Result};
use glam::{Mat4, Vec3};
use penumbra_engine::graph::ImageDesc;
use penumbra_engine::shader::ShaderLibrary;
use penumbra_engine::{vk, Access, Bind, Context, Engine, Graph, PassKind};
use penumbra_math::avs_maps::{check_res, words_per_map};
use penumbra_math::avs_sampling::SurfacePoint;
use std::sync::Arc;

/// Depth format of the atlas.
pub const ATLAS_FORMAT: vk::Format = vk::Format::D32_SFLOAT;

/// Hemicube visibility maps (bench baseline).
pub struct HemicubeMaps {
    raster: Pipeline,
    convert: Pipeline,
    nearest: Sampler,
}

/// Maps and GPU times of one run.
pub struct HemicubeResult {
    /// Packed maps, `words_per_map(r)` words per point.
    pub maps: Vec<u32>,
    /// GPU milliseconds per pass (`avs_hc_raster_<b>`, `avs_hc_convert_<b>`).
    pub gpu_ms: Vec<(String, f64)>,
    /// Triangles rasterized per face.
    pub triangles: usize,
}

impl HemicubeMaps {
    pub fn new(ctx: &Arc<Context>, shaders: &ShaderLibrary) -> Result<Self> {
        let raster = crate::raster::raster_pipeline(
            ctx,
            shaders,
            &RasterDesc {
                name: "avs_hemicube",
                shaders: &["avs/avs_hemicube.vert"],
                push_constant_bytes: 64,
                vertex_input: VertexInput::PositionOfStride(12),
                cull: vk::CullModeFlags::NONE,
                depth: Some(DepthState { format: ATLAS_FORMAT, write: true, compare: vk::CompareOp::LESS }),
                ..Default::default()
            },
        )?;
        let convert = compute_pipeline(ctx, shaders, "avs/avs_hemicube.comp", 16)?;
        Ok(HemicubeMaps { raster, convert, nearest: Sampler::nearest(ctx)? })
    }

    /// Face resolution for map resolution r.
    pub fn face_res(r: u32) -> u32 {
        (r / 2).max(8)
    }

    /// View-projections of the 5 faces of a point (eye = position + offset x normal).
    pub fn face_matrices(p: &SurfacePoint, offset: f32, near: f32, far: f32) -> [Mat4; 5] {
        let f = penumbra_math::avs_sampling::point_frame(p.normal);
        let (t, b, n) = (f.t.as_vec3(), f.b.as_vec3(), f.n.as_vec3());
        let eye = p.pos + n * offset;
        let mut proj = Mat4::perspective_rh(std::f32::consts::FRAC_PI_2, 1.0, near, far);
        proj.y_axis.y = -proj.y_axis.y;
        let view = |d: Vec3, up: Vec3| proj * Mat4::look_at_rh(eye, eye + d, up);
        [view(n, b), view(t, n), view(-t, n), view(b, n), view(-b, n)]
    }

    /// Renders and converts the maps of `points` at resolution r in one submission (waited for).
    /// `tris`: world triangles that cast shadows.
    pub fn run(
        &self,
        engine: &mut Engine,
        tris: &[[Vec3; 3]],
        points: &[SurfacePoint],
        offset: f32,
        r: u32,
        readback: bool,
    ) -> Result<HemicubeResult> {
        check_res(r).map_err(|e| anyhow::anyhow!("hemicube maps: r: {e}"))?;
        if points.is_empty() {
            bail!("hemicube maps: no sample points");
        }
        let fr = Self::face_res(r);
        let batch = (4096 / fr).max(1) as usize;
        let words = words_per_map(r) as u64;
        // near / far from the triangles' extent
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for t in tris {
            for v in t {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
        }
        for p in points {
            lo = lo.min(p.pos);
            hi = hi.max(p.pos);
        }
        let diag = (hi - lo).length().max(1e-3);
        let (near, far) = (offset.max(diag * 1e-5), diag * 2.0);
        let mut verts: Vec<[f32; 3]> = tris.iter().flat_map(|t| t.iter().map(|v| v.to_array())).collect();
        let vcount = verts.len() as u32;
        if verts.is_empty() {
            verts.push([0.0; 3]);
        }
        let faces: Vec<[f32; 16]> =
            points.iter().flat_map(|p| Self::face_matrices(p, offset, near, far)).map(|m| m.to_cols_array()).collect();
        let mut g = Graph::new();
        let vb = g.create_buffer_init("avs_hc_vertices", bytes_of(&verts));
        let pts = g.create_buffer_init("avs_hc_points", bytes_of(&super::point_data(points, offset)));
        let fb = g.create_buffer_init("avs_hc_faces", bytes_of(&faces));
        let mut maps = g.create_buffer("avs_hc_maps", points.len() as u64 * words * 4);
        let rows = batch.min(points.len()) as u32;
        let mut atlas = g.create_image("avs_hc_atlas", ImageDesc::new_2d(ATLAS_FORMAT, 5 * fr, rows * fr));
        let (rp, rl) = (self.raster.pipeline, self.raster.layout);
        let convert = self.convert.handle();
        let nearest = self.nearest.sampler;
        for (bi, start) in (0..points.len()).step_by(batch).enumerate() {
            let count = batch.min(points.len() - start);
            let mats: Vec<[f32; 16]> = faces[5 * start..5 * (start + count)].to_vec();
            let mut p = g.pass(&format!("avs_hc_raster_{bi}"), PassKind::Raster);
            let at = p.write(atlas, Access::DepthAttachmentWrite);
            let vbuf = p.read(vb, Access::VertexBuffer);
            let (aw, ah) = (5 * fr, rows * fr);
            p.record(move |rc| {
                let d = rc.device();
                let depth_att = crate::util::depth_attachment(rc.image(at)?.view, true);
                let area =
                    vk::Rect2D { offset: vk::Offset2D::default(), extent: vk::Extent2D { width: aw, height: ah } };
                let info = vk::RenderingInfo::default().render_area(area).layer_count(1).depth_attachment(&depth_att);
                let vbb = rc.buffer(vbuf)?;
                unsafe {
                    d.cmd_begin_rendering(rc.cmd, &info);
                    d.cmd_bind_pipeline(rc.cmd, vk::PipelineBindPoint::GRAPHICS, rp);
                    d.cmd_bind_vertex_buffers(rc.cmd, 0, &[vbb.buffer], &[0]);
                    for (k, m) in mats.iter().enumerate() {
                        let (e, face) = ((k / 5) as u32, (k % 5) as u32);
                        let (x0, y0) = ((face * fr) as f32, (e * fr) as f32);
                        d.cmd_set_viewport(
                            rc.cmd,
                            0,
                            &[vk::Viewport {
                                x: x0,
                                y: y0,
                                width: fr as f32,
                                height: fr as f32,
                                min_depth: 0.0,
                                max_depth: 1.0,
                            }],
                        );
                        // side faces: the upper half only (the hemisphere above the horizon)
                        let hgt = if face == 0 { fr } else { fr / 2 };
                        d.cmd_set_scissor(
                            rc.cmd,
                            0,
                            &[vk::Rect2D {
                                offset: vk::Offset2D { x: x0 as i32, y: y0 as i32 },
                                extent: vk::Extent2D { width: fr, height: hgt },
                            }],
                        );
                        d.cmd_push_constants(rc.cmd, rl, vk::ShaderStageFlags::VERTEX, 0, &bytes_of(m));
                        if vcount > 0 {
                            d.cmd_draw(rc.cmd, vcount, 1, 0, 0);
                        }
                    }
                    d.cmd_end_rendering(rc.cmd);
                }
                Ok(())
            });
            atlas = at;
            let mut p = g.pass(&format!("avs_hc_convert_{bi}"), PassKind::Compute);
            let a = p.read(atlas, Access::ComputeShaderReadSampled);
            let pb = p.read(pts, Access::ComputeShaderReadStorage);
            let fbb = p.read(fb, Access::ComputeShaderReadStorage);
            let out = p.write(
                maps,
                if bi == 0 { Access::ComputeShaderWriteStorage } else { Access::ComputeShaderReadWriteStorage },
            );
            let push = [r, fr, start as u32, count as u32];
            p.record(move |rc| {
                let binds = [
                    Bind::SampledImage(a, nearest),
                    Bind::StorageBuffer(pb),
                    Bind::StorageBuffer(fbb),
                    Bind::StorageBuffer(out),
                ];
                crate::util::dispatch(
                    rc,
                    convert,
                    &binds,
                    &bytes_of(&push),
                    [groups(words as u32, 64), count as u32, 1],
                )
            });
            maps = out;
        }
        let total = points.len() as u64 * words * 4;
        let rb = g.create_readback("avs_hc_readback", if readback { total } else { 4 });
        {
            let mut p = g.pass("avs_hc_readback", PassKind::Transfer);
            let s = p.read(maps, Access::TransferSrc);
            let d = p.write(rb, Access::TransferDst);
            let size = if readback { total } else { 4 };
            p.record(move |rc| {
                let (sb, db) = (rc.buffer(s)?, rc.buffer(d)?);
                unsafe {
                    rc.device().cmd_copy_buffer(
                        rc.cmd,
                        sb.buffer,
                        db.buffer,
                        &[vk::BufferCopy { src_offset: 0, dst_offset: 0, size }],
                    )
                };
                Ok(())
            });
        }
        let out = engine.submit_wait(g)?;
        let bytes = out.readbacks.get("avs_hc_readback").cloned().unwrap_or_default();
        let maps = if readback {
            bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
        } else {
            Vec::new()
        };
        Ok(HemicubeResult { maps, gpu_ms: out.gpu_ms.clone(), triangles: tris.len() })
    }
}

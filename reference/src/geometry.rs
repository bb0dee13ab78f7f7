//! World-space triangles of a [`Frame`] in an `obvhs` CWBVH, closest-hit and visibility queries.

use glam::{Mat3, Vec2, Vec3};
use obvhs::{
    cwbvh::{builder::build_cwbvh_from_tris, CwBvh},
    ray::{Ray, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};
use obvhs_glam::Vec3A;
use penumbra_scene::{Frame, Scene};

/// Per-triangle shading data.
#[derive(Clone, Copy, Debug)]
pub struct TriData {
    pub v0: Vec3,
    pub e1: Vec3,
    pub e2: Vec3,
    /// Vertex normals in world space (unit), or the geometric normal if the mesh has none.
    pub n: [Vec3; 3],
    /// World-space dP/du (zero if the mesh has no usable UVs).
    pub tangent: Vec3,
    /// World-space dP/dv (zero if the mesh has no usable UVs): with `tangent`, the frame of
    /// tangent-space normal maps.
    pub bitangent: Vec3,
    /// Vertex texture coordinates (zero if the mesh has none).
    pub uv: [Vec2; 3],
    pub material: u32,
    /// Whether the triangle blocks shadow rays (`ObjectInfo::casts_shadow`).
    pub casts_shadow: bool,
}

/// A surface hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f32,
    pub p: Vec3,
    /// Unit geometric normal (winding order: counter-clockwise = front).
    pub ng: Vec3,
    /// Unit interpolated shading normal, on the same side as `ng`.
    pub ns: Vec3,
    pub tangent: Vec3,
    /// dP/dv of the hit triangle.
    pub bitangent: Vec3,
    /// Interpolated texture coordinates.
    pub uv: Vec2,
    pub material: u32,
    pub triangle: u32,
}

/// The scene's triangles at one time, with a BVH.
pub struct Geometry {
    tris: Vec<Triangle>,
    data: Vec<TriData>,
    bvh: Option<CwBvh>,
    /// Largest absolute coordinate, to scale ray offsets.
    pub extent: f32,
}

fn a(v: Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

impl Geometry {
    /// Gather the instances' triangles in world space (deformed meshes when the frame has them).
    /// Errors name the object and mesh at fault.
    pub fn new(scene: &Scene, frame: &Frame) -> Result<Self, String> {
        let mut tris = Vec::new();
        let mut data = Vec::new();
        let mut extent = 1.0f32;
        for inst in &frame.instances {
            let obj_name = scene.objects.get(inst.object).map(|o| o.name.as_str()).unwrap_or("?");
            let mesh = match inst.deformed_mesh.as_deref() {
                Some(m) => m,
                None => scene.meshes.get(inst.mesh).ok_or_else(|| {
                    format!("object '{obj_name}' refers to mesh {} of {}", inst.mesh, scene.meshes.len())
                })?,
            };
            if inst.material >= frame.materials.len() {
                return Err(format!(
                    "object '{obj_name}' refers to material {} of {}",
                    inst.material,
                    frame.materials.len()
                ));
            }
            let casts_shadow = scene.object_info(inst.object).casts_shadow;
            if !inst.world.is_finite() {
                return Err(format!("object '{obj_name}' has a non-finite world transform"));
            }
            let m3 = Mat3::from_mat4(inst.world);
            let normal_m = if m3.determinant().abs() > 1e-20 { m3.inverse().transpose() } else { m3 };
            let has_n = mesh.normals.len() == mesh.positions.len();
            let has_uv = mesh.uvs.len() == mesh.positions.len();
            let np = mesh.positions.len();
            let wp: Vec<Vec3> = mesh.positions.iter().map(|p| inst.world.transform_point3(*p)).collect();
            for t in mesh.indices.chunks_exact(3) {
                let [i0, i1, i2] = [t[0] as usize, t[1] as usize, t[2] as usize];
                if i0 >= np || i1 >= np || i2 >= np {
                    return Err(format!(
                        "mesh '{}' of object '{obj_name}' has index out of range ({} vertices)",
                        mesh.name, np
                    ));
                }
                let (p0, p1, p2) = (wp[i0], wp[i1], wp[i2]);
                if !(p0.is_finite() && p1.is_finite() && p2.is_finite()) {
                    return Err(format!("mesh '{}' of object '{obj_name}' has non-finite vertices", mesh.name));
                }
                let e1 = p1 - p0;
                let e2 = p2 - p0;
                let ng = e1.cross(e2);
                if ng.length_squared() <= 0.0 {
                    continue; // degenerate: never hit
                }
                let ng = ng.normalize();
                let n = if has_n {
                    [i0, i1, i2].map(|i| {
                        let n = (normal_m * mesh.normals[i]).normalize_or_zero();
                        if n == Vec3::ZERO || !n.is_finite() {
                            ng
                        } else {
                            n
                        }
                    })
                } else {
                    [ng; 3]
                };
                let (tangent, bitangent) = if has_uv {
                    let (uv0, uv1, uv2) = (mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]);
                    let (d1, d2): (Vec2, Vec2) = (uv1 - uv0, uv2 - uv0);
                    let det = d1.x * d2.y - d1.y * d2.x;
                    if det.abs() > 1e-12 {
                        let t = (e1 * d2.y - e2 * d1.y) / det;
                        let b = (e2 * d1.x - e1 * d2.x) / det;
                        if t.is_finite() && b.is_finite() {
                            (t, b)
                        } else {
                            (Vec3::ZERO, Vec3::ZERO)
                        }
                    } else {
                        (Vec3::ZERO, Vec3::ZERO)
                    }
                } else {
                    (Vec3::ZERO, Vec3::ZERO)
                };
                extent = extent.max(p0.abs().max_element()).max(p1.abs().max_element()).max(p2.abs().max_element());
                tris.push(Triangle { v0: a(p0), v1: a(p1), v2: a(p2) });
                let uv = if has_uv { [mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]] } else { [Vec2::ZERO; 3] };
                data.push(TriData {
                    v0: p0,
                    e1,
                    e2,
                    n,
                    tangent,
                    bitangent,
                    uv,
                    material: inst.material as u32,
                    casts_shadow,
                });
            }
        }
        let bvh = if tris.is_empty() {
            None
        } else {
            Some(build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut Default::default()))
        };
        Ok(Geometry { tris, data, bvh, extent })
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Offset along the geometric normal for spawning rays off a surface at `p` (relative to the
    /// point's magnitude, so that contacts stay tight in large scenes).
    pub fn epsilon_at(&self, p: Vec3) -> f32 {
        3e-5 * (1.0 + p.abs().max_element())
    }

    fn ray(o: Vec3, d: Vec3, tmax: f32) -> Ray {
        Ray::new(a(o), a(d), 0.0, tmax)
    }

    /// Closest hit along `o + t d`, `t` in (0, tmax].
    pub fn intersect(&self, o: Vec3, d: Vec3, tmax: f32) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let mut hit = RayHit::none();
        let tris = &self.tris;
        let found = bvh.ray_traverse(Self::ray(o, d, tmax), &mut hit, |ray, id| {
            tris[bvh.primitive_indices[id] as usize].intersect(ray)
        });
        if !found || !hit.t.is_finite() {
            return None;
        }
        let ti = bvh.primitive_indices[hit.primitive_id as usize];
        let td = &self.data[ti as usize];
        let p = o + d * hit.t;
        // Barycentrics of p (projected onto the triangle's plane).
        let vp = p - td.v0;
        let (d00, d01, d11) = (td.e1.dot(td.e1), td.e1.dot(td.e2), td.e2.dot(td.e2));
        let (d20, d21) = (vp.dot(td.e1), vp.dot(td.e2));
        let den = d00 * d11 - d01 * d01;
        let (mut b1, mut b2) = ((d11 * d20 - d01 * d21) / den, (d00 * d21 - d01 * d20) / den);
        if !(b1.is_finite() && b2.is_finite()) {
            b1 = 1.0 / 3.0;
            b2 = 1.0 / 3.0;
        }
        let (b1, b2) = (b1.clamp(0.0, 1.0), b2.clamp(0.0, 1.0));
        let b0 = (1.0 - b1 - b2).max(0.0);
        let ng = td.e1.cross(td.e2).normalize();
        let mut ns = (td.n[0] * b0 + td.n[1] * b1 + td.n[2] * b2).normalize_or_zero();
        if ns == Vec3::ZERO {
            ns = ng;
        }
        let uv = td.uv[0] * b0 + td.uv[1] * b1 + td.uv[2] * b2;
        // Vertex normals that disagree with the winding: trust the vertex normals' side.
        let ng = if ns.dot(ng) < 0.0 { -ng } else { ng };
        Some(Hit {
            t: hit.t,
            p,
            ng,
            ns,
            tangent: td.tangent,
            bitangent: td.bitangent,
            uv,
            material: td.material,
            triangle: ti,
        })
    }

    /// True if no shadow-casting triangle blocks `o + t d` for `t` in (0, tmax).
    pub fn unoccluded(&self, o: Vec3, d: Vec3, tmax: f32) -> bool {
        let Some(bvh) = self.bvh.as_ref() else { return true };
        let (tris, data) = (&self.tris, &self.data);
        bvh.ray_traverse_miss(Self::ray(o, d, tmax), |ray, id| {
            let k = bvh.primitive_indices[id] as usize;
            if data[k].casts_shadow {
                tris[k].intersect(ray)
            } else {
                f32::INFINITY
            }
        })
    }
}

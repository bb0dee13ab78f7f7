//! Ray-triangle intersection shared by the CPU tracers of the precomputes (shadow fields,
//! vectorized visibility).

use glam::DVec3;

/// Möller-Trumbore: the distance `t` in `(0, tmax)` at which the ray `o + t d` meets the
/// triangle `tri` (edges and corners included), or `None`. A ray whose determinant is below
/// `det_eps` in magnitude (parallel to the plane, or a degenerate triangle) misses.
pub fn ray_triangle(o: DVec3, d: DVec3, tri: &[DVec3; 3], tmax: f64, det_eps: f64) -> Option<f64> {
    let e1 = tri[1] - tri[0];
    let e2 = tri[2] - tri[0];
    let p = d.cross(e2);
    let det = e1.dot(p);
    if det.abs() < det_eps {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri[0];
    let u = s.dot(p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0 && t < tmax).then_some(t)
}

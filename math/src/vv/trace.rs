//! Closest-hit ray casting for the visibility precompute and the ray-traced ground truth (a
//! median-split binary BVH over the occluder triangles, f64).

use glam::{DVec3, Vec3};

struct Node {
    lo: DVec3,
    hi: DVec3,
    /// leaf: first primitive; inner: left child
    a: u32,
    /// leaf: count; inner: right child
    b: u32,
    leaf: bool,
}

/// Closest-hit caster over a model's occluder triangles; hits report the model triangle index.
pub struct Tracer {
    tris: Vec<([DVec3; 3], u32)>,
    nodes: Vec<Node>,
}

impl Tracer {
    /// BVH over the triangles `t` of `indices` with `occluder[t]` (all when `occluder` is empty).
    pub fn new(positions: &[Vec3], indices: &[u32], occluder: &[bool]) -> Self {
        let mut tris: Vec<([DVec3; 3], u32)> = indices
            .chunks_exact(3)
            .enumerate()
            .filter(|(t, _)| occluder.get(*t).copied().unwrap_or(true))
            .filter(|(_, i)| i.iter().all(|&k| (k as usize) < positions.len()))
            .map(|(t, i)| ([0, 1, 2].map(|k| positions[i[k] as usize].as_dvec3()), t as u32))
            .collect();
        let mut nodes = Vec::new();
        if !tris.is_empty() {
            let n = tris.len();
            build(&mut tris, 0, n, &mut nodes);
        }
        Tracer { tris, nodes }
    }

    /// Closest hit of the ray `o + t d`, `t in (0, tmax)`, skipping triangles for which
    /// `skip(triangle)` is true: `(t, triangle)`.
    pub fn closest(&self, o: DVec3, d: DVec3, tmax: f64, skip: &dyn Fn(u32) -> bool) -> Option<(f64, u32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv = DVec3::ONE / d;
        let mut best: Option<(f64, u32)> = None;
        let mut tbest = tmax;
        let mut stack = [0u32; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let n = &self.nodes[stack[sp] as usize];
            let t0 = (n.lo - o) * inv;
            let t1 = (n.hi - o) * inv;
            let tn = t0.min(t1).max_element().max(0.0);
            let tf = t0.max(t1).min_element().min(tbest);
            if tn > tf || tf.is_nan() {
                continue;
            }
            if n.leaf {
                for (tri, id) in &self.tris[n.a as usize..(n.a + n.b) as usize] {
                    if let Some(t) = crate::ray::ray_triangle(o, d, tri, tbest, 1e-18) {
                        if !skip(*id) {
                            tbest = t;
                            best = Some((t, *id));
                        }
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = n.a;
                stack[sp + 1] = n.b;
                sp += 2;
            }
        }
        best
    }
}

fn build(tris: &mut [([DVec3; 3], u32)], start: usize, end: usize, nodes: &mut Vec<Node>) -> u32 {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for (t, _) in &tris[start..end] {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let id = nodes.len() as u32;
    nodes.push(Node { lo, hi, a: start as u32, b: (end - start) as u32, leaf: true });
    if end - start <= 4 {
        return id;
    }
    let ext = hi - lo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    let mid = (start + end) / 2;
    let key = |t: &([DVec3; 3], u32)| t.0[0][axis] + t.0[1][axis] + t.0[2][axis];
    tris[start..end].select_nth_unstable_by(mid - start, |p, q| key(p).total_cmp(&key(q)));
    let l = build(tris, start, mid, nodes);
    let r = build(tris, mid, end, nodes);
    let n = &mut nodes[id as usize];
    n.leaf = false;
    n.a = l;
    n.b = r;
    id
}

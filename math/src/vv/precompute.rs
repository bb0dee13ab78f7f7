//! Stage 1 (section II-B): per-vertex vectorized visibility from a traced visibility map.
//! See the module docs of [`super`] for the method.

use super::trace::Tracer;
use super::*;
use rayon::prelude::*;
use std::collections::HashMap;

/// Vertex welding and one-rings of a model.
pub struct Topology {
    /// Model vertex -> canonical vertex (first vertex of the same position and normal).
    pub canon: Vec<u32>,
    /// Model vertex -> position group (vertices at the same position).
    pub pos_group: Vec<u32>,
    /// Per triangle: the position groups of its three vertices.
    pub tri_groups: Vec<[u32; 3]>,
    /// Bounding-box diagonal of the model.
    pub scale: f64,
}

fn qkey(p: Vec3, s: f32) -> [i64; 3] {
    let q = |x: f32| (x as f64 / s as f64).round() as i64;
    [q(p.x), q(p.y), q(p.z)]
}

impl Topology {
    /// Welds positions (relative tolerance 1e-6 of the bounding diagonal) and normals
    /// (1e-4).
    pub fn new(model: &VvModel) -> Self {
        let (lo, hi) = model
            .positions
            .iter()
            .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(l, h), p| (l.min(*p), h.max(*p)));
        let scale = ((hi - lo).length() as f64).max(1e-30);
        let ps = (scale * 1e-6) as f32;
        let mut groups: HashMap<[i64; 3], u32> = HashMap::new();
        let mut canon_map: HashMap<([i64; 3], [i64; 3]), u32> = HashMap::new();
        let mut pos_group = Vec::with_capacity(model.positions.len());
        let mut canon = Vec::with_capacity(model.positions.len());
        for (v, (p, n)) in model.positions.iter().zip(&model.normals).enumerate() {
            let k = qkey(*p, ps);
            let g = groups.len() as u32;
            pos_group.push(*groups.entry(k).or_insert(g));
            canon.push(*canon_map.entry((k, qkey(*n, 1e-4))).or_insert(v as u32));
        }
        let tri_groups = model.indices.chunks_exact(3).map(|t| [0, 1, 2].map(|k| pos_group[t[k] as usize])).collect();
        Topology { canon, pos_group, tri_groups, scale }
    }

    /// Whether triangle `t` touches a vertex of position group `g`.
    pub fn touches(&self, t: u32, g: u32) -> bool {
        self.tri_groups[t as usize].contains(&g)
    }

    /// Ray origin offset used for every vertex and ground-truth ray (along the normal).
    pub fn offset(&self) -> f64 {
        1e-5 * self.scale
    }
}

/// Ray-traced visibility with the precompute's conventions: from `p + offset n`, directions in
/// the hemisphere of `n`, triangles touching any position group of `local` are not occluders
/// (the local surface is the tangent plane). `Some(hit point)` when occluded.
pub fn trace_occluder(tracer: &Tracer, topo: &Topology, local: &[u32], p: DVec3, n: DVec3, d: DVec3) -> Option<DVec3> {
    if d.dot(n) <= 0.0 {
        return None;
    }
    let o = p + n * topo.offset();
    let skip = |t: u32| local.iter().any(|&g| topo.touches(t, g));
    tracer.closest(o, d, 1e3 * topo.scale, &skip).map(|(t, _)| o + d * t)
}

/// Precomputes the vectorized visibility of every vertex of `model`. `progress(n)` is called
/// with finished model-vertex increments (total = vertex count), from any thread.
pub fn precompute_visibility(
    model: &VvModel,
    params: &VvParams,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<VectorizedVisibility, String> {
    model.validate()?;
    params.validate()?;
    let topo = Topology::new(model);
    let tracer = Tracer::new(&model.positions, &model.indices, &model.occluder);
    let mut count = vec![0u64; model.positions.len()];
    for &c in &topo.canon {
        count[c as usize] += 1;
    }
    let canon: Vec<usize> = (0..model.positions.len()).filter(|&v| topo.canon[v] as usize == v).collect();
    let loops: Vec<Vec<Vec<[f32; 4]>>> = canon
        .par_iter()
        .map(|&v| {
            let l = vertex_loops(
                &tracer,
                &topo,
                model.positions[v].as_dvec3(),
                model.normals[v],
                topo.pos_group[v],
                params,
            );
            progress(count[v]);
            l
        })
        .collect();
    let mut vis = VectorizedVisibility {
        seq_offsets: vec![0],
        vertex_seqs: vec![[0, 0]; model.positions.len()],
        ..Default::default()
    };
    let mut range = vec![[0u32; 2]; model.positions.len()];
    for (&v, ls) in canon.iter().zip(&loops) {
        range[v] = [vis.sequence_count() as u32, ls.len() as u32];
        for l in ls {
            vis.points.extend_from_slice(l);
            vis.seq_offsets.push(vis.points.len() as u32);
        }
    }
    for v in 0..model.positions.len() {
        vis.vertex_seqs[v] = range[topo.canon[v] as usize];
    }
    vis.vertex_points = vis.points.len() as u32;
    Ok(vis)
}

/// The occluded-region loops of one vertex at `p` with normal `n`.
pub fn vertex_loops(
    tracer: &Tracer,
    topo: &Topology,
    p: DVec3,
    n: Vec3,
    group: u32,
    params: &VvParams,
) -> Vec<Vec<[f32; 4]>> {
    let nn = n.as_dvec3().normalize();
    let f = frame(n);
    let big_n = params.resolution as i64;
    let w = (big_n + 2) as usize;
    let h = 2.0 / big_n as f64;
    let uv = |i: i64| -1.0 + (i as f64 + 0.5) * h;
    let sample = |u: f64, v: f64| -> Option<DVec3> {
        if u * u + v * v >= 1.0 {
            return None;
        }
        trace_occluder(tracer, topo, &[group], p, nn, lambert_inv(u, v, &f))
    };
    // node (i, j), i, j in -1..=N (the padding ring is visible)
    let node = |i: i64, j: i64| ((i + 1) as usize) * w + (j + 1) as usize;
    let mut occ: Vec<Option<DVec3>> = vec![None; w * w];
    for i in 0..big_n {
        for j in 0..big_n {
            occ[node(i, j)] = sample(uv(i), uv(j));
        }
    }
    if occ.iter().all(|o| o.is_none()) {
        return Vec::new();
    }
    let is = |i: i64, j: i64| occ[node(i, j)].is_some();
    // edge id: node(i, j) * 2 + (0: to (i+1, j), 1: to (i, j+1))
    let mut next: HashMap<usize, usize> = HashMap::new();
    for i in -1..big_n {
        for j in -1..big_n {
            let c = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
            let e = [node(i, j) * 2, node(i + 1, j) * 2 + 1, node(i, j + 1) * 2, node(i, j) * 2 + 1];
            let o: [bool; 4] = c.map(|(a, b)| is(a, b));
            let crossing: Vec<usize> = (0..4).filter(|&k| o[k] != o[(k + 1) % 4]).collect();
            match crossing.len() {
                2 => {
                    let (a, b) = if o[crossing[0]] { (crossing[0], crossing[1]) } else { (crossing[1], crossing[0]) };
                    next.insert(e[a], e[b]);
                }
                4 => {
                    let centre = sample(uv(i) + 0.5 * h, uv(j) + 0.5 * h).is_some();
                    for k in 0..4 {
                        if o[k] {
                            let to = if centre { (k + 1) % 4 } else { (k + 3) % 4 };
                            next.insert(e[k], e[to]);
                        }
                    }
                }
                _ => {}
            }
        }
    }
    // crossing points, refined by bisection
    let crossing_point = |edge: usize| -> [f32; 4] {
        let nd = edge / 2;
        let (i, j) = ((nd / w) as i64 - 1, (nd % w) as i64 - 1);
        let (i2, j2) = if edge.is_multiple_of(2) { (i + 1, j) } else { (i, j + 1) };
        let (a, b) = ((uv(i), uv(j)), (uv(i2), uv(j2)));
        let (mut ou, mut vu, mut hit) = match (occ[node(i, j)], occ[node(i2, j2)]) {
            (Some(x), None) => (a, b, x),
            (None, Some(x)) => (b, a, x),
            _ => unreachable!("crossing edges join an occluded and a visible node"),
        };
        for _ in 0..params.refine_steps {
            let m = (0.5 * (ou.0 + vu.0), 0.5 * (ou.1 + vu.1));
            match sample(m.0, m.1) {
                Some(x) => {
                    ou = m;
                    hit = x;
                }
                None => vu = m,
            }
        }
        if vu.0 * vu.0 + vu.1 * vu.1 >= 1.0 {
            let d = lambert_inv(ou.0, ou.1, &f);
            let t = (d - d.dot(nn) * nn).try_normalize().unwrap_or(f[0]);
            [t.x as f32, t.y as f32, t.z as f32, 0.0]
        } else {
            [hit.x as f32, hit.y as f32, hit.z as f32, 1.0]
        }
    };
    let mut starts: Vec<usize> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut done = std::collections::HashSet::new();
    let mut loops = Vec::new();
    for s in starts {
        if done.contains(&s) {
            continue;
        }
        let mut l = Vec::new();
        let mut e = s;
        while done.insert(e) {
            l.push(crossing_point(e));
            match next.get(&e) {
                Some(&x) => e = x,
                None => break,
            }
        }
        if l.len() >= 3 {
            loops.push(simplify(&l, p, params));
        }
    }
    loops
}

/// Direction of a homogeneous point seen from `p` (f64).
fn dir_of(q: [f32; 4], p: DVec3) -> DVec3 {
    let d = DVec3::new(q[0] as f64, q[1] as f64, q[2] as f64) - q[3] as f64 * p;
    d.try_normalize().unwrap_or(DVec3::Z)
}

/// Angle between `d` and the great arc `a -> b` (to the great circle when the foot is inside
/// the arc, else to the nearer end point).
fn arc_distance(d: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ang = |x: DVec3, y: DVec3| x.dot(y).clamp(-1.0, 1.0).acos();
    let c = a.cross(b);
    let cl = c.length();
    if cl < 1e-12 {
        return ang(d, a);
    }
    let c = c / cl;
    let foot = d - c * d.dot(c);
    if foot.length() > 1e-12 {
        let f = foot.normalize();
        if a.cross(f).dot(c) >= 0.0 && f.cross(b).dot(c) >= 0.0 {
            return d.dot(c).abs().clamp(0.0, 1.0).asin();
        }
    }
    ang(d, a).min(ang(d, b))
}

/// Douglas-Peucker on a closed loop (angle tolerance), keeping segments under the length cap
/// and at least 3 points.
pub fn simplify(l: &[[f32; 4]], p: DVec3, params: &VvParams) -> Vec<[f32; 4]> {
    let m = l.len();
    if m <= 3 {
        return l.to_vec();
    }
    let dirs: Vec<DVec3> = l.iter().map(|q| dir_of(*q, p)).collect();
    let tol = (params.tolerance_deg as f64).to_radians();
    let cap = (params.max_segment_deg as f64).to_radians();
    let far = (1..m).max_by(|&a, &b| dirs[0].dot(dirs[b]).total_cmp(&dirs[0].dot(dirs[a]))).unwrap();
    let third = if far > 1 { far / 2 } else { (far + m) / 2 };
    let mut keep = vec![false; m];
    keep[0] = true;
    keep[far] = true;
    keep[third.min(m - 1)] = true;
    let mut anchors: Vec<usize> = (0..m).filter(|&i| keep[i]).collect();
    anchors.push(m);
    for w in anchors.windows(2) {
        dp(&dirs, w[0], w[1], tol, cap, &mut keep);
    }
    (0..m).filter(|&i| keep[i]).map(|i| l[i]).collect()
}

fn dp(dirs: &[DVec3], a: usize, b: usize, tol: f64, cap: f64, keep: &mut [bool]) {
    if b <= a + 1 {
        return;
    }
    let m = dirs.len();
    let (da, db) = (dirs[a], dirs[b % m]);
    let (mut worst, mut wi) = (-1.0, a + 1);
    for (i, &di) in dirs[..b].iter().enumerate().skip(a + 1) {
        let d = arc_distance(di, da, db);
        if d > worst {
            worst = d;
            wi = i;
        }
    }
    let long = da.dot(db).clamp(-1.0, 1.0).acos() > cap;
    if worst > tol || long {
        let split = if worst > tol { wi } else { (a + b) / 2 };
        keep[split] = true;
        dp(dirs, a, split, tol, cap, keep);
        dp(dirs, split, b, tol, cap, keep);
    }
}

//! Spherical Delaunay triangulation (= the dual of the spherical Voronoi diagram) of unit
//! vectors as their 3D convex hull (incremental, O(n^2)); [`sites`] prepares raw sites:
//! duplicates merged, a seeded symbolic perturbation breaks cocircular configurations.
//!
//! Each hull face is a Voronoi vertex (its circumcentre is the face normal) whose three
//! Voronoi cells are the face's sites.

use glam::DVec3;
use std::collections::HashMap;

/// Sites prepared for the hull: unique directions and, per unique direction, the input sites
/// it stands for.
pub struct Sites {
    /// Unique (perturbed) unit directions.
    pub dirs: Vec<DVec3>,
    /// Per unique direction, the indices of the input sites merged into it.
    pub members: Vec<Vec<usize>>,
}

/// Merges input directions closer than `1e-9` rad (sorted, so the result does not depend on
/// the input order beyond ties), then perturbs each unique direction by at most ~`1e-7` rad
/// with a hash of `seed` and its index (deterministic).
pub fn sites(input: &[DVec3], seed: u64) -> Sites {
    let mut order: Vec<usize> =
        (0..input.len()).filter(|&i| input[i].is_finite() && input[i].length_squared() > 0.5).collect();
    order.sort_by(|&a, &b| {
        let (p, q) = (input[a], input[b]);
        p.x.total_cmp(&q.x).then(p.y.total_cmp(&q.y)).then(p.z.total_cmp(&q.z)).then(a.cmp(&b))
    });
    let mut dirs: Vec<DVec3> = Vec::new();
    let mut members: Vec<Vec<usize>> = Vec::new();
    // grid hashing for duplicates
    let cell = 1e-9;
    let key = |d: DVec3| [(d.x / cell).floor() as i64, (d.y / cell).floor() as i64, (d.z / cell).floor() as i64];
    let mut grid: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for &i in &order {
        let d = input[i].normalize();
        let k = key(d);
        let mut found = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &u in list {
                            if (dirs[u] - d).length() < cell {
                                found = Some(u);
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        match found {
            Some(u) => members[u].push(i),
            None => {
                grid.entry(k).or_default().push(dirs.len());
                dirs.push(d);
                members.push(vec![i]);
            }
        }
    }
    for (u, d) in dirs.iter_mut().enumerate() {
        let h = |s: u64| {
            let mut z = seed.wrapping_add(0x9e3779b97f4a7c15u64.wrapping_mul(u as u64 * 3 + s + 1));
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        *d = (*d + DVec3::new(h(0), h(1), h(2)) * 2e-7).normalize();
    }
    Sites { dirs, members }
}

struct Face {
    v: [usize; 3],
    n: DVec3,
    d: f64,
    alive: bool,
}

fn face(p: &[DVec3], v: [usize; 3]) -> Face {
    let n = (p[v[1]] - p[v[0]]).cross(p[v[2]] - p[v[0]]).normalize_or_zero();
    Face { v, n, d: n.dot(p[v[0]]), alive: true }
}

/// Convex hull faces (outward, counter-clockwise seen from outside) of points on the unit
/// sphere. Fewer than 3 points: no face; exactly 3 (or all coplanar): the two sides of their
/// triangle fan (every face is still a Delaunay triangle of the circle they lie on).
pub fn convex_hull(p: &[DVec3]) -> Vec<[usize; 3]> {
    let n = p.len();
    if n < 3 {
        return Vec::new();
    }
    let i0 = 0;
    let i1 =
        (1..n).max_by(|&a, &b| (p[a] - p[i0]).length_squared().total_cmp(&(p[b] - p[i0]).length_squared())).unwrap();
    let e = (p[i1] - p[i0]).normalize_or_zero();
    let line_d = |x: DVec3| {
        let w = x - p[i0];
        (w - e * w.dot(e)).length_squared()
    };
    let i2 = (0..n).max_by(|&a, &b| line_d(p[a]).total_cmp(&line_d(p[b]))).unwrap();
    if line_d(p[i2]) < 1e-24 {
        return Vec::new();
    }
    let pn = (p[i1] - p[i0]).cross(p[i2] - p[i0]).normalize();
    let plane_d = |x: DVec3| (x - p[i0]).dot(pn);
    let i3 = (0..n).max_by(|&a, &b| plane_d(p[a]).abs().total_cmp(&plane_d(p[b]).abs())).unwrap();
    if plane_d(p[i3]).abs() < 1e-13 {
        // coplanar: fan both sides (points ordered by angle around the plane normal)
        let c = p.iter().copied().sum::<DVec3>() / n as f64;
        let u = e;
        let v = pn.cross(u);
        let mut ord: Vec<usize> = (0..n).collect();
        ord.sort_by(|&a, &b| {
            let (wa, wb) = (p[a] - c, p[b] - c);
            wa.dot(v).atan2(wa.dot(u)).total_cmp(&wb.dot(v).atan2(wb.dot(u)))
        });
        let mut out = Vec::new();
        for k in 1..n - 1 {
            out.push([ord[0], ord[k], ord[k + 1]]);
            out.push([ord[0], ord[k + 1], ord[k]]);
        }
        return out;
    }
    let mut faces: Vec<Face> = Vec::new();
    let mut edges: HashMap<(usize, usize), usize> = HashMap::new();
    let centroid = (p[i0] + p[i1] + p[i2] + p[i3]) * 0.25;
    let add = |faces: &mut Vec<Face>, edges: &mut HashMap<(usize, usize), usize>, v: [usize; 3]| {
        let f = face(p, v);
        let id = faces.len();
        for k in 0..3 {
            edges.insert((v[k], v[(k + 1) % 3]), id);
        }
        faces.push(f);
    };
    for t in [[i0, i1, i2], [i0, i1, i3], [i0, i2, i3], [i1, i2, i3]] {
        let f = face(p, t);
        let v = if f.n.dot(centroid) - f.d > 0.0 { [t[0], t[2], t[1]] } else { t };
        add(&mut faces, &mut edges, v);
    }
    let eps = 1e-15;
    for (i, &x) in p.iter().enumerate() {
        if i == i0 || i == i1 || i == i2 || i == i3 {
            continue;
        }
        let visible: Vec<usize> =
            (0..faces.len()).filter(|&f| faces[f].alive && faces[f].n.dot(x) - faces[f].d > eps).collect();
        if visible.is_empty() {
            continue;
        }
        let mut horizon = Vec::new();
        for &f in &visible {
            let v = faces[f].v;
            for k in 0..3 {
                let (a, b) = (v[k], v[(k + 1) % 3]);
                let twin = edges.get(&(b, a)).copied();
                let twin_visible = twin.is_some_and(|t| faces[t].alive && faces[t].n.dot(x) - faces[t].d > eps);
                if !twin_visible {
                    horizon.push((a, b));
                }
            }
        }
        for &f in &visible {
            faces[f].alive = false;
            let v = faces[f].v;
            for k in 0..3 {
                let key = (v[k], v[(k + 1) % 3]);
                if edges.get(&key) == Some(&f) {
                    edges.remove(&key);
                }
            }
        }
        for (a, b) in horizon {
            add(&mut faces, &mut edges, [a, b, i]);
        }
    }
    faces.into_iter().filter(|f| f.alive).map(|f| f.v).collect()
}

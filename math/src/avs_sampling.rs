//! CPU parts of adaptive visibility sampling (Wang et al., "Parallel and adaptive visibility
//! sampling", sections 4.1 and 4.3): the geometric error metric `e_g` (eq. 6), k-means clustering
//! of vertices with it, a kd-tree over sample points with range search, the SH16 spatial
//! visibility error `e_v` (eq. 7), the inverse-`e_g` interpolation weights (eq. 8) and one
//! insert/erase step of the spatial adaptation.
//!
//! Positions are divided by the scene scale (the bounding-box diagonal of the vertices, see
//! [`scene_scale`]) before `e_g` is evaluated, so `alpha` means the same for every scene (the
//! paper: 0.1 - 0.5 "after the scene geometry scale is normalized").
//!
//! The SH16 projection of a visibility map is the order-4 real SH (`crate::sh` convention) of
//! the visibility function over WORLD directions (`V = 1` on visible texels of the hemisphere,
//! 0 elsewhere), so coefficients of points with different tangent frames are comparable;
//! [`sh16_project`] is the CPU mirror of the GPU pass (`glsl/avs/avs_sh.comp`).

use crate::avs_maps::{texel_dir, texel_solid_angle, Frame, VisMap};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Number of SH coefficients of the spatial error (4 bands).
pub const SH_COUNT: usize = 16;

/// Bounding-box diagonal of `positions` (1 when empty or degenerate).
pub fn scene_scale(positions: &[Vec3]) -> f32 {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in positions.iter().filter(|p| p.is_finite()) {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let d = (hi - lo).length();
    if d.is_finite() && d > 0.0 {
        d
    } else {
        1.0
    }
}

/// Eq. 6: `alpha |x_i - x_k| / scale + sqrt(2 - 2 n_i . n_k)` (normals unit length).
pub fn e_g(alpha: f32, inv_scale: f32, xi: Vec3, ni: Vec3, xk: Vec3, nk: Vec3) -> f32 {
    alpha * (xi - xk).length() * inv_scale + (2.0 - 2.0 * ni.dot(nk)).max(0.0).sqrt()
}

/// A surface point (vertex) with its unit normal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfacePoint {
    /// World position.
    pub pos: Vec3,
    /// Unit normal.
    pub normal: Vec3,
}

/// k-means over `points` with the `e_g` metric (centres: mean position and renormalised mean
/// normal), `iterations` Lloyd steps from `k` seeds spread along a Morton order; returns the
/// index of the point nearest (in `e_g`) to each non-empty cluster's centre, sorted and without
/// duplicates. `progress(done, total)` is called once per iteration.
pub fn kmeans_eg(
    points: &[SurfacePoint],
    k: usize,
    alpha: f32,
    iterations: usize,
    progress: &mut dyn FnMut(usize, usize),
) -> Vec<usize> {
    let n = points.len();
    if n == 0 || k == 0 {
        return Vec::new();
    }
    if k >= n {
        return (0..n).collect();
    }
    let pos: Vec<Vec3> = points.iter().map(|p| p.pos).collect();
    let scale = scene_scale(&pos);
    let inv = 1.0 / scale;
    // Seeds: every (n/k)-th point along a Morton order of the positions (spatially spread).
    let order = morton_order(&pos);
    let mut centres: Vec<SurfacePoint> = (0..k).map(|c| points[order[(c * n) / k + n / (2 * k)]]).collect();
    let mut assign = vec![0usize; n];
    // Candidate centres of a point: rings of grid cells around it until the positional term
    // alone exceeds the best e_g found.
    let iterations = iterations.max(1);
    for it in 0..iterations {
        let grid = Grid::new(&centres.iter().map(|c| c.pos).collect::<Vec<_>>(), 0.0);
        assign.par_iter_mut().enumerate().for_each(|(i, a)| {
            let p = points[i];
            let mut best = (f32::MAX, 0usize);
            for ring in 0.. {
                if !grid.visit_ring(p.pos, ring, |c, _| {
                    let e = e_g(alpha, inv, p.pos, p.normal, centres[c].pos, centres[c].normal);
                    if e < best.0 {
                        best = (e, c);
                    }
                }) {
                    break;
                }
                // later rings are at least ring * cell away: their e_g exceeds alpha * that
                if alpha * ring as f32 * grid.cell * inv > best.0 {
                    break;
                }
            }
            *a = best.1;
        });
        let mut sum_p = vec![Vec3::ZERO; k];
        let mut sum_n = vec![Vec3::ZERO; k];
        let mut count = vec![0usize; k];
        for (i, &c) in assign.iter().enumerate() {
            sum_p[c] += points[i].pos;
            sum_n[c] += points[i].normal;
            count[c] += 1;
        }
        for c in 0..k {
            if count[c] > 0 {
                let nn = sum_n[c].normalize_or_zero();
                centres[c] = SurfacePoint {
                    pos: sum_p[c] / count[c] as f32,
                    normal: if nn == Vec3::ZERO { centres[c].normal } else { nn },
                };
            }
        }
        progress(it + 1, iterations);
    }
    // Nearest member of each cluster to its centre.
    let mut best = vec![(f32::MAX, usize::MAX); k];
    for (i, &c) in assign.iter().enumerate() {
        let e = e_g(alpha, inv, points[i].pos, points[i].normal, centres[c].pos, centres[c].normal);
        if e < best[c].0 {
            best[c] = (e, i);
        }
    }
    let mut out: Vec<usize> = best.into_iter().filter(|b| b.1 != usize::MAX).map(|b| b.1).collect();
    out.sort_unstable();
    out.dedup();
    out
}

fn morton_order(pos: &[Vec3]) -> Vec<usize> {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in pos {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let ext = (hi - lo).max(Vec3::splat(1e-20));
    let spread = |v: u32| -> u64 {
        let mut x = v as u64 & 0x1fffff;
        x = (x | x << 32) & 0x1f00000000ffff;
        x = (x | x << 16) & 0x1f0000ff0000ff;
        x = (x | x << 8) & 0x100f00f00f00f00f;
        x = (x | x << 4) & 0x10c30c30c30c30c3;
        (x | x << 2) & 0x1249249249249249
    };
    let code = |p: Vec3| {
        let q = ((p - lo) / ext * 2097151.0).clamp(Vec3::ZERO, Vec3::splat(2097151.0));
        spread(q.x as u32) | spread(q.y as u32) << 1 | spread(q.z as u32) << 2
    };
    let mut idx: Vec<usize> = (0..pos.len()).collect();
    idx.sort_by_key(|&i| code(pos[i]));
    idx
}

/// A uniform grid over points (cell lists), for nearest and range queries; also the layout the
/// GPU range search reads (`cell_start`, `items`).
#[derive(Clone, Debug)]
pub struct Grid {
    /// Lower corner.
    pub lo: Vec3,
    /// Cell edge.
    pub cell: f32,
    /// Cells per axis.
    pub dims: [u32; 3],
    /// `cells + 1` prefix offsets into `items`.
    pub cell_start: Vec<u32>,
    /// Point indices sorted by cell.
    pub items: Vec<u32>,
    points: Vec<Vec3>,
}

impl Grid {
    /// Grid over `points` with cell edge `cell` (0: chosen for about 2 points per cell), at most
    /// 128 cells per axis and 2^21 cells.
    pub fn new(points: &[Vec3], cell: f32) -> Grid {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for p in points {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        if points.is_empty() {
            lo = Vec3::ZERO;
            hi = Vec3::ZERO;
        }
        let ext = (hi - lo).max(Vec3::splat(1e-6));
        let mut cell = if cell > 0.0 && cell.is_finite() {
            cell
        } else {
            let vol = ext.x * ext.y * ext.z;
            let area = ext.x * ext.y + ext.y * ext.z + ext.x * ext.z;
            // surfaces: points spread over an area more than a volume
            (area / (points.len().max(1) as f32 / 2.0)).sqrt().max((vol / points.len().max(1) as f32).cbrt()).max(1e-6)
        };
        let dims_for = |c: f32| {
            let d = (ext / c).ceil();
            [d.x.max(1.0) as u32, d.y.max(1.0) as u32, d.z.max(1.0) as u32]
        };
        let mut dims = dims_for(cell);
        while dims.iter().any(|&d| d > 128) || (dims[0] as u64 * dims[1] as u64 * dims[2] as u64) > (1 << 21) {
            cell *= 1.5;
            dims = dims_for(cell);
        }
        let ncells = (dims[0] * dims[1] * dims[2]) as usize;
        let mut g = Grid {
            lo,
            cell,
            dims,
            cell_start: vec![0; ncells + 1],
            items: vec![0; points.len()],
            points: points.to_vec(),
        };
        let cells: Vec<usize> = points.iter().map(|p| g.cell_index(g.cell_of(*p))).collect();
        for &c in &cells {
            g.cell_start[c + 1] += 1;
        }
        for c in 0..ncells {
            g.cell_start[c + 1] += g.cell_start[c];
        }
        let mut fill = g.cell_start.clone();
        for (i, &c) in cells.iter().enumerate() {
            g.items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        g
    }

    /// The points the grid was built over.
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Integer cell of `p` (clamped to the grid).
    pub fn cell_of(&self, p: Vec3) -> [i32; 3] {
        let q = ((p - self.lo) / self.cell).floor();
        [
            (q.x as i32).clamp(0, self.dims[0] as i32 - 1),
            (q.y as i32).clamp(0, self.dims[1] as i32 - 1),
            (q.z as i32).clamp(0, self.dims[2] as i32 - 1),
        ]
    }

    fn cell_index(&self, c: [i32; 3]) -> usize {
        (c[0] as usize) + self.dims[0] as usize * (c[1] as usize + self.dims[1] as usize * c[2] as usize)
    }

    /// Points within `radius` of `q` (indices, unordered).
    pub fn range(&self, q: Vec3, radius: f32) -> Vec<usize> {
        let mut out = Vec::new();
        if self.points.is_empty() {
            return out;
        }
        let r2 = radius * radius;
        let a = self.cell_of(q - Vec3::splat(radius));
        let b = self.cell_of(q + Vec3::splat(radius));
        for z in a[2]..=b[2] {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    let c = self.cell_index([x, y, z]);
                    for &i in &self.items[self.cell_start[c] as usize..self.cell_start[c + 1] as usize] {
                        if (self.points[i as usize] - q).length_squared() <= r2 {
                            out.push(i as usize);
                        }
                    }
                }
            }
        }
        out
    }

    /// Calls `f(index, squared distance)` for the points in the cells at Chebyshev distance
    /// `ring` from the cell of `q`; returns false when the ring lies entirely outside the grid.
    /// Points of rings beyond `ring` are at least `ring * cell` away from `q`.
    /// Only the ring's own cells are visited (its faces: O(ring^2) cells, not the cube's
    /// O(ring^3)): a nearest query far from every point (the midpoint of two points of different
    /// objects) walked tens of rings, 43 % of falling's `bench avs` time in session 40.
    pub fn visit_ring(&self, q: Vec3, ring: i32, mut f: impl FnMut(usize, f32)) -> bool {
        let c = self.cell_of(q);
        let mut inside = false;
        let (xlo, xhi) = ((c[0] - ring).max(0), (c[0] + ring).min(self.dims[0] as i32 - 1));
        let mut visit = |x: i32, y: i32, z: i32| {
            inside = true;
            let ci = self.cell_index([x, y, z]);
            for &i in &self.items[self.cell_start[ci] as usize..self.cell_start[ci + 1] as usize] {
                f(i as usize, (self.points[i as usize] - q).length_squared());
            }
        };
        for z in (c[2] - ring).max(0)..=(c[2] + ring).min(self.dims[2] as i32 - 1) {
            for y in (c[1] - ring).max(0)..=(c[1] + ring).min(self.dims[1] as i32 - 1) {
                if (y - c[1]).abs() == ring || (z - c[2]).abs() == ring {
                    // a face of the ring across x: every cell of the row
                    for x in xlo..=xhi {
                        visit(x, y, z);
                    }
                } else {
                    // inside the ring's y and z faces: its two x faces only
                    for x in [c[0] - ring, c[0] + ring] {
                        if x >= 0 && x < self.dims[0] as i32 {
                            visit(x, y, z);
                        }
                    }
                }
            }
        }
        inside
    }

    /// Index of the point nearest to `q` (Euclidean), `None` when empty.
    pub fn nearest(&self, q: Vec3) -> Option<usize> {
        let mut best = (f32::MAX, None);
        for ring in 0.. {
            if !self.visit_ring(q, ring, |i, d2| {
                if d2 < best.0 {
                    best = (d2, Some(i));
                }
            }) {
                break;
            }
            let reach = ring as f32 * self.cell;
            if best.1.is_some() && best.0 <= reach * reach {
                break;
            }
        }
        best.1
    }
}

/// A static 3-d tree over points for exact nearest-point queries: balanced, median splits on
/// the widest axis of each range, stored implicitly (the node of range `[lo, hi)` is its middle
/// entry). A query costs O(log n) where it lies near points and stays cheap far from all of them:
/// the midpoints the adaptation looks up between two sample points of different objects lie in
/// empty space, where [`Grid::nearest`] walks ring after ring of cells (falling's pool grid:
/// 45 % of its adaptation step in session 40).
#[derive(Clone, Debug, Default)]
pub struct PointTree {
    points: Vec<Vec3>,
    /// Point indices in tree order.
    order: Vec<u32>,
    /// Split axis of the node at each position.
    axis: Vec<u8>,
}

impl PointTree {
    /// The tree of `points` (indices into it are the query results).
    pub fn new(points: &[Vec3]) -> PointTree {
        let mut t = PointTree {
            points: points.to_vec(),
            order: (0..points.len() as u32).collect(),
            axis: vec![0; points.len()],
        };
        t.build(0, points.len());
        t
    }

    fn build(&mut self, lo: usize, hi: usize) {
        if hi - lo <= 1 {
            return;
        }
        let (mut a, mut b) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for &i in &self.order[lo..hi] {
            a = a.min(self.points[i as usize]);
            b = b.max(self.points[i as usize]);
        }
        let e = b - a;
        let ax = if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        };
        let mid = (lo + hi) / 2;
        let pts = &self.points;
        self.order[lo..hi].select_nth_unstable_by(mid - lo, |&x, &y| {
            pts[x as usize][ax].total_cmp(&pts[y as usize][ax]).then(x.cmp(&y))
        });
        self.axis[mid] = ax as u8;
        self.build(lo, mid);
        self.build(mid + 1, hi);
    }

    /// Index of the point nearest to `q` (Euclidean; of equally near points the lowest index),
    /// `None` when empty.
    pub fn nearest(&self, q: Vec3) -> Option<usize> {
        let mut best = (f32::INFINITY, u32::MAX);
        self.search(0, self.order.len(), q, &mut best);
        (best.1 != u32::MAX).then_some(best.1 as usize)
    }

    fn search(&self, lo: usize, hi: usize, q: Vec3, best: &mut (f32, u32)) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        let i = self.order[mid];
        let p = self.points[i as usize];
        let d2 = (p - q).length_squared();
        if d2 < best.0 || (d2 == best.0 && i < best.1) {
            *best = (d2, i);
        }
        if hi - lo == 1 {
            return;
        }
        let ax = self.axis[mid] as usize;
        let diff = q[ax] - p[ax];
        let (near, far) = if diff < 0.0 { ((lo, mid), (mid + 1, hi)) } else { ((mid + 1, hi), (lo, mid)) };
        self.search(near.0, near.1, q, best);
        // the far side's points lie at least |diff| away along the axis (ties kept: an equally
        // near point of lower index may lie there)
        if diff * diff <= best.0 {
            self.search(far.0, far.1, q, best);
        }
    }
}

/// Order-4 SH (16 coefficients) of a visibility map of a point with frame `frame`, over world
/// directions (see the module docs).
pub fn sh16_project(map: &VisMap, frame: &Frame) -> [f32; SH_COUNT] {
    let r = map.r;
    let mut acc = [0f64; SH_COUNT];
    let mut basis = [0f64; SH_COUNT];
    for i in 0..r {
        let sa = texel_solid_angle(i, r);
        for j in 0..r {
            if !map.get(i, j) {
                continue;
            }
            let w = frame.to_world(texel_dir(i, j, r));
            crate::sh::eval_basis_into(4, w, &mut basis);
            for k in 0..SH_COUNT {
                acc[k] += basis[k] * sa;
            }
        }
    }
    acc.map(|v| v as f32)
}

/// Eq. 7: `sum |c_i - c_k|`.
pub fn e_v(a: &[f32; SH_COUNT], b: &[f32; SH_COUNT]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum()
}

/// `sum |c|` (the denominator of the relative error).
pub fn sh_norm(a: &[f32; SH_COUNT]) -> f32 {
    a.iter().map(|x| x.abs()).sum()
}

/// Eq. 8 weights of neighbours `(pos, normal)` at `(x, n)`: `1/e_g` normalised (an `e_g` below
/// `1e-6` counts as `1e-6`). Empty for no neighbours.
pub fn eq8_weights(alpha: f32, inv_scale: f32, x: Vec3, n: Vec3, neighbours: &[(Vec3, Vec3)]) -> Vec<f32> {
    let inv: Vec<f32> = neighbours.iter().map(|(p, m)| 1.0 / e_g(alpha, inv_scale, x, n, *p, *m).max(1e-6)).collect();
    let s: f32 = inv.iter().sum();
    inv.into_iter().map(|w| w / s).collect()
}

/// Whether `b` may stand in for `a` (interpolation neighbours): normals in the same hemisphere
/// and `b` within a quarter of `radius` of `a`'s tangent plane (points off the plane lie on another
/// surface, e.g. cloth under a hat brim; `e_g` alone barely separates them after the scale
/// normalisation). The same test is used by the GPU shading (`glsl/avs/avs_shade.comp`).
pub fn same_surface(a: &SurfacePoint, b: &SurfacePoint, radius: f32) -> bool {
    a.normal.dot(b.normal) > 0.0 && (b.pos - a.pos).dot(a.normal).abs() <= 0.25 * radius
}

/// Parameters of one spatial adaptation step.
#[derive(Clone, Copy, Debug)]
pub struct AdaptParams {
    /// `alpha` of `e_g`.
    pub alpha: f32,
    /// Range-search radius (world units).
    pub radius: f32,
    /// Relative error above which points are inserted (paper: 0.10).
    pub e_max: f32,
    /// Relative error below which a point may be erased (paper: 0.05).
    pub e_min: f32,
}

/// What one adaptation step decided.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AdaptStep {
    /// Relative interpolation error `e_v(x_i, x_avg) / sum |c_i|` per point (`None` without
    /// neighbours in range).
    pub rel_error: Vec<Option<f32>>,
    /// Indices into the candidate pool to insert (nearest pool vertex to the midpoint of a point
    /// and a neighbour with pairwise relative error above `e_max`), deduplicated, not already
    /// sample points.
    pub insert: Vec<usize>,
    /// Indices into `points` to erase.
    pub erase: Vec<usize>,
}

/// The visible solid angle of a map from its SH16 projection: the DC coefficient over the
/// constant basis function Y_00 = 1 / (2 sqrt(pi)).
pub fn visible_solid_angle(sh: &[f32; SH_COUNT]) -> f32 {
    sh[0] * 2.0 * std::f32::consts::PI.sqrt()
}

/// A sample point whose map is occluded in every direction (`visible`, its map's visible solid
/// angle, not above 0): a candidate inside a closed object (the pool's points on a floor under a
/// chess piece's base), every ray hitting the object from within, or a point under something
/// that closes its whole hemisphere. Its map stands for no visible surface beside the object: it
/// takes no part in the adaptation (neither as a point nor as a neighbour), and the shading
/// interpolates it only where no other point is in reach (`glsl/include/avs_gather.glsl`; its
/// all-occluded map drew black rings around the objects standing on it).
pub fn buried(visible: f32) -> bool {
    !(visible > 0.0)
}

/// One step of section 4.3. `points` are the current sample points (their pool indices in
/// `pool_index`), `sh` their SH16 visibility, `pool` the candidate vertices. A point's neighbours
/// are the other points within `radius`; `x_avg` is their eq. 8 interpolation; relative error
/// above `e_max`: every neighbour whose pairwise relative error exceeds `e_max` yields a new point
/// at the pool vertex nearest to the pair's midpoint; below `e_min`: an erase candidate. Erasing
/// takes candidates in order of increasing error and erases one only if none of its neighbours
/// was erased in this step or is being inserted next to it, so no two adjacent points go at once.
/// `visible` holds each map's visible solid angle: [`buried`] points are left out, as points and
/// as neighbours.
pub fn adapt_step(
    points: &[SurfacePoint],
    pool_index: &[usize],
    sh: &[[f32; SH_COUNT]],
    visible: &[f32],
    pool: &[SurfacePoint],
    pool_tree: &PointTree,
    params: &AdaptParams,
) -> AdaptStep {
    let n = points.len();
    let pos: Vec<Vec3> = points.iter().map(|p| p.pos).collect();
    let grid = Grid::new(&pos, params.radius);
    let scale = scene_scale(&pool.iter().map(|p| p.pos).collect::<Vec<_>>());
    let inv = 1.0 / scale;
    let mut step = AdaptStep { rel_error: vec![None; n], ..Default::default() };
    let mut neighbours: Vec<Vec<usize>> = Vec::with_capacity(n);
    let existing: std::collections::HashSet<usize> = pool_index.iter().copied().collect();
    let mut inserted = std::collections::HashSet::new();
    let mut grows = vec![false; n];
    let mut candidates = Vec::new();
    // Per point, independent of the others (in parallel): its neighbours, its relative error and,
    // when it is over e_max, the pool candidate nearest the midpoint towards each neighbour it
    // differs from. The insertions are then taken in point order, as a sequential loop would.
    let evals: Vec<(Vec<usize>, Option<f32>, Vec<(usize, Option<usize>)>)> = (0..n)
        .into_par_iter()
        .map(|i| {
            if buried(visible[i]) {
                return (Vec::new(), None, Vec::new());
            }
            let nb: Vec<usize> = grid
                .range(points[i].pos, params.radius)
                .into_iter()
                .filter(|&j| j != i && !buried(visible[j]) && same_surface(&points[i], &points[j], params.radius))
                .collect();
            if nb.is_empty() {
                return (nb, None, Vec::new());
            }
            let pairs: Vec<(Vec3, Vec3)> = nb.iter().map(|&j| (points[j].pos, points[j].normal)).collect();
            let w = eq8_weights(params.alpha, inv, points[i].pos, points[i].normal, &pairs);
            let mut avg = [0f32; SH_COUNT];
            for (k, &j) in nb.iter().enumerate() {
                for c in 0..SH_COUNT {
                    avg[c] += w[k] * sh[j][c];
                }
            }
            let norm = sh_norm(&sh[i]).max(1e-6);
            let rel = e_v(&sh[i], &avg) / norm;
            let mut mids = Vec::new();
            if rel > params.e_max {
                for &j in &nb {
                    if e_v(&sh[i], &sh[j]) / norm > params.e_max {
                        mids.push((j, pool_tree.nearest(0.5 * (points[i].pos + points[j].pos))));
                    }
                }
            }
            (nb, Some(rel), mids)
        })
        .collect();
    for (i, (nb, rel, mids)) in evals.into_iter().enumerate() {
        let Some(rel) = rel else {
            neighbours.push(nb);
            continue;
        };
        step.rel_error[i] = Some(rel);
        if rel > params.e_max {
            for (j, v) in mids {
                if let Some(v) = v {
                    if !existing.contains(&v) && inserted.insert(v) {
                        step.insert.push(v);
                        grows[i] = true;
                        grows[j] = true;
                    }
                }
            }
        } else if rel < params.e_min {
            candidates.push((rel, i));
        }
        neighbours.push(nb);
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut blocked = grows;
    for (_, i) in candidates {
        if blocked[i] {
            continue;
        }
        step.erase.push(i);
        blocked[i] = true;
        for &j in &neighbours[i] {
            blocked[j] = true;
        }
    }
    step.erase.sort_unstable();
    step
}

/// The eq. 8 interpolation of `sh` at `x` from the points in range (helper for tests).
pub fn interpolate_sh(
    alpha: f32,
    inv_scale: f32,
    x: Vec3,
    n: Vec3,
    neighbours: &[(Vec3, Vec3, [f32; SH_COUNT])],
) -> [f32; SH_COUNT] {
    let pairs: Vec<(Vec3, Vec3)> = neighbours.iter().map(|(p, m, _)| (*p, *m)).collect();
    let w = eq8_weights(alpha, inv_scale, x, n, &pairs);
    let mut out = [0f32; SH_COUNT];
    for (k, (_, _, c)) in neighbours.iter().enumerate() {
        for i in 0..SH_COUNT {
            out[i] += w[k] * c[i];
        }
    }
    out
}

/// Frame of a sample point as the GPU passes use it (tangent from the world up hint).
pub fn point_frame(normal: Vec3) -> Frame {
    Frame::from_normal_hint(normal.as_dvec3(), DVec3::Y)
}

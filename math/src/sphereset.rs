//! Sphere-set approximation of closed triangle meshes (the blockers of the ISG technique).
//!
//! Method (a voxel variant of the medial-axis approach of Bradshaw & O'Sullivan 2004, "Adaptive
//! medial-axis approximation for sphere-tree construction"):
//! 1. the mesh is voxelized (inside/outside by ray parity along X, per column);
//! 2. the Euclidean distance transform of the outside gives, at each interior voxel, the radius of
//!    the largest inscribed sphere there; the maximal balls (not inside a neighbour's ball)
//!    approximate the medial axis and are the candidate spheres;
//! 3. `count` spheres are chosen greedily (lazy greedy max-coverage, a `1 - 1/e` approximation of
//!    the best `count`-subset) to cover the most interior voxels not covered yet.
//!
//! The spheres are inscribed (volume outside the mesh is only voxel-level). [`measure_coverage`]
//! reports the fraction of the mesh volume they cover and the volume they put outside it.
//!
//! Each sphere is bound to its four nearest mesh vertices: for a deformed mesh the centre is
//! `mean(deformed anchors) + (rest centre - mean(rest anchors))` and the radius scales with the
//! square root of the centre's clearance ratio to the mesh (deformed over rest), no refit ([`SphereSet::deformed`]).
//!
//! File format (text, `.spheres`): a line `penumbra-spheres 1 N`, then N lines
//! `cx cy cz r a0 a1 a2 a3` (object space, anchor vertex indices); `#` starts a comment.

use glam::{DVec3, Vec3};
use std::collections::BinaryHeap;
use std::fmt::Write as _;

/// One sphere in object space, bound to four mesh vertices.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoundSphere {
    /// Rest centre (object space).
    pub center: Vec3,
    /// Radius.
    pub radius: f32,
    /// Anchor vertex indices (nearest mesh vertices to the centre).
    pub anchors: [u32; 4],
}

/// A sphere set approximating one mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SphereSet {
    /// The spheres.
    pub spheres: Vec<BoundSphere>,
    /// Per sphere, its centre's distance to the rest mesh ([`SphereSet::with_rest_clearances`]),
    /// which [`SphereSet::deformed`] then reuses instead of searching the rest mesh every frame;
    /// empty (or of another length): searched.
    pub rest_clearance: Vec<Option<f32>>,
}

/// Problems with the input mesh or a sphere file.
#[derive(Debug, Clone, PartialEq)]
pub enum SphereError {
    /// The mesh has no triangles, an index out of range or a non-finite position.
    BadMesh(String),
    /// A sphere file could not be parsed.
    Parse(String),
}

impl std::fmt::Display for SphereError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SphereError::BadMesh(m) => write!(f, "bad mesh: {m}"),
            SphereError::Parse(m) => write!(f, "bad sphere file: {m}"),
        }
    }
}

impl std::error::Error for SphereError {}

/// Coverage of a mesh by a sphere set.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coverage {
    /// Mesh volume (from the voxelization).
    pub mesh_volume: f64,
    /// Fraction of the mesh volume inside at least one sphere.
    pub covered: f64,
    /// Volume inside spheres but outside the mesh, as a fraction of the mesh volume.
    pub outside: f64,
}

fn check_mesh(positions: &[Vec3], indices: &[u32]) -> Result<(), SphereError> {
    if indices.len() < 3 || !indices.len().is_multiple_of(3) {
        return Err(SphereError::BadMesh(format!("{} indices (need a positive multiple of 3)", indices.len())));
    }
    if let Some(i) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(SphereError::BadMesh(format!("index {i} out of range ({} vertices)", positions.len())));
    }
    if positions.iter().any(|p| !p.is_finite()) {
        return Err(SphereError::BadMesh("non-finite vertex position".into()));
    }
    Ok(())
}

/// An inside/outside voxel grid of a mesh, with one voxel of padding on every side.
struct Voxels {
    origin: DVec3,
    h: f64,
    dims: [usize; 3],
    inside: Vec<bool>,
}

impl Voxels {
    fn idx(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.dims[1] + y) * self.dims[0] + x
    }
    fn center(&self, x: usize, y: usize, z: usize) -> DVec3 {
        self.origin + DVec3::new(x as f64 + 0.5, y as f64 + 0.5, z as f64 + 0.5) * self.h
    }
}

fn voxelize(positions: &[Vec3], indices: &[u32], resolution: usize) -> Voxels {
    let res = resolution.clamp(4, 512);
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &i in indices {
        let p = positions[i as usize].as_dvec3();
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let ext = (hi - lo).max_element().max(1e-9);
    let h = ext / res as f64;
    let origin = lo - DVec3::splat(h);
    let dims = [
        ((hi.x - lo.x) / h).ceil() as usize + 2,
        ((hi.y - lo.y) / h).ceil() as usize + 2,
        ((hi.z - lo.z) / h).ceil() as usize + 2,
    ];
    let mut v = Voxels { origin, h, dims, inside: vec![false; dims[0] * dims[1] * dims[2]] };
    // Bin triangles by the (y, z) columns their bounding boxes touch.
    let (ny, nz) = (dims[1], dims[2]);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); ny * nz];
    let tris: Vec<[DVec3; 3]> =
        indices.chunks_exact(3).map(|t| [0, 1, 2].map(|k| positions[t[k] as usize].as_dvec3())).collect();
    for (ti, t) in tris.iter().enumerate() {
        let ymin = t.iter().map(|p| p.y).fold(f64::INFINITY, f64::min);
        let ymax = t.iter().map(|p| p.y).fold(f64::NEG_INFINITY, f64::max);
        let zmin = t.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
        let zmax = t.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
        let cy0 = (((ymin - origin.y) / h - 0.5).floor().max(0.0)) as usize;
        let cy1 = ((((ymax - origin.y) / h - 0.5).ceil()).max(0.0) as usize).min(ny - 1);
        let cz0 = (((zmin - origin.z) / h - 0.5).floor().max(0.0)) as usize;
        let cz1 = ((((zmax - origin.z) / h - 0.5).ceil()).max(0.0) as usize).min(nz - 1);
        for z in cz0..=cz1 {
            for y in cy0..=cy1 {
                bins[z * ny + y].push(ti as u32);
            }
        }
    }
    let mut xs = Vec::new();
    for z in 0..nz {
        for y in 0..ny {
            // Tiny irrational offsets keep the ray off edges and vertices.
            let py = origin.y + (y as f64 + 0.5 + 1.37e-7) * h;
            let pz = origin.z + (z as f64 + 0.5 + 2.71e-7) * h;
            xs.clear();
            for &ti in &bins[z * ny + y] {
                let [a, b, c] = tris[ti as usize];
                // Barycentrics of (py, pz) in the triangle's (y, z) projection.
                let d = (b.y - a.y) * (c.z - a.z) - (c.y - a.y) * (b.z - a.z);
                if d.abs() < 1e-300 {
                    continue;
                }
                let u = ((py - a.y) * (c.z - a.z) - (c.y - a.y) * (pz - a.z)) / d;
                let w = ((b.y - a.y) * (pz - a.z) - (py - a.y) * (b.z - a.z)) / d;
                if u < 0.0 || w < 0.0 || u + w > 1.0 {
                    continue;
                }
                xs.push(a.x + u * (b.x - a.x) + w * (c.x - a.x));
            }
            xs.sort_by(|p, q| p.total_cmp(q));
            let mut k = 0;
            for x in 0..dims[0] {
                let px = origin.x + (x as f64 + 0.5) * h;
                while k < xs.len() && xs[k] < px {
                    k += 1;
                }
                if k % 2 == 1 {
                    let i = v.idx(x, y, z);
                    v.inside[i] = true;
                }
            }
        }
    }
    v
}

/// 1D squared distance transform (Felzenszwalb & Huttenlocher) of `f` in place.
fn dt1(f: &mut [f64], v: &mut Vec<usize>, z: &mut Vec<f64>, out: &mut Vec<f64>) {
    let n = f.len();
    v.clear();
    v.resize(n, 0);
    z.clear();
    z.resize(n + 1, 0.0);
    out.clear();
    out.resize(n, 0.0);
    let mut k = 0usize;
    // Find the first finite sample.
    let Some(first) = f.iter().position(|x| x.is_finite()) else { return };
    v[0] = first;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in first + 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0 and the new parabola dominates everywhere.
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
            break;
        }
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        *o = (q as f64 - p as f64).powi(2) + f[p];
    }
    f.copy_from_slice(out);
}

/// Squared distance (voxels) from every voxel centre to the nearest outside voxel centre.
fn distance_to_outside(v: &Voxels) -> Vec<f64> {
    let [nx, ny, nz] = v.dims;
    let mut d: Vec<f64> = v.inside.iter().map(|&i| if i { f64::INFINITY } else { 0.0 }).collect();
    let (mut vv, mut zz, mut out) = (Vec::new(), Vec::new(), Vec::new());
    let mut line = Vec::new();
    let dims = [nx, ny, nz];
    // one pass per axis over every line of voxels along it
    for axis in 0..3 {
        let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
        let at = |k: usize, i: usize, j: usize| {
            let mut c = [0; 3];
            (c[axis], c[u], c[w]) = (k, i, j);
            v.idx(c[0], c[1], c[2])
        };
        for j in 0..dims[w] {
            for i in 0..dims[u] {
                line.clear();
                line.extend((0..dims[axis]).map(|k| d[at(k, i, j)]));
                dt1(&mut line, &mut vv, &mut zz, &mut out);
                for (k, &x) in line.iter().enumerate() {
                    d[at(k, i, j)] = x;
                }
            }
        }
    }
    d
}

/// Visits the rows of voxels whose centres are within `r` voxels of voxel-space point `c`: for
/// each row `(y, z)` that has any, `f(y, z, x0, x1)` with the inclusive x range. The range comes
/// from a square root and is then settled with the exact test `|p - c|^2 <= r^2` at its ends (the
/// test is monotone along a row), so the visited voxels are exactly those the test accepts.
fn for_rows_in_sphere(dims: [usize; 3], c: DVec3, r: f64, mut f: impl FnMut(usize, usize, usize, usize)) {
    let lo = (c - DVec3::splat(r)).floor().max(DVec3::ZERO);
    let hi = (c + DVec3::splat(r)).ceil();
    let r2 = r * r;
    let (xlo, xhi) = (lo.x as usize, (hi.x as usize).min(dims[0] - 1));
    if xlo > xhi {
        return;
    }
    for z in lo.z as usize..=(hi.z as usize).min(dims[2] - 1) {
        for y in lo.y as usize..=(hi.y as usize).min(dims[1] - 1) {
            let inside = |x: usize| DVec3::new(x as f64, y as f64, z as f64).distance_squared(c) <= r2;
            let (dy, dz) = (y as f64 - c.y, z as f64 - c.z);
            let rest = r2 - dy * dy - dz * dz;
            // the nearest voxel of the row to c, then the estimate, settled both ways
            let mid = (c.x.round().max(xlo as f64) as usize).min(xhi);
            let s = rest.max(0.0).sqrt();
            let mut x0 = ((c.x - s).ceil().max(xlo as f64) as usize).min(mid);
            let mut x1 = ((c.x + s).floor().max(xlo as f64) as usize).clamp(mid, xhi);
            if !inside(mid) {
                continue;
            }
            while x0 > xlo && inside(x0 - 1) {
                x0 -= 1;
            }
            while x0 < mid && !inside(x0) {
                x0 += 1;
            }
            while x1 < xhi && inside(x1 + 1) {
                x1 += 1;
            }
            while x1 > mid && !inside(x1) {
                x1 -= 1;
            }
            f(y, z, x0, x1);
        }
    }
}

/// Visits the voxels whose centres are within `r` voxels of voxel-space point `c` (z, then y,
/// then x ascending).
pub fn for_voxels_in_sphere(dims: [usize; 3], c: DVec3, r: f64, mut f: impl FnMut(usize, usize, usize)) {
    for_rows_in_sphere(dims, c, r, |y, z, x0, x1| {
        for x in x0..=x1 {
            f(x, y, z);
        }
    });
}

/// Approximates the closed mesh `(positions, indices)` by at most `count` spheres (fewer if the
/// voxelized interior is covered earlier), voxelizing at 64 voxels along the longest axis.
/// See the module docs for the method. `count == 0` gives an empty set.
pub fn approximate_spheres(positions: &[Vec3], indices: &[u32], count: usize) -> Result<SphereSet, SphereError> {
    approximate_spheres_with(positions, indices, count, 64)
}

/// [`approximate_spheres`] with an explicit voxel resolution (voxels along the longest axis,
/// clamped to 4..512).
pub fn approximate_spheres_with(
    positions: &[Vec3],
    indices: &[u32],
    count: usize,
    resolution: usize,
) -> Result<SphereSet, SphereError> {
    check_mesh(positions, indices)?;
    if count == 0 {
        return Ok(SphereSet::default());
    }
    let vox = voxelize(positions, indices, resolution);
    let [nx, ny, nz] = vox.dims;
    let d2 = distance_to_outside(&vox);
    // Candidates: centres of maximal inscribed balls (the discrete medial axis): interior voxels
    // whose ball is not contained in a neighbour's ball (r_n < r + |n - x|).
    let mut cands: Vec<(usize, usize, usize, f64)> = Vec::new();
    for z in 1..nz - 1 {
        for y in 1..ny - 1 {
            for x in 1..nx - 1 {
                let c = d2[vox.idx(x, y, z)];
                if c <= 0.0 {
                    continue;
                }
                let r = c.sqrt();
                let mut maximal = true;
                'n: for dz in 0..3usize {
                    for dy in 0..3usize {
                        for dx in 0..3usize {
                            let k = (dx != 1) as usize + (dy != 1) as usize + (dz != 1) as usize;
                            if k == 0 {
                                continue;
                            }
                            let rn = d2[vox.idx(x + dx - 1, y + dy - 1, z + dz - 1)].sqrt();
                            if rn >= r + (k as f64).sqrt() - 1e-9 {
                                maximal = false;
                                break 'n;
                            }
                        }
                    }
                }
                if maximal {
                    // Radius to the surface: half a voxel short of the nearest outside centre.
                    cands.push((x, y, z, (r - 0.5).max(0.5)));
                }
            }
        }
    }
    // Bound the greedy cost: keep at most 20000 candidates (largest balls first, then strided).
    if cands.len() > 20000 {
        cands.sort_by(|a, b| b.3.total_cmp(&a.3));
        let stride = cands.len().div_ceil(20000);
        cands = cands.into_iter().step_by(stride).collect();
    }
    // A ball's gain is its count of inside voxels not yet covered, summed per row of the ball from
    // prefix counts of those voxels (`free`, one row of `px + 1` counts per (y, z)); covering a
    // ball recounts the rows it touches.
    let [px, py, pz] = vox.dims;
    let mut free_voxel = vox.inside.clone();
    let mut free = vec![0u32; (px + 1) * py * pz];
    let recount = |free: &mut [u32], free_voxel: &[bool], row: usize| {
        for x in 0..px {
            free[row * (px + 1) + x + 1] = free[row * (px + 1) + x] + free_voxel[row * px + x] as u32;
        }
    };
    for row in 0..py * pz {
        recount(&mut free, &free_voxel, row);
    }
    let gain = |c: &(usize, usize, usize, f64), free: &[u32]| {
        let mut g = 0usize;
        for_rows_in_sphere(vox.dims, DVec3::new(c.0 as f64, c.1 as f64, c.2 as f64), c.3 + 0.5, |y, z, x0, x1| {
            let row = (z * py + y) * (px + 1);
            g += (free[row + x1 + 1] - free[row + x0]) as usize;
        });
        g
    };
    let mut heap: BinaryHeap<(usize, usize)> = cands.iter().enumerate().map(|(i, c)| (gain(c, &free), i)).collect();
    let mut chosen = Vec::new();
    while chosen.len() < count {
        let Some((_, i)) = heap.pop() else { break };
        let g = gain(&cands[i], &free);
        if g == 0 {
            continue;
        }
        if let Some(&(next, _)) = heap.peek() {
            if g < next {
                heap.push((g, i));
                continue;
            }
        }
        let c = cands[i];
        for_rows_in_sphere(vox.dims, DVec3::new(c.0 as f64, c.1 as f64, c.2 as f64), c.3 + 0.5, |y, z, x0, x1| {
            let row = z * py + y;
            free_voxel[row * px + x0..=row * px + x1].fill(false);
            recount(&mut free, &free_voxel, row);
        });
        chosen.push(c);
    }
    let spheres = chosen
        .iter()
        .map(|&(x, y, z, r)| {
            let center = vox.center(x, y, z).as_vec3();
            BoundSphere { center, radius: ((r + 0.5) * vox.h) as f32, anchors: nearest4(positions, center) }
        })
        .collect();
    Ok(SphereSet { spheres, rest_clearance: Vec::new() })
}

fn nearest4(positions: &[Vec3], c: Vec3) -> [u32; 4] {
    let mut best = [(f32::INFINITY, 0u32); 4];
    for (i, p) in positions.iter().enumerate() {
        let d = p.distance_squared(c);
        if d < best[3].0 {
            best[3] = (d, i as u32);
            best.sort_by(|a, b| a.0.total_cmp(&b.0));
        }
    }
    let first = best[0].1;
    best.map(|(d, i)| if d.is_finite() { i } else { first })
}

/// Coverage of `(positions, indices)` by `spheres` on a voxel grid of `resolution` voxels along
/// the longest axis (independent of the grid used to build the set when the resolutions differ).
pub fn measure_coverage(
    positions: &[Vec3],
    indices: &[u32],
    spheres: &[BoundSphere],
    resolution: usize,
) -> Result<Coverage, SphereError> {
    check_mesh(positions, indices)?;
    let vox = voxelize(positions, indices, resolution);
    let mut hit = vec![false; vox.inside.len()];
    for s in spheres {
        let c = (s.center.as_dvec3() - vox.origin) / vox.h - DVec3::splat(0.5);
        let r = s.radius as f64 / vox.h;
        if !(c.is_finite() && r.is_finite()) || r <= 0.0 {
            continue;
        }
        for_voxels_in_sphere(vox.dims, c, r, |x, y, z| {
            let i = vox.idx(x, y, z);
            hit[i] = true;
        });
    }
    let vol = vox.h.powi(3);
    let inside = vox.inside.iter().filter(|&&b| b).count();
    let covered = vox.inside.iter().zip(&hit).filter(|(i, h)| **i && **h).count();
    // Counted on the padded grid (one voxel beyond the mesh bounds): enough for inscribed sets.
    let out_grid = vox.inside.iter().zip(&hit).filter(|(i, h)| !**i && **h).count();
    let inside_f = inside.max(1) as f64;
    Ok(Coverage {
        mesh_volume: inside as f64 * vol,
        covered: covered as f64 / inside_f,
        outside: out_grid as f64 / inside_f,
    })
}

impl SphereSet {
    /// Spheres for deformed vertex positions (same vertex order as the rest mesh): each centre
    /// moves with the mean of its four anchors, and with the mesh's triangles (`indices`, empty:
    /// radii kept) each radius scales by the square root of the centre's clearance ratio (its
    /// distance to the nearest triangle, deformed over at rest). A sphere under an anisotropic
    /// deformation becomes an ellipsoid: scaling by the clearance ratio itself gives the
    /// inscribed sphere (it never pokes out, but is as thin as the ellipsoid's shortest axis),
    /// keeping the radius gives a volume-preserving squash's equal-volume sphere (it pokes out
    /// of the flattened side); the geometric mean lies between. hat_on_cloth at frame 30
    /// (squashed to 0.7 of its height), isg rmse/mean at 40x30 / 160x120: radius kept 0.0626 /
    /// 0.0460 (the crown's flat top blotched by its own spheres poking through it), clearance
    /// ratio 0.0604 / 0.0486 (no blotches, the crown's shadow on the brim too light), its square
    /// root 0.0579 / 0.0455. Anchors out of range keep the rest sphere.
    pub fn deformed(&self, rest: &[Vec3], deformed: &[Vec3], indices: &[u32]) -> Vec<BoundSphere> {
        // each mesh's triangles bounded once, searched by every sphere; the rest mesh's
        // clearances from the cache when the set holds them
        let cached = self.rest_clearance.len() == self.spheres.len();
        let rest_tris = (!cached).then(|| MeshTriangles::new(rest, indices));
        let now_tris = MeshTriangles::new(deformed, indices);
        self.spheres
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let ok = s.anchors.iter().all(|&a| (a as usize) < rest.len() && (a as usize) < deformed.len());
                if !ok {
                    return *s;
                }
                let mean = |v: &[Vec3]| s.anchors.iter().map(|&a| v[a as usize]).sum::<Vec3>() / 4.0;
                let center = s.center + mean(deformed) - mean(rest);
                let clear_rest = match &rest_tris {
                    Some(t) => t.clearance(s.center, &s.anchors, rest),
                    None => self.rest_clearance[i],
                };
                let clear_now = now_tris.clearance(center, &s.anchors, deformed);
                let radius = match (clear_rest, clear_now) {
                    (Some(a), Some(b)) if a > 0.0 && b.is_finite() => s.radius * (b / a).sqrt(),
                    _ => s.radius,
                };
                BoundSphere { center, radius, ..*s }
            })
            .collect()
    }

    /// The set with each sphere's rest clearance (its centre's distance to the nearest triangle
    /// of `rest`, the mesh in the set's frame) stored, for [`SphereSet::deformed`] to reuse every
    /// frame (the same clearances it would search for; a set built for a deforming object).
    pub fn with_rest_clearances(mut self, rest: &[Vec3], indices: &[u32]) -> Self {
        let tris = MeshTriangles::new(rest, indices);
        self.rest_clearance = self.spheres.iter().map(|s| tris.clearance(s.center, &s.anchors, rest)).collect();
        self
    }

    /// The file text (format in the module docs).
    pub fn to_text(&self) -> String {
        let mut s = format!("penumbra-spheres 1 {}\n", self.spheres.len());
        for b in &self.spheres {
            let _ = writeln!(
                s,
                "{} {} {} {} {} {} {} {}",
                b.center.x, b.center.y, b.center.z, b.radius, b.anchors[0], b.anchors[1], b.anchors[2], b.anchors[3]
            );
        }
        s
    }

    /// Parses the file text.
    pub fn parse(text: &str) -> Result<SphereSet, SphereError> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.split('#').next().unwrap_or("").trim()))
            .filter(|(_, l)| !l.is_empty());
        let (_, head) = lines.next().ok_or_else(|| SphereError::Parse("empty file".into()))?;
        let h: Vec<&str> = head.split_whitespace().collect();
        if h.len() != 3 || h[0] != "penumbra-spheres" || h[1] != "1" {
            return Err(SphereError::Parse(format!("line 1: expected `penumbra-spheres 1 N`, got `{head}`")));
        }
        let n: usize = h[2].parse().map_err(|_| SphereError::Parse(format!("line 1: bad count `{}`", h[2])))?;
        let mut spheres = Vec::with_capacity(n.min(1 << 20));
        for (ln, l) in lines {
            let f: Vec<&str> = l.split_whitespace().collect();
            if f.len() != 8 {
                return Err(SphereError::Parse(format!("line {ln}: expected 8 fields, got {}", f.len())));
            }
            let num = |k: usize| {
                f[k].parse::<f32>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| SphereError::Parse(format!("line {ln}: bad number `{}`", f[k])))
            };
            let idx = |k: usize| {
                f[k].parse::<u32>().map_err(|_| SphereError::Parse(format!("line {ln}: bad index `{}`", f[k])))
            };
            let radius = num(3)?;
            if radius <= 0.0 {
                return Err(SphereError::Parse(format!("line {ln}: radius {radius} <= 0")));
            }
            spheres.push(BoundSphere {
                center: Vec3::new(num(0)?, num(1)?, num(2)?),
                radius,
                anchors: [idx(4)?, idx(5)?, idx(6)?, idx(7)?],
            });
        }
        if spheres.len() != n {
            return Err(SphereError::Parse(format!("header says {n} spheres, file has {}", spheres.len())));
        }
        Ok(SphereSet { spheres, rest_clearance: Vec::new() })
    }
}

/// Distance from `p` to the nearest triangle of the mesh (`None`: no valid triangle).
pub fn surface_distance(p: Vec3, positions: &[Vec3], indices: &[u32]) -> Option<f32> {
    MeshTriangles::new(positions, indices).distance_below(p, f32::INFINITY)
}

/// A mesh's valid triangles, each with a bounding sphere about its centroid (its farthest vertex
/// the radius), for nearest-triangle searches.
struct MeshTriangles {
    tris: Vec<([Vec3; 3], Vec3, f32)>,
}

impl MeshTriangles {
    fn new(positions: &[Vec3], indices: &[u32]) -> Self {
        let tris = indices
            .chunks_exact(3)
            .filter_map(|t| {
                let v = [positions.get(t[0] as usize)?, positions.get(t[1] as usize)?, positions.get(t[2] as usize)?];
                let [a, b, c] = v.map(|p| *p);
                let m = (a + b + c) / 3.0;
                Some(([a, b, c], m, (a - m).length().max((b - m).length()).max((c - m).length())))
            })
            .collect();
        MeshTriangles { tris }
    }

    /// The distance from `c` to the nearest triangle, the search bounded by the nearest of the
    /// `anchors` (mesh vertices of `positions`, the mesh the triangles were made from), which
    /// lets it skip almost every triangle; unbounded when an anchor is out of range.
    fn clearance(&self, c: Vec3, anchors: &[u32; 4], positions: &[Vec3]) -> Option<f32> {
        let near = if anchors.iter().all(|&a| (a as usize) < positions.len()) {
            anchors.iter().map(|&a| (positions[a as usize] - c).length()).fold(f32::INFINITY, f32::min)
        } else {
            f32::INFINITY
        };
        self.distance_below(c, near)
    }

    /// The distance from `p` to the nearest triangle given an upper bound of it (the distance to
    /// a mesh vertex: triangles whose bounding sphere cannot come nearer are skipped; `None`
    /// when there is no valid triangle).
    fn distance_below(&self, p: Vec3, bound: f32) -> Option<f32> {
        let mut best = bound;
        for &([a, b, c], m, reach) in &self.tris {
            if (p - m).length() - reach < best {
                best = best.min((p - closest_point_on_triangle(p, a, b, c)).length());
            }
        }
        (!self.tris.is_empty() && best.is_finite()).then_some(best)
    }
}

/// The point of triangle `abc` nearest to `p` (Ericson, "Real-Time Collision Detection" 5.1.5,
/// by Voronoi regions; a degenerate triangle gives a point of its edges).
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = va + vb + vc;
    if !(denom.abs() > 0.0) {
        // degenerate: the nearest of the three edges' points
        let seg = |u: Vec3, v: Vec3| {
            let d = v - u;
            let l = d.length_squared();
            if l > 0.0 {
                u + d * ((p - u).dot(d) / l).clamp(0.0, 1.0)
            } else {
                u
            }
        };
        return [seg(a, b), seg(b, c), seg(c, a)]
            .into_iter()
            .min_by(|x, y| (p - *x).length_squared().total_cmp(&(p - *y).length_squared()))
            .unwrap_or(a);
    }
    let (v, w) = (vb / denom, vc / denom);
    a + ab * v + ac * w
}
